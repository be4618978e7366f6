"""``diagnose``: compare a recording with the plant model, locate the mismatch, name and fit the
left-out physics, and score it on held-out data (issue 6; docs/diagnosis.md has the method).

Procedure
---------
1. Re-simulate the recorded command with the model (:mod:`diagnosis.simulation`), residual
   ``e = l_measured - l_model``.
2. Split the samples into interleaved training and held-out blocks (``block_s``).
3. Is there anything to explain? The residual must fail the whiteness test (Ljung-Box, p < ``alpha``)
   *and* be material (RMS above 1.5 times the noise level: the smaller of the residual's own
   white-noise level and the encoder noise the model states). If not, the verdict is
   ``no_significant_mismatch`` and no cause is named: the difference is noise.
4. Fit every candidate effect on the training blocks (:mod:`diagnosis.candidates`), score each on the
   held-out blocks. The best is accepted when it is significant: it removes at least
   ``min_reduction`` of the held-out squared error, and the held-out residual's projection on the
   effect's contribution, in units of the white-noise level, rejects "only noise" at level ``alpha``
   (a one-sided z-test; the contribution was fitted on other samples, so under "only noise" the
   projection is standard normal).
5. While the residual is still structured and holds more than ``unexplained_share`` of the initial
   excess energy (above noise), try the remaining candidates on top of the accepted ones (greedy
   forward selection, at most ``max_effects``).
6. If a structured, material residual remains, add the finding ``unexplained`` with where and in which
   regime it lives.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from scipy import stats

from fmu_plant import PlantParams

from .candidates import CANDIDATES, Candidate, FitResult, Problem
from .residual_analysis import (Correlation, autocorrelation_test, cross_correlation_test, fit_percent,
                                interleaved_split, is_structured, located_windows, regime_summary,
                                white_noise_level_mm)
from .simulation import Simulator

__all__ = ["Finding", "Diagnosis", "diagnose", "sensor_noise_mm", "MIN_SAMPLES"]

#: Fewest samples a recording must have (the tests need ~10x their 25 lags per part).
MIN_SAMPLES = 300


@dataclass
class Finding:
    """One entry of ``diagnosis.json``'s ``findings``."""

    effect: str
    """Candidate name, or ``"unexplained"``."""
    explanation: str
    parameters: dict[str, float]
    """Fitted plant parameters (``group.field``: value, as the plant FMU names them)."""
    fit_gain_points: float
    """Held-out fit gained by adding this effect [percentage points]."""
    located: list[tuple[float, float]]
    """Time windows [s] where it acts."""
    regime: str
    evidence: dict[str, Any] = field(default_factory=dict)
    """Numbers behind the acceptance (held-out SSE before/after, F-test p-value, ...)."""

    def to_json(self) -> dict[str, Any]:
        return {"effect": self.effect, "explanation": self.explanation, "parameters": self.parameters,
                "fit_gain_points": round(self.fit_gain_points, 3),
                "located": [{"t_start_s": round(a, 2), "t_end_s": round(b, 2)} for a, b in self.located],
                "regime": self.regime, "evidence": self.evidence}


@dataclass
class Diagnosis:
    """Everything ``diagnose`` found (``to_json`` is ``diagnosis.json``)."""

    verdict: str
    fit_before_percent: float
    fit_after_percent: float
    findings: list[Finding]
    calibrated: PlantParams
    """The model with the accepted effects' parameters."""
    t_s: np.ndarray
    u_v: np.ndarray
    y_mm: np.ndarray
    y_before_mm: np.ndarray
    y_after_mm: np.ndarray
    train: np.ndarray
    test: np.ndarray
    tests_before: dict[str, Any]
    tests_after: dict[str, Any]
    correlations: dict[str, Correlation]
    candidates: list[dict[str, Any]]
    """Every candidate tried, per round: name, held-out gain, SSE reduction, significance."""
    simulations: int
    elapsed_s: float

    def to_json(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "fit_before_percent": round(self.fit_before_percent, 3),
                "fit_after_percent": round(self.fit_after_percent, 3),
                "findings": [f.to_json() for f in self.findings],
                "residual_tests": {"before": self.tests_before, "after": self.tests_after},
                "candidates_tried": self.candidates,
                "split": {"method": "interleaved blocks", "train_samples": int(self.train.sum()),
                          "held_out_samples": int(self.test.sum())},
                "simulations": self.simulations, "elapsed_s": round(self.elapsed_s, 2)}


def sensor_noise_mm(model: PlantParams) -> float:
    """The encoder noise the model states [mm]: white noise and 0.01 mm quantisation, sqrt(s^2 + q^2/12)."""
    sp = model.sensor
    return math.sqrt(sp.encoder_noise_std_mm ** 2 + sp.encoder_resolution_mm ** 2 / 12.0)


def _residual_tests(u: np.ndarray, e: np.ndarray, sensor_mm: float) -> tuple[dict[str, Any], Correlation, Correlation]:
    structured, numbers = is_structured(e, sensor_noise_mm=sensor_mm)
    ac = autocorrelation_test(e)
    xc = cross_correlation_test(u, e)
    numbers.update({"structured": structured, "whiteness_p": ac.p_value, "autocorrelation_lags_outside": ac.outside,
                    "cross_correlation_p": xc.p_value, "cross_correlation_lags_outside": xc.outside,
                    "band_99": ac.band})
    return numbers, ac, xc


def _significance(e0: np.ndarray, e1: np.ndarray, noise_mm: float, alpha: float) -> dict[str, float]:
    """Is the held-out improvement ``e0 -> e1`` more than noise could give?

    With the effect's contribution ``d = e0 - e1`` (fitted on other samples), ``e0 . d / (sigma |d|)``
    is the residual's projection on the contribution in units of the white-noise level ``sigma``: a
    standard normal if the held-out residual were only noise. One-sided p-value.
    """
    sse0, sse1 = float(e0 @ e0), float(e1 @ e1)
    d = e0 - e1
    nd = float(np.linalg.norm(d))
    z = float(e0 @ d) / (noise_mm * nd) if nd > 0 and noise_mm > 0 else (math.inf if nd > 0 else 0.0)
    return {"sse_before_mm2": sse0, "sse_after_mm2": sse1, "reduction": 1.0 - sse1 / sse0 if sse0 > 0 else 0.0,
            "z": z, "p_value": float(stats.norm.sf(z)), "significant_at": alpha}


def diagnose(t_s: np.ndarray, u_v: np.ndarray, l_mm: np.ndarray, model: PlantParams, *,
             load_n: np.ndarray | None = None, p_mpa: np.ndarray | None = None, block_s: float = 10.0,
             fit_segment_s: float = 120.0, candidates: Sequence[Candidate] = CANDIDATES, max_effects: int = 3,
             alpha: float = 1e-3, min_reduction: float = 0.10, unexplained_share: float = 0.25,
             progress: Callable[[int, int], None] | None = None) -> Diagnosis:
    """Diagnose the mismatch between a recording and the plant model (module docstring).

    Parameters
    ----------
    t_s, u_v, l_mm : ndarray
        The recording: uniformly sampled times [s], command [V], encoder displacement [mm].
    model : PlantParams
        The calibrated plant (e.g. read from the MusclePlant FMU's parameters).
    load_n, p_mpa : ndarray, optional
        Recorded load [N] (re-simulated as recorded) and pressure [MPa] (for the regime breakdown).
    block_s : float
        Length of the interleaved training / held-out blocks [s].
    fit_segment_s : float
        Stationary effects are fitted on the first this many seconds.
    candidates : sequence of Candidate
        Effects to try (default: all of :data:`CANDIDATES`).
    max_effects : int
        Most effects combined.
    alpha, min_reduction, unexplained_share : float
        Significance level; least held-out SSE reduction of an accepted effect; residual excess share
        above which what is left is reported as ``unexplained`` (module docstring).

    Raises
    ------
    ValueError
        Arrays of different lengths, fewer than :data:`MIN_SAMPLES` samples, non-uniform sampling
        (naming the first offending sample), non-finite values, or a command that never changes.
    """
    started = time.perf_counter()
    t = np.asarray(t_s, float)
    u = np.asarray(u_v, float)
    y = np.asarray(l_mm, float)
    for name, arr in (("u_v", u), ("l_mm", y)) + ((("load_n", load_n),) if load_n is not None else ()):
        if len(arr) != len(t):
            raise ValueError(f"column {name} has {len(arr)} samples, t_s has {len(t)}")
    if len(t) < MIN_SAMPLES:
        raise ValueError(f"the recording has {len(t)} samples; the diagnosis needs at least {MIN_SAMPLES}")
    for name, arr in (("t_s", t), ("u_v", u), ("l_mm", y)):
        bad = np.nonzero(~np.isfinite(arr))[0]
        if bad.size:
            raise ValueError(f"column {name}, sample {int(bad[0])}: {arr[bad[0]]!r} is not finite")
    dt = np.diff(t)
    ts = float(np.median(dt))
    off = np.nonzero(np.abs(dt - ts) > 1e-3 * ts)[0]
    if ts <= 0 or off.size:
        k = int(off[0]) + 1 if off.size else 1
        raise ValueError(f"column t_s, sample {k}: t = {t[k]!r} s breaks the uniform sampling of {ts:g} s "
                         f"(previous sample {t[k - 1]!r} s); resample the recording first")
    if float(np.ptp(u)) == 0.0:
        raise ValueError(f"column u_v: the command is constant ({u[0]:g} V); nothing excites the plant")

    n = len(t)
    sim = Simulator(u, ts, None if load_n is None else np.asarray(load_n, float))
    y0 = sim.run(model, checkpoint_every=max(1, int(round(10.0 / ts))))[0]
    train, test = interleaved_split(n, ts, block_s)
    e0 = y - y0
    noise = white_noise_level_mm(e0)
    problem = Problem(y, t, u, ts, train, test, sim, noise, fit_segment_s, block_s)
    sensor_mm = sensor_noise_mm(model)
    tests0, ac0, xc0 = _residual_tests(u, e0, sensor_mm)
    floor = tests0["noise_reference_mm"]
    fit_before = fit_percent(y, y0, test)
    excess0 = max(tests0["rms_mm"] ** 2 - floor ** 2, 1e-30)

    base, y_base = model, y0
    findings: list[Finding] = []
    tried: list[dict[str, Any]] = []
    if tests0["structured"]:
        pool = list(candidates)
        total = len(pool)
        done = 0
        for round_no in range(1, max_effects + 1):
            if not pool:
                break
            results: list[tuple[Candidate, FitResult, dict[str, float]]] = []
            e_base_test = (y - y_base)[test]
            fit_base = fit_percent(y, y_base, test)
            for cand in pool:
                res = cand.fit(problem, base, y_base)
                done += 1
                if progress is not None:
                    progress(min(done, total), max(total, done))
                if res is None:
                    tried.append({"round": round_no, "effect": cand.name, "fitted": False})
                    continue
                sig = _significance(e_base_test, (y - res.y_hat)[test], noise, alpha)
                gain = fit_percent(y, res.y_hat, test) - fit_base
                tried.append({"round": round_no, "effect": cand.name, "fitted": True,
                              "fit_gain_points": round(gain, 3), "held_out_sse_reduction": round(sig["reduction"], 4),
                              "p_value": sig["p_value"], "parameters": res.values})
                results.append((cand, res, sig | {"fit_gain_points": gain}))
            if not results:
                break
            results.sort(key=lambda r: r[2]["sse_after_mm2"])
            cand, res, sig = results[0]
            if not (sig["reduction"] >= min_reduction and sig["p_value"] < alpha):
                break
            contribution = res.y_hat - y_base
            located = res.located or located_windows(contribution, ts, noise_mm=noise)
            regime, _ = regime_summary(contribution ** 2, y, ts, p_mpa, signal=contribution)
            findings.append(Finding(cand.name, cand.explain(res.values), res.values, sig["fit_gain_points"],
                                    located, regime, {k: v for k, v in sig.items() if k != "fit_gain_points"}))
            base = base.with_values(**res.values)
            y_base = res.y_hat
            e = y - y_base
            structured, numbers = is_structured(e, sensor_noise_mm=sensor_mm)
            if not structured or (numbers["rms_mm"] ** 2 - floor ** 2) / excess0 < unexplained_share:
                break
            # next round: the other candidates that helped at all on their own
            helpful = {c.name for c, _, s in results[1:] if s["reduction"] > 0.02}
            pool = [c for c in pool if c.name in helpful]
            total = done + len(pool)

    e_after = y - y_base
    tests1, ac1, xc1 = _residual_tests(u, e_after, sensor_mm)
    excess1 = tests1["rms_mm"] ** 2 - floor ** 2
    verdict = "mismatch" if tests0["structured"] else "no_significant_mismatch"
    if tests0["structured"] and tests1["structured"] and excess1 / excess0 >= unexplained_share:
        located = located_windows(e_after, ts, noise_mm=noise)
        regime, _ = regime_summary(e_after ** 2, y, ts, p_mpa, signal=e_after)
        share = 100.0 * excess1 / excess0
        findings.append(Finding(
            "unexplained",
            f"a structured residual remains (whiteness p = {tests1['whiteness_p']:.1e}, RMS "
            f"{tests1['rms_mm']:.3f} mm against {noise:.3f} mm of noise, {share:.0f} % of the initial "
            f"excess) that none of the candidate effects explains",
            {}, 0.0, located, regime, {"remaining_excess_share": excess1 / excess0}))
    return Diagnosis(verdict, fit_before, fit_percent(y, y_base, test), findings, base, t, u, y, y0, y_base,
                     train, test, tests0, tests1, {"autocorrelation_before": ac0, "cross_correlation_before": xc0,
                                                   "autocorrelation_after": ac1, "cross_correlation_after": xc1},
                     tried, sim.runs, time.perf_counter() - started)
