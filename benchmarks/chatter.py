"""MPC-servo's valve chatter with the paper's Eq. (5), and without it (the hysteresis notch).

Run: ``python benchmarks/chatter.py [--seeds 5] [--out out/chatter]`` (about 10 s). For every cell
of Tables 6 and 9 (44 and 68 N, 0.1 and 0.2 Hz), MPC-servo with the fixed predictor that
``tapmuscle paper`` identifies runs with the paper's Eq. (5) (``hysteresis_notch=False``) and with
the notch (the default), noise seeds 0..N-1. Printed per cell, means over the seeds (worst seed in
brackets): Eq. (21); the command's total variation in the Eq. (21) window above that of a smooth
command of the same range (2 x range per cycle); local extrema of ``u`` per cycle (a smooth command
has 2); the same for AMPC-servo with its defaults (the start-up mode, which turns the notch on) as a
reference. Stored: ``chatter.png``, one
cycle of ``u`` and of the cancelled ``H`` at 44 N, 0.2 Hz, seed 0.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from fmu_controller.displacement_control import P0_TABLE5, P0_TABLE8, ControllerSettings, DisplacementController
from fmu_controller.reference import SineReference
from fmu_plant import Plant
from tapmuscle.closed_loop import EQ21_WINDOW, command_tv_excess, eq21_error_mm, run_closed_loop
from tapmuscle.paper.reproduce import preliminary_theta
from tapmuscle.plots.figures import new_figure, save_figure

CELLS = [(44.0, 0.1), (44.0, 0.2), (68.0, 0.1), (68.0, 0.2)]


def run(method: str, notch: bool | None, load: float, f: float, seed: int, theta0: np.ndarray) -> dict:
    plant = Plant(seed=seed)
    plant.update(load_n=load)
    cs = ControllerSettings(method=method, p0=P0_TABLE8 if f == 0.2 else P0_TABLE5, hysteresis_notch=notch)
    return run_closed_loop(plant, DisplacementController(cs, theta0), SineReference(frequency_hz=f), duration_s=45.0, watch=False)


def figures(r: dict, f: float) -> tuple[float, float, float]:
    """Eq. (21) [mm], total-variation excess [%], extrema of u per cycle, in the Eq. (21) window."""
    k0, k1 = EQ21_WINDOW
    u = r["u_v"][k0:k1 + 1]
    cycles = (k1 - k0) * 0.1 * f
    tv = 100.0 * command_tv_excess(r["u_v"], f)
    extrema = np.count_nonzero(np.diff(np.sign(np.diff(u)))) / cycles
    return eq21_error_mm(r["r_mm"], r["l_mm"]), tv, extrema


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="noise seeds 0..N-1 (default 5)")
    parser.add_argument("--out", type=Path, default=Path("out/chatter"), help="folder of chatter.png")
    args = parser.parse_args(argv)
    theta0 = preliminary_theta(0, refine_hz=0.05)
    print(f"{'cell':<14} {'variant':<22} {'Eq. (21) [mm]':>16} {'TV above smooth [%]':>22} {'extrema/cycle':>16}")
    for load, f in CELLS:
        for label, method, notch in (("MPC-servo, Eq. (5)", "mpc_servo", False),
                                     ("MPC-servo, notch", "mpc_servo", None),
                                     ("AMPC-servo (default)", "ampc_servo", None)):
            fig = np.array([figures(run(method, notch, load, f, s, theta0), f) for s in range(args.seeds)])
            worst = fig.max(axis=0)
            print(f"{f'{load:.0f} N {f:g} Hz':<14} {label:<22} {fig[:, 0].mean():9.3f} ({worst[0]:.3f}) "
                  f"{fig[:, 1].mean():14.0f} ({worst[1]:4.0f}) {fig[:, 2].mean():10.1f} ({worst[2]:4.1f})")
    fig, ax = new_figure(2, 1, figsize=(9, 6), sharex=True)
    for label, notch, colour in (("Eq. (5): cancels H(k)", False, "tab:red"),
                                 ("notch: (1, 3, 4, 3, 1)/12 mean of H(k-2..k+2|k)", None, "tab:blue")):
        r = run("mpc_servo", notch, 44.0, 0.2, 0, theta0)
        k = (r["t_s"] >= 30.0) & (r["t_s"] <= 35.0)
        ax[0].step(r["t_s"][k], r["u_v"][k], where="post", color=colour, label=label)
        ax[1].plot(r["t_s"][k], r["h_mm"][k], ".-", color=colour, label=label)
    ax2 = ax[0].twinx()
    ax2.plot(r["t_s"][k], r["r_mm"][k], "k:", lw=1)
    ax2.set_ylabel("r [mm] (dotted)")
    ax[0].set_ylabel("u [V]")
    ax[0].set_title("MPC-servo, 44 N, 0.2 Hz, one cycle (seed 0)")
    ax[1].set_ylabel("cancelled H [mm]")
    ax[1].set_xlabel("t [s]")
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8, loc="upper right")
    png = save_figure(fig, args.out / "chatter.png")
    print(f"\nwrote {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
