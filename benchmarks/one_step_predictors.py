"""Benchmark: how well can l(k+1) be predicted from what the controller measures? (docs/fmu.md,
"Parallel masters").

A parallel co-simulation master at h = Ts applies the controller's command one sample late, and the
delay-compensated law then stands in its own prediction of l(k+1) for the measurement. With the true
l(k+1) it tracks as in a sequential master; within 10 % of that needs a one-step error under about
0.015 mm RMS. This script fits predictors *with hindsight* (least squares on the first half of a
120-s AMPC-servo run, scored on the second half), so each figure is about the best an online
predictor of that structure can do:

* ``arx``: l(k) and 3 differences of l, u(k), u(k-1), u(k-2), a constant;
* ``arx+p``: the same with the pressure sensor's p(k), p(k-1), p(k-2);
* ``quadratic+sign``: ``arx+p``, all products of its regressors, and each regressor times the
  direction of motion sign(l(k) - l(k-2)) (the braid friction's switch).

    python benchmarks/one_step_predictors.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fmu_controller.displacement_control import P0_TABLE5, P0_TABLE8, ControllerSettings, DisplacementController  # noqa: E402
from fmu_controller.preliminary_model import THETA0_44N  # noqa: E402
from fmu_controller.reference import SineReference  # noqa: E402
from fmu_plant import Plant  # noqa: E402
from tapmuscle.closed_loop import run_closed_loop  # noqa: E402

CASES = ((44.0, 0.1), (68.0, 0.2))
LOOPS = (("sequential", 0, 0), ("parallel", 1, 1))  # (name, input_delay_samples, loop_delay_samples)


def _loop(load_n: float, f_hz: float, delay: int, loop_delay: int) -> dict[str, np.ndarray]:
    plant = Plant(seed=0)
    plant.update(load_n=load_n)
    cs = ControllerSettings(method="ampc_servo", p0=P0_TABLE8 if f_hz == 0.2 else P0_TABLE5, input_delay_samples=delay)
    return run_closed_loop(plant, DisplacementController(cs, THETA0_44N), SineReference(frequency_hz=f_hz),
                           duration_s=120.0, loop_delay_samples=loop_delay, watch=False)


def _regressors(r: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    l, u, p = r["l_mm"], r["u_v"], r["p_mpa"]
    k = np.arange(200, len(l) - 1)  # after the start-up
    arx = [l[k], l[k] - l[k - 1], l[k - 1] - l[k - 2], l[k - 2] - l[k - 3], u[k], u[k - 1], u[k - 2], np.ones(len(k))]
    with_p = arx + [p[k], p[k - 1], p[k - 2]]
    b = np.column_stack(with_p)
    quad = [b[:, i] * b[:, j] for i in range(b.shape[1]) for j in range(i, b.shape[1]) if 7 not in (i, j)]
    sign = np.sign(l[k] - l[k - 2])
    signed = [b[:, i] * sign for i in range(b.shape[1])]
    return l[k + 1], {"arx": np.column_stack(arx), "arx+p": b, "quadratic+sign": np.column_stack(with_p + quad + signed)}


def _held_out_rms(y: np.ndarray, x: np.ndarray) -> float:
    half = len(y) // 2
    w, *_ = np.linalg.lstsq(x[:half], y[:half], rcond=None)
    return float(np.sqrt(np.mean((y[half:] - x[half:] @ w) ** 2)))


def main() -> None:
    print("one-step prediction error of l(k+1), RMS over the second half [mm] (fitted on the first half)")
    print(f"{'load, f':12s} {'loop':11s} {'arx':>8s} {'arx+p':>8s} {'quadratic+sign':>15s}")
    for load_n, f_hz in CASES:
        for name, delay, loop_delay in LOOPS:
            y, sets = _regressors(_loop(load_n, f_hz, delay, loop_delay))
            rms = {k: _held_out_rms(y, x) for k, x in sets.items()}
            print(f"{f'{load_n:.0f} N {f_hz} Hz':12s} {name:11s} {rms['arx']:8.4f} {rms['arx+p']:8.4f} "
                  f"{rms['quadratic+sign']:15.4f}", flush=True)
    print("within 10 % of the sequential master needs about 0.015 mm (docs/fmu.md)")


if __name__ == "__main__":
    main()
