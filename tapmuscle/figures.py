"""Matplotlib (Agg) figures of recordings, like the paper's Figs. 3 and 5.

Figures are written atomically (to a temporary file, then renamed) so that a failing plot never
leaves a truncated PNG behind.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["save_figure", "plot_recording"]


def save_figure(fig: "plt.Figure", path: str | os.PathLike, *, dpi: int = 120) -> Path:
    """Save ``fig`` as PNG to ``path`` atomically and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".png", dir=path.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        plt.close(fig)
    return path


def plot_recording(t_s: np.ndarray, u_v: np.ndarray, l_mm: np.ndarray, path: str | os.PathLike, *,
                   p_mpa: np.ndarray | None = None, title: str = "", settle_s: float = 0.0) -> Path:
    """Time traces of command, displacement (and pressure) and the (u, l) hysteresis loop.

    Left: paper Fig. 3 (valve input voltage and muscle displacement over time). Right: Fig. 5
    (displacement against command, the hysteresis loop), drawn for ``t >= settle_s``.
    """
    fig = plt.figure(figsize=(12, 6))
    gs = fig.add_gridspec(3 if p_mpa is not None else 2, 2, width_ratios=(1.6, 1))
    ax_u = fig.add_subplot(gs[0, 0])
    ax_u.plot(t_s, u_v, color="tab:blue", lw=1)
    ax_u.set_ylabel("valve input u [V]")
    ax_u.grid(alpha=0.3)
    ax_l = fig.add_subplot(gs[1, 0], sharex=ax_u)
    ax_l.plot(t_s, l_mm, color="tab:red", lw=1)
    ax_l.set_ylabel("displacement l [mm]")
    ax_l.grid(alpha=0.3)
    last = ax_l
    if p_mpa is not None:
        ax_p = fig.add_subplot(gs[2, 0], sharex=ax_u)
        ax_p.plot(t_s, p_mpa, color="tab:green", lw=1)
        ax_p.set_ylabel("pressure p [MPa]")
        ax_p.grid(alpha=0.3)
        last = ax_p
    last.set_xlabel("time t [s]")
    ax_h = fig.add_subplot(gs[:, 1])
    keep = np.asarray(t_s) >= settle_s
    # Pair u(k) with l(k+1): the command of row k acts on the following sample.
    ax_h.plot(np.asarray(u_v)[keep][:-1], np.asarray(l_mm)[keep][1:], color="tab:purple", lw=0.8)
    ax_h.set_xlabel("valve input u(k) [V]")
    ax_h.set_ylabel("displacement l(k+1) [mm]")
    ax_h.set_title(f"hysteresis loop (t >= {settle_s:g} s)", fontsize=10)
    ax_h.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)
