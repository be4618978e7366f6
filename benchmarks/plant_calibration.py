"""Print the simulated rig's calibration figures and the plant's step cost.

Run: ``python benchmarks/plant_calibration.py``. Makes the target recordings with
``tapmuscle record`` (Ts 0.1 s, seed 0, noise on) in a temporary folder and measures them.
"""

from __future__ import annotations

import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fmu_plant import Plant, PlantParams
from fmu_plant.rosenbrock import COMPILED
from tapmuscle.paper.rig_targets import TARGET_RECORDINGS, check_targets, loop_figures
from tapmuscle.cli.main import main as tapmuscle
from tapmuscle.io.recording import read_recording


def record(folder: Path, name: str, load: float, spec: str, duration: float, *extra: str):
    path = folder / f"{name}.csv"
    tapmuscle(["record", "--load", str(load), "--input", spec, "--duration", str(duration), "--ts", "0.1",
               "--seed", "0", "--out", str(path), "--quiet", *extra])
    rec = read_recording(path)
    return rec.t_s, rec.u_v, rec.l_mm


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        recs = {n: record(folder, n, *v) for n, v in TARGET_RECORDINGS.items()}
        checks = check_targets(recs)
        width = max(len(c.name) for c in checks)
        print(f"{'target':<{width}}  {'measured':>9}  bound")
        for c in checks:
            print(f"{c.name:<{width}}  {c.value:9.2f}  {c.bound}  {'ok' if c.ok else 'FAIL'}")
        lag = loop_figures(*record(folder, "lag_only", 44.0, "sine:bias=5,amp=3,freq=0.01", 240.0,
                                   "--set", "friction.base_n=0", "--set", "friction.per_mpa_n=0"))
        full = loop_figures(*recs["quasi_static_44"])
        print(f"\nquasi-static 44 N loop width at 5 V: {full.width_at_mm[5.0]:.2f} mm with friction, "
              f"{lag.width_at_mm[5.0]:.2f} mm from hydraulic lag alone (friction off)")
    plant = Plant(PlantParams(), seed=0)
    times = []
    for k in range(2000):
        t0 = time.perf_counter()
        plant.step(5 + 3 * math.sin(2 * math.pi * 0.1 * k * 0.1), 0.1)
        times.append(time.perf_counter() - t0)
    print(f"plant step (Ts 0.1 s, ROS34PW2 sub-steps, {'compiled' if COMPILED else 'Python'}): "
          f"median {1e6 * statistics.median(times):.0f} us, p99 {1e6 * float(np.percentile(times, 99)):.0f} us")
    return 0 if all(c.ok for c in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
