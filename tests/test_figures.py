"""The figures leave their caller's matplotlib alone (a notebook keeps its backend and its figures)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from matplotlib.image import imread

import tapmuscle as tm
from tapmuscle.plots.figures import plot_recording, plot_tracking

# A notebook's session as a fresh interpreter: its own backend (here pdf, a non-Agg backend that
# needs no display) and one figure of its own, then every tapmuscle module imported and figures drawn.
_SESSION = textwrap.dedent("""
    import importlib, json, pkgutil, sys
    import matplotlib
    matplotlib.use("pdf")
    import matplotlib.pyplot as plt
    mine = plt.figure()
    import numpy as np
    import tapmuscle
    for m in pkgutil.walk_packages(tapmuscle.__path__, "tapmuscle."):
        if not m.name.endswith("__main__"):
            importlib.import_module(m.name)
    from tapmuscle.plots.figures import plot_recording
    from tapmuscle.diagnosis.field_demo import confusion_figure
    t = np.arange(200) * 0.1
    plot_recording(t, 5 + 3 * np.sin(t), 40 + 20 * np.sin(t - 0.5), sys.argv[1] + "/rec.png", settle_s=5.0)
    rows, cols = ["none", "single: sensor_drift"], ["nothing", "sensor_drift"]
    conf = {"rows": rows, "columns": cols, "cases": {"none": 2, "single: sensor_drift": 3},
            "counts": {"none": {"nothing": 2, "sensor_drift": 0}, "single: sensor_drift": {"nothing": 1, "sensor_drift": 2}}}
    targets = {k: {"rate_percent": 50.0} for k in ("single_named", "single_named_alone", "pair_both_found",
                                                    "none_no_effect_claimed", "oov_unexplained")}
    confusion_figure({"confusion": conf, "targets": targets, "recordings": 5}, sys.argv[1] + "/confusion.png")
    print(json.dumps({"backend": matplotlib.get_backend(), "figures": plt.get_fignums(), "mine": mine.number}))
""")


def test_importing_and_drawing_keeps_the_callers_backend_and_figures(tmp_path):
    out = subprocess.run([sys.executable, "-c", _SESSION, str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    state = json.loads(out.stdout.strip().splitlines()[-1])
    assert state["backend"] == "pdf"
    assert state["figures"] == [state["mine"]]  # none of tapmuscle's left in pyplot, the user's kept
    for name in ("rec.png", "confusion.png"):
        image = imread(tmp_path / name)
        assert image.ndim == 3 and image.shape[0] > 300 and image.shape[1] > 300, name
        assert float(image[..., :3].std()) > 0.05, name  # something is drawn, not a blank canvas


def _runs(phase: float) -> dict[str, dict[str, np.ndarray]]:
    t = np.arange(0.0, 45.0, 0.1)
    r = 35 + 30 * np.sin(0.2 * np.pi * t)
    return {"ampc_servo": {"t_s": t, "r_mm": r, "l_mm": r - np.sin(t + phase), "u_v": 5 + 2 * np.cos(t + phase)}}


def test_figures_drawn_in_threads_at_once_are_those_drawn_one_by_one(tmp_path):
    # A threaded sweep (dask's local default) draws several figures at the same time: each must come
    # out as it does alone, pixel for pixel (same process, same Agg: a contract, not a tolerance).
    phases = [0.0, 0.7, 1.4, 2.1]
    for i, ph in enumerate(phases):
        plot_tracking(_runs(ph), tmp_path / f"serial{i}.png", title=f"run {i}", window_s=(10.1, 40.1))
        plot_recording(*(_runs(ph)["ampc_servo"][k] for k in ("t_s", "u_v", "l_mm")), tmp_path / f"serial_rec{i}.png")

    def draw(i: int) -> None:
        ph = phases[i]
        plot_tracking(_runs(ph), tmp_path / f"threaded{i}.png", title=f"run {i}", window_s=(10.1, 40.1))
        plot_recording(*(_runs(ph)["ampc_servo"][k] for k in ("t_s", "u_v", "l_mm")), tmp_path / f"threaded_rec{i}.png")

    with ThreadPoolExecutor(4) as pool:
        list(pool.map(draw, list(range(len(phases))) * 3))  # each three times, overlapping
    for i in range(len(phases)):
        for kind in ("", "_rec"):
            a, b = imread(tmp_path / f"serial{kind}{i}.png"), imread(tmp_path / f"threaded{kind}{i}.png")
            assert a.shape == b.shape and np.array_equal(a, b), f"{kind or 'tracking'} {i}"


def test_characters_no_font_draws_are_said_once(tmp_path):
    """A scenario named in Chinese with no CJK font installed: matplotlib warns per character and per
    drawing pass (four "Glyph ... missing from font(s) DejaVu Sans." for two characters, printed even
    under --quiet); save_figure says once which characters show as boxes. Other warnings pass through."""
    import warnings

    from matplotlib import font_manager

    from tapmuscle.plots.figures import MissingGlyphWarning, new_figure, save_figure

    font = font_manager.FontProperties(family="DejaVu Sans")
    if "模" in {chr(c) for c in font_manager.get_font(font_manager.findfont(font)).get_charmap()}:
        pytest.skip("the default font draws CJK characters here")
    fig, ax = new_figure(figsize=(3, 2))
    ax.set_title("模型 1 Müller")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        save_figure(fig, tmp_path / "a.png")
    assert [(w.category, str(w.message)) for w in caught] == [
        (MissingGlyphWarning, "a.png: no installed font draws '模型', shown as boxes (install a font that has them, "
                              "e.g. Debian's fonts-noto-cjk)")]
    assert (tmp_path / "a.png").stat().st_size > 1000
    # also for a figure laid out tightly (which draws it, and warns, before save_figure)
    from tapmuscle.plots.figures import plot_parameter_convergence

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        plot_parameter_convergence(np.arange(10) * 0.1, np.ones((10, 2)), ["a1", "b1"], tmp_path / "c.png",
                                   title="延迟")
    assert [w.category for w in caught] == [MissingGlyphWarning], [str(w.message) for w in caught]
    from matplotlib.artist import Artist

    class Warns(Artist):
        def draw(self, renderer):
            warnings.warn("drawn", RuntimeWarning)

    fig, ax = new_figure(figsize=(3, 2))
    fig.add_artist(Warns())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        save_figure(fig, tmp_path / "b.png")
    assert caught and {(w.category, str(w.message)) for w in caught} == {(RuntimeWarning, "drawn")}


def _drawn(monkeypatch):
    """The figures the plotting functions save, captured (their axes to look at)."""
    import tapmuscle.plots.figures as figures

    saved = []
    real = figures.save_figure
    monkeypatch.setattr(figures, "save_figure", lambda fig, path, **kw: (saved.append(fig), real(fig, path, **kw))[1])
    return saved


def test_a_method_has_one_colour_and_the_legend_covers_no_data(monkeypatch, tmp_path):
    """Each method has one colour in every figure (a reader compares Figs. 8-11 with Figs. 16-19 by it)
    and its own dashes, and the legends sit above the axes, where they hide none of the peaks and
    troughs a reader compares."""
    from tapmuscle.plots.figures import plot_prediction_errors

    saved = _drawn(monkeypatch)
    t = np.arange(451) * 0.1
    run = {"t_s": t, "r_mm": 35 + 30 * np.sin(t), "l_mm": 35 + 29 * np.sin(t), "u_v": 5 + np.sin(t),
           "pred_error_mm": 0.1 * np.sin(3 * t)}
    # Tables 6, 9 and 7's pairs (Figs. 8-11, 16-19, 12-15), and the two UCP methods
    pairs = (("mpc_servo", "mpc_ucp"), ("ampc_servo", "mpc_servo"), ("ampc_servo", "ampc_ucp"), ("ampc_ucp", "mpc_ucp"))
    colours: dict[str, set] = {}
    for i, pair in enumerate(pairs):
        plot_tracking({m: run for m in pair}, tmp_path / f"t{i}.png", window_s=(10.1, 40.1))
        plot_prediction_errors({m: run for m in pair}, tmp_path / f"p{i}.png", window_s=(10.1, 40.1))
    for fig in saved:
        ax = fig.axes[0]
        for line in ax.get_lines():
            if line.get_label().startswith(("MPC", "AMPC")):
                colours.setdefault(line.get_label().split(" (mean")[0], set()).add(line.get_color())
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        renderer = FigureCanvasAgg(fig).get_renderer()
        legend = ax.get_legend().get_window_extent(renderer)
        assert legend.y0 >= ax.get_window_extent(renderer).y1 - 1  # above the plotting area
    assert len(colours) == 4 and all(len(c) == 1 for c in colours.values()), colours
    assert len({next(iter(c)) for c in colours.values()}) == 4  # four colours for four methods
    # each pair differs in its dashes, and every method has its own: colours alone do not tell them
    # apart in grey print (dark red, navy) or to a red-green colour-blind reader (red, orange);
    # matplotlib names any dash pattern "--", so the patterns themselves are compared
    def dashes(line):
        return line._unscaled_dash_pattern

    patterns = {}
    for fig in saved[::2]:  # the tracking figures
        first, second = [line for line in fig.axes[0].get_lines() if line.get_label().startswith(("MPC", "AMPC"))]
        assert dashes(first) != dashes(second), (first.get_label(), second.get_label())
        (reference,) = [line for line in fig.axes[0].get_lines() if line.get_label() == "reference r"]
        assert dashes(reference) not in {dashes(first), dashes(second)}
        patterns.update({line.get_label(): dashes(line) for line in (first, second)})
    assert len(patterns) == 4 and len(set(patterns.values())) == 4, patterns


@pytest.mark.parametrize("signal", ["sine", "steps"])
def test_a_loop_is_a_line_under_a_sine_and_points_under_jumping_levels(monkeypatch, tmp_path, signal):
    """(u, l) of steps or random levels joined by lines would draw rectangles titled a hysteresis loop; a
    jumping input's samples are points, and the title says so."""
    from tapmuscle.plots.figures import input_jumps, plot_loop_comparison

    saved = _drawn(monkeypatch)
    t = np.arange(1200) * 0.1
    u = 5 + 3 * np.sin(0.2 * np.pi * t) if signal == "sine" else np.repeat([2.0, 7.0, 4.0, 9.0], 300)
    l = 10 * u + np.sin(t)
    assert input_jumps(u) == (signal == "steps")
    plot_loop_comparison(u, l, {"model": l + 0.1}, tmp_path / "loop.png")
    ax = saved[0].axes[0]
    styles = {(line.get_linestyle(), line.get_marker()) for line in ax.get_lines()}
    if signal == "steps":
        assert styles == {("None", ".")} and "points, not a loop" in ax.get_title()
    else:
        assert {ls for ls, _ in styles} == {"-", "--"} and "cf. paper Fig. 5" in ax.get_title()


def test_a_run_of_ones_own_takes_no_methods_colour(monkeypatch, tmp_path):
    """A run named otherwise (a user's own law beside the methods) takes a colour none of the four
    methods has, not matplotlib's C0, C1, ... (MPC-UCP's blue, MPC-servo's orange)."""
    saved = _drawn(monkeypatch)
    t = np.arange(451) * 0.1
    run = {"t_s": t, "r_mm": 35 + 30 * np.sin(t), "l_mm": 35 + 29 * np.sin(t), "u_v": 5 + np.sin(t)}
    plot_tracking({"pid": run, "pi": run, **{m: run for m in tm.METHODS}}, tmp_path / "t.png", window_s=(10.1, 40.1))
    from matplotlib.colors import to_hex

    lines = {line.get_label(): to_hex(line.get_color()) for line in saved[0].axes[0].get_lines()}
    ours, methods = {lines["pid"], lines["pi"]}, {c for label, c in lines.items() if label.startswith(("MPC", "AMPC"))}
    assert len(ours) == 2 and len(methods) == 4 and not ours & methods, lines


def test_runs_of_other_lengths_and_periods_plot_beside_each_other(monkeypatch, tmp_path):
    """A 0.05-s run and a 60-s run beside a 45-s one: each run's own samples scale the error axis (one
    run's time mask on another's samples is an IndexError); the window defaults to Eq. (21)'s; a law's
    commands of hundreds of volts leave the valve's range in view."""
    from tapmuscle.tracking_metrics import EQ21_WINDOW_S

    saved = _drawn(monkeypatch)

    def run(ts, duration, err, u_scale=1.0):
        t = np.arange(int(round(duration / ts)) + 1) * ts
        return {"t_s": t, "r_mm": 35 + 30 * np.sin(t), "l_mm": 35 + 30 * np.sin(t) - err * np.cos(t),
                "u_v": u_scale * (5 + np.sin(t))}

    plot_tracking({"ampc_servo": run(0.1, 45.0, 0.1), "fast": run(0.05, 45.0, 0.3),
                   "long": run(0.1, 60.0, 0.2, u_scale=300.0)}, tmp_path / "t.png")
    _, ax_e, ax_u = saved[0].axes[:3]
    assert ax_e.get_ylim() == pytest.approx((-1.2 * 0.3, 1.2 * 0.3), rel=1e-3)
    assert ax_u.get_ylim() == (-1.0, 11.0)
    shaded = [p for p in ax_e.patches]
    assert shaded and shaded[0].get_x() == pytest.approx(EQ21_WINDOW_S[0])
    with pytest.raises(ValueError, match="at least one run"):
        plot_tracking({}, tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()


def test_a_run_of_lists_is_drawn_and_a_run_it_cannot_draw_is_named(monkeypatch, tmp_path):
    """A notebook's run as lists must not meet 'list - list' (TypeError), a column vector an IndexError of a
    mask, a missing column a KeyError; lists draw as arrays, the others are named by run and column,
    before a figure is made."""
    import matplotlib.pyplot as plt

    saved = _drawn(monkeypatch)
    t = np.arange(451) * 0.1
    run = {"t_s": t, "r_mm": 35 + 30 * np.sin(t), "l_mm": 35 + 30 * np.sin(t) - 0.2, "u_v": 5 + np.sin(t)}
    plot_tracking({"mine": {k: list(v) for k, v in run.items()}}, tmp_path / "lists.png")
    plot_tracking({"mine": run}, tmp_path / "arrays.png")
    (lists_ax, *_), (arrays_ax, *_) = saved[0].axes, saved[1].axes
    assert np.array_equal(lists_ax.lines[1].get_ydata(), arrays_ax.lines[1].get_ydata())
    for bad, message in (({**run, "t_s": t[:, None]}, r"run 'mine': column t_s must be one-dimensional .* \(451, 1\)"),
                         ({**run, "u_v": run["u_v"][:400]}, r"run 'mine': column u_v has 400 samples, t_s 451"),
                         ({k: v for k, v in run.items() if k != "r_mm"}, r"run 'mine' has no r_mm")):
        with pytest.raises(ValueError, match=message):
            plot_tracking({"mine": bad}, tmp_path / "bad.png")
    assert len(saved) == 2 and plt.get_fignums() == [] and not (tmp_path / "bad.png").exists()


def test_the_model_error_panel_is_scaled_to_the_errors(monkeypatch, tmp_path):
    """identify's free-run figure must not draw a 2-mm residual on a +-22-mm axis (flat); the error panel is
    scaled to the largest error, and never beyond the data's scale."""
    from tapmuscle.plots.figures import plot_model_vs_measured

    saved = _drawn(monkeypatch)
    t = np.arange(600) * 0.1
    l = 40 + 40 * np.sin(0.2 * t)
    plot_model_vs_measured(t, 5 + np.sin(t), l, {"model": l + 2.0 * np.sin(t)}, tmp_path / "m.png")
    lo, hi = saved[0].axes[1].get_ylim()
    assert 2.0 < hi < 2.5 and lo == -hi
    plot_model_vs_measured(t, 5 + np.sin(t), l, {"diverging": l + np.exp(0.2 * t)}, tmp_path / "d.png")
    assert saved[1].axes[1].get_ylim()[1] <= 0.25 * 80 + 1e-6  # the data's range, as before


def test_the_missing_glyph_warning_is_recognised_in_every_supported_matplotlib_s_words():
    """matplotlib 3.8 (the lowest pyproject.toml allows) says "missing from current font.", 3.9 and
    later "missing from font(s) DejaVu Sans.": both are combined into one MissingGlyphWarning."""
    from tapmuscle.plots.figures import _GLYPH

    for text in ("Glyph 27169 (\\N{CJK UNIFIED IDEOGRAPH-6A21}) missing from current font.",
                 "Glyph 27169 (\\N{CJK UNIFIED IDEOGRAPH-6A21}) missing from font(s) DejaVu Sans."):
        assert _GLYPH.search(text).group(1) == "27169"


def test_a_figure_is_written_in_the_format_its_suffix_names(tmp_path):
    """.pdf and .svg paths get those formats; .png, no suffix and a suffix that is no figure format
    (a name with a frequency in it) get PNG."""
    from tapmuscle.plots.figures import new_figure, save_figure

    for name, magic in (("f.pdf", b"%PDF"), ("f.svg", b"<?xml"), ("f.png", b"\x89PNG"), ("f", b"\x89PNG"),
                        ("tracking_0.1Hz", b"\x89PNG")):
        fig, ax = new_figure(figsize=(3, 2))
        ax.plot([0, 1], [0, 1])
        ax.set_xlabel("time t [s]")
        path = save_figure(fig, tmp_path / name)
        assert path.read_bytes().startswith(magic), name
        if name == "f.pdf":  # fonts embedded as TrueType (Type 42): publishers' checks refuse Type 3
            data = path.read_bytes()
            assert b"/FontFile2" in data and b"/Type3" not in data
        if name == "f.svg":  # the text is text, not glyphs drawn as paths: an editor can change it
            text = path.read_text()
            assert ">time t [s]</text>" in text and "<use xlink:href=\"#DejaVuSans" not in text
        if name in ("f.pdf", "f.svg"):  # the same figure gives the same bytes (no date, fixed ids)
            again, ax = new_figure(figsize=(3, 2))
            ax.plot([0, 1], [0, 1])
            ax.set_xlabel("time t [s]")
            assert save_figure(again, tmp_path / f"again_{name}").read_bytes() == path.read_bytes()
    # text the default TrueType font lacks: drawn by fonts (a CJK collection of CFF outlines) that
    # break a Type 42 PDF, so that figure keeps matplotlib's Type 3
    fig, ax = new_figure(figsize=(3, 2))
    ax.set_title("\u65e5\u672c")
    with warnings.catch_warnings():  # without a CJK font installed, the missing glyphs are said
        warnings.simplefilter("ignore")
        data = save_figure(fig, tmp_path / "cjk.pdf").read_bytes()
    assert b"/Type3" in data and b"/FontFile2" not in data


def test_a_scenarios_load_and_supply_steps_are_marked_where_they_explain_the_error(monkeypatch, tmp_path):
    """``tapmuscle run``'s figures of scenarios/examples/load_step.toml show error spikes at 20 and
    30 s, which must not go without saying why: the steps are lines in every panel, named at the top."""
    from pathlib import Path

    from tapmuscle.cosim import load_scenario
    from tapmuscle.cosim.run import scenario_events
    from tapmuscle.plots.figures import plot_prediction_errors

    scenario = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "examples" / "load_step.toml")
    events = scenario_events(scenario)
    assert events == [(20.0, "load 44 -> 68 N"), (30.0, "supply 0.25 -> 0.22 MPa")]
    saved = _drawn(monkeypatch)
    t = np.arange(451) * 0.1
    run = {"t_s": t, "r_mm": 35 + 30 * np.sin(t), "l_mm": 35 + 29 * np.sin(t), "u_v": 5 + np.sin(t),
           "pred_error_mm": 0.1 * np.sin(3 * t)}
    plot_tracking({"ampc_servo": run}, tmp_path / "t.png", events=events)
    plot_prediction_errors({"ampc_servo": run}, tmp_path / "p.png", window_s=(25.0, 40.0), events=events)
    tracking, prediction = saved
    for ax in tracking.axes:
        marked = sorted(line.get_xdata()[0] for line in ax.get_lines() if line.get_label().startswith("_child"))
        assert marked == [20.0, 30.0]
    assert [a.get_text() for a in tracking.axes[0].texts] == ["load 44 -> 68 N", "supply 0.25 -> 0.22 MPa"]
    assert [a.get_text() for a in prediction.axes[0].texts] == ["supply 0.25 -> 0.22 MPa"]  # the window's only


def test_the_box_bounds_an_estimate_sits_on_are_dotted_in_its_panel(monkeypatch, tmp_path):
    """b1 pinned on Table 2's lower bound would look like a converged value; the bounds in view are dotted
    (one far from the estimate is left out: it would squash the panel's scale)."""
    from tapmuscle.plots.figures import plot_parameter_convergence

    saved = _drawn(monkeypatch)
    t = np.arange(400) * 0.1
    history = np.column_stack([np.full(400, 0.607) + np.where(t < 20, 0.3 * np.exp(-t / 5), 0.0),
                               np.linspace(-0.33, -0.30, 400)])
    plot_parameter_convergence(t, history, ("b1", "a2"), tmp_path / "c.png",
                               bounds={"b1": (0.607, 1.184), "a2": (-0.334, -0.278 + 5.0)})
    b1, a2 = saved[0].axes[:2]

    def dotted(ax):
        return sorted(round(line.get_ydata()[0], 6) for line in ax.get_lines() if line.get_linestyle() == ":")

    assert dotted(b1) == [0.607] and dotted(a2) == [-0.334]
    assert saved[0]._suptitle.get_text().endswith("dotted: the box's bounds")


def test_figures_saved_from_two_threads_leave_the_processs_warnings_and_settings_as_they_were(tmp_path):
    """A service saving figures from a thread pool: each save catches warnings and changes the fonts'
    settings for its figure only; saved at once, each would restore the other's state."""
    import threading

    import matplotlib
    from matplotlib.figure import Figure

    from tapmuscle.plots.figures import save_figure

    keys = ("pdf.fonttype", "ps.fonttype", "svg.fonttype", "svg.hashsalt")
    before = ({k: matplotlib.rcParams[k] for k in keys}, warnings.showwarning, list(warnings.filters))

    def save(name: str) -> None:
        for i in range(8):
            fig = Figure(figsize=(2, 1.5))
            fig.add_subplot().plot(np.arange(200.0) ** 0.5)
            save_figure(fig, tmp_path / f"{name}{i}.{('png', 'svg', 'pdf')[i % 3]}")

    threads = [threading.Thread(target=save, args=(n,)) for n in "ab"]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert ({k: matplotlib.rcParams[k] for k in keys}, warnings.showwarning, list(warnings.filters)) == before
    assert len(list(tmp_path.iterdir())) == 16
