"""The controller's guards on the displacement reading, and what they tell.

A reading ``l(k)`` [mm] the muscle cannot have made is not given to the law and the estimator: a
jump beyond what the muscle moves in a sample (a sensor glitch), a one-sample spike far from the
one-step prediction, a stale repeat of the last sample while the prediction has the muscle move.
The one-step prediction is used instead (``ControllerSettings.max_speed_mm_per_s``;
docs/control.md, "Sensor glitches", "Stale readings"). A reading that does not change at all while
the valve is driven to both limits is reported as a stuck sensor, and used. This module holds the
guards' thresholds, each with what it was measured on, and the messages the FMU logs and a closed
loop warns with.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .controller_settings import ControllerSettings

__all__ = ["L_RANGE_MM", "FASTEST_MUSCLE_MM_PER_S", "DEFAULT_MAX_SPEED_MM_PER_S", "HELD_READINGS_MAX",
           "SPIKE_MM", "SPIKE_SPREAD", "SPIKE_FORGET", "SPIKE_AFTER_S", "REPEAT_MOVE_MM", "REPEAT_SPREAD",
           "REF_STEP_SETTLE_S", "settle_samples", "STUCK_AT_LIMIT_S", "held_reading_message",
           "stuck_reading_message"]


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
