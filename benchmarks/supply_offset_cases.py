"""A supply at another constant pressure than the plant file's, and a load mismatch, on field rigs.

Run: ``python benchmarks/supply_offset_cases.py OUT [--jobs 2]`` (about 5 min on two cores). The
field generator does not draw ``supply_pressure_offset`` (``field_cases.NOT_DRAWN``: the documented
seeds' recordings stay the same), so its cases are made here the way the generator makes its own:
16 rigs with 3-6 constants off (:func:`~tapmuscle.diagnosis.field_cases.draw_parameter_errors`, seeded
``[7100, i]``), at 44 or 68 N, under steps, random levels, a sine, a sine sum and the AMPC loop
(:func:`~tapmuscle.diagnosis.field_cases.record_case`). Cases 0-7 have a supply at 0.20-0.40 MPa
against the plant's 0.25, cases 8-15 a load 5-16 N off either way. Each is recorded and diagnosed as
``tapmuscle demo-mismatch`` does (:func:`~tapmuscle.diagnosis.field_demo.run_field_case`, with the
discriminating experiment run on the truth for an ``ambiguous`` verdict), and the table printed is
docs/diagnosis.md's ("A supply at another constant pressure"). Each case's ``diagnosis.json`` is in
``OUT/<case>/``.
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from tapmuscle.diagnosis.demo import DEMO_MODEL
from tapmuscle.diagnosis.field_cases import LOADS_N, FieldCase, _draw_excitation, _sign, draw_parameter_errors
from tapmuscle.diagnosis.field_demo import run_field_case

SEED = 7100
#: The supply pressures of cases 0-7 [MPa] (the plant's is 0.25).
SUPPLY_MPA = (0.20, 0.22, 0.23, 0.27, 0.30, 0.35, 0.21, 0.40)
EXCITATIONS = ("steps", "random", "ampc", "sine", "sinesum", "random", "steps", "ampc")
#: What the table reads from a finding: the supply pressure [MPa] or the extra load [N].
READ = {"supply.supply_pressure_mpa": "{:.3f} MPa", "load_mismatch.extra_n": "{:+.1f} N"}


def cases() -> list[FieldCase]:
    """The 16 cases (module docstring)."""
    out = []
    for i in range(16):
        rng = np.random.default_rng([SEED, i])
        errors = draw_parameter_errors(rng, DEMO_MODEL)
        load = float(LOADS_N[int(rng.integers(0, len(LOADS_N)))])
        excitation = EXCITATIONS[i % 8]
        params = _draw_excitation(excitation, rng)
        if i < 8:
            effect, values = "supply_pressure_offset", (("supply.supply_pressure_mpa", SUPPLY_MPA[i]),)
        else:
            effect, values = "load_mismatch", (("load_mismatch.extra_n", _sign(rng) * float(rng.uniform(5.0, 16.0))),)
        out.append(FieldCase(index=i, seed=SEED, category="single", effects=(effect,), effect_values=values,
                             parameter_errors=errors, load_n=load, excitation=excitation, excitation_params=params,
                             noise_seed=int(rng.integers(0, 2 ** 31))))
    return out


def _run(args: tuple[FieldCase, Path]) -> dict[str, Any]:
    case, out = args
    return run_field_case(case, out)


def _read(out: Path, r: dict[str, Any]) -> str:
    """The fitted supply pressure or load of the case's findings and alternatives."""
    doc = json.loads((out / r["case"] / "diagnosis.json").read_text())
    params = [f.get("parameters") or {} for f in doc["findings"]]
    params += [a.get("parameters") or {} for g in doc.get("ambiguous") or [] for a in g.get("alternatives", [])]
    return ", ".join(READ[k].format(v) for p in params for k, v in p.items() if k in READ)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(_run, [(c, args.out) for c in cases()]))
    print("| case | excitation | constants off | truth | verdict: named | fitted | held-out fit [%] (truth's) | experiment picks |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        (key, value), = r["effect_values"].items()
        groups = " / ".join("{" + ", ".join(g) + "}" for g in r["ambiguous"])
        disc = r.get("discrimination") or {}
        picked = ", ".join(disc.get("picked") or []) + (" (right)" if disc.get("right") else " (wrong)") if disc else ""
        print(f"| `{r['case'][:3]}` | {r['excitation']} | {len(r['parameter_errors'])} | {READ[key].format(value)} | "
              f"{r['verdict']}: {', '.join(r['named']) or '-'}{' ambiguous ' + groups if groups else ''} | "
              f"{_read(args.out, r)} | {r['fit_after_percent']:.2f} ({r['fit_truth_percent']:.2f}) | {picked} |")


if __name__ == "__main__":
    main()
