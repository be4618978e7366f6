"""Predictions, fit and offline identification for the model of Eq. (1).

Conventions (``l`` in mm, ``u`` in V, sample index ``k``, period ``Ts``):

* The first :data:`N_INITIAL` = 4 samples ``l(0..3)`` are initial conditions.
  The virtual hysteresis variable (section 2.3) is ``v(k) = l(k) - [a1 l(k-1)
  + a2 l(k-2) + b1 u(k-1)]`` for ``k >= 2`` and ``v(0) = v(1) = 0`` (no data
  before ``k = 0``).  The first model output is ``l(4)``, whose regressor ``phi(3)``
  (``v(2)``, ``v(1)``) holds one of those placeholders; from ``l(5)`` on every ``v`` is
  the data's.  Starting at ``l(4)`` keeps at most one placeholder in a regressor.
* Inside a prediction, ``v`` is computed from *predicted* ``l`` with the same
  formula, which within the model equals the hysteresis term ``H(k-1)``.
* Results are full-length arrays; entries before ``start`` hold the measured
  samples (no prediction exists there) and must be excluded from scores:
  ``fit_percent(l, res.l_hat, start=res.start)``.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .hysteresis_model import (
    ModelState,
    ModelStructure,
    linear_residual,
    regressor_terms,
    virtual_hysteresis_sequence,
)
from .rls import ConstrainedRLS, RLSSettings

__all__ = [
    "N_INITIAL",
    "MAX_INPUT_DELAY_SAMPLES",
    "checked_input_delay",
    "delay_samples_for",
    "delayed_input",
    "guard_bounds",
    "PredictionResult",
    "IdentificationResult",
    "simulate",
    "RUNAWAY_RANGE_MM",
    "held_command_runaway",
    "predict_ahead",
    "fit_percent",
    "run_rls",
    "theta_scale_factors",
    "rescale_theta",
]

#: Number of leading measured samples used as initial conditions.
N_INITIAL = 4

# Divergence guard: outputs are clamped to [lo - G*span, hi + G*span].
_GUARD_SPANS = 10.0

#: Largest input delay [samples] of Eq. (1)'s input: the controller's ``input_delay_samples`` set and
#: the identification's. 0.5 s at Ts = 0.02 s, a rig logged at 50 Hz (the field rigs' transport delays
#: reach 0.35 s; a 0.15-s valve delay at that Ts is 8 samples), and 2.5 s at the paper's 0.1 s.
MAX_INPUT_DELAY_SAMPLES = 25


def checked_input_delay(delay_samples: int) -> int:
    """``delay_samples`` if it is a whole number of samples 0 .. :data:`MAX_INPUT_DELAY_SAMPLES`.

    Parameters
    ----------
    delay_samples : int
        Input delay [samples].

    Raises
    ------
    ValueError
        Anything else, named as ``input_delay_samples``.
    """
    d = delay_samples
    if isinstance(d, (bool, np.bool_)) or not isinstance(d, numbers.Integral) or not 0 <= d <= MAX_INPUT_DELAY_SAMPLES:
        raise ValueError(f"input_delay_samples must be a number of samples 0 .. {MAX_INPUT_DELAY_SAMPLES}, got {d!r}")
    return int(d)


def delay_samples_for(delay_s: float, ts_s: float) -> int:
    """The ``input_delay_samples`` for a transport delay of ``delay_s`` [s] at the sampling period
    ``ts_s`` [s]: the whole number of samples within a quarter of a sample of ``delay_s / ts_s``, else
    the longer of the two around it, which the servo methods track better with and
    ``input_delay_samples = -1`` decides (docs/control.md, "Transport delay"). Not capped at
    :data:`MAX_INPUT_DELAY_SAMPLES`: the caller says what a longer delay means for it.

    Parameters
    ----------
    delay_s : float
        Transport delay [s], >= 0.
    ts_s : float
        Sampling period [s], > 0.

    Raises
    ------
    ValueError
        ``delay_s`` negative or not finite, ``ts_s`` not positive and finite.
    """
    if not (math.isfinite(delay_s) and delay_s >= 0.0):
        raise ValueError(f"delay_s must be a delay >= 0 s, got {delay_s!r}")
    if not (math.isfinite(ts_s) and ts_s > 0.0):
        raise ValueError(f"ts_s must be a sampling period > 0 s, got {ts_s!r}")
    n = delay_s / ts_s
    return round(n) if abs(n - round(n)) <= 0.25 else math.ceil(n)


def delayed_input(u: np.ndarray, delay_samples: int) -> np.ndarray:
    """The command the valve had at each sample, ``u(k - d)`` [V], for a loop that applies each
    command ``d`` samples late (a rig's transport delay): Eq. (1)'s input on such a rig. The first
    ``d`` samples repeat ``u(0)`` (the record holds nothing earlier).

    Parameters
    ----------
    u : ndarray
        The commands computed, one per sample [V].
    delay_samples : int
        Input delay ``d`` [samples], 0 .. :data:`MAX_INPUT_DELAY_SAMPLES`.

    Raises
    ------
    ValueError
        ``delay_samples`` not a whole number 0 .. :data:`MAX_INPUT_DELAY_SAMPLES`.
    """
    d = checked_input_delay(delay_samples)
    u = np.asarray(u, dtype=float)
    if d == 0:
        return u
    return np.concatenate([np.full(d, u[0]), u[:len(u) - d]])


@dataclass(frozen=True)
class PredictionResult:
    """Output of :func:`simulate` / :func:`predict_ahead`.

    Attributes
    ----------
    l_hat : ndarray, shape (N,)
        Predicted displacement in mm; ``l_hat[k]`` for ``k >= start`` is the
        model prediction, earlier entries are the measured samples.
    start : int
        First index holding a prediction.
    horizon : int or None
        Prediction horizon ``h`` (``l_hat[k] = l_hat(k|k-h)``); None for the
        free-run simulation.
    diverged : bool
        True if the divergence guard clamped any predicted value.
    """

    l_hat: np.ndarray
    start: int
    horizon: int | None
    diverged: bool


@dataclass(frozen=True)
class IdentificationResult:
    """Output of :func:`run_rls`.

    Attributes
    ----------
    theta : ndarray, shape (n_params,)
        Final estimate.
    theta_history : ndarray, shape (N, n_params)
        Row ``k`` is ``theta(k)``, the estimate after using ``l(k)``; rows
        before ``start`` equal ``theta(0)``.
    errors : ndarray, shape (N,)
        A-priori one-step errors ``l(k) - phi(k-1)^T theta(k-1)`` in mm
        (0 before ``start``).
    start : int
        Index of the first RLS update (``N_INITIAL``).
    P : ndarray, shape (n_params, n_params)
        Final covariance.
    n_projections : int
        Updates where Algorithm 1 projected the estimate.
    n_resets : int
        Covariance resets (see ``RLSSettings.on_covariance_loss``).
    """

    theta: np.ndarray
    theta_history: np.ndarray
    errors: np.ndarray
    start: int
    P: np.ndarray
    n_projections: int
    n_resets: int


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def _vector(name: str, x, length: int | None = None) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if length is not None and arr.size != length:
        raise ValueError(f"{name} must have length {length}, got {arr.size}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite")
    return arr


def _theta(theta, structure: ModelStructure) -> np.ndarray:
    if not isinstance(structure, ModelStructure):
        raise ValueError(f"structure must be a ModelStructure, got {structure!r}")
    return _vector("theta", theta, structure.n_params)


def guard_bounds(output_range: tuple[float, float] | None, fallback: Sequence[float] | np.ndarray,
                 widen: bool) -> tuple[float, float]:
    """The divergence guard's interval ``[lo - 10 span, hi + 10 span]`` [mm] for predictions of Eq. (1).

    A prediction of the model outside it (or non-finite) is clamped into it: an estimate that is not
    physical, chained through its bilinear hysteresis terms, otherwise grows without bound (to the
    overflow of a float within a few samples).

    Parameters
    ----------
    output_range : (float, float) or None
        ``(lo, hi)`` [mm], typically a measured record's min and max; None: from ``fallback``.
    fallback : sequence of float
        Measured displacements [mm] that set ``(lo, hi)`` when ``output_range`` is None.
    widen : bool
        With ``fallback``: ``span`` at least ``max(|lo|, |hi|, 1 mm)`` (a few samples say little
        about the operating range), else ``hi - lo``.
    """
    if output_range is None:
        # a record's array, or a controller's few measured values at every sample (no array made there)
        lo, hi = ((float(fallback.min()), float(fallback.max())) if isinstance(fallback, np.ndarray)
                  else (float(min(fallback)), float(max(fallback))))
        if widen:
            # a few initial samples say little about the operating range
            span = max(hi - lo, abs(lo), abs(hi), 1.0)
        else:
            span = hi - lo if hi > lo else max(abs(lo), 1.0)
    else:
        lo, hi = (float(x) for x in output_range)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"output_range must be finite with lo < hi, got {output_range!r}")
        span = hi - lo
    return lo - _GUARD_SPANS * span, hi + _GUARD_SPANS * span


def _propagate(theta, n, l0, l1, l2, v0, v1, v2, u_steps, bounds, record):
    """Run the model recursion from one or many origins ``o``.

    ``l0..l2`` = ``l(o), l(o-1), l(o-2)``, ``v0..v2`` = ``v(o), v(o-1), v(o-2)``
    (Python floats for one origin, arrays over origins otherwise);
    ``u_steps[j]`` = ``u(o+j)``.  Returns the last prediction (and all of them
    if ``record``) and the divergence flag.
    """
    t = theta.tolist()[:n]
    a1, a2, b1 = t[0], t[1], t[2]
    lo, hi = bounds
    mid = 0.5 * (lo + hi)
    scalar = isinstance(l0, float)  # pure-float path is ~10x faster per step
    diverged = False
    out = []
    for u0 in u_steps:
        terms = regressor_terms(l0, l1, l2, u0, v1, v2)
        l_new = t[0] * terms[0]
        for coef, term in zip(t[1:], terms[1:n]):
            l_new = l_new + coef * term
        # clamp instead of propagating inf/NaN; NaN has no side, use mid
        if scalar:
            if not lo <= l_new <= hi:  # also true for NaN
                diverged = True
                l_new = mid if l_new != l_new else min(max(l_new, lo), hi)
        elif not ((l_new >= lo) & (l_new <= hi)).all():
            diverged = True
            l_new = np.where(np.isnan(l_new), mid, np.clip(l_new, lo, hi))
        v_new = linear_residual(l_new, l0, l1, u0, a1, a2, b1)
        l2, l1, l0 = l1, l0, l_new
        v2, v1, v0 = v1, v0, v_new
        if record:
            out.append(l_new)
    return l0, out, diverged


# ---------------------------------------------------------------------------
# predictions
# ---------------------------------------------------------------------------
def simulate(
    theta: Sequence[float] | np.ndarray,
    structure: ModelStructure,
    u: Sequence[float] | np.ndarray,
    l_init: Sequence[float] | np.ndarray,
    *,
    output_range: tuple[float, float] | None = None,
) -> PredictionResult:
    """Free-run ("simulated output", Table 4) of the regression model of Eq. (1).

    ``l(0..3)`` are the measured initial conditions; from ``l(4)`` on the model
    uses only its own outputs (and their ``v``) plus the input ``u``.

    Divergence guard: any output outside ``[lo - 10 span, hi + 10 span]``
    (``span = hi - lo``) or non-finite is clamped into that interval and
    ``diverged`` is set; the output is always finite.

    Parameters
    ----------
    theta : array_like, shape (n_params,)
        Regression coefficients (section 2.3).
    structure : ModelStructure
        Model variant.
    u : array_like, shape (N,)
        Valve voltage in V (``u(k-1)`` drives ``l(k)``; ``u[-1]`` is unused).
    l_init : array_like, shape (4,)
        Measured ``l(0..3)`` in mm.
    output_range : (float, float), optional
        ``(lo, hi)`` in mm, typically the measured record's min and max.
        Default: min and max of ``l_init`` with ``span`` widened to at least
        ``max(|lo|, |hi|, 1 mm)``.

    Returns
    -------
    PredictionResult
        ``start = 4``, ``horizon = None``.
    """
    theta = _theta(theta, structure)
    u = _vector("u", u)
    l_init = _vector("l_init", l_init, N_INITIAL)
    N = u.size
    if N <= N_INITIAL:
        raise ValueError(f"u must have more than {N_INITIAL} samples, got {N}")
    bounds = guard_bounds(output_range, l_init, widen=True)
    v = virtual_hysteresis_sequence(theta, l_init, u[:N_INITIAL])
    o = N_INITIAL - 1
    li, vi = l_init.tolist(), v.tolist()
    _, out, diverged = _propagate(
        theta, structure.n_params,
        li[o], li[o - 1], li[o - 2], vi[o], vi[o - 1], vi[o - 2],
        u[o:N - 1].tolist(), bounds, record=True,
    )
    l_hat = np.empty(N)
    l_hat[:N_INITIAL] = l_init
    l_hat[N_INITIAL:] = out
    return PredictionResult(l_hat=l_hat, start=N_INITIAL, horizon=None, diverged=diverged)


#: The free run of a model of the muscle from rest under a held command stays within ten spans of this
#: range [mm] either side, -1000..1100 mm (a McKibben muscle contracts by a fraction of its length: the
#: simulated 600-mm muscle at 0.4 MPa and 20 N by 163 mm); a model whose free run leaves it runs away.
RUNAWAY_RANGE_MM = (0.0, 100.0)


def held_command_runaway(theta: Sequence[float] | np.ndarray, structure: ModelStructure,
                         commands_v: Sequence[float], n_samples: int) -> float | None:
    """The first command of ``commands_v`` [V] under which Eq. (1)'s free run from rest runs away.

    From rest (``l = 0``, ``u = 0`` for the :data:`N_INITIAL` initial samples) the command is held for
    ``n_samples`` samples; the model runs away where its free run (:func:`simulate`) leaves the
    divergence guard of :data:`RUNAWAY_RANGE_MM`. A model identified with a box C that does not hold the
    rig can fit the data one step ahead to 99 % and still run away (its free run a meaningless fit): as
    a fixed law's predictor it inverts the valve's effect at rest and holds the valve at a limit.

    Parameters
    ----------
    theta : array_like, shape (n_params,)
        Eq. (1)'s parameters [mm, V].
    structure : ModelStructure
        Model variant.
    commands_v : sequence of float
        The held commands to try [V], in order.
    n_samples : int
        Samples of each held command (more than :data:`N_INITIAL`).

    Returns
    -------
    float or None
        The first command under which the free run ran away; None where none did.
    """
    for u_v in commands_v:
        u = np.full(int(n_samples), float(u_v))
        u[:N_INITIAL] = 0.0
        if simulate(theta, structure, u, np.zeros(N_INITIAL), output_range=RUNAWAY_RANGE_MM).diverged:
            return float(u_v)
    return None


def predict_ahead(
    theta: Sequence[float] | np.ndarray,
    structure: ModelStructure,
    u: Sequence[float] | np.ndarray,
    l: Sequence[float] | np.ndarray,
    horizon: int,
    *,
    output_range: tuple[float, float] | None = None,
) -> PredictionResult:
    """``horizon``-step-ahead predictions ``l_hat(k|k-h)`` (Table 4, Fig. 20).

    Uses measured ``l`` up to ``k-h`` (with ``v`` from the measured data and
    ``theta``), the known input up to ``u(k-1)``, and the model recursion for
    ``h`` steps with ``v`` computed from predicted ``l``.  ``horizon = 1`` is
    the one-step prediction ``phi(k-1)^T theta``.  Same divergence guard as
    :func:`simulate`.

    Parameters
    ----------
    theta : array_like, shape (n_params,)
        Regression coefficients.
    structure : ModelStructure
        Model variant.
    u, l : array_like, shape (N,)
        Measured valve voltage (V) and displacement (mm).
    horizon : int
        ``h >= 1``.
    output_range : (float, float), optional
        Guard range in mm; default ``(min(l), max(l))``.

    Returns
    -------
    PredictionResult
        ``start = 3 + h`` (origin ``k-h >= 3``, see module docstring).
    """
    theta = _theta(theta, structure)
    l = _vector("l", l)
    u = _vector("u", u, l.size)
    h = int(horizon)
    if h != horizon or h < 1:
        raise ValueError(f"horizon must be an integer >= 1, got {horizon!r}")
    N = l.size
    start = N_INITIAL - 1 + h
    if N <= start:
        raise ValueError(f"l has {N} samples, need more than {start} for horizon {h}")
    bounds = guard_bounds(output_range, l, widen=False)
    v = virtual_hysteresis_sequence(theta, l, u)
    o = np.arange(N_INITIAL - 1, N - h)
    u_steps = [u[o + j] for j in range(h)]
    last, _, diverged = _propagate(
        theta, structure.n_params,
        l[o], l[o - 1], l[o - 2], v[o], v[o - 1], v[o - 2],
        u_steps, bounds, record=False,
    )
    l_hat = l.copy()
    l_hat[start:] = last
    return PredictionResult(l_hat=l_hat, start=start, horizon=h, diverged=diverged)


def fit_percent(
    y: Sequence[float] | np.ndarray,
    yhat: Sequence[float] | np.ndarray,
    *,
    start: int = 0,
) -> float:
    """NRMSE fit in %, as MATLAB ``compare`` (Table 4).

    ``fit = 100 (1 - ||y - yhat||_2 / ||y - mean(y)||_2)`` over the samples
    ``k >= start`` only, i.e. where a prediction exists (pass
    ``PredictionResult.start``); ``mean(y)`` is taken over the same samples.
    100 = perfect, 0 = as good as predicting the mean, may be negative.

    Parameters
    ----------
    y : array_like, shape (N,)
        Measured output.
    yhat : array_like, shape (N,)
        Predicted output.
    start : int
        First compared sample.
    """
    y = _vector("y", y)
    yhat = _vector("yhat", yhat, y.size)
    if not (0 <= int(start) < y.size - 1):
        raise ValueError(f"start must be in [0, {y.size - 2}], got {start!r}")
    y = y[int(start):]
    yhat = yhat[int(start):]
    denom = np.linalg.norm(y - y.mean())
    if denom == 0.0:
        raise ValueError("y is constant over the compared samples; fit is undefined")
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / denom))


# ---------------------------------------------------------------------------
# identification
# ---------------------------------------------------------------------------
def run_rls(
    structure: ModelStructure,
    u: Sequence[float] | np.ndarray,
    l: Sequence[float] | np.ndarray,
    settings: RLSSettings | None = None,
) -> IdentificationResult:
    """Run the constrained RLS (Eq. (4), Algorithm 1) over a whole record.

    The regressor uses ``v(k)`` computed with the estimate current at time
    ``k`` (``theta(0)`` for ``k <= 3``, then the updated ``theta(k)``), as in
    section 2.3.  Updates start at ``k = 4`` (``phi(3)``, ``y = l(4)``); the
    constraint clock counts from ``k = 0`` (``t = k Ts``).

    Parameters
    ----------
    structure : ModelStructure
        Model variant.
    u, l : array_like, shape (N,)
        Valve voltage (V) and displacement (mm).
    settings : RLSSettings, optional
        Default ``RLSSettings()`` (paper: ``P(-1) = 1e3 I``, ``theta(0) = 0``,
        Table 2 box from 120 s).

    Returns
    -------
    IdentificationResult
    """
    if not isinstance(structure, ModelStructure):
        raise ValueError(f"structure must be a ModelStructure, got {structure!r}")
    l = _vector("l", l)
    u = _vector("u", u, l.size)
    N = l.size
    if N <= N_INITIAL:
        raise ValueError(f"l must have more than {N_INITIAL} samples, got {N}")
    o = N_INITIAL - 1
    rls = ConstrainedRLS(structure, settings, k0=o)
    theta = rls.theta
    v_init = virtual_hysteresis_sequence(theta, l[:N_INITIAL], u[:N_INITIAL])
    state = ModelState(
        structure, l_init=l[o - 2:o + 1], v_init=v_init[o - 2:o + 1], u_init=u[o]
    )
    history = np.empty((N, structure.n_params))
    history[:N_INITIAL] = theta
    errors = np.zeros(N)
    for k in range(N_INITIAL, N):
        phi = state.phi()
        errors[k] = l[k] - phi @ theta
        theta = rls.update(phi, l[k])
        history[k] = theta
        state.update(l[k], u[k], theta)
    return IdentificationResult(
        theta=theta,
        theta_history=history,
        errors=errors,
        start=N_INITIAL,
        P=rls.P,
        n_projections=rls.n_projections,
        n_resets=rls.n_resets,
    )


# ---------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------
def theta_scale_factors(structure: ModelStructure, l_scale: float, u_scale: float) -> np.ndarray:
    """Factors ``f`` with ``theta_physical = f * theta_scaled``.

    For data scaled as ``l / l_scale``, ``u / u_scale`` (``v`` scales like
    ``l``): ``a, A, c`` unchanged; ``b1`` times ``l_scale / u_scale``;
    ``beta, gamma, xi2`` times ``1 / l_scale``; ``xi3`` times ``1 / l_scale^2``.

    A box transforms as ``f * bound``.  The RLS covariance transforms as
    ``diag(f) P diag(f) / l_scale^2``: the ``1`` in the Eq. (4) denominator is
    the output-error weight, which is in the units of ``l^2``.  With ``P(-1)``
    and the box transformed this way, RLS on scaled data is exactly
    equivalent to RLS on raw data (up to rounding).

    Parameters
    ----------
    structure : ModelStructure
        Model variant (which parameters, in order).
    l_scale : float
        Scale the displacement was divided by (finite, > 0).
    u_scale : float
        Scale the command was divided by (finite, > 0).
    """
    for name, s in (("l_scale", l_scale), ("u_scale", u_scale)):
        if not (math.isfinite(float(s)) and float(s) > 0):
            raise ValueError(f"{name} must be finite and > 0, got {s!r}")
    l_scale, u_scale = float(l_scale), float(u_scale)
    per_name = {
        "a1": 1.0, "a2": 1.0, "b1": l_scale / u_scale,
        "A1": 1.0, "A2": 1.0,
        "beta1": 1.0 / l_scale, "beta2": 1.0 / l_scale,
        "gamma1": 1.0 / l_scale, "gamma2": 1.0 / l_scale,
        "c1": 1.0, "c2": 1.0,
        "xi21": 1.0 / l_scale, "xi22": 1.0 / l_scale,
        "xi31": 1.0 / l_scale ** 2, "xi32": 1.0 / l_scale ** 2,
    }
    return np.array([per_name[name] for name in structure.names])


def rescale_theta(
    theta: Sequence[float] | np.ndarray,
    structure: ModelStructure,
    l_scale: float,
    u_scale: float,
) -> np.ndarray:
    """Convert ``theta`` identified on ``(l / l_scale, u / u_scale)`` to physical units.

    See :func:`theta_scale_factors`.

    Parameters
    ----------
    theta : sequence of float or ndarray
        Parameters identified on the scaled data, in ``structure``'s order.
    structure : ModelStructure
        Model variant of ``theta``.
    l_scale : float
        Scale the displacement was divided by (finite, > 0).
    u_scale : float
        Scale the command was divided by (finite, > 0).
    """
    theta = _theta(theta, structure)
    return theta * theta_scale_factors(structure, l_scale, u_scale)
