"""24-hour soak of the adaptive loop (AMPC-servo): changing reference, load steps, drifting supply.

Run: ``python benchmarks/soak.py [--hours 24] [--seed 0] [--out out/soak]`` (about 3 minutes for
24 h on one core). Two estimators run through the same schedule (:mod:`tapmuscle.soak`):

* ``paper``: Algorithm 1 as the paper runs it (Eq. (4), no forgetting);
* ``long-run``: forgetting 0.999 (a memory of Ts / (1 - lambda) = 100 s, shorter than the shortest
  hold of any condition, 120 s) with the covariance ceiling ``P <= P(0)``
  (``ControllerSettings.covariance_ceiling``), which stops the wind-up that forgetting alone causes.

Printed: each check of :meth:`tapmuscle.soak.SoakResult.checks` and
:meth:`~tapmuscle.soak.SoakResult.timing_checks` with its figures, the covariance's
smallest eigenvalue and condition number every two hours, and the blocks above twice the first
hour's error next to a fresh loop's error on the same block. Stored: ``soak.png`` (error per block,
theta-hat, covariance over the run) and ``soak.json``. Exit status 1 when the long-run estimator
fails a check other than the literal ``error_bounded`` (whose exceptions ``no_degradation`` judges).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from fmu_controller.displacement_control import ControllerSettings
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.preliminary_model import THETA0_44N
from tapmuscle.progress import Progress
from tapmuscle.io.recording import atomic_write_text
from tapmuscle.plots.soak_figures import plot_soak
from tapmuscle.soak import SoakSettings, run_soak

CONFIGS = {
    "paper": ControllerSettings(method="ampc_servo"),
    "long-run": ControllerSettings(method="ampc_servo", forgetting=0.999, covariance_ceiling=True),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="simulated hours (default 24)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the schedule and the noise")
    parser.add_argument("--out", type=Path, default=Path("out/soak"), help="folder of soak.png and soak.json")
    args = parser.parse_args(argv)
    settings = SoakSettings(duration_s=args.hours * 3600.0, seed=args.seed)
    print(f"soak: {args.hours:g} h = {int(round(settings.duration_s / settings.ts_s)):,} samples, seed {args.seed}, "
          f"AMPC-servo; reference 0.05-0.3 Hz, 10-60 mm peak to peak; load 30-80 N; supply 0.20-0.30 MPa", flush=True)
    runs, report, failed = {}, {}, False
    for label, cs in CONFIGS.items():
        bar = Progress(f"soak {label}", min_total=1)
        bar(0, 1)
        res = run_soak(settings, theta0=THETA0_44N, controller=cs, progress=bar)
        checks = {**res.checks(), **res.timing_checks()}
        report[label] = {"checks": checks, "blocks": res.blocks, "elapsed_s": res.elapsed_s}
        print(f"\n== {label} (forgetting {cs.forgetting:g}, covariance ceiling {'on' if cs.covariance_ceiling else 'off'}): "
              f"{res.elapsed_s:.0f} s")
        for name, c in checks.items():
            figures = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in c.items() if k != "passed")
            print(f"  {'pass' if c['passed'] else 'FAIL'}  {name}: {figures}")
        print("  covariance over time (scaled form D^-1/2 P D^-1/2):")
        every = max(1, int(round(2 * 3600.0 / settings.covariance_every_s)))
        for i in range(0, len(res.covariance_t_s), every):
            t, (lo, hi, slo, shi) = res.covariance_t_s[i], res.p_eigenvalues[i]
            print(f"    {t / 3600.0:5.1f} h  P eig {lo:.2e} .. {hi:.3g}  scaled eig {slo:.2e} .. {shi:.3g}  "
                  f"scaled cond {shi / slo if slo > 0 else math.inf:.2e}")
        over = [b for b in res.blocks if b["fresh_eq21_mm"] is not None]
        if over:
            print(f"  blocks above 2 x first hour ({2 * checks['error_bounded']['first_hour_mm']:.3f} mm), soaked vs fresh loop:")
            for b in over:
                print(f"    {b['start_s'] / 3600.0:5.2f} h  {b['eq21_mm']:.3f} mm vs {b['fresh_eq21_mm']:.3f} mm  "
                      f"(load {b['load_n_mean']:.0f} N, supply {b['supply_mpa_mean']:.3f} MPa, f <= {b['frequency_hz_max']:.2f} Hz)")
        if label == "long-run":
            failed = not all(c["passed"] for n, c in checks.items() if n != "error_bounded")
        runs[label] = res.figure_data()
    cs = CONFIGS["long-run"]
    lower = np.array([cs.box_lower.get(n, -np.inf) for n in ASYMMETRIC.names])
    upper = np.array([cs.box_upper.get(n, np.inf) for n in ASYMMETRIC.names])
    png = plot_soak(runs, ASYMMETRIC.names, args.out / "soak.png", theta_lower=lower, theta_upper=upper)
    atomic_write_text(args.out / "soak.json", json.dumps(report, indent=1, default=float) + "\n")
    print(f"\nwrote {png} and {args.out / 'soak.json'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
