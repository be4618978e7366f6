"""A rig's log read as a recording and checked as the diagnosis would check it, before anything is
written or diagnosed: what ``tapmuscle import`` and ``tm.read_rig_log`` both do.

The reader (:func:`tapmuscle.io.rig_log.read_rig_log_columns`) takes each column in the unit it is
given; a unit given wrong leaves every value a finite number and the recording meaningless (a command
in percent read as volts, times in milliseconds, a position in micrometres). The checks of
:mod:`tapmuscle.diagnosis.recording_checks` refuse values no muscle recording has and say which unit
would read the column as one, spelled as the caller gives units: a flag on the command line
(``--u valve:%``) or a keyword in Python (``u='valve:%'``) (:class:`Spelling`). The displacement's
units are judged against the nominal plant driven by the same command, as the diagnosis judges them.
"""

from __future__ import annotations

import datetime
import math
import shlex
from dataclasses import dataclass, field

import numpy as np

from fmu_plant import PlantParams
from tapmuscle.diagnosis.recording_checks import (AT_REST_MM, COMMAND_RANGE_V, DISPLACEMENT_PLAUSIBLE_MM, DRAINED_MPA,
                                                  PRESSURE_PLAUSIBLE_MPA, SPAN_NOTED_MIN_MM, TS_RANGE_S,
                                                  RecordingCheckError, check_displacement_scale,
                                                  check_muscle_recording, check_pressure_scale, check_sampling_period,
                                                  displacement_fault_notes, displacement_scale_note,
                                                  muscle_recording_notes)
from tapmuscle.diagnosis.simulation import Simulator
from tapmuscle.io.decimation import decimated
from tapmuscle.io.recording import Recording, RecordingError
from tapmuscle.io.rig_log import (ABSOLUTE_UNITS, LINEAR_UNITS, MA_RANGE, NAME_SUFFIX, STANDARD_ATMOSPHERE_KPA, UNITS,
                                  LogColumn, likely_pressure_unit, read_rig_log_columns, unit_key)
from tapmuscle.io.sampling import Sampling, SamplingError, merge_advice

__all__ = ["Spelling", "COMMAND_LINE", "PYTHON", "LogOptions", "CheckedLog", "checked_rig_log"]

#: The recording's columns by the reader's names for them.
_KEYWORDS = {"t_s": "time", "u_v": "u", "l_mm": "l", "p_mpa": "p", "load_n": "load"}


@dataclass(frozen=True)
class Spelling:
    """How a message names the reader's options: ``tapmuscle import``'s flags (``python`` False) or
    ``tm.read_rig_log``'s keywords.

    Parameters
    ----------
    python : bool
        True: ``tm.read_rig_log``'s keywords; False: ``tapmuscle import``'s flags.
    """

    python: bool

    def column(self, target: str, spec: str) -> str:
        """The option that gives ``target``'s column as ``spec`` (``COLUMN:UNIT``)."""
        if self.python:
            return f"{_KEYWORDS[target]}={spec!r}"
        return f"--{_KEYWORDS[target]} {shlex.quote(spec)}"

    def unit_of(self, target: str) -> str:
        """Where ``target``'s unit is given: ``--p`` or ``p='COLUMN:UNIT'``."""
        return f"{_KEYWORDS[target]}='COLUMN:UNIT'" if self.python else f"--{_KEYWORDS[target]}"

    def option(self, name: str, value: object = None) -> str:
        """An option by its keyword (``ambient_kpa``, ``ts_s``, ``decimate``, ``use_pressure``),
        with ``value`` if given."""
        if self.python:
            return name if value is None else f"{name}={value}"
        flag = {"ts_s": "--ts"}.get(name, "--" + name.replace("_", "-"))
        return flag if value is None else f"{flag} {value}"

    @property
    def checks_off(self) -> str:
        """What takes a refused log as it is."""
        return "checks=False reads it as it is" if self.python else "--no-checks writes it as it is"


COMMAND_LINE = Spelling(python=False)
PYTHON = Spelling(python=True)


@dataclass(frozen=True)
class LogOptions:
    """The reader's arguments (:func:`tapmuscle.io.rig_log.read_rig_log`'s), and what the checks do:
    ``decimate`` samples merged into one (:func:`tapmuscle.io.decimation.decimated`) before the
    checks; ``checks`` False takes a refused log with a note instead.

    Parameters
    ----------
    path, time, u, l, p, load, load_n, delimiter, decimal, fill_gaps_s, skip_lines, encoding, ambient_kpa, ts_s
        As :func:`tapmuscle.io.rig_log.read_rig_log`'s.
    decimate : int, optional
        Samples merged into one before the checks; default 1 (none).
    checks : bool, optional
        Refuse a log that holds values no muscle recording has (True, default); False: take it
        with a note.
    """

    path: str
    time: LogColumn | str | None = None
    u: LogColumn | str | None = None
    l: LogColumn | str | None = None  # noqa: E741
    p: LogColumn | str | None = None
    load: LogColumn | str | None = None
    load_n: float | None = None
    delimiter: str | None = None
    decimal: str | None = None
    fill_gaps_s: float = 0.0
    skip_lines: int = 0
    encoding: str = "utf-8-sig"
    ambient_kpa: float | None = None
    ts_s: float | None = None
    decimate: int = 1
    checks: bool = True


@dataclass(frozen=True)
class CheckedLog:
    """A log read and checked: the ``recording``, its ``sampling``, and the ``notes`` to print, in
    order; ``findings`` are those of them that say something may be wrong (the rest repeat what the
    reader did: units, columns, missing values).

    Parameters
    ----------
    recording : Recording
        The log as a recording.
    sampling : Sampling
        Its sampling grid.
    notes : list of str, optional
        The notes to print, in order.
    findings : list of str, optional
        Those of ``notes`` that say something may be wrong.
    """

    recording: Recording
    sampling: Sampling
    notes: list[str] = field(default_factory=list)
    findings: list[str] = field(default_factory=list)


#: The metadata that say what the reader did other than as given, printed as notes.
_NOTED = {"units": "Units: {}", "units_unknown": "A unit the log writes is none known: {}",
          "names": "Columns: {}", "duplicates": "Duplicates: {}", "missing": "Missing values: {}",
          "time_counter": "Time: {}"}


def checked_rig_log(options: LogOptions, run: int | None = None, spelling: Spelling = PYTHON) -> CheckedLog:
    """Run ``run`` of the log read by ``options`` and checked as the diagnosis would (module
    docstring).

    Parameters
    ----------
    options : LogOptions
        The reader's arguments and what the checks do.
    run : int, optional
        Which run of the log to read (1 = the first); None (default): a log of one run.
    spelling : Spelling, optional
        How messages name the options; default ``tm.read_rig_log``'s keywords.

    Raises
    ------
    tapmuscle.io.recording.RecordingError
        The log cannot be read as given (the reader's refusals: file, line, column), or, with
        ``options.checks``, it holds values no muscle recording has: the message names the file, the
        line and column, and the unit that would read them as one, as ``spelling`` gives units.
    """
    path = options.path
    try:
        rec, cols = read_rig_log_columns(path, time=options.time, u=options.u, l=options.l, p=options.p,
                                         load=options.load, load_n=options.load_n, delimiter=options.delimiter,
                                         decimal=options.decimal, fill_gaps_s=options.fill_gaps_s,
                                         skip_lines=options.skip_lines, encoding=options.encoding, run=run,
                                         ambient_kpa=options.ambient_kpa, ts_s=options.ts_s)
        merged = None
        if options.decimate > 1:
            before = rec.sampling.ts_s  # the log's own grid checked first: a dropped sample is named by its line
            try:
                rec, moved = decimated(rec, options.decimate)
            except ValueError as exc:  # beyond the merge's largest
                raise RecordingError(f"{path}: {exc}") from None
            merged = (f"Decimated: every {options.decimate} samples merged into one (Ts {before:.6g} -> "
                      f"{before * options.decimate:.6g} s; the first sample's readings, the block's mean command)"
                      + (f"; {moved}" if moved else ""))
        sampling = rec.sampling  # a dropped or doubled sample, a drifting clock: refused before writing
        load = rec.load_n
    except SamplingError as exc:
        raise RecordingError(str(exc)) from None
    ts = sampling.ts_s
    # the units were declared (or read from the log): values no muscle recording has mean a wrong one
    # (percent given as V), refused naming the COLUMN:UNIT that would read them as one
    scale_note, problems, l_nominal = None, [], None

    def nominal():
        return Simulator(rec.u_v, ts, load).run(PlantParams().noise_free())[0]

    try:
        try:
            check_sampling_period(ts)
        except ValueError as exc:
            raise ValueError(_serial_dates(rec, cols, ts, spelling) or _period_refusal(options, cols, ts, exc, spelling)) \
                from None
        try:
            check_muscle_recording(rec.u_v, ts, rec.l_mm)
        except RecordingCheckError as exc:
            if exc.column == "u_v":
                hint = _fitting_unit(cols["u_v"], "u_v", rec.u_v, lambda u: _log_ratio(float(np.max(u)), 10.0) if (
                    COMMAND_RANGE_V[0] <= float(np.min(u)) and float(np.max(u)) <= COMMAND_RANGE_V[1]) else None,
                    spelling)
            else:
                model_span = float(np.ptp(nominal()))
                hint = _fitting_unit(cols["l_mm"], "l_mm", rec.l_mm, lambda x: _log_ratio(float(np.ptp(x)), model_span)
                                     if float(np.max(np.abs(x))) <= DISPLACEMENT_PLAUSIBLE_MM else None, spelling)
            raise ValueError(_located(path, rec, cols, exc, hint)) from None
        # the units against the nominal plant driven by the same command, as the diagnosis does it
        l_nominal = nominal()
        try:
            check_displacement_scale(rec.l_mm, l_nominal)
        except ValueError:
            span, model_span = float(np.ptp(rec.l_mm)), float(np.ptp(l_nominal))
            hint = _fitting_unit(cols["l_mm"], "l_mm", rec.l_mm, lambda x: _log_ratio(float(np.ptp(x)), model_span)
                                 if float(np.max(np.abs(x))) <= DISPLACEMENT_PLAUSIBLE_MM else None, spelling)
            col = cols["l_mm"]
            ratio = f"{model_span / span:.3g} times as much" if span > 0 else "the column does not move at all"
            unit = hint or "give it with " + spelling.column("l_mm", "COLUMN:UNIT")
            raise ValueError(f"column {col.column!r} (l_mm, given in {col.unit}) spans {span:.4g} mm where the nominal "
                             f"model, driven by the same command, spans {model_span:.4g} mm ({ratio}): is it in another "
                             f"unit ({unit}), the encoder stuck, or the supply closed? A diagnosis would blame whichever "
                             "effect shrinks the motion") from None
        col = cols["l_mm"]
        scale_note = displacement_scale_note(rec.l_mm, l_nominal, column=f"{col.column!r} (l_mm)", unit=col.unit)
        if scale_note and "rather than" in scale_note:
            likely = scale_note.split("is it in ", 1)[1].split(" ", 1)[0]
            scale_note = scale_note.replace(f"rather than {col.unit} ", f"rather than {col.unit} ("
                                            f"{spelling.column('l_mm', f'{col.column}:{likely}')}) ", 1)
    except ValueError as exc:
        message = str(exc) if str(exc).startswith(str(path)) else f"{path}: {exc}"
        if options.checks:
            raise RecordingError(f"{message} ({spelling.checks_off})") from None
        problems = [f"the diagnosis would refuse it: {message}"]
    if "p_mpa" in rec.columns and options.checks:  # said below otherwise, as the diagnosis says it
        try:
            check_pressure_scale(rec.columns["p_mpa"])
        except RecordingCheckError as exc:
            raise RecordingError(f"{_pressure_refusal(options, rec, cols['p_mpa'], exc.sample, spelling)} "
                                 f"({spelling.checks_off})") from None
    info = [_NOTED[key].format(rec.metadata[key]) for key in _NOTED if key in rec.metadata] + ([merged] if merged else [])
    findings = problems + muscle_recording_notes(rec.t_s, rec.l_mm, rec.columns.get("p_mpa"), load_n=load)
    if scale_note:
        findings.append(scale_note)
    if "p_mpa" in rec.columns:
        findings += _pressure_notes(options, rec, cols["p_mpa"], spelling)
    findings += displacement_fault_notes(rec.l_mm, ts, column=f"{cols['l_mm'].column!r} (l_mm)",
                                         where=lambda k: f"line {rec.lines[k]}")
    if "ambient_kpa" in rec.metadata and abs(rec.l_mm[0]) <= AT_REST_MM:
        # the median of the readings while the muscle stays at rest (up to 1 s): one reading carries the
        # sensor's noise into the proposed ambient
        rest = np.flatnonzero(np.abs(rec.l_mm) > AT_REST_MM)
        n = min(int(rest[0]) if rest.size else len(rec), max(1, int(round(1.0 / ts))))
        p0_kpa = 1e3 * float(np.median(rec.columns["p_mpa"][:n]))
        ambient = options.ambient_kpa or STANDARD_ATMOSPHERE_KPA
        if 1.0 < abs(p0_kpa) and abs(p0_kpa) <= 1e3 * DRAINED_MPA:  # a few kPa off: the day's atmosphere
            findings.append(f"At rest, the pressure reads {p0_kpa:+.3g} kPa (median of the first {n} samples) against "
                            f"the ambient {ambient:g} kPa; if the muscle was drained there, "
                            f"{spelling.option('ambient_kpa', f'{ambient + p0_kpa:.5g}')} (that reading) makes it 0")
    notes = info + findings
    if "filled" in rec.metadata:
        filled = rec.metadata["filled"][0].upper() + rec.metadata["filled"][1:]
        notes.insert(0, filled)
        findings.insert(0, filled)
    return CheckedLog(rec, sampling, notes, findings)


#: Spreadsheet serial dates [days since 1899-12-30] of the years 1954 to 2119: a time column that
#: starts within them and steps by a muscle's period in days holds dates, not seconds.
SERIAL_DATE_DAYS = (20000.0, 80000.0)


def _serial_dates(rec: Recording, cols: dict, ts: float, spelling: Spelling) -> str | None:
    """Why a time column of spreadsheet serial dates (``45356,4166``: days since 1899-12-30) is
    refused, or None where it is none: read as seconds it looked like a 1-MHz logger."""
    col = cols.get("t_s")
    start = str(rec.metadata.get("start", "")).strip()
    try:
        first = float(start.replace(",", "."))
    except ValueError:
        return None
    if col is None or col.conversion("t_s") != (1.0, 0.0) or not SERIAL_DATE_DAYS[0] <= first <= SERIAL_DATE_DAYS[1] \
            or not TS_RANGE_S[0] <= ts * 86400.0 <= TS_RANGE_S[1]:
        return None
    when = datetime.datetime(1899, 12, 30) + datetime.timedelta(days=first)
    return (f"line {rec.lines[0]}, column {col.column!r} (t_s, given in {col.unit}): {start} looks like a spreadsheet's "
            f"serial date ({when:%Y-%m-%d %H:%M:%S}: days since 1899-12-30, stepping {ts * 86400.0:.3g} s), not "
            f"seconds: export the time as seconds from the start, or as ISO 8601 text with the date, and give it "
            f"with {spelling.column('t_s', f'{col.column}:s')} or {spelling.column('t_s', f'{col.column}:iso')}")


def _period_refusal(options: LogOptions, cols: dict, ts: float, exc: ValueError, spelling: Spelling) -> str:
    """Why the sampling period ``ts`` [s] (outside :data:`TS_RANGE_S`) is refused, and what to give."""
    col = cols.get("t_s")
    decimate = spelling.option("decimate", options.decimate)
    if options.decimate > 1:  # the merge's period: what the log's own period needs instead
        log_ts = ts / options.decimate
        if ts > TS_RANGE_S[1]:
            return (f"{decimate} merges the log's {log_ts:g}-s samples to {ts:g} s, longer than the "
                    f"{TS_RANGE_S[1]:g} s of a muscle recording: merge fewer ({merge_advice(log_ts)})")
        return (f"the log is sampled every {log_ts:g} s ({1.0 / log_ts:g} Hz), and {decimate} gives {ts:g} s, still "
                f"shorter than {TS_RANGE_S[0]:g} s: {merge_advice(log_ts)}")
    if ts < TS_RANGE_S[0] and (col is None or options.ts_s is not None or col.conversion("t_s") is None
                               or unit_key(col.unit) == "s"):
        # seconds as given: a data acquisition faster than the muscle needs, most likely (2 kHz),
        # not minutes written to a ten-thousandth: merge samples, as the check says
        name = "the rows" if col is None else f"column {col.column!r} (t_s, given in {col.unit})"
        return f"{name}: {str(exc).removeprefix('column t_s: ')}"
    outside = (f"the sampling period is {ts:g} s, outside the {TS_RANGE_S[0]:g}..{TS_RANGE_S[1]:g} s of a "
               "muscle recording")
    if col is None or options.ts_s is not None or col.conversion("t_s") is None:  # no unit to name
        return f"{outside}: is it the rate the logger ran at?"
    written = ts / col.conversion("t_s")[0]
    hint = _fitting_unit(col, "t_s", np.array([0.0, ts]), lambda t: _log_ratio(
        t[1] - t[0], 0.1) if TS_RANGE_S[0] <= t[1] - t[0] <= TS_RANGE_S[1] else None, spelling)
    if unit_key(col.unit) != "s":  # the value as written, where it differs
        outside = outside.replace(" s,", f" s ({written:g} {col.unit}),", 1)
    faster = ""
    if ts < TS_RANGE_S[0]:  # another unit, or the unit right and a fast acquisition
        faster = f"; or, if {col.unit} is right, a data acquisition faster than the muscle needs: {merge_advice(ts)}"
    return (f"column {col.column!r} (t_s, given in {col.unit}): {outside}: "
            + (hint or f"is the time in another unit? Give its unit with {spelling.unit_of('t_s')}, or the period "
                       f"with {spelling.option('ts_s')}") + faster)


def _located(path: str, rec: Recording, cols: dict, exc: ValueError, hint: str | None = None) -> str:
    """A check's refusal of one sample (``column u_v, sample 3: ...``) named as the other refusals of a
    log are: by the log's file, line and column (``log.csv, line 8, column 'valve' (u_v): ...``); with
    ``hint`` (the ``COLUMN:UNIT`` that fits) in place of the check's own remedy."""
    if not isinstance(exc, RecordingCheckError):
        return f"{path}: {exc}"
    detail = f"{exc.finding}: {hint}" if hint else exc.detail
    return f"{path}, line {rec.lines[exc.sample]}, column {cols[exc.column].column!r} ({exc.column}): {detail}"


def _written(col: LogColumn, target: str, values: np.ndarray) -> np.ndarray:
    """``values`` (in the recording's unit) as the log holds them, in the column's unit."""
    scale, offset = col.conversion(target)
    return (values - offset) / scale


def _fitting_unit(col: LogColumn, target: str, values: np.ndarray, score, spelling: Spelling) -> str | None:
    """How to give the column (``the column is likely in UNIT (--x COLUMN:UNIT)``) in the unit of
    ``target`` that reads its ``values`` (in the recording's unit, read as given) best: ``score``
    takes the values so read and gives a misfit (smaller is better), or None where they cannot be."""
    written = _written(col, target, np.asarray(values, dtype=float))
    fits = {}
    for unit in [u for u, f in UNITS[target].items() if f is not None] + list(LINEAR_UNITS.get(target, {})):
        if unit == "mA" and not (MA_RANGE[0] <= float(np.min(written)) and float(np.max(written)) <= MA_RANGE[1]):
            continue
        scale, offset = LogColumn(col.column, unit).conversion(target)
        misfit = score(written * scale + offset)
        if misfit is not None:
            fits[unit] = misfit
    if not fits:
        return None
    best = min(fits, key=fits.get)
    if best == unit_key(col.unit):
        return None
    if col.origin in ("", NAME_SUFFIX):
        return f"the column is likely in {best} ({spelling.column(target, f'{col.column}:{best}')})"
    # a unit the log gives in brackets or a units row cannot be given otherwise: only a map overrides it
    scale, offset = LogColumn(col.column, best).conversion(target)
    linear = f"scale={scale:.10g}" + (f",offset={offset:.10g}" if offset else "")
    return (f"the log gives its unit as {col.unit} ({col.origin}); if the values are in {best} nonetheless, "
            f"{spelling.column(target, f'{col.column}:{linear}')}")


def _log_ratio(value: float, near: float) -> float | None:
    return abs(math.log(value / near)) if value > 0 else None


def _pressure_refusal(options: LogOptions, rec: Recording, col: LogColumn, k: int, spelling: Spelling) -> str:
    """Why the pressure column, whose largest value is at sample ``k``, is refused: that value as
    written in the unit given, its line, and the unit that reads it nearest the rig's supply."""
    p = rec.columns["p_mpa"]
    written, ambient, reading = _pressure_as_written(options, col, float(p[k]))
    supply = PlantParams().supply.supply_pressure_mpa
    plain = col.conversion("p_mpa") == (1.0, 0.0) and not ambient
    value = f"{written:g} {col.unit}" + ("" if plain else f" ({float(p[k]):g} MPa(G))")
    above = int((p > PRESSURE_PLAUSIBLE_MPA).sum())
    if reading is not None:
        best, mpa = reading
        likely_text = (f"the column is likely in {best} ({written:g} {best} is {mpa:.3g} MPa(G)): "
                       f"{spelling.column('p_mpa', f'{col.column}:{best}')}")
    else:
        likely_text = f"is the column in another unit? Give its unit with {spelling.unit_of('p_mpa')}"
    return (f"{options.path}, line {rec.lines[k]}, column {col.column!r} (p_mpa, given in {col.unit}): its largest "
            f"value, {value}, is no tap-water rig's pressure (mains water is at most about 1 MPa, the rig's supply "
            f"{supply:g} MPa; {above} sample{'s' if above > 1 else ''} above {PRESSURE_PLAUSIBLE_MPA:g} MPa): {likely_text}")


def _pressure_as_written(options: LogOptions, col: LogColumn, p_mpa: float):
    """A pressure [MPa(G)] as the log holds it (in the column's unit), the ambient subtracted from
    it [MPa] and the unit that reads that value nearest the rig's supply (None: none)."""
    given = unit_key(col.unit)
    ambient = 1e-3 * (options.ambient_kpa or STANDARD_ATMOSPHERE_KPA) if given in ABSOLUTE_UNITS else 0.0
    written = float(_written(col, "p_mpa", p_mpa + ambient))
    supply = PlantParams().supply.supply_pressure_mpa
    return written, ambient, likely_pressure_unit(written, given, near_mpa=supply, within_mpa=PRESSURE_PLAUSIBLE_MPA,
                                                  ambient_mpa=ambient)


def _pressure_notes(options: LogOptions, rec: Recording, col: LogColumn, spelling: Spelling) -> list[str]:
    """A pressure that no muscle of the nominal plant has, though below the bound refused: more than
    twice the supply, or below the threshold pressure all through a stroke. Named by the unit that
    reads it nearest the supply."""
    params = PlantParams()
    supply, threshold = params.supply.supply_pressure_mpa, params.muscle.threshold_pressure_mpa
    p = rec.columns["p_mpa"]
    k, span = int(np.argmax(p)), float(np.ptp(rec.l_mm))
    top = float(p[k])
    if 2.0 * supply < top <= PRESSURE_PLAUSIBLE_MPA:
        what = f"reaches {top:.3g} MPa (line {rec.lines[k]}), more than twice the nominal plant's supply ({supply:g} MPa)"
    elif top < threshold and span >= SPAN_NOTED_MIN_MM:
        what = (f"never exceeds {top:.3g} MPa while the muscle moves {span:.3g} mm, where a muscle contracts only "
                f"above its threshold pressure ({threshold:g} MPa)")
    else:
        return []
    written, _, reading = _pressure_as_written(options, col, top)
    if reading is not None and reading[1] > threshold:
        best, mpa = reading
        likely = (f"{best} given as {col.unit}? ({written:g} {best} is {mpa:.3g} MPa(G): "
                  f"{spelling.column('p_mpa', f'{col.column}:{best}')})")
    else:
        likely = "is it in another unit?"
    return [f"Column {col.column!r} (p_mpa, given in {col.unit}) {what}: {likely} The diagnosis takes it as given "
            f"(and weighs it with {spelling.option('use_pressure', 'True' if spelling.python else None)})"]
