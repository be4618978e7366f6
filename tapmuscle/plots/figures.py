"""Matplotlib figures of recordings, like the paper's Figs. 3 and 5.

The figures are made with matplotlib's object-oriented API (:class:`matplotlib.figure.Figure`), not
pyplot: a library must not switch its caller's backend or leave figures in pyplot's list, or a
notebook that calls tapmuscle stops showing its own plots. A ``Figure`` renders to PNG with Agg
whatever backend pyplot uses, and belongs to the thread that made it (a threaded sweep may draw
several at once).

Figures are written atomically (to a temporary file, then renamed) so that a failing plot never
leaves a truncated PNG behind.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import threading
import warnings
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from matplotlib import rc_context
from matplotlib.figure import Figure

from fmu_controller.hysteresis_model import THETA_UNITS
from fmu_plant.user_warning import warn_at_caller
from tapmuscle.io.atomic import atomic_path
from tapmuscle.tracking_metrics import EQ21_WINDOW_S

__all__ = ["MissingGlyphWarning", "new_figure", "save_figure", "plot_recording", "plot_parameter_convergence",
           "plot_input_delay_fits", "plot_model_vs_measured",
           "plot_loop_comparison", "plot_tracking", "plot_prediction_errors", "input_jumps", "loop_line", "JUMP_SHARE"]


def new_figure(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **subplots: Any) -> tuple[Figure, Any]:
    """A figure and its axes as ``pyplot.subplots`` makes them, but outside pyplot (module docstring).

    Parameters
    ----------
    nrows, ncols : int
        The grid of axes.
    figsize : (float, float)
        Width and height [inch].
    **subplots
        Passed to :meth:`matplotlib.figure.Figure.subplots` (``sharex``, ``squeeze``, ``gridspec_kw``).

    Returns
    -------
    fig : matplotlib.figure.Figure
    axes : Axes or ndarray of Axes
    """
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **subplots)


def _pdf_fonttype(fig: Figure) -> int:
    """42 (TrueType) where every character of the figure's text is in the default font, DejaVu Sans, a
    TrueType font; else 3, matplotlib's default: the fonts that draw the rest (a CJK font such as Noto
    CJK, a TrueType collection of CFF outlines) break a Type 42 PDF: matplotlib crashes on them or
    writes a PDF viewers cannot read."""
    from matplotlib import font_manager
    from matplotlib.text import Text

    text = "".join(t.get_text() for t in fig.findobj(Text))
    if text.isascii():
        return 42
    charmap = font_manager.get_font(font_manager.findfont("DejaVu Sans")).get_charmap()
    return 42 if all(ord(c) in charmap for c in set(text) if not c.isspace()) else 3


class MissingGlyphWarning(UserWarning):
    """A figure's text has characters that no font matplotlib uses draws (they show as boxes)."""


# matplotlib >= 3.9: "missing from font(s) DejaVu Sans."; 3.8: "missing from current font."
_GLYPH = re.compile(r"Glyph (\d+) .*missing from (?:current )?font")

#: One figure saved at a time in a process: the warnings caught and matplotlib's settings changed
#: while one is saved are the process's, and two threads saving at once would each restore the
#: other's (every later warning of the process lost, the fonts' settings left changed).
_SAVING = threading.Lock()


def save_figure(fig: Figure, path: str | os.PathLike, *, dpi: int = 120) -> Path:
    """Save ``fig`` to ``path`` atomically, in the format its suffix names (``.pdf``, ``.svg``, ...;
    PNG for ``.png``, no suffix, or one that is no figure format: ``tracking_0.1Hz``); a figure that
    pyplot made is closed there too. A PDF's (and PostScript's) fonts are embedded as TrueType, an
    SVG's text stays text (its font named, not drawn as paths).

    Characters of its text that the font lacks (a scenario named in Chinese or Japanese, with no CJK
    font installed) are said once, as one :class:`MissingGlyphWarning` naming them, instead of
    matplotlib's warning per character and drawing pass. Figures saved from several threads are
    saved one at a time.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or os.PathLike
        The file to write.
    dpi : int, optional
        Resolution of a raster format [dots per inch]; default 120.
    """
    path = Path(path)
    try:
        fmt = path.suffix[1:].lower()
        fmt = fmt if fmt in fig.canvas.get_supported_filetypes() else "png"
        with _SAVING, warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            # TrueType fonts in a PDF (matplotlib's Type 3 default is refused by IEEE's and other
            # publishers' checks) and text kept as text in an SVG (editable, searchable); the same
            # bytes for the same figure (no date, fixed ids), as the PNGs are
            fonttype = _pdf_fonttype(fig)
            settings = {"pdf.fonttype": fonttype, "ps.fonttype": fonttype, "svg.fonttype": "none",
                        "svg.hashsalt": "tapmuscle"}
            metadata = {"pdf": {"CreationDate": None}, "svg": {"Date": None}}.get(fmt)
            with atomic_path(path, suffix=f".{fmt}") as tmp, rc_context(settings):
                fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=fmt, metadata=metadata)
        missing = []
        for w in caught:
            glyph = _GLYPH.match(str(w.message))
            if glyph is None:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
            elif chr(int(glyph.group(1))) not in missing:
                missing.append(chr(int(glyph.group(1))))
        if missing:
            shown = ("kept as text, which a viewer without a font that has them shows as boxes" if fmt == "svg"
                     else "shown as boxes")
            warn_at_caller(f"{path.name}: no installed font draws {''.join(missing)!r}, {shown} (install a font "
                           "that has them, e.g. Debian's fonts-noto-cjk)", MissingGlyphWarning)
    finally:
        if getattr(fig.canvas, "manager", None) is not None:
            # only pyplot gives a figure a manager, so pyplot is already loaded here
            import matplotlib.pyplot as plt

            plt.close(fig)
    return path


def _until_divergence(y: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, int | None]:
    """``y`` with everything after it first leaves ``[lo, hi]`` blanked (NaN), and that index."""
    y = np.asarray(y, dtype=float).copy()
    out = np.nonzero((y < lo) | (y > hi))[0]
    if out.size == 0:
        return y, None
    y[out[0] + 1:] = np.nan
    return y, int(out[0])


def plot_recording(t_s: np.ndarray, u_v: np.ndarray, l_mm: np.ndarray, path: str | os.PathLike, *,
                   p_mpa: np.ndarray | None = None, title: str = "", settle_s: float = 0.0) -> Path:
    """Time traces of command, displacement (and pressure) and the (u, l) hysteresis loop.

    Left: paper Fig. 3 (valve input voltage and muscle displacement over time). Right: Fig. 5
    (displacement against command, the hysteresis loop), drawn for ``t >= settle_s``.

    Parameters
    ----------
    t_s : ndarray
        Time [s].
    u_v : ndarray
        Valve command [V].
    l_mm : ndarray
        Displacement [mm].
    path : str or os.PathLike
        The figure to write (:func:`save_figure`).
    p_mpa : ndarray, optional
        Muscle pressure [MPa], drawn in a third panel when given.
    title : str, optional
        The figure's title.
    settle_s : float, optional
        Start of the loop drawn on the right [s]; default 0.
    """
    fig = Figure(figsize=(12, 6))
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


def plot_parameter_convergence(t_s: np.ndarray, history: np.ndarray, names: tuple[str, ...],
                               path: str | os.PathLike, *, constraint_start_s: float | None = None,
                               title: str = "", events: Sequence[tuple[float, str]] = (),
                               bounds: Mapping[str, tuple[float, float]] | None = None) -> Path:
    """Estimated parameters over time, one panel each (parameter convergence, section 2.4), each
    titled with its unit where it is one of Eq. (1)'s (:data:`~fmu_controller.hysteresis_model.THETA_UNITS`);
    ``events`` (times [s] and their text, :func:`plot_tracking`) as lines in every panel, named in the
    title; ``bounds``: the constraint region C of Algorithm 1 by name (lower, upper), each finite
    bound dotted in its panel (an estimate pinned on one shows it).

    Parameters
    ----------
    t_s : ndarray
        Time [s].
    history : ndarray
        The estimates at each time, one column per parameter (``len(t_s) x len(names)``).
    names : tuple of str
        The parameters' names, in column order.
    path : str or os.PathLike
        The figure to write (:func:`save_figure`).
    constraint_start_s : float, optional
        When the constraint starts [s], dashed in every panel; None: not drawn.
    title : str, optional
        The figure's title; default ``"parameter convergence"``.
    events : sequence of (float, str), optional
        Times [s] and their text, drawn as lines.
    bounds : mapping of str to (float, float), optional
        The constraint region C of Algorithm 1 by name, ``(lower, upper)``.
    """
    n = len(names)
    cols = 5 if n > 12 else 4
    rows = -(-n // cols)
    fig, axes = new_figure(rows, cols, figsize=(3.2 * cols, 2.1 * rows), sharex=True, squeeze=False)
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.set_visible(False)
            continue
        # Scale to the settled part: the first seconds of RLS swing wildly and would hide the rest.
        settled = history[len(t_s) // 20:, i]
        lo, hi = float(np.min(settled)), float(np.max(settled))
        # a tiny or huge parameter (xi31 ~ 1e-5) in units of a power of ten named in the title:
        # matplotlib's own "1e-5" above the axes ran into the title
        size = max(abs(lo), abs(hi))
        power = int(np.floor(np.log10(size))) if size > 0 else 0
        power = power if not -3 <= power <= 3 else 0
        scale = 10.0 ** -power
        ax.plot(t_s, history[:, i] * scale, lw=1)
        lo, hi = lo * scale, hi * scale
        pad = 0.15 * (hi - lo) + 1e-12 + 0.02 * max(abs(lo), abs(hi))
        ax.set_ylim(lo - pad, hi + pad)
        for bound in (bounds or {}).get(names[i], ()):
            if math.isfinite(bound) and lo - pad <= bound * scale <= hi + pad:  # one far off would squash the rest
                ax.axhline(bound * scale, color="0.3", ls=":", lw=0.9)
        ax.ticklabel_format(axis="y", useOffset=False)
        unit = THETA_UNITS.get(names[i], "1").replace("^2", "\u00b2")
        shown = [f"x 1e{power}"] * (power != 0) + [unit] * (unit != "1")
        ax.set_title(f"{names[i]} [{' '.join(shown)}]" if shown else names[i], fontsize=9)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        if constraint_start_s is not None and constraint_start_s < t_s[-1]:
            ax.axvline(constraint_start_s, color="grey", ls="--", lw=0.8)
        _mark_events([ax], events, None)  # named in the title: 15 panels have no room for the text
        if i >= n - cols:
            ax.set_xlabel("t [s]", fontsize=8)
            ax.tick_params(labelbottom=True)  # the last panel of its column: shared x, its own tick labels
    dashed = (" (dashed: the constraint starts)" if constraint_start_s is not None and constraint_start_s < t_s[-1]
              else "")
    marked = ("; grey lines: " + ", ".join(f"{text} at {t:g} s" for t, text in events)) if events else ""
    dotted = "; dotted: the box's bounds" if any(math.isfinite(b) for pair in (bounds or {}).values()
                                                   for b in pair) else ""
    fig.suptitle((title or "parameter convergence") + dashed + dotted + marked)
    fig.set_layout_engine("tight")  # laid out as it is drawn: inside save_figure, with its warnings
    return save_figure(fig, path)


def plot_model_vs_measured(t_s: np.ndarray, u_v: np.ndarray, l_mm: np.ndarray, models: dict[str, np.ndarray],
                           path: str | os.PathLike, *, title: str = "") -> Path:
    """Measured displacement against free-run model outputs (paper Fig. 4) and their errors.

    Parameters
    ----------
    t_s : ndarray
        Time [s].
    u_v : ndarray
        Valve command [V] (not drawn).
    l_mm : ndarray
        Measured displacement [mm].
    models : dict of str to ndarray
        Label -> free-run model output [mm], on the same samples (up to three are drawn).
    path : str or os.PathLike
        The figure to write (:func:`save_figure`).
    title : str, optional
        The figure's title.
    """
    fig, (ax, ax_e) = new_figure(2, 1, figsize=(11, 6), sharex=True, gridspec_kw={"height_ratios": (2, 1)})
    ax.plot(t_s, l_mm, color="black", lw=1.2, label="measured")
    lo, hi = float(np.min(l_mm)), float(np.max(l_mm))
    pad = 0.25 * (hi - lo) + 1e-9
    worst = 0.0
    for (label, y), color in zip(models.items(), ("tab:red", "tab:blue", "tab:green")):
        # A diverged model is drawn until it leaves the chart, then marked, so it cannot hide the data.
        y, gone = _until_divergence(y, lo - pad, hi + pad)
        if gone is not None:
            label = f"{label}, leaves the chart at t = {t_s[gone]:.1f} s"
            ax.axvline(t_s[gone], color=color, lw=0.8, ls=":")
        ax.plot(t_s, y, color=color, lw=1, ls="--", label=label)
        ax_e.plot(t_s, l_mm - y, color=color, lw=0.8, label=label)
        error = np.abs(l_mm - y)
        worst = max(worst, float(np.max(error[np.isfinite(error)], initial=0.0)))
    ax.set_ylim(lo - pad, hi + pad)
    # scaled to the errors (at the data's scale a 2-mm residual drew flat), at most the data's
    ax_e.set_ylim(-min(1.15 * worst, pad) - 1e-9, min(1.15 * worst, pad) + 1e-9)
    ax.set_ylabel("displacement l [mm]")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    ax_e.set_ylabel("measured - model [mm]")
    ax_e.set_xlabel("time t [s]")
    ax_e.grid(alpha=0.3)
    fig.suptitle(title or "free-run model output against measurement (cf. paper Fig. 4)")
    return save_figure(fig, path)


def plot_input_delay_fits(fits_percent: list[float] | tuple[float, ...], chosen: int, ts_s: float,
                          path: str | os.PathLike, *, title: str = "") -> Path:
    """The 1-step fit [%] of Eq. (1) identified under each input delay ``D`` [samples], the chosen one
    marked (``tapmuscle identify --input-delay-samples auto``).

    Parameters
    ----------
    fits_percent : sequence of float
        The 1-step fit [%] under each input delay ``D = 0, 1, ...`` [samples].
    chosen : int
        The chosen delay [samples].
    ts_s : float
        Sampling period [s], to label the delays in seconds.
    path : str or os.PathLike
        The figure to write (:func:`save_figure`).
    title : str, optional
        The figure's title.
    """
    fig, ax = new_figure(figsize=(7, 4.5))
    d = np.arange(len(fits_percent))
    ax.plot(d, fits_percent, "o-", color="tab:blue", lw=1.2)
    ax.plot([chosen], [fits_percent[chosen]], "o", color="tab:red", ms=11, mfc="none", mew=2,
            label=f"chosen: D = {chosen} ({chosen * ts_s:g} s)")
    ax.set_xticks(d, [f"{k}\n{k * ts_s:g} s" for k in d])
    ax.set_xlabel("input delay D [samples] (time)")
    ax.set_ylabel("1-step fit on the record [%]")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=9)
    fig.suptitle(title or "1-step fit of Eq. (1) identified under each input delay")
    return save_figure(fig, path)


#: A command that moves by more than this share of its range in one sample jumps (steps, random
#: levels): its (u, l) samples joined by lines draw rectangles, not a loop, so they are drawn as points.
JUMP_SHARE = 0.1


def input_jumps(u_v: np.ndarray) -> bool:
    """Whether the command ``u_v`` [V] jumps (:data:`JUMP_SHARE`): its (u, l) plane is drawn as points.

    Parameters
    ----------
    u_v : ndarray
        Valve command [V].
    """
    u = np.asarray(u_v, dtype=float)
    u = u[np.isfinite(u)]
    span = float(np.ptp(u)) if u.size > 1 else 0.0
    return span > 0 and float(np.max(np.abs(np.diff(u)))) > JUMP_SHARE * span


def loop_line(jumps: bool, **style: Any) -> dict[str, Any]:
    """Matplotlib keywords for one curve of a (u, l) plane: ``style`` as a line, or, where the input
    :func:`input_jumps`, as small points of its colour (``lw``/``ls`` dropped).

    Parameters
    ----------
    jumps : bool
        Whether the input jumps (:func:`input_jumps`).
    **style
        Matplotlib line keywords (``color``, ``lw``, ``ls``, ``label``, ...).
    """
    if not jumps:
        return style
    points = {k: v for k, v in style.items() if k not in ("lw", "ls", "linewidth", "linestyle")}
    return {**points, "ls": "none", "marker": ".", "ms": 2.5}


def plot_loop_comparison(u_v: np.ndarray, l_mm: np.ndarray, models: dict[str, np.ndarray],
                         path: str | os.PathLike, *, skip: int = 0, title: str = "") -> Path:
    """Hysteresis loops (u, l) of the measurement and of models (paper Fig. 5); points where the input
    jumps (:func:`input_jumps`: steps or random levels draw no loop).

    Parameters
    ----------
    u_v : ndarray
        Valve command [V].
    l_mm : ndarray
        Measured displacement [mm].
    models : dict of str to ndarray
        Label -> model output [mm], on the same samples (up to three are drawn).
    path : str or os.PathLike
        The figure to write (:func:`save_figure`).
    skip : int, optional
        Samples left out at the start; default 0.
    title : str, optional
        The figure's title.
    """
    fig, ax = new_figure(figsize=(7, 6))
    u = np.asarray(u_v)[skip:-1]
    jumps = input_jumps(u)
    ax.plot(u, np.asarray(l_mm)[skip + 1:], **loop_line(jumps, color="black", lw=1.2, label="measured"))
    lo, hi = float(np.min(l_mm[skip:])), float(np.max(l_mm[skip:]))
    pad = 0.25 * (hi - lo) + 1e-9
    for (label, y), color in zip(models.items(), ("tab:red", "tab:blue", "tab:green")):
        y, gone = _until_divergence(np.asarray(y)[skip + 1:], lo - pad, hi + pad)
        if gone is not None:
            label = f"{label} (leaves the chart)"
        ax.plot(u, y, **loop_line(jumps, color=color, lw=1, ls="--", label=label, alpha=0.6 if jumps else 1.0))
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel("valve input u(k) [V]")
    ax.set_ylabel("displacement l(k+1) [mm]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, markerscale=4)
    default = ("(u, l) samples: model against measurement\n(the input jumps: points, not a loop; a sine draws "
               "Fig. 5's)" if jumps else
               "hysteresis loop: model against measurement (cf. paper Fig. 5)")
    ax.set_title(title or default, fontsize=10)
    return save_figure(fig, path)


#: One colour and line per method in every figure (a reader flipping from Fig. 10 to Fig. 18 reads a
#: colour as the same controller): the unique coincidence point in blues, the servo mechanism in reds,
#: the adaptive version the darker. Every method has its own dashes, so that each of the paper's
#: pairs (Figs. 8-19) also differs in its line where colour does not tell (printed in grey, where
#: navy and dark red are both dark; to a red-green colour-blind reader, who tells the reds apart only
#: by lightness): AMPC-servo solid, MPC-servo dashed, MPC-UCP dash-dotted, AMPC-UCP dash-dot-dotted.
#: The reference is dotted.
_METHOD_STYLE = {"mpc_ucp": ("tab:blue", "MPC, unique coincidence point", "-."),
                 "ampc_ucp": ("navy", "AMPC, unique coincidence point", (0, (6, 1.5, 1, 1.5, 1, 1.5))),
                 "mpc_servo": ("tab:orange", "MPC with servo mechanism", "--"),
                 "ampc_servo": ("darkred", "AMPC with servo mechanism", "-")}


#: Colours of runs that are not one of the four methods (a law of the user's own), none of theirs.
_OTHER_COLORS = ("tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:gray")


def _styles(names: Iterable[str]) -> list[tuple[str, str, Any]]:
    """Each run's colour, label and line style: a method's own, else the next of :data:`_OTHER_COLORS`,
    solid (matplotlib's C0, C1, ... are MPC-UCP's and MPC-servo's colours)."""
    others = itertools.cycle(_OTHER_COLORS)
    return [_METHOD_STYLE.get(name) or (next(others), name, "-") for name in names]


def _legend_above(ax: Any, ncol: int) -> None:
    """The legend in a row above the axes, where it covers no data (inside, it hid the peaks and
    troughs a reader compares)."""
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.01), ncol=ncol, fontsize=8, frameon=False,
              borderaxespad=0.0)


def _run_columns(name: str, cols: Mapping[str, Any], keys: Sequence[str]) -> dict[str, np.ndarray]:
    """A run's ``keys`` as 1-D float arrays of one length (lists, a notebook's columns), or a
    ValueError naming the run and the column; other columns as given."""
    missing = [k for k in keys if k not in cols]
    if missing:
        raise ValueError(f"run {name!r} has no {', '.join(missing)} (it needs {', '.join(keys)}; "
                         "tm.simulate_closed_loop returns them)")
    out = dict(cols)
    for k in keys:
        x = np.asarray(cols[k], dtype=float)
        if x.ndim != 1:
            raise ValueError(f"run {name!r}: column {k} must be one-dimensional (one value per sample), got shape "
                             f"{x.shape}")
        if len(x) != len(out[keys[0]]):
            raise ValueError(f"run {name!r}: column {k} has {len(x)} samples, {keys[0]} {len(out[keys[0]])}")
        out[k] = x
    return out


def _mark_events(axes: Sequence[Any], events: Sequence[tuple[float, str]], labelled: Any | None) -> None:
    """A thin grey line at each event's time [s] in every one of ``axes``, its text at the top of
    ``labelled`` (None: no text): a load step or a supply sag that explains the error after it."""
    for t, text in events:
        for ax in axes:
            ax.axvline(t, color="0.45", lw=0.8, zorder=1)
        if labelled is not None:
            labelled.annotate(text, xy=(t, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -3),
                              textcoords="offset points", ha="left", va="top", fontsize=7, color="0.25")


def plot_tracking(runs: dict[str, dict[str, np.ndarray]], path: str | os.PathLike, *, title: str = "",
                  window_s: tuple[float, float] | None = None, events: Sequence[tuple[float, str]] = ()) -> Path:
    """Reference and displacement of several runs, their tracking errors and commands (Figs. 8-18).

    Parameters
    ----------
    runs : dict
        Label (a method's name takes its colour) -> a run with ``t_s``, ``r_mm``, ``l_mm``, ``u_v``;
        runs may differ in length and period. The first run's reference is drawn.
    path : path
        The figure to write (atomically), in the format its suffix names (:func:`save_figure`: PDF,
        SVG, ...; otherwise PNG).
    title : str
        The figure's title.
    window_s : (float, float), optional
        The window shaded and the error axis scaled to [s]; default Eq. (21)'s 10.1..40.1 s.
    events : sequence of (float, str)
        Times [s] marked with a line in every panel and their text (``(20.0, "load 44 -> 68 N")``).
    """
    if not runs:
        raise ValueError("plot_tracking needs at least one run")
    runs = {name: _run_columns(name, cols, ("t_s", "r_mm", "l_mm", "u_v")) for name, cols in runs.items()}
    window_s = EQ21_WINDOW_S if window_s is None else window_s  # shaded
    fig, (ax, ax_e, ax_u) = new_figure(3, 1, figsize=(11, 8), sharex=True,
                                       gridspec_kw={"height_ratios": (2.2, 1, 1)})
    first = next(iter(runs.values()))
    # dotted: the fixed methods' lines are dashed
    ax.plot(first["t_s"], first["r_mm"], color="black", lw=1.4, ls=":", label="reference r")
    for (color, label, ls), cols in zip(_styles(runs), runs.values()):
        ax.plot(cols["t_s"], cols["l_mm"], color=color, lw=1, ls=ls, label=label)
        ax_e.plot(cols["t_s"], cols["r_mm"] - cols["l_mm"], color=color, lw=0.9, ls=ls, label=label)
        ax_u.plot(cols["t_s"], cols["u_v"], color=color, lw=0.9, ls=ls, label=label)
    for a in (ax, ax_e, ax_u):
        a.axvspan(*window_s, color="grey", alpha=0.07)
        a.grid(alpha=0.3)
    errors = []
    for c in runs.values():  # each run's own samples in the window (runs of other lengths or periods)
        t = np.asarray(c["t_s"])
        keep = (t >= window_s[0]) & (t <= window_s[1])
        e = np.abs(np.asarray(c["r_mm"]) - np.asarray(c["l_mm"]))[keep if keep.any() else slice(None)]
        errors.append(float(np.max(e)) if e.size else 0.0)
    emax = max(errors)
    if emax > 0 and np.isfinite(emax):
        ax_e.set_ylim(-1.2 * emax, 1.2 * emax)  # the start-up transient would hide the steady state
    u_all = np.concatenate([np.asarray(c["u_v"], dtype=float) for c in runs.values()])
    if u_all.size and (np.nanmin(u_all) < -1.0 or np.nanmax(u_all) > 11.0):
        # a law's unclipped commands would flatten every other trace: the valve's range in view
        ax_u.set_ylim(-1.0, 11.0)
        ax_u.text(0.99, 0.02, "commands beyond -1..11 V cut off in view", transform=ax_u.transAxes, ha="right",
                  va="bottom", fontsize=7, color="grey")
    _mark_events((ax, ax_e, ax_u), events, ax)
    ax.set_ylabel("displacement l [mm]")
    ax_e.set_ylabel("error r - l [mm]\n(scaled to the window)")
    ax_u.set_ylabel("valve input u [V]")
    ax_u.set_xlabel("time t [s] (shaded: Eq. (21) window)")
    _legend_above(ax, len(runs) + 1)
    fig.suptitle(title, y=0.995)
    return save_figure(fig, path)


def plot_prediction_errors(runs: dict[str, dict[str, np.ndarray]], path: str | os.PathLike, *,
                           title: str = "", window_s: tuple[float, float],
                           events: Sequence[tuple[float, str]] = ()) -> Path:
    """One-step prediction error ``l(k) - l(k|k-1)`` of each run's predictor over ``window_s`` [s]
    (Eq. (21)'s 10.1-40.1 s in Figs. 9-19), with ``events`` inside it marked as in :func:`plot_tracking`.

    Parameters
    ----------
    runs : dict of str to dict of str to ndarray
        Label -> a run's columns, with ``t_s`` [s] and ``pred_error_mm`` [mm].
    path : str or os.PathLike
        The figure to write (:func:`save_figure`).
    title : str, optional
        The figure's title.
    window_s : (float, float)
        The window drawn [s].
    events : sequence of (float, str), optional
        Times [s] and their text, marked as in :func:`plot_tracking`.
    """
    fig, ax = new_figure(figsize=(11, 4))
    _mark_events([ax], [(t, text) for t, text in events if window_s[0] <= t <= window_s[1]], ax)
    for (color, label, ls), cols in zip(_styles(runs), runs.values()):
        keep = (cols["t_s"] >= window_s[0]) & (cols["t_s"] <= window_s[1])
        err = cols["pred_error_mm"][keep]
        ax.plot(cols["t_s"][keep], err, color=color, lw=0.9, ls=ls,
                label=f"{label} (mean |e| {np.mean(np.abs(err)):.3f} mm)")
    ax.set_xlabel(f"time t [s] (the window {window_s[0]:g}-{window_s[1]:g} s)")
    ax.set_ylabel("prediction error l(k) - l(k|k-1) [mm]")
    ax.grid(alpha=0.3)
    _legend_above(ax, len(runs))
    fig.suptitle(title, y=0.995)
    return save_figure(fig, path)
