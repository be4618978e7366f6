"""The four controllers on rigs other than the paper's, from each source of a fixed predictor ``theta0``.

Run: ``python benchmarks/other_rigs.py [--seconds 60] [--rigs L600 ps015 ...]`` (about 15 s).
Ten simulated rigs: muscles of 250 and 600 mm (``muscle.rest_length_mm``), supplies of 0.15 and 0.4 MPa,
loads of 20 and 100 N, three of these together, and the paper's rig. At 20 N the braid lock is set to
15 N, as the plant's light-load warning advises. Each rig's reach is the displacement after 30 s at 10 V;
its reference is the paper's 35 + 30 sin(2 pi 0.1 t) mm as fractions of the paper's rig's reach
(0.36 and 0.30 of it). The sources of ``theta0``:

* ``THETA0_44N``: the controllers' default, the paper's rig's;
* ``identify``: Eq. (1) identified open loop (5 + 3 sin(2 pi 0.1 t) V, 240 s) with Table 2's box, as
  ``tapmuscle identify`` does at 0.1 s in mm and V (``*``: its free run diverged);
* ``refined 35+-30``: ``tapmuscle.paper.preliminary_theta(params=rig)``, refined in closed loop over the
  paper's 35 +- 30 mm;
* ``refined, rig's``: the same, refined over the rig's own reference (``refine_offset_mm``,
  ``refine_amplitude_mm``).

Printed per rig, source and method: the mean |r - l| [mm] over t >= 5 s, and ``!`` where the loop's
watch warned. The adaptive methods keep Table 2's box (the paper's), whatever ``theta0``.
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

import tapmuscle as tm
from fmu_controller.identification import identify_record
from fmu_plant.open_loop import run_open_loop
from tapmuscle.io.signals import parse_input_spec
from tapmuscle.paper.reproduce import preliminary_theta

LIGHT = {"muscle.braid_lock_force_n": 15.0}
RIGS = {
    "paper's": {},
    "L250": {"muscle.rest_length_mm": 250.0},
    "L600": {"muscle.rest_length_mm": 600.0},
    "ps015": {"supply.supply_pressure_mpa": 0.15},
    "ps040": {"supply.supply_pressure_mpa": 0.40},
    "W20": {"load.load_n": 20.0, **LIGHT},
    "W100": {"load.load_n": 100.0},
    "L250 ps015 W100": {"muscle.rest_length_mm": 250.0, "supply.supply_pressure_mpa": 0.15, "load.load_n": 100.0},
    "L600 ps040 W20": {"muscle.rest_length_mm": 600.0, "supply.supply_pressure_mpa": 0.40, "load.load_n": 20.0, **LIGHT},
    "L150 ps015 W100": {"muscle.rest_length_mm": 150.0, "supply.supply_pressure_mpa": 0.15, "load.load_n": 100.0},
}
#: The paper's 35 and 30 mm over the simulated paper's rig's reach (98 mm at 10 V).
OFFSET, AMPLITUDE = 0.36, 0.30


def reach_mm(rig: tm.PlantParams) -> float:
    """The displacement [mm] after 30 s at 10 V from rest."""
    return float(tm.simulate(np.full(301, 10.0), ts_s=0.1, params=rig, seed=0)["l_mm"][-1])


def rig_and_reference(values: dict[str, float]) -> tuple[tm.PlantParams, float, tm.SineReference]:
    """The rig of ``values`` (a :data:`RIGS` entry), its reach [mm] and its own reference: the paper's
    sine as fractions of the paper's rig's reach (:data:`OFFSET`, :data:`AMPLITUDE`)."""
    rig = tm.PlantParams().with_values(**values)
    hi = reach_mm(rig)
    return rig, hi, tm.SineReference(offset_mm=OFFSET * hi, amplitude_mm=AMPLITUDE * hi)


def sources(rig: tm.PlantParams, offset_mm: float, amplitude_mm: float) -> dict[str, tuple[np.ndarray, str]]:
    """Each source's theta0 and a mark (``*``: the identification's free run diverged)."""
    rec = run_open_loop(tm.Plant(rig, seed=0), parse_input_spec("sine:bias=5,amp=3,freq=0.1"), duration_s=240.0,
                        ts_s=0.1)
    report = identify_record(rec["u_v"], rec["l_mm"], ts_s=0.1)
    return {"THETA0_44N": (np.array(tm.THETA0_44N), ""),
            "identify": (report.theta, "*" if report.fit.free_run_diverged else ""),
            "refined 35+-30": (preliminary_theta(0, params=rig), ""),
            "refined, rig's": (preliminary_theta(0, params=rig, refine_offset_mm=offset_mm,
                                                 refine_amplitude_mm=amplitude_mm), "")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of each run [s] (default 60)")
    ap.add_argument("--rigs", nargs="+", choices=list(RIGS), default=list(RIGS), metavar="RIG",
                    help=f"rigs to run (default all: {', '.join(RIGS)})")
    args = ap.parse_args(argv)
    print(f"{'rig':16s} {'reach':>6s} {'theta0':15s} " + " ".join(f"{m:>11s}" for m in tm.METHODS))
    for i, name in enumerate(args.rigs):
        rig, hi, ref = rig_and_reference(RIGS[name])
        for source, (theta0, mark) in sources(rig, OFFSET * hi, AMPLITUDE * hi).items():
            cells = []
            for method in tm.METHODS:
                with warnings.catch_warnings(record=True) as told:
                    warnings.simplefilter("always")
                    run = tm.simulate_closed_loop(method, ref, duration_s=args.seconds, params=rig, theta0=theta0)
                late = run["t_s"] >= 5.0
                mae = float(np.mean(np.abs(run["r_mm"] - run["l_mm"])[late]))
                watched = any(issubclass(w.category, RuntimeWarning) for w in told)
                cells.append(f"{mae:10.3f}{'!' if watched else ' '}")
            print(f"{name:16s} {hi:6.1f} {source + mark:15s} " + " ".join(cells), flush=True)
        print(f"  ({i + 1}/{len(args.rigs)} rigs)", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
