"""Start from rest: the paper's start against the start-up mode (``ControllerSettings.startup_s``).

Run: ``python benchmarks/startup.py [--seeds 8] [--startup 12] [--out out/startup]`` (about 25 s).
Every method at 44 and 68 N, 0.1 and 0.2 Hz (P(0) of Table 8 at 0.2 Hz), from rest, with the fixed
predictor that ``tapmuscle paper`` identifies; noise seeds 0..N-1; 90 s each. The paper's start is
``startup_s = 0`` with the hysteresis notch by method as the paper start has it (off for AMPC-servo)
and Eq. (18) without the anti-windup hold;
the start-up mode is ``--startup`` with the defaults. Printed per cell and start, over the seeds and
the whole 90 s: the largest overshoot above the reference's 65-mm peak, the most full-range
(0 <-> 10 V) command reversals, how many runs break either limit of the start-up requirement (3 mm,
2 reversals), Eq. (21) over 10-40 s and the mean |r - l| over 50-90 s (means). Stored:
``startup.png``, the first 25 s of AMPC-servo at 44 N, 0.2 Hz and of AMPC-UCP at 44 N, 0.1 Hz, seed 0,
both starts.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from fmu_controller.displacement_control import (DEFAULT_PROBING_V, DEFAULT_STARTUP_S, METHODS, P0_TABLE5, P0_TABLE8,
                                                 ControllerSettings, DisplacementController)
from fmu_controller.reference import SineReference
from fmu_plant import Plant
from fmu_plant.parameters import PlantParams
from tapmuscle.closed_loop import command_tv_excess, eq21_error_mm, run_closed_loop
from tapmuscle.diagnosis.field_cases import draw_parameter_errors, off_nominal
from tapmuscle.paper.reproduce import preliminary_theta
from tapmuscle.plots.figures import new_figure, save_figure

CELLS = [(44.0, 0.1), (44.0, 0.2), (68.0, 0.1), (68.0, 0.2)]


def reversals(u: np.ndarray) -> int:
    """Changes between 0-V and 10-V saturation (samples in between ignored)."""
    s = np.where(u <= 0.05, -1, np.where(u >= 9.95, 1, 0))
    s = s[s != 0]
    return int(np.count_nonzero(s[1:] != s[:-1]))


def run(method: str, load: float, f: float, seed: int, startup_s: float, theta0: np.ndarray, *,
        params: PlantParams | None = None, input_delay: int = 0, loop_delay: int = 0,
        probing_v: float = DEFAULT_PROBING_V) -> dict:
    plant = Plant(params, seed=seed)
    plant.update(load_n=load)
    # the paper's start: Eq. (18) without the anti-windup hold, too
    cs = ControllerSettings(method=method, p0=P0_TABLE8 if f == 0.2 else P0_TABLE5, startup_s=startup_s,
                            input_delay_samples=input_delay, probing_v=probing_v, anti_windup=startup_s > 0)
    return run_closed_loop(plant, DisplacementController(cs, theta0), SineReference(frequency_hz=f), duration_s=90.0,
                           loop_delay_samples=loop_delay, watch=False)


def off_nominal_rigs(n: int, startup_s: float, theta0: np.ndarray, input_delay: int, loop_delay: int,
                     probing_v: float) -> None:
    """``n`` off-nominal rigs (3-6 constants off by 5-20 %, docs/diagnosis.md's field generator), load
    30-80 N, 0.1 or 0.2 Hz, the four methods in turn, each with the paper's start and the start-up mode."""
    bad = {"paper": 0, "mode": 0}
    e21 = {"paper": [], "mode": []}
    tv = {m: [] for m in METHODS}
    for i in range(n):
        rng = np.random.default_rng(1000 + i)
        load = float(rng.uniform(30.0, 80.0))
        f = 0.1 if i % 2 == 0 else 0.2
        method = METHODS[(i // 2) % len(METHODS)]
        errors = draw_parameter_errors(rng, PlantParams().with_values(**{"load.load_n": load}))
        params = off_nominal(PlantParams(), errors)
        for label, startup in (("paper", 0.0), ("mode", startup_s)):
            r = run(method, load, f, i, startup, theta0, params=params, input_delay=input_delay, loop_delay=loop_delay,
                    probing_v=probing_v)
            over, rev = float(np.max(r["l_mm"])) - 65.0, reversals(r["u_v"])
            e21[label].append(eq21_error_mm(r["r_mm"], r["l_mm"]))
            if label == "mode":
                tv[method].append(100.0 * command_tv_excess(r["u_v"], f))
            if over > 3.0 or rev > 2:
                bad[label] += 1
            if (over > 3.0 or rev > 2) and label == "mode":
                print(f"rig {i:3d} {method:<11} {load:5.1f} N {f:g} Hz  {label:<5}: overshoot {over:5.1f} mm, "
                      f"{rev} reversals", flush=True)
    for label, name in (("paper", "paper start"), ("mode", f"start-up mode {startup_s:g} s")):
        print(f"{name}: {bad[label]} of {n} off-nominal rigs break the start-up limits; mean Eq. (21) "
              f"{np.mean(e21[label]):.3f} mm")
    for m, v in tv.items():
        if v:
            print(f"  {m:<11} Eq. (21)-window TV above smooth, start-up mode: mean {np.mean(v):5.1f} %, "
                  f"worst {np.max(v):5.1f} % ({len(v)} rigs)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8, help="noise seeds 0..N-1 (default 8)")
    parser.add_argument("--startup", type=float, default=DEFAULT_STARTUP_S,
                        help=f"startup_s of the start-up mode (default {DEFAULT_STARTUP_S:g})")
    parser.add_argument("--out", type=Path, default=Path("out/startup"), help="folder of startup.png")
    parser.add_argument("--probing", type=float, default=DEFAULT_PROBING_V,
                        help=f"probing_v of the start-up mode [V] (default {DEFAULT_PROBING_V:g}; 0: none)")
    parser.add_argument("--off-nominal", type=int, default=0, metavar="N",
                        help="instead: N off-nominal rigs, the four methods in turn (see off_nominal_rigs)")
    parser.add_argument("--input-delay", type=int, default=0, choices=(-1, 0, 1),
                        help="the controller's input_delay_samples (with --off-nominal; default 0)")
    parser.add_argument("--loop-delay", type=int, default=0, choices=(0, 1),
                        help="1: apply each command one sample late, as a parallel master (with --off-nominal)")
    args = parser.parse_args(argv)
    theta0 = preliminary_theta(0, refine_hz=0.05)
    if args.off_nominal:
        off_nominal_rigs(args.off_nominal, args.startup, theta0, args.input_delay, args.loop_delay, args.probing)
        return 0
    print(f"{'method':<11} {'cell':<12} {'start':<10} {'overshoot [mm]':>15} {'reversals':>10} {'runs over':>10} "
          f"{'Eq.(21) 10-40 s':>16} {'|r-l| 50-90 s':>14}")
    totals = {}
    for method in METHODS:
        for load, f in CELLS:
            for label, startup in (("paper", 0.0), (f"{args.startup:g} s", args.startup)):
                over, rev, e21, late = [], [], [], []
                for seed in range(args.seeds):
                    r = run(method, load, f, seed, startup, theta0, probing_v=args.probing)
                    over.append(max(0.0, float(np.max(r["l_mm"])) - 65.0))
                    rev.append(reversals(r["u_v"]))
                    e21.append(eq21_error_mm(r["r_mm"], r["l_mm"]))
                    k = (r["t_s"] >= 50.0) & (r["t_s"] <= 90.0)
                    late.append(float(np.mean(np.abs(r["r_mm"][k] - r["l_mm"][k]))))
                bad = sum(o > 3.0 or v > 2 for o, v in zip(over, rev))
                totals[label] = totals.get(label, 0) + bad
                print(f"{method:<11} {f'{load:.0f} N {f:g} Hz':<12} {label:<10} {max(over):15.1f} {max(rev):10d} "
                      f"{bad:>6d}/{args.seeds:<3d} {np.mean(e21):16.3f} {np.mean(late):14.3f}", flush=True)
    for label, bad in totals.items():
        print(f"start '{label}': {bad} of {len(METHODS) * len(CELLS) * args.seeds} runs break the start-up limits")
    fig, ax = new_figure(2, 2, figsize=(12, 7), sharex=True)
    for col, (method, load, f) in enumerate((("ampc_servo", 44.0, 0.2), ("ampc_ucp", 44.0, 0.1))):
        for label, startup, colour in (("paper start", 0.0, "tab:red"), (f"start-up mode {args.startup:g} s",
                                                                         args.startup, "tab:blue")):
            r = run(method, load, f, 0, startup, theta0)
            k = r["t_s"] <= 25.0
            ax[0, col].plot(r["t_s"][k], r["l_mm"][k], color=colour, label=f"l, {label}")
            ax[1, col].step(r["t_s"][k], r["u_v"][k], where="post", color=colour, label=label)
        ax[0, col].plot(r["t_s"][k], r["r_mm"][k], "k:", label="r")
        ax[0, col].axhline(68.0, color="k", lw=0.6, ls="--")
        ax[0, col].set_title(f"{method}, {load:.0f} N, {f:g} Hz, seed 0 (dashed: 65 + 3 mm)")
        ax[0, col].set_ylabel("l [mm]")
        ax[1, col].set_ylabel("u [V]")
        ax[1, col].set_xlabel("t [s]")
        for a in ax[:, col]:
            a.grid(True, alpha=0.3)
            a.legend(fontsize=8)
    png = save_figure(fig, args.out / "startup.png")
    print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
