"""The one-step prediction ``l(k+1|k)`` of the delay-compensated control law.

With one sample of input delay (``ControllerSettings.input_delay_samples = 1``: a parallel
co-simulation master at h = Ts, or a controller whose computation takes a sample) the law computes
``u(k+1)`` at sample ``k`` and must stand in for the measurement ``l(k+1)`` it does not yet have.
How much that costs is set by the one-step error alone: with the rig's true ``l(k+1)`` handed to
it the delayed loop tracks exactly as the undelayed one, and a white error of 0.03 mm RMS in that
value already raises the Eq. (21) error by about 20 % (docs/fmu.md, "Parallel masters").

Eq. (1) alone predicts ``l(k+1)`` from ``l(k), l(k-1)`` and ``u(k)``. The rig's valve spool and
hydraulic compliance delay the response to the command by more than that (the command of the
sample before still acts), so on the closed loop its one-step error is 0.3-0.5 mm RMS, a slowly
varying bias rather than noise, which a fixed correction by the last error does not remove (the
loop then feeds the error back through the command). :class:`DelayPredictor` keeps Eq. (1)'s
prediction ``p(k+1|k)`` and adds a linear correction fitted online to its residual by recursive
least squares with forgetting, on the regressor

.. math::

    \\psi(k) = [\\,l(k) - l(k-1),\\; l(k) - l(k-2),\\; l(k) - l(k-3),\\; u(k),\\; u(k-1),\\; 1,\\;
               p(k+1|k) - l(k)\\,]

so that ``l(k+1|k) = p(k+1|k) + psi(k)^T w(k)``. The last entry lets the fit rescale Eq. (1)'s own
predicted increment (a gain error of ``b1`` or of the hysteresis term), the lags and ``u(k-1)`` give
it the dynamics Eq. (1) lacks, and the constant its bias. ``w`` starts at zero (Eq. (1) unchanged)
and the correction is applied once :attr:`DelayPredictor.warmup_samples` updates have been made.

Lifecycle as osqp's: construct, :meth:`DelayPredictor.reset` with the first measurement,
:meth:`DelayPredictor.predict` every sample; :meth:`get_state`/:meth:`set_state` for exact rewind.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from .argument_checks import real_number, whole_number
from .rls import ConstrainedRLS, Regressors, RLSSettings

__all__ = ["DelayPredictor", "DELAY_PREDICTOR_REGRESSORS"]

#: The entries of ``psi(k)`` (module docstring).
DELAY_PREDICTOR_REGRESSORS = Regressors(names=("dl1", "dl2", "dl3", "u0", "u1", "bias", "model_increment"))

_N = DELAY_PREDICTOR_REGRESSORS.n_params


class DelayPredictor:
    """Eq. (1)'s one-step prediction with an online-fitted residual correction (module docstring).

    Parameters
    ----------
    forgetting : float
        RLS forgetting factor ``lambda`` in (0, 1): a memory of about ``1 / (1 - lambda)`` samples.
        The default 0.975 (4 s at Ts = 0.1 s, under half a period of the paper's references) was the
        best of 0.95-0.999 in the delayed AMPC-servo loop at 44/68 N and 0.1/0.2 Hz.
    p0 : float
        Initial covariance ``P(0) = p0 I`` [mm^2 per regressor unit^2]; its ceiling too (the
        estimator never becomes more uncertain than at the start, which stops covariance wind-up
        while the rig is at rest).
    warmup_samples : int
        Updates made before the correction is applied.
    """

    def __init__(self, *, forgetting: float = 0.975, p0: float = 1.0, warmup_samples: int = 20) -> None:
        forgetting = real_number(forgetting, what="forgetting")
        p0 = real_number(p0, what="p0")
        warmup_samples = whole_number(warmup_samples, what="warmup_samples")
        if not 0.0 < forgetting < 1.0:
            raise ValueError(f"forgetting must be within (0, 1), got {forgetting!r}")
        if not p0 > 0:
            raise ValueError(f"p0 must be a positive finite number, got {p0!r}")
        if warmup_samples < 0:
            raise ValueError(f"warmup_samples must be an integer >= 0, got {warmup_samples!r}")
        self.forgetting = forgetting
        self.p0 = p0
        self.warmup_samples = warmup_samples
        inf = (math.inf,) * _N
        self._rls = ConstrainedRLS(DELAY_PREDICTOR_REGRESSORS, RLSSettings(
            p0=self.p0, theta0=(0.0,) * _N, forgetting=self.forgetting, box_lower=tuple(-x for x in inf),
            box_upper=inf, constraint_start_s=math.inf, covariance_ceiling=True))
        self.reset(0.0, 0.0)

    def reset(self, l_mm: float, u_prev_v: float) -> None:
        """Start over (``w = 0``) at rest at ``l_mm`` [mm], the valve last at ``u_prev_v`` [V]."""
        l, u = float(l_mm), float(u_prev_v)
        if not (math.isfinite(l) and math.isfinite(u)):
            raise ValueError(f"l_mm and u_prev_v must be finite, got {l_mm!r}, {u_prev_v!r}")
        self._rls.setup(DELAY_PREDICTOR_REGRESSORS, self._rls.settings)
        self._l = [l, l, l, l]  # l(k), l(k-1), l(k-2), l(k-3) once the next measurement is in
        self._u_prev = u
        self._w = self._rls.theta  # the estimator's own array, replaced (never modified) by each update
        self._psi: list[float] | None = None  # psi(k-1) and p(k|k-1), awaiting l(k)
        self._model = math.nan
        self._updates = 0

    @property
    def weights(self) -> np.ndarray:
        """The correction's coefficients ``w(k)`` (a copy), in the order of
        :data:`DELAY_PREDICTOR_REGRESSORS`."""
        return self._rls.theta

    def predict(self, l_mm: float, u_v: float, model_mm: float) -> float:
        """``l(k+1|k)`` [mm] from the measured ``l(k)`` [mm], the command ``u(k)`` [V] the valve has
        over ``[t_k, t_k+1)`` and Eq. (1)'s prediction ``p(k+1|k)`` [mm] under it.

        First fits the correction to ``l(k) - p(k|k-1)`` (the last prediction's residual), then
        predicts. Inputs are the controller's own finite floats; a non-finite correction is not
        applied (Eq. (1)'s prediction is returned).
        """
        l, u, p = float(l_mm), float(u_v), float(model_mm)
        if self._psi is not None:
            self._w = self._rls.update_unchecked(np.array(self._psi), l - self._model)
            self._updates += 1
        hist = self._l
        hist[3], hist[2], hist[1], hist[0] = hist[2], hist[1], hist[0], l
        psi = [l - hist[1], l - hist[2], l - hist[3], u, self._u_prev, 1.0, p - l]
        self._u_prev = u
        self._psi, self._model = psi, p
        if self._updates < self.warmup_samples:
            return p
        correction = float(np.dot(self._w, psi))
        return p + correction if math.isfinite(correction) else p

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        """Plain data (JSON-serialisable) to continue bit-identically."""
        rls = self._rls.get_state()
        rls["theta"], rls["P"] = rls["theta"].tolist(), rls["P"].tolist()
        return {"rls": rls, "l": list(self._l), "u_prev": self._u_prev, "psi": self._psi,
                "model": self._model, "updates": self._updates}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`'s result.

        Raises
        ------
        ValueError
            A field no predictor could have saved (non-finite, wrong length, negative count), named.
        """
        hist = [float(x) for x in state["l"]]
        if len(hist) != 4 or not all(map(math.isfinite, hist)):
            raise ValueError(f"delay predictor state field l must be 4 finite numbers, got {state['l']!r}")
        u_prev = float(state["u_prev"])
        if not math.isfinite(u_prev):
            raise ValueError(f"delay predictor state field u_prev = {state['u_prev']!r} must be finite")
        psi = state["psi"]
        if psi is not None:
            psi = [float(x) for x in psi]
            if len(psi) != _N or not all(map(math.isfinite, psi)) or not math.isfinite(float(state["model"])):
                raise ValueError(f"delay predictor state fields psi, model must be {_N} finite numbers and a "
                                 f"finite number, got {state['psi']!r}, {state['model']!r}")
        updates = int(state["updates"])
        if updates < 0:
            raise ValueError(f"delay predictor state field updates = {state['updates']!r} must be >= 0")
        self._rls.set_state(state["rls"])
        self._w = self._rls.theta
        self._l, self._u_prev, self._psi = hist, u_prev, psi
        self._model = math.nan if psi is None else float(state["model"])
        self._updates = updates
