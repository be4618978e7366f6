"""Expectations on a run's summary metrics: the ``[expect]`` table of a scenario or sweep file.

A scenario (or sweep) file may carry bounds that its runs must meet; ``tapmuscle check`` runs every file
with expectations and fails on any violation (docs/sweeps.md)::

    [expect]
    mae_mm_max = 0.35          # Eq. (21) error must be <= 0.35 mm
    max_abs_error_mm_max = 2.0
    u_within = [0, 10]         # the command stays within 0..10 V (u_min_v >= 0 and u_max_v <= 10)
    real_time_factor_min = 50  # any metric of METRICS, with _max or _min

Keys are ``<metric>_max`` (value <= bound), ``<metric>_min`` (value >= bound) for the metrics of
:data:`METRICS`, and ``u_within = [lo, hi]`` [V]. An unknown key or a bad value raises
:class:`~tapmuscle.cosim.spec.ScenarioError` naming the file and the key. A metric that is not finite (NaN)
violates every bound on it.

This module is pure: it computes the metrics from a run's columns and compares them with bounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from tapmuscle.tracking_metrics import eq21_error_mm

from tapmuscle.cosim.spec import Scenario, ScenarioError

__all__ = ["METRICS", "NEVER_NEGATIVE", "Bound", "Expectations", "Outcome", "parse_expectations", "scenario_metrics",
           "check_expectations"]

#: Summary metrics of one run (name -> meaning, unit in the name).
METRICS: dict[str, str] = {
    "mae_mm": "Eq. (21) error: mean |r - l| over the evaluation window [mm]",
    "rms_error_mm": "root-mean-square of r - l over the evaluation window [mm]",
    "max_abs_error_mm": "largest |r - l| over the evaluation window [mm]",
    "u_min_v": "smallest valve command of the run [V]",
    "u_max_v": "largest valve command of the run [V]",
    "wall_time_s": "wall time of the co-simulation loop [s]",
    "real_time_factor": "simulated time / wall time [-]",
}


#: The metrics no run makes negative: an upper bound below 0 on one of them always fails.
NEVER_NEGATIVE = frozenset({"mae_mm", "rms_error_mm", "max_abs_error_mm", "wall_time_s", "real_time_factor"})


@dataclass(frozen=True)
class Bound:
    """One expectation: ``lo <= metric <= hi`` (either side may be open, None)."""

    metric: str
    """The metric bounded (a key of :data:`METRICS`)."""
    lo: float | None = None
    """Lower bound, in the metric's unit; None: open."""
    hi: float | None = None
    """Upper bound, in the metric's unit; None: open."""
    key: str = ""
    """The ``[expect]`` key it came from (``mae_mm_max``, ``u_within``), for messages."""

    def violation(self, value: float) -> str | None:
        """None if ``value`` meets the bound, else a message such as ``mae_mm = 0.41 > 0.35 (mae_mm_max)``."""
        if not math.isfinite(value):
            return f"{self.metric} = {value!r} is not finite ({self.key})"
        if self.lo is not None and value < self.lo:
            return f"{self.metric} = {value:.6g} < {self.lo:g} ({self.key})"
        if self.hi is not None and value > self.hi:
            return f"{self.metric} = {value:.6g} > {self.hi:g} ({self.key})"
        return None

    def describe(self) -> str:
        """The bound as text, e.g. ``mae_mm <= 0.35``."""
        if self.lo is not None and self.hi is not None:
            return f"{self.lo:g} <= {self.metric} <= {self.hi:g}"
        return f"{self.metric} >= {self.lo:g}" if self.lo is not None else f"{self.metric} <= {self.hi:g}"


@dataclass(frozen=True)
class Expectations:
    """The bounds of one ``[expect]`` table, in file order."""

    bounds: tuple[Bound, ...]
    """The bounds, in file order."""
    source: str = ""
    """The file they came from."""

    def __bool__(self) -> bool:
        return bool(self.bounds)


@dataclass(frozen=True)
class Outcome:
    """The result of checking one run against its expectations."""

    violations: tuple[str, ...]
    """What each bound that was missed says of its value (empty: passed)."""
    checked: tuple[str, ...]
    """Each bound with the value it was checked on, e.g. ``mae_mm = 0.2843 <= 0.35``."""

    @property
    def passed(self) -> bool:
        return not self.violations


def _bound_value(source: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError(f"{source}: key 'expect.{key}': must be a finite number, got {value!r}")
    return float(value)


def parse_expectations(table: Any, *, source: str) -> Expectations:
    """Check an ``[expect]`` table (module docstring); errors name ``source`` and the key.

    Parameters
    ----------
    table : mapping
        The parsed TOML table.
    source : str
        The file, for messages.
    """
    if not isinstance(table, dict):
        raise ScenarioError(f"{source}: key 'expect': must be a table, got {type(table).__name__} {table!r}")
    bounds: list[Bound] = []
    for key, value in table.items():
        if key == "u_within":
            if (not isinstance(value, list) or len(value) != 2):
                raise ScenarioError(f"{source}: key 'expect.u_within': must be [lo, hi] in V, got {value!r}")
            lo, hi = (_bound_value(source, key, v) for v in value)
            if lo > hi:
                raise ScenarioError(f"{source}: key 'expect.u_within': lo {lo:g} > hi {hi:g}")
            bounds += [Bound("u_min_v", lo=lo, key=key), Bound("u_max_v", hi=hi, key=key)]
            continue
        metric, _, side = key.rpartition("_")
        if side not in ("min", "max") or metric not in METRICS:
            raise ScenarioError(f"{source}: key 'expect.{key}': unknown expectation; allowed: u_within, or "
                                f"<metric>_max / <metric>_min with metric one of {', '.join(METRICS)}")
        bound = _bound_value(source, key, value)
        if side == "max" and bound < 0.0 and metric in NEVER_NEGATIVE:
            raise ScenarioError(f"{source}: key 'expect.{key}': {bound:g}: no run can meet it ({metric} is never "
                                "negative)")
        bounds.append(Bound(metric, lo=bound, key=key) if side == "min" else Bound(metric, hi=bound, key=key))
    # a lower bound above an upper one on the same metric (u_within's included) no run can meet
    for low in (b for b in bounds if b.lo is not None):
        for high in (b for b in bounds if b.hi is not None and b.metric == low.metric):
            if low.lo > high.hi:
                raise ScenarioError(f"{source}: keys 'expect.{low.key}' = {low.lo:g} and 'expect.{high.key}' = "
                                    f"{high.hi:g}: no {low.metric} can meet both")
    return Expectations(tuple(bounds), source)


def scenario_metrics(scenario: Scenario, cols: Mapping[str, np.ndarray]) -> dict[str, float]:
    """The :data:`METRICS` of one run.

    Parameters
    ----------
    scenario : Scenario
        The scenario that was run (its ``evaluation_samples`` window, duration).
    cols : mapping of ndarray
        :func:`tapmuscle.cosim.master.co_simulate`'s result: ``r_mm``, ``l_mm`` [mm], ``u_v`` [V] per sample,
        ``wall_time_s`` [s].

    Returns
    -------
    dict
        Metric name -> value (floats; ``real_time_factor`` is inf for a zero wall time).
    """
    k0, k1 = scenario.evaluation_samples
    mae = eq21_error_mm(cols["r_mm"], cols["l_mm"], (k0, k1))  # checks the window
    err = np.asarray(cols["r_mm"], dtype=float)[k0:k1 + 1] - np.asarray(cols["l_mm"], dtype=float)[k0:k1 + 1]
    wall = float(cols["wall_time_s"])
    return {"mae_mm": mae, "rms_error_mm": float(np.sqrt(np.mean(err * err))),
            "max_abs_error_mm": float(np.max(np.abs(err))), "u_min_v": float(np.min(cols["u_v"])),
            "u_max_v": float(np.max(cols["u_v"])), "wall_time_s": wall,
            "real_time_factor": scenario.duration_s / wall if wall > 0 else math.inf}


def check_expectations(expect: Expectations, metrics: Mapping[str, float]) -> Outcome:
    """Compare ``metrics`` (:func:`scenario_metrics`) with every bound of ``expect``.

    Parameters
    ----------
    expect : Expectations
        The bounds to check.
    metrics : mapping of str to float
        The run's metrics (:func:`scenario_metrics`), by name.
    """
    violations, checked = [], []
    for bound in expect.bounds:
        value = float(metrics[bound.metric])
        problem = bound.violation(value)
        if problem is not None:
            violations.append(problem)
        checked.append(f"{bound.describe()}: {value:.6g}")
    return Outcome(tuple(violations), tuple(checked))
