"""What in a rig's recording of the muscle would make its diagnosis meaningless, checked before any
simulation runs: a command outside the valve's range, a displacement beyond the muscle's length or a
sampling period no muscle recording has, or a displacement that barely moves where the nominal model
moves a lot (metres logged as millimetres; refused), and a start away from rest, jittered timestamps,
a pressure column in another unit or a displacement that spans a few times more or less than the
model's (centimetres as millimetres) (said, in the report's notes). An importer also says what looks
like a sensor's fault: a jump faster than the muscle moves, a reading clipped at its range, a wrap.

A real rig's log differs from `tapmuscle record`'s in ways that leave every column a finite number
and yet make the diagnosis compare the wrong things: a command logged in percent, times in
milliseconds, pressure in kPa, an encoder zeroed elsewhere, a log started mid-run. The recording
format (docs/recordings.md) fixes the units; these checks name a value that cannot be in them.
"""

from __future__ import annotations

import numpy as np

from fmu_plant.plant import COMMAND_RANGE_V
from tapmuscle.errors import TapmuscleError
from tapmuscle.io.rig_log import STANDARD_GRAVITY
from tapmuscle.io.sampling import TS_RANGE_S, check_sampling_period, uniform_sampling

__all__ = ["RecordingCheckError", "check_muscle_recording", "check_pressure_scale", "check_sampling_period",
           "muscle_recording_notes", "check_displacement_scale", "COMMAND_RANGE_V",
           "TS_RANGE_S", "DISPLACEMENT_PLAUSIBLE_MM", "SPAN_RATIO_PLAUSIBLE", "AT_REST_MM", "DRAINED_MPA",
           "AMBIENT_MPA_RANGE", "PRESSURE_PLAUSIBLE_MPA", "LOAD_PLAUSIBLE_N", "LOAD_KG_NOTED_N", "LOAD_RANGE_N",
           "displacement_scale_note",
           "SPAN_RATIO_NOTED", "SPAN_NOTED_MIN_MM", "JUMP_MM_PER_S", "HELD_S", "displacement_fault_notes"]

#: No reading of the 400-mm muscle's contraction lies further than this from 0 [mm]: its length and
#: an encoder zeroed anywhere in its stroke (``sensor_drift.offset_mm``'s 100-mm bound); beyond: µm?
DISPLACEMENT_PLAUSIBLE_MM = 500.0
#: A recorded displacement whose span is below this fraction of the nominal model's for the same
#: command is in another unit (metres: a thousandth), not a rig a few tens of percent off.
SPAN_RATIO_PLAUSIBLE = 0.05
#: A recorded displacement whose span is this many times below or above the nominal model's for the
#: same command is noted: a rig a few tens of percent off its constants stays well within it, a
#: length in centimetres read as millimetres (a tenth) does not.
SPAN_RATIO_NOTED = 3.0
#: Spans compared so only where the nominal model moves at least this much [mm]: a command that
#: barely crosses the threshold pressure moves it a few millimetres, which any offset doubles.
SPAN_NOTED_MIN_MM = 10.0
#: No reading of the muscle moves faster than this [mm/s]: the nominal muscle's fastest, a full
#: 0->10 V step, is about 200 mm/s; a faster step between two samples is a sensor's jump.
JUMP_MM_PER_S = 500.0
#: Jumps whose sizes are all within this fraction of their median are one wrap repeated: the
#: modulus less the muscle's motion in that sample.
WRAP_TOLERANCE = 0.15
#: A reading held exactly (to the bit) for this long [s], entered at speed, is a sensor's: a muscle
#: slows down before it stops, and its noise moves the last digit.
HELD_S = 0.5
#: The speed [mm/s] at which a held reading must be entered to count, and the least step [mm] (five
#: 0.01-mm encoder counts): a muscle coming to rest under a steady command creeps to its level, its
#: last steps a count or two.
HELD_ENTRY_MM_PER_S = 5.0
#: A held (stuck or clipped) reading is told only at sampling periods up to this [s]: sampled once a
#: second, a muscle stepped from rest settles within a sample, and a noise-free log holds its reading
#: exactly.
HELD_TS_MAX_S = 0.2
HELD_ENTRY_MIN_MM = 0.05
#: A first reading further than this from 0 [mm] is not a muscle at rest with its encoder zeroed there.
AT_REST_MM = 0.5
#: A first pressure above this [MPa(G)] is not a drained muscle.
DRAINED_MPA = 0.02
#: The atmosphere's pressure [MPa(A)]: 0.101 MPa at sea level (weather moves it by a few kPa), 0.062 MPa
#: at 4000 m. A drained muscle reads this on an absolute sensor, 0 on the gauge sensor the recording
#: format asks for.
AMBIENT_MPA_RANGE = (0.06, 0.11)
#: A tap-water rig's muscle pressure stays below this [MPa(G)]; above: another unit (kPa?). Mains water
#: reaches a building at 0.2-0.6 MPa (the rig's supply is 0.25 MPa), and the domestic pipes and fittings
#: a muscle is fed through are rated to 1 MPa (PN 10): 2 MPa is twice what any tap can give, while a
#: supply of 0.25 MPa logged in kPa, psi or bar and read as MPa is 250, 36 or 2.5.
PRESSURE_PLAUSIBLE_MPA = 2.0
#: A hanging load that never reaches this [N] but is not zero is in another unit (kN: 0.044 for 44 N).
LOAD_PLAUSIBLE_N = 1.0
#: A hanging load below this [N] whose weight, read as a mass in kg, lies within :data:`LOAD_RANGE_N`
#: is noted: a mass logged in kg (4.49 for 44 N), which the diagnosis would take for a light load.
LOAD_KG_NOTED_N = 15.0
#: The loads a muscle of this kind lifts [N]: the paper's 44 and 68 N, and about half to twice them.
LOAD_RANGE_N = (20.0, 150.0)


class RecordingCheckError(TapmuscleError):
    """A recorded value no muscle recording has (a unit mistake), at one sample.

    Attributes
    ----------
    column : str
        The recording's column (``u_v``, ``l_mm``, ``p_mpa``).
    sample : int
        The sample's index (a file's line: ``Recording.lines[sample]``).
    detail : str
        What is wrong with it, and what to check; the message is ``column C, sample K: detail``.
    finding : str
        What is wrong with it alone (``detail`` without the remedy), for a caller that knows a
        better one (an importer names the ``COLUMN:UNIT`` that fits).
    """

    def __init__(self, column: str, sample: int, detail: str, remedy: str = "") -> None:
        super().__init__(f"column {column}, sample {sample}: {detail}{remedy}")
        self.column, self.sample, self.detail, self.finding = column, sample, detail + remedy, detail


def check_muscle_recording(u_v: np.ndarray, ts_s: float, l_mm: np.ndarray | None = None,
                           p_fitted_mpa: np.ndarray | None = None) -> None:
    """Refuse a command outside :data:`COMMAND_RANGE_V`, a period outside :data:`TS_RANGE_S`, a
    displacement ``l_mm`` beyond :data:`DISPLACEMENT_PLAUSIBLE_MM`, or a pressure that the fits weigh
    (``p_fitted_mpa``: ``diagnose(use_pressure=True)``) above :data:`PRESSURE_PLAUSIBLE_MPA`.

    Parameters
    ----------
    u_v : ndarray
        Command [V].
    ts_s : float
        Sampling period [s].
    l_mm : ndarray, optional
        Displacement [mm].
    p_fitted_mpa : ndarray, optional
        Pressure [MPa(G)], when the fits weigh it.

    Raises
    ------
    RecordingCheckError
        Naming the first sample outside the range (and its value).
    ValueError
        Naming the period.
    """
    lo, hi = COMMAND_RANGE_V
    bad = np.nonzero((u_v < lo) | (u_v > hi))[0]
    if bad.size:
        k = int(bad[0])
        raise RecordingCheckError("u_v", k, f"{float(u_v[k]):g} V is outside the -1..11 V the plant takes (the "
                                  f"valve's 0..10 V command; {bad.size} samples are outside, range {float(np.min(u_v)):g}.."
                                  f"{float(np.max(u_v)):g})", ": is the command logged in another unit (percent, mV)? "
                                  "Scale it to volts")
    check_sampling_period(ts_s)
    if l_mm is not None:
        far = np.nonzero(np.abs(l_mm) > DISPLACEMENT_PLAUSIBLE_MM)[0]
        if far.size:
            k = int(far[0])
            raise RecordingCheckError("l_mm", k, f"{float(l_mm[k]):g} mm is further from 0 than the muscle's "
                                      f"{DISPLACEMENT_PLAUSIBLE_MM:g} mm (its 400-mm length and an encoder zeroed anywhere in "
                                      f"its stroke; {far.size} samples are, range {float(np.min(l_mm)):g}.."
                                      f"{float(np.max(l_mm)):g})", ": is the displacement logged in another unit "
                                      "(micrometres)? Scale it to millimetres")
    if p_fitted_mpa is not None:
        high = np.nonzero(p_fitted_mpa > PRESSURE_PLAUSIBLE_MPA)[0]
        if high.size:
            k = int(high[0])
            raise RecordingCheckError("p_mpa", k, f"{float(p_fitted_mpa[k]):g} MPa is far above a tap-water rig's "
                                      f"(supply 0.25 MPa; {high.size} samples above {PRESSURE_PLAUSIBLE_MPA:g} MPa), and "
                                      "with --use-pressure the fits weigh it: is it logged in kPa? Scale it to MPa")


def check_pressure_scale(p_mpa: np.ndarray) -> None:
    """Refuse a pressure [MPa(G)] above :data:`PRESSURE_PLAUSIBLE_MPA`, which no tap-water rig has: a
    column in another unit (kPa declared as MPa).

    Parameters
    ----------
    p_mpa : ndarray
        Pressure [MPa(G)].

    Raises
    ------
    RecordingCheckError
        Naming the sample of the largest pressure, its value and how many samples are above the bound.
    """
    p = np.asarray(p_mpa, dtype=float)
    if not p.size or float(np.max(p)) <= PRESSURE_PLAUSIBLE_MPA:
        return
    k = int(np.argmax(p))
    above = int(np.count_nonzero(p > PRESSURE_PLAUSIBLE_MPA))
    raise RecordingCheckError("p_mpa", k, f"{float(p[k]):g} MPa, the largest pressure, is no tap-water rig's (mains "
                                          f"water is at most about 1 MPa, the rig's supply 0.25 MPa; {above} samples "
                                          f"above {PRESSURE_PLAUSIBLE_MPA:g} MPa): is it logged in another unit (kPa)? "
                                          "Scale it to MPa")


def muscle_recording_notes(t_s: np.ndarray, l_mm: np.ndarray, p_mpa: np.ndarray | None, *,
                           load_n: np.ndarray | float | None = None) -> list[str]:
    """What the report should say about the recording before its findings (empty: nothing).

    * the first reading away from rest (the model starts drained at ``l = 0``);
    * a pressure that starts at the atmosphere's (:data:`AMBIENT_MPA_RANGE`) with the muscle at rest
      and never drains below it: an absolute sensor's;
    * timestamps that scatter about the uniform grid (taken as on it);
    * a pressure column beyond :data:`PRESSURE_PLAUSIBLE_MPA` (another unit);
    * a load ``load_n`` [N] that is not zero but never reaches :data:`LOAD_PLAUSIBLE_N` (kN?), or
      stays below :data:`LOAD_KG_NOTED_N` where its value in kg would weigh a load the muscle lifts
      (:data:`LOAD_RANGE_N`; a mass in kg?).

    Parameters
    ----------
    t_s : ndarray
        Time [s].
    l_mm : ndarray
        Displacement [mm].
    p_mpa : ndarray or None
        Pressure [MPa(G)], if recorded.
    load_n : ndarray or float, optional
        Load [N], if known.
    """
    notes = []
    l0 = float(l_mm[0])
    p0 = None if p_mpa is None else float(p_mpa[0])
    absolute = (p0 is not None and abs(l0) <= AT_REST_MM and AMBIENT_MPA_RANGE[0] <= p0 <= AMBIENT_MPA_RANGE[1]
                and float(np.min(p_mpa)) >= p0 - DRAINED_MPA)
    if absolute:
        notes.append(f"Column p_mpa starts at {p0:g} MPa with the muscle at rest (l = {l0:g} mm) and never falls "
                     f"below {float(np.min(p_mpa)):g} MPa, where a drained muscle reads 0 MPa(G): an absolute "
                     "pressure (the atmosphere's is about 0.1 MPa), or a run started mid-stroke with the encoder "
                     "zeroed there? The recording format holds gauge pressure: import an absolute sensor's log with "
                     "--p COLUMN:bar_abs (or kPa_abs, MPa_abs, psi_abs), or subtract the ambient. As it is, the "
                     "start counts as mid-run: the first block is left out of the fits")
    elif abs(l0) > AT_REST_MM or (p0 is not None and p0 > DRAINED_MPA):
        what = f"l = {l0:g} mm" + (f", p = {p0:g} MPa" if p0 is not None else "")
        notes.append(f"The recording starts at {what}, but the model starts at rest (drained, l = 0): an encoder "
                     f"zeroed elsewhere is an offset (with a drained first pressure, or none recorded, the search "
                     f"starts with it as sensor_drift); a recording started mid-run has a "
                     "start-up transient that the model cannot reproduce (with a first pressure above a "
                     "drained muscle's, the first block is left out of the fits; expect an unexplained "
                     "window at the start, or record from rest)")
    jitter = uniform_sampling(t_s).note()
    if jitter:
        notes.append(jitter[0].upper() + jitter[1:])
    if p_mpa is not None and float(np.max(p_mpa)) > PRESSURE_PLAUSIBLE_MPA:
        notes.append(f"Column p_mpa reaches {float(np.max(p_mpa)):g} MPa, far above a tap-water rig's (supply "
                     "0.25 MPa): is it logged in kPa? It only enters the regime breakdown here (--use-pressure, "
                     "which weighs it in the fits, refuses it)")
    if load_n is not None:
        top = float(np.max(np.abs(load_n)))
        if 0.0 < top < LOAD_PLAUSIBLE_N:
            notes.append(f"The load never exceeds {top:g} N, where a muscle lifts tens of newtons (the rig's 44 and "
                         "68 N): is it logged in kN? The diagnosis takes it as given, and a wrong load shows as "
                         "load_mismatch")
        elif top < LOAD_KG_NOTED_N and LOAD_RANGE_N[0] <= top * STANDARD_GRAVITY <= LOAD_RANGE_N[1]:
            notes.append(f"The load never exceeds {top:g} N, where a muscle lifts tens of newtons (the rig's 44 and "
                         f"68 N): is it a mass logged in kg ({top:g} kg weighs {top * STANDARD_GRAVITY:.3g} N; "
                         "tapmuscle import --load COLUMN:kg reads it so)? The diagnosis takes it as given, and a "
                         "wrong load shows as load_mismatch or bends the constants")
    return notes


def displacement_scale_note(l_mm: np.ndarray, l_model_mm: np.ndarray, *, column: str = "l_mm",
                            unit: str = "mm") -> str | None:
    """A note when the recorded displacement spans more than ``1 / SPAN_RATIO_PLAUSIBLE`` times what
    the nominal model ``l_model_mm`` does for the same command, or :data:`SPAN_RATIO_NOTED` times
    less or more (where the model moves :data:`SPAN_NOTED_MIN_MM` or more); None otherwise.

    Not refused, as a span below ``SPAN_RATIO_PLAUSIBLE`` is (:func:`check_displacement_scale`): a
    valve that opens where the model's does not moves the rig while the model stands still. But the
    usual cause of a span twenty times the model's is a command in another unit (volts imported as
    percent are a tenth), and of one a few times off a length in another unit (centimetres as
    millimetres), named as the unit of the log's ``column`` (given in ``unit``) that matches.

    Parameters
    ----------
    l_mm : ndarray
        Recorded displacement [mm].
    l_model_mm : ndarray
        The nominal model's displacement for the same command [mm].
    column : str, optional
        How the note names the column; default ``"l_mm"``.
    unit : str, optional
        The unit the column was given in; default ``"mm"``.
    """
    span, model_span = float(np.ptp(l_mm)), float(np.ptp(l_model_mm))
    # a recording that moves where the model does not (a command read as a tenth of itself); a still
    # muscle's noise over a model that does not move at all is no such thing
    if span >= SPAN_NOTED_MIN_MM and span > model_span / SPAN_RATIO_PLAUSIBLE:
        return (f"Column {column} spans {span:.4g} mm where the nominal model, driven by the same command (u within "
                f"the recording's), spans {model_span:.4g} mm: is the command in another unit (volts imported as "
                "percent are a tenth of them)? A valve that opens far below the model's would do it as well")
    if model_span < SPAN_NOTED_MIN_MM or span <= 0.0 or 1.0 / SPAN_RATIO_NOTED < span / model_span < SPAN_RATIO_NOTED:
        return None
    from tapmuscle.io.rig_log import UNITS, unit_key  # the units a log's length may be in

    ratio = model_span / span  # what the values would have to be multiplied by
    units = UNITS["l_mm"]
    given = units.get(unit_key(unit), 1.0)
    likely = min(units, key=lambda u: abs(np.log(units[u] / given / ratio)))
    fits = abs(np.log(units[likely] / given / ratio)) < np.log(SPAN_RATIO_NOTED) / 2 and likely != unit_key(unit)
    what = (f"is it in {likely} rather than {unit} (read in {likely}, it spans {span * units[likely] / given:.4g} mm)?"
            if fits else "is it in another unit?")
    return (f"Column {column} spans {span:.4g} mm where the nominal model, driven by the same command, spans "
            f"{model_span:.4g} mm ({'%.3g times as much' % ratio if ratio > 1 else '%.3g times less' % (1 / ratio)}): "
            f"{what} A rig that far from the nominal plant (a much weaker valve, a much heavier load) would do it as "
            "well, and the diagnosis would take the difference as the rig's")


def displacement_fault_notes(l_mm: np.ndarray, ts_s: float, *, column: str = "l_mm",
                             where=None) -> list[str]:
    """What in a displacement looks like a sensor's fault rather than the muscle (empty: nothing).

    * a step between two samples faster than :data:`JUMP_MM_PER_S` (a spike, a re-zeroed or slipping
      encoder); several of about the same size are a wrap of the encoder's count;
    * a reading held exactly for :data:`HELD_S` or longer that was entered at speed: at the run's
      largest reading, the sensor's range clipping it (or a hard stop); elsewhere, a stuck sensor.

    ``where(k)`` names sample ``k`` (default ``"sample k"``; an importer names the log's line).

    Parameters
    ----------
    l_mm : ndarray
        Displacement [mm].
    ts_s : float
        Sampling period [s].
    column : str, optional
        How the notes name the column; default ``"l_mm"``.
    where : callable, optional
        ``where(k) -> str`` naming sample ``k``.
    """
    where = where or (lambda k: f"sample {k}")
    l = np.asarray(l_mm, dtype=float)  # noqa: E741
    notes = []
    step = np.diff(l)
    jumps = np.flatnonzero(np.abs(step) > JUMP_MM_PER_S * ts_s)
    if jumps.size:
        sizes = np.abs(step[jumps])
        listed = ", ".join(f"{where(int(k) + 1)} ({step[k]:+.4g} mm)" for k in jumps[:10])
        listed += f" and {jumps.size - 10} more" if jumps.size > 10 else ""
        fast = f"faster than the muscle moves ({JUMP_MM_PER_S:g} mm/s, {JUMP_MM_PER_S * ts_s:.3g} mm a sample)"
        size = float(np.median(sizes))
        # a spike is a jump and its way back; a wrap's jump is its modulus less what the muscle moved
        # in that sample, and comes back only where the muscle moves back across it
        back = np.isin(jumps + 1, jumps) & (np.sign(step[np.minimum(jumps + 1, step.size - 1)]) == -np.sign(step[jumps]))
        paired = np.isin(jumps, jumps[back] + 1) | back
        if jumps.size >= 2 and not paired.all() and np.all(np.abs(sizes - size) <= WRAP_TOLERANCE * size):
            notes.append(f"Column {column} jumps by about {size:.4g} mm {jumps.size} times in one sample, {fast}: at "
                         f"{listed}. An encoder's count wrapping at {size:.4g} mm? Unwrap it (add or subtract "
                         f"{size:.4g} mm after each jump) before the diagnosis, which takes every jump as the muscle's")
        else:
            notes.append(f"Column {column} jumps in one sample, {fast}: at {listed}. A spike, a re-zeroed or a "
                         "slipping encoder? The diagnosis takes every jump as the muscle's")
    held = max(5, int(round(HELD_S / ts_s)))
    same = np.concatenate([[False], step == 0.0, [False]])
    edges = np.flatnonzero(np.diff(same.astype(np.int8)))  # runs of equal steps: [start, end) in steps
    top = float(np.max(l)) if l.size else 0.0
    clipped, stuck = [], []
    for a, b in zip(edges[::2], edges[1::2]):
        # samples a..b hold l[a]; the speed it was entered at is the step before (a reading clipped
        # within a sample steps in by a part of it)
        entry = max(abs(l[a] - l[a - 1]), abs(l[a - 1] - l[a - 2])) if a >= 2 else 0.0
        # sampled slower than HELD_TS_MAX_S, a muscle settles within a sample and holds its reading
        if b - a + 1 < held or entry < max(HELD_ENTRY_MM_PER_S * ts_s, HELD_ENTRY_MIN_MM) or ts_s > HELD_TS_MAX_S:
            continue
        (clipped if l[a] == top else stuck).append((int(a), int(b - a + 1)))
    if clipped:
        runs = ", ".join(f"{where(a)} ({n} samples)" for a, n in clipped[:10])
        notes.append(f"Column {column} is held at exactly {top:g} mm, its largest reading, {len(clipped)} time"
                     f"{'s' if len(clipped) > 1 else ''}, each reached at speed: from {runs}. A sensor clipped at its "
                     "range (or a hard stop)? The diagnosis would take the flat top as the muscle's")
    if stuck:
        runs = ", ".join(f"{where(a)} ({n} samples at {l[a]:g} mm)" for a, n in stuck[:10])
        notes.append(f"Column {column} stops dead and holds one reading exactly {len(stuck)} time"
                     f"{'s' if len(stuck) > 1 else ''}: from {runs}. A stuck sensor? The diagnosis would take it as "
                     "the muscle's")
    return notes


def check_displacement_scale(l_mm: np.ndarray, l_model_mm: np.ndarray) -> None:
    """Refuse a recorded displacement that spans less than :data:`SPAN_RATIO_PLAUSIBLE` of what the
    nominal model ``l_model_mm`` does for the same command.

    No rig a few tens of percent off its nominal constants moves 20 times less than the model: the
    displacement is in another unit (metres: a thousandth), the encoder is stuck, or the supply was
    closed. Compared as millimetres, any candidate effect that shrinks the motion would be named with
    confidence, which is worse than no diagnosis.

    Parameters
    ----------
    l_mm : ndarray
        Recorded displacement [mm].
    l_model_mm : ndarray
        The nominal model's displacement for the same command [mm].

    Raises
    ------
    ValueError
        Naming both spans, their ratio and what to check.
    """
    span, model_span = float(np.ptp(l_mm)), float(np.ptp(l_model_mm))
    if model_span <= 0.0 or span >= SPAN_RATIO_PLAUSIBLE * model_span:
        return
    raise ValueError(f"column l_mm spans {span:.4g} mm where the nominal model, driven by the same command, spans "
                     f"{model_span:.4g} mm ({model_span / max(span, 1e-300):.3g} times as much): is the displacement "
                     "logged in metres (scale it to millimetres), the encoder stuck, or the supply closed? A "
                     "diagnosis would blame whichever effect shrinks the motion")
