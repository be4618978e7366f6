"""Choose a rig's transport delay for Eq. (1) from its recordings.

A valve that acts ``d`` samples late makes Eq. (1) hold on ``u(k - d)``
(:func:`~fmu_controller.identification.identify_record`'s ``input_delay_samples``). Identified under
each delay ``D = 0 .. MAX_INPUT_DELAY_SAMPLES``, the model's 1-step fit (Table 4) is highest at the
rig's delay: a smaller ``D`` credits the command with an effect it has not had yet, a larger one hides
the command that already acts (the fit then drops sharply). Measured on the simulated rig with delays
of 0 to 0.4 s under random, step and chirp commands, 20 of 20 recordings peak at the rig's delay, and
30 of 30 off-nominal rigs under random commands within a sample of it (benchmarks/input_delay_choice.py).

A single sine cannot tell a delay: at one frequency a delay is a phase lag, which Eq. (1)'s dynamics
take up as well, and the fit keeps rising past the rig's delay (the same rigs under a 0.1-Hz sine peak
at 3-5 samples for delays of 0-3). :func:`choose_input_delay` refuses a command that is one
frequency over at least 3 of its periods; the delay is then the user's to give. (A slower swing, less
than 3 periods in the record, is not refused: it is a ramp more than a tone.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .identification import IdentificationReport, identify_record, score_model
from .prediction import MAX_INPUT_DELAY_SAMPLES

__all__ = ["InputDelayChoice", "OneFrequencyCommandError", "choose_input_delay", "fits_by_delay", "one_frequency_hz",
           "ONE_FREQUENCY_SHARE", "MIN_PERIODS", "THIN_MARGIN_PERCENT"]

#: Share of a command's variance within a few periodogram bins of its strongest frequency at or above
#: which the command counts as one frequency. Measured on 120-s commands: a sine 0.998-1.000; a square
#: wave (``steps`` between two levels) 0.81; steps among five levels 0.45, random 0.61, a chirp 0.22.
ONE_FREQUENCY_SHARE = 0.9

#: Fewest periods of that frequency in the record: a single step's variance lies in the lowest bins
#: (0.95 of it for a step at 10 s of 120 s), a frequency the record holds less than 3 periods of.
MIN_PERIODS = 3

#: A lead of the best fit over the next smaller than this [% of fit] is reported as thin: on the
#: simulated rigs of benchmarks/input_delay_choice.py the rig's delay led by 0.03-1.0 %, and once by
#: 0.0005 % (a 0.4-s rig under random:seed=3, between 3 and 4 samples), all 50 chosen right.
THIN_MARGIN_PERCENT = 0.01

#: Half-width of the band of periodogram bins around the strongest one that counts as its frequency
#: (a window's leakage where a record holds a non-integer number of periods).
_BAND_BINS = 2


def one_frequency_hz(u: np.ndarray, ts_s: float) -> float | None:
    """The frequency [Hz] of a command that is one frequency (at least :data:`ONE_FREQUENCY_SHARE` of
    its variance within two periodogram bins of its strongest one, Hann window, and at least
    :data:`MIN_PERIODS` periods of it in the record), else None.

    Parameters
    ----------
    u : ndarray
        The command, one sample per period [V].
    ts_s : float
        Sampling period [s].
    """
    x = np.asarray(u, dtype=float)
    x = (x - x.mean()) * np.hanning(len(x))
    power = np.abs(np.fft.rfft(x)) ** 2
    power[0] = 0.0  # what is left of the mean after the window
    total = float(power.sum())
    if total == 0.0:
        return None
    k = int(np.argmax(power))  # periods of the strongest frequency in the record
    share = float(power[max(k - _BAND_BINS, 0):k + _BAND_BINS + 1].sum()) / total
    return k / (len(x) * ts_s) if k >= MIN_PERIODS and share >= ONE_FREQUENCY_SHARE else None


@dataclass(frozen=True)
class InputDelayChoice:
    """Result of :func:`choose_input_delay`."""

    input_delay_samples: int
    """The delay ``D`` [samples] whose model fits best one step ahead."""
    fits_percent: tuple[float, ...]
    """The 1-step fit [%] of the model identified under each ``D = 0, 1, ...`` (Table 4's NRMSE)."""
    scored_on: str
    """``"validation"`` (the fits are on the validation record) or ``"identification"``."""
    report: IdentificationReport
    """The identification under the chosen delay."""

    @property
    def margin_percent(self) -> float:
        """How much better [% of fit] the chosen delay fits than the next best (inf with one delay
        tried); below :data:`THIN_MARGIN_PERCENT` the record hardly tells the two apart."""
        rest = [f for d, f in enumerate(self.fits_percent) if d != self.input_delay_samples and np.isfinite(f)]
        return self.fits_percent[self.input_delay_samples] - max(rest) if rest else float("inf")

    @property
    def at_largest(self) -> bool:
        """The best fit is at the largest delay tried: the rig's delay may be larger still."""
        return self.input_delay_samples == len(self.fits_percent) - 1


class OneFrequencyCommandError(ValueError):
    """A record whose command is one frequency (:func:`one_frequency_hz`); ``record`` names which,
    ``"identification"`` or ``"validation"``."""

    def __init__(self, record: str, frequency_hz: float) -> None:
        super().__init__(f"the {record} record's command is one frequency (about {frequency_hz:.2g} Hz, a sine): "
                         "at one frequency a transport delay is a phase lag that Eq. (1)'s dynamics take up too, "
                         "so its fits cannot tell the delay; record a random, step or chirp command, or give the "
                         "delay yourself")
        self.record = record


def fits_by_delay(u_v: np.ndarray, l_mm: np.ndarray, *, ts_s: float,
                  validation: tuple[np.ndarray, np.ndarray] | None = None,
                  max_samples: int = MAX_INPUT_DELAY_SAMPLES,
                  **identify: Any) -> tuple[list[float], list[IdentificationReport]]:
    """The 1-step fits [%] (on ``validation`` if given, else on the identification record) of Eq. (1)
    identified under each input delay ``D = 0 .. max_samples``, and those identifications; the
    arguments as :func:`choose_input_delay`'s, whatever the command (no check of its frequencies)."""
    if isinstance(max_samples, bool) or not isinstance(max_samples, (int, np.integer)) \
            or not 0 <= max_samples <= MAX_INPUT_DELAY_SAMPLES:
        raise ValueError(f"max_samples must be an integer in 0..{MAX_INPUT_DELAY_SAMPLES}, got {max_samples!r}")
    if "input_delay_samples" in identify:
        raise ValueError("input_delay_samples is what choose_input_delay chooses; do not pass it")
    reports, fits = [], []
    for d in range(int(max_samples) + 1):
        report = identify_record(u_v, l_mm, ts_s=ts_s, input_delay_samples=d, **identify)
        fit = report.fit if validation is None else score_model(report.theta, report.structure, *validation,
                                                                input_delay_samples=d)
        reports.append(report)
        fits.append(fit.percent["1"])
    return fits, reports


def choose_input_delay(u_v: np.ndarray, l_mm: np.ndarray, *, ts_s: float,
                       validation: tuple[np.ndarray, np.ndarray] | None = None,
                       max_samples: int = MAX_INPUT_DELAY_SAMPLES, **identify: Any) -> InputDelayChoice:
    """Identify Eq. (1) under each input delay ``D = 0 .. max_samples`` and keep the best 1-step fit.

    Parameters
    ----------
    u_v, l_mm : ndarray
        Command [V] and displacement [mm] of the identification record, one sample per period.
    ts_s : float
        Sampling period [s].
    validation : (ndarray, ndarray), optional
        ``(u_v, l_mm)`` of a second record of the rig to score on (recommended); default the
        identification record itself.
    max_samples : int
        The largest delay tried [samples], 0 .. ``MAX_INPUT_DELAY_SAMPLES`` (5).
    **identify
        Keyword arguments of :func:`~fmu_controller.identification.identify_record` (``model``,
        ``box``, ``constraint_start_s``, ``p0``, ``forgetting``, ``theta0``), the same under each delay.

    Returns
    -------
    InputDelayChoice
        The delay, the fits under every delay and the identification under the chosen one.

    Raises
    ------
    OneFrequencyCommandError
        A command (of either record) that is one frequency (:func:`one_frequency_hz`): its fits cannot
        tell a delay.
    ValueError
        ``max_samples`` out of range; ``input_delay_samples`` among ``identify``; anything
        :func:`identify_record` refuses.
    """
    records = {"identification": u_v} | ({"validation": validation[0]} if validation is not None else {})
    for which, u in records.items():
        f_hz = one_frequency_hz(u, ts_s)
        if f_hz is not None:
            raise OneFrequencyCommandError(which, f_hz)
    fits, reports = fits_by_delay(u_v, l_mm, ts_s=ts_s, validation=validation, max_samples=max_samples, **identify)
    # a fit that is not a number (a diverged prediction) is the worst, not the best (argmax takes NaN)
    best = int(np.argmax([f if np.isfinite(f) else -np.inf for f in fits]))
    return InputDelayChoice(best, tuple(fits), "validation" if validation is not None else "identification",
                            reports[best])
