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


def _converted(args: argparse.Namespace, run: int | None):
    """The recording of run ``run`` of the log, checked as the diagnosis would, its sampling and notes."""
    from tapmuscle.diagnosis.rig_log_checks import COMMAND_LINE, LogOptions, checked_rig_log
    from tapmuscle.io.recording import RecordingError

    options = LogOptions(args.log, time=args.time, u=args.u, l=args.l, p=args.p, load=args.load, load_n=args.load_n,
                         delimiter=args.delimiter, decimal=args.decimal, fill_gaps_s=args.fill_gaps or 0.0,
                         skip_lines=args.skip_lines, encoding=args.encoding, ambient_kpa=args.ambient_kpa,
                         ts_s=args.ts, decimate=args.decimate, checks=not args.no_checks)
    try:
        checked = checked_rig_log(options, run, COMMAND_LINE)
    except RecordingError as exc:
        raise UsageError(str(exc)) from None
    return checked.recording, checked.sampling, checked.notes


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
    """Add ``import`` to the ``tapmuscle`` command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subparsers of the ``tapmuscle`` parser.
    """
    imp = sub.add_parser("import", help="convert a rig's data-acquisition log into a recording CSV",
                         description="Read a rig's log (any column names; units, separator and decimal mark as "
                                     "given or detected; text columns ignored) and write it as a recording "
                                     "(docs/recordings.md) that identify and diagnose read. Units: time s, ms, us (or µs), "
                                     "min, h or iso (ISO 8601 or day.month.year text); "
                                     "command V, mV, % (of 0..10 V), pwm (0..255 of 0..10 V) or mA (4-20 mA of "
                                     "0..10 V); "
                                     "displacement mm, um (or µm), cm or m; "
                                     "pressure MPa, kPa, bar, Pa or psi (gauge), or MPa_abs, kPa_abs, "
                                     "bar_abs, Pa_abs or psi_abs (absolute, read against --ambient-kpa); "
                                     "load N, kN or kg (a mass: its weight); "
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
    imp.add_argument("--load-n", action=Once, type=number_within("--load-n", 0.0, 500.0), default=None,
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
