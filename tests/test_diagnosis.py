"""Mismatch diagnosis (diagnosis/): concealed effects found from the CSV alone, clean recordings left
alone, windows located, 'unexplained' when no candidate fits, the CLI's files and errors."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from tapmuscle.diagnosis import CANDIDATES, diagnose
from tapmuscle.diagnosis.calibration import NOMINAL_PARAMETERS
from tapmuscle.diagnosis.diagnose import MATERIAL_FACTOR
from tapmuscle.diagnosis.candidates import _command_cuts, _edge_scan, _edge_search, _midway_edges, _tightest, candidate
from tapmuscle.diagnosis.demo import DEMO_MODEL, Case, run_case, record
from tapmuscle.diagnosis.residual_analysis import (autocorrelation_test, unstructured_reason, fit_percent, interleaved_split, iou,
                                         located_windows)
from tapmuscle.cli.main import main
from tapmuscle.provenance import software


# ------------------------------------------------------------------------------ residual analysis
def test_fit_percent_and_split():
    y = np.sin(np.linspace(0, 20, 500))
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0)
    train, test = interleaved_split(500, 0.1, 10.0)
    assert train.sum() + test.sum() == 500 and not np.any(train & test)
    assert train[:100].all() and test[100:200].all()


def test_whiteness_test_accepts_noise_and_rejects_structure():
    rng = np.random.default_rng(0)
    rejected = sum(autocorrelation_test(rng.standard_normal(1500)).p_value < 1e-3 for _ in range(50))
    assert rejected <= 2
    smooth = np.convolve(rng.standard_normal(1500), np.ones(10) / 10, mode="same")
    assert autocorrelation_test(smooth).p_value < 1e-6


def test_located_windows_finds_a_burst():
    rng = np.random.default_rng(1)
    e = 0.01 * rng.standard_normal(1500)
    e[600:900] += 0.5 * np.sin(np.arange(300) * 0.3)
    wins = located_windows(e, 0.1, noise_mm=0.01)
    assert iou(wins, [(60.0, 90.0)]) > 0.8


# ------------------------------------------------------------------------------ the diagnosis
@pytest.mark.parametrize("excitation,seed", [("sine", 11), ("steps", 12), ("ampc", 13)])
def test_clean_recordings_are_judged_noise(excitation, seed):
    cols = record(DEMO_MODEL, excitation, seed)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL)
    assert d.verdict == "no_significant_mismatch" and d.findings == []
    assert d.fit_after_percent == d.fit_before_percent > 99.5
    # why the calibration did not run, as the residual tests say it (white, or within the noise)
    assert d.to_json()["calibration"] == {"skipped": f"nothing to calibrate (the nominal plant's "
                                                     f"{unstructured_reason(d.tests_before)})"}


CONCEALED = [
    ("rate_dependent_hysteresis", {"friction.rate_gain": 0.6}, "sine"),
    ("valve_dead_zone", {"dead_zone.center_v": 4.6, "dead_zone.width_v": 0.8}, "steps"),
    ("valve_dead_zone", {"dead_zone.center_v": 6.38, "dead_zone.width_v": 0.47}, "sine"),
    ("transport_delay", {"delay.delay_s": 0.13}, "steps"),
    ("load_mismatch", {"load_mismatch.extra_n": -7.0}, "steps"),
    ("sensor_drift", {"sensor_drift.offset_mm": 0.3, "sensor_drift.rate_mm_per_min": -0.4}, "sine"),
    # an encoder zeroed elsewhere: a constant offset leaves a residual white about its mean
    ("sensor_drift", {"sensor_drift.offset_mm": 12.5}, "steps"),
    ("backlash", {"backlash.slack_mm": 0.8}, "ampc"),
]


@pytest.mark.slow
@pytest.mark.parametrize("effect,overrides,excitation", CONCEALED,
                         ids=[f"{c[0]}-{c[2]}" + ("-offset" if len(c[1]) == 1 and "offset" in str(c[1]) else "")
                              for c in CONCEALED])
def test_a_concealed_effect_is_named_fitted_and_improves_the_held_out_fit(tmp_path, effect, overrides, excitation):
    r = run_case(Case(effect, 1, excitation, 5, overrides), tmp_path)
    assert r["verdict"] == "mismatch"
    assert r["top_finding"] == effect, r
    assert r["cost_points"] > 0.3
    # the fit recovers (nearly) all the fit the concealed effect cost, on held-out blocks
    assert r["gain_points"] >= 0.8 * r["cost_points"], r
    if effect == "valve_dead_zone" and excitation == "steps":
        return  # with held commands only which levels fall in the band matters: its edges are not identifiable
    for key, value in overrides.items():
        assert r["fitted_parameters"][key] == pytest.approx(value, rel=0.15, abs=0.05), key


@pytest.mark.slow
def test_a_supply_sag_from_60_to_90_s_is_located(tmp_path):
    sag = {"supply_variation.sag_mpa": 0.03, "supply_variation.start_s": 60.0, "supply_variation.end_s": 90.0}
    r = run_case(Case("supply_pressure_variation", 1, "sine", 2, sag, (60.0, 91.0)), tmp_path)
    assert r["top_finding"] == "supply_pressure_variation"
    assert r["iou"] >= 0.5
    assert r["gain_points"] >= 3.0
    # 90-100 s is held out, so the training blocks allow any end from 90 to about 95 s: the fit's
    # recovery is a ramp across that stretch (the simplex alone would stop anywhere in it), the start,
    # in a training block, keeps about the model's 1-s fall
    fitted = r["fitted_parameters"]
    assert fitted["supply_variation.start_s"] == pytest.approx(60.0, abs=0.5)
    assert 1.0 <= fitted["supply_variation.ramp_s"] <= 2.0  # 1.0 here: no flat stretch at the start
    assert fitted["supply_variation.end_s"] == pytest.approx(90.0, abs=1.0)
    assert 3.0 <= fitted["supply_variation.recovery_ramp_s"] <= 8.0


def test_tightest_takes_the_nearest_point_within_tolerance():
    calls = []

    def cost(v):  # flat (a held-out block hides the edge) from 90 on, rising before
        calls.append(v)
        return 0.1 if v >= 90.0 else 0.1 + (90.0 - v) ** 2
    assert _tightest(cost, 60.0, 95.0, 0.2, 0.05) == pytest.approx(90.0, abs=0.35)
    assert len(calls) <= 12  # bisection
    assert _tightest(lambda v: 0.0, 60.0, 95.0, 0.2, 0.05) == 60.0


def test_edge_search_crosses_the_plateaus_of_a_sampled_command():
    """A cost that counts the samples of a sampled sine command on the wrong side of the band
    (piecewise constant in the edges, as the dead zone's): from a band 0.35 V off, the search ends with
    exactly the true samples inside."""
    u = np.round(5.0 + 3.0 * np.sin(2 * np.pi * 0.1 * 0.1 * np.arange(600)), 3)
    truth = (6.15, 6.61)
    inside = (u > truth[0]) & (u < truth[1])
    cuts = _command_cuts(u)

    def cost(x):
        a, b = x[0] - x[1] / 2, x[0] + x[1] / 2
        return float(np.sum(((u > a) & (u < b)) != inside))
    best, a, b = _edge_search(cost, 5.9 - 0.15, 5.9 + 0.15, (0.2, 0.1, 0.05, 0.02), cuts)
    assert best == 0.0
    assert np.array_equal((u > a) & (u < b), inside)


def _held_levels_band_cost(seed: int) -> tuple[np.ndarray, np.ndarray, tuple[float, float], object]:
    """Random held levels, and a staircase cost with a trap: a band holding part of the true one
    costs less than no band, but widening it one level at a time costs more before the rest of the
    band pays it back (the stall of a partly right band misplaces the muscle more than none)."""
    rng = np.random.default_rng(seed)
    u = np.round(rng.uniform(2.0, 8.0, 70), 3)
    truth = (5.35, 6.39)
    inside = (u > truth[0]) & (u < truth[1])
    cuts = _command_cuts(u)

    def cost(x):
        a, b = x[0] - x[1] / 2, x[0] + x[1] / 2
        held = (u > a) & (u < b)
        right, wrong = int(np.sum(held & inside)), int(np.sum(held & ~inside))
        # no band 10, the whole band 0; in between a valley at the band's top two levels
        part = 10.0 if right == 0 else 0.0 if right == np.sum(inside) else 4.0 + abs(right - 2)
        return 3.0 * wrong + part
    return u, cuts, truth, cost


@pytest.mark.parametrize("seed", range(5))
def test_edge_scan_leaves_a_band_holding_part_of_the_true_one(seed):
    """Held commands: from the true band's top two levels, a compass search stays put; scanning
    each edge over every recorded level ends with exactly the true levels inside, at a cost never
    above the start's, and no band wider than allowed is tried."""
    u, cuts, truth, cost = _held_levels_band_cost(seed)
    inside = (u > truth[0]) & (u < truth[1])
    top = np.sort(u[inside])[-2:]
    a0, b0 = float(cuts[cuts < top[0]].max()), float(cuts[cuts > top[1]].min())
    start = cost((0.5 * (a0 + b0), b0 - a0))
    stuck, a1, b1 = _edge_search(cost, a0, b0, (0.05, 0.02), cuts)
    assert stuck == start  # the trap: no single compass move helps
    tried = []

    def logged(x):
        tried.append(x[1])
        return cost(x)
    best, a, b = _edge_scan(logged, start, a0, b0, cuts, 1.5)
    assert best <= start
    assert max(tried) <= 1.5 + 1e-9
    assert np.array_equal((u > a) & (u < b), inside)
    assert best == cost((0.5 * (a + b), b - a))


def _held_levels_split(seed: int) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Random levels held 3 s each over 180 s, 10-s training and held-out blocks, and a band."""
    rng = np.random.default_rng(seed)
    u = np.repeat(np.round(rng.uniform(2.0, 8.0, 60), 3), 30)
    train, _ = interleaved_split(len(u), 0.1, 10.0)
    lo = rng.uniform(3.5, 4.5)
    return u, train, (lo, lo + rng.uniform(0.6, 1.4))


def test_a_band_s_edges_go_midway_between_the_training_blocks_commands():
    """Held levels; a cost that sees only the training blocks (the samples whose side of the band is
    wrong there), flat wherever an edge moves among held-out commands. From edges at the training
    commands' side of each plateau (a search may stop anywhere on it), each edge goes to the middle
    between the training commands around it, at the same cost, and over 200 recordings puts fewer
    held-out samples on the wrong side than either end of the plateau does. A cost that also sees the
    held-out commands, or a command that changes every sample, leaves the edges where they are."""
    wrong_mid = wrong_low = wrong_high = 0
    for seed in range(200):
        u, train, (lo, hi) = _held_levels_split(seed)
        inside = (u > lo) & (u < hi)

        def cost(x, mask=train):
            a, b = x[0] - x[1] / 2, x[0] + x[1] / 2
            return float(np.sum((((u > a) & (u < b)) != inside)[mask]))
        levels = np.unique(u[train])
        if not np.any(inside[train]):
            continue  # a band the training blocks never hold: both edges on one plateau
        below = [float(levels[levels < e].max()) for e in (lo, hi)]
        above = [float(levels[levels > e].min()) for e in (lo, hi)]
        a0, b0 = below[0] + 1e-4, above[1] - 1e-4  # the plateaus' outer ends: the widest band
        assert cost((0.5 * (a0 + b0), b0 - a0)) == 0.0
        a, b = _midway_edges(cost, 0.0, a0, b0, u, train)
        assert (a, b) == (0.5 * (below[0] + above[0]), 0.5 * (below[1] + above[1]))
        assert cost((0.5 * (a + b), b - a)) == 0.0

        def wrong(a_, b_):
            return int(np.sum((((u > a_) & (u < b_)) != inside)[~train]))
        wrong_mid += wrong(a, b)
        wrong_low += wrong(below[0] + 1e-4, below[1] + 1e-4)
        wrong_high += wrong(above[0] - 1e-4, above[1] - 1e-4)
        # the held-out commands seen too: from the rig's edges, no move changes a recorded command's side
        a1, b1 = _midway_edges(lambda x: cost(x, np.ones_like(train)), 0.0, lo, hi, u, train)
        assert np.array_equal((u > a1) & (u < b1), inside)
    assert wrong_mid < min(wrong_low, wrong_high)
    # a command changing every sample: no move
    u, train, (lo, hi) = _held_levels_split(0)
    ramp = np.linspace(2.0, 8.0, len(u))
    assert _midway_edges(lambda x: 0.0, 0.0, lo, hi, ramp, train) == (lo, hi)


def test_a_band_s_edge_goes_to_the_middle_of_the_training_commands_it_may_cross_as_well():
    """Seed 3's field case 047 in its levels: 6.68 V held briefly in a training block, 6.635 V held
    out, the rig's upper edge at 6.59 V. The training cost takes 6.68 V in by a hair (the model
    error's doing, within ``tol``), and an edge between 6.68 and 6.693 V has 6.635 V inside the band;
    the edge goes to the middle of 6.473 .. 6.693 V, the stretch it may cross as well, which leaves
    6.635 V out. A level that costs more than ``tol`` to cross bounds the stretch, the band keeps its
    cost within ``tol``, and with ``tol`` zero only the gap the edge lies in counts (the plain midway
    rule, which keeps 6.635 V in)."""
    levels = {5.5: 1, 5.98: 0, 6.011: 1, 6.017: 1, 6.174: 1, 6.194: 1, 6.201: 1, 6.337: 0, 6.37: 0,
              6.437: 1, 6.473: 1, 6.635: 0, 6.68: 1, 6.693: 1, 6.696: 1, 7.2: 1}
    u = np.repeat(list(levels), 10)
    train = np.repeat([bool(v) for v in levels.values()], 10)
    weight = np.where(u == 6.68, 0.02, 1.0)  # the brief level: its side is barely seen
    seen_inside = ((u > 5.957) & (u < 6.588)) | (u == 6.68)  # the rig's band, and the model error's hair

    def cost(x):
        a, b = x[0] - x[1] / 2, x[0] + x[1] / 2
        return float(np.sum((weight * (((u > a) & (u < b)) != seen_inside))[train]))
    lo0, hi0 = 0.5 * (5.5 + 6.011), 0.5 * (6.68 + 6.693)  # the search's band: 6.68 V taken in
    assert cost((0.5 * (lo0 + hi0), hi0 - lo0)) == 0.0
    a, b = _midway_edges(cost, 0.5, lo0, hi0, u, train)
    assert b == pytest.approx(0.5 * (6.473 + 6.693))
    assert a == pytest.approx(lo0)  # crossing 5.5 or 6.011 V costs ten samples
    assert cost((0.5 * (a + b), b - a)) <= 0.5
    assert not a < 6.635 < b
    a0, b0 = _midway_edges(cost, 0.0, lo0, hi0, u, train)
    assert (a0, b0) == (pytest.approx(lo0), pytest.approx(hi0))
    assert a0 < 6.635 < b0


@pytest.mark.parametrize("lower,upper", [(5.79, 6.59), (5.70, 6.70), (5.75, 6.60)])
def test_a_band_refined_on_its_model_holds_the_rig_s_commands(lower, upper):
    """A 0.9-V band at 6.2 V under the paper's sine; the model holds it with edges a few hundredths
    of a volt off (as after the constants moved under a band found earlier). The refinement on the
    whole run's training blocks ends with exactly the rig's recorded commands inside the band, and
    the held-out fit at the noise; on the rig's own band, and on a model without a band, it
    proposes nothing."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.fit_problem import Problem
    from tapmuscle.diagnosis.simulation import Simulator

    model = PlantParams()
    rig = model.with_values(**{"dead_zone.center_v": 6.2, "dead_zone.width_v": 0.9})
    cols = record(rig, "sine", 0, duration_s=180.0)
    u, y = cols["u_v"], cols["l_mm"]
    sim = Simulator(u, 0.1)
    train, test = interleaved_split(len(u), 0.1, 10.0)
    problem = Problem(y, cols["t_s"], u, 0.1, train, test, sim, 0.01)
    start = model.with_values(**{"dead_zone.center_v": 0.5 * (lower + upper), "dead_zone.width_v": upper - lower})
    refine = candidate("valve_dead_zone").refine
    moved = refine(problem, start)
    assert moved is not None
    c, w = moved["dead_zone.center_v"], moved["dead_zone.width_v"]
    inside = (u > c - w / 2) & (u < c + w / 2)
    assert np.array_equal(inside, (u > 5.75) & (u < 6.65))
    before = fit_percent(y, sim.run(start)[0], test)
    after = fit_percent(y, sim.run(start.with_values(**moved))[0], test)
    assert before < 97.0 and after >= 99.9
    assert refine(problem, rig) is None and refine(problem, model) is None


def test_a_sag_refined_on_its_model_places_the_edge_a_training_block_holds():
    """A 50-kPa sag from 46.7 s (inside the training block 40-50 s) to 80.8 s (inside the held-out
    block 80-90 s) under the paper's sine; the model holds it as the own search may leave it when
    judged against a round's larger training error: its fall hedged as an 11.6-s ramp from 45.6 s,
    reaching into the held-out block 50-60 s where the training cost is flat. The refinement on the
    model's constants places the fall within 0.3 s, keeps the recovery where it was (or a ramp
    across it), and brings the held-out fit near the noise; on a model without a sag
    it proposes nothing."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.fit_problem import Problem
    from tapmuscle.diagnosis.simulation import Simulator

    model = PlantParams()
    sag = {"supply_variation.sag_mpa": 0.05, "supply_variation.start_s": 46.7, "supply_variation.end_s": 80.8}
    cols = record(model.with_values(**sag), "sine", 0, duration_s=180.0)
    u, y = cols["u_v"], cols["l_mm"]
    sim = Simulator(u, 0.1)
    train, test = interleaved_split(len(u), 0.1, 10.0)
    problem = Problem(y, cols["t_s"], u, 0.1, train, test, sim, 0.01)
    hedged = model.with_values(**(sag | {"supply_variation.start_s": 45.6, "supply_variation.ramp_s": 11.6}))
    moved = candidate("supply_pressure_variation").refine(problem, hedged)
    assert moved is not None
    fitted = hedged.with_values(**moved).supply_variation
    assert fitted.start_s == pytest.approx(46.7, abs=0.3) and fitted.ramp_s <= 2.0
    # the recovery, in a held-out block: on the exact model the muscle's memory in the next training
    # block places it; a ramp would span it
    assert fitted.end_s - 0.3 <= 80.8 <= fitted.end_s + fitted.recovery_s + 0.3
    before = fit_percent(y, sim.run(hedged)[0], test)
    after = fit_percent(y, sim.run(hedged.with_values(**moved))[0], test)
    assert before < 97.0 and after >= 99.0, (before, after)
    assert candidate("supply_pressure_variation").refine(problem, model) is None


def _presliding_reading(x: np.ndarray, scale_mm: float) -> np.ndarray:
    """A friction's presliding lag (Dahl-like, bounded by ``scale_mm``): hysteresis that mimics a play."""
    out, z = np.empty_like(x), 0.0
    for k in range(1, len(x)):
        dx = x[k] - x[k - 1]
        z += dx - abs(dx) * z / scale_mm
        out[k] = z
    out[0] = 0.0
    return -out


def test_a_play_the_constants_took_up_is_searched_by_what_their_re_fit_leaves():
    """A 1.5-mm play in the reading; the calibrated model holds a friction lag fitted in its place (a
    constant scaling a presliding hysteresis, least squares). The play's search on that model as it
    stands finds a tenth of the play; judged by what the constant's linearised re-fit leaves, it finds
    a wider play, whose predicted joint error is lower, and reports the predicted gain. No
    simulation: the play acts on the reading."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.boundary_effects import backlash
    from tapmuscle.diagnosis.fit_problem import Problem
    from tapmuscle.diagnosis.linearised_constants import LinearisedConstants

    t = np.arange(1801) * 0.1
    core = 10.0 + 8.0 * np.sin(2 * np.pi * 0.1 * t) + 3.0 * np.sin(2 * np.pi * 0.023 * t)
    y = backlash(core, 1.5) + np.random.default_rng(0).normal(0.0, 0.01, t.size)
    lag = _presliding_reading(core, 0.5)
    taken = float(lag @ (y - core) / (lag @ lag))  # the constant's calibrated value
    y_base = core + taken * lag
    train, test = interleaved_split(t.size, 0.1, 10.0)
    pr = Problem(y, t, np.zeros_like(t), 0.1, train, test, None, 0.01)
    base = PlantParams()
    plain = candidate("backlash").fit(pr, base, y_base)
    assert plain.joint_gain_mm2 is None and plain.values["backlash.slack_mm"] < 0.3
    lin = LinearisedConstants(base, -lag[:pr.n_fit, None], np.array([taken]), np.array([True]),
                              np.array([-50.0]), np.array([50.0]), 0.01)
    # taken at another model: not used
    pr.constants = LinearisedConstants(base.with_values(**{"valve.cv_max": 1.1}), lin.jacobian, lin.x, lin.prior,
                                       lin.lower, lin.upper, lin.sigma_mm)
    assert candidate("backlash").fit(pr, base, y_base).values == plain.values
    pr.constants = lin
    res = candidate("backlash").fit(pr, base, y_base)
    seg = np.flatnonzero(train[:pr.n_fit])

    def left(s):
        return lin.left_mm2((y - backlash(y_base, s))[seg], seg)
    assert res.values["backlash.slack_mm"] > 2.0 * plain.values["backlash.slack_mm"] + 0.2
    assert left(res.values["backlash.slack_mm"]) < left(plain.values["backlash.slack_mm"])
    assert res.joint_gain_mm2 == pytest.approx(left(0.0) - left(res.values["backlash.slack_mm"]), rel=1e-9)
    assert res.joint_gain_mm2 > 0.0
    np.testing.assert_array_equal(res.y_hat, backlash(y_base, res.values["backlash.slack_mm"]))


@pytest.mark.slow
def test_unexplained_when_no_candidate_fits():
    """A load mismatch, with only the delay and backlash as candidates: the structure is reported as such."""
    rig = DEMO_MODEL.with_values(**{"load_mismatch.extra_n": 8.0})
    cols = record(rig, "sine", 4)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL,
                 candidates=[candidate("transport_delay"), candidate("backlash")], calibration=None)
    assert d.verdict == "mismatch"
    assert [f.effect for f in d.findings][-1] == "unexplained"
    assert all(f.effect != "load_mismatch" for f in d.findings)
    assert d.findings[-1].located and "explain (" in d.findings[-1].explanation


def test_a_report_with_nothing_named_says_what_to_do_next(tmp_path):
    """A mismatch with only an unexplained residual must not leave its reader without a next step: the report
    says what such a residual usually means and which recording separates the causes. A report that
    names an effect does not."""
    from tapmuscle.diagnosis.report import write_outputs

    rig = DEMO_MODEL.with_values(**{"load_mismatch.extra_n": 8.0})
    cols = record(rig, "sine", 4, duration_s=60.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL, candidates=[candidate("backlash")],
                 calibration=None)
    assert d.named == [] and [f.effect for f in d.findings] == ["unexplained"]
    write_outputs(d, tmp_path / "a", recording="rec.csv", plant="plant.json", plots=False)
    assert "Next: nothing in the vocabulary explains what is left." in (tmp_path / "a" / "report.md").read_text()
    assert json.loads((tmp_path / "a" / "diagnosis.json").read_text())["software"] == software()
    named = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL, candidates=[candidate("load_mismatch")],
                     calibration=None)
    assert named.named == ["load_mismatch"]
    write_outputs(named, tmp_path / "b", recording="rec.csv", plant="plant.json", plots=False)
    assert "Next: nothing" not in (tmp_path / "b" / "report.md").read_text()


@pytest.mark.parametrize("amplitude_mm, material", [(0.025, False), (0.3, True)])
def test_a_structured_remainder_is_reported_and_claimed_only_when_material(amplitude_mm, material, tmp_path):
    """The exact model and a slow ripple on the reading that no candidate describes: reported as
    ``unexplained`` with its share however small, a finding only at >= MATERIAL_FACTOR x the noise; a
    report with no finding says the remainder is there (not "at the noise level ... < 1.5 x" of a
    residual at 2 x)."""
    cols = record(DEMO_MODEL, "sine", 5)
    y = cols["l_mm"] + amplitude_mm * np.sin(2 * np.pi * 0.37 * cols["t_s"])
    d = diagnose(cols["t_s"], cols["u_v"], y, DEMO_MODEL, candidates=[candidate("backlash")], calibration=None)
    rem = d.unexplained
    assert rem is not None and rem["share"] > 0.0 and rem["material"] is material
    assert (rem["rms_mm"] >= MATERIAL_FACTOR * rem["noise_mm"]) is material
    assert ("unexplained" in [f.effect for f in d.findings]) is material
    assert d.verdict == ("mismatch" if material else "no_significant_mismatch")
    assert d.to_json()["unexplained"]["material"] is material
    assert d.to_json()["calibration"] == {"skipped": "off (calibration=None, --no-calibration)"}
    if not material:
        from tapmuscle.diagnosis.report import write_outputs

        write_outputs(d, tmp_path, recording="rec.csv", plant="plant.json", plots=False)
        assert "None: no cause is named (a structured remainder below the materiality level: RMS " in \
            (tmp_path / "report.md").read_text()


def test_every_effect_of_the_library_is_a_candidate():
    names = {c.name for c in CANDIDATES}
    assert names == {"rate_dependent_hysteresis", "valve_dead_zone", "transport_delay", "supply_pressure_variation",
                     "load_mismatch", "sensor_drift", "backlash", "input_map", "supply_pressure_offset"}
    for c in CANDIDATES:  # every fitted parameter is a plant (FMU) parameter; all at their bounds at once
        DEMO_MODEL.with_values(**{p.key: p.lo for p in c.parameters})
        DEMO_MODEL.with_values(**{p.key: p.hi for p in c.parameters})


def test_joint_parameters_and_starts_are_the_candidates_own_plant_parameters():
    from tapmuscle.diagnosis.model_space import MUSCLE
    by_name = {c.name: {p.key for p in c.parameters} for c in CANDIDATES}
    for name, keys in MUSCLE.joint_parameters.items():
        assert {k for k, _ in keys} <= by_name[name], name
    for name, starts in MUSCLE.joint_starts.items():
        assert starts and all(set(st) <= by_name[name] for st in starts), name
        for st in starts:  # each a plant the FMU accepts
            DEMO_MODEL.with_values(**st)
    # the map starts again from the identity, which switches it off
    assert any(DEMO_MODEL.with_values(**st).input_map.is_identity() for st in MUSCLE.joint_starts["input_map"])


def test_every_effect_is_off_at_its_off_values_as_in_the_effect_free_demo_model():
    # the backward step switches an effect off with these values: against the demos' model (calibrated
    # without rate dependence) every one is that model's; the rate dependence is the plant file's gain
    # (the default plant's 0.8 is the paper's calibration, which every rig has)
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.model_space import MuscleSpace
    for c in CANDIDATES:
        keys = [p.key for p in c.parameters]
        assert MuscleSpace(DEMO_MODEL).off_values(keys) == {k: DEMO_MODEL.value(k) for k in keys}, c.name
    assert MuscleSpace(PlantParams()).off_values(["friction.rate_gain"]) == {"friction.rate_gain": 0.8}


#: A command dead band of 1.2 V at 5 V in the amplifier: the valve keeps metering, but commands in the
#: band act as 5 V and the others 0.6 V closer to it.
BAND_5V = {"input_map.out_at_0_v": 0.6, "input_map.knot1_in_v": 4.4, "input_map.knot1_out_v": 5.0,
           "input_map.knot2_in_v": 5.6, "input_map.knot2_out_v": 5.0, "input_map.out_at_10_v": 9.4}
INPUT_MAPS = [
    ("dead band 1.2 V at 5 V", BAND_5V, "steps", "dead band"),
    ("dead band 0.8 V at 6.5 V", {"input_map.out_at_0_v": 0.4, "input_map.knot1_in_v": 6.1, "input_map.knot1_out_v": 6.5,
                                  "input_map.knot2_in_v": 6.9, "input_map.knot2_out_v": 6.5,
                                  "input_map.out_at_10_v": 9.6}, "sine", "dead band"),
    ("gain 0.85, offset +0.5 V", {"input_map.out_at_0_v": 0.5, "input_map.knot1_in_v": 2.0, "input_map.knot1_out_v": 2.2,
                                  "input_map.knot2_in_v": 6.0, "input_map.knot2_out_v": 5.6,
                                  "input_map.out_at_10_v": 9.0}, "ampc", "0.85 x the command +0.50 V"),
]


@pytest.mark.slow
@pytest.mark.parametrize("name,rig_map,excitation,words", INPUT_MAPS, ids=[c[0] for c in INPUT_MAPS])
def test_the_input_map_candidate_fits_a_static_input_map_to_the_noise(name, rig_map, excitation, words):
    """Fitted on the training blocks of the fit segment, on top of the model, and scored on the held-out
    blocks of the whole 180-s recording, the map is recovered to the noise."""
    from tapmuscle.diagnosis.candidates import Problem
    from tapmuscle.diagnosis.residual_analysis import white_noise_level_mm
    from tapmuscle.diagnosis.simulation import Simulator

    model = PlantParams_default_with({})
    cols = record(model.with_values(**rig_map), excitation, 0, duration_s=180.0)
    sim = Simulator(cols["u_v"], 0.1)
    y0 = sim.run(model, checkpoint_every=100)[0]
    train, test = interleaved_split(len(y0), 0.1, 10.0)
    problem = Problem(cols["l_mm"], cols["t_s"], cols["u_v"], 0.1, train, test, sim,
                      white_noise_level_mm(cols["l_mm"] - y0))
    runs = sim.runs
    res = candidate("input_map").fit(problem, model, y0)
    assert sim.runs - runs <= 71  # the search's budget and the final whole-run simulation
    assert fit_percent(cols["l_mm"], y0, test) < 90.0
    assert fit_percent(cols["l_mm"], res.y_hat, test) >= 99.0
    assert words in candidate("input_map").explain(res.values)
    # the map is the model's now: the candidate does not fit it again
    assert candidate("input_map").fit(problem, model.with_values(**res.values), res.y_hat) is None


@pytest.mark.slow
def test_a_command_dead_band_is_named_an_input_map():
    """The diagnosis names the 1.2-V dead band of the amplifier an input map, fitted to the noise."""
    model = PlantParams_default_with({})
    cols = record(model.with_values(**BAND_5V), "steps", 0, duration_s=180.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], model,
                 candidates=[candidate("valve_dead_zone"), candidate("input_map")])
    assert d.fit_before_percent < 50.0
    assert d.findings[0].effect == "input_map", [(c["effect"], c.get("fit_gain_points")) for c in d.candidates]
    assert d.fit_after_percent >= 95.0
    assert "dead band" in d.findings[0].explanation


# ------------------------------------------------------------------------------ the command
@pytest.mark.slow
def test_diagnose_cli_with_the_plant_fmu_and_its_calibrated_file(tmp_path, built_fmus, capsys):
    from tapmuscle.diagnosis.plant_source import load_plant, simulate_plant_fmu
    from tapmuscle.io.recording import Recording, read_recording, write_recording

    rig = PlantParams_default_with({"load_mismatch.extra_n": 6.0, "friction.rate_gain": 0.8})
    cols = record(rig, "sine", 7)
    rec = tmp_path / "rec.csv"
    write_recording(rec, Recording(cols, {"ts_s": "0.1"}))
    out = tmp_path / "diag"
    # the default plant FMU: rate dependence on, no load mismatch
    # the model is exact but for the load: a sine alone cannot tell a load from recalibrated constants
    assert main(["diagnose", "--recording", str(rec), "--plant", str(built_fmus["MusclePlant"]), "--out", str(out),
                 "--quiet", "--no-calibration"]) == 0
    printed = capsys.readouterr().out
    assert "load_mismatch" in printed
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["verdict"] == "mismatch" and doc["findings"][0]["effect"] == "load_mismatch"
    assert doc["split"]["block_s"] == 10.0  # the default blocks
    assert doc["fmu_check"]["max_abs_difference_mm"] < 1e-6
    assert doc["fit_after_percent"] - doc["fit_before_percent"] > 3.0
    for name in ("report.md", "residual.png", "overlay.png", "hysteresis.png", "residual_tests.png"):
        assert (out / name).stat().st_size > 0
    # re-simulating the FMU with the calibrated file's parameters gives the improved fit
    calibrated, _ = load_plant(out / "calibrated_plant.json")
    rec_back = read_recording(rec)
    y = simulate_plant_fmu(built_fmus["MusclePlant"], calibrated.noise_free().dotted(), rec_back.u_v, 0.1)
    _, test = interleaved_split(len(y), 0.1, 10.0)
    assert fit_percent(rec_back.l_mm, y, test) == pytest.approx(doc["fit_after_percent"], abs=0.01)


@pytest.mark.slow
def test_the_reported_constants_are_the_calibrated_plant_files(tmp_path):
    """The report's calibration rows state the final model's constants, the ones written to
    calibrated_plant.json. A 0.3-s delay under random steps: the first calibration, with the delay
    left out, bends the flow coefficient to 0.79 and the friction to 1.7 N; the delay's joint re-fit
    takes them back to the rig's 1.50 and 8 N, and the rows must not keep the first calibration's values."""
    from fmu_plant import PlantParams

    out = tmp_path / "diag"
    rec = tmp_path / "delayed.csv"
    assert main(["record", "--load", "44", "--input", "random:lo=2,hi=8,hold_min=2,hold_max=10,seed=0",
                 "--duration", "240", "--seed", "3", "--set", "delay.delay_s=0.3", "--out", str(rec), "--quiet"]) == 0
    nominal = tmp_path / "plant.json"
    nominal.write_text(json.dumps({"plant": PlantParams().to_dict()}))
    assert main(["diagnose", "--recording", str(rec), "--plant", str(nominal), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "diagnosis.json").read_text())
    assert [f["effect"] for f in doc["findings"]] == ["transport_delay"]
    plant = PlantParams.from_dict(json.loads((out / "calibrated_plant.json").read_text())["plant"])
    rows = doc["calibration"]["parameters"]
    assert len(rows) >= 10
    for row in rows:
        assert row["estimate"] == pytest.approx(plant.value(row["parameter"]), rel=1e-5), row
        assert row["ci95"][0] <= row["estimate"] <= row["ci95"][1], row
    # the final model is the rig's, to well within the noise: its constants are the nominal ones
    assert plant.value("valve.cv_max") == pytest.approx(1.5, rel=0.02)
    assert plant.value("friction.base_n") == pytest.approx(8.0, rel=0.05)


def test_diagnose_cli_recalibrates_the_constants_calibrate_names(tmp_path, capsys):
    """``--calibrate`` names the constants (``default`` the twelve): a rig whose supply pressure is 10 %
    low and friction 10 % high is recalibrated to within 1 % by those two; with ``--no-calibration``, an
    effect's parameter, a name twice or an unknown one, it is refused before anything runs, naming what
    is wrong."""
    rec, out = tmp_path / "rig.csv", tmp_path / "diag"
    assert main(["record", "--load", "44", "--input", "random:lo=2,hi=8,hold_min=2,hold_max=6,seed=3",
                 "--duration", "180", "--seed", "7", "--set", "supply.supply_pressure_mpa=0.225",
                 "--set", "friction.base_n=8.8", "--out", str(rec), "--quiet"]) == 0
    plant = tmp_path / "plant.json"
    plant.write_text('{"plant": {}}')
    base = ["diagnose", "--recording", str(rec), "--plant", str(plant), "--quiet", "--no-plots", "--workers", "1"]
    for extra, message in [(["--calibrate", "load.load_n", "--no-calibration"], "exclude each other"),
                           (["--calibrate", "default,dead_zone.width_v"], "'dead_zone.width_v' is a parameter of an effect"),
                           (["--calibrate", "load.load_n,load.load_n"], "'load.load_n' is given twice"),
                           (["--calibrate", "load.lod_n"], "unknown nominal parameter 'load.lod_n' .*load has: load_n")]:
        capsys.readouterr()
        assert main(base + ["--out", str(tmp_path / "refused")] + extra) == 2
        assert re.search(message, capsys.readouterr().err), extra
        assert not (tmp_path / "refused").exists()
    assert main(base + ["--out", str(out), "--calibrate", "friction.base_n,supply.supply_pressure_mpa",
                        "--effects", "transport_delay"]) == 0
    doc = json.loads((out / "diagnosis.json").read_text())
    rows = {row["parameter"]: row["estimate"] for row in doc["calibration"]["parameters"]}
    assert set(rows) == {"friction.base_n", "supply.supply_pressure_mpa"}
    assert rows["friction.base_n"] == pytest.approx(8.8, rel=0.01)
    assert rows["supply.supply_pressure_mpa"] == pytest.approx(0.225, rel=0.01)


def PlantParams_default_with(values):
    from fmu_plant import PlantParams

    return PlantParams().with_values(**values)


@pytest.mark.slow
def test_a_search_restricted_by_effects_that_leaves_a_structured_residual_says_to_search_them_all(tmp_path, capsys):
    """A discriminating experiment's re-diagnosis searches among its alternatives (``--effects``): on a
    rig whose 0.3-s delay the first diagnosis did not name, what remains is unexplained, and the
    command says to diagnose again without ``--effects``; with the delay among them, nothing is said."""
    from fmu_plant import PlantParams
    from tapmuscle.cli.main import main
    from tapmuscle.io.plant_file import write_plant_file

    rec, plant = tmp_path / "rec.csv", tmp_path / "nominal.json"
    write_plant_file(plant, PlantParams())
    assert main(["record", "--input", "random:lo=2,hi=8,hold_min=0.5,hold_max=3,seed=1", "--duration", "60",
                 "--set", "delay.delay_s=0.3", "--out", str(rec), "--quiet"]) == 0
    said = {}
    for effects in ("valve_dead_zone", "transport_delay,valve_dead_zone"):
        capsys.readouterr()
        assert main(["diagnose", "--recording", str(rec), "--plant", str(plant), "--effects", effects,
                     "--no-calibration", "--no-plots", "--quiet", "--out", str(tmp_path / effects)]) == 0
        out, err = capsys.readouterr()
        said[effects] = (out, err)
    out, err = said["valve_dead_zone"]
    assert "unexplained" in out and ("note: the search was restricted to --effects valve_dead_zone, and a structured "
                                     "residual remains (unexplained, below): diagnose this recording again without "
                                     "--effects to search every candidate") in err
    out, err = said["transport_delay,valve_dead_zone"]
    assert "transport_delay" in out and "the search was restricted" not in err

def test_diagnose_cli_names_the_line_and_column_of_a_malformed_recording(tmp_path, capsys):
    plant = tmp_path / "plant.json"
    plant.write_text(json.dumps({"plant": DEMO_MODEL.to_dict()}))
    rec = tmp_path / "bad.csv"
    rec.write_text("t_s,u_v,l_mm\n0.0,5.0,0.0\n0.1,five,0.1\n")
    out = tmp_path / "out"
    assert main(["diagnose", "--recording", str(rec), "--plant", str(plant), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "line 3" in err and "'u_v'" in err and "'five'" in err
    assert not out.exists()
    rec.write_text("t_s,u_v,l_mm\n" + "".join(f"{0.1 * k:.1f},{5 + (k % 7)},{k}\n" for k in range(400)).replace("\n20.0,", "\n20.05,"))
    assert main(["diagnose", "--recording", str(rec), "--plant", str(plant), "--out", str(out)]) == 2
    assert re.search(r"bad\.csv: column t_s, line 202 \(sample 200\): t = 20\.05 s lies \+0\.04\d+ s off the uniform grid "
                     r"of 0\.1 s", capsys.readouterr().err)
    rec.write_text("t_s,u_v,l_mm\n" + "".join(f"{0.1 * k:.1f},{5 + (k % 7)},{k}\n" for k in range(400)))
    assert main(["diagnose", "--recording", str(rec), "--plant", str(tmp_path / "nope.fmu"), "--out", str(out)]) == 2
    assert "nope.fmu" in capsys.readouterr().err


# ------------------------------------------------------------------------------ field recordings
#: A rig whose constants are off as real ones are (stiffness +15 %, base friction -20 %, valve Cv -10 %).
OFF = {"muscle.rubber_stiffness_n_per_mm": 1.38, "friction.base_n": 6.4, "valve.cv_max": 1.35}


@pytest.mark.slow
def test_parameter_errors_alone_are_calibrated_not_blamed_on_an_effect(tmp_path, capsys):
    from tapmuscle.io.plant_file import plant_file_text
    from tapmuscle.io.recording import Recording, atomic_write_text, write_recording
    from tapmuscle.diagnosis.plant_source import load_plant
    from tapmuscle.diagnosis.simulation import Simulator

    cols = record(DEMO_MODEL.with_values(**OFF), "steps", 3, duration_s=150.0)
    rec, plant, out = tmp_path / "rec.csv", tmp_path / "plant.json", tmp_path / "diag"
    write_recording(rec, Recording(cols, {"ts_s": "0.1"}))
    atomic_write_text(plant, plant_file_text(DEMO_MODEL, "nominal"))
    assert main(["diagnose", "--recording", str(rec), "--plant", str(plant), "--out", str(out), "--quiet",
                 "--no-plots"]) == 0
    assert "calibration only" in capsys.readouterr().out
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["verdict"] == "calibration_only" and doc["findings"] == [] and doc["ambiguous"] == []
    assert doc["fit_before_percent"] < 90.0 and doc["fit_after_percent"] > 99.5
    rows = {r["parameter"]: r for r in doc["calibration"]["parameters"]}
    assert set(rows) == {p.key for p in NOMINAL_PARAMETERS}
    assert rows["valve.cv_max"]["identifiable"] and rows["valve.cv_max"]["ci95"][0] <= 1.35 <= rows["valve.cv_max"]["ci95"][1] + 0.02
    for r in rows.values():
        assert r["ci95"][0] <= r["estimate"] <= r["ci95"][1]
        if not r["identifiable"]:
            assert r["estimate"] == r["nominal"]  # left alone
    # the calibrated plant file reproduces the fit the report states
    calibrated, _ = load_plant(out / "calibrated_plant.json")
    y = Simulator(cols["u_v"], 0.1).run(calibrated)[0]
    _, test = interleaved_split(len(y), 0.1, 10.0)
    assert fit_percent(cols["l_mm"], y, test) == pytest.approx(doc["fit_after_percent"], abs=0.01)


@pytest.mark.slow
@pytest.mark.parametrize("excitation,seed", [("sine", 22), ("steps", 23)])
def test_an_encoder_offset_beside_a_delay_is_named_from_the_first_reading(excitation, seed):
    """An encoder zeroed 12.5 mm off on a rig with a 0.3-s delay. Left to the calibration, the offset
    would bend the constants (radius and braid angle) and the delay would then be misread: an input map and a
    backlash (sine), an ambiguous delay (steps). The first reading, drained at t = 0 where the model
    reads 0 whatever its constants, starts the search with the offset, and both effects are named with
    the constants left near nominal (the fit at the noise floor)."""
    rig = DEMO_MODEL.with_values(**{"sensor_drift.offset_mm": 12.5, "delay.delay_s": 0.3})
    cols = record(rig, excitation, seed, duration_s=120.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL, p_mpa=cols["p_mpa"])
    assert d.verdict == "mismatch" and d.named == ["sensor_drift", "transport_delay"], d.named
    values = {k: v for f in d.findings for k, v in f.parameters.items()}
    assert values["sensor_drift.offset_mm"] == pytest.approx(12.5, abs=0.05)  # 5 encoder steps
    assert values["delay.delay_s"] == pytest.approx(0.3, abs=0.01)
    assert d.fit_after_percent > 99.8
    # the constants that took the offset up (to 72 % and 62 % off) stay well within a rig's 20 %
    for key in ("muscle.radius_mm", "muscle.braid_angle_deg"):
        assert d.calibrated.value(key) == pytest.approx(DEMO_MODEL.value(key), rel=0.05), key
    (first,) = [s for s in d.selection if s.get("round") == 0]
    assert (first["step"], first["effect"], first["from"]) == ("add", "sensor_drift", "the first reading")
    assert first["held_out_sse_reduction"] >= 0.10  # diagnose's min_reduction


@pytest.mark.slow
def test_samples_a_logger_dropped_and_the_import_put_back_are_left_out_of_the_fits():
    """1.5 s of a delayed rig's recording interpolated (what ``tapmuscle import --fill-gaps`` writes):
    fitted as if measured, they would make a supply sag be claimed beside the delay (99.79 %); left out of
    the fits and tests, the delay alone is named, and the state the unlogged command left after the
    gap is the unexplained window there."""
    rig = DEMO_MODEL.with_values(**{"delay.delay_s": 0.3})
    cols = record(rig, "steps", 21, duration_s=180.0)
    t, u, l = cols["t_s"], cols["u_v"].copy(), cols["l_mm"].copy()
    gap = np.arange(1000, 1015)
    kept = np.setdiff1d(np.arange(len(t)), gap)
    u[gap], l[gap] = np.interp(t[gap], t[kept], u[kept]), np.interp(t[gap], t[kept], l[kept])
    left_out = np.isin(np.arange(len(t)), gap)
    d = diagnose(t, u, l, DEMO_MODEL, p_mpa=cols["p_mpa"], left_out=left_out)
    assert [f.effect for f in d.findings] == ["transport_delay", "unexplained"], d.findings
    assert d.findings[0].parameters["delay.delay_s"] == pytest.approx(0.3, abs=0.01)
    (window, *_), = [f.located for f in d.findings if f.effect == "unexplained"]
    assert 96.0 < window[0] <= 100.0 and 101.5 <= window[1] < 106.0
    assert d.fit_after_percent > 99.8 and d.to_json()["split"]["left_out_samples"] == 15
    assert not (d.train | d.test)[gap].any()
    with pytest.raises(ValueError, match="left_out has 3 samples, the recording 1801"):
        diagnose(t, u, l, DEMO_MODEL, left_out=np.zeros(3, bool))


@pytest.mark.slow
def test_a_delay_on_a_rig_whose_constants_are_off_is_named_alone():
    """Without calibration first, this recording would be blamed on a supply sag, then a delay."""
    cols = record(DEMO_MODEL.with_values(**OFF, **{"delay.delay_s": 0.3}), "steps", 3, duration_s=150.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL,
                 candidates=[candidate(n) for n in ("transport_delay", "supply_pressure_variation", "sensor_drift")])
    assert d.named == ["transport_delay"] and d.verdict == "mismatch"
    assert d.findings[0].parameters["delay.delay_s"] == pytest.approx(0.3, abs=0.03)
    assert d.findings[0].explanation == candidate("transport_delay").explain(d.findings[0].parameters)
    assert d.fit_calibrated_percent < 95.0 < d.fit_after_percent
    # the delay's 95 % interval (joint with the calibrated constants) holds the rig's, and says so in the files
    lo, hi = d.findings[0].ci95["delay.delay_s"]
    assert lo <= 0.3 <= hi and hi - lo < 0.01
    assert d.to_json()["findings"][0]["ci95"]["delay.delay_s"] == [pytest.approx(lo, rel=1e-5), pytest.approx(hi, rel=1e-5)]
    from tapmuscle.diagnosis.report import _report_md
    text = _report_md(d, "rec.csv", "plant.json", None)
    shown = re.search(r"`delay\.delay_s` = [0-9.]+ \(95 %: ([0-9.]+) to ([0-9.]+)\)", text)
    # as many digits as tell the ends apart (an interval of 0.2 ms around 0.3 s is not "0.3 to 0.3")
    assert shown and float(shown[1]) < float(shown[2]) and float(shown[1]) == pytest.approx(lo, rel=1e-4)
    assert "linearised at the final model" in text
    # without the calibration, on the rig's own constants: the interval from the effect's own Jacobian
    d0 = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL.with_values(**OFF), calibration=None,
                  candidates=[candidate("transport_delay")])
    lo0, hi0 = d0.findings[0].ci95["delay.delay_s"]
    assert d0.named == ["transport_delay"] and lo0 <= 0.3 <= hi0 and hi0 - lo0 < 0.01


@pytest.mark.slow
def test_worker_processes_give_the_same_diagnosis():
    """workers = 2 spreads the candidates' own fits, the joint re-fits and the forward-difference
    Jacobians over two processes: the diagnosis is the serial one, bit for bit (same verdict, same
    simulations, same fitted prediction)."""
    cols = record(DEMO_MODEL.with_values(**OFF, **{"delay.delay_s": 0.3}), "steps", 3, duration_s=150.0)
    cands = [candidate(n) for n in ("transport_delay", "supply_pressure_variation", "sensor_drift")]
    calls = {1: [], 2: []}
    d = {w: diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL, candidates=cands, workers=w,
                     progress=lambda i, n, w=w: calls[w].append((i, n))) for w in (1, 2)}
    assert d[1].named == d[2].named == ["transport_delay"]
    assert d[1].simulations == d[2].simulations and calls[1] == calls[2]
    assert np.array_equal(d[1].y_after_mm, d[2].y_after_mm)
    assert [c["parameters"] for c in d[1].candidates if "parameters" in c] == \
        [c["parameters"] for c in d[2].candidates if "parameters" in c]


def test_worker_pool_is_validated():
    from tapmuscle.diagnosis.simulation import worker_pool
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="workers"):
            with worker_pool(bad):
                pass


def test_worker_processes_from_a_script_without_its_main_guard(tmp_path):
    """A script file that starts the pool at its top level: each worker imports it again and ends
    with its one line; the caller gets one error naming the setting and the guard, not the pool's
    BrokenProcessPool traceback through concurrent.futures."""
    script = tmp_path / "unguarded.py"
    script.write_text(textwrap.dedent("""
        import numpy as np
        from fmu_plant import PlantParams
        from tapmuscle.diagnosis.simulation import Simulator, worker_pool
        sim = Simulator(5.0 + 2.0 * np.sin(2 * np.pi * 0.01 * np.arange(101)), 0.1)
        with worker_pool(2) as pool:
            sim.executor = pool
            sim.run_many([PlantParams(), PlantParams().with_values(**{"load.load_n": 60.0})], stop=80)
    """))
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert out.returncode != 0
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("tapmuscle.errors.UsageError: workers=2: a worker process ended abruptly"), out.stderr
    assert f"imports {script} again" in last and 'if __name__ == "__main__":' in last
    assert "BrokenProcessPool" not in out.stderr


@pytest.mark.parametrize("how", ["stdin", "-c"])
def test_worker_processes_from_a_script_without_a_file(how):
    """Processes spawned from a script read from stdin cannot re-import its ``<stdin>`` main and
    would die at start; that is refused up front, naming the setting. ``python -c`` (like a notebook) has
    no main file, and its processes run and give the in-process result bit for bit."""
    script = textwrap.dedent("""
        import numpy as np
        from fmu_plant import PlantParams
        from tapmuscle.diagnosis.simulation import Simulator, worker_pool
        u = 5.0 + 2.0 * np.sin(2 * np.pi * 0.01 * np.arange(101))
        ps = [PlantParams().with_values(**{"load.load_n": w}) for w in (40.0, 60.0)]
        sim = Simulator(u, 0.1)
        one = sim.run_many(ps, stop=80)
        with worker_pool(2) as pool:
            sim.executor = pool
            many = sim.run_many(ps, stop=80)
        print("same" if all(np.array_equal(a, b) for a, b in zip(one, many)) else "differ")
    """)
    if how == "stdin":
        out = subprocess.run([sys.executable, "-"], input=script, capture_output=True, text=True, timeout=300)
        assert out.returncode != 0
        assert "UsageError: workers=2 starts worker processes" in out.stderr and "'<stdin>'" in out.stderr
        assert "BrokenProcessPool" not in out.stderr
    else:
        out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        assert out.stdout.split() == ["same"]


@pytest.mark.slow
def test_an_ambiguous_group_gets_a_discriminating_input(tmp_path, monkeypatch):
    """The report designs and writes the experiment for every ambiguous group (the alternatives here
    are made by hand: a delay and a load that the recording would not have told apart)."""
    from tapmuscle.diagnosis.diagnose import Alternative
    from tapmuscle.diagnosis.report import write_outputs
    from tapmuscle.io.signals import parse_input_spec

    cols = record(DEMO_MODEL, "sine", 11, duration_s=60.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL)
    a = DEMO_MODEL.with_values(**{"delay.delay_s": 0.1})
    b = DEMO_MODEL.with_values(**{"load_mismatch.extra_n": 3.0})
    d.calibrated = d.calibrated.with_values(**{"delay.delay_s": 0.1})  # the best alternative in the final model
    d.ambiguous = [[Alternative("transport_delay", "late", {"delay.delay_s": 0.1}, a, d.y_after_mm),
                    Alternative("load_mismatch", "heavier", {"load_mismatch.extra_n": 3.0}, b, d.y_after_mm)]]
    doc = write_outputs(d, tmp_path, recording="rec.csv", plant="plant.json", plots=False)
    group = doc["ambiguous"][0]
    assert group["discriminating_input"] == "discriminating_input.csv"
    assert [x["effect"] for x in group["alternatives"]] == ["transport_delay", "load_mismatch"]
    assert group["experiment"]["separation_sigma"] > 10.0 and group["experiment"]["duration_s"] == 60.0
    signal = parse_input_spec(f"csv:{tmp_path / 'discriminating_input.csv'}")
    # within the commands the recording covered (the alternatives were fitted there), so within 0..10 V
    lo, hi = float(np.min(cols["u_v"])), float(np.max(cols["u_v"]))
    assert 0.0 <= lo and hi <= 10.0
    assert all(lo <= signal(t) <= hi for t in np.arange(0.0, 60.0, 0.1))
    report = (tmp_path / "report.md").read_text()
    assert "Discriminating experiment" in report
    # what the calibrated plant holds of the group is said (its joint re-fit can move the value), and an
    # empty findings table says why no cause is named, by the residual's numbers
    kept = ("the calibrated plant file and the headline fit hold transport_delay as re-fitted jointly with the "
            "constants and the other effects (delay.delay_s = 0.1)")
    assert f"In the table, each alternative as fitted alone; {kept}." in report
    from tapmuscle.diagnosis.report import summary_lines

    import dataclasses

    said = summary_lines(dataclasses.replace(d, verdict="ambiguous"))
    assert any(line.endswith(kept) for line in said if line.startswith("ambiguous: transport_delay")), said
    assert "None: no cause is named (residual " in report and "consistent with sensor noise" not in report
    # the candidates' two measures, which can differ in sign, are told apart under their table
    assert "so the two can differ in sign" in report.split("## Candidates tried")[1]
    # the plant to re-diagnose its recording with: the calibrated one with both alternatives off
    from tapmuscle.io.plant_file import read_plant_file

    assert group["discriminate_plant"] == "discriminate_plant.json"
    base = read_plant_file(tmp_path / "discriminate_plant.json", "test").dotted()
    cal = d.calibrated.dotted()
    assert base["delay.delay_s"] == 0.0 and base["load_mismatch.extra_n"] == 0.0
    assert {k: v for k, v in base.items() if k not in ("delay.delay_s", "load_mismatch.extra_n")} == \
        {k: v for k, v in cal.items() if k not in ("delay.delay_s", "load_mismatch.extra_n")}
    assert (f"--plant {tmp_path / 'discriminate_plant.json'} --effects transport_delay,load_mismatch"
            in (tmp_path / "report.md").read_text())
    # the record command the report prints runs as printed, at the recording's load and period
    import re
    import shlex

    from tapmuscle.cli.main import main
    from tapmuscle.io.recording import read_recording

    printed = re.search(r"`(tapmuscle record [^`]*)`", (tmp_path / "report.md").read_text()).group(1)
    assert printed == group["experiment"]["record"]
    # as printed it records the nominal plant: the report says what a simulated rig of one's own adds
    assert "with the `--params` or `--set` options that made this recording added" in (tmp_path / "report.md").read_text()
    # from the folder the diagnosis ran in, not only from its output folder (the paths are the output
    # folder's as given: absolute here)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main(shlex.split(printed)[1:] + ["--quiet"]) == 0
    new = read_recording(elsewhere / "NEW.csv")
    assert np.all(new.load_n == DEMO_MODEL.load.load_n) and new.t_s[-1] == pytest.approx(60.0)
    assert np.allclose(new.u_v, [signal(t) for t in new.t_s], atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("levels, found", [((0.3,), False), (None, True)])
def test_the_sag_window_is_found_when_constants_off_raise_the_whole_residual(monkeypatch, levels, found):
    """Field case 044 of the proof: a 0.046 MPa sag at 54-99 s under a sine-sum on a rig whose
    friction and braid are off. The residual's 30 % window spans most of the run and a sag there
    fits worse than none; the higher levels isolate the sag's stretch."""
    import tapmuscle.diagnosis.candidates as candidates_module
    from tapmuscle.diagnosis.field_demo import field_cases, record_case
    from tapmuscle.diagnosis.fit_problem import Problem
    from tapmuscle.diagnosis.residual_analysis import white_noise_level_mm
    from tapmuscle.diagnosis.simulation import Simulator

    if levels is not None:
        monkeypatch.setattr(candidates_module, "SAG_WINDOW_LEVELS", levels)
    case = field_cases(100, 0)[44]
    assert case.effects == ("supply_pressure_variation",)
    cols = record_case(case)
    model = case.model()
    sim = Simulator(cols["u_v"], 0.1, cols["load_n"])
    y0 = sim.run(model, checkpoint_every=100)[0]
    train, test = interleaved_split(len(y0), 0.1, 10.0)
    problem = Problem(cols["l_mm"], cols["t_s"], cols["u_v"], 0.1, train, test, sim,
                      white_noise_level_mm(cols["l_mm"] - y0))
    res = candidate("supply_pressure_variation").fit(problem, model, y0)
    truth = dict(case.effect_values)
    hit = (res is not None and abs(res.values["supply_variation.start_s"] - truth["supply_variation.start_s"]) < 10.0
           and abs(res.values["supply_variation.end_s"] - truth["supply_variation.end_s"]) < 10.0)
    assert hit is found
    if found:
        assert fit_percent(cols["l_mm"], res.y_hat, test) > fit_percent(cols["l_mm"], y0, test) + 10.0


@pytest.mark.parametrize("block", ["600", "50"])
def test_blocks_too_long_for_held_out_data_are_refused(tmp_path, capsys, block):
    """With blocks as long as the recording nothing is held out (a NaN fit and NaN in the JSON): the
    block is refused, naming --block and the longest allowed, and nothing is written."""
    from tapmuscle.cli.main import main
    from tapmuscle.io.plant_file import plant_file_text
    from tapmuscle.io.recording import Recording, write_recording

    cols = record(DEMO_MODEL, "sine", 1)  # 150 s
    write_recording(tmp_path / "rec.csv", Recording({k: cols[k] for k in ("t_s", "u_v", "l_mm")}, {"ts_s": "0.1"}))
    (tmp_path / "plant.json").write_text(plant_file_text(DEMO_MODEL, "test"))
    out = tmp_path / "out"
    assert main(["diagnose", "--recording", str(tmp_path / "rec.csv"), "--plant", str(tmp_path / "plant.json"),
                 "--out", str(out), "--block", block, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--block" in err and "at most 37.5 s" in err and "Traceback" not in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_blocks_shorter_than_the_sampling_period_are_refused(tmp_path, capsys):
    """Blocks shorter than the period skip block numbers: at 1-s sampling and 0.5-s blocks every sample
    would fall in an even (training) block, nothing would be held out, and every fit would be NaN (a 100-s period
    with the default 10-s blocks would crash the JSON so after a 10-min run). Refused, naming both; the
    default block is never shorter than the period."""
    from tapmuscle.cli.main import main
    from tapmuscle.diagnosis.diagnose import split_length_s, validated_recording
    from tapmuscle.io.plant_file import plant_file_text
    from tapmuscle.io.recording import Recording, write_recording

    cols = record(DEMO_MODEL, "sine", 1, duration_s=400.0)
    slow = {k: cols[k][::10] for k in ("t_s", "u_v", "l_mm")}  # 1-s sampling, 401 samples
    write_recording(tmp_path / "rec.csv", Recording(slow))
    (tmp_path / "plant.json").write_text(plant_file_text(DEMO_MODEL, "test"))
    out = tmp_path / "out"
    assert main(["diagnose", "--recording", str(tmp_path / "rec.csv"), "--plant", str(tmp_path / "plant.json"),
                 "--out", str(out), "--block", "0.5", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--block) = 0.5 s is shorter than the sampling period 1 s" in err and "Traceback" not in err
    assert not out.exists()
    # a foreign FMU may be sampled more slowly than the default block: then one sample per block
    t = np.arange(400) * 20.0
    u = np.sin(t / 300.0)
    validated_recording(t, u, u, None)
    assert split_length_s(u, 20.0, None) == 20.0 and split_length_s(slow["u_v"], 1.0, None) == 10.0


def _sine_recording(n, ts_s):
    t = np.arange(n) * ts_s
    return t, 5.0 + 3.0 * np.sin(2 * np.pi * 0.1 * t)


def test_a_short_recording_is_refused_naming_its_file_before_any_progress(tmp_path, capsys):
    """``tapmuscle diagnose`` on a 30-s recording must not print "diagnose: 0% (0/9, 0.0 s)" before the refusal,
    nor tm.diagnose_files refuse it without naming the file the command line names."""
    from tapmuscle.diagnosis.report import diagnose_files
    from tapmuscle.io.plant_file import plant_file_text
    from tapmuscle.io.recording import Recording, write_recording

    t, u = _sine_recording(301, 0.1)
    rec = tmp_path / "m30.csv"
    write_recording(rec, Recording({"t_s": t, "u_v": u, "l_mm": 40.0 + 10.0 * np.sin(t)}, {"ts_s": "0.1"}))
    plant = tmp_path / "plant.json"
    plant.write_text(plant_file_text(DEMO_MODEL, "test"))
    with pytest.raises(ValueError, match=rf"^{re.escape(str(rec))}: the recording lasts 30 s .* at most 7.5 s$"):
        diagnose_files(rec, plant, tmp_path / "api", progress=True, plots=False)
    assert capsys.readouterr().err == ""
    assert main(["diagnose", "--recording", str(rec), "--plant", str(plant), "--out", str(tmp_path / "cli")]) == 2
    err = capsys.readouterr().err
    assert err == f"tapmuscle diagnose: error: {rec}: the recording lasts 30 s (301 samples at 0.1 s); " \
                  "the diagnosis needs at least 40 s with its default 10-s blocks (two training and two held-out " \
                  "blocks at least); shorter blocks (block_s, --block) lower that to four times their length: this " \
                  "recording takes blocks of at most 7.5 s\n"
    assert not (tmp_path / "api").exists() and not (tmp_path / "cli").exists()


@pytest.mark.parametrize("flag, value, pattern", [
    ("--effects", "", "--effects '' names no effect"),
    ("--effects", " , ", "names no effect"),
    ("--excitations", "", "--excitations '' names no excitation"),
    ("--effects", "gravity", "unknown effect 'gravity'"),
])
def test_demo_mismatch_refuses_an_empty_or_unknown_list(tmp_path, capsys, flag, value, pattern):
    """An empty --effects must not run every effect: refused before any work, nothing written."""
    from tapmuscle.cli.main import main

    out = tmp_path / "demo"
    assert main(["demo-mismatch", "--suite", "concealed", "--out", str(out), flag, value, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert pattern in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_effects_and_constants_are_chosen_by_name_or_object():
    """A name, a list of names or of objects: the same selection; a single name is one name, not its
    letters; what is neither is named before any fit."""
    from tapmuscle.diagnosis.catalogue import by_name

    delay, play = candidate("transport_delay"), candidate("backlash")
    assert by_name("transport_delay", CANDIDATES, "candidates", "effect") == [delay]
    assert by_name(["transport_delay", play], CANDIDATES, "candidates", "effect") == [delay, play]
    assert by_name(("valve.cv_max",), NOMINAL_PARAMETERS, "calibration", "nominal parameter") == [NOMINAL_PARAMETERS[0]]
    cols = record(DEMO_MODEL, "sine", 2)
    args = (cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL)
    with pytest.raises(ValueError, match=r"candidates: unknown effect 'delay'; known: rate_dependent_hysteresis, "):
        diagnose(*args, candidates=["delay"])
    with pytest.raises(ValueError, match=r"calibration: unknown nominal parameter 'none' \(unknown plant parameter 'none' "
                                         r"\(expected 'group.field', .*the default ones: valve.cv_max, .*"
                                         r"calibration=None: no calibration"):
        diagnose(*args, calibration="none")
    with pytest.raises(ValueError, match=r"calibration: 'delay.delay_s' is a parameter of an effect \(delay\)"):
        diagnose(*args, calibration=["valve.cv_max", "delay.delay_s"])
    with pytest.raises(TypeError, match=r"candidates: int 3 must be a Candidate or the name of one"):
        diagnose(*args, candidates=[delay, 3])


def test_a_constant_displacement_is_named_before_any_fit():
    """A disconnected encoder (l_mm constant) must not end in 'DeadZoneParams.width_v must be <= 5.0'."""
    cols = record(DEMO_MODEL, "sine", 2)
    with pytest.raises(ValueError, match=r"column l_mm: the displacement is constant \(3 mm\)"):
        diagnose(cols["t_s"], cols["u_v"], np.full_like(cols["l_mm"], 3.0), DEMO_MODEL)


def test_the_dead_zone_search_never_proposes_a_band_wider_than_the_plant_takes():
    """Held commands 2 V apart: four consecutive levels span 6 V, beyond the 5-V bound of
    ``dead_zone.width_v``. Such bands are skipped (tried, they would raise the plant's ValueError)."""
    from fmu_plant import Plant, PlantParams
    from fmu_plant.open_loop import run_open_loop
    from tapmuscle.diagnosis.candidates import Problem
    from tapmuscle.diagnosis.residual_analysis import white_noise_level_mm
    from tapmuscle.diagnosis.simulation import Simulator

    levels = (0.5, 2.5, 4.5, 6.5, 8.5, 6.5, 4.5, 2.5)
    rig = DEMO_MODEL.with_values(**{"dead_zone.center_v": 6.5, "dead_zone.width_v": 1.0})
    cols = run_open_loop(Plant(rig, seed=3), lambda t: levels[int(t // 5.0) % len(levels)], duration_s=120.0, ts_s=0.1)
    sim = Simulator(cols["u_v"], 0.1)
    y0 = sim.run(DEMO_MODEL, checkpoint_every=100)[0]
    train, test = interleaved_split(len(y0), 0.1, 10.0)
    problem = Problem(cols["l_mm"], cols["t_s"], cols["u_v"], 0.1, train, test, sim,
                      white_noise_level_mm(cols["l_mm"] - y0))
    assert len(np.unique(cols["u_v"])) == 5
    res = candidate("valve_dead_zone").fit(problem, DEMO_MODEL, y0)
    assert res is not None
    assert 0.0 < res.values["dead_zone.width_v"] <= PlantParams.bounds("dead_zone.width_v")[1]
    # the band holds the 6.5-V level and no other, as the rig's does
    lo = res.values["dead_zone.center_v"] - res.values["dead_zone.width_v"] / 2
    hi = res.values["dead_zone.center_v"] + res.values["dead_zone.width_v"] / 2
    assert [v for v in sorted(set(levels)) if lo < v < hi] == [6.5]


@pytest.mark.slow
def test_a_play_the_calibration_absorbed_is_found_by_the_joint_fit_the_score_test_ranks_in():
    """Field case 013 (seed 0): a 1.63-mm play on a rig with five constants off by 6-16 %. The
    calibration trades the play for friction (presliding 1.5 -> 0.3 mm), a play fitted on those
    constants as they stand comes out near zero, and without the score test's ranking the play would never get
    a joint fit: nothing would be named (98.6 % held-out fit). Judged by what the constants' linearised
    re-fit leaves, the own search finds more of it, still well short of the rig's; the joint fit
    finds the rest."""
    from tapmuscle.diagnosis.field_cases import field_cases, record_case

    case = field_cases(100, 0)[13]
    assert case.effects == ("backlash",)
    true_slack = dict(case.effect_values)["backlash.slack_mm"]
    cols = record_case(case)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], case.model(), load_n=cols["load_n"])
    tried = d.to_json()["candidates_tried"]
    own = next(t for t in tried if t["effect"] == "backlash" and not t.get("joint"))
    # absorbed in large part: what the ranking has to see past
    assert own["parameters"]["backlash.slack_mm"] < 0.5 * true_slack
    assert own["score_test_gain_mm2"] > 0.0 and own["linearised_gain_mm2"] > 0.0
    assert d.named == ["backlash"] and not d.ambiguous
    # the joint fit's play: within 15 % of the rig's (the friction constants it trades with stay uncertain)
    assert d.findings[0].parameters["backlash.slack_mm"] == pytest.approx(true_slack, rel=0.15)
    # the words state the value reported, which is the final joint fit's
    assert d.findings[0].explanation == candidate("backlash").explain(d.findings[0].parameters)
    assert d.fit_after_percent >= 99.0


def _stored_field_case(seed: int, index: int, tmp_path: Path):
    """Field case ``index`` of ``field_cases(100, seed)`` diagnosed as ``tapmuscle demo-mismatch`` does
    (the recording and the nominal plant through their files), from its stored recording in
    ``tests/field_recordings/``: a closed loop's recording made on another floating-point path is
    another recording (the AMPC's last bits, amplified by the loop), while the diagnosis of one
    recording is the same on every path. Returns the case, ``diagnosis.json`` and the truth's own
    held-out fit (its noise-free run on the recorded command, as the field demo scores it)."""
    from tapmuscle.diagnosis.field_cases import effect_costs, field_cases
    from tapmuscle.diagnosis.report import diagnose_files
    from tapmuscle.io.plant_file import plant_file_text
    from tapmuscle.io.recording import read_recording

    case = field_cases(100, seed)[index]
    rec = Path(__file__).parent / "field_recordings" / f"seed{seed}_{case.name}.csv"
    plant = tmp_path / "plant.json"
    plant.write_text(plant_file_text(case.model(), "the nominal model of the field demo"))
    doc = diagnose_files(rec, plant, tmp_path / "out", plots=False)[1]
    return case, doc, effect_costs(case, read_recording(rec).columns, None)["fit_truth_percent"]


@pytest.mark.slow
def test_a_play_in_the_closed_loop_is_named_before_a_map_can_mimic_it(tmp_path):
    """Field case 081 (seed 0): a 1.93-mm play in the closed loop, constants off, diagnosed as
    ``tapmuscle demo-mismatch`` does (the recording and the nominal plant through their files). With
    the play's own search judged on the calibrated constants as they stand, an amplifier map would be
    accepted first (it mimics part of the play), the play in the second round, and the backward step
    would drop the map. Judged by what the constants' linearised re-fit leaves, the play is accepted in
    the first round and named alone at the truth's own held-out fit; no map is ever accepted.

    The recording is the stored one (``tests/field_recordings/``): a closed loop's recording made on
    another floating-point path is another recording (the AMPC's last bits, amplified by the loop).
    The diagnosis of one recording is the same on every path."""
    case, doc, fit_truth = _stored_field_case(0, 81, tmp_path)
    assert case.effects == ("backlash",) and case.excitation == "ampc"
    added = [s for s in doc["selection"] if s["step"] == "add"]
    assert [(s["round"], s["effect"]) for s in added] == [(1, "backlash")], doc["selection"]
    assert [f["effect"] for f in doc["findings"]] == ["backlash"] and not doc["ambiguous"], doc["findings"]
    slack = doc["findings"][0]["parameters"]["backlash.slack_mm"]
    assert slack == pytest.approx(dict(case.effect_values)["backlash.slack_mm"], rel=0.2)
    assert doc["fit_after_percent"] >= fit_truth - 0.1


@pytest.mark.slow
def test_an_effect_that_a_later_one_explains_is_dropped(tmp_path):
    """Field case 030 (seed 0): a rate dependence (gain 1.27) in the closed loop, constants off,
    diagnosed as ``tapmuscle demo-mismatch`` does. An amplifier map mimics most of it on the
    constants calibrated at the first noise level and is accepted first (``ambiguous`` with the rate
    dependence in that round); the rate dependence is accepted in the next round, and the backward
    step finds that the map's removal no longer costs a significant share of the held-out error, and
    drops it (its finding and its parameters leave the model). What stays is the rate dependence
    alone, at the truth's own held-out fit. From the stored recording (:func:`_stored_field_case`)."""
    case, doc, fit_truth = _stored_field_case(0, 30, tmp_path)
    assert case.effects == ("rate_dependent_hysteresis",) and case.excitation == "ampc"
    steps = doc["selection"]
    added = {s["effect"]: s["round"] for s in steps if s["step"] == "add"}
    dropped = [s for s in steps if s["step"] == "drop"]
    assert len(dropped) == 1, steps
    gone = dropped[0]["effect"]
    # the dropped effect was accepted before the one that explains it, and its removal gives back
    # less than the acceptance rule's 10 % of the held-out error
    assert gone != "rate_dependent_hysteresis" and added[gone] < added["rate_dependent_hysteresis"], steps
    assert dropped[0]["held_out_sse_reduction_it_gave"] < 0.10
    assert [f["effect"] for f in doc["findings"]] == ["rate_dependent_hysteresis"] and not doc["ambiguous"]
    gain = doc["findings"][0]["parameters"]["friction.rate_gain"]
    assert gain == pytest.approx(dict(case.effect_values)["friction.rate_gain"], rel=0.15)
    assert doc["fit_after_percent"] >= fit_truth - 0.1
    # the calibrated plant file holds the dropped effect switched off (the rate dependence is a
    # friction parameter, not one of the library's switched effects)
    from fmu_plant.effect_library import effects_from_params
    from tapmuscle.io.plant_file import read_plant_file
    calibrated = read_plant_file(tmp_path / "out" / "calibrated_plant.json", "--plant")
    assert effects_from_params(calibrated) == [] and calibrated.friction.rate_gain == pytest.approx(gain)

@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError, reason="since the noise level is taken again from the second round on, "
                   "the constants recalibrated at it absorb part of this map and it is no longer accepted, so "
                   "the level to remove is not reached; the case is listed in docs/diagnosis.md's field results")
def test_an_accepted_effect_stays_unless_its_removal_is_clearly_insignificant(tmp_path):
    """Field case 052 (seed 1), as ``tapmuscle demo-mismatch`` runs it (the recording and the plant
    through their files): a 0.26-s transport delay and an amplifier map under a sine-sum, constants
    off. Both are accepted; in the backward step the map's removal costs 46 % of the held-out error,
    at p = 3.8e-3 here: not significant at the entry level 1e-3, significant at the level to remove,
    ``REMOVE_LEVEL_FACTOR`` x 1e-3. So the map stays, and both effects are named. (With the level to
    remove equal to the entry level the map is dropped and the delay is named alone, fit 99.16 %
    against 99.38 %.)"""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 1)[52]
    assert set(case.effects) == {"transport_delay", "input_map"}
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    assert {"transport_delay", "input_map"} <= set(result["named"]), doc["selection"]
    assert not [s for s in doc["selection"] if s["step"] == "drop" and s["effect"] == "input_map"]
    delay = dict(case.effect_values)["delay.delay_s"]
    found = next(f for f in doc["findings"] if f["effect"] == "transport_delay")["parameters"]["delay.delay_s"]
    assert found == pytest.approx(delay, rel=0.2)  # 0.225 s here: the map's offset trades with it
    assert result["fit_after_percent"] >= 99.0


@pytest.mark.slow
def test_an_effect_accepted_at_the_inflated_noise_level_must_beat_the_constants_calibrated_at_the_lower_one(tmp_path):
    """Field case 065 (seed 1): an encoder drift and an amplifier map under steps, constants off.
    The map is found first; a rate dependence is then accepted against the constants calibrated at
    the inflated noise level (21 % of the held-out error, a delay its alternative). Calibrated afresh
    at the better model's level, more constants are identifiable, and against them the rate
    dependence removes only 7 % of the held-out error, under the 10-% minimum: it is dropped, and
    the drift, which the rig has, is found after it (without this test the rate dependence would stay
    among the findings)."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 1)[65]
    assert case.effects == ("sensor_drift", "input_map") and case.excitation == "steps"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    steps = doc["selection"]
    i = next(k for k, s in enumerate(steps) if s["step"] == "noise level")
    assert steps[i - 1]["step"] == "add" and steps[i - 1]["effect"] == "rate_dependent_hysteresis", steps
    assert steps[i]["recalibrated"] and len(steps[i]["identifiable"]) > len(steps[0]["identifiable"])
    assert steps[i + 1]["step"] == "drop" and steps[i + 1]["effect"] == "rate_dependent_hysteresis"
    assert steps[i + 1]["held_out_sse_reduction_it_gave"] < 0.10
    assert "rate_dependent_hysteresis" not in result["named"] and "sensor_drift" in result["named"]


@pytest.mark.slow
def test_constants_that_explain_the_recording_at_their_own_noise_level_end_the_search(tmp_path):
    """Field case 049 (seed 0): no effect, five constants off, the closed loop. Calibrated at the
    nominal residual's level (0.195 mm) the constants leave a structured residual, and the search
    would then claim an ambiguous load or input map. Calibrated again at the level the calibrated
    residual shows (0.016 mm) they explain the recording: ``calibration_only``."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 0)[49]
    assert case.category == "none" and case.excitation == "ampc"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    first, again = doc["selection"][:2]
    assert first["step"] == "calibrate" and again["white"], doc["selection"]
    assert again["noise_mm"] < first["noise_mm"] / 2.0
    assert result["verdict"] == "calibration_only" and result["named"] == []
    assert result["fit_after_percent"] >= result["fit_truth_percent"] - 0.05


@pytest.mark.slow
def test_constants_put_back_at_an_inflated_noise_level_do_not_hide_a_calibration_that_explains_it_all(tmp_path):
    """Field case 003 (seed 2): no effect, six constants off, the closed loop. At the nominal
    residual's level (0.58 mm) the MAP fit with every constant free explains the training blocks to
    the encoder's noise, but only the threshold pressure passes as identifiable; the others put back,
    the calibrated plant fits 46 %, and a 0.75-s transport delay would be claimed (89.7 %). Calibrated
    again at the level the free MAP fit shows (the encoder's 0.01 mm), from that fit, the constants
    leave a white residual: ``calibration_only`` at the truth's own held-out fit."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 2)[3]
    assert case.category == "none" and case.excitation == "ampc"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    first, again = doc["selection"][:2]
    assert first["step"] == "calibrate" and first["fit_after_percent"] < 60.0, doc["selection"]
    assert again["from"] == "every constant free" and again["white"]
    assert again["noise_mm"] < first["noise_mm"] / 10.0
    assert len(again["identifiable"]) > len(first["identifiable"])
    assert result["verdict"] == "calibration_only" and result["named"] == []
    assert result["fit_after_percent"] >= result["fit_truth_percent"] - 0.05


@pytest.mark.slow
def test_the_noise_level_is_taken_again_from_the_better_models_residual(tmp_path):
    """Field case 063 (seed 0), as ``tapmuscle demo-mismatch`` runs it: a 0.17-s delay and a load
    14 N heavy in the closed loop, three constants off. Replaying the loop's command through the
    nominal model leaves a velocity error that changes from sample to sample, so the nominal
    residual's first-difference level is 7.4 mm, not the encoder's 0.01 mm. At that level the
    calibration pins almost nothing and the load's held-out test cannot pass; taken again from the
    residual once the delay is in the model, the constants are calibrated afresh and the load is
    found, to the truth's own held-out fit."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 0)[63]
    assert case.effects == ("transport_delay", "load_mismatch") and case.excitation == "ampc"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    steps = doc["selection"]
    assert steps[0]["step"] == "calibrate" and steps[0]["noise_mm"] > 1.0  # the inflated level
    levels = [s for s in steps if s["step"] == "noise level"]
    assert levels and levels[-1]["noise_mm"] < 0.05 and levels[-1]["recalibrated"], steps
    assert result["named"] == ["load_mismatch", "transport_delay"], steps
    truth = dict(case.effect_values)
    found = {k: v for f in doc["findings"] for k, v in f["parameters"].items()}
    assert found["delay.delay_s"] == pytest.approx(truth["delay.delay_s"], abs=0.02)  # 0.2 sample
    # the load trades with the constants (a threshold-pressure shift times the area), and the closed
    # loop's recording is made anew on each floating-point path (the AMPC's last bits, amplified by the
    # loop: displacements up to 28 mm apart): 13.5 N from this CPU's recording, 10.7 N from the one
    # made with OpenBLAS's Nehalem kernels, for 14.0 N
    assert found["load_mismatch.extra_n"] == pytest.approx(truth["load_mismatch.extra_n"], rel=0.3)
    # within 0.1 point of the truth's own held-out fit (99.94 %): what is left is the encoder's noise
    assert result["fit_after_percent"] >= result["fit_truth_percent"] - 0.1


@pytest.mark.slow
def test_an_amplifier_map_that_the_calibration_took_up_is_found_by_its_joint_re_fit(tmp_path):
    """Field case 067 (seed 0), as ``tapmuscle demo-mismatch`` runs it: an amplifier with gain 0.84
    and offset +0.48 V under a random input, constants off. The calibration takes most of it up (the
    flow coefficient, the threshold, the bladder), and the map's own search on the calibrated constants
    ends near the identity. Its four outputs are joint parameters, and its joint re-fit also starts
    from the identity (``MUSCLE.joint_starts``): that re-fit finds the amplifier, which is named alone
    at the truth's own held-out fit."""
    from fmu_plant.effect_library import input_map_v
    from fmu_plant.parameters import InputMapParams
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 0)[67]
    assert case.effects == ("input_map",) and case.excitation == "random"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    tried = [t for t in doc["candidates_tried"] if t["effect"] == "input_map" and t["round"] == 1]
    own = next(t for t in tried if not t.get("joint"))
    joint = next(t for t in tried if t.get("joint"))
    # on the calibrated constants the map's own fit stays near the identity (10 V acts as > 9.5 V; the
    # amplifier gives 8.9 V) and its held-out gain could not be claimed; the joint re-fit's can
    assert own["parameters"]["input_map.out_at_10_v"] > 9.5 and own["held_out_sse_reduction"] < 0.1
    assert joint["held_out_sse_reduction"] > 0.5 and joint["p_value"] < 1e-3
    assert result["named"] == ["input_map"] and not result["ambiguous"], doc["selection"]

    def mapped(values: dict[str, float]) -> np.ndarray:
        m = InputMapParams(**{k.partition(".")[2]: v for k, v in values.items() if k.startswith("input_map.")})
        return np.array([input_map_v(u, m) for u in (0.0, 2.5, 5.0, 7.5, 10.0)])
    found = next(f["parameters"] for f in doc["findings"] if f["effect"] == "input_map")
    # the map within 0.05 V over the command range (a gain error of 0.5 % at 10 V)
    assert mapped(found) == pytest.approx(mapped(dict(case.effect_values)), abs=0.05)
    assert result["fit_after_percent"] >= result["fit_truth_percent"] - 0.1


@pytest.mark.slow
def test_a_rate_dependence_that_the_friction_level_took_up_is_found_by_its_joint_starts(tmp_path):
    """Field case 072 (seed 0), as ``tapmuscle demo-mismatch`` runs it: a rate gain of 0.88 under a
    sine, four constants off. Calibrated without it, the friction's level rises to what the sine's
    speeds need, and the rate gain re-fitted from its own fit on those constants stops at about a
    quarter of the truth, where an amplifier's map fits the held-out blocks as well (without the
    starts the verdict is ``ambiguous``). The rate's joint re-fit also starts from gains either way of 0.8
    (``MUSCLE.joint_starts``): that re-fit is the better one, and the rate dependence is named alone."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 0)[72]
    assert case.effects == ("rate_dependent_hysteresis",) and case.excitation == "sine"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    assert result["named"] == ["rate_dependent_hysteresis"] and not result["ambiguous"], doc["selection"]
    found = next(f["parameters"] for f in doc["findings"] if f["effect"] == "rate_dependent_hysteresis")
    truth = dict(case.effect_values)["friction.rate_gain"]
    # the gain to 10 % (the final joint re-fit's, with the constants given back their friction level)
    assert found["friction.rate_gain"] == pytest.approx(truth, rel=0.1)
    assert result["fit_after_percent"] >= result["fit_truth_percent"] - 0.1


@pytest.mark.slow
def test_a_valve_bands_width_is_profiled_with_the_constants_refitted(tmp_path):
    """Field case 083 (seed 0), as ``tapmuscle demo-mismatch`` runs it: a valve band 1.18 V wide at
    5.10 V under a sine, three constants off. The calibration, made before the band is found, bends
    the bladder stiffness and the flow coefficient to mimic part of the stall, and the band's own
    search on those constants finds it 0.64 V wide (held-out fit 96.4 %). Profiled with the constants
    re-fitted at each width (``MUSCLE.profiled``), it comes out at its true width and the fit reaches
    the noise floor's neighbourhood."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 0)[83]
    assert case.effects == ("valve_dead_zone",)
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    assert result["named"] == ["valve_dead_zone"], doc["selection"]
    assert any(s["step"] == "profile with the constants re-fitted" and s["kept"] for s in doc["selection"])
    truth = dict(case.effect_values)
    band = next(f for f in doc["findings"] if f["effect"] == "valve_dead_zone")["parameters"]
    assert band["dead_zone.width_v"] == pytest.approx(truth["dead_zone.width_v"], rel=0.1)
    assert band["dead_zone.center_v"] == pytest.approx(truth["dead_zone.center_v"], abs=0.1)
    assert result["fit_after_percent"] >= 98.5


@pytest.mark.slow
def test_a_band_is_searched_again_on_constants_calibrated_from_nominal(tmp_path):
    """Field case 027 (seed 1), as ``tapmuscle demo-mismatch`` runs it: a valve band 1.24 V wide at
    6.28 V under a sine, constants off. The constants calibrated before the band was found took part
    of its stall up, and the profile's re-fits start from them: the verdict would be ``ambiguous`` between
    the band, an amplifier's map and a drift. The band's search alternated with the calibration from
    the nominal constants (``FROM_NOMINAL_ROUNDS``) leaves that valley, and the band is named alone."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 1)[27]
    assert case.effects == ("valve_dead_zone",) and case.excitation == "sine"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    assert result["named"] == ["valve_dead_zone"] and not result["ambiguous"], doc["selection"]
    assert any(s["step"] == "search and calibrate from the nominal constants" and s["kept"] for s in doc["selection"])
    truth = dict(case.effect_values)
    band = next(f for f in doc["findings"] if f["effect"] == "valve_dead_zone")["parameters"]
    # the edges to 0.1 V: the sine sweeps every command, so the band's edges are between close cuts
    assert band["dead_zone.width_v"] == pytest.approx(truth["dead_zone.width_v"], abs=0.1)
    assert band["dead_zone.center_v"] == pytest.approx(truth["dead_zone.center_v"], abs=0.1)


@pytest.mark.slow
def test_constants_implausible_under_their_prior_are_calibrated_again_from_nominal_with_the_effects(tmp_path):
    """Field case 087 (seed 3), as ``tapmuscle demo-mismatch`` runs it: a 0.23-s delay and a supply
    sag under a sine-sum, constants off. The constants calibrated before either effect was in the
    model take the sag up far beyond their prior (prior cost 40 over 7 constants, where the
    chi-square tail at ``alpha`` begins at 24); the delay's search on them, after the sag was
    accepted, would find nothing that passed, and the fit would stay at 86 %. Calibrated again from the
    nominal constants with the sag on (the sag searched again on them), the model fits the training
    blocks better, is kept, and the delay is found in the next round."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 3)[87]
    assert case.effects == ("transport_delay", "supply_pressure_variation") and case.excitation == "sinesum"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    steps = doc["selection"]
    assert steps[0]["prior_cost"] > stats.chi2.isf(1e-3, len(steps[0]["identifiable"]))
    assert any(s["step"] == "search and calibrate from the nominal constants" and s["round"] == 1 and s["kept"]
               for s in steps), steps
    assert sorted(result["named"]) == ["supply_pressure_variation", "transport_delay"], steps
    delay = next(f for f in doc["findings"] if f["effect"] == "transport_delay")["parameters"]["delay.delay_s"]
    # to a tenth of a sample: a sine-sum's phases pin a delay far finer than the sampling
    assert delay == pytest.approx(dict(case.effect_values)["delay.delay_s"], abs=0.01)
    # the sag's fall lies in a training block and its recovery is a sharp step the muscle's memory
    # shows in the next one: held out, the fit is near the noise floor (86 % without the calibration
    # again from nominal)
    assert result["fit_after_percent"] >= 99.0


@pytest.mark.slow
def test_a_band_the_calibrated_constants_took_up_is_found_by_what_their_re_fit_leaves(tmp_path):
    """Field case 079 (seed 1), as ``tapmuscle demo-mismatch`` runs it: a valve band 0.91 V wide at
    5.62 V under a sine sum, constants off (braid angle +14 %). Judged on the calibrated constants as
    they stand, the band's own search finds 0.18 V at 3.25 V: the band would never be accepted, an
    amplifier's map would be named instead and the held-out fit would stay at 90.5 %. Judged by what the
    constants' linearised re-fit leaves, the first round's search finds the band, and it is named."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 1)[79]
    assert case.effects == ("valve_dead_zone",) and case.excitation == "sinesum"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    own = next(t for t in doc["candidates_tried"]
               if t["round"] == 1 and t["effect"] == "valve_dead_zone" and not t.get("joint"))
    assert own["linearised_gain_mm2"] > 0.0
    truth = dict(case.effect_values)
    lower = truth["dead_zone.center_v"] - truth["dead_zone.width_v"] / 2
    upper = lower + truth["dead_zone.width_v"]
    found = own["parameters"]
    # the edges to 0.05 V: the sine sum sweeps the commands densely (cuts ~0.01 V apart near the band);
    # the plain search's band would be 2 V away
    assert found["dead_zone.center_v"] - found["dead_zone.width_v"] / 2 == pytest.approx(lower, abs=0.05)
    assert found["dead_zone.center_v"] + found["dead_zone.width_v"] / 2 == pytest.approx(upper, abs=0.05)
    assert {"step": "add", "round": 1, "effect": "valve_dead_zone"}.items() <= next(
        s for s in doc["selection"] if s["step"] == "add").items()
    assert "valve_dead_zone" in result["named"]
    assert result["fit_after_percent"] >= 98.0


@pytest.mark.slow
def test_a_band_under_held_random_levels_is_found_whole(tmp_path):
    """Field case 046 (seed 1), as ``tapmuscle demo-mismatch`` runs it: a valve band 1.04 V wide at
    5.87 V under random held levels, constants off. The compass search on the band's edges alone stops on
    its top 0.49 V (a band holding part of the rig's stalls the muscle where the rig moves, and one
    more level costs before the rest pays back): held-out fit 85.8 %. With each edge also scanned over
    every recorded level, the band is found whole and named alone."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 1)[46]
    assert case.effects == ("valve_dead_zone",) and case.excitation == "random"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    assert result["named"] == ["valve_dead_zone"] and not result["ambiguous"], doc["selection"]
    truth = dict(case.effect_values)
    band = next(f["parameters"] for f in doc["findings"] if f["effect"] == "valve_dead_zone")
    # the edges to 0.1 V: about 70 random levels over the command's range, ~0.05 V apart
    for sign in (-1.0, 1.0):
        assert band["dead_zone.center_v"] + sign * band["dead_zone.width_v"] / 2 == pytest.approx(
            truth["dead_zone.center_v"] + sign * truth["dead_zone.width_v"] / 2, abs=0.1)
    assert result["fit_after_percent"] >= 99.0


@pytest.mark.slow
def test_a_band_edge_among_held_out_levels_is_set_midway(tmp_path):
    """Field case 041 (seed 1), as ``tapmuscle demo-mismatch`` runs it: a valve band 0.85 V wide at
    4.52 V and a sensor drift of -0.98 mm/min under random held levels, constants off. Between the
    training blocks' levels 4.012 and 4.151 V around the band's lower edge (4.097 V) lie two held-out
    ones, 4.044 and 4.108 V. The band's search stops at 4.028 V, where the 4.044-V level's stall would cost the
    band its held-out test, and nothing would be named (83.7 %). Set midway between the training levels,
    the edge puts both held-out levels on the rig's side; band and drift are named, nothing else."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case
    from tapmuscle.io.recording import read_recording

    case = field_cases(100, 1)[41]
    assert set(case.effects) == {"valve_dead_zone", "sensor_drift"} and case.excitation == "random"
    result = run_field_case(case, tmp_path, keep=True)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    assert sorted(result["named"]) == ["sensor_drift", "valve_dead_zone"] and not result["ambiguous"], doc["selection"]
    truth = dict(case.effect_values)
    band = next(f["parameters"] for f in doc["findings"] if f["effect"] == "valve_dead_zone")
    u = read_recording(tmp_path / case.name / "recording.csv").columns["u_v"]
    train, test = interleaved_split(len(u), 0.1, 10.0)
    rig_lo = truth["dead_zone.center_v"] - truth["dead_zone.width_v"] / 2
    lo = band["dead_zone.center_v"] - band["dead_zone.width_v"] / 2
    trained = np.unique(u[train])
    a, b = trained[trained < rig_lo].max(), trained[trained > rig_lo].min()
    assert lo == pytest.approx(0.5 * (a + b), abs=1e-3)  # the levels to 1 mV, as the search takes them
    held_out = np.unique(u[test & (u > a) & (u < b)])
    assert held_out.size >= 1
    assert np.array_equal(held_out > lo, held_out > rig_lo)
    assert result["fit_after_percent"] >= 99.0


@pytest.mark.slow
def test_a_band_is_searched_again_when_the_constants_are_calibrated_afresh(tmp_path):
    """Field case 010 (seed 0), as ``tapmuscle demo-mismatch`` runs it: a valve band 1.26 V wide at
    4.19 V and a 0.21-s delay under a sine sum, constants off. Once the delay is in, the noise level
    drops (0.075 -> 0.015 mm) and the constants are calibrated afresh at it, with the band as fitted
    at the higher level; the band's search alternated with the calibration from the nominal
    constants then fits the training blocks better and is kept. Both effects are named, and nothing
    else (a spurious map would stand beside them were the band's search not judged by the constants'
    linearised step)."""
    from tapmuscle.diagnosis.field_cases import field_cases
    from tapmuscle.diagnosis.field_demo import run_field_case

    case = field_cases(100, 0)[10]
    assert set(case.effects) == {"valve_dead_zone", "transport_delay"} and case.excitation == "sinesum"
    result = run_field_case(case, tmp_path)
    doc = json.loads((tmp_path / case.name / "diagnosis.json").read_text())
    assert sorted(result["named"]) == ["transport_delay", "valve_dead_zone"] and not result["ambiguous"], doc["selection"]
    sel = doc["selection"]
    renoised = [k for k, s in enumerate(sel) if s["step"] == "noise level" and s.get("recalibrated")]
    assert renoised, sel
    assert any(s["step"] == "search and calibrate from the nominal constants" and s["kept"] for s in sel[renoised[0]:]), sel
    truth = dict(case.effect_values)
    found = {k: v for f in doc["findings"] for k, v in f["parameters"].items()}
    # the sine sum sweeps the commands densely: the band's edges to 0.1 V; the delay to a sample
    assert found["dead_zone.center_v"] == pytest.approx(truth["dead_zone.center_v"], abs=0.1)
    assert found["dead_zone.width_v"] == pytest.approx(truth["dead_zone.width_v"], abs=0.1)
    assert found["delay.delay_s"] == pytest.approx(truth["delay.delay_s"], abs=0.01)
    assert result["fit_after_percent"] >= 99.0


def test_the_report_lists_a_joint_re_fit_that_failed_with_its_reason(tmp_path):
    """A joint re-fit whose simulation failed is a row of the candidates table with the reason, and the
    numbers the acceptance rests on are in every other joint row of diagnosis.json."""
    from tapmuscle.diagnosis.report import write_outputs

    cols = record(DEMO_MODEL.with_values(**{"delay.delay_s": 0.3}), "sine", 5, duration_s=60.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL, calibration=())
    joint = [c for c in d.candidates if c.get("joint")]
    assert joint and all(c["contribution_rms_mm"] >= 0.0 for c in joint)
    d.candidates.append({"round": 1, "effect": "backlash", "joint": True, "rejected": "the plant diverged",
                         "simulations": 3, "seconds": 0.1})
    write_outputs(d, tmp_path, recording="rec.csv", plant="plant.json", plots=False)
    assert "| 1 | `backlash` re-fitted with the calibration | not fitted (the plant diverged) | | |" in \
        (tmp_path / "report.md").read_text()


def test_diagnose_names_bad_arguments_before_any_work():
    """A pressure column of another length must not crash after the calibration with a numpy IndexError, nor
    a fit segment of 0 s name a wrong effect silently; alpha and max_effects are checked too."""
    from fmu_plant import PlantParams

    t = np.arange(600) * 0.1
    u = 5.0 + 3.0 * np.sin(2 * np.pi * 0.1 * t)
    l = 40.0 + 30.0 * np.sin(2 * np.pi * 0.1 * t - 0.5)
    for kwargs, message in (({"p_mpa": np.zeros(599)}, r"p_mpa has shape \(599,\), t_s \(600,\)"),
                            ({"fit_segment_s": 0.0}, "fit_segment_s must be a number of seconds > 0, got 0.0"),
                            ({"fit_segment_s": float("nan")}, "fit_segment_s must be"),
                            ({"alpha": 2.0}, r"alpha \(the significance level\) must be in 0..1"),
                            ({"max_effects": -1}, "max_effects must be an integer >= 0, got -1")):
        with pytest.raises(ValueError, match=message):
            diagnose(t, u, l, PlantParams(), **kwargs)
    with pytest.raises(ValueError, match=r"column l_mm must be one-dimensional \(one value per sample\), got shape "
                                         r"\(600, 1\)"):
        diagnose(t, u, l[:, None], PlantParams())


def test_the_final_model_leaves_the_valley_the_search_left_it_in(tmp_path):
    """A rig with six constants 10-17 % off, a 0.25-s delay and a drift (noise seed 5), diagnosed with
    the vocabulary restricted to those two effects (as for a discriminating experiment's
    re-diagnosis): both named, but the constants would stay in the valley of the first calibration, the
    final simulation's squared error 2.83 mm^2 against the true rig's 0.26. A final model whose
    residual is still structured is calibrated afresh from the nominal constants with the effects on
    (kept as it fits the training blocks better): 0.27 mm^2."""
    import tapmuscle as tm
    from fmu_plant import Plant, PlantParams

    rig = PlantParams().with_values(**{
        "valve.cv_max": 1.28, "muscle.rubber_stiffness_n_per_mm": 1.4, "muscle.threshold_pressure_mpa": 0.046,
        "friction.base_n": 9.3, "friction.per_mpa_n": 25.5, "supply.compliance_m3_per_mpa": 1.15e-05,
        "delay.delay_s": 0.25, "sensor_drift.rate_mm_per_min": 0.4})
    r = tm.simulate("random:lo=2,hi=8,hold_min=2,hold_max=8,seed=5", duration_s=240.0, ts_s=0.1, params=rig, seed=5)
    tm.write_recording(tmp_path / "rig.csv", tm.Recording({k: r[k] for k in ("t_s", "u_v", "l_mm", "p_mpa")},
                                                          {"ts_s": "0.1", "load_n": "44"}))
    (tmp_path / "nominal.json").write_text('{"plant": {}}')
    d, _ = tm.diagnose_files(tmp_path / "rig.csv", tmp_path / "nominal.json", tmp_path / "out", plots=False,
                             effects=["transport_delay", "sensor_drift"])
    assert {f.effect for f in d.findings} == {"transport_delay", "sensor_drift"}

    def sse(params):  # of the noise-free simulation against the recording
        clean = params.with_values(**{"sensor.encoder_noise_std_mm": 0.0, "sensor.encoder_resolution_mm": 0.0})
        l, _ = Plant(clean, seed=0).step_many(r["u_v"], 0.1)
        return float(np.sum((r["l_mm"][1:] - l[:-1]) ** 2))

    assert sse(d.calibrated) < 1.5 * sse(rig)
    assert any(s["step"] == "search and calibrate from the nominal constants" and s["kept"] for s in d.selection)


def test_the_calibrated_plant_carries_the_recordings_load():
    """A recording at another load than the plant file's is re-simulated at the recording's, and the
    calibrated plant says so: ``load.load_n`` is the recording's where one number can hold it (a
    constant load), else the plant's with a note; the same load needs no note."""
    rig = DEMO_MODEL.with_values(**{"load.load_n": 68.0})
    cols = record(rig, "steps", 0)
    assert np.all(cols["load_n"] == 68.0)
    heavy = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL, load_n=cols["load_n"],
                     candidates=[], calibration=None)
    assert DEMO_MODEL.load.load_n == 44.0 and heavy.calibrated.load.load_n == 68.0
    assert any("load is 68 N, the plant's 44 N" in n for n in heavy.notes), heavy.notes
    # the re-simulation was at 68 N: the exact rig at its load is within the noise
    assert heavy.verdict == "no_significant_mismatch" and heavy.fit_after_percent > 99.0
    same = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], rig, load_n=68.0, candidates=[], calibration=None)
    assert same.calibrated.load.load_n == 68.0 and not any("load" in n for n in same.notes), same.notes
    varying = cols["load_n"].copy()
    varying[len(varying) // 2:] = 70.0
    mixed = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], rig, load_n=varying, candidates=[], calibration=None)
    assert mixed.calibrated.load.load_n == 68.0
    assert any("load varies (68..70 N)" in n for n in mixed.notes), mixed.notes


def _named_or_alternative(d) -> set[str]:
    return set(d.named) | {a.effect for g in d.ambiguous for a in g}


@pytest.mark.slow
@pytest.mark.parametrize("supply_mpa", [0.22, 0.30])
def test_a_supply_at_another_constant_pressure_is_named_with_its_pressure_not_as_a_load(supply_mpa):
    """A building's supply at another constant pressure than the plant file's, on a rig whose constants
    are off too: named as the supply offset (alone, or with the alternatives the held-out data cannot
    tell from it) at the rig's pressure, not as a load the muscle does not carry with the flow
    coefficient recalibrated to take up the rest (0.22 MPa would be "3.4 N less", cv_max 1.5 -> 1.05)."""
    rig = DEMO_MODEL.with_values(**OFF, **{"supply.supply_pressure_mpa": supply_mpa})
    cols = record(rig, "steps", 5, duration_s=150.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL)
    assert "supply_pressure_offset" in _named_or_alternative(d) and d.named != ["load_mismatch"], (d.verdict, d.named)
    fitted = next(f.parameters for f in d.findings if f.effect == "supply_pressure_offset") if not d.ambiguous else \
        next(a.parameters for g in d.ambiguous for a in g if a.effect == "supply_pressure_offset")
    assert fitted["supply.supply_pressure_mpa"] == pytest.approx(supply_mpa, abs=0.01)
    assert d.calibrated.supply.supply_pressure_mpa == pytest.approx(supply_mpa, abs=0.01)
    assert d.fit_after_percent > 99.0


@pytest.mark.slow
def test_a_load_mismatch_is_still_named_with_the_supply_offset_in_the_vocabulary():
    """A heavier load is not taken for a supply offset: the load shifts the muscle's equilibrium by a
    force (most at low pressure), a supply offset scales the pressure (most at high commands)."""
    rig = DEMO_MODEL.with_values(**OFF, **{"load_mismatch.extra_n": 9.0})
    cols = record(rig, "steps", 5, duration_s=150.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL)
    assert "load_mismatch" in _named_or_alternative(d) and d.named != ["supply_pressure_offset"], (d.verdict, d.named)
    assert d.calibrated.supply.supply_pressure_mpa == pytest.approx(0.25, abs=0.01)


@pytest.mark.slow
def test_a_plant_file_at_0_3_mpa_is_the_supply_offsets_reference(tmp_path):
    """The supply offset is stated against the plant file's pressure (0.3 MPa here, not the default
    plant's 0.25): a rig at 0.25 MPa is 0.05 MPa low, and the words say which pressure it is
    measured against."""
    plant = DEMO_MODEL.with_values(**{"supply.supply_pressure_mpa": 0.3})
    cols = record(DEMO_MODEL, "steps", 6, duration_s=150.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], plant)
    assert d.named == ["supply_pressure_offset"] and d.verdict == "mismatch", (d.verdict, d.named)
    f = d.findings[0]
    assert f.parameters["supply.supply_pressure_mpa"] == pytest.approx(0.25, abs=0.005)
    assert f.explanation == "the supply delivers 0.250 MPa, not the plant's 0.300 MPa, throughout the recording"


@pytest.mark.slow
def test_an_effect_acting_all_along_is_located_all_along():
    """A rate-dependent friction at 0.2 Hz checked against a plant without it: the effect acts in every
    cycle, and the whole record is located: with the floor of the location at the noise level taken before
    the effect was in (0.34 mm there: the mismatch's own sample-to-sample change, against 0.01 mm
    after), only the start-up transient (0-3.3 s) would be shaded."""
    import tapmuscle as tm
    from fmu_plant import PlantParams

    rec = tm.simulate("sine:bias=5,amp=3,freq=0.2", duration_s=180.0, load_n=44.0, seed=2)
    d = tm.diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], PlantParams().with_values(**{"friction.rate_gain": 0.0}))
    (finding,) = [f for f in d.findings if f.effect == "rate_dependent_hysteresis"]
    covered = sum(b - a for a, b in finding.located)
    assert covered >= 0.9 * 180.0, finding.located


def test_a_supply_within_a_few_per_cent_of_the_plant_files_is_not_claimed():
    """Beside a delay or a drift, the field suite's rigs (whose supply is the plant file's) must not have a
    supply offset of 4-5 % accepted with 0.03-0.06 mm of contribution. A supply within
    6 % of the plant file's (SUPPLY_MATERIAL_FRACTION) is a calibration matter; 8 % off (a user's rig at
    0.23 MPa) and every other effect are claimed, against the plant file's own pressure."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.candidates import material_value

    nominal, at_03 = PlantParams(), PlantParams().with_values(**{"supply.supply_pressure_mpa": 0.3})
    for ps, claimed in ((0.263, False), (0.2397, False), (0.23, True), (0.27, True), (0.35, True)):
        assert material_value("supply_pressure_offset", {"supply.supply_pressure_mpa": ps}, nominal) is claimed, ps
    assert material_value("supply_pressure_offset", {"supply.supply_pressure_mpa": 0.25}, at_03)
    assert not material_value("supply_pressure_offset", {"supply.supply_pressure_mpa": 0.29}, at_03)
    assert material_value("load_mismatch", {"load_mismatch.extra_n": 0.1}, nominal)


def test_an_input_maps_words_give_the_fitted_map_at_its_ends():
    """A gain-and-offset map must not be said as the line through its knots alone ("0.98 x the command +0.09 V")
    while the fitted map passes 0.0003 V at 0 V and 9.83 V at 10 V (its outer gains within the
    tolerance of the middle one): the words give the map's own values at 0, 5 and 10 V."""
    from tapmuscle.diagnosis.input_map_fit import explain_input_map

    fitted = {"input_map.out_at_0_v": 0.000335, "input_map.knot1_in_v": 3.3333333, "input_map.knot1_out_v": 3.3545,
              "input_map.knot2_in_v": 6.6666667, "input_map.knot2_out_v": 6.6216, "input_map.out_at_10_v": 9.8319}
    said = explain_input_map(fitted)
    assert said.startswith("the valve sees 0.98 x the command +0.09 V (amplifier gain and offset error; ")
    assert said.endswith("commands of 0, 5 and 10 V act as 0.00, 4.99 and 9.83 V)"), said


def test_a_sensor_much_noisier_than_the_models_is_noted_and_still_no_mismatch():
    """The exact rig read through 0.5 mm of sensor noise (a potentiometer; the plant states the encoder's
    0.0104 mm) is no mismatch, and the report says that the recording is about 50 times noisier than
    the plant's sensor and what that means for its findings; the encoder's recording says nothing of it."""
    from fmu_plant import PlantParams
    from tapmuscle.api import simulate
    from tapmuscle.diagnosis.diagnose import NOISIER_SENSOR_FACTOR

    for noise, noted in ((0.5, True), (0.01, False)):
        rec = simulate("random", duration_s=150.0, params=PlantParams().with_values(
            **{"sensor.encoder_noise_std_mm": noise}), seed=1)
        d = diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], PlantParams())
        assert d.verdict == "no_significant_mismatch"
        said = [n for n in d.notes if "times the sensor noise the plant states" in n]
        assert bool(said) == noted, d.notes
        if noted:
            m = re.match(r"The recording's white noise \(([\d.]+) mm\) is (\d+) times the sensor noise the plant "
                         r"states \(0\.0104 mm", said[0])
            assert m and 0.45 < float(m[1]) < 0.55 and int(m[2]) > NOISIER_SENSOR_FACTOR, said
            assert "jumps from sample to sample" not in said[0]  # the residual after is white: the sensor's


def test_a_noise_that_the_models_own_mismatch_makes_is_not_put_on_the_sensor_alone():
    """A plant file with a 30-kPa sag at 20-50 s that the rig (a 0.15-s delay) did not have, diagnosed
    among a delay and a drift: the residual after is structured and its white part 0.34 mm, 33 times
    the encoder's. The note names the model's own mismatch too, not a noisier sensor only."""
    from fmu_plant import PlantParams

    import tapmuscle as tm

    rec = tm.simulate("sine:bias=5,amp=3,freq=0.5", duration_s=120.0,
                      params=PlantParams().with_values(**{"delay.delay_s": 0.15}), seed=1)
    wrong = PlantParams().with_values(**{"supply_variation.sag_mpa": 0.03, "supply_variation.start_s": 20.0,
                                         "supply_variation.end_s": 50.0})
    d = diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], wrong, candidates=["transport_delay", "sensor_drift"])
    said = [n for n in d.notes if "times the sensor noise the plant states" in n]
    assert d.tests_after["structured"] and len(said) == 1, d.notes
    assert "a noisier sensor than the model's (a potentiometer or an ADC?), or a mismatch that jumps from sample to " \
           "sample in what the model leaves" in said[0]


@pytest.mark.slow
def test_a_mismatch_that_jumps_between_samples_is_not_taken_for_a_noisy_sensor():
    """A 2-mm backlash and a 0.12-s delay under the 0.2-Hz sine: the nominal model's residual changes
    from sample to sample by tenths of a mm (its white part, from first differences, 0.35 mm), which
    would make the report call the rig's encoder a potentiometer; the final model leaves the encoder's 0.0105 mm."""
    from fmu_plant import PlantParams
    from tapmuscle.api import simulate

    rig = PlantParams().with_values(**{"backlash.slack_mm": 2.0, "delay.delay_s": 0.12})
    rec = simulate("sine:bias=5,amp=2.5,freq=0.2", duration_s=150.0, params=rig, seed=9)
    d = diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], PlantParams(), calibration=None)
    assert d.tests_before["white_noise_mm"] > 10 * 0.0104 and d.tests_after["white_noise_mm"] < 0.02
    assert sorted(d.named) == ["backlash", "transport_delay"]
    assert not [n for n in d.notes if "times the sensor noise the plant states" in n], d.notes


def test_the_diagnosis_keeps_a_copy_of_the_recording():
    """A notebook's later ``l -= 10`` on its own array must not change the diagnosis's recording with it."""
    cols = record(DEMO_MODEL, "sine", 3, duration_s=60.0)
    t, u, l = (np.array(cols[k]) for k in ("t_s", "u_v", "l_mm"))
    d = diagnose(t, u, l, DEMO_MODEL, calibration=None)
    kept = (d.t_s.copy(), d.u_v.copy(), d.y_mm.copy())
    assert np.array_equal(kept[2], cols["l_mm"])
    t += 1.0
    u *= 2.0
    l -= 10.0
    assert all(np.array_equal(a, b) for a, b in zip((d.t_s, d.u_v, d.y_mm), kept))


def test_a_sag_of_the_recording_is_left_out_of_the_discriminating_experiments_plants():
    """A supply sag found beside an ambiguous group happened at the recording's times; the experiment,
    recorded later, has its own clock, so the plant to re-diagnose it with and the alternatives the
    input is designed on leave it out (carried over, a 0.15-s delay against a drift would be re-diagnosed
    as a 0.212-s delay, a spurious drift and an unexplained window, 83.7 %; docs/diagnosis.md). An
    effect that lasts the whole run (a delay) stays, and a sag that is itself an alternative stays."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.model_space import MUSCLE
    from tapmuscle.diagnosis.report import _passing_effects, _without

    rig = PlantParams().with_values(**{"supply_variation.sag_mpa": 0.03, "supply_variation.start_s": 20.0,
                                       "supply_variation.end_s": 50.0, "delay.delay_s": 0.15})
    assert _passing_effects(rig, MUSCLE, ["transport_delay", "sensor_drift"]) == ["supply_pressure_variation"]
    assert _passing_effects(rig, MUSCLE, ["supply_pressure_variation", "load_mismatch"]) == []
    assert _passing_effects(PlantParams().with_values(**{"delay.delay_s": 0.15}), MUSCLE, []) == []
    off = _without(rig, MUSCLE, ["supply_pressure_variation"])
    assert off.supply_variation == PlantParams().supply_variation and off.delay.delay_s == 0.15
    assert _without(rig, MUSCLE, []) is rig


def test_a_named_transport_delay_says_what_the_controller_needs():
    """A diagnosis that names a 0.15-s delay must say something of control, or a user who sets what it finds
    through the plant file alone runs the loop uncompensated: the summary and report.md say the
    controller's input_delay_samples (the longer of two samples for a delay between them, as the
    controller's own decision), and where to set it."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.report import delay_advice, summary_lines

    import tapmuscle as tm

    assert "input_delay_samples = 1 at Ts = 0.1 s, with a theta0" in delay_advice(0.11, 0.1)
    assert "input_delay_samples = 2 at Ts = 0.1 s (1.50 samples: the longer of 1 and 2," in delay_advice(0.15, 0.1)
    assert "input_delay_samples = 8 at Ts = 0.02 s (7.50 samples" in delay_advice(0.15, 0.02)
    assert "under a quarter of a sample: the controller needs no input_delay_samples" in delay_advice(0.02, 0.1)
    assert "more than the controller compensates (input_delay_samples up to 25)" in delay_advice(2.6, 0.1)
    # at a short Ts Table 5's 5-sample servo horizon barely looks past a delay of 4: the horizon is said
    assert delay_advice(0.2, 0.05).endswith("for the servo methods, Table 5's servo.Hp = 5 samples spans 0.25 s at Ts = "
                                            "0.05 s and looks 0.05 s past the input delay of 4 samples: servo.Hp = 10, "
                                            "Table 5's 0.5 s at this Ts, is advised (on delayed rigs at Ts = 0.05 s, 10 "
                                            "samples tracked better than 5: docs/control.md, \"A short Ts\")")
    assert "servo.Hp" not in delay_advice(0.15, 0.05) and "servo.Hp" not in delay_advice(0.4, 0.1)
    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=60.0,
                      params=PlantParams().with_values(**{"delay.delay_s": 0.15}))
    d = diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], PlantParams(), candidates=["transport_delay"], calibration=None)
    assert d.named == ["transport_delay"] and abs(d.calibrated.delay.delay_s - 0.15) < 0.01
    said = [line for line in summary_lines(d) if "for control:" in line]
    assert len(said) == 1 and "input_delay_samples = 2 at Ts = 0.1 s" in said[0], summary_lines(d)
    clean = diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], PlantParams().with_values(**{"delay.delay_s": 0.15}),
                     calibration=None)
    assert not [line for line in summary_lines(clean) if "for control:" in line]
