"""``tapmuscle import``: a rig's data-acquisition log into the recording format (docs/recordings.md),
with what the mismatch diagnosis would refuse or say about it printed before any diagnosis runs."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from tapmuscle.cli.arguments import Once, integer_at_least, number_within, output_path
from tapmuscle.errors import UsageError

__all__ = ["register"]


def _column(target: str, flag: str):
    from tapmuscle.io.rig_log import parse_column_spec

    def parse(text: str):
        try:
            return parse_column_spec(text, target)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"{flag} {exc}") from None
    return parse


def _run_number(text: str) -> int | str:
    if text == "all":
        return text
    try:
        return integer_at_least("--run", 1, 10 ** 6)(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"--run must be a run number (1 = the first) or 'all', "
                                         f"got {text!r}") from None


def _run_outputs(out: Path, runs: int) -> list[Path]:
    """OUT_run1.csv .. OUT_runN.csv beside ``out``: one recording per run of a restarted log."""
    return [out.with_name(f"{out.stem}_run{k}{out.suffix}") for k in range(1, runs + 1)]


def _quoted(col, unit: str) -> str:
    """``COLUMN:UNIT`` as a shell takes it (a name with a space or brackets quoted)."""
    return shlex.quote(f"{col.column}:{unit}")


def _located(args: argparse.Namespace, rec, cols: dict, exc: ValueError, hint: str | None = None) -> str:
    """A check's refusal of one sample (``column u_v, sample 3: ...``) named as the other refusals of a
    log are: by the log's file, line and column (``log.csv, line 8, column 'valve' (u_v): ...``); with
    ``hint`` (the ``COLUMN:UNIT`` that fits) in place of the check's own remedy."""
    from tapmuscle.diagnosis.recording_checks import RecordingCheckError

    if not isinstance(exc, RecordingCheckError):
        return f"{args.log}: {exc}"
    detail = f"{exc.finding}: {hint}" if hint else exc.detail
    return f"{args.log}, line {rec.lines[exc.sample]}, column {cols[exc.column].column!r} ({exc.column}): {detail}"


def _written(col, target: str, values):
    """``values`` (in the recording's unit) as the log holds them, in the column's unit."""
    scale, offset = col.conversion(target)
    return (values - offset) / scale


def _fitting_unit(col, target: str, values, score) -> str | None:
    """How to give the column (``the column is likely in UNIT (--x COLUMN:UNIT)``) in the unit of
    ``target`` that reads its ``values`` (in the recording's unit, read as given) best: ``score``
    takes the values so read and gives a misfit (smaller is better), or None where they cannot be."""
    import numpy as np

    from tapmuscle.io.rig_log import LINEAR_UNITS, MA_RANGE, NAME_SUFFIX, UNITS, LogColumn, unit_key

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
    flag = {"t_s": "--time", "u_v": "--u", "l_mm": "--l", "p_mpa": "--p", "load_n": "--load"}[target]
    if col.origin in ("", NAME_SUFFIX):
        return f"the column is likely in {best} ({flag} {_quoted(col, best)})"
    # a unit the log gives in brackets or a units row cannot be given otherwise: only a map overrides it
    scale, offset = LogColumn(col.column, best).conversion(target)
    linear = f"scale={scale:.10g}" + (f",offset={offset:.10g}" if offset else "")
    return (f"the log gives its unit as {col.unit} ({col.origin}); if the values are in {best} nonetheless, "
            f"{flag} {_quoted(col, linear)}")


def _log_ratio(value: float, near: float) -> float | None:
    import math

    return abs(math.log(value / near)) if value > 0 else None


def _pressure_refusal(args: argparse.Namespace, rec, col, k: int) -> str:
    """Why the pressure column, whose largest value is at sample ``k``, is refused: that value as
    written in the unit given, its line, and the unit that reads it nearest the rig's supply."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.recording_checks import PRESSURE_PLAUSIBLE_MPA

    p = rec.columns["p_mpa"]
    written, ambient, reading = _pressure_as_written(args, col, float(p[k]))
    supply = PlantParams().supply.supply_pressure_mpa
    plain = col.conversion("p_mpa") == (1.0, 0.0) and not ambient
    value = f"{written:g} {col.unit}" + ("" if plain else f" ({float(p[k]):g} MPa(G))")
    above = int((p > PRESSURE_PLAUSIBLE_MPA).sum())
    if reading is not None:
        best, mpa = reading
        likely_text = f"the column is likely in {best} ({written:g} {best} is {mpa:.3g} MPa(G)): --p {_quoted(col, best)}"
    else:
        likely_text = "is the column in another unit? Give its unit with --p"
    return (f"{args.log}, line {rec.lines[k]}, column {col.column!r} (p_mpa, given in {col.unit}): its largest value, "
            f"{value}, is no tap-water rig's pressure (mains water is at most about 1 MPa, the rig's supply "
            f"{supply:g} MPa; {above} sample{'s' if above > 1 else ''} above {PRESSURE_PLAUSIBLE_MPA:g} MPa): {likely_text}")


def _pressure_as_written(args: argparse.Namespace, col, p_mpa: float):
    """A pressure [MPa(G)] as the log holds it (in the column's unit), the ambient subtracted from
    it [MPa] and the unit that reads that value nearest the rig's supply (None: none)."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.recording_checks import PRESSURE_PLAUSIBLE_MPA
    from tapmuscle.io.rig_log import ABSOLUTE_UNITS, STANDARD_ATMOSPHERE_KPA, likely_pressure_unit, unit_key

    given = unit_key(col.unit)
    ambient = 1e-3 * (args.ambient_kpa or STANDARD_ATMOSPHERE_KPA) if given in ABSOLUTE_UNITS else 0.0
    written = float(_written(col, "p_mpa", p_mpa + ambient))
    supply = PlantParams().supply.supply_pressure_mpa
    return written, ambient, likely_pressure_unit(written, given, near_mpa=supply, within_mpa=PRESSURE_PLAUSIBLE_MPA,
                                                  ambient_mpa=ambient)


def _pressure_notes(args: argparse.Namespace, rec, col) -> list[str]:
    """A pressure that no muscle of the nominal plant has, though below the bound refused: more than
    twice the supply, or below the threshold pressure all through a stroke. Named by the unit that
    reads it nearest the supply."""
    import numpy as np

    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.recording_checks import PRESSURE_PLAUSIBLE_MPA, SPAN_NOTED_MIN_MM

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
    written, _, reading = _pressure_as_written(args, col, top)
    if reading is not None and reading[1] > threshold:
        best, mpa = reading
        likely = f"{best} given as {col.unit}? ({written:g} {best} is {mpa:.3g} MPa(G): --p {_quoted(col, best)})"
    else:
        likely = "is it in another unit?"
    return [f"Column {col.column!r} (p_mpa, given in {col.unit}) {what}: {likely} The diagnosis takes it as given "
            "(and weighs it with --use-pressure)"]


#: The metadata that say what the reader did other than as given, printed as notes.
_NOTED = {"units": "Units: {}", "units_unknown": "A unit the log writes is none known: {}",
          "names": "Columns: {}", "duplicates": "Duplicates: {}", "missing": "Missing values: {}",
          "time_counter": "Time: {}"}


def _converted(args: argparse.Namespace, run: int | None):
    """The recording of run ``run`` of the log, checked as the diagnosis would, and its notes."""
    import numpy as np

    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.recording_checks import (AT_REST_MM, COMMAND_RANGE_V, DISPLACEMENT_PLAUSIBLE_MM,
                                                      DRAINED_MPA, TS_RANGE_S, RecordingCheckError,
                                                      check_displacement_scale, check_muscle_recording,
                                                      check_pressure_scale, check_sampling_period,
                                                      displacement_fault_notes, displacement_scale_note,
                                                      muscle_recording_notes)
    from tapmuscle.diagnosis.simulation import Simulator, noise_free
    from tapmuscle.io.recording import RecordingError
    from tapmuscle.io.rig_log import STANDARD_ATMOSPHERE_KPA, read_rig_log_columns
    from tapmuscle.io.decimation import decimated
    from tapmuscle.io.rig_log import unit_key
    from tapmuscle.io.sampling import SamplingError, merge_advice

    try:
        rec, cols = read_rig_log_columns(args.log, time=args.time, u=args.u, l=args.l, p=args.p, load=args.load,
                                         load_n=args.load_n, delimiter=args.delimiter, decimal=args.decimal,
                                         fill_gaps_s=args.fill_gaps or 0.0, skip_lines=args.skip_lines,
                                         encoding=args.encoding, run=run, ambient_kpa=args.ambient_kpa, ts_s=args.ts)
        merged = None
        if args.decimate > 1:
            before = rec.sampling.ts_s  # the log's own grid checked first: a dropped sample is named by its line
            rec, moved = decimated(rec, args.decimate)
            merged = (f"Decimated: every {args.decimate} samples merged into one (Ts {before:.6g} -> "
                      f"{before * args.decimate:.6g} s; the first sample's readings, the block's mean command)"
                      + (f"; {moved}" if moved else ""))
        sampling = rec.sampling  # a dropped or doubled sample, a drifting clock: refused before writing
        load = rec.load_n
    except (RecordingError, SamplingError) as exc:
        raise UsageError(str(exc)) from None
    ts = sampling.ts_s
    # the units were declared (or read from the log): values no muscle recording has mean a wrong one
    # (percent given as V), refused naming the COLUMN:UNIT that would read them as one
    scale_note, problems, l_nominal = None, [], None

    def nominal():
        return Simulator(rec.u_v, ts, load).run(noise_free(PlantParams()))[0]

    try:
        try:
            check_sampling_period(ts)
        except ValueError as exc:
            col = cols.get("t_s")
            if args.decimate > 1:  # the merge's period: what the log's own period needs instead
                log_ts = ts / args.decimate
                if ts > TS_RANGE_S[1]:
                    raise ValueError(f"--decimate {args.decimate} merges the log's {log_ts:g}-s samples to {ts:g} s, longer "
                                     f"than the {TS_RANGE_S[1]:g} s of a muscle recording: merge fewer ("
                                     f"{merge_advice(log_ts)})") from None
                raise ValueError(f"the log is sampled every {log_ts:g} s ({1.0 / log_ts:g} Hz), and --decimate "
                                 f"{args.decimate} gives {ts:g} s, still shorter than {TS_RANGE_S[0]:g} s: "
                                 f"{merge_advice(log_ts)}") from None
            if ts < TS_RANGE_S[0] and (col is None or args.ts is not None or col.conversion("t_s") is None
                                       or unit_key(col.unit) == "s"):
                # seconds as given: a data acquisition faster than the muscle needs, most likely (2 kHz),
                # not minutes written to a ten-thousandth: merge samples, as the check says
                name = "the rows" if col is None else f"column {col.column!r} (t_s, given in {col.unit})"
                raise ValueError(f"{name}: {str(exc).removeprefix('column t_s: ')}") from None
            outside = (f"the sampling period is {ts:g} s, outside the {TS_RANGE_S[0]:g}..{TS_RANGE_S[1]:g} s of a "
                       "muscle recording")
            if col is None or args.ts is not None or col.conversion("t_s") is None:  # no unit to name
                raise ValueError(f"{outside}: is it the rate the logger ran at?") from None
            written = ts / col.conversion("t_s")[0]
            hint = _fitting_unit(col, "t_s", np.array([0.0, ts]), lambda t: _log_ratio(
                t[1] - t[0], 0.1) if TS_RANGE_S[0] <= t[1] - t[0] <= TS_RANGE_S[1] else None)
            outside = outside.replace(" s,", f" s ({written:g} {col.unit}),", 1)
            faster = ""
            if ts < TS_RANGE_S[0]:  # another unit, or the unit right and a fast acquisition
                faster = f"; or, if {col.unit} is right, a data acquisition faster than the muscle needs: {merge_advice(ts)}"
            raise ValueError(f"column {col.column!r} (t_s, given in {col.unit}): {outside}: " + (
                hint or "is the time in another unit? Give its unit with --time, or the period with --ts") + faster) from None
        try:
            check_muscle_recording(rec.u_v, ts, rec.l_mm)
        except RecordingCheckError as exc:
            if exc.column == "u_v":
                hint = _fitting_unit(cols["u_v"], "u_v", rec.u_v, lambda u: _log_ratio(float(np.max(u)), 10.0) if (
                    COMMAND_RANGE_V[0] <= float(np.min(u)) and float(np.max(u)) <= COMMAND_RANGE_V[1]) else None)
            else:
                model_span = float(np.ptp(nominal()))
                hint = _fitting_unit(cols["l_mm"], "l_mm", rec.l_mm, lambda x: _log_ratio(float(np.ptp(x)), model_span)
                                     if float(np.max(np.abs(x))) <= DISPLACEMENT_PLAUSIBLE_MM else None)
            raise ValueError(_located(args, rec, cols, exc, hint)) from None
        # the units against the nominal plant driven by the same command, as the diagnosis does it
        l_nominal = nominal()
        try:
            check_displacement_scale(rec.l_mm, l_nominal)
        except ValueError:
            span, model_span = float(np.ptp(rec.l_mm)), float(np.ptp(l_nominal))
            hint = _fitting_unit(cols["l_mm"], "l_mm", rec.l_mm, lambda x: _log_ratio(float(np.ptp(x)), model_span)
                                 if float(np.max(np.abs(x))) <= DISPLACEMENT_PLAUSIBLE_MM else None)
            col = cols["l_mm"]
            raise ValueError(f"column {col.column!r} (l_mm, given in {col.unit}) spans {span:.4g} mm where the nominal "
                             f"model, driven by the same command, spans {model_span:.4g} mm ({model_span / max(span, 1e-300):.3g} "
                             f"times as much): is it in another unit ({hint or 'give it with --l COLUMN:UNIT'}), the "
                             "encoder stuck, or the supply closed? A diagnosis would blame whichever effect shrinks the "
                             "motion") from None
        col = cols["l_mm"]
        scale_note = displacement_scale_note(rec.l_mm, l_nominal, column=f"{col.column!r} (l_mm)", unit=col.unit)
        if scale_note and "rather than" in scale_note:
            likely = scale_note.split("is it in ", 1)[1].split(" ", 1)[0]
            scale_note = scale_note.replace(f"rather than {col.unit} ", f"rather than {col.unit} (--l "
                                            f"{_quoted(col, likely)}) ", 1)
    except ValueError as exc:
        message = str(exc) if str(exc).startswith(str(args.log)) else f"{args.log}: {exc}"
        if not args.no_checks:
            raise UsageError(f"{message} (--no-checks writes it as it is)") from None
        problems = [f"the diagnosis would refuse it: {message}"]
    if "p_mpa" in rec.columns and not args.no_checks:  # said below otherwise, as the diagnosis says it
        try:
            check_pressure_scale(rec.columns["p_mpa"])
        except RecordingCheckError as exc:
            raise UsageError(f"{_pressure_refusal(args, rec, cols['p_mpa'], exc.sample)} (--no-checks writes it as it "
                             "is)") from None
    notes = [_NOTED[key].format(rec.metadata[key]) for key in _NOTED if key in rec.metadata] + ([merged] if merged else [])
    notes += problems + muscle_recording_notes(rec.t_s, rec.l_mm, rec.columns.get("p_mpa"), load_n=load)
    if scale_note:
        notes.append(scale_note)
    if "p_mpa" in rec.columns:
        notes += _pressure_notes(args, rec, cols["p_mpa"])
    notes += displacement_fault_notes(rec.l_mm, ts, column=f"{cols['l_mm'].column!r} (l_mm)",
                                      where=lambda k: f"line {rec.lines[k]}")
    if "ambient_kpa" in rec.metadata and abs(rec.l_mm[0]) <= AT_REST_MM:
        # the median of the readings while the muscle stays at rest (up to 1 s): one reading carries the
        # sensor's noise into the proposed ambient
        rest = np.flatnonzero(np.abs(rec.l_mm) > AT_REST_MM)
        n = min(int(rest[0]) if rest.size else len(rec), max(1, int(round(1.0 / ts))))
        p0_kpa = 1e3 * float(np.median(rec.columns["p_mpa"][:n]))
        ambient = args.ambient_kpa or STANDARD_ATMOSPHERE_KPA
        if 1.0 < abs(p0_kpa) and abs(p0_kpa) <= 1e3 * DRAINED_MPA:  # a few kPa off: the day's atmosphere
            notes.append(f"At rest, the pressure reads {p0_kpa:+.3g} kPa (median of the first {n} samples) against the "
                         f"ambient {ambient:g} kPa; if the muscle was drained there, --ambient-kpa {ambient + p0_kpa:.5g} "
                         "(that reading) makes it 0")
    if "filled" in rec.metadata:
        notes.insert(0, rec.metadata["filled"][0].upper() + rec.metadata["filled"][1:])
    return rec, sampling, notes


def _cmd_import(args: argparse.Namespace) -> int:
    from tapmuscle.io.recording import RecordingError, write_recording
    from tapmuscle.io.rig_log import rig_log_runs

    if args.load is not None and args.load_n is not None:
        raise UsageError("--load and --load-n: give the load as a column or as one value, not both")
    if args.time is None and args.ts is None:
        raise UsageError("--time COLUMN[:UNIT] or --ts S: the log's time column, or the sampling period that builds "
                         "the times from the row numbers")
    if args.run == "all":
        try:
            runs = rig_log_runs(args.log, delimiter=args.delimiter, skip_lines=args.skip_lines, encoding=args.encoding)
        except RecordingError as exc:
            raise UsageError(str(exc)) from None
        outs = _run_outputs(Path(args.out), runs)
        wanted = list(range(1, runs + 1))
    else:
        outs, wanted = [Path(args.out)], [args.run]
    for out in outs:
        if out.resolve() == Path(args.log).resolve():
            raise UsageError(f"--out {out} is the log itself: write the recording beside it, the log is the raw data")
    # every run converted and checked before the first file is written: all of them, or none
    converted = []
    for run in wanted:
        try:
            converted.append(_converted(args, run))
        except UsageError as exc:
            if args.run != "all":
                raise
            raise UsageError(f"run {run} of {len(wanted)}: {exc}; nothing written (--run K imports the "
                             f"others one by one)") from None
    for out, (rec, sampling, notes) in zip(outs, converted):
        write_recording(out, rec)
        print(f"{args.log}: {len(rec)} samples, Ts {sampling.ts_s:.9g} s, {rec.metadata['source'].partition(': ')[2]}"
              + (f"; {rec.metadata['run']}" if "run" in rec.metadata else "")
              + (f"; {rec.metadata['units_row']} (units row)" if "units_row" in rec.metadata else "")
              + (f"; ambient {rec.metadata['ambient_kpa']}" if "ambient_kpa" in rec.metadata else "")
              + (f"; {rec.metadata['remarks']}" if "remarks" in rec.metadata else ""))
        for note in notes:
            print(f"note: {note}", file=sys.stderr)
        print(f"wrote {out}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``import`` to the ``tapmuscle`` command line."""
    imp = sub.add_parser("import", help="convert a rig's data-acquisition log into a recording CSV",
                         description="Read a rig's log (any column names; units, separator and decimal mark as "
                                     "given or detected; text columns ignored) and write it as a recording "
                                     "(docs/recordings.md) that identify and diagnose read. Units: time s, ms, us (or µs), "
                                     "min, h or iso (ISO 8601 or day.month.year text); "
                                     "command V, mV, % (of 0..10 V), pwm (0..255 of 0..10 V) or mA (4-20 mA of "
                                     "0..10 V); "
                                     "displacement mm, um (or µm), cm or m; "
                                     "pressure MPa, kPa, bar, Pa or psi (gauge), or MPa_abs, kPa_abs, "
                                     "bar_abs, Pa_abs or psi_abs (absolute, read against --ambient-kpa); load N or kN; "
                                     "any column: scale=A,offset=B (A x written + B). A column given without a "
                                     "unit takes the one the log gives (Druck [bar], position_um, a units row).")
    imp.add_argument("log", help="the logger's file")
    imp.add_argument("--out", action=Once, type=output_path("--out", "file"), required=True, help="output recording CSV")
    imp.add_argument("--time", action=Once, type=_column("t_s", "--time"), default=None, metavar="COLUMN[:UNIT]",
                     help="time column and unit (default: the unit the log gives in the column's name or units "
                          "row, else s), e.g. time_ms:ms or stamp:iso")
    imp.add_argument("--ts", action=Once, type=number_within("--ts", 1e-3, 10.0), default=None, metavar="S",
                     help="the sampling period [s]: without --time, the times are the row numbers times S (a log "
                          "without a time column); with --time COLUMN (no unit), the column counts samples and the "
                          "times are its counts times S (a count skipped is a dropped sample)")
    imp.add_argument("--u", action=Once, type=_column("u_v", "--u"), required=True, metavar="COLUMN[:UNIT]",
                     help="valve command column (default: the log's unit for it, else V), e.g. valve_pct:%%, "
                          "valve_ma:mA (4-20 mA) or valve:scale=0.5,offset=0 (V = 0.5 x written + 0)")
    imp.add_argument("--l", action=Once, type=_column("l_mm", "--l"), required=True, metavar="COLUMN[:UNIT]",
                     help="encoder displacement column (default: the log's unit for it, else mm), e.g. position_um:um")
    imp.add_argument("--p", action=Once, type=_column("p_mpa", "--p"), default=None, metavar="COLUMN[:UNIT]",
                     help="muscle pressure column (default: the log's unit for it, else MPa), e.g. p_kpa:kPa")
    imp.add_argument("--ambient-kpa", action=Once, type=number_within("--ambient-kpa", 30.0, 120.0), default=None, metavar="KPA",
                     help="with an absolute pressure unit (e.g. --p p_abs:bar_abs): the ambient pressure subtracted "
                          "to give the recording's gauge pressure, the local barometric pressure or the sensor's "
                          "reading of the drained muscle (default: the standard atmosphere, 101.325 kPa)")
    imp.add_argument("--load", action=Once, type=_column("load_n", "--load"), default=None, metavar="COLUMN[:UNIT]",
                     help="load column (default: the log's unit for it, else N)")
    imp.add_argument("--load-n", action=Once, type=number_within("--load-n", 1e-9, 500.0), default=None,
                     help="the hanging load [N] when it is not a column (written as the recording's load_n)")
    imp.add_argument("--delimiter", action=Once, default=None, help="field separator: one character, or 'tab' (default: the one "
                                                       "of ';', tab, ',' the header row holds most of)")
    imp.add_argument("--fill-gaps", action=Once, type=number_within("--fill-gaps", 1e-9, 3600.0), default=None, metavar="S",
                     help="put back samples the logger dropped, in gaps of up to S seconds (every column "
                          "interpolated linearly, marked in a column 'filled'); default: a dropped sample is refused")
    imp.add_argument("--skip-lines", action=Once, type=integer_at_least("--skip-lines", 0, 10 ** 6), default=0, metavar="N",
                     help="lines before the header to skip (a program's preamble, boot messages)")
    imp.add_argument("--run", action=Once, type=_run_number, default=None, metavar="K|all",
                     help="of a log a restarted logger wrote on (the header repeated among the data), read run "
                          "K (1 = the first), or every run, each to its own OUT_runK file (all written, or none "
                          "when one is refused); default: a log of several runs is refused, naming where they start")
    imp.add_argument("--encoding", action=Once, default="utf-8-sig",
                     help="the file's text encoding (default UTF-8, or UTF-16 where the file starts with its "
                          "byte-order mark; e.g. latin-1, cp1252)")
    imp.add_argument("--no-checks", action="store_true",
                     help="write values no muscle recording has (a command outside -1..11 V, a displacement beyond "
                          "500 mm, a period outside 1 ms..10 s) instead of refusing them, e.g. for identify on "
                          "another rig's units")
    imp.add_argument("--decimate", action=Once, type=integer_at_least("--decimate", 1, 1000), default=1,
                     metavar="N", help="merge every N samples into one (a log taken faster than the muscle needs: "
                          "1 kHz with N = 20 gives Ts = 0.02 s): the first sample's time and readings, the block's "
                          "mean command (docs/recordings.md, \"Fast data acquisition\"); default 1")
    imp.add_argument("--decimal", action=Once, choices=(".", ","), default=None,
                     help="decimal mark (default: ',' when the separator is not and a value reads 12,5)")
    imp.set_defaults(func=_cmd_import)
