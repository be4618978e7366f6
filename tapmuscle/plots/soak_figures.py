"""Matplotlib (Agg) figure of a soak run (``benchmarks/soak.py``): the Eq. (21) error per block, the
estimator's parameters and its covariance over hours. Input: plain arrays, so that the figure knows
nothing of the loop that made them."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from tapmuscle.plots.figures import new_figure, save_figure

__all__ = ["plot_soak"]


def plot_soak(runs: Mapping[str, Mapping[str, np.ndarray]], names: Sequence[str], path: str | os.PathLike, *,
              theta_lower: np.ndarray, theta_upper: np.ndarray) -> Path:
    """Four panels over the run's hours, one line per run (e.g. the paper's estimator and the
    long-run setting): Eq. (21) error per block with twice the first hour's value; the estimated input
    gain ``b1`` of Eq. (1) within its Table 2 box; the smallest eigenvalue of the scaled covariance;
    its condition number.

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
    fig, ax = new_figure(4, 1, figsize=(11, 12), sharex=True)
    for (label, r), colour in zip(runs.items(), ("tab:red", "tab:blue", "tab:green", "tab:orange")):
        h = np.asarray(r["block_t_s"]) / 3600.0
        ax[0].step(h, r["eq21_mm"], where="post", color=colour, label=f"{label}: per 10-min block")
        ax[0].axhline(2.0 * float(r["first_hour_mm"]), color=colour, ls=":", lw=1,
                      label=f"{label}: 2 x first hour ({2.0 * float(r['first_hour_mm']):.3f} mm)")
        hc = np.asarray(r["cov_t_s"]) / 3600.0
        ax[2].semilogy(hc, r["scaled_min_eig"], color=colour, label=label)
        ax[3].semilogy(hc, r["scaled_cond"], color=colour, label=label)
    i_b1 = list(names).index("b1")
    for (label, r), colour in zip(runs.items(), ("tab:red", "tab:blue", "tab:green", "tab:orange")):
        ax[1].plot(np.asarray(r["cov_t_s"]) / 3600.0, np.asarray(r["theta"])[:, i_b1], color=colour, lw=0.6,
                   label=f"{label}: b1 (sampled every minute)")
    for bound in (theta_lower[i_b1], theta_upper[i_b1]):
        if np.isfinite(bound):
            ax[1].axhline(float(bound), color="k", ls="--", lw=0.8)
    ax[0].set_ylabel("mean |r - l| [mm]")
    ax[0].set_title("Eq. (21) error per 10-minute block")
    ax[1].set_ylabel("b1 [mm/V]")
    ax[1].set_title("input gain b1 of Eq. (1) as estimated (dashed: the Table 2 box)")
    ax[2].set_ylabel("smallest eigenvalue")
    ax[2].set_title("scaled covariance D^-1/2 P D^-1/2: smallest eigenvalue (> 0: positive definite)")
    ax[3].set_ylabel("condition number")
    ax[3].set_title("scaled covariance: condition number")
    ax[3].set_xlabel("time [h]")
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    fig.set_layout_engine("tight")  # laid out as it is drawn: inside save_figure, with its warnings
    return save_figure(fig, path)
