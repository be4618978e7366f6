"""How long the adaptive estimates sit on a bound of Table 2's box, on rigs that track.

Run: ``python benchmarks/box_bounds.py [--seconds 120]`` (about 5 s).
The rigs and references of ``benchmarks/other_rigs.py`` (each rig's own 35 + 30 sin(2 pi 0.1 t) mm
scaled to its reach), AMPC-UCP and AMPC-servo from their defaults (``THETA0_44N``, Table 2's box).
Printed per rig and method: the mean |r - l| [mm] over t >= 5 s, and for ``a1``, ``a2``, ``b1`` the share
of the run's second half spent on the lower / upper bound (Algorithm 1's projection). It shows why the
loop's watch does not tell a bound held: the estimates sit on one on rigs that track to 0.1 mm.
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

import tapmuscle as tm
from fmu_controller.rls import TABLE2_LOWER, TABLE2_UPPER
from other_rigs import RIGS, rig_and_reference


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=120.0, help="length of each run [s] (default 120)")
    args = ap.parse_args(argv)
    print(f"{'rig':16s} {'method':10s} {'mae':>6s}  share on lower/upper bound, second half")
    for i, (name, values) in enumerate(RIGS.items()):
        rig, _, ref = rig_and_reference(values)
        for method in ("ampc_ucp", "ampc_servo"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                run = tm.simulate_closed_loop(method, ref, duration_s=args.seconds, params=rig)
            mae = float(np.mean(np.abs(run["r_mm"] - run["l_mm"])[run["t_s"] >= 5.0]))
            half = run["t_s"] >= args.seconds / 2
            cells = []
            for p in ("a1", "a2", "b1"):
                theta = run["theta_" + p][half]
                on_lo = np.mean(np.abs(theta - TABLE2_LOWER[p]) < 1e-9)
                on_up = np.mean(np.abs(theta - TABLE2_UPPER[p]) < 1e-9)
                cells.append(f"{p} {on_lo:4.2f}/{on_up:4.2f}")
            print(f"{name:16s} {method:10s} {mae:6.2f}  " + "  ".join(cells), flush=True)
        print(f"  ({i + 1}/{len(RIGS)} rigs)", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
