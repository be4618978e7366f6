"""Per-step compute time of the simulated rig: ``Plant.step(u, 0.1)`` on the identification sine.

Run: ``python benchmarks/plant_step_time.py [--steps N] [--repeats R]``. Each repeat runs a fresh
plant (default parameters, 44 N) for N steps of 0.1 s under ``u = 5 + 3 sin(2 pi f t)`` V and times
every step; the machine may be shared, so the figures are the best (lowest) over the repeats. Also
prints the sub-steps the adaptive integrator took (attempts, rejected) and the plant-only real-time
factor, 0.1 s / median step time, for the compiled sub-step (fmu_plant/_ros34pw2.c, when installed)
and for the Python one (the FMUs'; the same bits). Goal: median <= 80 us (real-time factor >= 1250)
with the Python sub-step, the slower of the two.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

import numpy as np

from fmu_plant import Plant, PlantParams
from fmu_plant.rosenbrock import COMPILED, adaptive_steps, build_model

TS_S = 0.1


def run_once(freq_hz: float, steps: int, compiled: bool) -> tuple[list[float], int, int]:
    """Step times [s] of one run, and the integrator's sub-step attempts and rejections."""
    plant = Plant(PlantParams(), seed=0)
    _, _, inner, plant._set_gate, advance = build_model(plant.params, compiled=compiled)
    counts = [0, 0]

    def counting(*args):
        out = inner(*args)
        counts[0] += 1
        counts[1] += not out[5] <= 1.0
        return out

    commands = [5.0 + 3.0 * math.sin(2.0 * math.pi * freq_hz * k * TS_S) for k in range(steps)]
    times = []
    clock = time.perf_counter
    for phase in ("count", "time"):
        plant.reset()
        # the sub-steps are counted in the Python loop around the same sub-step (the same bits)
        plant._advance_substeps = adaptive_steps(counting, plant.params) if phase == "count" else advance
        for u in commands:
            if phase == "time":
                t0 = clock()
                plant.step(u, TS_S)
                times.append(clock() - t0)
            else:
                plant.step(u, TS_S)
    return times, counts[0], counts[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000, help="steps per repeat (>= 2000)")
    ap.add_argument("--repeats", type=int, default=5, help="repeats; the best is reported")
    args = ap.parse_args(argv)
    if args.steps < 2000 or args.repeats < 1:
        ap.error("need --steps >= 2000 and --repeats >= 1")
    print(f"Plant.step(u, {TS_S} s), u = 5 + 3 sin(2 pi f t) V, 44 N, {args.steps} steps, best of {args.repeats}")
    print(f"{'sub-step':>9} {'f [Hz]':>6} {'median [us]':>12} {'p99 [us]':>9} {'RTF':>7} {'sub-steps/step':>15} "
          f"{'rejected/step':>14}")
    ok = True
    for compiled in (True, False) if COMPILED else (False,):
        for freq in (0.1, 0.2):
            medians, p99s = [], []
            for _ in range(args.repeats):
                times, attempts, rejected = run_once(freq, args.steps, compiled)
                medians.append(statistics.median(times))
                p99s.append(float(np.percentile(times, 99)))
            med, p99 = min(medians), min(p99s)
            print(f"{'compiled' if compiled else 'Python':>9} {freq:6.1f} {med * 1e6:12.1f} {p99 * 1e6:9.1f} "
                  f"{TS_S / med:7.0f} {attempts / args.steps:15.2f} {rejected / args.steps:14.2f}")
            if freq == 0.1 and not compiled:
                ok = med <= 80e-6
    print(f"\ngoal (0.1 Hz, Python sub-step: median <= 80 us): {'met' if ok else 'NOT met'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
