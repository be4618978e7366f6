"""The field-recording proof (tapmuscle/diagnosis/field_demo.py): the generator is seeded and varied, the scoring
counts what it says on made-up results, the discriminating experiment is run on the truth, and a tiny
run writes its files."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tapmuscle.diagnosis import CANDIDATES
from tapmuscle.diagnosis import field_demo as fd
from tapmuscle.diagnosis.field_demo import (CATEGORY_MIX, EXCITATIONS, FIELD_ERROR_PARAMETERS, INCOMPATIBLE_PAIRS, OOV_KINDS,
                                  field_cases, record_case, run_field_case, run_field_demo, score_results,
                                  scores_markdown, vocabulary)
from fmu_plant import PlantParams
from tapmuscle.io.recording import Recording, atomic_write_text, read_recording, write_recording
from tapmuscle.diagnosis.residual_analysis import fit_percent, interleaved_split
from tapmuscle.diagnosis.simulation import Simulator
from tapmuscle.provenance import software


@pytest.fixture(scope="module")
def cases120():
    return field_cases(120, 0)


# ------------------------------------------------------------------------------------ generator
def test_the_same_seed_gives_the_same_cases_and_another_seed_others(cases120):
    assert field_cases(120, 0) == cases120
    other = field_cases(120, 1)
    assert other != cases120
    assert sum(a.parameter_errors != b.parameter_errors for a, b in zip(cases120, other)) > 100
    assert len({c.name for c in cases120}) == 120


def test_three_to_six_constants_are_off_by_5_to_20_percent_within_their_bounds(cases120):
    counts = Counter()
    for c in cases120:
        keys = [k for k, _ in c.parameter_errors]
        assert 3 <= len(keys) <= 6 and len(set(keys)) == len(keys)
        assert set(keys) <= set(FIELD_ERROR_PARAMETERS)
        counts[len(keys)] += 1
        for key, rel in c.parameter_errors:
            assert 0.05 - 1e-12 <= abs(rel) <= 0.20 + 1e-12, (c.name, key, rel)
        truth = c.truth()  # constructing it validates every field's bounds
        assert truth.valve.cv_max <= 1.6
        for key, value in c.true_constants().items():
            group, _, name = key.partition(".")
            assert getattr(getattr(truth, group), name) == value
        assert c.model().load.load_n == c.load_n and c.model().friction.rate_gain == 0.0
    assert set(counts) == {3, 4, 5, 6}
    signs = [np.sign(rel) for c in cases120 for _, rel in c.parameter_errors]
    assert 0.35 < np.mean(np.array(signs) > 0) < 0.65
    # cv_max above its rating is clipped to 1.6 (+6.7 %)
    cv = [rel for c in cases120 for k, rel in c.parameter_errors if k == "valve.cv_max"]
    assert max(cv) == pytest.approx(1.6 / 1.5 - 1.0)


def test_category_mix_effects_excitations_and_disturbances(cases120):
    cats = Counter(c.category for c in cases120)
    assert cats == {"none": 30, "single": 42, "pair": 30, "oov": 18}
    assert sum(share for _, share in CATEGORY_MIX) == pytest.approx(1.0)
    assert sum(Counter(c.category for c in field_cases(7, 3)).values()) == 7
    vocab = set(vocabulary())
    singles = Counter(c.effects[0] for c in cases120 if c.category == "single")
    assert set(singles) == vocab and max(singles.values()) - min(singles.values()) <= 1
    for c in cases120:
        assert len(c.effects) == {"none": 0, "single": 1, "pair": 2, "oov": 0}[c.category]
        assert (c.oov is not None) == (c.category == "oov")
        if c.category == "pair":
            assert c.effects[0] != c.effects[1] and frozenset(c.effects) not in INCOMPATIBLE_PAIRS
        assert set(c.effects) <= vocab
        c.truth()  # the effects' parameters are valid plant parameters
    assert set(e for c in cases120 for e in c.effects) == vocab
    assert Counter(c.oov for c in cases120 if c.oov) == {k: 6 for k in OOV_KINDS}
    exc = Counter(c.excitation for c in cases120)
    assert set(exc) == set(EXCITATIONS) and min(exc.values()) >= 20
    assert {c.load_n for c in cases120} == {44.0, 68.0}


def test_every_candidate_of_the_diagnosis_can_be_drawn():
    # but those left out so that the seeds' draws stay those of the documented tables
    from tapmuscle.diagnosis.field_cases import NOT_DRAWN

    assert {c.name for c in CANDIDATES} - NOT_DRAWN == set(vocabulary())
    assert NOT_DRAWN <= {c.name for c in CANDIDATES} and not NOT_DRAWN & set(vocabulary())
    if "input_map" in {f for f in PlantParams().to_dict()}:
        assert "input_map" in vocabulary()


def test_excitation_parameters_stay_within_their_ranges(cases120):
    for c in cases120:
        p = dict(c.excitation_params)
        if c.excitation == "sine":
            assert 4 <= p["offset_v"] <= 6 and 2 <= p["amplitude_v"] <= 4 and 0.05 <= p["frequency_hz"] <= 0.2
            assert c.input_spec().startswith("sine:")
        elif c.excitation == "sinesum":
            amps = [v for k, v in p.items() if k.startswith("amplitude")]
            assert len(amps) in (2, 3) and 2 <= sum(amps) <= 4 and c.input_spec() is None
        elif c.excitation in ("steps", "random"):
            assert c.input_spec().startswith("random:")
        else:
            assert 20 <= p["amplitude_mm"] <= 30 and 0.05 <= p["frequency_hz"] <= 0.15


def test_out_of_vocabulary_disturbances_act_as_documented(cases120):
    base = next(c for c in cases120 if c.category == "none" and c.excitation == "sine")
    short = dict(duration_s=40.0)

    def with_oov(kind, params):
        return replace(base, category="oov", oov=kind, oov_params=tuple(params.items()))

    clean = record_case(base, **short)
    vib = record_case(with_oov("vibration", {"amplitude_mm": 1.0, "frequency_hz": 1.0, "phase_rad": 0.0}), **short)
    d = vib["l_mm"] - clean["l_mm"]  # same noise seed: the difference is the vibration (quantised)
    assert np.max(np.abs(d - np.sin(2 * np.pi * vib["t_s"]))) < 0.02
    stop = record_case(with_oov("end_stop", {"below_peak_mm": 5.0}), end_stop_mm=30.0, **short)
    assert stop["l_mm"].max() <= 30.0 + 0.05 and clean["l_mm"].max() > 35.0
    load = record_case(with_oov("varying_load", {"form": 1.0, "extra_n": 8.0, "on_s": 10.0, "off_s": 25.0}), **short)
    assert np.all(load["load_n"] == base.load_n)  # the recording does not know the extra weight
    late = load["t_s"] > 12.0
    assert np.max(np.abs(load["l_mm"] - clean["l_mm"])[late]) > 1.0
    before = load["t_s"] < 9.95
    assert np.array_equal(load["l_mm"][before], clean["l_mm"][before])


# ------------------------------------------------------------------------------------ scoring
def _r(category, effects=(), findings=(), ambiguous=(), fit_after=97.0, oov=None, verdict=None, **more):
    r = {"case": f"c{_r.i}", "category": category, "effects": list(effects), "oov": oov,
         "findings": list(findings), "ambiguous": [list(g) for g in ambiguous],
         "verdict": verdict or ("ambiguous" if ambiguous else "mismatch" if findings else "calibration_only"),
         "fit_before_percent": 60.0, "fit_after_percent": fit_after, **more}
    _r.i += 1
    return r


_r.i = 0


def test_scores_count_each_target_the_confusion_and_the_misses():
    results = [
        # none: 3 right (two calibration_only, one no_significant_mismatch), 1 claims drift, 1 unexplained
        _r("none"), _r("none"), _r("none", verdict="no_significant_mismatch"),
        _r("none", findings=["sensor_drift"]), _r("none", findings=["unexplained"], fit_after=90.0),
        # single: named alone, named with an extra, named as an ambiguous alternative, missed, failed
        _r("single", ["backlash"], ["backlash"]),
        _r("single", ["backlash"], ["backlash", "unexplained"]),
        _r("single", ["transport_delay"], ambiguous=[["transport_delay", "rate_dependent_hysteresis"]],
           discrimination={"alternatives": ["rate_dependent_hysteresis", "transport_delay"], "input_written": True,
                           "right": True}),
        _r("single", ["load_mismatch"], ["supply_pressure_variation"]),
        {**_r("single", ["load_mismatch"]), "error": "RuntimeError: boom"},
        # pair: both, one, neither
        _r("pair", ["backlash", "sensor_drift"], ["sensor_drift", "backlash"]),
        _r("pair", ["backlash", "sensor_drift"], ["sensor_drift"]),
        _r("pair", ["load_mismatch", "transport_delay"], ["unexplained"]),
        # oov: unexplained alone, unexplained with a wrong name, only a wrong name
        _r("oov", oov="vibration", findings=["unexplained"], oov_cost_points=2.0),
        _r("oov", oov="end_stop", findings=["backlash", "unexplained"], oov_cost_points=5.0),
        _r("oov", oov="end_stop", findings=["sensor_drift"], oov_cost_points=0.1),
    ]
    s = score_results(results)
    t = s["targets"]
    assert (t["none_no_effect_claimed"]["passed"], t["none_no_effect_claimed"]["cases"]) == (3, 5)
    assert t["none_no_effect_claimed"]["rate_percent"] == pytest.approx(60.0) and not t["none_no_effect_claimed"]["met"]
    assert (t["single_named"]["passed"], t["single_named"]["cases"]) == (3, 5)
    # alone: the only effect named (an unexplained remainder beside it allowed); strictly: no remainder
    assert t["single_named_alone"]["passed"] == 2
    assert s["more"]["single_named_alone_no_remainder"]["passed"] == 1
    assert (t["pair_both_found"]["passed"], t["pair_both_found"]["cases"]) == (1, 3)
    assert (t["oov_unexplained"]["passed"], t["oov_unexplained"]["cases"]) == (2, 3)
    # visible: the oov case whose disturbance costs 0.1 points is not
    assert (t["oov_unexplained"]["visible_passed"], t["oov_unexplained"]["visible_cases"]) == (2, 2)
    assert t["oov_unexplained"]["visible_rate_percent"] == pytest.approx(100.0)
    # fit after >= 95 in the 13 in-vocabulary cases: the failed one and the 90 % one miss
    assert (t["fit_after_at_least_95"]["passed"], t["fit_after_at_least_95"]["cases"]) == (11, 13)
    assert s["more"]["oov_unexplained_alone"]["passed"] == 1
    assert s["more"]["pair_found_alone"]["passed"] == 1
    assert s["more"]["none_verdicts"] == {"calibration_only": 2, "no_significant_mismatch": 1, "mismatch": 2}
    assert s["failed"] == 1 and s["recordings"] == 16

    conf = s["confusion"]
    c = conf["counts"]
    assert c["none"]["nothing"] == 3 and c["none"]["sensor_drift"] == 1 and c["none"]["unexplained"] == 1
    assert c["single: backlash"]["backlash"] == 2 and c["single: backlash"]["unexplained"] == 1
    assert c["single: transport_delay"]["ambiguous"] == 1
    assert c["single: transport_delay"]["transport_delay"] == 1
    assert c["single: transport_delay"]["rate_dependent_hysteresis"] == 1
    assert c["single: load_mismatch"]["supply_pressure_variation"] == 1 and c["single: load_mismatch"]["failed"] == 1
    assert conf["cases"]["single: load_mismatch"] == 2 and conf["correct"]["single: load_mismatch"] == 0
    assert c["pair"]["backlash"] == 1 and c["pair"]["sensor_drift"] == 2 and c["pair"]["unexplained"] == 1
    assert c["oov: end_stop"]["unexplained"] == 1 and c["oov: end_stop"]["backlash"] == 1
    assert conf["cases"]["oov: end_stop"] == 2 and conf["correct"]["oov: end_stop"] == 1
    assert s["pairs"]["backlash+sensor_drift"] == {"cases": 2, "both": 1, "one": 1, "neither": 0, "failed": 0}
    assert s["pairs"]["load_mismatch+transport_delay"]["neither"] == 1
    assert s["discrimination"] == {"ambiguous_verdicts": 1, "inputs_written": 1, "re_diagnosed": 1, "right": 1,
                                 "failed": 0}

    why = {m["case"]: m["why"] for m in s["misses"]}
    assert len(s["misses"]) == 8
    assert why[results[4]["case"]] == "claimed something; fit after < 95 %"
    assert results[6]["case"] not in why  # named alone, with a remainder reported beside it
    assert why[results[7]["case"]] == "named, not alone"
    assert why[results[9]["case"]] == "failed"

    md = scores_markdown(s)
    assert "| one effect -> named (or an ambiguous alternative) | 3 / 5 | 60.0 % | >= 90 % | **no** |" in md
    assert "| none | 5 | 3 |" in md and "Misses (8)" in md and "RuntimeError: boom" in md


def test_confusion_figure_is_a_png(tmp_path, monkeypatch):
    """Rows and columns named alike (words, not snake_case), and the colour bar says what a share is."""
    import tapmuscle.plots.figures as figures

    saved = []
    real = figures.save_figure
    monkeypatch.setattr(figures, "save_figure", lambda fig, path, **kw: (saved.append(fig), real(fig, path, **kw))[1])
    s = score_results([_r("none"), _r("single", ["backlash"], ["backlash"]),
                       _r("oov", oov="vibration", findings=["unexplained"])])
    path = fd.confusion_figure(s, tmp_path / "confusion.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ax, bar = saved[0].axes
    assert all("_" not in t.get_text() for t in ax.get_yticklabels() + ax.get_xticklabels())
    assert bar.get_ylabel() == "share of the row's cases claiming it"


# ------------------------------------------------------------------------------------ running
def test_an_ambiguous_verdict_runs_the_discriminating_input_on_the_truth(tmp_path, monkeypatch, cases120):
    """With a stand-in diagnosis: the first call says `ambiguous` and writes an input and the plant to
    re-diagnose with, the re-diagnosis (limited to the alternatives, on that plant) names the true effect."""
    import tapmuscle.diagnosis.report as report

    case = next(c for c in cases120 if c.category == "single" and c.excitation == "sine")
    case = replace(case, duration_s=40.0)
    true, other = case.effects[0], next(e for e in vocabulary() if e != case.effects[0])
    calls = []

    def fake(rec, plant, out, *, plots=True, effects=None, **options):
        out = Path(out)
        calls.append({"samples": len(read_recording(rec).t_s), "effects": effects, "plant": Path(plant)})
        if effects is None:
            t = np.arange(0.0, 35.05, 0.1)
            write_recording(out / "discriminating_input.csv",
                            Recording({"t_s": t, "u_v": 5 + 2 * np.sign(np.sin(t)), "l_mm": 0 * t}, {"ts_s": "0.1"}))
            atomic_write_text(out / "discriminate_plant.json", "{}\n")
            doc = {"verdict": "ambiguous", "findings": [], "fit_before_percent": 50.0, "fit_after_percent": 96.0,
                   "ambiguous": [{"alternatives": [{"effect": true}, {"effect": other}],
                                  "discriminating_input": "discriminating_input.csv",
                                  "discriminate_plant": "discriminate_plant.json"}]}
        else:
            doc = {"verdict": "mismatch", "findings": [{"effect": true}], "fit_before_percent": 40.0,
                   "fit_after_percent": 98.0}
        atomic_write_text(out / "diagnosis.json", json.dumps(doc))
        atomic_write_text(out / "report.md", "# stand-in\n")
        return None, doc

    monkeypatch.setattr(report, "diagnose_files", fake)
    r = run_field_case(case, tmp_path)
    assert r["verdict"] == "ambiguous" and r["named"] == sorted([true, other])
    d = r["discrimination"]
    assert d["input_written"] and d["right"] and d["picked"] == [true] and d["duration_s"] == pytest.approx(35.0)
    assert calls[1]["effects"] == sorted([true, other])
    assert calls[1]["samples"] == 351  # recorded for the input's 35 s
    assert calls[0]["plant"].name == "plant.json" and calls[1]["plant"] == tmp_path / case.name / "discriminate_plant.json"
    folder = tmp_path / case.name
    assert sorted(p.name for p in folder.iterdir()) == ["diagnosis.json", "discriminate", "report.md", "result.json"]
    assert sorted(p.name for p in (folder / "discriminate").iterdir()) == ["diagnosis.json", "report.md"]

    # a diagnosis without the `effects` keyword: the re-diagnosis runs with every candidate
    def older(rec, plant, out, *, plots=True, **options):
        if "effects" in options:
            raise TypeError("diagnose() got an unexpected keyword argument 'effects'")
        return fake(rec, plant, out, plots=plots, effects=["second call"] if calls else None)

    calls.clear()
    monkeypatch.setattr(report, "diagnose_files", older)
    r = run_field_case(case, tmp_path / "older")
    assert len(calls) == 2 and r["discrimination"]["verdict"] == "mismatch" and r["discrimination"]["right"]



def test_the_truth_s_fit_is_taken_on_the_held_out_blocks_of_the_diagnosis_s_split(tmp_path, monkeypatch, cases120):
    """The truth's held-out fit (beside which the diagnosis's is judged) is taken on the held-out
    blocks of the split the diagnosis reports, here 9-s blocks (a stand-in diagnosis)."""
    import tapmuscle.diagnosis.report as report
    from tapmuscle.diagnosis.field_cases import _replay

    case = replace(next(c for c in cases120 if c.category == "single" and c.excitation == "sine"), duration_s=60.0)

    def fake(rec, plant, out, *, plots=True, effects=None, **options):
        doc = {"verdict": "mismatch", "findings": [], "fit_before_percent": 50.0, "fit_after_percent": 96.0,
               "split": {"block_s": 9.0}}
        atomic_write_text(Path(out) / "diagnosis.json", json.dumps(doc))
        return None, doc

    monkeypatch.setattr(report, "diagnose_files", fake)
    r = run_field_case(case, tmp_path)
    cols = record_case(case)  # the recording again (seeded), unrounded as the run has it
    truth = _replay(case.truth(), cols["u_v"], 0.1)
    fits = {b: fit_percent(cols["l_mm"], truth, interleaved_split(len(truth), 0.1, b)[1]) for b in (9.0, 10.0)}
    assert fits[9.0] != fits[10.0]  # the two splits hold different samples out
    assert r["fit_truth_percent"] == fits[9.0]  # the same arithmetic on the same samples


def test_each_ambiguous_group_gets_its_own_experiment_as_the_report_says(tmp_path, monkeypatch, cases120):
    """Two ambiguous groups, as the report gives them: each group's input is recorded on the truth
    (its own noise seed) and diagnosed from that group's plant among that group's alternatives. Right
    only when every group's re-diagnosis names exactly its true effects (none for a group without one)."""
    import tapmuscle.diagnosis.report as report

    case = next(c for c in cases120 if c.category == "single" and c.excitation == "sine")
    case = replace(case, duration_s=40.0)
    true = case.effects[0]
    others = [e for e in vocabulary() if e != true]
    first, second = sorted([true, others[0]]), sorted(others[1:3])  # the second group has no true effect
    calls = []

    def fake(named_in_second, first_input=True):
        def diagnose_files(rec, plant, out, *, plots=True, effects=None, **options):
            out = Path(out)
            samples = len(read_recording(rec).t_s)
            calls.append({"samples": samples, "effects": effects, "plant": Path(plant), "folder": out.name,
                          "u0": float(read_recording(rec).u_v[0])})
            if effects is None:
                groups = []
                for k, (alts, u0, seconds) in enumerate(((first, 3.0, 30.0), (second, 7.0, 20.0)), 1):
                    tail = "" if k == 1 else f"_{k}"
                    groups.append({"alternatives": [{"effect": a} for a in alts]})
                    if k == 1 and not first_input:  # the design failed for this group
                        continue
                    t = np.arange(0.0, seconds + 0.05, 0.1)
                    write_recording(out / f"discriminating_input{tail}.csv",
                                    Recording({"t_s": t, "u_v": u0 + np.sign(np.sin(t)), "l_mm": 0 * t}, {"ts_s": "0.1"}))
                    atomic_write_text(out / f"discriminate_plant{tail}.json", "{}\n")
                    groups[-1].update({"discriminating_input": f"discriminating_input{tail}.csv",
                                       "discriminate_plant": f"discriminate_plant{tail}.json"})
                doc = {"verdict": "ambiguous", "findings": [], "fit_before_percent": 50.0,
                       "fit_after_percent": 96.0, "ambiguous": groups}
            else:
                named = [true] if true in effects else named_in_second
                doc = {"verdict": "mismatch" if named else "calibration_only",
                       "findings": [{"effect": e} for e in named], "fit_before_percent": 40.0, "fit_after_percent": 98.0}
            atomic_write_text(out / "diagnosis.json", json.dumps(doc))
            atomic_write_text(out / "report.md", "# stand-in\n")
            return None, doc
        return diagnose_files

    monkeypatch.setattr(report, "diagnose_files", fake([]))
    r = run_field_case(case, tmp_path)
    d = r["discrimination"]
    assert [c["effects"] for c in calls] == [None, first, second]
    assert [c["plant"].name for c in calls] == ["plant.json", "discriminate_plant.json", "discriminate_plant_2.json"]
    assert [c["folder"] for c in calls[1:]] == ["discriminate", "discriminate_2"]
    assert [c["samples"] for c in calls[1:]] == [301, 201]  # each group's own input, 30 s and 20 s
    assert [c["u0"] for c in calls[1:]] == pytest.approx([3.0, 7.0])  # the rig ran each group's command
    assert d["right"] and d["picked"] == [true] and [g["right"] for g in d["groups"]] == [True, True]
    assert d["alternatives"] == sorted(first + second) and d["true_alternatives"] == [true]
    assert d["groups"][1]["true_alternatives"] == [] and d["groups"][1]["verdict"] == "calibration_only"

    calls.clear()  # the second group's re-diagnosis names one of its alternatives, which the truth lacks
    monkeypatch.setattr(report, "diagnose_files", fake([second[0]]))
    d = run_field_case(case, tmp_path / "wrong")["discrimination"]
    assert not d["right"] and d["picked"] == sorted([true, second[0]]) and [g["right"] for g in d["groups"]] == [True, False]

    calls.clear()  # no input for the first group: the second is still run, and the verdict is not resolved
    monkeypatch.setattr(report, "diagnose_files", fake([], first_input=False))
    d = run_field_case(case, tmp_path / "no_first")["discrimination"]
    assert [c["effects"] for c in calls] == [None, second] and calls[1]["folder"] == "discriminate_2"
    assert d["input_written"] and not d["right"] and [g["input_written"] for g in d["groups"]] == [False, True]
    assert d["verdict"] == "calibration_only" and d["picked"] == []


@pytest.mark.slow
def test_a_tiny_run_writes_its_files(tmp_path):
    scores = run_field_demo(tmp_path, n=2, seed=4, jobs=2, duration_s=40.0)  # 4 blocks of 10 s at least
    assert scores["recordings"] == 2 and scores["failed"] == 0, scores["misses"]
    for name in ("scores.md", "scores.json", "confusion.png"):
        assert (tmp_path / name).is_file()
    doc = json.loads((tmp_path / "scores.json").read_text())
    assert len(doc["cases"]) == 2 and {c["category"] for c in doc["cases"]} == {"none", "single"}
    assert doc["software"] == software()
    for c in doc["cases"]:
        assert c["fit_truth_percent"] > 99.0 and "verdict" in c
        folder = tmp_path / "cases" / c["case"]
        assert sorted(p.name for p in folder.iterdir()) == ["diagnosis.json", "report.md", "result.json"]
    assert "Confusion table" in (tmp_path / "scores.md").read_text()

    # resume: a finished case is reused (not diagnosed again), one whose stored truth differs is re-run
    first = json.loads((tmp_path / "cases" / doc["cases"][0]["case"] / "result.json").read_text())
    other = tmp_path / "cases" / doc["cases"][1]["case"] / "result.json"
    other.write_text(json.dumps({**json.loads(other.read_text()), "noise_seed": -1}))
    again = run_field_demo(tmp_path, n=2, seed=4, jobs=1, duration_s=40.0, resume=True)
    redo = json.loads((tmp_path / "scores.json").read_text())
    assert redo["scores"]["settings"]["resumed_cases"] == 1 and again["recordings"] == 2
    assert redo["cases"][0]["elapsed_s"] == first["elapsed_s"]
    assert json.loads(other.read_text())["noise_seed"] == doc["cases"][1]["noise_seed"]


@pytest.mark.slow
def test_the_discriminating_experiment_picks_the_rate_dependence_over_a_map(tmp_path):
    """Seed 1 case 089 as the demo runs it: a backlash is named and a rate dependence is ambiguous with
    an input map. The experiment stays within the recording's commands, and its recording,
    re-diagnosed from the plant the diagnosis wrote (calibrated, the group off), names the rate
    dependence alone and fits it (the same re-diagnosed from the nominal plant would fit 65.7 %)."""
    case = field_cases(100, 1)[89]
    assert sorted(case.effects) == ["backlash", "rate_dependent_hysteresis"]
    r = run_field_case(case, tmp_path, keep=True)
    assert r["verdict"] == "ambiguous" and r["findings"] == ["backlash"]
    assert [sorted(g) for g in r["ambiguous"]] == [["input_map", "rate_dependent_hysteresis"]]
    d = r["discrimination"]
    assert d["right"] and d["picked"] == ["rate_dependent_hysteresis"] and not d["ambiguous"]
    assert d["fit_after_percent"] > 97.0
    folder = tmp_path / case.name
    u = read_recording(folder / "recording.csv").u_v
    u_exp = read_recording(folder / "discriminating_input.csv").u_v
    assert u.min() <= u_exp.min() and u_exp.max() <= u.max()
    rediag = json.loads((folder / "discriminate" / "diagnosis.json").read_text())
    assert Path(rediag["plant"]).name == "discriminate_plant.json"


@pytest.mark.slow
def test_a_second_effect_beside_a_sag_is_judged_without_the_blocks_of_its_unplaced_edge(tmp_path):
    """Seed 3 case 028: a supply sag and a rate dependence under the AMPC loop, constants off,
    diagnosed as ``tapmuscle demo-mismatch`` does (the recording and the nominal plant through their
    files), from its stored recording (``tests/field_recordings/``: a closed loop's recording made on
    another floating-point path is another recording, the AMPC's last bits amplified by the loop; an
    aarch64 CPU's lost the rate dependence altogether, while the diagnosis of one recording is the
    same on every path). The sag's fall lies in the held-out block 50-60 s, where the training blocks
    do not place it, and the model's error there is the fall's. Judged on every held-out block, the
    rate dependence's joint re-fit removed 2.3 % of the held-out error and was not accepted; without
    that block it removes over 40 %, and both effects are found."""
    from tapmuscle.diagnosis.report import diagnose_files
    from tapmuscle.io.plant_file import plant_file_text

    case = field_cases(100, 3)[28]
    assert sorted(case.effects) == ["rate_dependent_hysteresis", "supply_pressure_variation"]
    rec = Path(__file__).parent / "field_recordings" / f"seed3_{case.name}.csv"
    plant = tmp_path / "plant.json"
    plant.write_text(plant_file_text(case.model(), "the nominal model of the field demo"))
    out = tmp_path / case.name
    doc = diagnose_files(rec, plant, out, plots=False)[1]
    found = {f["effect"] for f in doc["findings"]} | {a["effect"] for g in doc["ambiguous"] for a in g["alternatives"]}
    assert set(case.effects) <= found, (doc["findings"], doc["ambiguous"])
    # The held-out fit is not a figure of this recording: the fall may be placed anywhere in the
    # held-out block the training blocks leave (their fit moves by 0.005 point across the 4 s before
    # the rig's fall), and the held-out fit then ranges from 85 % (the fall at 49.9 s) to 97.7 % (at
    # 53.8 s). What holds: the fall lies in the held-out block that holds the rig's, which the training
    # blocks either side bound, and with the rig's edges the fitted plant reaches 99.9 %
    # (docs/diagnosis.md, "Why the sag cases miss the fit target").
    sag = next(f["parameters"] for f in doc["findings"] if f["effect"] == "supply_pressure_variation")
    rig = dict(case.effect_values)
    block_s = doc["split"]["block_s"]
    block = block_s * (rig["supply_variation.start_s"] // block_s)
    assert round(block / block_s) % 2 == 1  # a held-out block (odd blocks are held out)
    fall = (sag["supply_variation.start_s"], sag["supply_variation.start_s"] + sag["supply_variation.ramp_s"])
    assert block - 0.1 <= fall[0] <= fall[1] <= block + block_s + 0.1, (fall, block)
    assert doc["fit_after_percent"] > 84.0
    fitted = PlantParams.from_dict(json.loads((out / "calibrated_plant.json").read_text())["plant"])
    cols = read_recording(rec).columns
    sim = Simulator(cols["u_v"], float(np.median(np.diff(cols["t_s"]))), cols.get("load_n"))
    _, held_out = interleaved_split(len(cols["l_mm"]), sim.ts_s, doc["split"]["block_s"])
    edges = ("supply_variation.start_s", "supply_variation.end_s", "supply_variation.ramp_s",
             "supply_variation.recovery_ramp_s")
    at_rig = fitted.with_values(**{k: rig.get(k, PlantParams().value(k)) for k in edges})
    assert fit_percent(cols["l_mm"], sim.run(at_rig)[0], held_out) > 99.0
    added = [s for s in doc["selection"] if s["step"] == "add"]
    assert [s["effect"] for s in added[:2]] == ["supply_pressure_variation", "rate_dependent_hysteresis"]
    assert "held_out_blocks_left_out_s" not in added[0]  # nothing in the model yet: every block judged
    assert [50.0, 60.0] in added[1]["held_out_blocks_left_out_s"]
    assert added[1]["held_out_sse_reduction"] > 0.2
    report = (out / "report.md").read_text()
    assert "added `rate_dependent_hysteresis` (round 2) left out the held-out blocks" in report


def test_the_closed_loop_recording_is_the_fmus_bit_for_bit(tmp_path, built_fmus, cases120):
    """The AMPC FMU driving the plant FMU, with the truth's constants and effects as FMU parameters,
    records what the direct loop records (docs/diagnosis.md). The recordings use the paper's timing
    (input_delay_samples = 0): the FMU's default detection would switch on a rig with a transport
    delay, which looks like a parallel master (docs/fmu.md); and Eq. (18) without the anti-windup hold,
    as the suite's recordings were defined."""
    from tapmuscle.cosim.master import co_simulate
    from tapmuscle.cosim.spec import load_scenario

    case = next(c for c in cases120 if c.excitation == "ampc" and c.category == "pair")
    default = PlantParams().dotted()
    params = {k: v for k, v in case.truth().dotted().items() if v != default[k]}
    p = dict(case.excitation_params)
    path = tmp_path / "field.toml"
    path.write_text("\n".join([
        'duration_s = 30.0', 'step_s = 0.1', f'seed = {case.noise_seed}',
        '[plant]', "parameters = { " + ", ".join(f'"{k}" = {v!r}' for k, v in params.items()) + " }",
        '[controller]', 'method = "ampc_servo"', 'parameters = { input_delay_samples = 0, anti_windup = 0, startup_guard = 0 }',
        '[reference]', 'kind = "sine"', f'offset_mm = {p["offset_mm"]!r}', f'amplitude_mm = {p["amplitude_mm"]!r}',
        f'frequency_hz = {p["frequency_hz"]!r}', '[load]', f'initial_n = {case.load_n!r}']) + "\n")
    said: list[str] = []
    cols = co_simulate(load_scenario(path), built_fmus, fmu_warnings=said)
    direct = record_case(case, duration_s=30.0)
    assert np.array_equal(cols["l_mm"], direct["l_mm"]) and np.array_equal(cols["u_v"], direct["u_v"])
    # that timing on a rig with a transport delay: the controller FMU says what the recording shows
    # (a limit cycle; and at 30 s the delay the measurements show, as that test's rig has one)
    assert said and all("a limit cycle" in m or "the measurements show an input delay of" in m for m in said), said


def test_the_cli_keeps_each_suites_flags_to_it(tmp_path, capsys):
    from tapmuscle.cli.main import main

    out = tmp_path / "out"
    assert main(["demo-mismatch", "--out", str(out), "--seeds", "2"]) == 2
    assert "--seeds belongs to --suite concealed, not --suite field" in capsys.readouterr().err
    assert main(["demo-mismatch", "--out", str(out), "--suite", "concealed", "--recordings", "5", "--seed", "1"]) == 2
    assert "--recordings, --seed belong to --suite field" in capsys.readouterr().err
    assert main(["demo-mismatch", "--out", str(out), "--suite", "concealed", "--use-pressure"]) == 2
    assert "--use-pressure belongs to --suite field, not --suite concealed" in capsys.readouterr().err
    assert main(["demo-mismatch", "--out", str(out), "--suite", "foreign", "--use-pressure"]) == 2
    assert "--use-pressure belongs to --suite field, not --suite foreign" in capsys.readouterr().err
    assert main(["demo-mismatch", "--out", str(out), "--suite", "foreign", "--keep-files"]) == 2
    assert "--keep-files belongs to --suite field, not --suite foreign" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["demo-mismatch", "--out", str(out), "--recordings", "0"])
    assert "--recordings must be >= 1" in capsys.readouterr().err
    assert not out.exists()


def test_a_tidied_case_says_which_of_its_files_are_gone(tmp_path):
    """A case's report names the designed experiment and the calibrated plant as files to use: where
    the demo deletes them (the default), the report says so and how to keep them."""
    from tapmuscle.diagnosis.field_demo import KEPT_FILES, _tidy

    names = ["diagnosis.json", "report.md", "recording.csv", "calibrated_plant.json", "discriminating_input.csv"]
    for keep in (True, False):
        folder = tmp_path / f"keep_{keep}"
        folder.mkdir()
        for name in names:
            (folder / name).write_text("# report\nsee discriminating_input.csv\n" if name == "report.md" else "x")
        _tidy(folder, keep)
        left = sorted(p.name for p in folder.iterdir())
        report = (folder / "report.md").read_text()
        if keep:
            assert left == sorted(names) and "deleted" not in report
        else:
            assert left == sorted(KEPT_FILES)
            assert report.startswith("# report\nsee discriminating_input.csv\n") and report.endswith(
                "demo-mismatch deleted this case's other files (calibrated_plant.json, discriminating_input.csv, "
                "recording.csv) to save space; `tapmuscle demo-mismatch --keep-files` keeps them.\n")


@pytest.mark.slow
def test_a_load_and_a_supply_offset_are_never_both_in_the_model(tmp_path):
    """Seed 2 case 069 (a load and an amplifier map under one sine): a load mismatch and a supply offset
    must not both be accepted, trading along the constants' valley; the model holds one of them at most,
    the other staying its alternative where the data cannot tell them apart."""
    case = field_cases(100, seed=2)[69]
    assert case.name.startswith("069_pair_load_mismatch")
    run_field_case(case, tmp_path, keep=True)
    folder = tmp_path / case.name
    doc = json.loads((folder / "diagnosis.json").read_text())
    plant = json.loads((folder / "calibrated_plant.json").read_text())["plant"]
    accepted = {f["effect"] for f in doc["findings"]}
    assert not {"load_mismatch", "supply_pressure_offset"} <= accepted, accepted
    load_on = plant.get("load_mismatch", {}).get("extra_n", 0.0) != 0.0
    supply_on = plant["supply"]["supply_pressure_mpa"] != 0.25
    assert not (load_on and supply_on), plant
