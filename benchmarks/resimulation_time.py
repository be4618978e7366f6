"""Time of one noise-free re-simulation of a recording's commands, the unit of work of a diagnosis.

Run: ``python benchmarks/resimulation_time.py [--seconds S] [--repeats R]``. A diagnosis re-simulates
the recorded command with candidate plants thousands of times (``Simulator.run``, which steps the plant
with :meth:`fmu_plant.Plant.step_many`); this times that run for the nominal plant and with each
effect of the vocabulary that acts on the plant's ports, on a sine-sum command of ``S`` seconds at
10 Hz (default 600 s, the 10-minute recording of ``diagnose_time.py``). The machine may be shared,
so each figure is the best (lowest) of the repeats. Prints milliseconds per run and microseconds per
10-Hz step.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from fmu_plant import PlantParams
from tapmuscle.diagnosis.simulation import Simulator

TS_S = 0.1

#: The plants timed: the nominal one and one per port effect (magnitudes as in the field suite).
RIGS = {
    "nominal": {},
    "transport_delay 0.2 s": {"delay.delay_s": 0.2},
    "valve_dead_zone 0.9 V at 5.6 V": {"dead_zone.center_v": 5.6, "dead_zone.width_v": 0.9},
    "input_map (dead band 1.2 V at 5 V)": {"input_map.out_at_0_v": 0.6, "input_map.knot1_in_v": 4.4,
                                           "input_map.knot1_out_v": 5.0, "input_map.knot2_in_v": 5.6,
                                           "input_map.knot2_out_v": 5.0, "input_map.out_at_10_v": 9.4},
    "load_mismatch +10 N": {"load_mismatch.extra_n": 10.0},
    "supply sag 0.03 MPa, 240-300 s": {"supply_variation.sag_mpa": 0.03, "supply_variation.start_s": 240.0,
                                       "supply_variation.end_s": 300.0},
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0, help="length of the command [s]")
    ap.add_argument("--repeats", type=int, default=3, help="repeats; the best is reported")
    args = ap.parse_args(argv)
    if not args.seconds >= 10.0 or args.repeats < 1:
        ap.error("need --seconds >= 10 and --repeats >= 1")
    n = int(round(args.seconds / TS_S)) + 1
    t = np.arange(n) * TS_S
    u = 5.0 + 2.5 * np.sin(2 * np.pi * 0.05 * t) + 1.5 * np.sin(2 * np.pi * 0.13 * t + 1.0)
    sim = Simulator(u, TS_S)
    print(f"Simulator.run on {args.seconds:g} s of a sine-sum command ({n} samples), best of {args.repeats}")
    print(f"{'plant':<36} {'ms per run':>11} {'us per step':>12}")
    for name, values in RIGS.items():
        params = PlantParams().with_values(**values)
        best = np.inf
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            sim.run(params)
            best = min(best, time.perf_counter() - t0)
        print(f"{name:<36} {best * 1e3:11.1f} {best / (n - 1) * 1e6:12.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
