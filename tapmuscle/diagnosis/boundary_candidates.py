"""The candidate effects of a foreign plant FMU: physics the master adds at the FMU's boundary.

For every recorded input ``v``: ``transport_delay[v]`` (any fraction of a sample), ``input_map[v]``
(a static, monotone piecewise-linear characteristic: dead band anywhere, gain or offset error,
saturation), ``input_backlash[v]`` (play). For every FMU input the recording has no column for:
``secondary_input[v]`` (the input, held at its start value otherwise, changed by a constant over a
window: a supply pressure that sagged, an ambient that warmed). For the measured output ``y``:
``output_drift[y]`` (offset and linear drift) and ``output_gain[y]`` (a sensor gain error). The
transforms are :mod:`tapmuscle.diagnosis.boundary_effects`; the search that selects among them,
after calibrating the FMU's own parameters, is the tapmuscle plant's
(:func:`tapmuscle.diagnosis.diagnose.diagnose_with`), told about this model family by
:class:`BoundarySpace`.

Fitting (each simulation runs the first ``fit_segment_s`` seconds, except the window's):

* delay and play: a grid, then a bounded scalar search (Brent) around the best grid point;
* input map: dead bands of a tenth of the range at seven centres and the identity as starts, then
  bounded least squares on the map's six coordinates (trust-region reflective, forward-difference
  Jacobian, Broyden updates), each a monotone map by construction;
* secondary input: the window where the residual is located (at three levels of its moving RMS),
  a scan of changes of either sign, then Nelder-Mead on change, start and end over the whole run;
* output drift and gain: linear least squares on the base prediction (the sensor does not feed
  back), no simulation.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Iterable

import numpy as np
from scipy import optimize

from tapmuscle.diagnosis.boundary_effects import (MAP_FIELDS, dead_band_map, identity_map, input_defaults,
                                                  map_knots, output_defaults, secondary_defaults)
from tapmuscle.diagnosis.calibration import FittedParameter, NominalParameter, fit_parameters
from tapmuscle.diagnosis.candidates import Candidate, ParameterSpec, bounded_nelder_mead
from tapmuscle.diagnosis.fit_problem import FitResult, Problem
from tapmuscle.diagnosis.foreign_model import FmuInterface, ForeignSimulator, ModelValues
from tapmuscle.diagnosis.model_space import ModelSpace
from tapmuscle.diagnosis.residual_analysis import located_windows
from tapmuscle.diagnosis.reproducible import dot, snap_relative, sse

__all__ = ["BoundarySpace", "boundary_candidates", "calibration_parameters", "nominal_values", "effect_kind",
           "map_bounds", "DELAY_MAX_SAMPLES", "GAIN_BOUNDS"]

#: Longest transport delay searched, in samples.
DELAY_MAX_SAMPLES = 20
#: Levels of the residual's moving RMS (fractions of its maximum) at which a secondary input's window is sought.
WINDOW_LEVELS = (0.3, 0.5, 0.7)


#: Bounds of a sensor gain [-].
GAIN_BOUNDS = (0.2, 5.0)


def map_bounds(lo: float, hi: float) -> tuple[tuple[float, float], ...]:
    """Bounds of the map's coordinates (``MAP_FIELDS`` order) on the input range ``[lo, hi]``: knots
    within the range, outputs within a span beyond it, rises up to twice the span.

    Parameters
    ----------
    lo, hi : float
        The input's range, in its unit.
    """
    span = hi - lo
    return ((lo, hi), (0.0, span), (lo - span, hi + span), (0.0, 2.0 * span), (0.0, 2.0 * span), (0.0, 2.0 * span))


def effect_kind(name: str) -> tuple[str, str]:
    """``("transport_delay", "V")`` of ``"transport_delay[V]"``.

    Parameters
    ----------
    name : str
        An effect's name, ``"<kind>[<variable>]"``.
    """
    kind, _, rest = name.partition("[")
    return kind, rest.rstrip("]")


# ------------------------------------------------------------------------------------ the space
class BoundarySpace(ModelSpace):
    """Bounds, "off" values and jointly re-fitted parameters of a foreign FMU with boundary effects.

    A foreign FMU's parameters are whatever its author exposed, often redundant for one output (a
    motor's ``R, K, J, b`` reach its speed in three combinations): the calibration keeps every MAP
    estimate (``combinations``), so that the combinations the recording pins are calibrated.

    Parameters
    ----------
    sim : ForeignSimulator
        The recording's simulator: the FMU's interface, the recorded inputs and their ranges, the
        output and the recording's times.
    """

    combinations = True

    def __init__(self, sim: ForeignSimulator) -> None:
        iface = sim.interface
        t0, t1 = float(sim.t_s[0]), float(sim.t_s[-1])
        self._bounds: dict[str, tuple[float, float]] = {p.name: (p.lo, p.hi) for p in iface.parameters}
        self._off: dict[str, float] = {}
        self.joint_parameters = {}
        for v in iface.inputs:
            if v.name in sim.inputs:
                lo, hi = sim.input_ranges[v.name]
                span = hi - lo
                self._off |= input_defaults(v.name, lo, hi)
                self._bounds |= {f"{v.name}:delay_s": (0.0, DELAY_MAX_SAMPLES * sim.ts_s),
                                 f"{v.name}:backlash": (0.0, 0.5 * span)}
                self._bounds |= {f"{v.name}:{k}": b for k, b in zip(MAP_FIELDS, map_bounds(lo, hi))}
                # the smooth boundary parameters are re-fitted jointly with the calibrated constants (a
                # map's coordinates and a play move the prediction continuously)
                self.joint_parameters[f"transport_delay[{v.name}]"] = ((f"{v.name}:delay_s", 0.2 * sim.ts_s),)
                self.joint_parameters[f"input_map[{v.name}]"] = tuple((f"{v.name}:{k}", 0.05 * span) for k in MAP_FIELDS)
                self.joint_parameters[f"input_backlash[{v.name}]"] = ((f"{v.name}:backlash", 0.02 * span),)
            else:
                scale = _scale(v.start)
                self._off |= secondary_defaults(v.name)
                self._bounds |= {f"{v.name}:change": (-math.inf, math.inf),
                                 f"{v.name}:start_s": (t0, t1), f"{v.name}:end_s": (t0, t1)}
                self.joint_parameters[f"secondary_input[{v.name}]"] = ((f"{v.name}:change", 0.02 * scale),)
        self._off |= output_defaults(sim.output)
        self._bounds |= {f"{sim.output}:gain": GAIN_BOUNDS, f"{sim.output}:offset": (-math.inf, math.inf),
                         f"{sim.output}:drift_per_min": (-math.inf, math.inf)}

    def bounds(self, key: str) -> tuple[float, float]:
        return self._bounds.get(key, (-math.inf, math.inf))

    def off_values(self, keys: Iterable[str]) -> dict[str, float]:
        return {k: self._off[k] for k in keys}

    def defaults(self) -> dict[str, float]:
        """Every boundary parameter at its "off" value."""
        return dict(self._off)


def _scale(start: float | None) -> float:
    """The magnitude of an input's changes: its start value's, or 1 for a start at 0."""
    return abs(start) if start else 1.0


def nominal_values(sim: ForeignSimulator, space: BoundarySpace) -> ModelValues:
    """The nominal parameter set: the FMU's start values (except those the map fixes), no effect.

    Parameters
    ----------
    sim : ForeignSimulator
        The recording's simulator (the FMU's parameters and the map's fixed ones).
    space : BoundarySpace
        The model space, whose defaults switch every boundary effect off.
    """
    own = {p.name: p.start for p in sim.interface.parameters if p.start is not None and p.name not in sim.fixed}
    return ModelValues(own | space.defaults())


def calibration_parameters(iface: FmuInterface, fixed: Iterable[str] = (), only: Iterable[str] | None = None
                           ) -> list[NominalParameter]:
    """The FMU's Real parameters the calibration may re-estimate: finite, non-zero start values (a
    relative prior needs a scale), not fixed by the map; ``only``: just these names.

    Parameters
    ----------
    iface : FmuInterface
        The FMU.
    fixed : iterable of str, optional
        Parameters the map fixes (left out).
    only : iterable of str, optional
        Just these parameters (the map's ``[calibrate]``); None (default): every one that
        qualifies.
    """
    fixed = set(fixed)
    keep = None if only is None else set(only)
    return [NominalParameter(p.name, p.unit or "-") for p in iface.parameters
            if p.start is not None and math.isfinite(p.start) and p.start != 0.0 and p.name not in fixed
            and (keep is None or p.name in keep)]


# ------------------------------------------------------------------------------------- fitters
def _cost(pr: Problem, params: ModelValues) -> float:
    r = pr.fit_residual(params)
    return sse(r)


def _scalar_search(pr: Problem, base: ModelValues, key: str, grid: np.ndarray, xatol: float) -> float:
    """The value of ``key`` in ``grid``'s range with the least training cost: grid, then Brent between
    the best point's neighbours."""
    costs = [_cost(pr, base.with_values(**{key: float(g)})) for g in grid]
    i = int(np.argmin(costs))
    a, b = float(grid[max(i - 1, 0)]), float(grid[min(i + 1, len(grid) - 1)])
    if b - a <= xatol:
        return float(grid[i])
    res = optimize.minimize_scalar(lambda x: _cost(pr, base.with_values(**{key: float(x)})), bounds=(a, b),
                                   method="bounded", options={"xatol": xatol, "maxiter": 10})
    return float(res.x) if res.fun < costs[i] else float(grid[i])


def _fit_delay(pr: Problem, base: ModelValues, y_base: np.ndarray, *, var: str) -> FitResult | None:
    key = f"{var}:delay_s"
    if base.value(key) > 0.0:
        return None
    ts = pr.ts_s
    grid = ts * np.array([0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 12.0, DELAY_MAX_SAMPLES])
    d = _scalar_search(pr, base, key, grid, 0.01 * ts)
    if d <= 0.0:
        return None
    values = {key: d}
    return FitResult(values, pr.sim.run(base.with_values(**values))[0])


def _fit_backlash(pr: Problem, base: ModelValues, y_base: np.ndarray, *, var: str) -> FitResult | None:
    key = f"{var}:backlash"
    if base.value(key) > 0.0:
        return None
    lo, hi = pr.sim.input_ranges[var]
    span = hi - lo
    grid = span * np.array([0.0, 0.005, 0.01, 0.02, 0.04, 0.07, 0.11, 0.16, 0.25])
    w = _scalar_search(pr, base, key, grid, 1e-3 * span)
    if w <= 0.0:
        return None
    values = {key: w}
    return FitResult(values, pr.sim.run(base.with_values(**values))[0])


def _fit_input_map(pr: Problem, base: ModelValues, y_base: np.ndarray, *, var: str) -> FitResult | None:
    lo, hi = pr.sim.input_ranges[var]
    keys = [f"{var}:{k}" for k in MAP_FIELDS]
    if {k: base.value(f"{var}:{k}") for k in MAP_FIELDS} != identity_map(lo, hi):
        return None
    span = hi - lo
    starts = [identity_map(lo, hi)] + [dead_band_map(c, 0.1 * span, lo, hi)
                                       for c in np.linspace(lo + 0.1 * span, hi - 0.1 * span, 7)]
    costs = [_cost(pr, base.with_values(**{f"{var}:{k}": v for k, v in s.items()})) for s in starts[1:]]
    r0 = pr.train_residual(y_base[:pr.n_fit])
    costs = [sse(r0)] + costs
    best = starts[int(np.argmin(costs))]
    if best is starts[0]:  # from the identity: a small dead band in the middle gives the knots room to move
        best = dead_band_map(0.5 * (lo + hi), 0.02 * span, lo, hi)
    start = base.with_values(**{f"{var}:{k}": v for k, v in best.items()})
    coords = [FittedParameter(k, 0.0, 0.05 * span, False, *b) for k, b in zip(keys, map_bounds(lo, hi))]
    fit = fit_parameters(pr.fit_residual, start, coords, max(pr.noise_mm, 1e-12), max_iterations=30)
    values = {k: fit.values[k] for k in keys}
    if sse(fit.residual) >= sse(r0):
        return None
    return FitResult(values, pr.sim.run(base.with_values(**values))[0])


def _fit_secondary(pr: Problem, base: ModelValues, y_base: np.ndarray, *, var: str) -> FitResult | None:
    kc, ka, kb = f"{var}:change", f"{var}:start_s", f"{var}:end_s"
    if base.value(kc) != 0.0:
        return None
    e = pr.y_mm - y_base
    t0, t1 = float(pr.t_s[0]), float(pr.t_s[-1])
    duration = t1 - t0
    # Where: the windows the residual locates (which a slow plant shifts late), and a coarse grid of
    # windows over the run. How much: the plant is nearly linear in a small change, so each window's
    # best change is the least-squares multiple of its response to a unit change (two simulations).
    windows = []
    for level in WINDOW_LEVELS:
        wins = located_windows(e, pr.ts_s, noise_mm=pr.noise_mm, relative=level)
        windows += [(a + t0, b + t0) for a, b in wins]
    windows += [(t0 + f * duration, min(t1, t0 + (f + g) * duration)) for g in (0.1, 0.25, 0.5)
                for f in np.arange(0.0, 1.0 - g / 2, g / 2)]
    unit = _scale(pr.sim.interface.variable(var).start)

    def params(x: np.ndarray) -> ModelValues:
        return base.with_values(**{kc: float(x[0]), ka: float(x[1]), kb: float(max(x[1], x[2]))})

    def cost(x: np.ndarray) -> float:
        r = pr.train_residual(pr.sim.run(params(x))[0])
        return sse(r)
    best = None
    et = e[pr.train]
    for a, b in dict.fromkeys(windows):
        resp = (pr.sim.run(params(np.array([unit, a, b])))[0] - y_base)[pr.train] / unit
        den = sse(resp)
        if den == 0.0:
            continue
        c = dot(resp, et) / den
        r = et - c * resp
        if best is None or sse(r) < best[0]:
            best = (sse(r), c, a, b)
    if best is None or best[1] == 0.0:
        return None
    _, c0, a0, b0 = best
    step = max(pr.block_s / 4.0, 3.0 * pr.ts_s)
    x = bounded_nelder_mead(cost, np.array([c0, a0, b0]), np.array([0.2 * c0, step, step]),
                     np.array([-math.inf, t0, t0]), np.array([math.inf, t1, t1]), max_evals=40)
    p = params(x)
    if p.value(kc) == 0.0 or p.value(kb) <= p.value(ka):
        return None
    values = {kc: p.value(kc), ka: p.value(ka), kb: p.value(kb)}
    return FitResult(values, pr.sim.run(p)[0], located=[(values[ka] - t0, values[kb] - t0)])


def _fit_output_drift(pr: Problem, base: ModelValues, y_base: np.ndarray, *, var: str) -> FitResult | None:
    t = pr.t_s - pr.t_s[0]
    e = pr.y_mm - y_base
    a = np.column_stack([np.ones(pr.n), t])[pr.train]
    (offset, rate), *_ = np.linalg.lstsq(a, e[pr.train], rcond=None)
    offset, rate = snap_relative(offset), snap_relative(rate)  # least squares in the BLAS: rounded alike on every CPU
    values = {f"{var}:offset": base.value(f"{var}:offset") + offset,
              f"{var}:drift_per_min": base.value(f"{var}:drift_per_min") + rate * 60.0}
    return FitResult(values, y_base + offset + rate * t)


def _fit_output_gain(pr: Problem, base: ModelValues, y_base: np.ndarray, *, var: str) -> FitResult | None:
    if base.value(f"{var}:gain") != 1.0:
        return None
    t = pr.t_s - pr.t_s[0]
    raw = y_base - base.value(f"{var}:offset") - base.value(f"{var}:drift_per_min") / 60.0 * t
    e = pr.y_mm - y_base
    den = sse(raw[pr.train])
    if den == 0.0:
        return None
    a = dot(raw[pr.train], e[pr.train]) / den
    g = min(max(1.0 + a, GAIN_BOUNDS[0]), GAIN_BOUNDS[1])
    return FitResult({f"{var}:gain": g}, y_base + (g - 1.0) * raw)


# ------------------------------------------------------------------------------------ catalogue
def _explain_delay(v: dict[str, float], *, var: str) -> str:
    return f"input {var} acts {1000 * v[f'{var}:delay_s']:.0f} ms after it is recorded"


def _explain_map(v: dict[str, float], *, var: str, lo: float, hi: float) -> str:
    xs, ys = map_knots({k: v[f"{var}:{k}"] for k in MAP_FIELDS}, lo, hi)
    knots = ", ".join(f"{x:.3g} -> {y:.3g}" for x, y in zip(xs, ys))
    return f"input {var} reaches the plant through a static characteristic (recorded -> effective: {knots})"


def _explain_backlash(v: dict[str, float], *, var: str, unit: str) -> str:
    return f"input {var} acts through {v[f'{var}:backlash']:.3g} {unit} of play"


def _secondary_edges(v: dict[str, float], *, var: str) -> list[tuple[float, float]]:
    """The change's start and end [s], as fitted (steps: each an instant)."""
    return [(v[f"{var}:start_s"],) * 2, (v[f"{var}:end_s"],) * 2]


def _explain_secondary(v: dict[str, float], *, var: str, unit: str) -> str:
    return (f"input {var} (not recorded, held at its start value) changed by {v[f'{var}:change']:+.3g} {unit} from "
            f"{v[f'{var}:start_s']:.1f} s to {v[f'{var}:end_s']:.1f} s")


def _explain_drift(v: dict[str, float], *, var: str, unit: str) -> str:
    return (f"the sensor of {var} reads {v[f'{var}:offset']:+.4g} {unit} off at the start, drifting "
            f"{v[f'{var}:drift_per_min']:+.4g} {unit}/min")


def _explain_gain(v: dict[str, float], *, var: str) -> str:
    return f"the sensor of {var} reads {v[f'{var}:gain']:.4g} times the value"


def boundary_candidates(sim: ForeignSimulator) -> list[Candidate]:
    """The candidates for ``sim``'s FMU and recording (module docstring), in a fixed order.

    Parameters
    ----------
    sim : ForeignSimulator
        The recording's simulator (the FMU's inputs and output, which inputs are recorded and
        their ranges).
    """
    out: list[Candidate] = []
    iface = sim.interface
    for v in iface.inputs:
        unit = v.unit or sim.units.get(v.name) or "(unit)"  # the FMU's, else the recording's
        if v.name in sim.inputs:
            lo, hi = sim.input_ranges[v.name]
            out += [
                Candidate(f"transport_delay[{v.name}]", f"Input {v.name} reaches the plant late (bus or "
                          "actuator latency), by any time, not only whole samples.",
                          (ParameterSpec(f"{v.name}:delay_s", "s", 0.0, DELAY_MAX_SAMPLES * sim.ts_s),),
                          "Grid then bounded scalar search on the delay (fractional: the step's mean input).",
                          partial(_fit_delay, var=v.name), partial(_explain_delay, var=v.name)),
                Candidate(f"input_map[{v.name}]", f"The actuator's static characteristic for {v.name} differs "
                          "from the model's: a dead band anywhere, a gain or offset error, a saturation (a "
                          "monotone piecewise-linear map of the input).",
                          tuple(ParameterSpec(f"{v.name}:{k}", unit, *b) for k, b in zip(MAP_FIELDS, map_bounds(lo, hi))),
                          "Dead-band and identity starts, then bounded least squares on the map's six coordinates.",
                          partial(_fit_input_map, var=v.name), partial(_explain_map, var=v.name, lo=lo, hi=hi)),
                Candidate(f"input_backlash[{v.name}]", f"Play between the recorded {v.name} and what the plant "
                          "receives: after each reversal the input moves through the play first.",
                          (ParameterSpec(f"{v.name}:backlash", unit, 0.0, 0.5 * (hi - lo)),),
                          "Grid then bounded scalar search on the play's width.",
                          partial(_fit_backlash, var=v.name), partial(_explain_backlash, var=v.name, unit=unit)),
            ]
        else:
            out.append(Candidate(
                f"secondary_input[{v.name}]", f"Input {v.name} has no column in the recording and is held at "
                "its start value; it changed for a while (a supply that sagged, an ambient that warmed).",
                (ParameterSpec(f"{v.name}:change", unit, -math.inf, math.inf),
                 ParameterSpec(f"{v.name}:start_s", "s", float(sim.t_s[0]), float(sim.t_s[-1])),
                 ParameterSpec(f"{v.name}:end_s", "s", float(sim.t_s[0]), float(sim.t_s[-1]))),
                "Window from the residual's location, a scan of changes, then Nelder-Mead on change, start and end.",
                partial(_fit_secondary, var=v.name), partial(_explain_secondary, var=v.name, unit=unit),
                edges=partial(_secondary_edges, var=v.name)))
    y = sim.output
    unit = iface.variable(y).unit or sim.units.get(y) or "(unit)"
    out += [
        Candidate(f"output_drift[{y}]", f"The sensor of {y} is offset and drifts: the reading is the value plus a "
                  "slowly changing offset, whatever the plant does.",
                  (ParameterSpec(f"{y}:offset", unit, -math.inf, math.inf),
                   ParameterSpec(f"{y}:drift_per_min", f"{unit}/min", -math.inf, math.inf)),
                  "Linear least squares of the residual on (1, t); no simulation.",
                  partial(_fit_output_drift, var=y), partial(_explain_drift, var=y, unit=unit)),
        Candidate(f"output_gain[{y}]", f"The sensor of {y} has a gain error: the reading is a constant multiple of "
                  "the value.",
                  (ParameterSpec(f"{y}:gain", "-", *GAIN_BOUNDS),),
                  "Linear least squares of the residual on the prediction; no simulation.",
                  partial(_fit_output_gain, var=y), partial(_explain_gain, var=y)),
    ]
    return out
