"""The sampling period of a recorded time column, and what counts as uniformly sampled.

Every tool works on samples ``k = 0, 1, ...`` at ``t_0 + k Ts`` (docs/recordings.md, "Sampling
convention"). A logger on a PC or a microcontroller stamps its samples with jitter: its times scatter
about that grid by milliseconds while no sample is missing. *Decided:* a time within a quarter period
of its slot is that slot's sample (the jitter is in the stamp, as measured: ±5 ms on a 0.1-s period
leaves the diagnosis of an exact model at no mismatch, 99.87 % held-out fit); a time further off means
a dropped, doubled or late sample, which shifts every later command against its response, and is
refused with the sample named. A quarter period keeps a single dropped sample detectable wherever it
lies (it moves the later samples a whole period off the grid fitted through all of them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from fmu_controller.argument_checks import MUSCLE_TS_RANGE_S, in_sampling_range
from tapmuscle.errors import TapmuscleError

__all__ = ["Sampling", "SamplingError", "uniform_sampling", "JITTER_TOLERANCE", "STRICT_TOLERANCE", "TS_RANGE_S",
           "GAP_PERIODS", "check_sampling_period", "step_kind", "DECIMATED_TS_S", "decimation_factor", "merge_advice",
           "MAX_DECIMATION", "period_change", "PERIOD_CHANGE_MIN_STEPS", "PERIOD_CHANGE_STRAY", "nominal_period",
           "NOMINAL_PERIOD_TOLERANCE"]

#: Largest distance of a sample's time from its slot on the uniform grid, as a fraction of the period.
JITTER_TOLERANCE = 0.25
#: Steps within this fraction of the median step count as exactly uniform (a recording written with
#: rounded times): the period is then the median step, as written.
STRICT_TOLERANCE = 1e-3

#: A jittered log's period (the slope through its times) within this relative distance, plus three of
#: the slope's standard errors, of a value of at most 6 significant digits is taken as that value: a
#: logger's nominal period (0.05 s), which the jitter and a clock's drift below 1 ppm (0.09 s a day)
#: move in the last digits (0.0499999999, 0.100000042 s). Carried on, such a period made a model's loop
#: run at another Ts than a scenario's 0.05 s, and the two differ in their last bits, which a loop near
#: a limit cycle amplifies (2.36 against 1.49 mm).
NOMINAL_PERIOD_TOLERANCE = 1e-6
#: Sampling periods [s] a muscle recording may have (those of ``tapmuscle record --ts``).
TS_RANGE_S = MUSCLE_TS_RANGE_S


#: The sampling period [s] to merge a log taken faster than :data:`TS_RANGE_S` allows to: a 10-min
#: 1-kHz log of a rig with a 0.3-s delay, merged to 0.02 s (`tapmuscle import --decimate 20`), was
#: diagnosed in 10 s (the 1-kHz log in 160 s) with the delay named at 300 ms and 99.94 % held-out fit, as
#: at 0.01 s (24 s); merged to 0.1 s, 303 ms and a structured residual left. Identification wants 0.02 s
#: or more (:data:`fmu_controller.identification.SHORT_TS_S`).
DECIMATED_TS_S = 0.02


#: Most samples ``tapmuscle import --decimate`` merges into one (a 50-kHz log to 0.02 s).
MAX_DECIMATION = 1000


def decimation_factor(ts_s: float, target_s: float = DECIMATED_TS_S) -> int:
    """Samples to merge into one so that a log sampled every ``ts_s`` [s] has a period of about
    ``target_s`` [s]: 1 .. :data:`MAX_DECIMATION`.

    Parameters
    ----------
    ts_s : float
        The log's sampling period [s].
    target_s : float, optional
        The period to come near [s]; default :data:`DECIMATED_TS_S`.
    """
    return min(max(1, round(target_s / ts_s)), MAX_DECIMATION)


def merge_advice(ts_s: float) -> str:
    """How to merge a log sampled every ``ts_s`` [s] (shorter than :data:`TS_RANGE_S` allows) to about
    :data:`DECIMATED_TS_S`, in words: the option, the period it gives, and where even the largest
    merge is not enough.

    Parameters
    ----------
    ts_s : float
        The log's sampling period [s].
    """
    n = decimation_factor(ts_s)
    advice = (f"merge every {n} samples into one (tapmuscle import --decimate {n}, tm.read_rig_log(..., decimate={n}), "
              f"tm.decimated: Ts = {n * ts_s:g} s")
    if n * ts_s < TS_RANGE_S[0]:
        advice += f", still shorter than {TS_RANGE_S[0]:g} s: resample the log before, it is beyond the merge's {MAX_DECIMATION}"
    return advice + ")"


def check_sampling_period(ts_s: float) -> None:
    """Refuse a sampling period [s] outside :data:`TS_RANGE_S`: a shorter one is a log taken faster
    than the tools sample (decimate it), a longer one times in another unit (milliseconds?).

    Parameters
    ----------
    ts_s : float
        Sampling period [s].

    Raises
    ------
    ValueError
        Naming the period and the column ``t_s``, and the remedy.
    """
    where = in_sampling_range(ts_s)
    if where < 0:
        merge = merge_advice(ts_s)
        raise ValueError(f"column t_s: the sampling period is {ts_s:g} s ({1.0 / ts_s:g} Hz), shorter than the "
                         f"{TS_RANGE_S[0]:g} s the tools sample at least: a data acquisition faster than the muscle "
                         f"needs? {merge[0].upper()}{merge[1:]}; docs/recordings.md, "
                         "\"Fast data acquisition\"; else the times are in a unit larger than seconds")
    if where > 0:
        raise ValueError(f"column t_s: the sampling period is {ts_s:g} s, outside the {TS_RANGE_S[0]:g}..{TS_RANGE_S[1]:g} s "
                         "of a muscle recording: is the time logged in another unit (milliseconds)? Scale it to seconds")


#: A step this many periods long or more is a gap (a paused logger, a clock that jumped), not a
#: sample or two dropped.
GAP_PERIODS = 10


class SamplingError(TapmuscleError):
    """A time column that is not uniformly sampled; the message names the sample and its time, and
    :attr:`sample` is its index (None: no one sample is to blame). :attr:`steps` holds every sample
    that follows a step off the period (a dropped or doubled sample, a gap), in order, and
    :attr:`largest` the one after the largest of them (empty and None for a drifting clock).
    :attr:`period_change` is True where the period changes part way (:attr:`sample` the first sample
    of the second period, :attr:`steps` empty): no sample is missing, so filling gaps cannot mend it."""

    def __init__(self, message: str, sample: int | None = None, steps: tuple[int, ...] = (),
                 largest: int | None = None, *, period_change: bool = False) -> None:
        super().__init__(message)
        self.sample = sample
        self.steps = steps
        self.largest = largest
        self.period_change = period_change


@dataclass(frozen=True)
class Sampling:
    """The uniform grid a time column was sampled on.

    Attributes
    ----------
    ts_s : float
        Sampling period [s]: the median step when every step is within 0.1 % of it, else the slope of
        the least-squares line through the times (the jitter averages out over the run), rounded to
        the fewest digits that move it by at most 1 ppm and the slope's uncertainty (:func:`nominal_period`).
    jitter_s : float
        Largest distance of a time from its slot on that line [s]; 0 when the steps are uniform.
    """

    ts_s: float
    jitter_s: float

    @property
    def jittered(self) -> bool:
        """Whether the times scatter about the grid (by up to :attr:`jitter_s`) rather than lie on it."""
        return self.jitter_s > 0.0

    def note(self) -> str | None:
        """What a tool tells its user about jittered times (None: they lie on the grid)."""
        if not self.jittered:
            return None
        return (f"the timestamps scatter by up to {1e3 * self.jitter_s:.3g} ms about a uniform {self.ts_s:.6g}-s grid "
                "(logger jitter); the samples are taken as on it")


def step_kind(step_s: float, ts_s: float) -> str:
    """What a step of ``step_s`` [s] in times sampled every ``ts_s`` [s] likely is.

    Parameters
    ----------
    step_s : float
        The step between two time stamps [s].
    ts_s : float
        Sampling period [s].
    """
    if step_s > 0.0 and step_s >= GAP_PERIODS * ts_s:
        return (f"a gap of {step_s:.6g} s, about {round(step_s / ts_s) - 1} samples missing (a paused logger, or a "
                "clock that jumped)")
    if step_s < -0.5 * ts_s:
        return "time goes back (a clock that restarted: two recordings appended, or a logger restarted into its file)"
    return "a dropped or doubled sample"


#: Fewest steps at another period that :func:`uniform_sampling` calls a change of period rather than
#: samples dropped or doubled.
PERIOD_CHANGE_MIN_STEPS = 10
#: Largest share of one side's steps that may lie nearer the other side's period in a change of
#: period (a jittered stamp now and then).
PERIOD_CHANGE_STRAY = 0.01


def period_change(t_s: np.ndarray) -> tuple[int, float, float] | None:
    """Where the sampling period of the times ``t_s`` [s] changes part way, as ``(k, first_s,
    second_s)``, or None: ``k`` is the sample after the first step at the second period, the two
    periods are the medians of the steps on either side.

    The cumulative sum of the steps about their mean peaks near a change of mean (a logger's jitter
    is zero-mean); the two sides' medians there are the candidate periods, and the split is then the
    one that leaves the fewest steps nearer the other side's period. It is a change when each side
    has at least :data:`PERIOD_CHANGE_MIN_STEPS` steps, at most :data:`PERIOD_CHANGE_STRAY` of them
    nearer the other side's period, the two medians differ by more than a quarter of the smaller,
    and each side's steps lie within half of their own median of it, as jittered stamps do: a logger
    set to another rate part way, or two recordings appended. Samples dropped or doubled here and
    there, or one long gap, are not one.

    Parameters
    ----------
    t_s : ndarray
        Time stamps [s].
    """
    t = np.asarray(t_s, dtype=float)
    dt = np.diff(t)
    n = dt.size
    if n < 2 * PERIOD_CHANGE_MIN_STEPS + 1:
        return None
    lo, hi = PERIOD_CHANGE_MIN_STEPS, n - PERIOD_CHANGE_MIN_STEPS
    drift = np.cumsum(dt - np.mean(dt))
    j = int(np.argmax(np.abs(drift[lo - 1:hi]))) + lo  # roughly: steps 0..j-1 before, j.. after
    first, second = float(np.median(dt[:j])), float(np.median(dt[j:]))
    if not (first > 0.0 and second > 0.0) or abs(first - second) <= 0.25 * min(first, second):
        return None
    # exactly: the split that leaves the fewest steps nearer the other side's period (the cumulative
    # sum's peak drifts by many steps where one side is short and its mean near the whole one's)
    nearer_second = np.abs(dt - second) < np.abs(dt - first)
    wrong = np.concatenate(([0], np.cumsum(nearer_second))) + (np.count_nonzero(~nearer_second)
                                                              - np.concatenate(([0], np.cumsum(~nearer_second))))
    j = int(np.argmin(wrong[lo:hi + 1])) + lo  # dt[j] is the first step at the second period
    before, after = dt[:j], dt[j:]
    # each side at its own period: hardly a step nearer the other's (a few dropped samples at the end
    # would be a short side with one step of the old period in it), and none beyond half its own
    if (np.count_nonzero(nearer_second[:j]) > PERIOD_CHANGE_STRAY * j
            or np.count_nonzero(~nearer_second[j:]) > PERIOD_CHANGE_STRAY * (n - j)):
        return None
    first, second = float(np.median(before)), float(np.median(after))
    if abs(first - second) <= 0.25 * min(first, second):
        return None
    # the two steps at the change left out: their stamps carry either period's jitter; but time must go
    # on across it by no more than a step of the longer period and its jitter (a clock that restarts
    # or a gap there is named as what it is)
    if np.any(np.abs(before[:-1] - first) > 0.5 * first) or np.any(np.abs(after[1:] - second) > 0.5 * second):
        return None
    if not np.all((dt[j - 1:j + 1] > 0.0) & (dt[j - 1:j + 1] <= 1.5 * max(first, second))):
        return None
    return j + 1, first, second


def uniform_sampling(t_s: np.ndarray, column: str = "t_s", where: Callable[[int], str] | None = None) -> Sampling:
    """The uniform grid of the times ``t_s`` [s], or a :class:`SamplingError` naming the sample off it.

    Parameters
    ----------
    t_s : array of float
        Sample times [s], strictly increasing, at least 2.
    column : str
        The column's name, for the messages.
    where : callable, optional
        Names sample ``k`` in a message about steps other than the first (default ``"sample k"``; a
        file's reader names its line).

    Raises
    ------
    SamplingError
        Fewer than 2 times; a step off the median step by more than half of it (a dropped or doubled
        sample, a gap: the first such step named, and the largest when it is another); or a time
        more than a quarter period (:data:`JITTER_TOLERANCE`) from its slot (a drifting clock, late
        samples).
    """
    where = where or (lambda k: f"sample {k}")
    t = np.asarray(t_s, dtype=float)
    if len(t) < 2:
        raise SamplingError(f"column {column}: cannot tell the sampling period of fewer than 2 samples")
    dt = np.diff(t)
    ts = float(np.median(dt))
    if not ts > 0.0:
        raise SamplingError(f"column {column}: the median time step is {ts!r} s; times must increase")
    off = np.abs(dt - ts) > STRICT_TOLERANCE * ts
    if not off.any():
        return Sampling(ts, 0.0)
    change = period_change(t)
    if change is not None:  # no sample is missing, nor is the clock late: either name would mislead
        k, first, second = change
        raise SamplingError(
            f"column {column}, sample {k}: the sampling period changes between t = {float(t[k - 1])!r} and "
            f"{float(t[k])!r} s, from {first:.6g} s to {second:.6g} s: one recording has one period; split it "
            "there into two recordings, or resample it onto one grid", k, period_change=True)
    # steps against the median, which a gap leaves where it is (a least-squares slope through the
    # times is pulled by it: a 1-h gap in 3 min of 0.1-s samples makes it 2 s)
    # (a step exactly half a period off, as written, is a late sample for the grid check below: the
    # written times' rounding puts it a few ulps either side of the bound)
    bad = np.flatnonzero((dt <= 0.0) | (np.abs(dt - ts) > 0.5 * ts * (1.0 + 1e-9)))
    if bad.size:
        # named by the first such step in the file (the first that goes back, if one does: two files
        # appended with a clock that restarts), the largest said too
        back = bad[dt[bad] <= 0.0]
        j, big = int(back[0] if back.size else bad[0]), int(bad[np.argmax(np.abs(dt[bad] - ts))])
        more = ""
        if bad.size > 1:
            more = f"; {bad.size} such steps in all"
            if big != j:
                more += f", the largest {float(dt[big]):.6g} s at {where(big + 1)}"
        raise SamplingError(
            f"column {column}, sample {j + 1}: t = {float(t[j + 1])!r} s follows {float(t[j])!r} s, a step of "
            f"{float(dt[j]):.6g} s in a recording sampled every {ts:.6g} s: {step_kind(float(dt[j]), ts)}{more}; "
            f"resample the recording onto a uniform grid first", j + 1, tuple(int(k) + 1 for k in bad), big + 1)
    index = np.arange(len(t), dtype=float)
    slope, intercept = np.polyfit(index, t - t[0], 1)  # from the first time: Unix stamps keep their digits
    slot = t[0] + intercept + slope * index
    dev = np.abs(t - slot)
    if float(np.max(dev)) > JITTER_TOLERANCE * slope:
        k = int(np.argmax(dev))
        raise SamplingError(
            f"column {column}, sample {k}: t = {float(t[k])!r} s lies {float(t[k] - slot[k]):+.6g} s off the uniform "
            f"grid of {slope:.6g} s through all samples, more than a quarter period (logger jitter may be up to "
            f"that): the logger's clock drifts or samples are late; resample the recording onto a uniform grid first", k)
    n = len(t)
    # the slope's standard error: the stamps' scatter about the line over sqrt(sum (k - mean k)^2)
    error = float(np.std(t - slot, ddof=2)) * math.sqrt(12.0 / (n * (n * n - 1.0))) if n > 2 else 0.0
    return Sampling(nominal_period(float(slope), error), float(np.max(dev)))


def nominal_period(ts_s: float, standard_error_s: float = 0.0) -> float:
    """``ts_s`` [s] to the fewest significant digits (up to 6) that move it by at most
    :data:`NOMINAL_PERIOD_TOLERANCE` of itself plus three times ``standard_error_s`` [s], the estimate's
    own (a logger's nominal period: 0.05 for 0.0499999999), else ``ts_s`` as it is.

    Parameters
    ----------
    ts_s : float
        The estimated sampling period [s].
    standard_error_s : float, optional
        The estimate's standard error [s]; default 0.
    """
    allowed = NOMINAL_PERIOD_TOLERANCE * ts_s + 3.0 * standard_error_s
    for digits in range(1, 7):
        rounded = float(f"{ts_s:.{digits}g}")
        if abs(rounded - ts_s) <= allowed:
            return rounded
    return ts_s
