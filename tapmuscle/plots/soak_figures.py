"""Matplotlib (Agg) figure of a soak run (``benchmarks/soak.py``): the Eq. (21) error per block, the
estimator's parameters and its covariance over hours. Input: plain arrays, so that the figure knows
nothing of the loop that made them."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from tapmuscle.plots.figures import plt, save_figure

__all__ = ["plot_soak"]


def plot_soak(runs: Mapping[str, Mapping[str, np.ndarray]], names: Sequence[str], path: str | os.PathLike, *,
              theta_lower: np.ndarray, theta_upper: np.ndarray) -> Path:
    """Four panels over the run's hours, one line per run (e.g. the paper's estimator and the
    long-run setting): Eq. (21) error per block with twice the first hour's value; the 15 parameters of
    Eq. (1) (one run, the last), each scaled to its range over the run or to its Table 2 box; the
    smallest eigenvalue of the scaled covariance; its condition number.

    Parameters
    ----------
    runs : mapping label -> arrays
        Per run: ``block_t_s``, ``eq21_mm`` (per block), ``first_hour_mm`` (scalar array),
        ``cov_t_s``, ``scaled_min_eig``, ``scaled_cond``, ``theta`` (n x 15).
    names : sequence of str
        The 15 parameter names of Eq. (1).
    path : path
        PNG to write (atomically).
    theta_lower, theta_upper : ndarray
        Table 2's box (+-inf where unbounded).
    """
    fig, ax = plt.subplots(4, 1, figsize=(11, 12), sharex=True)
    for (label, r), colour in zip(runs.items(), ("tab:red", "tab:blue", "tab:green", "tab:orange")):
        h = np.asarray(r["block_t_s"]) / 3600.0
        ax[0].step(h, r["eq21_mm"], where="post", color=colour, label=f"{label}: per 10-min block")
        ax[0].axhline(2.0 * float(r["first_hour_mm"]), color=colour, ls=":", lw=1,
                      label=f"{label}: 2 x first hour ({2.0 * float(r['first_hour_mm']):.3f} mm)")
        hc = np.asarray(r["cov_t_s"]) / 3600.0
        ax[2].semilogy(hc, r["scaled_min_eig"], color=colour, label=label)
        ax[3].semilogy(hc, r["scaled_cond"], color=colour, label=label)
    last_label, last = list(runs.items())[-1]
    th = np.asarray(last["theta"])
    hc = np.asarray(last["cov_t_s"]) / 3600.0
    cmap = plt.get_cmap("tab20")
    for i, name in enumerate(names):
        lo, hi = float(theta_lower[i]), float(theta_upper[i])
        if not (np.isfinite(lo) and np.isfinite(hi)):
            lo, hi = float(np.min(th[:, i])), float(np.max(th[:, i]))
        span = hi - lo if hi > lo else 1.0
        ax[1].plot(hc, (th[:, i] - lo) / span, color=cmap(i % 20), lw=0.8, label=name)
    ax[0].set_ylabel("mean |r - l| [mm]")
    ax[0].set_title("Eq. (21) error per 10-minute block")
    ax[1].set_ylabel("theta, scaled")
    ax[1].set_title(f"{last_label}: theta-hat (a1, a2, b1 scaled to the Table 2 box; the rest to their range)")
    ax[1].legend(ncol=8, fontsize=7, loc="upper center")
    ax[1].set_ylim(-0.1, 1.35)
    ax[2].set_ylabel("smallest eigenvalue")
    ax[2].set_title("scaled covariance D^-1/2 P D^-1/2: smallest eigenvalue (> 0: positive definite)")
    ax[3].set_ylabel("condition number")
    ax[3].set_title("scaled covariance: condition number")
    ax[3].set_xlabel("time [h]")
    for a in ax:
        a.grid(True, alpha=0.3)
    for a in (ax[0], ax[2], ax[3]):
        a.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
