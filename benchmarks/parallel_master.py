"""Tracking in a parallel (Jacobi) co-simulation master at h = Ts: the tables of docs/fmu.md, "Parallel masters".

A parallel master applies the controller's command one macro step late. The direct loop
``run_closed_loop(..., loop_delay_samples=1)`` is that master to 1e-9 mm (libcosim, Ecos and the FMU
container are checked against it in the tests), so this runs the direct loops: seed 0, the controller
FMU's defaults but for ``input_delay_samples`` (and ``delay_correction``), the built-in sine.

Prints Eq. (21) (10-40 s) for each method, load and frequency of docs/fmu.md: the sequential master
with 0, and the parallel one with 0, with 1 (Eq. (1) alone and with the corrected one-step
prediction) and with the default -1; writes ``parallel_master.png`` (AMPC-servo, 44 N, 0.1 Hz).

    python benchmarks/parallel_master.py [--out out/parallel_master]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from fmu_controller.displacement_control import ControllerSettings, DisplacementController
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.reference import SineReference
from fmu_plant import Plant, PlantParams
from tapmuscle.closed_loop import eq21_error_mm, run_closed_loop
from tapmuscle.plots.figures import new_figure, save_figure

CASES = (("ampc_servo", 44.0, 0.1), ("ampc_servo", 44.0, 0.2), ("ampc_servo", 68.0, 0.1), ("ampc_servo", 68.0, 0.2),
         ("mpc_servo", 44.0, 0.1), ("mpc_servo", 68.0, 0.2), ("mpc_ucp", 44.0, 0.1), ("ampc_ucp", 44.0, 0.1))
#: (label, input_delay_samples, delay_correction, loop_delay_samples)
COLUMNS = (("sequential, 0", 0, True, 0), ("parallel, 0", 0, True, 1), ("par., 1, Eq.(1)", 1, False, 1),
           ("parallel, 1", 1, True, 1), ("parallel, -1", -1, True, 1))


def run(method: str, load_n: float, frequency_hz: float, input_delay: int, correction: bool, loop_delay: int,
        duration_s: float = 45.0) -> dict[str, np.ndarray]:
    settings = ControllerSettings(method=method, input_delay_samples=input_delay, delay_correction=correction)
    plant = Plant(PlantParams().with_values(**{"load.load_n": load_n}), seed=0)
    return run_closed_loop(plant, DisplacementController(settings, THETA0_44N),
                           SineReference(frequency_hz=frequency_hz), duration_s=duration_s,
                           loop_delay_samples=loop_delay, watch=False)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/parallel_master"), help="folder of parallel_master.png")
    args = parser.parse_args(argv)
    print("Eq. (21), 10-40 s [mm], seed 0:")
    print(f"  {'method':<11} {'load, f':<13}" + "".join(f"{c[0]:>16}" for c in COLUMNS))
    for i, (method, load, f) in enumerate(CASES):
        values = [eq21_error_mm(r["r_mm"], r["l_mm"]) for r in (run(method, load, f, *c[1:]) for c in COLUMNS)]
        ratio = values[3] / values[0]
        print(f"  {method:<11} {f'{load:g} N, {f:g} Hz':<13}" + "".join(f"{v:>16.3f}" for v in values)
              + f"   parallel 1 / sequential {ratio:4.2f}", flush=True)
    print("  (par., 1, Eq.(1): input_delay_samples = 1 with delay_correction = 0)")

    fig, (ax_e, ax_u) = new_figure(2, 1, figsize=(10, 6.5), sharex=True)
    for (label, d, corr, loop), color in zip((COLUMNS[0], COLUMNS[2], COLUMNS[3]), ("k", "tab:red", "tab:blue")):
        r = run("ampc_servo", 44.0, 0.1, d, corr, loop, duration_s=60.0)
        e = r["r_mm"] - r["l_mm"]
        mean = float(np.mean(np.abs(e)[200:601]))
        ax_e.plot(r["t_s"], e, color=color, lw=0.9, label=f"{label}: mean |r - l| 20-60 s = {mean:.3f} mm")
        ax_u.plot(r["t_s"], r["u_v"], color=color, lw=0.9, label=label)
    ax_e.set_ylim(-1.5, 1.5)
    ax_e.set_ylabel("r - l [mm]")
    ax_e.set_title("AMPC-servo, 44 N, 35 + 30 sin(2 pi 0.1 t) mm, h = Ts = 0.1 s")
    ax_e.legend(loc="upper right", fontsize=8)
    ax_u.set_ylabel("u at the valve [V]")
    ax_u.set_xlabel("t [s]")
    ax_u.set_xlim(10, 60)
    for ax in (ax_e, ax_u):
        ax.grid(alpha=0.3)
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"wrote {save_figure(fig, args.out / 'parallel_master.png', dpi=110)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
