"""Matplotlib (Agg) figures of a sweep's results (``tapmuscle sweep``): Eq. (21) error per method and
over the swept fields. Input: the rows of ``results.csv`` (strings, as read by :mod:`csv`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from fmu_controller.displacement_control import METHODS

from .figures import plt, save_figure

__all__ = ["plot_mae_by_method", "plot_mae_map"]

_LABELS = {"load_n": "load [N]", "frequency_hz": "reference frequency [Hz]", "supply_mpa": "supply pressure [MPa]"}


def _methods(rows: Sequence[Mapping[str, str]]) -> list[str]:
    present = {row["method"] for row in rows}
    return [m for m in METHODS if m in present] + sorted(present - set(METHODS))


def _ok(rows: Sequence[Mapping[str, str]]) -> list[Mapping[str, str]]:
    return [row for row in rows if row["status"] == "ok" and row.get("mae_mm", "") != ""]


def _norm(values: np.ndarray):
    from matplotlib.colors import LogNorm, Normalize

    lo, hi = float(np.min(values)), float(np.max(values))
    return LogNorm(lo, hi) if lo > 0 and hi / lo > 10 else Normalize(lo, hi if hi > lo else lo + 1e-9)


def plot_mae_by_method(rows: Sequence[Mapping[str, str]], path: str | os.PathLike, *, title: str = "") -> Path | None:
    """Box plot and points of ``mae_mm`` per method (runs that finished); None if there are none."""
    ok = _ok(rows)
    if not ok:
        return None
    methods = _methods(ok)
    data = [np.array([float(r["mae_mm"]) for r in ok if r["method"] == m]) for m in methods]
    fig, ax = plt.subplots(figsize=(1.8 + 1.6 * len(methods), 4.5))
    ax.boxplot(data, showfliers=False, widths=0.5)
    rng = np.random.default_rng(0)  # fixed jitter: the same figure for the same results
    for i, values in enumerate(data, start=1):
        ax.scatter(i + rng.uniform(-0.15, 0.15, len(values)), values, s=10, alpha=0.6, color="tab:blue", zorder=3)
    ax.set_xticks(range(1, len(methods) + 1), [f"{m}\n(n={len(v)})" for m, v in zip(methods, data)])
    every = np.concatenate(data)
    if every.min() > 0 and every.max() / every.min() > 20:
        ax.set_yscale("log")
    ax.set_ylabel("Eq. (21) error [mm]")
    ax.grid(True, axis="y", alpha=0.3)
    ax.set_title(title)
    return save_figure(fig, path)


def _numeric_axes(rows: Sequence[Mapping[str, str]], candidates: Sequence[str]) -> list[tuple[str, np.ndarray]]:
    axes = []
    for name in candidates:
        try:
            values = np.array([float(row[name]) for row in rows])
        except (KeyError, ValueError):
            continue
        if len(np.unique(values)) > 1 and name not in (a for a, _ in axes):
            axes.append((name, values))
    return axes[:2]


def plot_mae_map(rows: Sequence[Mapping[str, str]], candidates: Sequence[str], path: str | os.PathLike, *,
                 title: str = "") -> Path | None:
    """``mae_mm`` over the first two varying numeric ``candidates`` (columns), one panel per method.

    Both fields with at most 12 values each (a grid): a heat map of the mean over the other fields
    (e.g. seeds), with the numbers; otherwise points coloured by the error (a Monte-Carlo sample). One
    varying field: the error against it. None (nothing written) if no candidate varies.
    """
    ok = _ok(rows)
    axes = _numeric_axes(ok, candidates) if ok else []
    if not axes:
        return None
    methods = _methods(ok)
    mae = np.array([float(r["mae_mm"]) for r in ok])
    method = np.array([r["method"] for r in ok])
    fig, panels = plt.subplots(1, len(methods), figsize=(0.8 + 3.6 * len(methods), 3.8), squeeze=False,
                               sharex=True, sharey=True)
    (xname, x), (yname, y) = axes[0], axes[1] if len(axes) > 1 else (None, None)
    norm = _norm(mae)
    grid = y is not None and len(np.unique(x)) <= 12 and len(np.unique(y)) <= 12
    image = None
    for ax, m in zip(panels[0], methods):
        sel = method == m
        if y is None:
            ax.plot(x[sel], mae[sel], "o", ms=4, alpha=0.7)
            ax.set_ylabel("Eq. (21) error [mm]" if ax is panels[0][0] else "")
        elif grid:
            xs, ys = np.unique(x), np.unique(y)
            cell = np.full((len(ys), len(xs)), np.nan)
            for i, yv in enumerate(ys):
                for j, xv in enumerate(xs):
                    hit = sel & (x == xv) & (y == yv)
                    if hit.any():
                        cell[i, j] = float(np.mean(mae[hit]))
                        ax.text(j, i, f"{cell[i, j]:.2f}", ha="center", va="center", fontsize=8,
                                color="white" if norm(cell[i, j]) < 0.5 else "black")
            image = ax.imshow(cell, origin="lower", aspect="auto", cmap="viridis", norm=norm)
            ax.set_xticks(range(len(xs)), [f"{v:g}" for v in xs])
            ax.set_yticks(range(len(ys)), [f"{v:g}" for v in ys])
        else:
            image = ax.scatter(x[sel], y[sel], c=mae[sel], cmap="viridis", norm=norm, s=18)
        ax.set_title(m)
        ax.set_xlabel(_LABELS.get(xname, xname))
        if y is not None and ax is panels[0][0]:
            ax.set_ylabel(_LABELS.get(yname, yname))
    if image is not None:
        fig.colorbar(image, ax=panels[0].tolist(), label="Eq. (21) error [mm]" + (" (mean)" if grid else ""))
    fig.suptitle(title)
    return save_figure(fig, path)
