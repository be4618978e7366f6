"""tapmuscle.plots.sweep_figures: the map of a sweep's Eq. (21) errors over its swept fields."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import tapmuscle.plots.sweep_figures as sweep_figures


def _rows(extra_values=(1.0, 2.0)):
    """A 2 methods x 2 loads x 2 frequencies x extra grid, 2 seeds each; mae depends on every field."""
    rows = []
    for method, load, freq, extra, seed in itertools.product(("mpc_ucp", "ampc_ucp"), (44.0, 68.0), (0.1, 0.2),
                                                            extra_values, (0, 1)):
        mae = load / 100 + freq + 10 * extra + (0.5 if method == "ampc_ucp" else 0.0) + 0.01 * seed
        rows.append({"method": method, "status": "ok", "mae_mm": repr(mae), "load_n": repr(load),
                     "frequency_hz": repr(freq), "controller.parameters.box_lower.a2": repr(extra),
                     "seed": str(seed)})
    return rows


@pytest.fixture
def drawn(monkeypatch):
    """The figure plot_mae_map would save, kept for inspection."""
    figures = []
    monkeypatch.setattr(sweep_figures, "save_figure", lambda fig, path: figures.append(fig) or path)
    return figures


def _cells(ax) -> list[float]:
    return sorted(float(t.get_text()) for t in ax.texts)


def test_a_third_swept_field_gets_its_own_row_of_panels(drawn, tmp_path):
    rows = _rows()
    columns = ["load_n", "frequency_hz", "controller.parameters.box_lower.a2"]
    sweep_figures.plot_mae_map(rows, columns, tmp_path / "map.png", title="t")
    (fig,) = drawn
    panels = [ax for ax in fig.axes if ax.get_title()]  # the colour bar has no title
    assert len(panels) == 4  # 2 values of the third field x 2 methods
    for ax in panels:
        method, label = ax.get_title().split("\n")
        extra = float(label.split("=")[1])
        assert label.startswith("controller box_lower.a2")
        want = sorted(float(np.mean([float(r["mae_mm"]) for r in rows
                                     if r["method"] == method and float(r["load_n"]) == load
                                     and float(r["frequency_hz"]) == freq
                                     and float(r["controller.parameters.box_lower.a2"]) == extra]))
                      for load in (44.0, 68.0) for freq in (0.1, 0.2))
        # the cell's text is the mean to 2 decimals; averaging over the third field would be 5 mm off
        assert _cells(ax) == pytest.approx(want, abs=0.0051)
    assert fig._suptitle.get_text() == "t"


def test_too_many_combinations_are_averaged_and_the_title_says_over_what(drawn, tmp_path):
    extra = tuple(float(v) for v in range(sweep_figures._MAX_FACET_ROWS + 1))
    sweep_figures.plot_mae_map(_rows(extra), ["load_n", "frequency_hz", "controller.parameters.box_lower.a2"],
                               tmp_path / "map.png", title="t")
    (fig,) = drawn
    assert len([ax for ax in fig.axes if ax.get_title()]) == 2  # one row: a panel per method
    assert fig._suptitle.get_text() == "t (mean over controller box_lower.a2)"


def test_two_fields_draw_one_row(drawn, tmp_path):
    rows = [r for r in _rows() if r["controller.parameters.box_lower.a2"] == "1.0"]
    sweep_figures.plot_mae_map(rows, ["load_n", "frequency_hz", "controller.parameters.box_lower.a2"],
                               tmp_path / "map.png")
    (fig,) = drawn
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert [ax.get_title() for ax in panels] == ["mpc_ucp", "ampc_ucp"]
    assert panels[0].get_xlabel() == "load [N]" and panels[0].get_ylabel() == "reference frequency [Hz]"


def test_a_cell_without_a_run_says_so(drawn, tmp_path):
    """The paper's grid runs the UCP methods at 0.1 Hz only: their 0.2-Hz cells must not be blank, which
    reads as a colour; they say "no run"."""
    rows = [r for r in _rows() if r["controller.parameters.box_lower.a2"] == "1.0"
            and not (r["method"] == "mpc_ucp" and r["frequency_hz"] == "0.2")]
    sweep_figures.plot_mae_map(rows, ["load_n", "frequency_hz"], tmp_path / "map.png")
    (fig,) = drawn
    ucp, ampc = [ax for ax in fig.axes if ax.get_title()]
    assert [t.get_text() for t in ucp.texts].count("no run") == 2 and len(ucp.texts) == 4
    assert "no run" not in [t.get_text() for t in ampc.texts]


def test_a_monte_carlo_sample_with_a_third_field_says_so(drawn, tmp_path):
    rng = np.random.default_rng(1)
    rows = [{"method": "ampc_servo", "status": "ok", "mae_mm": repr(float(rng.uniform(0.1, 0.3))),
             "load_n": repr(float(rng.uniform(30, 90))), "supply_mpa": repr(float(rng.uniform(0.2, 0.3))),
             "plant.parameters.friction.rate_gain": repr(float(rng.uniform(0, 1)))} for _ in range(40)]
    sweep_figures.plot_mae_map(rows, ["load_n", "supply_mpa", "plant.parameters.friction.rate_gain"],
                               tmp_path / "map.png", title="mc")
    (fig,) = drawn
    assert fig._suptitle.get_text() == ("mc (points at all values of plant friction.rate_gain)\n"
                                        "(each panel its own colour scale)")
    (panel,) = [ax for ax in fig.axes if ax.get_title()]
    assert len(panel.collections[0].get_offsets()) == 40  # every run is a point


def test_a_monte_carlo_sample_has_a_colour_scale_per_method_and_readable_log_ticks(drawn, tmp_path):
    """One scale for all methods would draw the servo methods (0.15-0.27 mm beside 0.7-3 mm) one hue each;
    each method's points span their own scale, and a log scale labels 1, 2 and 5 of each decade
    (not only 0.1 and 1)."""
    rng = np.random.default_rng(2)
    rows = [{"method": m, "status": "ok", "mae_mm": repr(float(rng.uniform(lo, hi))),
             "load_n": repr(float(rng.uniform(30, 90))), "supply_mpa": repr(float(rng.uniform(0.2, 0.3)))}
            for m, lo, hi in (("mpc_ucp", 0.7, 3.0), ("ampc_servo", 0.07, 0.2)) for _ in range(30)]
    sweep_figures.plot_mae_map(rows, ["load_n", "supply_mpa"], tmp_path / "map.png")
    sweep_figures.plot_mae_by_method(rows, tmp_path / "box.png", title="t", pooled=["load_n", "supply_mpa"])
    (fig, box) = drawn
    for ax in (ax for ax in fig.axes if ax.get_title()):
        points = ax.collections[0]
        values = [float(r["mae_mm"]) for r in rows if r["method"] == ax.get_title()]
        assert (points.norm.vmin, points.norm.vmax) == (min(values), max(values))
    # the same colour is another error in each panel: every bar says so, and the title
    bars = [ax for ax in fig.axes if not ax.get_title()]
    assert len(bars) == 2 and all(b.get_ylabel() == "Eq. (21) error [mm], this panel's scale" for b in bars)
    assert fig._suptitle.get_text().endswith("(each panel its own colour scale)")
    (ax,) = box.axes
    assert ax.get_yscale() == "log" and ax.get_ylabel() == "Eq. (21) error [mm], log scale"
    labels = {t.get_text() for t in ax.get_yticklabels()}
    assert {"0.1", "0.2", "0.5", "1", "2"} <= labels, labels
    assert ax.get_title() == "t\n(each box pools every load [N], supply pressure [MPa])"
