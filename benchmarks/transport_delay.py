"""The four controllers on a rig whose valve acts on each command late (a transport delay).

Run: ``python benchmarks/transport_delay.py [--seeds 2] [--off-nominal 0] [--out out/transport_delay]``
(about 4 min; ``--off-nominal N`` adds N rigs with 3-6 constants off, about N x 6 s). The paper's
tables assume none (docs/control.md, "Transport delay"). Each method at 44 N, 0.1 Hz and 68 N, 0.2 Hz
(P(0) of Table 8 at 0.2 Hz), with the fixed predictor that ``tapmuscle paper`` identifies, on the
nominal rig with a transport delay of 0-0.4 s (``delay.delay_s``), 90 s from rest, noise seeds
0..N-1, with ``input_delay_samples`` 0 (the paper's law), the delay in samples (rounded to the
nearest) and -1 (decided from the data); ``--servo-r R`` sets the servo methods' move weight R
(Table 5: 15) and ``--delay-move-weight F`` the factor on it for delays of 2 samples or more
(``ControllerSettings.delay_move_weight``, default 16; 1 keeps R). Printed per
method, delay and setting, over the cells and seeds: Eq. (21) over 10-40 s, the mean |r - l| over
50-90 s (after -1's restart of the estimator and its start-up mode), the share of 10-90 s the valve
sits at 0 or 10 V, and -1's decisions. ``--off-nominal N``: N rigs drawn as docs/diagnosis.md's
field generator does (load 30-80 N, 0.1 or 0.2 Hz, a delay of 0.1-0.4 s, the four methods in turn),
each with 0, the rounded delay and -1; how many track within 2 mm over 50-90 s. ``--delay-check N``
(only that, about N x 0.7 s): the set delay's 30-s check with ``THETA0_44N`` and 0 set on N off-nominal
rigs (every third with a dead band, every third heavier than believed), each without a delay and
with 0.2 s: how often it speaks. Stored:
``transport_delay.png``, AMPC-servo at 44 N, 0.1 Hz, seed 0 with a 0.3-s delay under the three settings.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np

from fmu_controller.displacement_control import (METHODS, P0_TABLE5, P0_TABLE8, ControllerSettings,
                                                 DisplacementController)
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.reference import SineReference
from fmu_controller.servo_settings import ServoMPCSettings
from fmu_plant import Plant
from fmu_plant.parameters import PlantParams
from tapmuscle.closed_loop import eq21_error_mm, run_closed_loop
from tapmuscle.diagnosis.field_cases import draw_parameter_errors, off_nominal
from tapmuscle.paper.reproduce import preliminary_theta
from tapmuscle.plots.figures import new_figure, save_figure

CELLS = [(44.0, 0.1), (68.0, 0.2)]
DELAYS_S = (0.0, 0.1, 0.2, 0.3, 0.4)
TS_S = 0.1


def samples_of(delay_s: float) -> int:
    """The delay in samples, rounded to the nearest (half a sample up)."""
    return math.floor(delay_s / TS_S + 0.5 + 1e-9)


SERVO = ServoMPCSettings()
DELAY_MOVE_WEIGHT = ControllerSettings().delay_move_weight


def run(method: str, load: float, f: float, seed: int, theta0: np.ndarray, params: PlantParams,
        input_delay: int) -> tuple[dict, int | None]:
    plant = Plant(params, seed=seed)
    plant.update(load_n=load)
    cs = ControllerSettings(method=method, p0=P0_TABLE8 if f == 0.2 else P0_TABLE5, input_delay_samples=input_delay,
                            servo=SERVO, delay_move_weight=DELAY_MOVE_WEIGHT)
    ctrl = DisplacementController(cs, theta0)
    r = run_closed_loop(plant, ctrl, SineReference(frequency_hz=f), duration_s=90.0, watch=False)
    return r, ctrl.input_delay_decision


def scores(r: dict) -> tuple[float, float, float]:
    """Eq. (21) [mm], mean |r - l| over 50-90 s [mm], share of 10-90 s at a valve limit."""
    u = r["u_v"][100:]
    return (eq21_error_mm(r["r_mm"], r["l_mm"]), float(np.mean(np.abs(r["r_mm"][500:] - r["l_mm"][500:]))),
            float(np.mean((u <= 1e-9) | (u >= 10.0 - 1e-9))))


def table(seeds: int, theta0: np.ndarray) -> None:
    print(f"{'method':<11} {'delay':>6} | {'setting':>7} : Eq.(21) mm  50-90 s mm  at a limit | -1 decided")
    for method in METHODS:
        for delay_s in DELAYS_S:
            params = PlantParams().with_values(**{"delay.delay_s": delay_s})
            settings = sorted({0, samples_of(delay_s), -1}, key=lambda d: (d < 0, d))
            for d in settings:
                got, decided = [], []
                for load, f in CELLS:
                    for seed in range(seeds):
                        r, dec = run(method, load, f, seed, theta0, params, d)
                        got.append(scores(r))
                        decided.append(dec)
                e21, late, limit = np.mean(got, axis=0)
                note = f" | {sorted(set(decided))}" if d == -1 else ""
                print(f"{method:<11} {delay_s:5.2f}s | {d:>7} : {e21:10.3f}  {late:10.3f}  {100 * limit:8.0f} %{note}",
                      flush=True)


def off_nominal_rigs(n: int, theta0: np.ndarray) -> None:
    ok = {"0": 0, "matched": 0, "-1": 0}
    for i in range(n):
        rng = np.random.default_rng(2000 + i)
        load = float(rng.uniform(30.0, 80.0))
        f = 0.1 if i % 2 == 0 else 0.2
        delay_s = round(float(rng.uniform(0.1, 0.4)), 2)
        method = METHODS[(i // 2) % len(METHODS)]
        errors = draw_parameter_errors(rng, PlantParams().with_values(**{"load.load_n": load}))
        params = off_nominal(PlantParams(), errors).with_values(**{"delay.delay_s": delay_s})
        line = []
        for label, d in (("0", 0), ("matched", samples_of(delay_s)), ("-1", -1)):
            r, dec = run(method, load, f, i, theta0, params, d)
            e21, late, _ = scores(r)
            ok[label] += late < 2.0
            line.append(f"{label} {late:6.2f}" + (f" (decided {dec})" if d == -1 else ""))
        print(f"rig {i:3d} {method:<11} {load:5.1f} N {f:g} Hz delay {delay_s:.2f} s: 50-90 s mm: " + ", ".join(line),
              flush=True)
    print(f"within 2 mm over 50-90 s, of {n} off-nominal rigs with a delay: " +
          ", ".join(f"{k}: {v}" for k, v in ok.items()))


def _rig_with_a_map_or_a_load(i: int, rng: np.random.Generator, load: float) -> PlantParams:
    """An off-nominal rig as the field generator draws one; every third with a dead band of 0.4-1.2 V
    somewhere in 3.5-6.5 V (the amplifier's map), every third 8-20 N heavier than believed."""
    params = off_nominal(PlantParams(), draw_parameter_errors(rng, PlantParams().with_values(**{"load.load_n": load})))
    if i % 3 == 0:
        c, w = float(rng.uniform(3.5, 6.5)), float(rng.uniform(0.4, 1.2))
        params = params.with_values(**{"input_map.out_at_0_v": w / 2, "input_map.knot1_in_v": c - w / 2,
                                       "input_map.knot1_out_v": c, "input_map.knot2_in_v": c + w / 2,
                                       "input_map.knot2_out_v": c, "input_map.out_at_10_v": 10.0 - w / 2})
    elif i % 3 == 1:
        params = params.with_values(**{"load_mismatch.extra_n": float(rng.uniform(8.0, 20.0))})
    return params.with_values(**{"load.load_n": load})


def delay_check(n: int) -> None:
    """The set delay's 30-s check (``DisplacementController.delay_evidence``, the warning "the
    measurements show an input delay of ...") with the controller's default ``THETA0_44N`` and
    ``input_delay_samples = 0``, the four methods on each of ``n`` off-nominal rigs: how often it
    speaks on a rig without a delay (a false alarm) and on the same rig with a 0.2-s delay (a find)."""
    told = {0.0: 0, 0.2: 0}
    for i in range(n):
        rng = np.random.default_rng(5000 + i)
        load, f = float(rng.uniform(30.0, 80.0)), (0.1, 0.2)[i % 2]
        rig = _rig_with_a_map_or_a_load(i, rng, load)
        for delay_s in told:
            for method in METHODS:
                plant = Plant(rig.with_values(**{"delay.delay_s": delay_s}), seed=i)
                ctrl = DisplacementController(ControllerSettings(method=method, input_delay_samples=0), THETA0_44N)
                with warnings.catch_warnings():  # the rigs' own notes (a light load, a spike held): not this count's
                    warnings.simplefilter("ignore")
                    r = run_closed_loop(plant, ctrl, SineReference(frequency_hz=f), duration_s=45.0, watch=False)
                evidence = ctrl.delay_evidence
                told[delay_s] += evidence is not None
                if (evidence is not None) != (delay_s > 0.0):
                    print(f"rig {i:3d} {load:5.1f} N {f:g} Hz ({('a map', 'heavier', 'constants only')[i % 3]}), "
                          f"delay {delay_s:g} s, {method}: told {evidence}; Eq. (21) "
                          f"{eq21_error_mm(r['r_mm'], r['l_mm']):.2f} mm", flush=True)
    runs = n * len(METHODS)
    print(f"the 30-s check with 0 set, {n} off-nominal rigs x {len(METHODS)} methods: told on {told[0.0]} of {runs} "
          f"runs without a delay, on {told[0.2]} of {runs} with a 0.2-s delay")


def figure(theta0: np.ndarray, out: Path) -> None:
    params = PlantParams().with_values(**{"delay.delay_s": 0.3})
    fig, axes = new_figure(3, 1, figsize=(9, 6.5), sharex=True)
    for ax, d in zip(axes, (0, 3, -1)):
        r, dec = run("ampc_servo", 44.0, 0.1, 0, theta0, params, d)
        ax.plot(r["t_s"], r["r_mm"], "k--", lw=1, label="reference r")
        ax.plot(r["t_s"], r["l_mm"], lw=1, label="displacement l")
        ax2 = ax.twinx()
        ax2.plot(r["t_s"], r["u_v"], color="tab:red", lw=0.6, alpha=0.6)
        ax2.set_ylim(-0.5, 10.5)
        ax2.set_ylabel("u [V]", color="tab:red")
        title = {0: "input_delay_samples = 0 (the paper's law)", 3: "input_delay_samples = 3",
                 -1: f"input_delay_samples = -1 (decided {dec})"}[d]
        ax.set_title(f"AMPC-servo (R = {SERVO.r:g}, x {DELAY_MOVE_WEIGHT:g} for a delay of 2 or more), 44 N, 0.1 Hz, "
                     f"transport delay 0.3 s: {title}; Eq. (21) "
                     f"{eq21_error_mm(r['r_mm'], r['l_mm']):.2f} mm", fontsize=9)
        ax.set_ylabel("l [mm]")
        ax.set_ylim(-5, 80)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time t [s]")
    out.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out / "transport_delay.png")
    print(f"wrote {out / 'transport_delay.png'}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--off-nominal", type=int, default=0, metavar="N")
    ap.add_argument("--servo-r", type=float, default=None, metavar="R")
    ap.add_argument("--delay-move-weight", type=float, default=None, metavar="F")
    ap.add_argument("--delay-check", type=int, default=0, metavar="N")
    ap.add_argument("--out", type=Path, default=Path("out/transport_delay"))
    args = ap.parse_args(argv)
    if args.delay_check:
        delay_check(args.delay_check)
        return 0
    global SERVO, DELAY_MOVE_WEIGHT
    if args.servo_r is not None:
        SERVO = ServoMPCSettings(r=args.servo_r)
    if args.delay_move_weight is not None:
        DELAY_MOVE_WEIGHT = args.delay_move_weight
    theta0 = preliminary_theta(0, refine_hz=0.05)
    table(args.seeds, theta0)
    if args.off_nominal:
        off_nominal_rigs(args.off_nominal, theta0)
    figure(theta0, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
