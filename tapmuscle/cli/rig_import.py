"""``tapmuscle import``: a rig's data-acquisition log into the recording format (docs/recordings.md),
with what the mismatch diagnosis would refuse or say about it printed before any diagnosis runs."""

from __future__ import annotations

import argparse
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


def _log_column(args: argparse.Namespace, target: str):
    """The log's column (a LogColumn) read into the recording's column ``target``."""
    return {"t_s": args.time, "u_v": args.u, "l_mm": args.l, "p_mpa": args.p, "load_n": args.load}[target]


def _located(args: argparse.Namespace, rec, exc: ValueError) -> str:
    """A check's refusal of one sample (``column u_v, sample 3: ...``) named as the other refusals of a
    log are: by the log's file, line and column (``log.csv, line 8, column 'valve' (u_v): ...``)."""
    from tapmuscle.diagnosis.recording_checks import RecordingCheckError

    if not isinstance(exc, RecordingCheckError):
        return f"{args.log}: {exc}"
    return (f"{args.log}, line {rec.lines[exc.sample]}, column {_log_column(args, exc.column).column!r} "
            f"({exc.column}): {exc.detail}")


def _pressure_refusal(args: argparse.Namespace, rec, k: int) -> str:
    """Why the pressure column, whose largest value is at sample ``k``, is refused: that value as
    written in the unit given, its line, and the unit that reads it nearest the rig's supply."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.recording_checks import PRESSURE_PLAUSIBLE_MPA
    from tapmuscle.io.rig_log import ABSOLUTE_UNITS, STANDARD_ATMOSPHERE_KPA, UNITS, likely_pressure_unit, unit_key

    col, p = args.p, rec.columns["p_mpa"]
    given = unit_key(args.p.unit)
    ambient = 1e-3 * (args.ambient_kpa or STANDARD_ATMOSPHERE_KPA) if given in ABSOLUTE_UNITS else 0.0
    written = (float(p[k]) + ambient) / UNITS["p_mpa"][given]  # the largest value as the log holds it
    supply = PlantParams().supply.supply_pressure_mpa
    value = f"{written:g} {col.unit}" + ("" if UNITS["p_mpa"][given] == 1.0 and not ambient else f" ({float(p[k]):g} MPa(G))")
    above = int((p > PRESSURE_PLAUSIBLE_MPA).sum())
    likely = likely_pressure_unit(written, given, near_mpa=supply, within_mpa=PRESSURE_PLAUSIBLE_MPA, ambient_mpa=ambient)
    if likely is not None:
        best, reading = likely
        likely_text = f"the column is likely in {best} ({written:g} {best} is {reading:.3g} MPa(G)): --p {col.column}:{best}"
    else:
        likely_text = "is the column in another unit? Give its unit with --p"
    return (f"{args.log}, line {rec.lines[k]}, column {col.column!r} (p_mpa, given in {col.unit}): its largest value, "
            f"{value}, is no tap-water rig's pressure (mains water is at most about 1 MPa, the rig's supply "
            f"{supply:g} MPa; {above} sample{'s' if above > 1 else ''} above {PRESSURE_PLAUSIBLE_MPA:g} MPa): {likely_text}")


def _converted(args: argparse.Namespace, run: int | None):
    """The recording of run ``run`` of the log, checked as the diagnosis would, and its notes."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.recording_checks import (AT_REST_MM, DRAINED_MPA, RecordingCheckError,
                                                      check_displacement_scale, check_muscle_recording,
                                                      check_pressure_scale, displacement_scale_note,
                                                      muscle_recording_notes)
    import numpy as np

    from tapmuscle.diagnosis.simulation import Simulator, noise_free
    from tapmuscle.io.recording import RecordingError
    from tapmuscle.io.rig_log import STANDARD_ATMOSPHERE_KPA, read_rig_log
    from tapmuscle.io.sampling import SamplingError

    try:
        rec = read_rig_log(args.log, time=args.time, u=args.u, l=args.l, p=args.p, load=args.load,
                           load_n=args.load_n, delimiter=args.delimiter, decimal=args.decimal,
                           fill_gaps_s=args.fill_gaps or 0.0, skip_lines=args.skip_lines, encoding=args.encoding,
                           run=run, ambient_kpa=args.ambient_kpa)
        sampling = rec.sampling  # a dropped or doubled sample, a drifting clock: refused before writing
        load = rec.load_n
    except (RecordingError, SamplingError) as exc:
        raise UsageError(str(exc)) from None
    # the units were declared: values no muscle recording has mean a wrong one (percent given as V)
    scale_note = None
    try:
        check_muscle_recording(rec.u_v, sampling.ts_s, rec.l_mm)
        # the units against the nominal plant driven by the same command, as the diagnosis does it
        l_nominal = Simulator(rec.u_v, sampling.ts_s, load).run(noise_free(PlantParams()))[0]
        check_displacement_scale(rec.l_mm, l_nominal)
        scale_note = displacement_scale_note(rec.l_mm, l_nominal)
        problems = []
    except ValueError as exc:
        message = _located(args, rec, exc)
        if not args.no_checks:
            raise UsageError(f"{message} (--no-checks writes it as it is)") from None
        problems = [f"the diagnosis would refuse it: {message}"]
    if "p_mpa" in rec.columns and not args.no_checks:  # said below otherwise, as the diagnosis says it
        try:
            check_pressure_scale(rec.columns["p_mpa"])
        except RecordingCheckError as exc:
            raise UsageError(f"{_pressure_refusal(args, rec, exc.sample)} (--no-checks writes it as it is)") from None
    notes = problems + muscle_recording_notes(rec.t_s, rec.l_mm, rec.columns.get("p_mpa"), load_n=load)
    if scale_note:
        notes.append(scale_note)
    if "ambient_kpa" in rec.metadata and abs(rec.l_mm[0]) <= AT_REST_MM:
        # the median of the readings while the muscle stays at rest (up to 1 s): one reading carries the
        # sensor's noise into the proposed ambient
        rest = np.flatnonzero(np.abs(rec.l_mm) > AT_REST_MM)
        n = min(int(rest[0]) if rest.size else len(rec), max(1, int(round(1.0 / sampling.ts_s))))
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
                                     "command V, mV, % (of 0..10 V) or pwm (0..255 of 0..10 V); "
                                     "displacement mm, um (or µm), cm or m; "
                                     "pressure MPa, kPa, bar, Pa or psi (gauge), or MPa_abs, kPa_abs, "
                                     "bar_abs, Pa_abs or psi_abs (absolute, read against --ambient-kpa); load N or kN.")
    imp.add_argument("log", help="the logger's file")
    imp.add_argument("--out", action=Once, type=output_path("--out", "file"), required=True, help="output recording CSV")
    imp.add_argument("--time", action=Once, type=_column("t_s", "--time"), required=True, metavar="COLUMN[:UNIT]",
                     help="time column and unit (default unit s), e.g. time_ms:ms or stamp:iso")
    imp.add_argument("--u", action=Once, type=_column("u_v", "--u"), required=True, metavar="COLUMN[:UNIT]",
                     help="valve command column (default unit V), e.g. valve_pct:%%")
    imp.add_argument("--l", action=Once, type=_column("l_mm", "--l"), required=True, metavar="COLUMN[:UNIT]",
                     help="encoder displacement column (default unit mm), e.g. position_um:um")
    imp.add_argument("--p", action=Once, type=_column("p_mpa", "--p"), default=None, metavar="COLUMN[:UNIT]",
                     help="muscle pressure column (default unit MPa), e.g. p_kpa:kPa")
    imp.add_argument("--ambient-kpa", action=Once, type=number_within("--ambient-kpa", 30.0, 120.0), default=None, metavar="KPA",
                     help="with an absolute pressure unit (e.g. --p p_abs:bar_abs): the ambient pressure subtracted "
                          "to give the recording's gauge pressure, the local barometric pressure or the sensor's "
                          "reading of the drained muscle (default: the standard atmosphere, 101.325 kPa)")
    imp.add_argument("--load", action=Once, type=_column("load_n", "--load"), default=None, metavar="COLUMN[:UNIT]",
                     help="load column (default unit N)")
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
                     help="the file's text encoding (default UTF-8; e.g. latin-1, cp1252, utf-16)")
    imp.add_argument("--no-checks", action="store_true",
                     help="write values no muscle recording has (a command outside -1..11 V, a displacement beyond "
                          "500 mm, a period outside 1 ms..10 s) instead of refusing them, e.g. for identify on "
                          "another rig's units")
    imp.add_argument("--decimal", action=Once, choices=(".", ","), default=None,
                     help="decimal mark (default: ',' when the separator is not and a value reads 12,5)")
    imp.set_defaults(func=_cmd_import)
