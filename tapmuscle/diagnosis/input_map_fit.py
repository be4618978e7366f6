"""The ``input_map`` candidate's fitter: a monotone piecewise-linear map of the valve command.

The map runs through (0 V, ``out_at_0_v``), two knots and (10 V, ``out_at_10_v``)
(:class:`fmu_plant.parameters.InputMapParams`). :func:`fit_input_map` starts from a 1-V dead band at
13 centres, then runs bounded least squares (trust-region reflective, finite-difference Jacobian
Broyden-updated between refreshes) in coordinates where order and monotonicity are bounds,
simulating the fit segment, within a budget of simulations; the straight line closest to the fit
replaces it when it fits as well (docs/diagnosis.md, the vocabulary table).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from fmu_plant import PlantParams
from fmu_plant.effect_library import input_map_v
from fmu_plant.parameters import InputMapParams
from tapmuscle.diagnosis.fit_problem import FitResult, Problem, full_prediction
from tapmuscle.diagnosis.reproducible import broyden_update, snap, snap_relative, sse

__all__ = ["fit_input_map", "explain_input_map"]


#: Bounds of the input-map search in its reparameterisation (:func:`_input_map_values`): knots' centre,
#: knots' spacing [V]; mean output at the knots, output rise between them [V]; slopes of the segments
#: below and above the knots [-].
_MAP_LO = np.array([0.05, 0.02, 0.0, 0.0, 0.0, 0.0])
_MAP_HI = np.array([9.95, 6.0, 10.0, 10.0, 3.0, 3.0])
#: Finite-difference steps of the input-map Jacobian, well above the solver's tolerance in the cost.
_MAP_STEP = np.array([0.05, 0.05, 0.05, 0.05, 0.02, 0.02])
#: Most simulations of the fit segment one input-map fit may run (starts, steps and Jacobians).
_MAP_SIMULATIONS = 70
#: Of those, kept for trying a straight line once the search is done.
_MAP_SIMPLER = 1
#: Between finite-difference Jacobians, this many Broyden updates (one simulation each, not seven).
_MAP_BROYDEN = 8
#: A least-squares run that lowers the cost by less than this share ends the fit; more gain a restart
#: from a fresh finite-difference Jacobian.
_MAP_FTOL = 1e-2
#: Weight of the damping rows towards a least-squares run's start, in noise levels per unit of the
#: search coordinates (volts, or a slope).
_MAP_DAMPING = 0.1
#: The input-map fit stops once the training residual's RMS is within this factor of the noise, or
#: its energy below this share of the base residual's (RMS 0.3 %: the fit then lacks < 0.3 % of the
#: base residual's held-out RMS).
_MAP_DONE_RMS = 1.5
_MAP_DONE_SHARE = 1e-5
#: A segment of the input map this flat [V/V] is a dead band (inside the knots) or a saturation (outside).
_FLAT_GAIN = 0.15
#: Segments whose gains differ by no more than this [V/V] read as one straight line (gain and offset).
_SAME_GAIN = 0.1


def _input_map_values(x: np.ndarray) -> dict[str, float]:
    """Plant parameters ``input_map.*`` of the search point ``x`` (see :data:`_MAP_LO`).

    In these coordinates the map's ordering and monotonicity are simple bounds (a spacing, a rise and
    slopes that are not negative); what the bounds leave open (a knot beyond 0..10 V, an output above
    10 V) is clipped, which keeps the map, and so the cost, continuous in ``x``.
    """
    c, w, vm, dv, s_lo, s_hi = (float(v) for v in x)
    k1 = min(max(c - 0.5 * w, 0.01), 9.97)
    k2 = min(max(c + 0.5 * w, k1 + 0.01), 9.99)
    v1 = min(max(vm - 0.5 * dv, 0.0), 10.0)
    v2 = min(max(vm + 0.5 * dv, v1), 10.0)
    return {"input_map.out_at_0_v": min(max(v1 - s_lo * k1, 0.0), v1), "input_map.knot1_in_v": k1,
            "input_map.knot1_out_v": v1, "input_map.knot2_in_v": k2, "input_map.knot2_out_v": v2,
            "input_map.out_at_10_v": min(max(v2 + s_hi * (10.0 - k2), v2), 10.0)}


class _BudgetSpentError(Exception):
    """The input-map fit has run its simulations, or reached the noise."""


def fit_input_map(pr: Problem, base: PlantParams, y_base: np.ndarray) -> FitResult | None:
    """Fit the six ``input_map.*`` parameters on the fit segment's training samples, on top of ``base``.

    Returns None when ``base`` already has an input map or no map lowers the training cost.

    Parameters
    ----------
    pr : Problem
        The recording to explain.
    base : PlantParams
        The model the map is fitted on top of.
    y_base : ndarray
        Its prediction of the whole recording [mm].
    """
    if not base.input_map.is_identity():
        return None  # already in the base model
    n_fit = pr.n_fit
    # on every sensor the fits weigh: an amplifier's map shows in the pressure the command sets
    r0 = pr.stacked_residual(*pr.sim.run(base, stop=n_fit)) if pr.uses_pressure else pr.train_residual(y_base[:n_fit])
    cost_base = sse(r0)
    # Done once the training residual is down to the noise (the smaller of the residual's white-noise
    # level, inflated while the map is still off, and the encoder noise the model states), or to a
    # sliver of the base residual (no held-out fit left to gain): more steps would only cost time.
    sp = base.sensor
    noise = min(pr.noise_mm, math.sqrt(sp.encoder_noise_std_mm ** 2 + sp.encoder_resolution_mm ** 2 / 12.0))
    done_cost = max(r0.size * (_MAP_DONE_RMS * noise) ** 2, _MAP_DONE_SHARE * cost_base)
    seen: list[tuple[float, tuple[float, ...]]] = []
    last: dict[str, np.ndarray] = {}
    jac_at: dict[str, object] = {}

    def train_cost(x: np.ndarray) -> float:
        r = pr.stacked_residual(*pr.sim.run(base.with_values(**_input_map_values(x)), stop=n_fit))
        return sse(r)

    def data(x: np.ndarray) -> np.ndarray:
        if len(seen) >= _MAP_SIMULATIONS - _MAP_SIMPLER or (seen and min(seen)[0] <= done_cost):
            raise _BudgetSpentError
        x = snap(x)  # the solver's steps come out of the BLAS: on the grid, every CPU simulates the same maps
        r = pr.stacked_residual(*pr.sim.run(base.with_values(**_input_map_values(x)), stop=n_fit))
        seen.append((sse(r), tuple(float(v) for v in x)))
        last["x"], last["r"] = np.array(x, float), r
        return r

    # A knot or slope that no training command reaches (or that the clipping holds) leaves the
    # Jacobian singular, and the solver's step along it is then rounding noise (another CPU, another
    # map). Damping rows towards the run's start keep such coordinates where they are; at a tenth of
    # the noise per volt they weigh nothing against the data.
    damping = _MAP_DAMPING * noise
    run: dict[str, np.ndarray] = {}

    def resid(x: np.ndarray) -> np.ndarray:
        return np.concatenate([data(x), damping * (snap(x) - run["x0"])])

    def jac(x: np.ndarray) -> np.ndarray:
        # Each simulation costs as much as the whole search step, so the Jacobian is a Broyden update
        # along the step from where the last one was taken (one simulation), and forward differences
        # (inward at an upper bound; six more) only at a run's start and every _MAP_BROYDEN updates.
        x = snap(x)
        r = last["r"] if "x" in last and np.array_equal(last["x"], x) else data(x)
        if not jac_at or jac_at["age"] >= _MAP_BROYDEN:
            cols = []
            for i, h in enumerate(_MAP_STEP):
                h = h if x[i] + h <= _MAP_HI[i] else -h
                xi = x.copy()
                xi[i] += h
                cols.append((data(xi) - r) / h)
            j, age = np.column_stack(cols), 0
        else:
            j = broyden_update(jac_at["j"], x - jac_at["x"], r - jac_at["r"])
            age = jac_at["age"] + 1
        jac_at.update(x=x, r=r, j=j, age=age)
        return np.vstack([j, damping * np.eye(len(x))])

    # Starts: a 1-V dead band with slope-1 outer parts, its centre over the commanded range and just
    # beyond it. Such a band shifts commands above it down and those below it up, so the same starts
    # serve a gain error about its centre, and one beyond the range is an offset of either sign.
    lo_u, hi_u = (float(v) for v in np.percentile(pr.u_v[:n_fit], [1, 99]))
    centres = np.clip(np.linspace(lo_u - 0.5, hi_u + 0.5, 13), _MAP_LO[0], _MAP_HI[0])
    try:
        for c in centres:
            data(np.array([c, 1.0, c, 0.0, 1.0, 1.0]))
        while True:  # a run may stop on a poor Broyden Jacobian: restart while that gains
            before = min(seen)[0]
            jac_at.clear()
            run["x0"] = np.array(min(seen)[1])
            optimize.least_squares(resid, run["x0"], jac=jac, bounds=(_MAP_LO, _MAP_HI),
                                   method="trf", ftol=_MAP_FTOL, xtol=1e-4, max_nfev=_MAP_SIMULATIONS)
            if min(seen)[0] > (1.0 - _MAP_FTOL) * before:
                break
    except _BudgetSpentError:
        pass
    cost, best = min(seen)
    if cost >= cost_base:
        return None
    # A segment with few commands in it is barely identified and its slope may end anywhere, which
    # would misdescribe the map (a gain error read as three gains, or as a band where no command
    # fell). Prefer the straight line that is closest to the fitted map at the recorded commands, when
    # its training cost stays within the noise's energy of the fit's.
    x = np.array(best)
    u_fit = pr.u_v[:n_fit]
    fitted = InputMapParams(**{k.partition(".")[2]: v for k, v in _input_map_values(x).items()})
    # a least-squares line out of LAPACK: rounded, it is the same line on every CPU
    gain, offset = (snap_relative(v) for v in np.polyfit(u_fit, [input_map_v(float(u), fitted) for u in u_fit], 1))
    k1, k2 = fitted.knot1_in_v, fitted.knot2_in_v
    line = np.clip([0.5 * (k1 + k2), k2 - k1, offset + gain * 0.5 * (k1 + k2), gain * (k2 - k1), gain, gain],
                   _MAP_LO, _MAP_HI)
    if gain > _FLAT_GAIN and train_cost(line) <= (1.0 + _MAP_FTOL) * cost + r0.size * noise ** 2:
        x = line
    values = _input_map_values(x)
    return FitResult(values, full_prediction(pr, base, values))


def explain_input_map(v: dict[str, float]) -> str:
    """Plain words for a fitted input map: a dead band, a gain and offset error, a saturation, or its
    three gains.

    Parameters
    ----------
    v : dict of str to float
        The fitted ``input_map.*`` parameters [V].
    """
    o0, o10 = v["input_map.out_at_0_v"], v["input_map.out_at_10_v"]
    k1, v1 = v["input_map.knot1_in_v"], v["input_map.knot1_out_v"]
    k2, v2 = v["input_map.knot2_in_v"], v["input_map.knot2_out_v"]
    g_lo, g_mid, g_hi = (v1 - o0) / k1, (v2 - v1) / (k2 - k1), (o10 - v2) / (10.0 - k2)
    offset = v1 - g_mid * k1  # of the line through the knots
    if g_mid > _FLAT_GAIN and max(g_lo, g_mid, g_hi) - min(g_lo, g_mid, g_hi) <= _SAME_GAIN:
        # the line through the knots, and the map's own values at the ends, where its outer gains
        # (within _SAME_GAIN of the middle one) can leave it a tenth of a volt off that line
        at_5 = (v1 + (5.0 - k1) * g_mid if k1 <= 5.0 <= k2 else
                o0 + 5.0 * g_lo if 5.0 < k1 else v2 + (5.0 - k2) * g_hi)
        return (f"the valve sees {g_mid:.2f} x the command {offset:+.2f} V (amplifier gain and offset error; "
                f"commands of 0, 5 and 10 V act as {o0:.2f}, {at_5:.2f} and {o10:.2f} V)")
    if g_mid <= _FLAT_GAIN < min(g_lo, g_hi):
        return (f"the valve sees a command dead band {k1:.2f}-{k2:.2f} V (held at {0.5 * (v1 + v2):.2f} V), "
                f"gain {g_lo:.2f} below ({v1 - k1:+.2f} V at the band) / {g_hi:.2f} above "
                f"({v2 - k2:+.2f} V at the band)")
    parts = []
    if g_lo <= _FLAT_GAIN:
        parts.append(f"commands below {k1:.2f} V all act as about {v1:.2f} V")
    if g_hi <= _FLAT_GAIN:
        parts.append(f"the command saturates at about {v2:.2f} V above {k2:.2f} V")
    return ("the valve's command map is distorted: " + "; ".join(parts + [
        f"gain {g_lo:.2f} below {k1:.2f} V, {g_mid:.2f} up to {k2:.2f} V, {g_hi:.2f} above "
        f"({k1:.2f} V acts as {v1:.2f} V, {k2:.2f} V as {v2:.2f} V)"]))
