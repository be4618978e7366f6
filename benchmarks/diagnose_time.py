"""Benchmark: wall time of ``diagnose`` on a 10-minute, 10 Hz recording (issue 6 goal: <= 30 s, one core).

Records the simulated rig (demo model + a concealed effect, the identification sine, noise on) for
600 s, then times :func:`diagnosis.report.diagnose_files` (the whole ``tapmuscle diagnose`` job:
reading, fitting every candidate, writing the JSON, report and PNGs) once per effect given.

    python benchmarks/diagnose_time.py [--effects transport_delay,supply_pressure_variation,none]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from diagnosis.demo import DEMO_MODEL, record  # noqa: E402
from diagnosis.report import diagnose_files  # noqa: E402
from tapmuscle.plant_file import plant_file_text  # noqa: E402
from tapmuscle.recording import Recording, atomic_write_text, write_recording  # noqa: E402

RIGS = {
    "none": {},
    "transport_delay": {"delay.delay_s": 0.15},
    "supply_pressure_variation": {"supply_variation.sag_mpa": 0.03, "supply_variation.start_s": 240.0,
                                  "supply_variation.end_s": 300.0},
    "valve_dead_zone": {"dead_zone.center_v": 4.5, "dead_zone.width_v": 0.8},
    "rate_dependent_hysteresis": {"friction.rate_gain": 0.6},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", default="none,transport_delay,supply_pressure_variation,valve_dead_zone,"
                                         "rate_dependent_hysteresis")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        plant = Path(tmp) / "plant.json"
        atomic_write_text(plant, plant_file_text(DEMO_MODEL, "demo model"))
        print(f"{'concealed effect':28s} {'samples':>8s} {'verdict':>24s} {'top finding':>28s} {'sims':>5s} {'wall [s]':>9s}")
        for name in args.effects.split(","):
            cols = record(DEMO_MODEL.with_values(**RIGS[name]), "sine", 0, duration_s=600.0)
            rec = Path(tmp) / f"{name}.csv"
            write_recording(rec, Recording(cols, {"ts_s": "0.1"}))
            t0 = time.perf_counter()
            d, doc = diagnose_files(rec, plant, Path(tmp) / name)
            wall = time.perf_counter() - t0
            top = doc["findings"][0]["effect"] if doc["findings"] else "-"
            print(f"{name:28s} {len(cols['t_s']):8d} {doc['verdict']:>24s} {top:>28s} {d.simulations:5d} {wall:9.1f}")


if __name__ == "__main__":
    main()
