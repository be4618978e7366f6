"""The ``tapmuscle`` command line: a thin shell around the numerics packages.

Each subcommand parses and validates its arguments, calls pure functions, and writes its outputs
atomically. Errors in the user's input end with ``tapmuscle <cmd>: error: ...`` and exit status 2,
having written nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Sequence

__all__ = ["main"]


class UsageError(ValueError):
    """A problem with the user's input; reported without a traceback."""


def _positive(name: str, lo: float, hi: float):
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
        if not math.isfinite(v) or not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{name} must be within {lo:g}..{hi:g}, got {text!r}")
        return v
    return parse


def _load_plant_params(path: str | None, overrides: Sequence[str]):
    from fmu_plant import PlantParams

    params = PlantParams()
    if path:
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise UsageError(f"--params: no such file {path!r}") from None
        except json.JSONDecodeError as exc:
            raise UsageError(f"--params {path}: not valid JSON (line {exc.lineno}, column {exc.colno}): {exc.msg}") from None
        try:
            params = PlantParams.from_dict(data.get("plant", data) if isinstance(data, dict) else data)
        except ValueError as exc:
            raise UsageError(f"--params {path}: {exc}") from None
    flat = {}
    for item in overrides:
        key, eq, text = item.partition("=")
        if not eq:
            raise UsageError(f"--set expects group.field=value, got {item!r}")
        try:
            flat[key.strip()] = float(text)
        except ValueError:
            raise UsageError(f"--set {item!r}: {text!r} is not a number") from None
    try:
        return params.with_values(**flat) if flat else params
    except ValueError as exc:
        raise UsageError(f"--set: {exc}") from None


# --------------------------------------------------------------------------------------- record
def _cmd_record(args: argparse.Namespace) -> int:
    from fmu_plant import Plant
    from fmu_plant.open_loop import run_open_loop

    from .figures import plot_recording
    from .progress import Progress
    from .recording import Recording, write_recording
    from .signals import parse_input_spec

    if args.ts > args.duration:
        raise UsageError(f"--ts ({args.ts:g} s) must not exceed --duration ({args.duration:g} s)")
    try:
        signal = parse_input_spec(args.input)
    except ValueError as exc:
        raise UsageError(f"--input: {exc}") from None
    params = _load_plant_params(args.params, args.set)
    overrides = {"load.load_n": args.load}
    if args.no_noise:
        overrides.update({"sensor.encoder_noise_std_mm": 0.0, "sensor.pressure_noise_std_mpa": 0.0})
    params = params.with_values(**overrides)
    plant = Plant(params, seed=args.seed)
    try:
        data = run_open_loop(plant, signal, duration_s=args.duration, ts_s=args.ts,
                             progress=Progress("record", enabled=not args.quiet))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    meta = {"ts_s": f"{args.ts:g}", "load_n": f"{args.load:g}", "seed": str(args.seed),
            "input": args.input, "source": "tapmuscle record (simulated rig)",
            "command": " ".join(["tapmuscle"] + list(args.argv))}
    rec = Recording(data, meta)
    out = Path(args.out)
    write_recording(out, rec)
    print(f"wrote {out} ({len(rec)} samples, l {rec.l_mm.min():.2f}..{rec.l_mm.max():.2f} mm)")
    if args.plot:
        png = plot_recording(rec.t_s, rec.u_v, rec.l_mm, out.with_suffix(".png"), p_mpa=data["p_mpa"],
                             title=f"{args.input}, load {args.load:g} N, seed {args.seed}",
                             settle_s=min(30.0, args.duration / 2))
        print(f"wrote {png}")
    return 0


# --------------------------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tapmuscle", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    rec = sub.add_parser("record", help="run the simulated rig open-loop and write a recording CSV",
                         description="Run the simulated rig open-loop with a valve-command signal and "
                                     "write a recording (docs/recordings.md).")
    rec.add_argument("--load", type=_positive("--load", 1e-9, 500.0), default=44.0,
                     help="hanging load [N], 0 < load <= 500 (paper: 44, 68)")
    rec.add_argument("--input", required=True,
                     help="command spec, e.g. sine:bias=5,amp=3,freq=0.1 | step:initial=4,final=6,at=10 | "
                          "steps:levels=3/7/5,period=20 | chirp:f0=0.01,f1=0.5 | random:lo=2,hi=8,seed=1 | csv:PATH")
    rec.add_argument("--duration", type=_positive("--duration", 1e-3, 86400.0), required=True,
                     help="length [s]")
    rec.add_argument("--ts", type=_positive("--ts", 1e-3, 10.0), default=0.1, help="sampling period [s]")
    rec.add_argument("--seed", type=int, default=0, help="noise seed (>= 0)")
    rec.add_argument("--out", required=True, help="output CSV path")
    rec.add_argument("--plot", action="store_true", help="also write OUT.png: time traces and hysteresis loop")
    rec.add_argument("--no-noise", action="store_true", help="switch sensor noise off (quantisation stays)")
    rec.add_argument("--params", help="plant parameter file (JSON, as written by `tapmuscle diagnose`)")
    rec.add_argument("--set", action="append", default=[], metavar="GROUP.FIELD=VALUE",
                     help="override one plant parameter, e.g. --set friction.rate_gain=0 (repeatable)")
    rec.add_argument("--quiet", action="store_true", help="no progress output")
    rec.set_defaults(func=_cmd_record)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tapmuscle`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = argv
    if getattr(args, "seed", 0) is not None and getattr(args, "seed", 0) < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    try:
        return int(args.func(args) or 0)
    except UsageError as exc:
        print(f"tapmuscle {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except (OSError, ValueError) as exc:
        print(f"tapmuscle {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
