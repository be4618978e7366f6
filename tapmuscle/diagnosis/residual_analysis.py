"""Residual analysis: fit, whiteness and input cross-correlation tests (as MATLAB's ``resid``), where
in time and in which operating regime the residual lives.

All functions are pure: arrays in, numbers out. ``e`` is always ``measured - simulated`` [mm].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from tapmuscle.diagnosis.recording_checks import PRESSURE_PLAUSIBLE_MPA
from tapmuscle.diagnosis.reproducible import dot, moving_sum, norm, sse

__all__ = ["STRUCTURE_ALPHA", "STRUCTURE_MATERIALITY",
           "block_index", "fit_percent", "white_noise_level_mm", "Correlation", "autocorrelation_test",
           "cross_correlation_test", "is_structured", "unstructured_reason", "mean_test", "located_windows", "regime_summary",
           "interleaved_split", "iou", "dominant_frequency_hz"]

#: Lags of the whiteness and cross-correlation tests (MATLAB's resid default is 25).
MAX_LAG = 25
#: Confidence level of the bands and of the structure test.
CONFIDENCE = 0.99


def fit_percent(y: np.ndarray, y_hat: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Normalised-RMSE fit ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` [%] (MATLAB ``compare``).

    Parameters
    ----------
    y : ndarray
        Measured output.
    y_hat : ndarray
        Predicted output, same unit.
    mask : ndarray of bool, optional
        The samples scored; None (default): all.
    """
    if mask is not None:
        y, y_hat = y[mask], y_hat[mask]
    den = norm(y - np.mean(y))
    return 100.0 * (1.0 - norm(y - y_hat) / den) if den > 0 else float("nan")


def white_noise_level_mm(e: np.ndarray) -> float:
    """Standard deviation of the white part of ``e`` [mm], from its first differences.

    A smooth mismatch barely changes from one sample to the next, white noise doubles its variance
    in a difference, so ``MAD(diff e) / (0.6745 sqrt 2)`` estimates the noise level whatever the
    mismatch (robust to the few samples where a mismatch jumps).

    Parameters
    ----------
    e : ndarray
        The residual [mm].
    """
    d = np.diff(e)
    mad = float(np.median(np.abs(d - np.median(d))))
    sigma = mad / (0.6745 * math.sqrt(2.0))
    if sigma == 0.0:  # quantised, mostly identical readings: fall back to the plain std of differences
        sigma = float(np.std(d)) / math.sqrt(2.0)
    return sigma


@dataclass(frozen=True)
class Correlation:
    """A normalised correlation function with its confidence band (MATLAB ``resid``)."""

    lags: np.ndarray
    """The lags [samples]."""
    values: np.ndarray
    """The normalised correlation at each lag [-]."""
    band: float
    """Half-width of the band that white (independent) residuals stay within with CONFIDENCE."""
    p_value: float
    """Portmanteau (Ljung-Box / Box-Pierce) p-value of 'no correlation at these lags'."""

    @property
    def outside(self) -> int:
        """Lags outside the band."""
        return int(np.sum(np.abs(self.values) > self.band))


def autocorrelation_test(e: np.ndarray, max_lag: int = MAX_LAG) -> Correlation:
    """Whiteness test: autocorrelation of ``e`` at lags 1..max_lag, band ``z / sqrt(N)``, Ljung-Box p.

    Parameters
    ----------
    e : ndarray
        The residual.
    max_lag : int, optional
        The largest lag [samples]; default :data:`MAX_LAG`.
    """
    x = np.asarray(e, float) - np.mean(e)
    n = len(x)
    den = sse(x)
    lags = np.arange(1, max_lag + 1)
    r = np.array([dot(x[:-k], x[k:]) / den for k in lags]) if den > 0 else np.zeros(max_lag)
    q = n * (n + 2) * float(np.sum(r * r / (n - lags)))
    z = stats.norm.ppf(0.5 + CONFIDENCE / 2)
    return Correlation(lags, r, z / math.sqrt(n), float(stats.chi2.sf(q, max_lag)))


def cross_correlation_test(u: np.ndarray, e: np.ndarray, max_lag: int = MAX_LAG) -> Correlation:
    """Cross-correlation of input ``u`` and residual ``e`` at lags -max_lag..max_lag (``e`` after ``u``
    for positive lags); band ``z / sqrt(N)`` as for independent signals, Box-Pierce p-value.

    Parameters
    ----------
    u : ndarray
        The input.
    e : ndarray
        The residual.
    max_lag : int, optional
        The largest lag [samples]; default :data:`MAX_LAG`.
    """
    a = np.asarray(u, float) - np.mean(u)
    b = np.asarray(e, float) - np.mean(e)
    n = len(a)
    den = math.sqrt(sse(a) * sse(b))
    lags = np.arange(-max_lag, max_lag + 1)
    if den == 0:
        r = np.zeros(len(lags))
    else:
        r = np.array([dot(a[:n - k], b[k:]) if k >= 0 else dot(a[-k:], b[:n + k]) for k in lags]) / den
    q = n * float(np.sum(r * r))
    z = stats.norm.ppf(0.5 + CONFIDENCE / 2)
    return Correlation(lags, r, z / math.sqrt(n), float(stats.chi2.sf(q, len(lags))))


#: How many times the noise level a residual's RMS must exceed to count as structured (is_structured).
STRUCTURE_MATERIALITY = 1.5
#: The level of is_structured's whiteness and zero-mean tests.
STRUCTURE_ALPHA = 1e-3


def is_structured(e: np.ndarray, *, sensor_noise_mm: float | None = None, alpha: float = STRUCTURE_ALPHA,
                  materiality: float = STRUCTURE_MATERIALITY) -> tuple[bool, dict]:
    """Does ``e`` hold structure beyond white noise? Both must hold:

    * the Ljung-Box whiteness test rejects white noise at level ``alpha``, or the residual's mean is
      not zero at that level (a t-test: a constant offset, an encoder zeroed elsewhere, is white about
      its mean, which the whiteness test removes);
    * the residual is material: its RMS exceeds ``materiality`` times the noise level, the smaller of
      its own white-noise level (:func:`white_noise_level_mm`) and the sensor noise the model states
      (an oscillation at a few samples' period inflates the first, a rig noisier than its model the
      second; either alone would hide a real mismatch).

    Returns the decision and the numbers behind it.

    Parameters
    ----------
    e : ndarray
        The residual [mm].
    sensor_noise_mm : float, optional
        The sensor noise the model states [mm]; None (or <= 0): the residual's own white-noise
        level alone.
    alpha : float, optional
        Level of the whiteness and mean tests; default :data:`STRUCTURE_ALPHA`.
    materiality : float, optional
        Factor on the noise level the RMS must exceed; default :data:`STRUCTURE_MATERIALITY`.
    """
    ac = autocorrelation_test(e)
    sigma = white_noise_level_mm(e)
    ref = sigma if sensor_noise_mm is None or sensor_noise_mm <= 0 else min(sigma, sensor_noise_mm)
    rms = float(np.sqrt(np.mean(e ** 2)))
    mean_p = mean_test(e)
    structured = (ac.p_value < alpha or mean_p < alpha) and rms > materiality * ref
    return structured, {"ljung_box_p": ac.p_value, "lags_outside_band": ac.outside, "rms_mm": rms,
                        "white_noise_mm": sigma, "noise_reference_mm": ref, "mean_mm": math.fsum(np.asarray(e, float).tolist()) / len(e),
                        "mean_p": mean_p}


def unstructured_reason(numbers: dict, unit: str = "mm") -> str:
    """Why :func:`is_structured` (at its default levels) found no structure, in words, from the numbers
    it returned: a white, zero-mean residual, or one that is not but lies within
    :data:`STRUCTURE_MATERIALITY` times the noise level (a structure too small to matter).

    Parameters
    ----------
    numbers : dict
        What :func:`is_structured` returned beside its decision.
    unit : str, optional
        The residual's unit; default ``"mm"``.
    """
    if numbers["ljung_box_p"] >= STRUCTURE_ALPHA and numbers["mean_p"] >= STRUCTURE_ALPHA:
        return "residual white"
    return (f"residual at the noise level: RMS {numbers['rms_mm']:.4f} {unit} against "
            f"{numbers['noise_reference_mm']:.4f} {unit} of noise, < {STRUCTURE_MATERIALITY:g} x")


def mean_test(e: np.ndarray) -> float:
    """Two-sided p-value of "``e`` has zero mean" (one-sample t-test on independent samples).

    As ``scipy.stats.ttest_1samp``, but on correctly rounded sums: the verdict it gates must not
    depend on the CPU's summation order (:mod:`tapmuscle.diagnosis.reproducible`).

    Parameters
    ----------
    e : ndarray
        The residual.
    """
    x = np.asarray(e, float)
    n = len(x)
    if n < 2:
        return 1.0
    mean = math.fsum(x.tolist()) / n
    sd = math.sqrt(sse(x - mean) / (n - 1))
    if sd == 0.0:
        return 1.0 if mean == 0.0 else 0.0
    return float(2.0 * stats.t.sf(abs(mean) / (sd / math.sqrt(n)), n - 1))


def block_index(n: int, ts_s: float, block_s: float) -> np.ndarray:
    """The block of ``block_s`` seconds each of ``n`` samples at ``ts_s`` lies in (0, 1, ...; float).

    Parameters
    ----------
    n : int
        Number of samples.
    ts_s : float
        Sampling period [s].
    block_s : float
        Block length [s].
    """
    return np.arange(n) * ts_s // block_s


def interleaved_split(n: int, ts_s: float, block_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out masks: alternating blocks of ``block_s`` seconds (even blocks train;
    :func:`block_index`).

    Interleaving keeps both parts spread over the whole run, so an effect that is present only for a
    while is seen by both (a first-half/second-half split could hide it from one of them).

    Parameters
    ----------
    n : int
        Number of samples.
    ts_s : float
        Sampling period [s].
    block_s : float
        Block length [s].
    """
    block = block_index(n, ts_s, block_s)
    train = (block % 2) == 0
    return train, ~train


#: Command changes at most this fraction of the samples: the command is held between changes (random
#: levels, steps). Counted as changes, not distinct levels: a sampled periodic sine repeats its levels
#: but changes every sample.
HELD_FRACTION = 0.25

#: Largest difference, between the training and the held-out blocks, of the rising share of a
#: continuous command's motion (:func:`direction_imbalance`) at which a split counts as balanced.
SPLIT_BALANCE = 0.2

#: Block lengths tried, in this order, when the preferred one splits a continuous command unbalanced
#: (multiples of the preferred length; :func:`balanced_block_s`).
BLOCK_CHOICES = (1.0, 0.9, 1.1, 0.8, 1.2, 0.7, 1.3)


def held_command(u_v: np.ndarray) -> bool:
    """Is the command held between changes (it changes in at most :data:`HELD_FRACTION` of the
    samples: random levels, steps)?"""
    return np.count_nonzero(np.diff(u_v)) <= HELD_FRACTION * len(u_v)


def direction_imbalance(u_v: np.ndarray, ts_s: float, block_s: float) -> float:
    """How differently the training and the held-out blocks of :func:`interleaved_split` see the
    command move: the difference of their rising shares of the command's motion
    (:math:`\\sum \\max(\\Delta u, 0) / \\sum |\\Delta u|`), 0 (alike) to 1 (one part sees the
    command rise only, the other fall only); 0 for a part that sees no motion.
    """
    du = np.diff(np.asarray(u_v, float), prepend=float(u_v[0]))
    train, test = interleaved_split(len(du), ts_s, block_s)

    def rising(m: np.ndarray) -> float:
        total = float(np.sum(np.abs(du[m])))
        return float(np.sum(np.maximum(du[m], 0.0))) / total if total > 0 else 0.5
    return abs(rising(train) - rising(test))


def balanced_block_s(u_v: np.ndarray, ts_s: float, preferred_s: float, *, longest_s: float = math.inf) -> float:
    """The block length [s] of the training / held-out split of a recording with command ``u_v``.

    ``preferred_s`` unless the command is continuous (not :func:`held_command`) and that split is
    unbalanced (:func:`direction_imbalance` above :data:`SPLIT_BALANCE`); then the first of
    :data:`BLOCK_CHOICES` (those up to ``longest_s``) that balances it, or the least unbalanced of them.

    The held-out blocks test what the training blocks fitted only if both see the same kind of
    motion. A periodic command whose period is near twice the block length (or an odd fraction of
    it) is phase-locked to the split: every training block sees it rise and every held-out block
    fall, or nearly so, and a hysteretic plant's error differs between the two. Field case ``087``
    (seed 3: a sine sum whose 1.7-V component has a 19.6-s period; a 0.23-s delay and a supply sag):
    with 10-s blocks the training blocks see 0.28 more of the motion rising than the held-out ones,
    the delay cut the training error 20-fold and raised the held-out error, and it was dropped; with
    9-s or 12-s blocks (imbalance 0.07) the delay is found, 0.228 and 0.229 s. A held command's
    split is left alone: its few jumps per block make the share a matter of chance, not of phase.
    """
    if held_command(u_v) or direction_imbalance(u_v, ts_s, preferred_s) <= SPLIT_BALANCE:
        return preferred_s
    choices = [preferred_s * k for k in BLOCK_CHOICES if preferred_s * k <= longest_s] or [preferred_s]
    for b in choices:
        if direction_imbalance(u_v, ts_s, b) <= SPLIT_BALANCE:
            return b
    return min(choices, key=lambda b: direction_imbalance(u_v, ts_s, b))


def _moving_rms(x: np.ndarray, width: int) -> np.ndarray:
    width = max(1, min(width, len(x)))
    c = moving_sum(x * x, width, centred=True) / width
    return np.sqrt(np.maximum(c, 0.0))


def located_windows(signal: np.ndarray, ts_s: float, *, noise_mm: float, window_s: float = 5.0,
                    min_length_s: float = 3.0, merge_gap_s: float = 5.0, floor: float = 3.0,
                    relative: float = 0.3) -> list[tuple[float, float]]:
    """Time windows [s] where ``signal`` (a residual, or an effect's contribution) is large.

    The moving RMS over ``window_s`` must exceed both ``floor`` times the noise level and ``relative``
    times its own maximum; runs closer than ``merge_gap_s`` merge, runs shorter than ``min_length_s``
    are dropped.

    Parameters
    ----------
    signal : ndarray
        The residual or contribution, one value per sample [mm].
    ts_s : float
        Sampling period [s].
    noise_mm : float
        The noise level [mm].
    window_s : float, optional
        Length of the moving RMS [s]; default 5.
    min_length_s : float, optional
        Shortest window kept [s]; default 3.
    merge_gap_s : float, optional
        Runs this close merge [s]; default 5.
    floor : float, optional
        Factor on the noise level the moving RMS must exceed; default 3.
    relative : float, optional
        Fraction of its own maximum the moving RMS must exceed; default 0.3.
    """
    if len(signal) == 0:
        return []
    m = _moving_rms(np.asarray(signal, float), int(round(window_s / ts_s)))
    thr = max(floor * noise_mm, relative * float(np.max(m)))
    above = m > thr
    runs: list[list[float]] = []
    k = 0
    n = len(above)
    while k < n:
        if above[k]:
            j = k
            while j + 1 < n and above[j + 1]:
                j += 1
            a, b = k * ts_s, j * ts_s
            if runs and a - runs[-1][1] <= merge_gap_s:
                runs[-1][1] = b
            else:
                runs.append([a, b])
            k = j + 1
        else:
            k += 1
    return [(a, b) for a, b in runs if b - a >= min_length_s]


def iou(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> float:
    """Intersection over union of two sets of disjoint time windows.

    Parameters
    ----------
    a, b : list of (float, float)
        Disjoint time windows ``(start, end)`` [s].
    """
    def total(ws):
        return sum(max(0.0, y - x) for x, y in ws)
    inter = sum(max(0.0, min(y1, y2) - max(x1, x2)) for x1, y1 in a for x2, y2 in b)
    union = total(a) + total(b) - inter
    return inter / union if union > 0 else 0.0


def regime_summary(energy: np.ndarray, l_mm: np.ndarray, ts_s: float, p_mpa: np.ndarray | None = None,
                   *, signal: np.ndarray | None = None, min_ratio: float = 1.3,
                   output: tuple[str, str] | None = None) -> tuple[str, dict]:
    """In which operating regime does ``energy`` (per-sample squared residual or contribution) concentrate?

    Regimes: direction of motion (contracting / extending / holding, from the recorded displacement
    smoothed over 0.5 s), speed, displacement and pressure terciles, and (given the signed ``signal``)
    the frequency at which its power peaks. A regime is reported when its share of the energy is at least
    ``min_ratio`` times its share of the time.

    ``output``: ``(name, unit)`` of another model's measured output in place of the muscle's
    displacement ``l_mm``; the regimes are then its direction (rising / falling / steady), rate of
    change and level, in its unit.

    Parameters
    ----------
    energy : ndarray
        Per-sample squared residual or contribution.
    l_mm : ndarray
        Recorded displacement [mm] (or the other model's output, with ``output``).
    ts_s : float
        Sampling period [s].
    p_mpa : ndarray, optional
        Recorded pressure [MPa], for the pressure terciles.
    signal : ndarray, optional
        The signed residual or contribution, for its dominant frequency.
    min_ratio : float, optional
        Smallest ratio of a regime's energy share to its time share that is reported; default
        1.3.
    output : (str, str), optional
        ``(name, unit)`` of another model's measured output.

    Returns
    -------
    text : str
        Plain words, e.g. ``"mostly while extending (61 % of the residual energy in 42 % of the time)"``.
    table : dict
        ``{axis: {regime: {"time_share": x, "energy_share": x}}}`` and ``"dominant_frequency_hz"``.
    """
    e = np.asarray(energy, float)
    total = float(np.sum(e))
    k = max(1, int(round(0.5 / ts_s)))
    smooth = moving_sum(l_mm, k, centred=True) / k
    v = np.gradient(smooth, ts_s)
    if output is None:
        hold = max(0.5, 0.1 * float(np.percentile(np.abs(v), 90)))  # [mm/s]
        up, down, still, quantity, unit = "contracting", "extending", "holding", "displacement", "mm"
    else:  # no unit-bound floor: only the recording's own rates
        hold = 0.1 * float(np.percentile(np.abs(v), 90))
        (quantity, unit), (up, down, still) = output, ("rising", "falling", "steady")
    axes: dict[str, dict[str, np.ndarray]] = {"direction": {up: v > hold, down: v < -hold, still: np.abs(v) <= hold}}

    def span(a: float, b: float, fmt: str) -> str:
        # "-0" is 0; a negative bound is joined with "to" ("-3 to 54", not "-3-54")
        lo, hi = (fmt.format(x) for x in (a, b))
        lo, hi = ("0" + t[2:] if t.startswith("-0") and float(t) == 0.0 else t for t in (lo, hi))
        return f"{lo} to {hi}" if lo.startswith("-") or hi.startswith("-") else f"{lo}-{hi}"

    def terciles(x: np.ndarray, unit: str, fmt: str) -> dict[str, np.ndarray]:
        q1, q2 = np.percentile(x, [100 / 3, 200 / 3])
        return {f"low ({span(x.min(), q1, fmt)} {unit})": x <= q1,
                f"middle ({span(q1, q2, fmt)} {unit})": (x > q1) & (x <= q2),
                f"high ({span(q2, x.max(), fmt)} {unit})": x > q2}

    axes["speed"] = terciles(np.abs(v), f"{unit or '1'}/s", "{:.1f}" if output is None else "{:.3g}")
    axes["displacement"] = terciles(np.asarray(l_mm, float), unit or "-", "{:.0f}" if output is None else "{:.3g}")
    if p_mpa is not None:
        p = np.asarray(p_mpa, float)
        # a column far above any tap's pressure is in another unit (recording_checks notes it): its
        # terciles are labelled as logged, not in MPa
        in_mpa = float(np.max(p)) <= PRESSURE_PLAUSIBLE_MPA
        axes["pressure"] = terciles(p, "MPa" if in_mpa else "as logged, not MPa", "{:.3f}" if in_mpa else "{:.4g}")
    table: dict = {}
    notes = []
    for axis, regimes in axes.items():
        table[axis] = {}
        best = None
        for name, mask in regimes.items():
            ts = float(np.mean(mask))
            es = float(np.sum(e[mask])) / total if total > 0 else 0.0
            table[axis][name] = {"time_share": ts, "energy_share": es}
            if ts > 0.05 and es >= min_ratio * ts and (best is None or es / ts > best[2] / best[1]):
                best = (name, ts, es)
        if best is not None:
            where = {"direction": f"while {best[0]}" if output is None else f"while {quantity} is {best[0]}",
                     "speed": f"at {best[0]} speed" if output is None else f"at {best[0]} rate of change of {quantity}",
                     "displacement": f"at {best[0]} {quantity}", "pressure": f"at {best[0]} pressure"}[axis]
            notes.append(f"{where} ({100 * best[2]:.0f} % of it in {100 * best[1]:.0f} % of the time)")
    if signal is not None:
        f = dominant_frequency_hz(signal, ts_s)
        table["dominant_frequency_hz"] = f
        notes.append(f"its power peaks at {f:.3g} Hz" if f > 0 else "no dominant frequency")
    text = "; ".join(notes) if notes else "spread evenly over the operating range"
    return text, table


def dominant_frequency_hz(e: np.ndarray, ts_s: float) -> float:
    """Frequency [Hz] of the largest peak of the residual's periodogram (mean removed; 0 if flat).

    Parameters
    ----------
    e : ndarray
        The residual.
    ts_s : float
        Sampling period [s].
    """
    x = np.asarray(e, float) - np.mean(e)
    if len(x) < 8 or not np.any(x):
        return 0.0
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x)))) ** 2
    f = np.fft.rfftfreq(len(x), ts_s)
    return float(f[1 + int(np.argmax(spec[1:]))])
