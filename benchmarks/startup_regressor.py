"""Which hysteresis state Algorithm 1's regressor takes during the start-up mode.

Run: ``python benchmarks/startup_regressor.py`` (a few seconds). Section 2.3 of the paper computes
``y_hy(k) = v(k) = l(k) - [a1 l(k-1) + a2 l(k-2) + b1 u(k-1)]`` with the current estimate, and the
regressor ``phi(k)`` of Eq. (1) takes ``v(k-1), v(k-2)``. With the start-up mode
(``ControllerSettings.startup_s``) the law runs on ``theta0`` and then on a blend while the estimator
warms up; the controller keeps one model state, so ``v`` is computed with the law's parameters and the
regressor takes that. This prints AMPC-servo's Eq. (21) error and its estimate of ``a1, a2, b1`` at
45 s (0.1 Hz, noise seeds 0-2, 44 and 68 N, the shipped ``theta0``) as coded, and with the
regressor's ``v`` computed from the raw estimate instead (the law unchanged), with and without the
probing signal (docs/control.md, "What the gentle start costs, and the probing signal").
"""

from __future__ import annotations

import numpy as np

from fmu_controller.displacement_control import DEFAULT_PROBING_V, ControllerSettings, DisplacementController
from fmu_controller.hysteresis_model import ASYMMETRIC, ModelState, regressor_terms
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.reference import SineReference
from fmu_plant import Plant
from tapmuscle.closed_loop import eq21_error_mm, run_closed_loop


class _EstimateRegressorState(ModelState):
    """The controller's model state, whose regressor takes ``w``: ``v`` from the raw estimate."""

    w: tuple[float, float, float] = (0.0, 0.0, 0.0)  # (v(k-2), v(k-1), v(k)) of section 2.3

    def phi_list(self) -> list[float]:
        return regressor_terms(self._l0, self._l1, self._l2, self._u, self.w[1], self.w[0])


class _SectionTwoThreeController(DisplacementController):
    """After each step (the law looks ahead on its state, so not inside it), section 2.3's ``v(k)``."""

    def reset(self, *args, **kwargs) -> None:
        super().reset(*args, **kwargs)
        self._state = _EstimateRegressorState(ASYMMETRIC, l_init=self._state.l, u_init=0.0)
        self._u_before = 0.0

    def step(self, l_mm, r_preview_mm):
        out = super().step(l_mm, r_preview_mm)
        s, th = self._state, self._rls.theta
        l2, l1, l0 = s.l
        s.w = (s.w[1], s.w[2], l0 - (th[0] * l1 + th[1] * l2 + th[2] * self._u_before))
        self._u_before = out.u_v
        return out


def run(regressor: str, seed: int, load_n: float, probing_v: float) -> tuple[float, np.ndarray]:
    plant = Plant(seed=seed)
    plant.update(load_n=load_n)
    cls = DisplacementController if regressor == "as coded" else _SectionTwoThreeController
    controller = cls(ControllerSettings(method="ampc_servo", probing_v=probing_v), THETA0_44N)
    out = run_closed_loop(plant, controller, SineReference(frequency_hz=0.1), duration_s=45.0, watch=False)
    return eq21_error_mm(out["r_mm"], out["l_mm"]), np.asarray(controller.theta[:3])


def main() -> None:
    print("AMPC-servo, 0.1 Hz, 45 s, shipped theta0; Eq. (21) [mm] and (a1, a2, b1) at 45 s "
          "(C's lower bound on b1: 0.607)")
    print(f"{'seed':>4} {'load':>5} {'probe V':>7}  {'as coded':<34} {'regressor v from the raw estimate':<34}")
    for probing_v in (DEFAULT_PROBING_V, 0.0):
        for seed in range(3):
            for load_n in (44.0, 68.0):
                cells = []
                for regressor in ("as coded", "section 2.3"):
                    e, lin = run(regressor, seed, load_n, probing_v)
                    cells.append(f"{e:6.3f}  ({lin[0]:.3f}, {lin[1]:.3f}, {lin[2]:.3f})")
                print(f"{seed:>4} {load_n:>5g} {probing_v:>7g}  {cells[0]:<34} {cells[1]:<34}")


if __name__ == "__main__":
    main()
