"""The spike guard under a sensor that spikes every few seconds.

Run: ``python benchmarks/frequent_spikes.py [--seconds 90] [--every-s 2] [--seeds 0 1]`` (about 30 s).
The paper's rig (44 N, the sine 35 + 30 sin(2 pi 0.1 t) mm); from 6 s on, every ``--every-s`` the
reading is 30 mm (or 15 mm) off, towards the middle of the range (a potentiometer's wiper lifting, an
ADC's bad conversion). Printed per method: the mean |r - l| of the real displacement over t >= 30 s
and the readings held, without spikes, with them and the guard (``max_speed_mm_per_s`` default), and
with them unguarded (``max_speed_mm_per_s = 0``); means over the seeds (held: summed).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import tapmuscle as tm


def run(method: str, spike_mm: float, every: int, seconds: float, seed: int, guard: bool = True) -> tuple[float, int]:
    """Mean |r - l| [mm] over t >= 30 s and the readings held, for readings ``spike_mm`` off every
    ``every`` samples from 6 s on."""
    settings = tm.ControllerSettings(method=method, max_speed_mm_per_s=400.0 if guard else 0.0)
    c = tm.DisplacementController(settings, tm.THETA0_44N)
    plant, ref = tm.Plant(seed=seed), tm.SineReference()
    c.reset(plant.measurement.l_mm)
    errors, held = [], 0
    for k in range(int(round(seconds / settings.ts_s)) + 1):
        l = plant.measurement.l_mm
        if spike_mm and k > 60 and k % every == 0:
            l = l - spike_mm if l > spike_mm + 2.0 else l + spike_mm
        step = c.step(l, ref.preview(k, settings.preview_samples))
        held += c.reading_held is not None
        if k * settings.ts_s >= 30.0:
            errors.append(abs(ref.at(k) - plant.l_mm))
        plant.step(step.u_v, settings.ts_s)
    return float(np.mean(errors)), held


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=90.0, help="length of each run [s] (default 90)")
    ap.add_argument("--every-s", type=float, default=2.0, help="time between spikes [s] (default 2)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="noise seeds (default 0 1)")
    args = ap.parse_args(argv)
    every = max(1, int(round(args.every_s / 0.1)))
    cases = [("no spikes", 0.0, True), ("30 mm, guard", 30.0, True), ("30 mm, no guard", 30.0, False),
             ("15 mm, guard", 15.0, True), ("15 mm, no guard", 15.0, False)]
    print(f"mean |r - l| [mm] over t >= 30 s (readings held), spikes every {args.every_s:g} s, seeds {args.seeds}")
    print(f"{'method':11s} " + " ".join(f"{name:>18s}" for name, _, _ in cases))
    for method in tm.METHODS:
        cells = []
        for _, spike, guard in cases:
            got = [run(method, spike, every, args.seconds, seed, guard) for seed in args.seeds]
            cells.append(f"{np.mean([g[0] for g in got]):10.3f} ({sum(g[1] for g in got):3d})")
        print(f"{method:11s} " + " ".join(f"{c:>18s}" for c in cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
