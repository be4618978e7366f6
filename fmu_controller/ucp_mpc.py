"""MPC with a unique coincidence point (section 3.1, Eq. 11-14).

The controller makes the model's prediction meet the reference at the single coincidence point
``k + Hp``, assuming the input changes only now and is then held:

.. math::
    \\hat l(k+H_p|k) = \\hat l_f(k+H_p|k) + S(H_p)\\,\\Delta u(k), \\qquad
    \\Delta u(k) = \\frac{r(k+H_p|k) - \\hat l_f(k+H_p|k)}{S(H_p)}, \\qquad u(k) = u(k-1) + \\Delta u(k)

The predictor is the nonlinear Eq. (1) model itself (no linearisation), so the free response
``l_f`` (input held at ``u(k-1)``) and the step response ``S(Hp)`` are obtained by simulating the
model from its current state. For a nonlinear model the "unit step response at Hp" depends on the
state; we take it as the model's response to ``u(k-1) + 1 V`` minus the free response, from the
current state (a secant sensitivity, exact for the linear part).

Decisions the paper leaves open:

* **Reference trajectory.** Section 3.1 leaves ``r(k+Hp|k)`` to the designer (a trajectory from the
  current output ``l(k)`` towards the set-point is the classic choice). We take the reference itself,
  ``r(k+Hp|k) = r(k+Hp)``: the references here are known ahead (a sine, steps), and a trajectory
  from ``l(k)`` would add its own time constant to the tracking of a moving reference. The servo
  law takes ``r(k+i|k) = r(k+i)`` in Eq. (15) for the same reason.
* **Input limits.** ``u(k)`` is clipped to the valve's 0-10 V. The clipped value is what ``u(k-1)``
  means at the next step (it is what the valve got), so there is no wind-up.
* **Small step response.** If the model's ``|S(Hp)|`` falls below ``min_step_response_mm_per_v`` (a
  degenerate estimate), the linear part's ``b1 (1 + a1 + ...)`` step response is used instead, so
  Eq. (13) never divides by ~0.
* **A prediction that diverges.** Held for a long horizon (``Hp`` = 20 and more), the adapted
  nonlinear model's prediction can grow without bound (its cubic ``g(l)`` outside the range it was
  fitted on) and overflow. The move is then taken on the linear part ``a1, a2, b1`` alone, the model
  Eq. (1) reduces to without hysteresis, rather than failing the step; if that diverges too, the
  command is held.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import InitVar, dataclass

import numpy as np

from .argument_checks import real_number, whole_number
from .hysteresis_model import ModelState, linear_residual, regressor_terms
from .servo_settings import MAX_HORIZON

_dot = np.dot
_array = np.array

__all__ = ["UCPSettings", "UCPResult", "predict_held_input", "held_input_run", "ucp_move"]


@dataclass(frozen=True, kw_only=True)
class UCPSettings:
    """Settings of the unique-coincidence-point MPC (Table 5)."""

    hp: int = 2
    """Prediction horizon ``Hp`` = the coincidence point [samples] (Table 5: 2)."""
    u_min_v: float = 0.0
    """Lowest valve command [V]."""
    u_max_v: float = 10.0
    """Highest valve command [V]."""
    min_step_response_mm_per_v: float = 1e-3
    """Smallest ``|S(Hp)|`` [mm/V] accepted from the nonlinear model before falling back to the
    linear part's step response."""
    min_step_response_mm: InitVar[float | None] = None
    """The same under its former name (its unit is mm/V): accepted with a DeprecationWarning."""

    def __post_init__(self, min_step_response_mm: float | None) -> None:
        if min_step_response_mm is not None:
            warnings.warn("UCPSettings(min_step_response_mm=...) is min_step_response_mm_per_v (its unit is mm/V)",
                          DeprecationWarning, stacklevel=3)
            object.__setattr__(self, "min_step_response_mm_per_v", min_step_response_mm)
        object.__setattr__(self, "hp", whole_number(self.hp, what="UCPSettings.hp"))
        if not 1 <= self.hp <= MAX_HORIZON:
            raise ValueError(f"UCPSettings.hp must be an integer in 1..{MAX_HORIZON}, got {self.hp!r}")
        for name in ("u_min_v", "u_max_v", "min_step_response_mm_per_v"):  # numpy numbers as Python floats
            object.__setattr__(self, name, real_number(getattr(self, name), what=f"UCPSettings.{name}"))
        if self.u_max_v <= self.u_min_v:
            raise ValueError(f"UCPSettings.u_max_v ({self.u_max_v}) must exceed u_min_v ({self.u_min_v})")
        if self.min_step_response_mm_per_v <= 0:
            raise ValueError(f"UCPSettings.min_step_response_mm_per_v must be > 0, got {self.min_step_response_mm_per_v!r}")


@dataclass(frozen=True)
class UCPResult:
    """One move of the UCP controller."""

    u_v: float
    """Valve command ``u(k)`` [V] after the 0-10 V limit."""
    free_response_mm: float
    """``l_f(k+Hp|k)`` [mm]."""
    step_response_mm_per_v: float
    """``S(Hp)`` used in Eq. (13) [mm/V]."""
    predicted_mm: np.ndarray
    """Model prediction ``l(k+1..k+Hp|k)`` under the chosen (clipped) input [mm]."""
    saturated: bool
    """The 0-10 V limit was active."""


def predict_held_input(state: ModelState, theta: np.ndarray, u_v: float, steps: int) -> np.ndarray:
    """Simulate the Eq. (1) model ``steps`` samples ahead from ``state`` with the input held at ``u_v``.

    ``state`` must hold ``l(k)`` observed (not yet ``u(k)``); it is not modified.

    Parameters
    ----------
    state : ModelState
        History of Eq. (1)'s regressor, with ``l(k)`` observed; not modified.
    theta : ndarray
        Parameters of Eq. (1), ``state.structure``'s length.
    u_v : float
        The command held over the prediction [V].
    steps : int
        Number of samples to predict.
    """
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (state.structure.n_params,):
        raise ValueError(f"theta must have shape ({state.structure.n_params},), got {theta.shape}")
    return np.array(held_input_run(state, theta, theta[:3].tolist(), float(u_v), steps))


def held_input_run(state: ModelState, theta: np.ndarray, lin: list[float], u: float, steps: int,
                   bounds: tuple[float, float] | None = None) -> list[float]:
    """:func:`predict_held_input` as a list, for a float ``theta`` array of the right length and
    its linear part ``lin = [a1, a2, b1]`` as python floats.

    The same arithmetic as stepping a copy of ``state`` by ``phi() @ theta``, ``observe`` and
    ``apply`` (one BLAS dot per step, the rest in python floats), without building the copy.
    ``bounds`` ``(lo, hi)`` [mm]: each prediction clamped into them (the divergence guard of
    :func:`~fmu_controller.prediction.guard_bounds`) before it is carried on.

    Parameters
    ----------
    state : ModelState
        History of Eq. (1)'s regressor, with ``l(k)`` observed; not modified.
    theta : ndarray
        Parameters of Eq. (1) as a float array, ``state.structure``'s length.
    lin : list of float
        Its linear part ``[a1, a2, b1]`` as Python floats.
    u : float
        The command held over the prediction [V] (finite).
    steps : int
        Number of samples to predict.
    bounds : (float, float), optional
        ``(lo, hi)`` [mm]: each prediction clamped into them before it is carried on; None
        (default): no clamp.
    """
    if not math.isfinite(u):
        raise ValueError(f"u must be finite, got {u}")
    a1, a2, b1 = lin
    n = state.structure.n_params
    l2, l1, l0, v2, v1, v0 = state.history
    out = []
    for _ in range(steps):
        terms = regressor_terms(l0, l1, l2, u, v1, v2)
        nxt = float(_dot(_array(terms if n == 15 else terms[:n]), theta))
        if not math.isfinite(nxt):
            raise ValueError(f"l must be finite, got {nxt}")
        if bounds is not None:
            nxt = min(max(nxt, bounds[0]), bounds[1])
        v = linear_residual(nxt, l0, l1, u, a1, a2, b1)
        if not math.isfinite(v):
            raise ValueError(f"theta gives a non-finite v: {v}")
        l2, l1, l0 = l1, l0, nxt
        v2, v1, v0 = v1, v0, v
        out.append(nxt)
    return out


def ucp_move(settings: UCPSettings, state: ModelState, theta: np.ndarray, *, u_prev_v: float,
             r_target_mm: float) -> UCPResult:
    """Eq. (11)-(14): the input ``u(k)`` that puts the prediction on ``r(k+Hp)`` (to the accuracy of
    the step response's secant under the nonlinear model).

    Parameters
    ----------
    settings : UCPSettings
    state : ModelState
        Model history after observing ``l(k)`` (``u(k)`` not applied yet).
    theta : ndarray
        Model parameters (fixed for MPC, the RLS estimate for AMPC).
    u_prev_v : float
        ``u(k-1)`` [V], the command the valve received last.
    r_target_mm : float
        ``r(k+Hp|k)`` [mm].
    """
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (state.structure.n_params,):
        raise ValueError(f"theta must have shape ({state.structure.n_params},), got {theta.shape}")
    u_prev_v = float(u_prev_v)
    linear = np.concatenate([theta[:3], np.zeros(theta.size - 3)])
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is caught as a non-finite value
        for predictor in (theta, linear):
            try:
                return _move(settings, state, predictor, u_prev_v, r_target_mm)
            except ValueError:  # diverged (module docstring)
                continue
    # an unstable linear part as well: the command is held, the prediction is the reading
    held = min(max(u_prev_v, settings.u_min_v), settings.u_max_v) if math.isfinite(u_prev_v) else settings.u_min_v
    l_now = state.history[2]
    return UCPResult(held, l_now, settings.min_step_response_mm_per_v, np.full(settings.hp, l_now), held != u_prev_v)


def _move(settings: UCPSettings, state: ModelState, theta: np.ndarray, u_prev_v: float,
          r_target_mm: float) -> UCPResult:
    """:func:`ucp_move` with the predictor ``theta``; ``ValueError`` if its prediction diverges."""
    hp = settings.hp
    lin = theta[:3].tolist()
    free = held_input_run(state, theta, lin, u_prev_v, hp)
    stepped = held_input_run(state, theta, lin, u_prev_v + 1.0, hp)
    s = stepped[-1] - free[-1]
    if not math.isfinite(s) or abs(s) < settings.min_step_response_mm_per_v:
        # Linear part's unit step response at Hp: sum of its impulse response.
        a1, a2, b1 = float(theta[0]), float(theta[1]), float(theta[2])
        y1, y0, s = 0.0, 0.0, 0.0
        for _ in range(hp):
            y1, y0 = a1 * y1 + a2 * y0 + b1, y1
        s = y1 if abs(y1) >= settings.min_step_response_mm_per_v else math.copysign(settings.min_step_response_mm_per_v, y1 or 1.0)
    du = (r_target_mm - free[-1]) / s
    u = u_prev_v + du
    clipped = min(max(u, settings.u_min_v), settings.u_max_v)
    if not math.isfinite(clipped):
        clipped = u_prev_v if math.isfinite(u_prev_v) else settings.u_min_v
    pred = np.array(held_input_run(state, theta, lin, float(clipped), hp))
    return UCPResult(clipped, free[-1], s, pred, clipped != u)
