"""A PID baseline beside the paper's four controllers, on the simulated rig: the user's own loop.

Run: ``python benchmarks/pid_baseline.py [--out out/pid_baseline]`` (about 5 s).

The PID is what a control engineer would set up first on this rig: a feed-forward that inverts the
rig's static map ``l(u)`` (measured open loop from a staircase of 1-V steps held 15 s, up and down,
at 44 N; blended towards the rising or the falling branch by the sign of the reference's slope, plus
0.05 V per mm/s of it), then PI on the error (Kp 0.8 V/mm, Ki 5 V/(mm s); no D), with conditional
integration and back-calculation at the valve's 0..10 V. Its gains were tuned on another seed and
another reference than those scored here (a user's study, 2026-12-06).

Printed: Eq. (21) [mm], the mean of seeds 0-2, for the PID and the four methods at their defaults
(``simulate_closed_loop``), at 44 and 68 N and 0.1 and 0.2 Hz; then on rigs with a transport delay
(``delay.delay_s`` 0.1-0.3 s; 90-s runs, seeds 0-1, 44 N), the PID as tuned against AMPC-servo with
the delay decided (``input_delay_samples = -1``, the default) and set. Writes ``tracking.png``
(44 N, 0.1 Hz, seed 0).
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np

import tapmuscle as tm
from tapmuscle.plots.figures import plot_tracking

TS_S = 0.1


def static_map(load_n: float = 44.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The commands [V] and the rig's rising and falling static displacements [mm] there (the mean of
    the last second of each 15-s hold of a 0..10..0 V staircase), each made increasing for inversion."""
    levels = np.arange(0.0, 10.01, 1.0)
    hold = 150
    steps = np.concatenate([levels, levels[::-1][1:]])
    l_mm = tm.simulate(np.repeat(steps, hold), ts_s=TS_S, load_n=load_n, seed=0)["l_mm"]
    ends = np.array([np.mean(l_mm[(i + 1) * hold - 10:(i + 1) * hold]) for i in range(len(steps))])
    up, down = ends[:len(levels)], ends[len(levels) - 1:][::-1]
    tiny = 1e-6 * np.arange(len(levels))  # strictly increasing where the map is flat (below the threshold)
    return levels, np.maximum.accumulate(up + tiny), np.maximum.accumulate(down + tiny)


class PID:
    """PI with the static map's feed-forward (module docstring): a law of one's own
    (``tm.ControlLaw``: ``step(l_mm, preview_mm) -> u_v``, ``reset()`` before each run, ``ts_s``)."""

    def __init__(self, levels: np.ndarray, up: np.ndarray, down: np.ndarray, *, kp: float = 0.8, ki: float = 5.0,
                 k_rate: float = 0.05, ts_s: float = TS_S) -> None:
        self.levels, self.up, self.down = levels, up, down
        self.kp, self.ki, self.k_rate, self.ts_s = kp, ki, k_rate, ts_s
        self.integral = 0.0

    def reset(self) -> None:
        self.integral = 0.0

    def feedforward(self, r_mm: float, r_next_mm: float) -> float:
        rate = (r_next_mm - r_mm) / self.ts_s
        rising = 0.5 + 0.5 * math.tanh(rate / 2.0)
        u_up = float(np.interp(r_next_mm, self.up, self.levels))
        u_down = float(np.interp(r_next_mm, self.down, self.levels))
        u_mean = float(np.interp(r_next_mm, 0.5 * (self.up + self.down), self.levels))
        return 0.5 * u_mean + 0.5 * (rising * u_up + (1.0 - rising) * u_down) + self.k_rate * rate

    def step(self, l_mm: float, preview_mm: np.ndarray) -> float:
        e = float(preview_mm[0]) - l_mm
        v = self.feedforward(float(preview_mm[0]), float(preview_mm[1])) + self.kp * e + self.integral
        u = min(max(v, 0.0), 10.0)
        if not ((v > 10.0 and e > 0.0) or (v < 0.0 and e < 0.0)):  # no integration further into a limit
            self.integral += self.ki * self.ts_s * e
        self.integral += self.ts_s * (u - v) / self.ki  # back-calculation: d(integral)/dt = (u - v) / Ki, as tuned
        return u


def run_pid(pid: PID, reference: tm.SineReference, *, duration_s: float, seed: int, load_n: float,
            delay_s: float = 0.0) -> dict[str, np.ndarray]:
    """The PID's closed loop on the rig, in the loop the paper's methods run in (``simulate_closed_loop``)."""
    rig = tm.PlantParams().with_values(**{"load.load_n": load_n, "delay.delay_s": delay_s})
    return tm.simulate_closed_loop(pid, reference, duration_s=duration_s, seed=seed, params=rig, ts_s=TS_S)


def mae_mm(run: dict[str, np.ndarray], from_s: float) -> float:
    late = run["t_s"] >= from_s
    return float(np.mean(np.abs(run["r_mm"] - run["l_mm"])[late]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/pid_baseline"), help="folder of tracking.png")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")  # the methods' watch on the delayed rigs: the table says it
    rig_map = static_map(load_n=44.0)  # the 44-N map at both loads, as a user measures it once
    print("Eq. (21) [mm], mean of seeds 0-2, 45-s runs")
    print(f"{'load, f':12s} {'PID':>7s} " + " ".join(f"{m:>10s}" for m in tm.METHODS))
    shown = {}
    for load in (44.0, 68.0):
        for f in (0.1, 0.2):
            ref = tm.SineReference(frequency_hz=f)
            cells = [np.mean([tm.eq21_error_mm(run_pid(PID(*rig_map), ref, duration_s=45.0, seed=s, load_n=load))
                              for s in range(3)])]
            for method in tm.METHODS:
                cells.append(np.mean([tm.eq21_error_mm(tm.simulate_closed_loop(method, ref, duration_s=45.0, seed=s,
                                                                               load_n=load)) for s in range(3)]))
            print(f"{load:3.0f} N {f:.1f} Hz {cells[0]:7.3f} " + " ".join(f"{c:10.3f}" for c in cells[1:]), flush=True)
        print(f"  ({load:g} N done)", file=sys.stderr, flush=True)
    ref = tm.SineReference()
    shown["PID"] = run_pid(PID(*rig_map), ref, duration_s=45.0, seed=0, load_n=44.0)
    shown["ampc_servo"] = tm.simulate_closed_loop("ampc_servo", ref, duration_s=45.0, seed=0, load_n=44.0)
    print("\nTransport delay, 44 N, 0.1 Hz, 90-s runs, seeds 0-1: mean |r - l| over 10-90 s [mm]")
    print(f"{'delay':>6s} {'PID':>7s} {'AMPC-servo -1':>14s} {'AMPC-servo set':>15s}")
    for delay_s in (0.1, 0.2, 0.3):
        rig = tm.PlantParams().with_values(**{"delay.delay_s": delay_s})
        pid = np.mean([mae_mm(run_pid(PID(*rig_map), ref, duration_s=90.0, seed=s, load_n=44.0, delay_s=delay_s),
                              10.0) for s in range(2)])
        auto, set_ = (np.mean([mae_mm(tm.simulate_closed_loop(
            "ampc_servo", ref, duration_s=90.0, seed=s, params=rig,
            settings=tm.ControllerSettings(method="ampc_servo", input_delay_samples=d)), 10.0) for s in range(2)])
            for d in (-1, round(delay_s / TS_S)))
        print(f"{delay_s:5.1f}s {pid:7.3f} {auto:14.3f} {set_:15.3f}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    plot_tracking(shown, args.out / "tracking.png", title="PID with a static-map feed-forward and AMPC-servo, 44 N, "
                  "0.1 Hz, seed 0", window_s=(10.1, 40.1))
    print(f"wrote {args.out / 'tracking.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
