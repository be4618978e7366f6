"""Matplotlib (Agg) figures of a sweep's results (``tapmuscle sweep``): Eq. (21) error per method and
over the swept fields. Input: the rows of ``results.csv`` (strings, as read by :mod:`csv`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from fmu_controller.methods import METHODS

from tapmuscle.plots.figures import new_figure, save_figure

__all__ = ["plot_mae_by_method", "plot_mae_map"]

_LABELS = {"load_n": "load [N]", "frequency_hz": "reference frequency [Hz]", "supply_mpa": "supply pressure [MPa]"}


def _label(name: str) -> str:
    """Axis or panel label of a column: its unit for the derived columns, the FMU variable name for a
    swept FMU parameter (``controller.parameters.box_lower.a1`` -> ``controller box_lower.a1``)."""
    for prefix in ("controller", "plant"):
        if name.startswith(f"{prefix}.parameters."):
            return f"{prefix} {name[len(prefix) + len('.parameters.'):]}"
    return _LABELS.get(name, name)


def _methods(rows: Sequence[Mapping[str, str]]) -> list[str]:
    present = {row["method"] for row in rows}
    return [m for m in METHODS if m in present] + sorted(present - set(METHODS))


def _ok(rows: Sequence[Mapping[str, str]]) -> list[Mapping[str, str]]:
    return [row for row in rows if row["status"] == "ok" and row.get("mae_mm", "") != ""]


def _norm(values: np.ndarray):
    from matplotlib.colors import LogNorm, Normalize

    lo, hi = float(np.min(values)), float(np.max(values))
    return LogNorm(lo, hi) if lo > 0 and hi / lo > 10 else Normalize(lo, hi if hi > lo else lo + 1e-9)


def _log_ticks(axis) -> None:
    """Ticks at 1, 2 and 5 times the powers of ten, as plain numbers, on a log axis (only 0.1 and 1
    were labelled, so 0.09 and 0.18 could not be read)."""
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

    axis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FormatStrFormatter("%g"))
    axis.set_minor_formatter(NullFormatter())


def plot_mae_by_method(rows: Sequence[Mapping[str, str]], path: str | os.PathLike, *, title: str = "",
                       pooled: Sequence[str] = ()) -> Path | None:
    """Box plot and points of ``mae_mm`` per method (runs that finished); None if there are none.
    ``pooled``: the columns that vary among the runs of a box, named in the title (a box of two
    loads has a median no run has).

    Parameters
    ----------
    rows : sequence of mapping of str to str
        The sweep's ``results.csv`` rows.
    path : str or os.PathLike
        The figure to write.
    title : str, optional
        The figure's title.
    pooled : sequence of str, optional
        The columns whose varying values a box pools, named in the title.
    """
    ok = _ok(rows)
    if not ok:
        return None
    varying = [name for name in pooled if len({row.get(name, "") for row in ok}) > 1]
    if varying:
        title = f"{title}\n(each box pools every {', '.join(_label(n) for n in varying)})".strip()
    methods = _methods(ok)
    data = [np.array([float(r["mae_mm"]) for r in ok if r["method"] == m]) for m in methods]
    fig, ax = new_figure(figsize=(1.8 + 1.6 * len(methods), 4.5))
    ax.boxplot(data, showfliers=False, widths=0.5)
    rng = np.random.default_rng(0)  # fixed jitter: the same figure for the same results
    for i, values in enumerate(data, start=1):
        ax.scatter(i + rng.uniform(-0.15, 0.15, len(values)), values, s=10, alpha=0.6, color="tab:blue", zorder=3)
    ax.set_xticks(range(1, len(methods) + 1), [f"{m}\n(n={len(v)})" for m, v in zip(methods, data)])
    every = np.concatenate(data)
    log = every.min() > 0 and every.max() / every.min() > 20
    if log:
        ax.set_yscale("log")
        _log_ticks(ax.yaxis)
    ax.set_ylabel("Eq. (21) error [mm]" + (", log scale" if log else ""))
    ax.grid(True, axis="y", alpha=0.3)
    ax.set_title(title)
    return save_figure(fig, path)


def _numeric_axes(rows: Sequence[Mapping[str, str]], candidates: Sequence[str]) -> list[tuple[str, np.ndarray]]:
    """Every candidate column that is numeric and varies, in ``candidates`` order."""
    axes = []
    for name in candidates:
        try:
            values = np.array([float(row[name]) for row in rows])
        except (KeyError, ValueError):
            continue
        if len(np.unique(values)) > 1 and name not in (a for a, _ in axes):
            axes.append((name, values))
    return axes


#: At most this many rows of panels, one per combination of the fields beyond the two map axes.
_MAX_FACET_ROWS = 6


def plot_mae_map(rows: Sequence[Mapping[str, str]], candidates: Sequence[str], path: str | os.PathLike, *,
                 title: str = "") -> Path | None:
    """``mae_mm`` over the first two varying numeric ``candidates`` (columns), one panel per method.

    Both fields with at most 12 values each (a grid): a heat map of the mean over the runs that share
    a cell (e.g. seeds), with the numbers; otherwise points coloured by the error (a Monte-Carlo
    sample). One varying field: the error against it. Further varying fields of a grid get a row of
    panels per combination of their values (at most ``_MAX_FACET_ROWS``), so no cell averages over
    them; beyond that, or off a grid, the title names the fields the cells average over (the points
    do not tell apart). None (nothing written) if no candidate varies.

    Parameters
    ----------
    rows : sequence of mapping of str to str
        The sweep's ``results.csv`` rows.
    candidates : sequence of str
        Columns the error may be drawn over: the first two that are numeric and vary are used.
    path : str or os.PathLike
        The figure to write.
    title : str, optional
        The figure's title.
    """
    from matplotlib.colors import LogNorm

    ok = _ok(rows)
    axes = _numeric_axes(ok, candidates) if ok else []
    if not axes:
        return None
    methods = _methods(ok)
    mae = np.array([float(r["mae_mm"]) for r in ok])
    method = np.array([r["method"] for r in ok])
    (xname, x), (yname, y) = axes[0], axes[1] if len(axes) > 1 else (None, None)
    grid = y is not None and len(np.unique(x)) <= 12 and len(np.unique(y)) <= 12
    extra = axes[2:]
    facets: list[tuple[str, np.ndarray]] = [("", np.ones(len(ok), dtype=bool))]
    if extra:
        combos = sorted({tuple(v[i] for _, v in extra) for i in range(len(ok))})
        if grid and len(combos) <= _MAX_FACET_ROWS:
            facets = [(", ".join(f"{_label(n)} = {c:g}" for (n, _), c in zip(extra, combo)),
                       np.all([v == c for (_, v), c in zip(extra, combo)], axis=0)) for combo in combos]
        else:
            others = ", ".join(_label(n) for n, _ in extra)
            title = f"{title} ({'mean over' if grid else 'points at all values of'} {others})".strip()
    fig, panels = new_figure(len(facets), len(methods), figsize=(0.8 + 3.6 * len(methods), 0.4 + 3.4 * len(facets)),
                             squeeze=False, sharex=True, sharey=True)
    # a Monte-Carlo sample's points: one colour scale per method, so that the dependence within each
    # shows (a shared scale left the servo methods one hue each); a grid's cells carry their numbers
    own_scale = y is not None and not grid
    norm = _norm(mae)
    image = None
    for r, (row, (label, in_facet)) in enumerate(zip(panels, facets)):
        for ax, m in zip(row, methods):
            sel = (method == m) & in_facet
            if y is None:
                ax.plot(x[sel], mae[sel], "o", ms=4, alpha=0.7)
                ax.set_ylabel("Eq. (21) error [mm]" if ax is row[0] else "")
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
                        else:  # a blank cell is no run there (or none that finished), not a small error
                            ax.text(j, i, "no run", ha="center", va="center", fontsize=7, color="0.4")
                image = ax.imshow(cell, origin="lower", aspect="auto", cmap="viridis", norm=norm)
                ax.set_xticks(range(len(xs)), [f"{v:g}" for v in xs])
                ax.set_yticks(range(len(ys)), [f"{v:g}" for v in ys])
            else:
                own = _norm(mae[sel]) if sel.any() else norm
                points = ax.scatter(x[sel], y[sel], c=mae[sel], cmap="viridis", norm=own, s=18)
                # every panel's bar labelled: the same colour is another error in each
                bar = fig.colorbar(points, ax=ax, label="Eq. (21) error [mm], this panel's scale")
                if isinstance(own, LogNorm):
                    _log_ticks(bar.ax.yaxis)
            ax.set_title(f"{m}\n{label}" if label else m, fontsize=9 if label else None)
            if r == len(facets) - 1:
                ax.set_xlabel(_label(xname))
            if y is not None and ax is row[0]:
                ax.set_ylabel(_label(yname))
    if own_scale:
        title = f"{title}\n(each panel its own colour scale)".strip()
    if image is not None and not own_scale:
        bar = fig.colorbar(image, ax=panels.ravel().tolist(), label="Eq. (21) error [mm]" + (" (mean)" if grid else ""))
        if isinstance(norm, LogNorm):
            _log_ticks(bar.ax.yaxis)
    fig.suptitle(title)
    return save_figure(fig, path)
