"""``tapmuscle diagnose`` and ``tapmuscle demo-mismatch``: thin shells around :mod:`diagnosis`."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from tapmuscle.cli.arguments import integer_at_least, number_within, output_path
from tapmuscle.errors import UsageError

__all__ = ["register"]


def _effect_list(text: str, option: str = "--effects") -> list[str]:
    """The names of ``--effects`` (or another ``option``; comma-separated); a name given twice is refused."""
    names = [e.strip() for e in text.split(",") if e.strip()]
    twice = sorted({e for e in names if names.count(e) > 1})
    if twice:
        raise UsageError(f"{option} {text!r}: {twice[0]!r} is given twice")
    return names


def _calibration(args: argparse.Namespace) -> dict:
    """The ``calibration`` option of :func:`diagnose` from ``--no-calibration`` / ``--calibrate``."""
    from tapmuscle.diagnosis.calibration import NOMINAL_PARAMETERS, nominal_parameter

    if args.calibrate is None:
        return {"calibration": None} if args.no_calibration else {}
    if args.no_calibration:
        raise UsageError("--calibrate and --no-calibration exclude each other")
    keys = _effect_list(args.calibrate, "--calibrate")
    if not keys:
        raise UsageError(f"--calibrate {args.calibrate!r} names no constant (--no-calibration: none)")
    chosen = []
    for key in keys:
        try:
            chosen += list(NOMINAL_PARAMETERS) if key == "default" else [nominal_parameter(key)]
        except ValueError as exc:
            raise UsageError(f"--calibrate {args.calibrate!r}: {exc}") from None
    return {"calibration": list(dict.fromkeys(chosen))}


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from tapmuscle.diagnosis.report import diagnose_files, summary_lines

    from tapmuscle.progress import Progress

    from tapmuscle.diagnosis.candidates import CANDIDATES

    if _is_foreign(args.plant):  # its candidates depend on the FMU and the map: checked there
        if args.candidates is not None:
            raise UsageError(f"--candidates is for tapmuscle's plant, whose parameters a candidate sets; the foreign "
                             f"FMU {args.plant} has candidates of its own inputs")
        if args.use_pressure:
            raise UsageError(f"--use-pressure is for tapmuscle's plant; the foreign FMU {args.plant} predicts "
                             "no muscle pressure")
        return _diagnose_foreign(args)
    out = Path(args.out)
    own = _own_candidates(args.candidates) if args.candidates is not None else []
    table = {c.name: c for c in CANDIDATES} | {c.name: c for c in own}
    candidates = list(table.values())
    if args.effects is not None:
        effects = _effect_list(args.effects)
        unknown = [e for e in effects if e not in table]
        if unknown or not effects:
            raise UsageError(f"--effects {args.effects!r}: "
                             + (f"unknown effect {unknown[0]!r}" if unknown else "names no effect")
                             + f"; known: {', '.join(table)}"
                             + ("" if own else " (a candidate of your own: --candidates FILE.py)"))
        candidates = [table[e] for e in effects]
    if args.map is not None or args.output is not None:
        raise UsageError(f"--map and --output are for a foreign plant FMU; {args.plant} is tapmuscle's plant")
    options = _calibration(args) | {"use_pressure": args.use_pressure}
    try:
        d, _ = diagnose_files(args.recording, args.plant, out, plots=not args.no_plots,
                              progress=Progress("diagnose", enabled=not args.quiet, counts=False),
                              block_s=args.block,
                              fit_segment_s=120.0 if args.fit_segment is None else args.fit_segment,
                              candidates=candidates,
                              workers=args.workers or os.cpu_count() or 1, **options)
    except ValueError as exc:  # each names the recording or plant file at fault
        raise UsageError(str(exc)) from None
    if args.use_pressure and d.pressure_noise_mpa is None:
        print("--use-pressure: the recording has no usable p_mpa column (missing, constant, short or not "
              "finite); judged on the displacement alone")
    notes = list(d.notes)
    if args.effects is not None and any(f.effect == "unexplained" for f in d.findings):
        # a discriminating experiment's re-diagnosis searches among its alternatives: what else the rig
        # has (a delay the first diagnosis did not name) is left, and said where a residual remains
        notes.append(f"the search was restricted to --effects {','.join(c.name for c in candidates)}, and a structured "
                     "residual remains (unexplained, below): diagnose this recording again without --effects to search "
                     "every candidate")
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    for line in summary_lines(d):
        print(line)
    print(f"wrote {Path(out) / 'diagnosis.json'}, calibrated_plant.json, report.md"
          + (", discriminating_input.csv, discriminate_plant.json" if d.ambiguous else "")
          + ("" if args.no_plots else " and *.png") + f" ({d.simulations} simulations, {d.elapsed_s:.1f} s)")
    return 0


def _own_candidates(path: str) -> list:
    """The candidates of one's own that the Python file ``path`` defines as ``candidates`` (a list of
    :class:`~tapmuscle.diagnosis.candidates.Candidate`), or a :class:`UsageError` naming the file and
    what is wrong: missing, failing to run (its exception and line), no such list."""
    import importlib.util
    import traceback

    from tapmuscle.diagnosis.candidates import Candidate

    file = Path(path)
    if not file.is_file():
        raise UsageError(f"--candidates {path}: no such file (a Python file defining candidates = [Candidate(...), "
                         "...]: docs/diagnosis.md, \"A candidate of your own\")")
    spec = importlib.util.spec_from_file_location(f"tapmuscle_own_candidates_{file.stem}", file)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # the user's code: where it failed in it
        lines = [f.lineno for f in traceback.extract_tb(exc.__traceback__) if Path(f.filename).resolve() == file.resolve()]
        if isinstance(exc, SyntaxError) and exc.lineno is not None:
            lines.append(exc.lineno)
        where = f", line {lines[-1]}" if lines else ""
        raise UsageError(f"--candidates {path}{where}: {type(exc).__name__}: {exc}") from exc
    found = getattr(module, "candidates", None)
    if found is None:
        raise UsageError(f"--candidates {path}: it defines no 'candidates' (a list of tapmuscle.diagnosis.Candidate "
                         "objects: docs/diagnosis.md, \"A candidate of your own\")")
    items = [found] if isinstance(found, Candidate) else list(found) if isinstance(found, (list, tuple)) else None
    if items is None or not items or not all(isinstance(c, Candidate) for c in items):
        raise UsageError(f"--candidates {path}: its 'candidates' is {type(found).__name__} {found!r:.60}, not a "
                         "non-empty list of tapmuscle.diagnosis.Candidate objects")
    return items


def _is_foreign(plant: str) -> bool:
    """Is ``plant`` an FMU other than tapmuscle's MusclePlant (read from its model description)?"""
    from tapmuscle.diagnosis.foreign_model import ForeignFmuError, read_interface

    if not str(plant).lower().endswith(".fmu") or not os.path.isfile(plant):
        return False  # the plant's own reader names what is wrong with it
    try:
        return read_interface(plant).model_name != "MusclePlant"
    except ForeignFmuError as exc:
        raise UsageError(str(exc)) from None


def _diagnose_foreign(args: argparse.Namespace) -> int:
    from tapmuscle.progress import Progress
    from tapmuscle.diagnosis.foreign_diagnose import diagnose_foreign, diagnose_foreign_outputs
    from tapmuscle.diagnosis.foreign_model import ForeignFmuError
    from tapmuscle.diagnosis.report import summary_lines
    from tapmuscle.diagnosis.signal_map import SignalMapError
    from tapmuscle.io.recording import RecordingError

    if args.calibrate is not None:
        raise UsageError(f"--calibrate names tapmuscle's plant constants; {args.plant} is another model: its map "
                         "file's [calibrate] table lists the parameters to recalibrate (docs/diagnosis.md, \"Foreign "
                         "plant FMUs\")")
    effects = None if args.effects is None else _effect_list(args.effects)
    options = dict(map_path=args.map, block_s=args.block,
                   fit_segment_s=args.fit_segment, effects=effects,
                   calibrate=not args.no_calibration, plots=not args.no_plots,
                   progress=Progress("diagnose", enabled=not args.quiet, counts=False))
    try:
        if args.output == "all":
            results = diagnose_foreign_outputs(args.recording, args.plant, args.out, **options)
        else:
            d, _ = diagnose_foreign(args.recording, args.plant, args.out, output=args.output, **options)
    except (RecordingError, SignalMapError, ForeignFmuError) as exc:
        raise UsageError(str(exc)) from None
    except ValueError as exc:  # the API names the recording where the fault is its own
        named = str(exc).startswith(str(args.recording))
        raise UsageError(str(exc) if named else f"{args.recording}: {exc}") from None
    if args.output == "all":
        print((Path(args.out) / "summary.md").read_text(encoding="utf-8"), end="")
        print(f"wrote {Path(args.out) / 'summary.md'}, summary.json and {', '.join(os.path.join(v, '') for v in results)}")
        return 0
    for line in summary_lines(d):
        print(line)
    print(f"wrote {Path(args.out) / 'diagnosis.json'}, calibrated_parameters.json, report.md"
          + ("" if args.no_plots else ", overlay.png") + f" ({d.simulations} simulations, {d.elapsed_s:.1f} s)")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from tapmuscle.progress import Progress

    field_only = {"--recordings": args.recordings, "--seed": args.seed, "--resume": args.resume or None,
                  "--use-pressure": args.use_pressure or None, "--keep-files": args.keep_files or None}
    concealed_only = {"--seeds": args.seeds, "--clean-seeds": args.clean_seeds, "--effects": args.effects,
                      "--excitations": args.excitations}
    home = {"field": "field", "concealed": "concealed", "foreign": "field"}[args.suite]
    wrong = [k for k, v in (concealed_only if home == "field" else field_only).items() if v is not None]
    if wrong:
        raise UsageError(f"{', '.join(wrong)} belong{'s' if len(wrong) == 1 else ''} to --suite "
                         f"{'concealed' if home == 'field' else 'field'}, not --suite {args.suite}")
    for flag, value in (("--resume", args.resume), ("--use-pressure", args.use_pressure),
                        ("--keep-files", args.keep_files)):
        if args.suite == "foreign" and value:
            raise UsageError(f"{flag} belongs to --suite field, not --suite foreign")
    progress = Progress("demo-mismatch", enabled=not args.quiet)
    if args.suite == "foreign":
        from tapmuscle.diagnosis.foreign_demo import foreign_scores_markdown, run_foreign_demo

        scores = run_foreign_demo(args.out, n=40 if args.recordings is None else args.recordings,
                                  seed=0 if args.seed is None else args.seed, jobs=args.jobs, progress=progress)
        print(foreign_scores_markdown(scores))
        print(f"wrote {Path(args.out) / 'scores.md'}, scores.json and cases/*/ (recording.csv, map.toml, diagnosis/)")
        return 0
    if args.suite == "field":
        from tapmuscle.diagnosis.field_demo import run_field_demo, scores_markdown as field_markdown

        n = 120 if args.recordings is None else args.recordings
        scores = run_field_demo(args.out, n=n, seed=0 if args.seed is None else args.seed, jobs=args.jobs,
                                resume=args.resume, progress=progress, use_pressure=args.use_pressure,
                                keep=args.keep_files)
        print(field_markdown(scores))
        print(f"wrote {Path(args.out) / 'scores.md'}, scores.json (every case's truth and result), confusion.png and "
              f"cases/*/diagnosis.json, report.md" + (" and the recordings, plants and experiments" if args.keep_files else ""))
        return 0

    from tapmuscle.diagnosis.demo import EXCITATIONS, MAGNITUDES, run_demo, scores_markdown

    effects = None if args.effects is None else tuple(_effect_list(args.effects))
    if effects is not None and not effects:
        raise UsageError(f"--effects {args.effects!r} names no effect; known: {', '.join(MAGNITUDES)} "
                         "(leave the flag out for all)")
    for e in effects or ():
        if e not in MAGNITUDES:
            raise UsageError(f"--effects: unknown effect {e!r}; known: {', '.join(MAGNITUDES)}")
    excitations = (EXCITATIONS if args.excitations is None
                   else tuple(x.strip() for x in args.excitations.split(",") if x.strip()))
    if not excitations:
        raise UsageError(f"--excitations {args.excitations!r} names no excitation; known: {', '.join(EXCITATIONS)}")
    for x in excitations:
        if x not in EXCITATIONS:
            raise UsageError(f"--excitations: unknown excitation {x!r}; known: {', '.join(EXCITATIONS)}")
    scores = run_demo(args.out, seeds=3 if args.seeds is None else args.seeds,
                      clean_seeds=20 if args.clean_seeds is None else args.clean_seeds, jobs=args.jobs,
                      effects=effects, excitations=excitations, progress=progress)
    print(scores_markdown(scores))
    print(f"wrote {Path(args.out) / 'scores.json'}, scores.md, showcase/ (the sag-window and Fig. 20 cases with their "
          f"reports) and cases/*/diagnosis.json")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``diagnose`` and ``demo-mismatch`` to the ``tapmuscle`` command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subparsers of the ``tapmuscle`` parser.
    """
    dia = sub.add_parser("diagnose", help="locate and explain where a simulation and a rig recording differ",
                         description="Re-simulate a recording's command with the plant, recalibrate the nominal "
                                     "constants the recording identifies, then fit the candidate left-out effects "
                                     "jointly with them on training blocks and score them on held-out blocks; say "
                                     "'ambiguous' and design a discriminating input when alternatives tie "
                                     "(docs/diagnosis.md).")
    dia.add_argument("--recording", required=True, help="recording CSV (docs/recordings.md): t_s,u_v,l_mm[,load_n,p_mpa]")
    dia.add_argument("--plant", required=True,
                     help="a MusclePlant .fmu or a plant parameter .json; or any FMI 2.0 FMU (co-simulation, or model "
                          "exchange integrated by CVode) "
                          "(boundary effects and calibration of its parameters, docs/diagnosis.md)")
    dia.add_argument("--map", default=None,
                     help="foreign FMU: MAP.toml saying which columns drive which inputs and which are measured "
                          "outputs (default: columns named as the FMU's variables; the mapping is printed)")
    dia.add_argument("--output", default=None,
                     help="foreign FMU: the mapped output to diagnose (default: the first); 'all': each mapped "
                          "output in turn, into OUT/<output>/, with OUT/summary.md setting them side by side")
    dia.add_argument("--out", type=output_path("--out", "folder"), required=True, help="output folder")
    dia.add_argument("--block", type=number_within("--block", 0.5, 3600.0), default=None,
                     help="length of the interleaved training / held-out blocks [s] (default 10, or, for a "
                          "continuous command (the first input of a foreign FMU) that the training blocks see "
                          "rise and the held-out ones fall, the nearest length that balances them)")
    dia.add_argument("--fit-segment", type=number_within("--fit-segment", 0.5, 3600.0), default=None,
                     help="stationary effects are fitted on the first this many seconds (default 120 for "
                          "tapmuscle's plant, the whole recording for a foreign FMU)")
    dia.add_argument("--effects", default=None,
                     help="comma-separated candidate effects to consider (default all), e.g. the alternatives of an "
                          "ambiguous verdict when diagnosing the discriminating experiment's recording")
    dia.add_argument("--candidates", default=None, metavar="FILE.py",
                     help="a Python file defining candidates = [Candidate(...), ...], effects of your own tried "
                          "beside the built-in ones (--effects may name them); it is run as Python code, so give "
                          "only a file you trust (docs/diagnosis.md, \"A candidate of your own\")")
    dia.add_argument("--no-calibration", action="store_true",
                     help="take the plant's nominal constants as exact (skip the calibration step)")
    dia.add_argument("--calibrate", default=None, metavar="KEY,...",
                     help="the plant's constants to recalibrate, comma-separated (default: the twelve of "
                          "docs/diagnosis.md, step 4; 'default' names them, e.g. default,load.load_n): any "
                          "constant of the rig but an effect's, sensor's or solver's parameter")
    dia.add_argument("--workers", type=integer_at_least("--workers", 1), default=None,
                     help="processes for the independent simulations (default: all cores; 1: this process "
                          "only); the diagnosis is the same")
    dia.add_argument("--use-pressure", action="store_true",
                     help="weigh the recording's p_mpa beside l_mm in the fits and tests (docs/diagnosis.md)")
    dia.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    dia.add_argument("--quiet", action="store_true", help="no progress output")
    dia.set_defaults(func=_cmd_diagnose)

    demo = sub.add_parser("demo-mismatch", help="prove the diagnosis on simulated recordings with known truth",
                          description="The proof of tapmuscle diagnose. Suite 'field' (default): N recordings of "
                                      "rigs with 3-6 constants off by up to 20 % and 0, 1 or 2 effects of the "
                                      "vocabulary or a disturbance outside it, open and closed loop; diagnosed "
                                      "from the CSV alone, scored, confusion table. Suite 'concealed': one "
                                      "effect concealed in the exact model (every effect x 3 magnitudes x "
                                      "excitations x seeds), clean recordings, a 60-90 s supply sag and the "
                                      "Fig. 20 case (docs/diagnosis.md).")
    demo.add_argument("--out", type=output_path("--out", "folder"), required=True, help="output folder")
    demo.add_argument("--suite", choices=("field", "concealed", "foreign"), default="field",
                      help="field recordings (default), the concealed-effect proof, or foreign FMUs (a DC motor "
                           "in C, a thermal two-mass model in pythonfmu) with concealed boundary effects")
    demo.add_argument("--recordings", type=integer_at_least("--recordings", 1), default=None,
                      help="field / foreign: number of recordings (default 120 / 40)")
    demo.add_argument("--seed", type=integer_at_least("--seed", 0), default=None,
                      help="field: seed of the drawn cases (default 0)")
    demo.add_argument("--resume", action="store_true",
                      help="field: reuse the cases that an interrupted run into --out finished (same truths)")
    demo.add_argument("--seeds", type=integer_at_least("--seeds", 1), default=None,
                      help="concealed: seeds per effect, level and excitation (default 3)")
    demo.add_argument("--clean-seeds", type=integer_at_least("--clean-seeds", 0), default=None,
                      help="concealed: clean recordings (default 20)")
    demo.add_argument("--effects", help="concealed: comma-separated subset of the effects (default all)")
    demo.add_argument("--excitations", help="concealed: comma-separated subset of sine,ampc,steps (default all)")
    demo.add_argument("--jobs", type=integer_at_least("--jobs", 1), default=None, help="worker processes (default: all cores)")
    demo.add_argument("--use-pressure", action="store_true",
                      help="field: diagnose with the recorded pressure beside the displacement")
    demo.add_argument("--keep-files", action="store_true",
                      help="field: keep each case's recordings, calibrated plants and designed experiments "
                           "(default: only diagnosis.json and report.md)")
    demo.add_argument("--quiet", action="store_true", help="no progress output")
    demo.set_defaults(func=_cmd_demo)
