"""Benchmark (accuracy): how much of the field suite's held-out fit misses is a supply sag's timing
(docs/diagnosis.md, "Where it misses, and why").

The field suite's target "held-out fit after >= 95 %" is missed mostly on recordings with a supply
sag whose fall or recovery lies inside a held-out block: the training blocks cannot say when, within
that block, the edge came, and the diagnosis predicts a ramp across the stretch (method, step 5).
This script measures that ceiling. Every case of the given seeds whose truth has a sag is diagnosed
(``run_field_case(..., keep=True)``, as ``tapmuscle demo-mismatch`` does); where the held-out fit
after is under 95 %, the kept ``calibrated_plant.json`` is re-simulated on the same recording with
only the sag's timing (start, end, both ramps) set to the rig's, its fitted depth and every other
value kept. A fit that then reaches 95 % lacked nothing but what the training blocks cannot show;
one that does not also lacks an effect (the pair misses).

    python benchmarks/sag_timing_ceiling.py [--seeds 0 1 2 3] [--jobs 2] [--out DIR]

About 30 s per sag case on one core (12 per seed on average).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fmu_plant.parameters import PlantParams  # noqa: E402
from tapmuscle.diagnosis.diagnose import BLOCK_S  # noqa: E402
from tapmuscle.diagnosis.field_cases import FieldCase, field_cases  # noqa: E402
from tapmuscle.diagnosis.field_demo import run_field_case  # noqa: E402
from tapmuscle.diagnosis.plant_source import load_plant  # noqa: E402
from tapmuscle.diagnosis.residual_analysis import fit_percent, interleaved_split  # noqa: E402
from tapmuscle.diagnosis.simulation import Simulator  # noqa: E402
from tapmuscle.io.recording import read_recording  # noqa: E402

SAG = "supply_pressure_variation"
TIMING = ("supply_variation.start_s", "supply_variation.end_s", "supply_variation.ramp_s",
          "supply_variation.recovery_ramp_s")
TARGET_PERCENT = 95.0


def _one(case: FieldCase, out: Path) -> dict[str, Any]:
    result = run_field_case(case, out, keep=True)
    row = {"case": f"seed {case.seed} {case.name}", "effects": list(case.effects), "named": result["named"],
           "fit": result["fit_after_percent"], "resimulated": None, "rig_timing": None}
    if row["fit"] is None or row["fit"] >= TARGET_PERCENT:
        return row
    folder = out / case.name
    fitted, _ = load_plant(folder / "calibrated_plant.json")
    cols = read_recording(folder / "recording.csv").columns
    ts = float(np.median(np.diff(cols["t_s"])))
    sim = Simulator(cols["u_v"], ts, cols.get("load_n"))
    y = cols["l_mm"]
    _, held_out = interleaved_split(len(y), ts, BLOCK_S)
    rig = dict(case.effect_values)
    default = PlantParams()
    timing = {key: rig.get(key, default.value(key)) for key in TIMING}
    row["resimulated"] = fit_percent(y, sim.run(fitted)[0], held_out)
    row["rig_timing"] = fit_percent(y, sim.run(fitted.with_values(**timing))[0], held_out)
    return row


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--recordings", type=int, default=100, help="the suite's size per seed (as demo-mismatch)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="keep the cases' folders here (default: a temporary one)")
    args = ap.parse_args(argv)
    cases = [c for seed in args.seeds for c in field_cases(args.recordings, seed) if SAG in c.effects]
    print(f"{len(cases)} cases with a supply sag in seeds {args.seeds}", flush=True)
    with tempfile.TemporaryDirectory() as tmp, ProcessPoolExecutor(args.jobs) as pool:
        out = args.out or Path(tmp)
        futures = [pool.submit(_one, c, out / f"seed{c.seed}") for c in cases]
        rows = []
        for i, fut in enumerate(futures, 1):
            row = fut.result()
            rows.append(row)
            tail = "" if row["rig_timing"] is None else f" -> {row['rig_timing']:.2f} % with the rig's sag timing"
            print(f"[{i}/{len(cases)}] {row['case']}: truth {'+'.join(row['effects'])}, named "
                  f"{', '.join(row['named']) or 'nothing'}; held-out fit {row['fit']:.2f} %{tail}", flush=True)
    misses = [r for r in rows if r["rig_timing"] is not None]
    reached = [r for r in misses if r["rig_timing"] >= TARGET_PERCENT]
    worst = max((abs(r["resimulated"] - r["fit"]) for r in misses), default=0.0)
    print(f"\n{len(rows)} sag cases; {len(misses)} under {TARGET_PERCENT:g} % held-out fit; "
          f"{len(reached)} of them reach it with only the sag's timing set to the rig's "
          f"(re-simulation of the kept plant within {worst:.3f} point of the diagnosis's figure)")
    for r in misses:
        if r["rig_timing"] < TARGET_PERCENT:
            missing = sorted(set(r["effects"]) - set(r["named"]))
            print(f"  not reached: {r['case']} {r['rig_timing']:.2f} %; not named: {', '.join(missing) or 'none'}")


if __name__ == "__main__":
    main()
