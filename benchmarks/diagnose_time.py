"""Benchmark: wall time of ``diagnose`` on a 10-minute, 10 Hz recording (goal: <= 60 s on this 2-core
machine for a rig whose constants are off with two left-out effects).

Records the simulated rig for 600 s (the identification sine, noise on): the demo model with some of
its nominal constants off by 10-20 % and 0, 1 or 2 concealed effects; then times
:func:`tapmuscle.diagnosis.report.diagnose_files` (the whole ``tapmuscle diagnose`` job: reading, calibrating,
fitting the candidates, writing the JSON, report and PNGs) once per rig given.

    python benchmarks/diagnose_time.py [--rigs field_two_effects,field_none,...] [--excitation sine] [--workers 2]
                                       [--use-pressure]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tapmuscle.diagnosis.demo import DEMO_MODEL, record  # noqa: E402
from tapmuscle.diagnosis.report import diagnose_files  # noqa: E402
from tapmuscle.io.plant_file import plant_file_text  # noqa: E402
from tapmuscle.io.recording import Recording, atomic_write_text, write_recording  # noqa: E402

#: Nominal constants off as a real rig's are: stiffness +15 %, base friction -20 %, valve Cv -10 %,
#: friction growth with pressure +12 %.
OFF = {"muscle.rubber_stiffness_n_per_mm": 1.2 * 1.15, "friction.base_n": 8.0 * 0.8, "valve.cv_max": 1.5 * 0.9,
       "friction.per_mpa_n": 30.0 * 1.12}

RIGS = {
    "clean": {},
    "field_none": OFF,
    "field_two_effects": OFF | {"delay.delay_s": 0.2, "supply_variation.sag_mpa": 0.03,
                                "supply_variation.start_s": 240.0, "supply_variation.end_s": 300.0},
    "field_delay_load": OFF | {"delay.delay_s": 0.15, "load_mismatch.extra_n": 8.0},
    "transport_delay": {"delay.delay_s": 0.15},
    "valve_dead_zone": {"dead_zone.center_v": 4.5, "dead_zone.width_v": 0.8},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", default="clean,field_none,field_two_effects,field_delay_load")
    ap.add_argument("--excitation", default="sine", choices=("sine", "steps", "ampc"))
    ap.add_argument("--workers", type=int, default=2, help="processes for the simulations (default 2)")
    ap.add_argument("--use-pressure", action="store_true", help="weigh the recorded pressure too (diagnose(use_pressure=True))")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        plant = Path(tmp) / "plant.json"
        atomic_write_text(plant, plant_file_text(DEMO_MODEL, "demo model"))
        print(f"{'rig':20s} {'samples':>8s} {'verdict':>24s} {'named (ambiguous)':>48s} {'fit after':>9s} "
              f"{'sims':>5s} {'wall [s]':>9s}", flush=True)
        for name in args.rigs.split(","):
            if name not in RIGS:
                sys.exit(f"unknown rig {name!r}; known: {', '.join(RIGS)}")
            cols = record(DEMO_MODEL.with_values(**RIGS[name]), args.excitation, 0, duration_s=600.0)
            rec = Path(tmp) / f"{name}.csv"
            write_recording(rec, Recording(cols, {"ts_s": "0.1"}))
            t0 = time.perf_counter()
            d, doc = diagnose_files(rec, plant, Path(tmp) / name, workers=args.workers, use_pressure=args.use_pressure)
            wall = time.perf_counter() - t0
            named = ",".join(d.named) or "-"
            if d.ambiguous:
                named += " (" + "; ".join("/".join(a.effect for a in g) for g in d.ambiguous) + ")"
            print(f"{name:20s} {len(cols['t_s']):8d} {doc['verdict']:>24s} {named:>48s} "
                  f"{doc['fit_after_percent']:8.2f}% {d.simulations:5d} {wall:9.1f}", flush=True)


if __name__ == "__main__":
    main()
