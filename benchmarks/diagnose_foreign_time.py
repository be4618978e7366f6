"""Benchmark: ``tapmuscle diagnose`` of a foreign FMU's 10-minute recording (goal: <= 120 s on this
2-core machine), and the time of one simulation of it through the FMU.

The FMU is the demo's DC motor (C, ``tapmuscle.diagnosis.foreign_fmus``), 600 s at Ts = 0.05 s (12001
samples) of random voltage steps, with three of its parameters off by 10-15 % and two boundary
effects: a 0.15 s transport delay on ``V`` and a drifting speed sensor. The whole job is timed as the
command line runs it (mapping, calibration, search, JSON, report and figure).

With ``--model-exchange`` the recording (made through the co-simulation build) is diagnosed
through the motor built as a model-exchange-only FMU: integrated between samples by fmpy's CVode.

    python benchmarks/diagnose_foreign_time.py [--duration 600] [--model-exchange]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tapmuscle.diagnosis.foreign_demo import ForeignCase, build_demo_fmus, record_foreign_case  # noqa: E402
from tapmuscle.diagnosis.foreign_diagnose import diagnose_foreign  # noqa: E402
from tapmuscle.diagnosis.foreign_fmus import build_dc_motor_fmu  # noqa: E402

CASE = ForeignCase("benchmark_DcMotor", "DcMotor", "transport_delay[V]",
                   {"V:delay_s": 0.15, "omega:offset": 0.8, "omega:drift_per_min": 0.5},
                   {"K": 0.12, "J": -0.1, "Tc": 0.15}, "steps", True, [2026, 11])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0, help="recording length [s] (default 600)")
    ap.add_argument("--model-exchange", action="store_true",
                    help="diagnose through the model-exchange-only build of the motor")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fmu = build_demo_fmus(tmp / "fmus")["DcMotor"]
        rec, m = record_foreign_case(CASE, fmu, tmp / "case", duration_s=args.duration)
        t0 = time.perf_counter()
        plant = build_dc_motor_fmu(tmp / "me", interfaces=("ModelExchange",)) if args.model_exchange else fmu
        d, _ = diagnose_foreign(rec, plant, tmp / "out", map_path=m, progress=None)
        wall = time.perf_counter() - t0
    print(f"verdict {d.verdict}: {', '.join(d.named) or '-'}; ambiguous: "
          f"{[[a.effect for a in g] for g in d.ambiguous]}; held-out fit {d.fit_before_percent:.2f} % -> "
          f"{d.fit_after_percent:.2f} %")
    kind = "model exchange" if args.model_exchange else "co-simulation"
    print(f"whole diagnosis ({kind}): {wall:.1f} s, {d.simulations} simulations (goal <= 120 s)")


if __name__ == "__main__":
    main()
