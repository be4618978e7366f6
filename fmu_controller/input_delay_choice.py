"""Choose a rig's transport delay for Eq. (1) from its recording.

A valve that acts ``d`` samples late makes Eq. (1) hold on ``u(k - d)``
(:func:`~fmu_controller.identification.identify_record`'s ``input_delay_samples``). Identified under
each delay ``D`` from 0 to :func:`search_samples` (0.5 s at the record's period, at least 5 samples),
the model's 1-step fit (Table 4) on the record is highest at the rig's delay: a smaller ``D`` credits
the command with an effect it has not had yet, a larger one hides the command that already acts (the
fit then drops sharply). Measured on simulated rigs (benchmarks/input_delay_choice.py): 120-s random,
step and chirp records of nominal rigs with delays of 0 to 0.4 s peak at the rig's delay in 20 of 20,
off-nominal rigs under random commands within a sample of it in 30 of 30. At Ts = 0.02 s a 300-s
random record of a rig with a 0.15-s valve delay (and the valve spool's 0.03-s lag) peaks at 8
samples, 0.16 s.

The fits are those of the identification record itself. Scored on another record instead, the choice
went wrong where that record differed (another command kind, another load: one sample short in about
7 of 10 such cases), and a validation score of the best of six models is no longer a held-out one.

Algorithm 1's box matters for the choice: where the record ends before the box would apply
(``constraint_start_s``, the paper's 120 s, on a 120-s record), the unconstrained estimates chose one
sample short in 4 of 20 nominal cases; the choice therefore applies the box from half the record then
(and says so), and only the identification it returns is the one asked for.

A delay between two samples (0.15 s at Ts = 0.1 s) fits nearly as well under the longer of the two
as under the better (one-step errors 1.15-1.17 times the best's, where a whole number of samples
leaves its neighbours 2.0-2.8 times, and 1.4 samples 1.6 times), and the adaptive controllers track
better with the longer: on the nominal rig, identified and run under each (AMPC-servo and AMPC-UCP,
60 s of the paper's sine, two seeds) 0.32 against 0.56 mm and 0.75 against 0.80 at 0.15 s, 0.62
against 1.22 and 1.16 against 3.03 at 0.25 s (at 1.4 samples the shorter stays: AMPC-UCP 0.58
against 1.11). The choice therefore takes the longer of two neighbours whose errors lie within
:data:`BETWEEN_SAMPLES_RATIO` (the longer erring less than the delay a sample below the best), where
the pair stands out from the delay beyond it (:data:`BETWEEN_SAMPLES_STANDOUT`), as the
controller's ``input_delay_samples = -1`` does for the servo methods (docs/control.md, "Transport
delay").

A command of one or two sines cannot tell a delay: at a few frequencies a delay is a phase lag, which
Eq. (1)'s dynamics take up as well (a 0.1-Hz sine's fit keeps rising past the rig's delay to 3-5
samples; two sines chose one sample short or 2-4 long). :func:`choose_input_delay` refuses such a
command (:func:`tone_frequencies_hz`); the delay is then the user's to give.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np
from scipy.optimize import minimize_scalar

from .argument_checks import real_number
from .identification import IdentificationReport, check_record, identify_record
from .prediction import MAX_INPUT_DELAY_SAMPLES

__all__ = ["InputDelayChoice", "ToneCommandError", "choose_input_delay", "fits_by_delay", "tone_frequencies_hz",
           "search_samples", "TONE_SHARE", "THIN_MARGIN_PERCENT", "SEARCH_S", "MIN_SEARCH_SAMPLES",
           "BETWEEN_SAMPLES_RATIO", "BETWEEN_SAMPLES_STANDOUT"]

#: Share of a command's variance that one or two fitted sinusoids must explain for the command to be
#: taken as tones. Measured on 120-s commands: a sine 1.000 (any number of periods), two sines 0.997-1.000,
#: a sine with a +-0.5 V dither 0.982; two sinusoids explain 0.90 of a square wave, 0.93 of a single step
#: at mid-record, 0.71 of steps among five levels, 0.55 of a chirp over 0.08-0.12 Hz, 0.38 of a random
#: command.
TONE_SHARE = 0.99

_DEFAULT_CONSTRAINT_START_S = inspect.signature(identify_record).parameters["constraint_start_s"].default

#: A lead of the best fit over the next smaller than this [% of fit] is reported as thin. On the
#: simulated rigs of benchmarks/input_delay_choice.py right choices led by 0.0005-1.0 %; choices gone
#: wrong (short records, long holds, other conditions) led by a median of 0.06 %.
THIN_MARGIN_PERCENT = 0.1

#: The longer of two neighbouring delays is taken where its one-step error (100 % less its fit) is at
#: most this many times the best's ... (module docstring; half a sample gives 1.15-1.17, a whole
#: number of samples 2.0-2.8 for its neighbours)
BETWEEN_SAMPLES_RATIO = 1.2
#: ... where it errs less than the shorter neighbour does, and the delay beyond it (where tried) errs
#: at least this many times the best: a chirp's fits lie within a few hundredths of a point over
#: every delay (errors 1.03-1.24 times the best's), a run of flat fits and no pair; there the best
#: fit alone is kept.
BETWEEN_SAMPLES_STANDOUT = 1.3

#: :func:`choose_input_delay` tries the delays up to this long [s] (the field rigs' transport delays
#: reach 0.35 s) ...
SEARCH_S = 0.5
#: ... and at least this many samples (the whole search at the paper's Ts = 0.1 s and above, and the
#: delays ``input_delay_samples = -1`` decides), at most :data:`~fmu_controller.prediction.MAX_INPUT_DELAY_SAMPLES`.
MIN_SEARCH_SAMPLES = 5


def search_samples(ts_s: float) -> int:
    """The largest delay [samples] :func:`choose_input_delay` tries by default at the sampling period
    ``ts_s`` [s]: :data:`SEARCH_S` rounded to samples, within :data:`MIN_SEARCH_SAMPLES` ..
    :data:`~fmu_controller.prediction.MAX_INPUT_DELAY_SAMPLES` (25 at 0.02 s, 5 at 0.1 s and above).

    Parameters
    ----------
    ts_s : float
        Sampling period [s].

    Raises
    ------
    ValueError
        ``ts_s`` not a positive finite number.
    """
    ts = float(ts_s)
    if not (math.isfinite(ts) and ts > 0.0):
        raise ValueError(f"ts_s must be a positive finite number of seconds, got {ts_s!r}")
    # rounded, not floored: a jittered log's least-squares period (0.0200000001 s) is 0.02 s
    return min(max(round(SEARCH_S / ts), MIN_SEARCH_SAMPLES), MAX_INPUT_DELAY_SAMPLES)


def _best_sinusoid(x: np.ndarray, t: np.ndarray, ts_s: float) -> tuple[np.ndarray, float]:
    """``x`` less the sinusoid (and offset) that fits it best, and its frequency [Hz], refined within a
    periodogram bin of the strongest one (Hann window)."""
    power = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(len(x)))) ** 2
    power[0] = 0.0
    bin_hz = 1.0 / (len(x) * ts_s)
    f0 = int(np.argmax(power)) * bin_hz

    def residual(f: float) -> np.ndarray:
        basis = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
        return x - basis @ np.linalg.lstsq(basis, x, rcond=None)[0]

    def squares(f: float) -> float:
        r = residual(f)
        return float(r @ r)

    f = minimize_scalar(squares, bounds=(max(f0 - bin_hz, 0.1 * bin_hz), f0 + bin_hz), method="bounded").x
    return residual(f), float(f)


def tone_frequencies_hz(u: np.ndarray, ts_s: float) -> tuple[float, ...] | None:
    """The frequencies [Hz] of a command that is one or two sines (fitted sinusoids explain at least
    :data:`TONE_SHARE` of its variance), else None (also for a constant command).

    Parameters
    ----------
    u : ndarray
        The command, one sample per period [V].
    ts_s : float
        Sampling period [s].
    """
    x = np.asarray(u, dtype=float)
    x = x - x.mean()
    total = float(x @ x)
    if len(x) < 8 or not math.isfinite(total) or total == 0.0:
        return None
    t = np.arange(len(x)) * ts_s
    found = []
    for _ in range(2):
        x, f = _best_sinusoid(x, t, ts_s)
        found.append(float(f))
        if 1.0 - float(x @ x) / total >= TONE_SHARE:
            return tuple(found)
    return None


class ToneCommandError(ValueError):
    """The identification record's command is one or two sines (:func:`tone_frequencies_hz`)."""

    def __init__(self, frequencies_hz: tuple[float, ...]) -> None:
        what = (f"one sine ({frequencies_hz[0]:.2g} Hz)" if len(frequencies_hz) == 1 else
                f"two sines ({frequencies_hz[0]:.2g} and {frequencies_hz[1]:.2g} Hz)")
        super().__init__(f"the record's command is {what}: at a few frequencies a transport delay is a phase lag "
                         "that Eq. (1)'s dynamics take up too, so its fits cannot tell the delay; record a random, "
                         "step or chirp command, or give the delay yourself (tapmuscle identify "
                         "--input-delay-samples D; tm.identify(..., input_delay_samples=D))")
        self.frequencies_hz = frequencies_hz


@dataclass(frozen=True)
class InputDelayChoice:
    """Result of :func:`choose_input_delay`."""

    input_delay_samples: int
    """The delay ``D`` [samples] whose model fits best one step ahead, or the next longer one where the
    two fit nearly alike (:attr:`between_samples`)."""
    fits_percent: tuple[float, ...]
    """The 1-step fit [%] on the record of the model identified under each ``D = 0, 1, ...``."""
    constraint_start_s: float
    """When Algorithm 1's box applied in the identifications the choice compared [s]: the one asked
    for, or half the record where that lies beyond its end."""
    report: IdentificationReport
    """The identification under the chosen delay, with the options asked for."""
    between_samples: bool = False
    """The rig's delay lies between ``input_delay_samples - 1`` and ``input_delay_samples`` samples:
    the shorter fits best, the chosen longer within :data:`BETWEEN_SAMPLES_RATIO` of it."""

    @property
    def margin_percent(self) -> float:
        """How much better [% of fit] the chosen delay fits than the next best (inf with one delay
        tried), the two of a delay between samples counted as one; below :data:`THIN_MARGIN_PERCENT`
        the record hardly tells the two apart."""
        chosen = {self.input_delay_samples} | ({self.input_delay_samples - 1} if self.between_samples else set())
        rest = [f for d, f in enumerate(self.fits_percent) if d not in chosen and math.isfinite(f)]
        return max(self.fits_percent[d] for d in chosen) - max(rest) if rest else math.inf

    @property
    def at_largest(self) -> bool:
        """The best fit is at the largest delay tried: the rig's delay may be larger still."""
        return self.input_delay_samples == len(self.fits_percent) - 1 and not self.between_samples


def _between_samples(fits: list[float], best: int) -> bool:
    """Whether the rig's delay lies between ``best`` and ``best + 1`` samples, by the 1-step fits [%]
    under each delay: the longer errs within :data:`BETWEEN_SAMPLES_RATIO` of the best and less than
    the shorter neighbour, and the delay beyond the pair at least :data:`BETWEEN_SAMPLES_STANDOUT`
    times the best."""
    err = [100.0 - f if math.isfinite(f) else math.inf for f in fits]
    if best + 1 >= len(err) or not err[best + 1] <= BETWEEN_SAMPLES_RATIO * err[best]:
        return False
    if best >= 1 and not err[best + 1] < err[best - 1]:
        return False
    return best + 2 >= len(err) or err[best + 2] >= BETWEEN_SAMPLES_STANDOUT * err[best]


def fits_by_delay(u_v: np.ndarray, l_mm: np.ndarray, *, ts_s: float, max_samples: int | None = None,
                  on_delay: Callable[[int, int], None] | None = None,
                  **identify: Any) -> tuple[list[float], list[IdentificationReport]]:
    """The 1-step fits [%] on the record of Eq. (1) identified under each input delay
    ``D = 0 .. max_samples``, and those identifications; the arguments as :func:`choose_input_delay`'s,
    whatever the command (its frequencies are not checked) and with the options as given.

    Parameters
    ----------
    u_v, l_mm : ndarray
        Command [V] and displacement [mm] of the record, one sample per period.
    ts_s : float
        Sampling period [s].
    max_samples : int, optional
        The largest delay tried [samples], 0 .. ``MAX_INPUT_DELAY_SAMPLES``; by default
        :func:`search_samples`.
    on_delay : callable, optional
        ``on_delay(done, total)`` after each delay's identification (``total`` = ``max_samples +
        1``).
    **identify
        Keyword arguments of :func:`~fmu_controller.identification.identify_record`, the same
        under each delay (not ``input_delay_samples``).
    """
    if max_samples is None:
        max_samples = search_samples(ts_s)
    if isinstance(max_samples, bool) or not isinstance(max_samples, (int, np.integer)) \
            or not 0 <= max_samples <= MAX_INPUT_DELAY_SAMPLES:
        raise ValueError(f"max_samples must be an integer in 0..{MAX_INPUT_DELAY_SAMPLES}, got {max_samples!r}")
    if "input_delay_samples" in identify:
        raise ValueError("input_delay_samples is what choose_input_delay chooses; do not pass it")
    reports = []
    for d in range(int(max_samples) + 1):
        reports.append(identify_record(u_v, l_mm, ts_s=ts_s, input_delay_samples=d, **identify))
        if on_delay is not None:
            on_delay(d + 1, int(max_samples) + 1)
    return [r.fit.percent["1"] for r in reports], reports


def choose_input_delay(u_v: np.ndarray, l_mm: np.ndarray, *, ts_s: float,
                       max_samples: int | None = None, on_delay: Callable[[int, int], None] | None = None,
                       **identify: Any) -> InputDelayChoice:
    """Identify Eq. (1) under each input delay ``D = 0 .. max_samples`` and keep the best 1-step fit
    on the record (module docstring).

    Parameters
    ----------
    u_v, l_mm : ndarray
        Command [V] and displacement [mm] of the record, one sample per period (120 s or more, a
        random, step or chirp command: module docstring).
    ts_s : float
        Sampling period [s].
    max_samples : int, optional
        The largest delay tried [samples], 0 .. ``MAX_INPUT_DELAY_SAMPLES`` (25); by default
        :func:`search_samples`: 0.5 s at ``ts_s``, at least 5 samples (identifications cost about 0.35 s
        each on a 300-s record at 0.02 s).
    on_delay : callable, optional
        ``on_delay(done, total)`` after each delay's identification (``total`` = ``max_samples + 1``;
        a progress report's hook: a long record takes seconds a delay).
    **identify
        Keyword arguments of :func:`~fmu_controller.identification.identify_record` (``model``,
        ``box``, ``constraint_start_s``, ``p0``, ``forgetting``, ``theta0``), the same under each delay.

    Returns
    -------
    InputDelayChoice
        The delay, the fits under every delay and the identification under the chosen one. Score it
        on another record of the rig (:func:`~fmu_controller.identification.score_model`) to check it.

    Raises
    ------
    ToneCommandError
        A command of one or two sines: its fits cannot tell a delay.
    ValueError
        ``max_samples`` out of range; ``input_delay_samples`` among ``identify``; anything
        :func:`identify_record` refuses.
    """
    # the record's shape, values and period first, as identify_record names them (the tone fit's
    # numpy error on a column vector names nothing)
    check_record(np.asarray(u_v, dtype=float), np.asarray(l_mm, dtype=float), real_number(ts_s, what="ts_s"))
    tones = tone_frequencies_hz(u_v, ts_s)
    if tones is not None:
        raise ToneCommandError(tones)
    duration_s = (len(np.asarray(l_mm)) - 1) * float(ts_s)
    asked = float(identify.get("constraint_start_s", _DEFAULT_CONSTRAINT_START_S))
    start = asked if asked < duration_s else duration_s / 2.0
    fits, reports = fits_by_delay(u_v, l_mm, ts_s=ts_s, max_samples=max_samples, on_delay=on_delay,
                                  **(identify | {"constraint_start_s": start}))
    # a fit that is not a number (a diverged prediction) is the worst, not the best (argmax takes NaN)
    best = int(np.argmax([f if math.isfinite(f) else -math.inf for f in fits]))
    between = _between_samples(fits, best)
    best += between
    report = reports[best] if start == asked else identify_record(u_v, l_mm, ts_s=ts_s, input_delay_samples=best,
                                                                   **identify)
    tried = len(fits) - 1
    if max_samples is None and round(SEARCH_S / float(ts_s)) > MAX_INPUT_DELAY_SAMPLES:
        # the controllers compensate at most MAX_INPUT_DELAY_SAMPLES: at a short Ts they span less than
        # the delays a rig has (0.15 s is 150 samples at 1 ms)
        note = (f"the delays were searched only up to {tried} samples, {tried * float(ts_s):g} s at Ts = {float(ts_s):g} s "
                f"(the controllers compensate at most {MAX_INPUT_DELAY_SAMPLES}), not the {SEARCH_S:g} s a rig's delay "
                f"may reach: merge the record to Ts = {SEARCH_S / MAX_INPUT_DELAY_SAMPLES:g} s or more to search that far "
                "(tapmuscle import --decimate N, tm.decimated)")
        report = replace(report, notes=report.notes + (note,))
    return InputDelayChoice(best, tuple(fits), start, report, between_samples=between)
