"""The controller's guards on the displacement reading, and what they tell.

A reading ``l(k)`` [mm] the muscle cannot have made is not given to the law and the estimator: a
jump beyond what the muscle moves in a sample (a sensor glitch), a one-sample spike far from the
one-step prediction, a stale repeat of the last sample while the prediction has the muscle move.
The one-step prediction is used instead (``ControllerSettings.max_speed_mm_per_s``;
docs/control.md, "Sensor glitches", "Stale readings"). A reading that does not change at all while
the valve is driven to both limits is reported as a stuck sensor, and used. The reading after a held
spike or repeat tells whether that one was the muscle's own (a supply lost, a load dropped): then it
is reported so, and the two guards wait a transient out. This module holds the
guards' thresholds, each with what it was measured on, and the messages the FMU logs and a closed
loop warns with.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Mapping

if TYPE_CHECKING:
    from .controller_settings import ControllerSettings

__all__ = ["L_RANGE_MM", "FASTEST_MUSCLE_MM_PER_S", "DEFAULT_MAX_SPEED_MM_PER_S", "HELD_READINGS_MAX",
           "SPIKE_MM", "SPIKE_SPREAD", "SPIKE_MEAN_CAP", "SPIKE_FORGET", "SPIKE_AFTER_S", "REPEAT_MOVE_MM",
           "REPEAT_SPREAD",
           "REF_STEP_SETTLE_S", "settle_samples", "STUCK_AT_LIMIT_S", "held_reading_message",
           "real_move_message", "stuck_reading_message", "ReadingGuard"]


#: Every contraction [mm] the plant FMU's parameter ranges allow (rest lengths up to 5000 mm, an
#: encoder offset of +-100 mm, stretch under the load): a reading ``l`` outside is refused (by the
#: controller FMU and :meth:`DisplacementController.step` alike), and its ``r`` inputs and built-in
#: sine stay within it.
L_RANGE_MM = (-1000.0, 5000.0)

#: The simulated rig's fastest move [mm/s]: from rest to 10 V and back at 0.25 MPa and 10-100 N.
FASTEST_MUSCLE_MM_PER_S = 200.0
#: Fastest the muscle moves [mm/s] as far as the glitch guard is concerned
#: (``ControllerSettings.max_speed_mm_per_s``): twice the simulated rig's fastest, room for a faster rig.
DEFAULT_MAX_SPEED_MM_PER_S = 2.0 * FASTEST_MUSCLE_MM_PER_S
#: Readings held in a row, at most, before one that stays as far from the last used is taken as the new
#: level (an encoder re-zeroed, a real step): a glitch lasts a sample or two.
HELD_READINGS_MAX = 3
#: From :data:`SPIKE_AFTER_S` after the start-up on, a reading further from the one-step prediction
#: than the larger of :data:`SPIKE_MM` and :data:`SPIKE_SPREAD` times the running mean |prediction
#: error| (weight :data:`SPIKE_FORGET` a sample: about 50 samples, 5 s at Ts = 0.1 s) is taken for a
#: one-sample spike of the sensor (a potentiometer's wiper lifting, an ADC's bad conversion) where the
#: two readings before came within half that (a loop whose errors swing already is not told from a
#: spike): the prediction is used instead, once. Without it a spike
#: under the max_speed bound (40 mm) is used as a reading, and one 30 mm low moves the muscle by 36-40
#: mm. The guard waits :data:`REF_STEP_SETTLE_S` after the preview moves by more than
#: :data:`SPIKE_MM` in a sample (a step: the fixed predictors miss by 7.5 mm in its transient, which
#: starts as the step enters the preview), and as long after a reading as far off follows a held one
#: (a model that predicts badly just then). On 68 runs without spikes (the paper's cells, load steps,
#: staircases, delayed rigs, 0.5-mm sensor noise, rigs with constants off) it holds none.
SPIKE_MM = 5.0
SPIKE_SPREAD = 10.0
#: An error counts in the spike guard's running mean as at most this many times the mean (or half
#: :data:`SPIKE_MM`, where that is more), so that the mean stays the ordinary error's: a spike of 30 mm
#: every 2 s, counted whole, had raised it to 4-5 mm and the limit to 40-55 mm, and no spike was
#: held. A lasting rise of the error is followed within seconds (the mean can grow by 8 % a sample);
#: of the ordinary errors 0-0.9 % exceed 5 times their mean (the paper's cells, 120 s), which lowers
#: the mean by at most 3 %.
SPIKE_MEAN_CAP = 5.0
SPIKE_FORGET = 0.02
SPIKE_AFTER_S = 5.0
#: A reading equal to the last one, to the bit, where the one-step prediction has the muscle move by
#: more than the larger of :data:`REPEAT_MOVE_MM` and :data:`REPEAT_SPREAD` times the running mean
#: |prediction error| (the spike guard's), is taken for a stale sample (a data acquisition that
#: delivered the last value again): the prediction is used instead, for the first repeat only (a
#: muscle that stopped, at an end stop or on a shut supply, reads the same again, and that reading is
#: used). An encoder read with noise never repeats to the bit while the muscle moves a millimetre in a
#: sample; without the guard one repeat at the fastest point of the paper's sine (1.9 mm a sample)
#: made the law push the valve for a move that had happened (docs/control.md, "Stale readings"). The
#: same gates as the spike guard's (from :data:`SPIKE_AFTER_S` after the start-up). The threshold sits
#: between the misses measured at a stale repeat (4.3-5.4 times the fixed predictors' mean error) and
#: those of a muscle that really stopped short (backlash, a swinging loop, a poor predictor: 3.4-3.9
#: times).
REPEAT_MOVE_MM = 1.0
REPEAT_SPREAD = 4.0
#: The first seconds after a reference step are its transient: the spike guard waits them out, and the
#: loop's watch does not count their swings.
REF_STEP_SETTLE_S = 3.0


def settle_samples(ts_s: float) -> int:
    """:data:`REF_STEP_SETTLE_S` in samples of ``ts_s`` [s].

    Parameters
    ----------
    ts_s : float
        Sampling period [s].
    """
    return int(round(REF_STEP_SETTLE_S / ts_s))


#: Seconds the command sits at each of the valve's limits, within one stretch of readings that have not
#: changed at all, that tell a stuck sensor: the valve held open, then shut (or the other way round),
#: moves a working muscle by millimetres within a second, whatever its transport delay (at most 0.5 s
#: here) or end stop; the encoder resolves 0.01 mm (:attr:`DisplacementController.reading_stuck`).
STUCK_AT_LIMIT_S = 2.0


def held_reading_message(settings: ControllerSettings, reading_mm: float, used_mm: float, last_mm: float,
                         spike_mm: float | None) -> str:
    """What to tell of a reading :attr:`DisplacementController.reading_held` reports (without the time):
    the ``reading_mm`` [mm], the prediction ``used_mm`` instead, the last reading used ``last_mm``, and
    ``spike_mm``, its :attr:`~DisplacementController.spike_limit_mm` (None: a jump beyond ``max_speed``,
    or, where the reading is ``last_mm`` itself, a stale repeat: :data:`REPEAT_MOVE_MM`).

    Parameters
    ----------
    settings : ControllerSettings
        The controller's settings (``max_speed_mm_per_s`` [mm/s] and ``ts_s`` [s] for a jump's
        message).
    reading_mm : float
        The reading held [mm].
    used_mm : float
        The one-step prediction used instead [mm].
    last_mm : float
        The last reading used [mm].
    spike_mm : float or None
        The spike limit [mm] for a one-sample spike, or None for a jump beyond ``max_speed`` or a
        stale repeat.
    """
    if spike_mm is None and reading_mm == last_mm:
        return (f"the reading l = {reading_mm:g} mm repeats the last one to the bit while the one-step prediction has "
                f"the muscle move {abs(used_mm - last_mm):.3g} mm (more than {REPEAT_MOVE_MM:g} mm and "
                f"{REPEAT_SPREAD:g} times the mean error): taken for a stale sample of the data acquisition, the law "
                f"and the estimator used the prediction {used_mm:.4g} mm instead (a second repeat is used, as a "
                "muscle that stopped; max_speed = 0 turns this off)")
    if spike_mm is not None:
        return (f"the reading l = {reading_mm:g} mm is {abs(reading_mm - used_mm):.3g} mm from the one-step prediction "
                f"{used_mm:.4g} mm, more than the {spike_mm:.3g} mm it has lately come within (the larger of "
                f"{SPIKE_MM:g} mm and {SPIKE_SPREAD:g} times the mean error): taken for a one-sample spike of the sensor, "
                "the law and the estimator used the prediction instead (the next reading is not held as a spike; "
                "max_speed = 0 turns this off)")
    s = settings
    return (f"the reading l = {reading_mm:g} mm is {abs(reading_mm - last_mm):.3g} mm from the last one used, more than "
            f"the muscle moves in a sample (max_speed x Ts = {s.max_speed_mm_per_s:g} x {s.ts_s:g} = "
            f"{s.max_speed_mm_per_s * s.ts_s:g} mm): taken for a sensor glitch, the law and the estimator used the "
            f"prediction {used_mm:.4g} mm instead (after {HELD_READINGS_MAX} in a row the reading is taken as the new "
            "level; max_speed = 0 turns this off)")


def real_move_message(kind: str, held_mm: float, reading_mm: float, predicted_mm: float) -> str:
    """What to tell of a held reading that :attr:`DisplacementController.held_reading_real` found the
    muscle's own (without the times).

    Parameters
    ----------
    kind : {"spike", "repeat"}
        What the reading was held as: a one-sample spike, a stale repeat.
    held_mm : float
        The reading held one sample before [mm].
    reading_mm : float
        This sample's reading [mm].
    predicted_mm : float
        This sample's one-step prediction [mm] (from the value used instead of the held one).
    """
    what = "a one-sample spike of the sensor" if kind == "spike" else "a stale sample of the data acquisition"
    return (f"the reading held one sample before as {what}, l = {held_mm:g} mm, was the muscle's own: this one, "
            f"{reading_mm:g} mm, lies {abs(reading_mm - held_mm):.3g} mm from it and {abs(reading_mm - predicted_mm):.3g} "
            f"mm from the one-step prediction {predicted_mm:.4g} mm. The muscle moved or stopped as its model does not "
            "have it (a supply lost or back, a load dropped, a stop reached?), or the sensor's fault lasts (a spike or "
            f"repeat of two samples or more); the spike and repeat guards hold no reading for {REF_STEP_SETTLE_S:g} s")


def stuck_reading_message(t_s: float, reading_mm: float, unchanged_s: float) -> str:
    """What to tell of a reading :attr:`DisplacementController.reading_stuck` reported at ``t_s`` [s]:
    ``reading_mm`` [mm], unchanged for ``unchanged_s`` [s].

    Parameters
    ----------
    t_s : float
        Time of the report [s].
    reading_mm : float
        The stuck reading [mm].
    unchanged_s : float
        How long it has not changed [s].
    """
    return (f"t = {t_s:.12g} s: the reading l = {reading_mm:g} mm has not changed at all for {unchanged_s:.4g} s while "
            f"the command sat at each of the valve's limits for {STUCK_AT_LIMIT_S:g} s or more, which moves a working "
            "muscle by millimetres: the sensor is stuck or disconnected (a DAQ holding its last value?), or the supply "
            "is shut with the muscle at rest. The controller goes on with the reading")


#: The spike guard's state at the start: the running mean |one-step prediction error| [mm], the last
#: reading's |error| [mm] (NaN: none yet), the sample the guard acts from (after a reference step's
#: transient), the preview's last sample at the last step [mm], the |error| of the reading before the
#: last [mm].
_NEW_SPIKE_GUARD = (math.nan, math.nan, 0, math.nan, math.nan)


def _valid_spike_guard(spike: Any) -> bool:
    """Whether ``spike`` is a spike guard's state (``_NEW_SPIKE_GUARD``'s fields) a controller could save."""
    if not isinstance(spike, (list, tuple)) or len(spike) != 5:
        return False
    try:
        mean, last, acts_from, r, earlier = (float(spike[0]), float(spike[1]), spike[2], float(spike[3]),
                                             float(spike[4]))
    except (TypeError, ValueError):
        return False
    errors_ok = all(x != x or 0.0 <= x < math.inf for x in (mean, last, earlier))
    whole = not isinstance(acts_from, bool) and isinstance(acts_from, (int, float)) and int(acts_from) == acts_from >= 0
    return errors_ok and whole and (r != r or math.isfinite(r))


def _valid_still(still: Any) -> bool:
    """Whether ``still`` is a stretch of identical readings that :meth:`DisplacementController.get_state`
    could have saved: ``[reading or NaN, samples, samples after the lower limit, after the upper, said]``."""
    try:
        if not isinstance(still, (list, tuple)) or len(still) != 5 or still[4] not in (True, False):
            return False
        reading, counts = float(still[0]), still[1:4]
        if any(isinstance(n, bool) or int(n) != n or int(n) < 0 for n in counts):
            return False
        return ((math.isnan(reading) or L_RANGE_MM[0] <= reading <= L_RANGE_MM[1])
                and int(counts[1]) + int(counts[2]) <= int(counts[0]))
    except (TypeError, ValueError, OverflowError):
        return False


def _valid_last_held(last: Any) -> bool:
    """Whether ``last`` is a held spike or repeat :meth:`ReadingGuard.get_state` could have saved:
    ``[kind, sample, reading]``."""
    try:
        if not isinstance(last, (list, tuple)) or len(last) != 3 or last[0] not in ("spike", "repeat"):
            return False
        k, reading = last[1], float(last[2])
        return (not isinstance(k, bool) and int(k) == k and int(k) >= 0
                and L_RANGE_MM[0] <= reading <= L_RANGE_MM[1])
    except (TypeError, ValueError, OverflowError):
        return False


class ReadingGuard:
    """The guards on one controller's readings ``l(k)`` [mm]: a glitch (a jump beyond what the muscle
    moves in a sample), a one-sample spike (:data:`SPIKE_MM`), a stale repeat (:data:`REPEAT_MOVE_MM`),
    each replaced by the one-step prediction; and the watch for a stuck sensor
    (:data:`STUCK_AT_LIMIT_S`), which only reports. After :meth:`check`, :attr:`reading_held`,
    :attr:`spike_limit_mm`, :attr:`held_reading_real` and :attr:`reading_stuck` say what it found at
    that sample.

    Parameters
    ----------
    max_jump_mm : float
        The most the muscle moves in a sample [mm], ``max_speed_mm_per_s * ts_s``; 0: every reading used
        (the stuck-sensor watch stays).
    ts_s : float
        Sampling period [s].
    preview_samples : int
        The reference samples the law takes, ``r(k..k+n-1)``: a step that enters the preview's last one
        is acted on from then, and the spike guard waits its transient out from there.
    u_min_v, u_max_v : float
        The law's valve limits [V] (Eq. (19)), for the stuck-sensor watch.
    """

    def __init__(self, max_jump_mm: float, ts_s: float, preview_samples: int, u_min_v: float, u_max_v: float) -> None:
        self._max_jump = max_jump_mm
        self._ts = ts_s
        self._need = preview_samples
        self._u_min, self._u_max = u_min_v, u_max_v
        self._stuck_n = max(1, int(math.ceil(STUCK_AT_LIMIT_S / ts_s - 1e-9)))
        #: The samples after the guards' start (the estimator's, plus the start-up) they wait
        #: (:data:`SPIKE_AFTER_S`).
        self.after_samples = int(round(SPIKE_AFTER_S / ts_s))
        self.reset()

    def reset(self) -> None:
        """Start over: no reading seen."""
        self._held_in_a_row = 0  # readings the glitch guard held in a row
        self._spike = list(_NEW_SPIKE_GUARD)
        # the stretch of identical readings: its reading (NaN before the first), its samples, the
        # samples of it that followed a command at the lower and at the upper valve limit, and whether
        # reading_stuck has said it
        self._still = [math.nan, 0, 0, 0, False]
        self._last_held: list[Any] | None = None  # the spike or repeat held: [kind, its sample, its reading]
        self.reading_held: tuple[float, float, float] | None = None
        """The last step's reading taken for a glitch, a spike or a stale repeat (then equal to the last
        one used), the value used instead and the last one used before [mm]; None where the reading
        was used."""
        self.spike_limit_mm: float | None = None
        """Where :attr:`reading_held` is a one-sample spike (further from the prediction than
        :data:`SPIKE_MM` and :data:`SPIKE_SPREAD` times the usual error), the distance it exceeded [mm];
        None where it is a jump beyond ``max_speed_mm_per_s`` or no reading was held."""
        self.held_reading_real: tuple[str, float, float, float] | None = None
        """On the step after a reading was held as a one-sample spike or a stale repeat, where this
        reading lies nearer the held one than its own one-step prediction (the muscle itself moved or
        stopped: a supply lost or back, a load dropped): what it was held as (``"spike"``,
        ``"repeat"``), the held reading, this reading and the prediction [mm]. The spike and repeat
        guards then hold no reading for :data:`REF_STEP_SETTLE_S`. None otherwise."""
        self.reading_stuck: tuple[float, float] | None = None
        """On the step that tells it, once a stretch: the reading [mm] that has not changed at all
        while the command sat at each of the valve's limits for :data:`STUCK_AT_LIMIT_S` or more, and
        how long it has not changed [s] (a stuck or disconnected sensor, a DAQ holding its last value,
        or the supply shut with the muscle at rest); None otherwise. The law goes on with the reading."""

    def check(self, l: float, k: int, predicted: float, last_l: float, l_prev: float, r_last: float, u_last: float,
              guarded: bool) -> float:
        """The reading to use at sample ``k`` for the measured ``l`` [mm].

        Parameters
        ----------
        l : float
            The reading ``l(k)`` [mm].
        k : int
            The sample.
        predicted : float
            The one-step prediction ``l(k|k-1)`` [mm] (NaN before the first).
        last_l, l_prev : float
            The last two readings used, ``l(k-1)`` and ``l(k-2)`` [mm].
        r_last : float
            The preview's last sample [mm] (a step entering it pauses the spike guard).
        u_last : float
            The command that followed the last reading [V].
        guarded : bool
            Whether the spike and repeat guards act at this sample (a prediction to use, the start-up
            and :attr:`after_samples` after it over).
        """
        self.reading_held = None
        self.reading_stuck = None
        self._judge_last_held(l, k, predicted)
        still = self._still
        if l == still[0]:
            self._watch_still(u_last)
        else:
            still[:] = [l, 0, 0, 0, False]
        self.spike_limit_mm = None
        if not (self._max_jump and k > 0):
            return l
        if abs(l - last_l) <= self._max_jump:
            self._held_in_a_row = 0
            if still[1] == 1 and l == last_l and self._stale(l, k, predicted, guarded):
                self.reading_held = (l, predicted, last_l)
                self._last_held = ["repeat", k, l]
                return predicted
            return self._spike_guard(l, k, predicted, last_l, r_last, guarded)
        spike = self._spike
        if self._held_in_a_row >= HELD_READINGS_MAX or (
                not self._held_in_a_row and abs(l - l_prev) <= self._max_jump
                and spike[1] > min(self._spike_limit(), max(SPIKE_MM, abs(l - l_prev)))):
            # the new level; or, after a used reading that was far from its prediction (beyond the spike
            # limit, or further than this reading lies from the one before it), within reach of the
            # reading before it: that one was a spike under the bound, and the readings after it are the
            # muscle's. The model's state has jumped: its predictions are no guide for a while
            self._held_in_a_row = 0
            spike[1], spike[4] = abs(l - predicted) if math.isfinite(predicted) else math.nan, spike[1]
            spike[2], spike[3] = k + settle_samples(self._ts), r_last
            return l
        # further than the muscle moves in a sample: a glitch, the prediction used instead
        self._held_in_a_row += 1
        used = predicted if math.isfinite(predicted) else last_l
        self.reading_held = (l, used, last_l)
        return used

    def _judge_last_held(self, l: float, k: int, predicted: float) -> None:
        """Whether the spike or repeat held at sample ``k - 1`` was the muscle's own: the reading ``l``
        [mm] lies nearer it than the prediction ``predicted`` [mm] made from the value used instead.
        A sensor's spike or a stale sample leaves the muscle on the model's track, so the next reading
        comes back to it; a supply lost, a load dropped or a stop reached moves the muscle off it."""
        last, self._last_held = self._last_held, None
        self.held_reading_real = None
        if last is None or last[1] != k - 1 or not math.isfinite(predicted):
            return
        kind, _, held = last
        if abs(l - held) < abs(l - predicted):
            self.held_reading_real = (kind, held, l, predicted)
            # the model misses what the muscle does now: its predictions are no measure of a spike or a
            # stale sample until a transient is over
            self._spike[2] = max(self._spike[2], k + settle_samples(self._ts))

    def _spike_limit(self) -> float:
        """How far [mm] a reading may lie from its one-step prediction before it is a spike: the larger of
        :data:`SPIKE_MM` and :data:`SPIKE_SPREAD` times the running mean error (inf before one)."""
        mean = self._spike[0]
        return max(SPIKE_MM, SPIKE_SPREAD * mean) if mean == mean else math.inf

    def _stale(self, l: float, k: int, predicted: float, guarded: bool) -> bool:
        """Whether ``l`` [mm], a reading equal to the last one used, is a stale sample: the prediction
        has the muscle move further than :data:`REPEAT_MOVE_MM` and :data:`REPEAT_SPREAD` times the
        running mean prediction error."""
        mean = self._spike[0]
        # not in a reference step's transient either, where a muscle held by its friction stops short of
        # a prediction that misses by a millimetre (the spike guard's wait, spike[2])
        return (guarded and mean == mean and k >= self._spike[2]
                and abs(predicted - l) > max(REPEAT_MOVE_MM, REPEAT_SPREAD * mean))

    def _spike_guard(self, l: float, k: int, predicted: float, last_l: float, r: float, guarded: bool) -> float:
        """The reading ``l`` [mm] to use: the one-step prediction where ``l`` is a one-sample spike
        (:data:`SPIKE_MM`; ``r``: the preview's last sample [mm], whose steps pause the guard from when
        the law first sees them), else ``l``, the running mean of the prediction errors updated with it."""
        spike = self._spike
        ts = self._ts
        if abs(r - spike[3]) > SPIKE_MM:  # a step at the preview's end: the law acts on it now
            spike[2] = k + self._need + settle_samples(ts)
        spike[3] = r
        if not math.isfinite(predicted):
            return l
        error = abs(l - predicted)
        limit = self._spike_limit()
        before = spike[1]
        # a reading after two ordinary ones (within half the limit); not in the start-up, whose estimate is
        # still learning (an open-loop theta0 at 0.3 MPa missed by 60 mm there), nor in the seconds after
        # it; and the prediction used instead must itself be a reading the muscle could give
        if (error > limit and before <= 0.5 * limit and spike[4] <= 0.5 * limit and k >= spike[2] and guarded
                and abs(predicted - last_l) <= self._max_jump):
            spike[1], spike[4] = error, before
            self.spike_limit_mm = limit
            self.reading_held = (l, predicted, last_l)
            self._last_held = ["spike", k, l]
            return predicted
        if before > limit and error > limit:
            # a reading as far off after a held (or far-off) one: no spike but a model that predicts this
            # badly now; the guard waits a transient out and takes the error in whole
            spike[2] = k + settle_samples(ts)
            limit = error
        spike[1], spike[4] = error, before
        # an error counts as at most SPIKE_MEAN_CAP times the mean (or half SPIKE_MM): spikes, even every
        # few seconds, and a transient do not blunt the guard
        mean = spike[0]
        spike[0] = error if mean != mean else mean + SPIKE_FORGET * (
            min(error, limit, max(0.5 * SPIKE_MM, SPIKE_MEAN_CAP * mean)) - mean)
        return l

    def _watch_still(self, u_last: float) -> None:
        """Count a reading equal to the last one: after a command ``u_last`` [V] at a valve limit, towards
        that limit's time; set :attr:`reading_stuck` when both reach :data:`STUCK_AT_LIMIT_S`."""
        still = self._still
        still[1] += 1
        if u_last <= self._u_min + 1e-9:
            still[2] += 1
        elif u_last >= self._u_max - 1e-9:
            still[3] += 1
        if not still[4] and still[2] >= self._stuck_n and still[3] >= self._stuck_n:
            still[4] = True
            self.reading_stuck = (still[0], still[1] * self._ts)

    def get_state(self) -> dict[str, Any]:
        """The guards' state as plain data: ``held_in_a_row``, ``still``, ``spike``, ``last_held``."""
        return {"held_in_a_row": self._held_in_a_row, "still": list(self._still), "spike": list(self._spike),
                "last_held": None if self._last_held is None else list(self._last_held)}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore what :meth:`get_state` returned; a field left out starts anew (a state saved
        without that guard).

        Raises
        ------
        ValueError
            A field no guard could have saved, named; nothing is changed then.
        """
        held = state.get("held_in_a_row", 0)
        if isinstance(held, bool) or int(held) != held or not 0 <= held <= HELD_READINGS_MAX:
            raise ValueError(f"state field held_in_a_row = {held!r} must be a count 0 .. {HELD_READINGS_MAX}")
        still = state.get("still", [math.nan, 0, 0, 0, False])
        if not _valid_still(still):
            raise ValueError(f"state field still = {still!r} must be [reading within {L_RANGE_MM[0]:g}..{L_RANGE_MM[1]:g} "
                             "mm or NaN, samples >= 0, samples after the lower limit and after the upper one (together "
                             "at most the samples), said true/false]")
        spike = state.get("spike", _NEW_SPIKE_GUARD)
        if not _valid_spike_guard(spike):
            raise ValueError(f"state field spike = {spike!r} must be [mean |prediction error| >= 0 mm or NaN, the last "
                             "reading's |error| >= 0 mm or NaN, the sample the guard acts from >= 0, the preview's last "
                             "sample (finite) or NaN, the |error| before >= 0 mm or NaN]")
        last_held = state.get("last_held")
        if last_held is not None and not _valid_last_held(last_held):
            raise ValueError(f"state field last_held = {last_held!r} must be null or ['spike' or 'repeat', the sample "
                             f"(>= 0), the reading held (within {L_RANGE_MM[0]:g}..{L_RANGE_MM[1]:g} mm)]")
        self._held_in_a_row = int(held)
        self._last_held = None if last_held is None else [last_held[0], int(last_held[1]), float(last_held[2])]
        self._still = [float(still[0]), int(still[1]), int(still[2]), int(still[3]), bool(still[4])]
        self._spike = [float(spike[0]), float(spike[1]), int(spike[2]), float(spike[3]), float(spike[4])]
