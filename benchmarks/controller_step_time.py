"""Per-step compute time of each controller (issue 4): median and p99 over >= 2000 steps.

Run: ``python benchmarks/controller_step_time.py``. Each controller runs in closed loop with the
simulated rig (44 N, 0.1 Hz reference); only ``DisplacementController.step`` is timed (the plant
is not). Goal for AMPC-servo: median <= 100 us, p99 <= 1 ms on one core.
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from fmu_controller.displacement_control import METHODS, ControllerSettings, DisplacementController
from fmu_controller.reference import SineReference
from fmu_plant import Plant
from tapmuscle.paper import preliminary_theta

STEPS = 2500


def main() -> int:
    theta0 = preliminary_theta(0)
    ref = SineReference()
    print(f"{'method':<11} {'median [us]':>12} {'p99 [us]':>10} {'max [us]':>10}   ({STEPS} steps, closed loop)")
    result = {}
    for method in METHODS:
        c = DisplacementController(ControllerSettings(method=method), theta0)
        plant = Plant(seed=0)
        hp = c.settings.preview_samples
        meas = plant.measurement
        c.reset(meas.l_mm)
        times = []
        for k in range(STEPS):
            preview = ref.preview(k, hp)
            t0 = time.perf_counter()
            step = c.step(meas.l_mm, preview)
            times.append(time.perf_counter() - t0)
            meas = plant.step(step.u_v, ref.ts_s)
        med, p99 = statistics.median(times) * 1e6, float(np.percentile(times, 99)) * 1e6
        result[method] = (med, p99)
        print(f"{method:<11} {med:12.0f} {p99:10.0f} {max(times) * 1e6:10.0f}")
    med, p99 = result["ampc_servo"]
    print(f"\nAMPC-servo goal (median <= 100 us, p99 <= 1000 us): {'met' if med <= 100 and p99 <= 1000 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
