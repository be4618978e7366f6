"""``tapmuscle diagnose`` and ``tapmuscle demo-mismatch``: thin shells around :mod:`diagnosis`."""

from __future__ import annotations

import argparse
from pathlib import Path

from .arguments import integer_at_least, number_within

__all__ = ["register"]


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from diagnosis.report import diagnose_files, summary_lines

    from .cli import UsageError
    from .plant_file import PlantFileError
    from .progress import Progress
    from .recording import RecordingError

    out = Path(args.out)
    try:
        d, _ = diagnose_files(args.recording, args.plant, out, plots=not args.no_plots,
                              progress=Progress("diagnose", enabled=not args.quiet, min_total=1),
                              block_s=args.block, fit_segment_s=args.fit_segment)
    except (RecordingError, PlantFileError) as exc:
        raise UsageError(str(exc)) from None
    except ValueError as exc:
        raise UsageError(f"{args.recording}: {exc}") from None
    for line in summary_lines(d):
        print(line)
    print(f"wrote {out}/diagnosis.json, calibrated_plant.json, report.md"
          + ("" if args.no_plots else " and *.png") + f" ({d.simulations} simulations, {d.elapsed_s:.1f} s)")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from diagnosis.demo import EXCITATIONS, MAGNITUDES, run_demo, scores_markdown

    from .cli import UsageError
    from .progress import Progress

    effects = tuple(args.effects.split(",")) if args.effects else None
    for e in effects or ():
        if e not in MAGNITUDES:
            raise UsageError(f"--effects: unknown effect {e!r}; known: {', '.join(MAGNITUDES)}")
    excitations = tuple(args.excitations.split(","))
    for x in excitations:
        if x not in EXCITATIONS:
            raise UsageError(f"--excitations: unknown excitation {x!r}; known: {', '.join(EXCITATIONS)}")
    scores = run_demo(args.out, seeds=args.seeds, clean_seeds=args.clean_seeds, jobs=args.jobs, effects=effects,
                      excitations=excitations,
                      progress=Progress("demo-mismatch", enabled=not args.quiet, min_total=1))
    print(scores_markdown(scores))
    print(f"wrote {args.out}/scores.json, scores.md, showcase/ (the sag-window and Fig. 20 cases with their "
          f"reports) and cases/*/diagnosis.json")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``diagnose`` and ``demo-mismatch`` to the ``tapmuscle`` command line."""
    dia = sub.add_parser("diagnose", help="locate and explain where a simulation and a rig recording differ",
                         description="Re-simulate a recording's command with the plant, locate the residual in "
                                     "time and operating regime, fit the candidate left-out effects on training "
                                     "blocks, score them on held-out blocks (docs/diagnosis.md).")
    dia.add_argument("--recording", required=True, help="recording CSV (docs/recordings.md): t_s,u_v,l_mm[,load_n,p_mpa]")
    dia.add_argument("--plant", required=True, help="a MusclePlant .fmu, or a plant parameter .json")
    dia.add_argument("--out", required=True, help="output folder")
    dia.add_argument("--block", type=number_within("--block", 0.5, 3600.0), default=10.0,
                     help="length of the interleaved training / held-out blocks [s] (default 10)")
    dia.add_argument("--fit-segment", type=number_within("--fit-segment", 0.5, 3600.0), default=120.0,
                     help="stationary effects are fitted on the first this many seconds (default 120)")
    dia.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    dia.add_argument("--quiet", action="store_true", help="no progress output")
    dia.set_defaults(func=_cmd_diagnose)

    demo = sub.add_parser("demo-mismatch", help="prove the diagnosis on recordings with a concealed effect",
                          description="Record the simulated rig with one effect concealed (every effect x 3 "
                                      "magnitudes x excitations x seeds), clean recordings, a 60-90 s supply "
                                      "sag and the Fig. 20 case; diagnose each from its CSV alone and score.")
    demo.add_argument("--out", required=True, help="output folder")
    demo.add_argument("--seeds", type=integer_at_least("--seeds", 1), default=3, help="seeds per effect, level and excitation (default 3)")
    demo.add_argument("--clean-seeds", type=integer_at_least("--clean-seeds", 0), default=20, help="clean recordings (default 20)")
    demo.add_argument("--effects", help="comma-separated subset of the effects (default all)")
    demo.add_argument("--excitations", default="sine,ampc,steps", help="comma-separated subset of sine,ampc,steps")
    demo.add_argument("--jobs", type=integer_at_least("--jobs", 1), default=None, help="worker processes (default: all cores)")
    demo.add_argument("--quiet", action="store_true", help="no progress output")
    demo.set_defaults(func=_cmd_demo)
