"""The ``tapmuscle`` command line: a thin shell around the numerics packages.

Each subcommand parses and validates its arguments, calls pure functions, and writes its outputs
atomically. Errors in the user's input end with ``tapmuscle <cmd>: error: ...`` and exit status 2,
having written nothing.
"""

from __future__ import annotations

import argparse
import codecs
import io
import json
import math
import os
import signal
import sys
import threading
import warnings
from collections import Counter
from pathlib import Path
from typing import Any, Sequence

from tapmuscle.cli.arguments import integer_at_least, number_within, output_path
from tapmuscle.cli.diagnose import register as _register_diagnose
from tapmuscle.cli.rig_import import register as _register_import
from tapmuscle.cli.sweep import register as _register_sweep
from tapmuscle.errors import UsageError
from tapmuscle.plots.figure_formats import FIGURE_FORMATS
from tapmuscle.provenance import invoked_as, produced_by

__all__ = ["main", "build_parser", "MAX_SAMPLES"]

#: Most samples of one recording (24 h at Ts = 0.1 s, the longest --duration): a finer --ts over such a
#: length is almost surely a unit mistake, and it would run for a day.
MAX_SAMPLES = 864_001

#: fmu_plant.seed.SEED_MAX, written out so that the parser does not import the numerics (startup
#: time); tests/test_cli_record.py checks that they agree.
_SEED_MAX = 2 ** 64 - 1

#: fmu_controller.prediction.MAX_INPUT_DELAY_SAMPLES, written out for the same reason;
#: tests/test_identify_cli.py checks that they agree.
_INPUT_DELAY_MAX = 25


def _load_plant_params(path: str | None, overrides: Sequence[str]):
    from fmu_plant import PlantParams

    from tapmuscle.io.plant_file import PlantFileError, read_plant_file

    params = PlantParams()
    if path:
        try:
            params = read_plant_file(path, "--params")
        except PlantFileError as exc:
            raise UsageError(str(exc)) from None
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
    from fmu_plant.open_loop import run_open_loop, run_samples

    from tapmuscle.progress import Progress
    import numpy as np

    from tapmuscle.io.atomic import atomic_path
    from tapmuscle.io.recording import Recording, write_recording
    from tapmuscle.io.signals import parse_input_spec

    if args.ts > args.duration:
        raise UsageError(f"--ts ({args.ts:g} s) must not exceed --duration ({args.duration:g} s)")
    try:
        signal = parse_input_spec(args.input, run_duration_s=args.duration, run_ts_s=args.ts)
    except ValueError as exc:
        raise UsageError(f"--input: {exc}") from None
    params = _load_plant_params(args.params, args.set)
    set_load = any(item.partition("=")[0].strip() == "load.load_n" for item in args.set)
    if args.load is not None and set_load and args.load != params.load.load_n:
        raise UsageError(f"--load {args.load:g} and --set load.load_n={params.load.load_n:g} name two loads: give it once")
    # --load overrides the --params file's load; without it the file's (or --set's) load is recorded
    load_n = params.load.load_n if args.load is None else args.load
    overrides = {"load.load_n": load_n}
    if args.no_noise:
        overrides.update({"sensor.encoder_noise_std_mm": 0.0, "sensor.pressure_noise_std_mpa": 0.0})
    params = params.with_values(**overrides)
    # the recorded u_v is the command the valve receives: a signal outside the valve's range is the
    # user's mistake (the amplifier would clip it), named before anything runs
    try:
        n = run_samples(args.duration, args.ts, names=("--duration", "--ts"))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if n > MAX_SAMPLES:
        raise UsageError(f"--duration {args.duration:g} / --ts {args.ts:g} makes {n} samples; at most {MAX_SAMPLES} "
                         "in one recording")
    t_grid = np.arange(n) * args.ts
    u_grid = np.array([signal(t) for t in t_grid])
    lo, hi = params.valve.u_min_v, params.valve.u_max_v
    bad = np.nonzero(~((u_grid >= lo) & (u_grid <= hi)))[0]
    if bad.size:
        k = int(bad[0])
        raise UsageError(f"--input {args.input!r}: the command is {float(u_grid[k]):.6g} V at t = {float(t_grid[k]):g} s; "
                         f"the valve takes {lo:g}..{hi:g} V")
    plant = Plant(params, seed=args.seed)
    try:
        data = run_open_loop(plant, signal, duration_s=args.duration, ts_s=args.ts,
                             progress=Progress("record", enabled=not args.quiet, min_total=500))
    except (ValueError, FloatingPointError) as exc:
        raise UsageError(str(exc)) from None
    meta = {"ts_s": f"{args.ts:g}", "load_n": f"{load_n:g}", "seed": str(args.seed),
            "input": args.input, "source": "tapmuscle record (simulated rig)",
            "command": " ".join(["tapmuscle"] + list(args.argv))}
    rec = Recording(data, meta)
    out = Path(args.out)
    png = out.with_suffix(".png")
    # both files or neither: the CSV is renamed into place only after the plot succeeded
    with atomic_path(out) as tmp_csv:
        write_recording(tmp_csv, rec)
        if args.plot:
            # matplotlib only when plotting: its import alone writes to stderr where HOME is not writable
            from tapmuscle.plots.figures import plot_recording

            with atomic_path(png, suffix=".png") as tmp_png:
                plot_recording(rec.t_s, rec.u_v, rec.l_mm, tmp_png, p_mpa=data["p_mpa"],
                               title=f"{args.input}, load {load_n:g} N, seed {args.seed}",
                               settle_s=min(30.0, args.duration / 2))
    print(f"wrote {out} ({len(rec)} samples, l {rec.l_mm.min():.2f}..{rec.l_mm.max():.2f} mm)")
    if args.plot:
        print(f"wrote {png}")
    return 0


# --------------------------------------------------------------------------------------- identify
def _parse_box(text: str):
    if text in ("auto", "none"):
        return None if text == "none" else "auto"
    if not text.strip():
        raise UsageError("--box '' names no bound: give 'auto', 'none' or name=lower:upper,... "
                         "(e.g. a1=1.208:1.26,b1=0.6:1.2)")
    box = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        name, eq, rng = item.partition("=")
        lo, colon, hi = rng.partition(":")
        if not eq or not colon:
            raise UsageError(f"--box: expected name=lower:upper, got {item!r} (e.g. a1=1.208:1.26,b1=0.6:1.2)")
        name = name.strip()
        if name in box:
            raise UsageError(f"--box: {name!r} is given twice")
        try:
            bounds = (float(lo), float(hi))
        except ValueError:
            raise UsageError(f"--box: bounds of {name!r} must be numbers, got {rng!r}") from None
        if any(math.isnan(b) for b in bounds):  # an infinite one is a one-sided box
            raise UsageError(f"--box: bounds of {name!r} must be numbers, not NaN, got {rng!r}")
        box[name] = bounds
    return box


def _identify_notes(args: argparse.Namespace, rec, val, report, choice) -> list[str]:
    """What ``identify`` says beside its figures: the identification's notes, the recording's jitter, a
    validation record at another load, and with ``--input-delay-samples auto`` what the delays' fits
    leave open (printed and in the JSON)."""
    from fmu_controller.input_delay_choice import THIN_MARGIN_PERCENT

    jitter = rec.sampling.note()
    notes = list(report.notes) + ([jitter] if jitter else [])
    filled = int((rec.columns["filled"] != 0).sum()) if "filled" in rec.columns else 0
    if filled:  # tapmuscle import --fill-gaps: the diagnosis leaves them out, RLS needs every sample
        notes.append(f"{filled} samples of the record were filled in by interpolation (its column filled, tapmuscle "
                     "import --fill-gaps) and are fitted as if measured; over a long gap the fits and the model "
                     "lean on the straight line drawn there")
    if val is not None:
        loads = [r.metadata.get("load_n") for r in (rec, val)]
        if None not in loads and loads[0] != loads[1]:
            notes.append(f"the validation record {Path(args.validate).name} was taken at {loads[1]} N, the identification "
                         f"record at {loads[0]} N: Eq. (1) holds for the load it was identified at, so the validation "
                         "fits score the load change too")
    if choice is None:
        return notes
    if choice.constraint_start_s != args.constraint_start and (report.box_lower or report.box_upper):  # a box to start
        notes.append(f"the delays were compared with Algorithm 1's box from {choice.constraint_start_s:g} s (half the "
                     f"record): --constraint-start {args.constraint_start:g} lies beyond its end, and unconstrained "
                     "estimates tell delays apart less well")
    if choice.between_samples:
        d, fits = choice.input_delay_samples, choice.fits_percent
        notes.append(f"the rig's delay lies between {d - 1} and {d} samples (1-step fits {fits[d - 1]:.2f} and "
                     f"{fits[d]:.2f} %): {d} is taken, the longer, which the controllers track better with "
                     "(docs/identification.md, \"Transport delay\")")
    if choice.margin_percent < THIN_MARGIN_PERCENT:
        notes.append(f"the best fit leads the next by {choice.margin_percent:.3f} % only: this record hardly tells "
                     "those delays apart; check the choice on another record (--validate), or record a longer random "
                     "command")
    if choice.at_largest:
        d = choice.input_delay_samples
        further = ("the controllers take at most that" if d >= _INPUT_DELAY_MAX else
                   f"identify with --input-delay-samples N for a longer one, up to {_INPUT_DELAY_MAX}, and compare "
                   "the 1-step fits")
        notes.append(f"the fit is best at the largest delay tried ({d} samples, {d * rec.ts_s:g} s): the rig's "
                     f"delay may be larger still ({further})")
    return notes


def _cmd_identify(args: argparse.Namespace) -> int:
    from fmu_controller.identification import identify_record, score_model
    from fmu_controller.input_delay_choice import choose_input_delay, search_samples

    from tapmuscle.progress import Progress

    from tapmuscle.plots.figures import (input_jumps, plot_input_delay_fits, plot_loop_comparison, plot_model_vs_measured,
                                         plot_parameter_convergence)
    from tapmuscle.io.atomic import atomic_path, staged_folder
    from tapmuscle.io.json_file import json_text
    from fmu_controller.hysteresis_model import THETA_UNITS
    from tapmuscle.io.recording import Recording, atomic_write_text, read_recording, write_recording
    from tapmuscle.io.sampling import STRICT_TOLERANCE, check_sampling_period

    rec = read_recording(args.recording)
    val = read_recording(args.validate) if args.validate else None
    for path, r in ((args.recording, rec), (args.validate, val)):
        try:
            if r is not None:
                check_sampling_period(r.ts_s)
        except ValueError as exc:
            raise UsageError(f"{path}: {exc}") from None
    # the periods of two jittered logs (each a least-squares grid) agree as closely as a header must
    if val is not None and abs(val.ts_s - rec.ts_s) > STRICT_TOLERANCE * rec.ts_s:
        raise UsageError(f"--validate {args.validate}: sampling period {val.ts_s:g} s differs from the "
                         f"identification record's {rec.ts_s:g} s (by more than {100 * STRICT_TOLERANCE:g} %)")
    # the period as the grid's least-squares slope carries the written times' rounding (0.05000000000000071):
    # nine digits are far inside the tolerance two periods must agree to
    options = dict(ts_s=float(f"{rec.ts_s:.9g}"), model=args.model, box=_parse_box(args.box), constraint_start_s=args.constraint_start,
                   forgetting=args.forgetting)
    # the work's steps, reported as each starts (the inputs checked first: a refusal comes alone); an
    # identification of a long record, and the delays of auto, take minutes, through which the
    # report's heartbeat says the command is still running
    progress = Progress("identify", enabled=not args.quiet)
    steps = ["identify"] + (["validate"] if val is not None else []) + (["plot"] if args.plot else [])
    # auto's identifications each a unit of the identify step, so that its report moves with them, and
    # one more for the choice (a re-identification where the box's start moved) and the writing
    per_step = search_samples(options["ts_s"]) + 2 if args.input_delay_samples == "auto" else 1

    def step(name: str, what: str) -> None:
        progress(steps.index(name) * per_step, len(steps) * per_step, what)
    choice = None
    try:
        if args.input_delay_samples == "auto":
            step("identify", f"identifying Eq. (1) on {len(rec)} samples under each input delay 0..{per_step - 2} "
                             f"samples ({per_step - 1} identifications)")
            choice = choose_input_delay(rec.u_v, rec.l_mm, **options, on_delay=lambda done, total: progress(
                done, len(steps) * per_step, f"identified under delays 0..{done - 1} of 0..{total - 1}"))
            report = choice.report
        else:
            step("identify", f"identifying Eq. (1) on {len(rec)} samples")
            report = identify_record(rec.u_v, rec.l_mm, input_delay_samples=args.input_delay_samples, **options)
    except ValueError as exc:
        raise UsageError(f"{args.recording}: {exc}") from None
    # the recording as given and as an absolute path (the first is relative to where identify ran), and
    # its load: a model holds for the load it was identified at
    load = rec.metadata.get("load_n")
    try:
        load = float(load) if load is not None else None
    except ValueError:  # free text in the header: kept as written
        pass
    out = report.to_dict() | {"recording": str(args.recording), "recording_path": str(Path(args.recording).resolve()),
                              "load_n": load, **produced_by()}
    notes = _identify_notes(args, rec, val, report, choice)
    out["notes"] = notes
    if choice is not None:
        out["input_delay_choice"] = {"fit_percent_1_step": list(choice.fits_percent),
                                     "constraint_start_s": choice.constraint_start_s}
    val_fit = None
    if val is not None:
        step("validate", f"scoring the model on {args.validate}")
        val_fit = score_model(report.theta, report.structure, val.u_v, val.l_mm,
                              input_delay_samples=report.input_delay_samples)
        out["validation_fit_percent"] = val_fit.percent
        out["validation_free_run_diverged"] = val_fit.free_run_diverged
        out["validation_recording"] = str(args.validate)
    # the JSON is renamed into place only once the plots are written: a plot folder that cannot be
    # written leaves no JSON behind
    with atomic_path(args.json) as tmp_json:
        atomic_write_text(tmp_json, json_text(out, indent=2))
        if args.plot:
            step("plot", f"plotting into {args.plot}")
            # every file at once, and an earlier run's of these names replaced or removed (its figures
            # in another format, a validation it had): files of other names in the folder stay
            with staged_folder(Path(args.plot), owned=IDENTIFY_PLOT_FILES) as folder:
                fmt = args.figure_format
                t = rec.t_s
                # the figures' data, to redraw them in one's own style
                units = ", ".join(f"{n} {THETA_UNITS[n]}" for n in report.structure.names)
                base = {"source": f"tapmuscle identify {args.recording}", "model": report.model, "ts_s": f"{report.ts_s:g}"}
                write_recording(folder / "identification.csv", Recording(
                    {"t_s": t, "u_v": rec.u_v, "l_mm": rec.l_mm, "l_model_mm": report.fit.simulated_mm}
                    | {f"theta_{n}": report.theta_history[:, i] for i, n in enumerate(report.structure.names)},
                    base | {"l_model_mm": f"the identified model's free run ({report.fit.percent['sim']:.2f} % fit)",
                            "theta_units": units, "theta": "the estimate after each sample (convergence figure)"}))
                if val is not None:
                    write_recording(folder / "validation.csv", Recording(
                        {"t_s": val.t_s, "u_v": val.u_v, "l_mm": val.l_mm, "l_model_mm": val_fit.simulated_mm},
                        base | {"validation_recording": str(args.validate),
                                "l_model_mm": f"the identified model's free run ({val_fit.percent['sim']:.2f} % fit)"}))
                plot_parameter_convergence(t, report.theta_history, report.structure.names, folder / f"convergence.{fmt}",
                                           constraint_start_s=report.constraint_start_s if report.box_lower else None,
                                           bounds={n: (report.box_lower.get(n, -math.inf), report.box_upper.get(n, math.inf))
                                                   for n in report.structure.names},
                                           title=f"{report.model} model: parameter convergence "
                                                 f"({Path(args.recording).name})")
                shown, fit = (val, val_fit) if val is not None else (rec, report.fit)
                label = f"{report.model} model, free run ({fit.percent['sim']:.1f} %)"
                shown_path = args.validate if val is not None else args.recording
                shown_load = shown.metadata.get("load_n")
                plot_model_vs_measured(shown.t_s, shown.u_v, shown.l_mm, {label: fit.simulated_mm},
                                       folder / f"model_vs_measured.{fmt}",
                                       title=f"free run against {'validation' if val is not None else 'identification'} "
                                             f"record {Path(shown_path).name}"
                                             + (f", {shown_load} N" if shown_load else "") + " (cf. Fig. 4)")
                skip = int(len(shown.t_s) // 4)
                jumps = input_jumps(shown.u_v[skip:])
                plot_loop_comparison(shown.u_v, shown.l_mm, {label: fit.simulated_mm}, folder / f"hysteresis_loop.{fmt}",
                                     skip=skip, title=("(u, l) samples" if jumps else "hysteresis loop")
                                     + f" of {Path(shown_path).name}" + (f", {shown_load} N" if shown_load else "")
                                     + f" (t >= {shown.t_s[skip]:g} s; "
                                     + ("the input jumps: points, not a loop)" if jumps else "cf. Fig. 5)"))
                if choice is not None:
                    plot_input_delay_fits(choice.fits_percent, choice.input_delay_samples, rec.ts_s,
                                          folder / f"input_delay_fits.{fmt}",
                                          title=f"1-step fit under each input delay ({Path(args.recording).name})")
    progress(len(steps) * per_step, len(steps) * per_step, f"wrote {args.json}")
    if choice is not None:
        print(f"{'input delay D [samples]':32s}" + "".join(f"{d:7d}" for d in range(len(choice.fits_percent))))
        print(f"{'1-step fit [%] on the record':32s}" + "".join(f"{f:7.2f}" for f in choice.fits_percent)
              + f"  -> D = {choice.input_delay_samples} ({choice.input_delay_samples * rec.ts_s:g} s)")
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    fits = report.fit.percent
    delay = (f", on the command {report.input_delay_samples} sample{'s' if report.input_delay_samples > 1 else ''} "
             "earlier (--input-delay-samples)" if report.input_delay_samples else "")
    print(f"{report.model} model, {report.n_samples} samples at Ts {report.ts_s:g} s{delay} -> {args.json}")
    print("fit [%]      1-step  3-step  5-step  free run")
    print(f"identif.    {fits['1']:7.1f} {fits['3']:7.1f} {fits['5']:7.1f} {fits['sim']:9.1f}"
          + ("  (diverged)" if report.fit.free_run_diverged else ""))
    if val_fit is not None:
        v = val_fit.percent
        print(f"validation  {v['1']:7.1f} {v['3']:7.1f} {v['5']:7.1f} {v['sim']:9.1f}"
              + ("  (diverged)" if val_fit.free_run_diverged else ""))
    if args.plot:
        fmt = args.figure_format
        print(f"wrote {Path(args.plot) / ('convergence.' + fmt)}, model_vs_measured.{fmt}, hysteresis_loop.{fmt}"
              + (f", input_delay_fits.{fmt}" if choice is not None else "")
              + ", identification.csv" + (", validation.csv" if val is not None else "") + " (the figures' data)")
    return 0


#: What ``identify --plot DIR`` writes into DIR (figures in any of the formats, the validation's data
#: only with --validate); other files there are left alone.
IDENTIFY_PLOT_FILES = ("identification.csv", "validation.csv") + tuple(
    f"{name}.{fmt}" for fmt in FIGURE_FORMATS
    for name in ("convergence", "model_vs_measured", "hysteresis_loop", "input_delay_fits"))


# --------------------------------------------------------------------------------------- paper
def _cmd_paper(args: argparse.Namespace) -> int:
    from tapmuscle.paper.reproduce import PAPER_RUNS, checked_seeds, run_paper
    from tapmuscle.progress import Progress

    out = Path(args.out)
    try:
        seeds = tuple(int(x) for x in args.seeds.split(","))
    except ValueError:
        raise UsageError(f"--seeds must be comma-separated integers (0,1,2), got {args.seeds!r}") from None
    try:
        checked_seeds(seeds)
    except ValueError as exc:
        raise UsageError(f"--{exc} (--seeds {args.seeds})") from None
    print(f"tapmuscle paper: section 4's {len(PAPER_RUNS)} closed-loop experiments on the simulated rig -> {os.path.join(out, '')}")
    run_paper(out, seeds=seeds, id_seed=args.id_seed, progress=Progress("paper", enabled=not args.quiet),
              faithful_eq5=args.paper_eq5, faithful_start=args.paper_start, figure_format=args.figure_format)
    print(f"\nwrote {out / 'paper.json'}, {out / 'tables.csv'}, {out / 'runs' / '*.csv'} and "
          f"{out / ('fig*.' + args.figure_format)}")
    return 0


# --------------------------------------------------------------------------------------- build
def _linux64_note(fmu: Path) -> str:
    """What runs the slave in the FMU's linux64 binary, as the build recorded it; "" if not recorded."""
    import zipfile

    from build_scripts.native_host import CONFIG_NAME, machine_name, python_machine

    with zipfile.ZipFile(fmu) as z:
        if f"resources/{CONFIG_NAME}" not in z.namelist():
            return ""
        config = json.loads(z.read(f"resources/{CONFIG_NAME}"))
    library = "pythonfmu's FMI library" if config.get("fmi_export", "pythonfmu") == "pythonfmu" \
        else "the project's FMI export library"
    hosts = "; Python hosts only: the building Python has no shared libpython" if config.get("python_hosts_only") \
        else ""
    return f" (linux64 for {machine_name(python_machine())}: {library}{hosts})"


def _cmd_build(args: argparse.Namespace) -> int:
    from build_scripts.build_fmus import FMUS, build_fmus
    from build_scripts.ssp import RIG_SET, write_ssp
    from fmu_controller.identification import PAPER_TS_S
    from fmu_controller.prediction import MAX_INPUT_DELAY_SAMPLES, delay_samples_for

    if args.params and not args.ssp:
        raise UsageError("--params puts a rig's plant file into TapMuscleLoop.ssp: give --ssp with it (the FMUs "
                         "take the file's values as parameters in any host: docs/fmu.md, \"Your rig's plant file\")")
    rig = _load_plant_params(args.params, ()) if args.params else None
    # the rig's transport delay in samples of the controller FMU's default Ts, at which SSP tools step
    delay = delay_samples_for(rig.delay.delay_s, PAPER_TS_S) if rig is not None else 0
    if delay + 1 > MAX_INPUT_DELAY_SAMPLES:
        raise UsageError(f"--params {args.params}: a transport delay of {rig.delay.delay_s:g} s is {delay} samples at "
                         f"Ts = {PAPER_TS_S:g} s, and with the parallel master's one more than the controller "
                         f"compensates (input_delay_samples up to {MAX_INPUT_DELAY_SAMPLES})")
    paths = build_fmus(args.out)
    for path in paths:
        print(f"wrote {path}{_linux64_note(path)}")
    if not args.ssp:
        return 0
    if rig is None:
        print(f"wrote {write_ssp(dict(zip(FMUS, paths)), args.out)} (both FMUs as one closed loop for SSP tools)")
        return 0
    path = write_ssp(dict(zip(FMUS, paths)), args.out, rig=rig.dotted(), rig_delay_samples=delay)
    print(f"wrote {path} (both FMUs as one closed loop for SSP tools; the plant and the controller bind the "
          f"parameter sets {RIG_SET!r} of {args.params}, the controller's input_delay_samples = {delay + 1}: "
          f"{delay} for the rig's transport delay of {rig.delay.delay_s:g} s at Ts = {PAPER_TS_S:g} s and 1 for "
          "the parallel master)")
    return 0


# --------------------------------------------------------------------------------------- run
def _cmd_run(args: argparse.Namespace) -> int:
    from build_scripts.build_fmus import FMUS, cached_fmus
    from tapmuscle.cosim import ScenarioError, load_scenario, run_scenario
    from tapmuscle.cosim.run import RUN_FILES

    from tapmuscle.progress import Progress

    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        raise UsageError(str(exc)) from None
    if args.fmu_dir:
        fmus = {name: Path(args.fmu_dir) / f"{name}.fmu" for name in FMUS}
        for name, path in fmus.items():
            if not path.is_file():
                raise UsageError(f"--fmu-dir {args.fmu_dir}: {path.name} is missing (tapmuscle build --out DIR)")
    else:
        fmus = cached_fmus()
    out = Path(args.out)
    try:
        summary = run_scenario(scenario, out, fmus, progress=Progress(scenario.name, enabled=not args.quiet,
                                                                      min_total=500), figure_format=args.figure_format)
    except ScenarioError as exc:
        # the outputs are staged and moved in only after a complete run: say what the folder holds
        earlier = [name for name in RUN_FILES if (out / name).exists()]
        raise UsageError(f"{exc} (nothing was written to {out}"
                         + (f"; {', '.join(earlier)} there are an earlier run's, as they were)" if earlier else ")")) from None
    (k0, k1), (t0, t1) = summary["evaluation_samples"], summary["evaluation_window_s"]
    print(f"{scenario.name}: Eq. (21) error {summary['mae_mm']:.3f} mm over {t0:g}..{t1:g} s (samples "
          f"{k0}..{k1}), u in "
          f"[{summary['u_min_v']:.2f}, {summary['u_max_v']:.2f}] V, real-time factor "
          f"{summary['real_time_factor']:.0f}x")
    used = summary.get("input_delay_samples_used", 0)
    if used != 0:
        how = "decided" if scenario.controller.parameters.get("input_delay_samples") == -1 else "set"
        print(f"the controller compensated an input delay of {used} sample{'s' if used > 1 else ''} "
              f"(input_delay_samples {how})" if used > 0 else "the controller had not decided the input delay "
              "(input_delay_samples = -1) by the end")
    # each warning once, with how often it came (an FMU of one's own may warn every sample)
    for text, times in Counter(summary["fmu_warnings"]).items():
        print(f"warning: {text}" + (f" ({times} times)" if times > 1 else ""), file=sys.stderr)
    print(f"wrote {out / 'result.csv'}, {out / 'summary.json'} and {out / ('*.' + args.figure_format)}")
    return 0


# --------------------------------------------------------------------------------------- main
class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors, like the commands' own: ``tapmuscle <cmd>: error: ...``."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                   namespace: argparse.Namespace | None = None) -> argparse.Namespace:
        """argparse's, but an argument no subcommand takes is refused by that subcommand's parser
        (``tapmuscle identify: error: unrecognized arguments: --quiet``), not by ``tapmuscle``'s."""
        argv = list(sys.argv[1:] if args is None else args)
        parsed, extras = self.parse_known_args(argv, namespace)
        if extras:
            commands = next((a.choices for a in self._actions if isinstance(a, argparse._SubParsersAction)), {})
            name = getattr(parsed, "command", None)
            # the subcommand's only where every extra came after its name (before it: tapmuscle's own)
            at = argv.index(name) if name in argv else len(argv)
            before = [x for x in extras if x in argv[:at]]
            if before:  # tapmuscle's own options come before the command: those are its to refuse
                self.error(f"unrecognized arguments: {' '.join(before)}")
            commands.get(name, self).error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed


class _Version(argparse.Action):
    """``tapmuscle --version``: this version, the Python, the packages the numbers come from, whether
    the plant runs its compiled sub-step, whether a C FMU's messages are formatted (the compiled
    logger) and (Linux) whether the Python has a shared libpython, which
    the FMUs need in hosts that run no Python: what a bug report needs, as results move by last bits
    between their releases. Looked up only when asked (startup time)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, help="print the versions and exit")

    def __call__(self, parser: argparse.ArgumentParser, *args: Any) -> None:
        from tapmuscle.provenance import software_text

        more = []
        if sys.platform.startswith("linux"):  # whether the FMUs built here can start a Python in a C host
            from build_scripts.native_host import build_environment

            more.append("libpython " + ("shared" if build_environment()["libpython_soname"]
                                        else "static: FMUs for Python hosts only"))
        from tapmuscle.cosim.master import formats_fmu_messages

        print(software_text(more=[f"C FMU messages formatted {'yes' if formats_fmu_messages() else 'no'}", *more]))
        parser.exit(0)


def build_parser() -> argparse.ArgumentParser:
    """The ``tapmuscle`` parser with every subcommand (errors are one line, exit status 2)."""
    parser = _Parser(prog="tapmuscle", description="Simulate, identify and control a tap-water McKibben muscle; "
                     "the plant and the AMPC controller as FMI 2.0 co-simulation FMUs. "
                     "'tapmuscle <command> --help' for each command.")
    parser.add_argument("--version", action=_Version)
    sub = parser.add_subparsers(dest="command", required=True)

    rec = sub.add_parser("record", help="run the simulated rig open-loop and write a recording CSV",
                         description="Run the simulated rig open-loop with a valve-command signal and "
                                     "write a recording (docs/recordings.md).")
    rec.add_argument("--load", type=number_within("--load", 0.0, 500.0), default=None,
                     help="hanging load [N], 0..500 (paper: 44, 68); default: the --params file's "
                          "load.load_n, else 44")
    rec.add_argument("--input", required=True,
                     help="command spec, e.g. sine:bias=5,amp=3,freq=0.1 | step:initial=4,final=6,at=10 | "
                          "steps:levels=3/7/5,period=20 | chirp:f0=0.01,f1=0.5 | random:lo=2,hi=8,seed=1 | const:value=5 | "
                          "csv:PATH")
    rec.add_argument("--duration", type=number_within("--duration", 1e-3, 86400.0), required=True,
                     help="length [s], up to 86400 (a day)")
    rec.add_argument("--ts", type=number_within("--ts", 1e-3, 10.0), default=0.1,
                     help="sampling period [s], 0.001..10 (default 0.1, the paper's)")
    rec.add_argument("--seed", type=integer_at_least("--seed", 0, _SEED_MAX), default=0,
                     help="noise seed (0 .. 2**64 - 1)")
    rec.add_argument("--out", type=output_path("--out", "file"), required=True, help="output CSV path")
    rec.add_argument("--plot", action="store_true", help="also write OUT.png: time traces and hysteresis loop")
    rec.add_argument("--no-noise", action="store_true", help="switch sensor noise off (quantisation stays)")
    rec.add_argument("--params", help="plant parameter file (JSON, as written by `tapmuscle diagnose`)")
    rec.add_argument("--set", action="append", default=[], metavar="GROUP.FIELD=VALUE",
                     help="override one plant parameter, e.g. --set friction.rate_gain=0 (repeatable)")
    rec.add_argument("--quiet", action="store_true", help="no progress output")
    rec.set_defaults(func=_cmd_record)

    idf = sub.add_parser("identify", help="identify the paper's Eq. (1) model on a recording by (constrained) RLS",
                         description="Identify Eq. (1) (linear ARX + discretised Bouc-Wen) on a recording with the "
                                     "RLS of Eq. (4) and the constrained RLS of Algorithm 1; report Table-4 fits.")
    idf.add_argument("recording", help="recording CSV (docs/recordings.md)")
    idf.add_argument("--model", choices=("asymmetric", "standard"), default="asymmetric",
                     help="asymmetric Bouc-Wen (with g(l), 15 parameters) or standard (11)")
    idf.add_argument("--validate", help="a second recording to score the identified model on")
    idf.add_argument("--json", type=output_path("--json", "file"), required=True, help="output JSON path")
    idf.add_argument("--plot", type=output_path("--plot", "folder"), metavar="DIR",
                     help="write the convergence, model-vs-measured and loop figures into DIR, with their data: "
                          "identification.csv (the record, the model's free run, the estimate after each sample) "
                          "and, with --validate, validation.csv")
    idf.add_argument("--figure-format", choices=FIGURE_FORMATS, default="png",
                     help="with --plot: the figures' format, png (default), or pdf or svg for a publication")
    idf.add_argument("--box", default="auto",
                     help="constraint region: auto (Table 2 for mm, V, Ts 0.1 s), none, or name=lo:hi,... "
                          "in the recording's units")
    idf.add_argument("--constraint-start", type=number_within("--constraint-start", 0.0, math.inf), default=120.0,
                     help="time from which the constraint applies [s] (paper: 120)")
    idf.add_argument("--forgetting", type=number_within("--forgetting", 1e-6, 1.0), default=1.0,
                     help="forgetting factor lambda in (0, 1] (1 = off, the paper)")
    idf.add_argument("--input-delay-samples", type=integer_at_least("--input-delay-samples", 0, _INPUT_DELAY_MAX,
                                                                    words=("auto",)),
                     default=0, metavar="D",
                     help=f"the rig's transport delay in samples (0..{_INPUT_DELAY_MAX}): identify on the command "
                          "the valve had, u(k-D), for a controller with input_delay_samples = D (docs/control.md, "
                          "Transport delay); auto: the D up to 0.5 s (at least 5 samples) whose model fits best one step "
                          "ahead on the record (a random, step or chirp command; not one or two sines)")
    idf.add_argument("--quiet", action="store_true", help="no progress output")
    idf.set_defaults(func=_cmd_identify)

    pap = sub.add_parser("paper", help="run the paper's section 4 experiments and print Tables 6, 7, 9",
                         description="Identify the fixed predictor at 44 N, then run the four controllers at 44 and "
                                     "68 N (0.1 Hz) and the servo controllers at 0.2 Hz; write paper.json, run CSVs "
                                     "and Figs. 8-19, and print Tables 6, 7 and 9 beside the paper's.")
    pap.add_argument("--out", type=output_path("--out", "folder"), default="out/paper", help="output folder (default out/paper)")
    pap.add_argument("--seeds", default="0,1,2",
                     help="noise seeds, each once; each table cell is the mean over them, tables.csv has their spread, "
                          "runs/ a CSV per run and seed (NAME.csv the first seed's, shown in the figures; "
                          "NAME_seedS.csv the others'), each with its own Eq. (21) error (default 0,1,2)")
    pap.add_argument("--id-seed", type=integer_at_least("--id-seed", 0, _SEED_MAX), default=None,
                     help="noise seed of the preliminary identification that gives the fixed predictor "
                          "(default: the first of --seeds)")
    pap.add_argument("--paper-eq5", action="store_true",
                     help="MPC-servo cancels H(k) exactly as the paper's Eq. (5) (valve chatter at the bottom of "
                          "the cycle); default: the controller FMU's hysteresis notch (docs/control.md, Chatter)")
    pap.add_argument("--paper-start", action="store_true",
                     help="start as the paper does: the full reference and the raw adaptive estimate from the first "
                          "sample (overshoot and valve slamming in the first seconds), and the servo integrator Eq. (18) "
                          "without the anti-windup hold; default: the controller FMU's start-up mode and hold "
                          "(docs/control.md, Start-up, Integrator wind-up). With --paper-eq5: the paper's controllers exactly")
    pap.add_argument("--figure-format", choices=FIGURE_FORMATS, default="png",
                     help="format of Figs. 8-19: png (default), or pdf or svg for a publication (vector; the text "
                          "as text); the data of each is in runs/, the cells in tables.csv")
    pap.add_argument("--quiet", action="store_true", help="no progress bar")
    pap.set_defaults(func=_cmd_paper)

    run = sub.add_parser("run", help="run a scenario file through the FMUs (fmpy co-simulation)",
                         description="Co-simulate MusclePlant and AMPCController (or a controller FMU of your "
                                     "own: [controller] interface) as a scenario file says (tapmuscle/cosim/spec.py, "
                                     "docs/fmu.md); write result.csv, summary.json, PNGs (what they show: "
                                     "docs/README.md). Every key names its unit: duration_s and step_s in s, "
                                     "offset_mm in mm, initial_n (the load) in N, initial_mpa (the supply) in MPa.")
    run.add_argument("scenario", help="scenario TOML file (e.g. scenarios/paper/ampc_servo_44N_0.1Hz.toml)")
    run.add_argument("--out", type=output_path("--out", "folder"), required=True, help="output folder")
    run.add_argument("--fmu-dir", help="folder with MusclePlant.fmu and AMPCController.fmu "
                                       "(default: built from the sources, cached)")
    run.add_argument("--figure-format", choices=FIGURE_FORMATS, default="png",
                     help="format of the figures: png (default), or pdf or svg for a publication (vector; the text as "
                          "text); their data is result.csv")
    run.add_argument("--quiet", action="store_true", help="no progress output")
    run.set_defaults(func=_cmd_run)

    bld = sub.add_parser("build", help="build the FMI 2.0 co-simulation FMUs",
                         description="Build MusclePlant.fmu and AMPCController.fmu with pythonfmu (docs/fmu.md).")
    bld.add_argument("--out", type=output_path("--out", "folder"), default="out/fmu", help="output folder (default out/fmu)")
    bld.add_argument("--ssp", action="store_true",
                     help="also write TapMuscleLoop.ssp: both FMUs connected, parameter sets for 44 N and 68 N, "
                          "for SSP tools (libcosim, Ecos, OMSimulator)")
    bld.add_argument("--params", metavar="FILE",
                     help="with --ssp: a rig's plant file (calibrated_plant.json from `tapmuscle diagnose`) bound in "
                          "TapMuscleLoop.ssp as the parameter sets 'rig' of the plant and of the controller (its "
                          "input_delay_samples for the file's transport delay), a digital twin of that rig")
    bld.set_defaults(func=_cmd_build)
    _register_sweep(sub)
    _register_diagnose(sub)
    _register_import(sub)
    return parser


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                      file: Any = None, line: str | None = None) -> None:
    """A warning during a command as the FMUs' are printed: one line, without the library's source line."""
    print(f"warning: {message}", file=file or sys.stderr)


def _ending_on_interrupt(process: bool) -> None:
    """After a Ctrl-C that ends the console script's process: further ones (a key held, pressed again)
    are ignored, as one arriving in the clean-up at exit would end the process by the signal, not with
    exit 130, and with an "Exception ignored in atexit callback" traceback. An in-process caller (a
    notebook) keeps its Ctrl-C. (Under :func:`_interrupting_once` they are ignored already: this
    covers an interrupt raised by other means.)"""
    if process and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _interrupting_once(process: bool) -> Any:
    """In the console script's process, Python's SIGINT handler replaced by one that ignores every
    later SIGINT from the moment it raises (:func:`tapmuscle.interrupts.interrupt_once`): a key held
    down otherwise lands a second interrupt in the first one's unwinding, even in the ``except`` that
    reports it, and the process ends by the signal (exit -2, a traceback) instead of exit 130.
    Returns the handler to put back at the end (None: nothing replaced)."""
    if not process or threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return None  # in-process callers, and a SIGINT ignored or handled by someone else, keep theirs
    from tapmuscle.interrupts import interrupt_once

    return signal.signal(signal.SIGINT, interrupt_once)


#: Commands whose time is mostly the plant's integration, in this process or in the FMUs they build.
_SIMULATING = frozenset({"diagnose", "demo-mismatch", "record", "paper", "run", "build", "sweep", "check"})


def _note_python_substep(command: str, quiet: bool) -> None:
    """Say on stderr, before a simulating ``command``, that the plant's compiled sub-step is missing
    (installed where no C compiler was): the results are the same, the time is not, and nothing
    else tells (unless ``TAPMUSCLE_PURE_PYTHON=1`` asked for the Python sub-step)."""
    from fmu_plant.rosenbrock import COMPILED, COMPILED_FOR_ANOTHER_PYTHON

    if quiet or command not in _SIMULATING or COMPILED or os.environ.get("TAPMUSCLE_PURE_PYTHON") == "1":
        return
    why = (f"{COMPILED_FOR_ANOTHER_PYTHON} is another Python's" if COMPILED_FOR_ANOTHER_PYTHON else
           "no C compiler was found when tapmuscle was installed")
    print(f"tapmuscle {command}: note: the plant's compiled integrator sub-step is not installed ({why}): its "
          "Python sub-step gives the same results, a plant step about 8 times slower and a diagnosis's "
          f"re-simulation 20-26 times (docs/plant.md, \"The compiled sub-step\"); install {_c_compiler()} and "
          "reinstall tapmuscle to have it", file=sys.stderr)


def _c_compiler() -> str:
    """The C compiler that builds Python extensions on this system, as a user installs it."""
    if sys.platform == "win32":
        return "Microsoft's C++ Build Tools (the compiler Python's extensions are built with on Windows)"
    if sys.platform == "darwin":
        return "Xcode's command line tools (xcode-select --install)"
    return "gcc"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tapmuscle`` console script.

    Parameters
    ----------
    argv : sequence of str, optional
        The command line's arguments without the program name; None (default): ``sys.argv[1:]``,
        as the console script, whose process then ends with the command.
    """
    process = argv is None  # the console script: the process ends with the command
    argv = list(sys.argv[1:] if argv is None else argv)
    if process:
        _printable_anywhere()
    previous = _interrupting_once(process)
    try:
        return _main(argv, process)
    finally:
        if previous is not None and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
            signal.signal(signal.SIGINT, previous)  # not interrupted: the caller's handler back


def _printable_anywhere() -> None:
    """Print what the output's encoding lacks as escapes (``\u0394``), as Python's stderr does,
    rather than fail: a Windows console or a redirected output in cp1252 cannot show a folder named
    "Δp" or "日本", and a command that has written every file must not end in an encoding error then."""
    for stream in (sys.stdout, sys.stderr):
        # a UTF encoding shows everything: its surrogateescape (a file name's undecodable bytes) kept
        if isinstance(stream, io.TextIOWrapper) and stream.errors in ("strict", "surrogateescape") \
                and not codecs.lookup(stream.encoding).name.startswith("utf"):
            stream.reconfigure(errors=_ESCAPING if stream.errors == "surrogateescape" else "backslashreplace")


def _escape_keeping_bytes(error: UnicodeEncodeError) -> tuple[str | bytes, int]:
    """An encoding error handler: a file name's undecodable bytes (lone surrogates) written back as
    those bytes, as ``surrogateescape`` does on a POSIX locale that is not UTF-8; anything else the
    encoding lacks as an escape (``backslashreplace``)."""
    chunk = error.object[error.start:error.end]
    if all("\udc80" <= c <= "\udcff" for c in chunk):
        return codecs.lookup_error("surrogateescape")(error)
    return codecs.lookup_error("backslashreplace")(error)


_ESCAPING = "tapmuscle.escape_keeping_bytes"
codecs.register_error(_ESCAPING, _escape_keeping_bytes)


def _main(argv: list[str], process: bool) -> int:
    try:
        parser = build_parser()  # most of a second: its subcommands' modules are imported
        args = parser.parse_args(argv)
    except KeyboardInterrupt:
        _ending_on_interrupt(process)
        print("\ntapmuscle: interrupted before anything ran; nothing is written", file=sys.stderr)
        return 130
    args.argv = argv
    try:
        _note_python_substep(args.command, bool(getattr(args, "quiet", False)))
        with warnings.catch_warnings(), invoked_as(argv):  # restores Python's own display for an in-process caller
            warnings.showwarning = _one_line_warning
            code = int(args.func(args) or 0)
        if code == 130:  # a command that said what its interrupt kept (sweep, check)
            _ending_on_interrupt(process)
        sys.stdout.flush()  # here, so that a reader gone by now is met by the handler below, not at exit
        return code
    except UsageError as exc:
        print(f"tapmuscle {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader of the printed lines went away (tapmuscle ... | head): not bad input, and the
        # files are written; stdout to /dev/null so that the exit's flush raises nothing either
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):
            pass
        return 141  # 128 + SIGPIPE, as a shell reports a command ended by a closed pipe
    except (OSError, ValueError) as exc:
        print(f"tapmuscle {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except Warning as exc:  # the warning filters made a warning an error (PYTHONWARNINGS=error, -W error)
        print(f"tapmuscle {args.command}: error: {type(exc).__name__}, a warning that the warning filters raise as an "
              f"error (PYTHONWARNINGS, -W): {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        _ending_on_interrupt(process)
        # every output is written whole or not at all (tapmuscle.io.atomic): say so, not a traceback
        field_run = args.command == "demo-mismatch" and getattr(args, "suite", None) == "field"
        resume = "; the same command with --resume goes on from the finished cases" if field_run else ""
        print(f"\ntapmuscle {args.command}: interrupted; nothing is half-written (each output file is complete "
              f"or absent){resume}", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
