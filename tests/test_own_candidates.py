"""Candidates of one's own (tapmuscle/diagnosis/own_candidates.py): refused before the search where
the search could not carry them, held to their fit's and refine's contract during it, re-fitted with
the constants where they name joint parameters, and taken through diagnose_files beside named effects."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

from tapmuscle.diagnosis import diagnose


def test_a_candidate_of_ones_own_is_refused_where_the_search_could_not_carry_it():
    """A researcher's candidate that simulates its own physics (no plant parameter) would be fitted, score
    +54 points, then be silently dropped from every joint model (named nothing, or a wrong effect); one
    with a key of its own would fail late with 'unknown plant parameter'; one named 'transport_delay' would take
    the built-in's joint re-fit; a fitted value outside its own bounds would be used. Each is refused,
    naming the candidate (the first three before any simulation)."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.candidates import Candidate, CandidateError, FitResult, ParameterSpec, full_prediction

    import tapmuscle as tm

    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=60.0, params=PlantParams().with_values(**{"delay.delay_s": 0.3}))
    t, u, y = rec["t_s"], rec["u_v"], rec["l_mm"]

    def own(name, parameters, value=0.8):
        def fit(problem, base, y_base):
            values = {spec.key: value for spec in parameters}
            return FitResult(values, full_prediction(problem, base, values))
        return Candidate(name, "physics of my own", tuple(parameters), "a constant", fit, lambda values: "mine")

    asym = ParameterSpec("friction.asymmetry", "-", 0.5, 0.9)
    refused = {
        "sets no plant parameter": own("stiffness_drift", ()),
        "sets 'rubber_drift.frac_per_min', which is not a plant parameter":
            own("stiffness_drift", (ParameterSpec("rubber_drift.frac_per_min", "1/min", 0.0, 1.0),)),
        "a candidate of your own is named 'transport_delay', a built-in candidate's name":
            own("transport_delay", (ParameterSpec("delay.delay_s", "s", 0.0, 2.0),)),
    }
    for said, cand in refused.items():
        with pytest.raises(CandidateError, match=re.escape(said)):
            diagnose(t, u, y, PlantParams(), candidates=[cand], calibration=None)
    with pytest.raises(ValueError, match=r"'transport_delay' is given twice"):
        diagnose(t, u, y, PlantParams(), candidates=["transport_delay", "transport_delay"], calibration=None)
    with pytest.raises(CandidateError, match=r"candidate 'asym': its fit set friction\.asymmetry = 0\.3, outside its "
                                             r"bounds 0\.5 \.\. 0\.9"):
        diagnose(t, u, y, PlantParams(), candidates=[own("asym", (asym,), value=0.3)], calibration=None)
    fine = diagnose(t, u, y, PlantParams(), candidates=[own("asym", (asym,)), "transport_delay"], calibration=None)
    assert {c["effect"] for c in fine.candidates} >= {"asym", "transport_delay"} and fine.named == ["transport_delay"]



def _own_candidate(name, key, lo, hi, fit_value=None, *, joint=(), y_hat=None, raises=None):
    """A candidate of one's own on the plant parameter ``key``: a grid of 9 over ``lo .. hi`` and a
    bounded scalar search on the training blocks (as a researcher writes one), or, given, a fit that
    returns ``fit_value`` (with the prediction ``y_hat(full)`` if given) or raises ``raises``."""
    from scipy import optimize

    from tapmuscle.diagnosis.candidates import Candidate, FitResult, ParameterSpec, full_prediction

    def fit(problem, base, y_base):
        if raises is not None:
            raise raises
        if fit_value is not None:
            full = full_prediction(problem, base, {key: fit_value})
            return FitResult({key: fit_value}, full if y_hat is None else y_hat(full))

        def cost(x):
            y = problem.sim.run(base.with_values(**{key: float(x)}), stop=problem.n_fit)[0]
            return float(np.sum(problem.train_residual(y) ** 2))
        grid = np.linspace(lo, hi, 9)
        i = int(np.argmin([cost(x) for x in grid]))
        x = float(optimize.minimize_scalar(cost, bounds=(grid[max(i - 1, 0)], grid[min(i + 1, 8)]), method="bounded",
                                           options={"xatol": 1e-3 * (hi - lo)}).x)
        if cost(x) >= cost(base.value(key)):
            return None
        return FitResult({key: x}, full_prediction(problem, base, {key: x}))
    return Candidate(name, "physics of my own", (ParameterSpec(key, "-", lo, hi),), "grid and scalar search", fit,
                     lambda values: f"mine at {values[key]:.3g}", joint=joint)


def test_a_candidate_of_ones_own_is_checked_before_the_search_and_its_fits_contract_after():
    """Mistakes a researcher may make with a candidate of her own, each refused naming the candidate (a
    CandidateError, which diagnose_files does not blame on the recording): a built-in's name beside
    the built-ins (else "given twice"), the report's 'unexplained' (else accepted and reported as an
    unexplained finding), bounds reversed or beyond the plant's (else scipy's or the plant's words
    after the search), a plant parameter another candidate sets, a joint entry that is not one of
    its parameters; a fit whose prediction is NaN (else a silent loss and 'nan %' in the report) or
    of another length (numpy's broadcast error), and a fit that raises (else raw, nameless)."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.candidates import CANDIDATES, CandidateError, ParameterSpec

    import tapmuscle as tm

    # a rig with a mismatch, so that the candidates are fitted
    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=60.0,
                      params=PlantParams().with_values(**{"friction.rate_gain": 2.5}))
    t, u, y = rec["t_s"], rec["u_v"], rec["l_mm"]
    gain = "friction.rate_gain"

    def refused(candidates, said):
        with pytest.raises(CandidateError, match=re.escape(said)):
            diagnose(t, u, y, PlantParams(), candidates=candidates, calibration=None)

    refused([*CANDIDATES, _own_candidate("sensor_drift", "sensor_drift.offset_mm", -1, 1)],
            "a candidate of your own is named 'sensor_drift', a built-in candidate's name")
    refused([_own_candidate("unexplained", gain, 0, 3)], "is named 'unexplained', the report's name for what no effect")
    mine = _own_candidate("speed_friction", gain, 0, 3)
    refused([dataclasses.replace(mine, parameters=(ParameterSpec(gain, "-", 3, 0),))],
            "'speed_friction': its bounds of friction.rate_gain are 3 .. 0: give the lower bound first")
    refused([dataclasses.replace(mine, parameters=(ParameterSpec(gain, "-", -1, 3),))],
            "'speed_friction': its bounds of friction.rate_gain are -1 .. 3, beyond the plant's 0 .. 10")
    refused([mine, "rate_dependent_hysteresis"],
            "'rate_dependent_hysteresis' and 'speed_friction' both set 'friction.rate_gain'")
    refused([dataclasses.replace(mine, joint=(("friction.base_n", 1.0),))],
            "'speed_friction': its joint names 'friction.base_n', not one of its parameters (friction.rate_gain)")
    refused([dataclasses.replace(mine, joint=((gain, 0.0),))], "'speed_friction': its joint scale of friction.rate_gain is 0.0")
    refused([_own_candidate("speed_friction", gain, 0, 3, 1.2, y_hat=lambda full: np.where(np.arange(full.size) < 100,
                                                                                           full, np.nan))],
            "candidate 'speed_friction': its fit's prediction y_hat is nan at sample 100 (501 samples not finite)")
    refused([_own_candidate("speed_friction", gain, 0, 3, 1.2, y_hat=lambda full: full[:500])],
            "candidate 'speed_friction': its fit's prediction y_hat has shape (500,), not the recording's (601,)")
    with pytest.raises(CandidateError, match="candidate 'speed_friction': its fit raised ZeroDivisionError: division by "
                                             "zero") as raised:
        diagnose(t, u, y, PlantParams(), candidates=[_own_candidate("speed_friction", gain, 0, 3,
                                                                    raises=ZeroDivisionError("division by zero"))],
                 calibration=None)
    assert isinstance(raised.value.__cause__, ZeroDivisionError)
    import tapmuscle.diagnosis.candidates as module
    with pytest.raises(TypeError, match=r"candidates: module <module 'tapmuscle\.diagnosis\.candidates' from .{10,}\.\.\. "
                                        r"must be a Candidate or the name of one \(a module: pass the Candidate objects"):
        diagnose(t, u, y, PlantParams(), candidates=[module], calibration=None)



def test_diagnose_files_takes_candidates_of_ones_own_beside_named_effects(tmp_path):
    """``tm.diagnose_files(..., effects=[...], candidates=[mine])`` must not drop the candidate silently (the
    effects replacing it); the two are one list, and a candidate's error is the candidate's, not
    put on the recording's name."""
    from fmu_plant import PlantParams

    import tapmuscle as tm

    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=60.0,
                      params=PlantParams().with_values(**{"friction.rate_gain": 2.5}))
    tm.write_recording(tmp_path / "rec.csv", rec)
    tm.write_plant_file(tmp_path / "plant.json", PlantParams())
    from tapmuscle.diagnosis.fit_problem import SimulationError
    failing = _own_candidate("slack", "backlash.slack_mm", 0.0, 5.0,
                             raises=SimulationError("the plant with backlash.slack_mm=4: a sub-step | failed"))
    d, doc = tm.diagnose_files(tmp_path / "rec.csv", tmp_path / "plant.json", tmp_path / "out", plots=False,
                               effects=["transport_delay"], calibration=None,
                               candidates=[_own_candidate("speed_friction", "friction.rate_gain", 0.0, 3.0), failing])
    assert {c["effect"] for c in doc["candidates_tried"]} == {"transport_delay", "speed_friction", "slack"}
    assert d.named == ["speed_friction"]
    # the report says why a candidate was not fitted (its table's cell, the bar escaped)
    assert "| `slack` | not fitted (the plant with backlash.slack_mm=4: a sub-step \\| failed) |" in \
        (tmp_path / "out" / "report.md").read_text()
    broken = _own_candidate("speed_friction", "friction.rate_gain", 0.0, 3.0, raises=KeyError("gain"))
    with pytest.raises(tm.TapmuscleError, match=r"^candidate 'speed_friction': its fit raised KeyError: 'gain'$"):
        tm.diagnose_files(tmp_path / "rec.csv", tmp_path / "plant.json", tmp_path / "out2", plots=False,
                          effects="transport_delay", calibration=None, candidates=[broken])
    assert not (tmp_path / "out2").exists()


def test_a_candidate_of_ones_own_named_joint_is_refitted_with_the_constants():
    """A rig whose friction grows with speed (rate gain 1.5 against the nominal 0.8) and three
    constants off by 10-15 %, diagnosed with a candidate of one's own for the rate gain beside four
    built-ins: fitted on the calibrated constants alone it comes out near the nominal 0.8 (the
    constants took up the effect) and is not named; with ``joint`` it is re-fitted with them, named,
    near the rig's value, and the held-out fit rises. The same with two worker processes (the
    built-ins' fits there, one's own here)."""
    from fmu_plant import PlantParams

    import tapmuscle as tm

    nominal = PlantParams()
    rig = nominal.with_values(**{"friction.rate_gain": 1.5, "valve.cv_max": nominal.valve.cv_max * 0.9,
                                 "muscle.rubber_stiffness_n_per_mm": nominal.muscle.rubber_stiffness_n_per_mm * 0.88,
                                 "friction.base_n": nominal.friction.base_n * 1.15})
    rec = tm.simulate("random", duration_s=180.0, params=rig, seed=3)
    builtins = ["transport_delay", "valve_dead_zone", "sensor_drift", "load_mismatch"]
    mine = _own_candidate("speed_friction", "friction.rate_gain", 0.0, 3.0)
    alone = tm.diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], nominal, candidates=[mine, *builtins])
    joint = dataclasses.replace(mine, joint=(("friction.rate_gain", 0.15),))
    refitted = tm.diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], nominal, candidates=[joint, *builtins])
    # measured: alone 0.806 fitted, not named, 99.08 %; joint named at 1.325, 99.85 %
    fitted = [c["parameters"]["friction.rate_gain"] for c in alone.candidates if c["effect"] == "speed_friction"
              and c.get("parameters")]
    assert "speed_friction" not in alone.named and max(fitted) < 1.1, (alone.named, fitted)
    assert "speed_friction" in refitted.named, refitted.named
    assert 1.5 * 0.75 < refitted.calibrated.friction.rate_gain < 1.5 * 1.25, refitted.calibrated.friction.rate_gain
    assert refitted.fit_after_percent > alone.fit_after_percent + 0.3 and refitted.fit_after_percent > 99.5
    on_workers = tm.diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], nominal, candidates=[joint, *builtins], workers=2)
    assert on_workers.named == refitted.named and on_workers.fit_after_percent == refitted.fit_after_percent
    assert on_workers.calibrated == refitted.calibrated


def test_a_refine_of_ones_own_is_held_to_its_contract_and_a_failed_simulation_in_it_keeps_the_values():
    """An own ``refine`` whose simulation fails leaves the values where they are (the diagnosis goes
    on, as for a fit whose simulation fails), not stopping the diagnosis with a RuntimeError; one
    that returns no dict, and a fit that returns no FitResult, are refused naming the candidate."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.calibration import NOMINAL_PARAMETERS
    from tapmuscle.diagnosis.candidates import CandidateError
    from tapmuscle.diagnosis.fit_problem import SimulationError

    import tapmuscle as tm

    key = "friction.rate_gain"
    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=60.0, params=PlantParams().with_values(**{key: 2.0}))
    t, u, y = rec["t_s"], rec["u_v"], rec["l_mm"]
    mine = _own_candidate("speed_friction", key, 0.0, 3.0, 2.0)

    def refine_fails(problem, params):
        raise SimulationError("the plant with friction.rate_gain=2.1: a sub-step failed")

    d = diagnose(t, u, y, PlantParams(), candidates=[dataclasses.replace(mine, refine=refine_fails)],
                 calibration=NOMINAL_PARAMETERS[:1])
    assert d.named == ["speed_friction"] and d.calibrated.friction.rate_gain == 2.0
    assert [s["kept"] for s in d.selection if s.get("step") == "refine on the final constants"] == [False]
    with pytest.raises(CandidateError, match=r"candidate 'speed_friction': its refine returned tuple "
                                             r"\('friction\.rate_gain', 2\.0\), not a dict"):
        diagnose(t, u, y, PlantParams(), candidates=[dataclasses.replace(mine, refine=lambda problem, params: (key, 2.0))],
                 calibration=NOMINAL_PARAMETERS[:1])
    with pytest.raises(CandidateError, match=r"candidate 'speed_friction': its fit returned tuple .*, not a FitResult "
                                             r"or None"):
        diagnose(t, u, y, PlantParams(), calibration=None,
                 candidates=[dataclasses.replace(mine, fit=lambda problem, base, y_base: ({key: 2.0}, y_base))])


def test_numpy_numbers_are_bounds_and_scales_and_one_name_or_candidate_goes_to_diagnose_files(tmp_path):
    """Bounds and a joint scale given as numpy numbers (np.int64, np.float32) are numbers; a single
    name or a single candidate in diagnose_files' candidates is one candidate (a name must not be split
    into letters: "unknown effect 'b'", blamed on the recording)."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.candidates import ParameterSpec
    from tapmuscle.diagnosis.own_candidates import check_own_candidates

    import tapmuscle as tm

    key = "friction.rate_gain"
    mine = _own_candidate("speed_friction", key, 0.0, 3.0)
    numpy_numbers = dataclasses.replace(mine, parameters=(ParameterSpec(key, "-", np.int64(0), np.float32(3.0)),),
                                        joint=((key, np.float32(0.15)),))
    check_own_candidates([numpy_numbers], PlantParams())
    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=60.0, params=PlantParams().with_values(**{key: 2.5}))
    tm.write_recording(tmp_path / "rec.csv", rec)
    tm.write_plant_file(tmp_path / "plant.json", PlantParams())
    for i, candidates in enumerate(("backlash", mine)):
        doc = tm.diagnose_files(tmp_path / "rec.csv", tmp_path / "plant.json", tmp_path / f"out{i}", plots=False,
                                effects=["transport_delay"], calibration=None, candidates=candidates)[1]
        tried = {c["effect"] for c in doc["candidates_tried"]}
        assert tried == {"transport_delay", "backlash" if i == 0 else "speed_friction"}, tried


CANDIDATE_FILE = '''
import numpy as np
from scipy import optimize
from tapmuscle.diagnosis.candidates import Candidate, FitResult, ParameterSpec, full_prediction

KEY = "friction.rate_gain"


def fit(problem, base, y_base):
    def cost(x):
        y = problem.sim.run(base.with_values(**{KEY: float(x)}), stop=problem.n_fit)[0]
        return float(np.sum(problem.train_residual(y) ** 2))
    x = float(optimize.minimize_scalar(cost, bounds=(0.0, 3.0), method="bounded").x)
    if cost(x) >= cost(base.value(KEY)):
        return None
    return FitResult({KEY: x}, full_prediction(problem, base, {KEY: x}))


candidates = [Candidate("speed_friction", "friction growing with speed", (ParameterSpec(KEY, "-", 0.0, 3.0),),
                        "a scalar search", fit, lambda v: f"rate gain {v[KEY]:.2f}")]
'''


def test_the_command_line_takes_candidates_of_ones_own_from_a_file(tmp_path, capsys):
    """``tapmuscle diagnose --candidates FILE.py`` (not built-in names only): the
    file's ``candidates`` tried beside the built-ins or those ``--effects`` names, its own included; a
    file that is missing, fails at a line, or defines no list is refused naming it, nothing written."""
    from fmu_plant import PlantParams
    from tapmuscle.cli.main import main

    import tapmuscle as tm

    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=60.0,
                      params=PlantParams().with_values(**{"friction.rate_gain": 2.5}))
    tm.write_recording(tmp_path / "rec.csv", rec)
    tm.write_plant_file(tmp_path / "plant.json", PlantParams())
    (tmp_path / "mine.py").write_text(CANDIDATE_FILE)
    base = ["diagnose", "--recording", str(tmp_path / "rec.csv"), "--plant", str(tmp_path / "plant.json"),
            "--no-calibration", "--no-plots", "--quiet", "--workers", "1"]
    assert main(base + ["--candidates", str(tmp_path / "mine.py"), "--effects", "transport_delay,speed_friction",
                        "--out", str(tmp_path / "out")]) == 0
    doc = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert {c["effect"] for c in doc["candidates_tried"]} == {"transport_delay", "speed_friction"}
    assert [f["effect"] for f in doc["findings"]] == ["speed_friction"]
    assert "speed_friction" in capsys.readouterr().out
    (tmp_path / "broken.py").write_text("import numpy\n\ncandidates = [1 / 0]\n")
    (tmp_path / "empty.py").write_text("mine = []\n")
    for file, said in (("nowhere.py", "no such file"), ("broken.py", "broken.py, line 3: ZeroDivisionError: division by zero"),
                       ("empty.py", "it defines no 'candidates'")):
        assert main(base + ["--candidates", str(tmp_path / file), "--out", str(tmp_path / "refused")]) == 2
        assert f"--candidates {tmp_path / file}" in (err := capsys.readouterr().err) and said in err, err
    assert main(base + ["--effects", "speed_friction", "--out", str(tmp_path / "refused")]) == 2
    assert "unknown effect 'speed_friction'" in (err := capsys.readouterr().err) and "--candidates FILE.py" in err
    assert not (tmp_path / "refused").exists()


def test_the_rediagnosis_command_of_an_experiment_asks_for_the_candidates_file_where_one_is_yours():
    """The printed re-diagnosis of a discriminating experiment must not name the effects only, which the
    command line refuses for a candidate of one's own without its file."""
    from pathlib import Path

    from tapmuscle.diagnosis.report import _rediagnose_command

    plant = Path("out") / "discriminate_plant.json"
    assert _rediagnose_command(plant, ["transport_delay", "sensor_drift"]) == (
        "tapmuscle diagnose --recording NEW.csv --plant out/discriminate_plant.json --effects "
        "transport_delay,sensor_drift --out NEW_DIAGNOSIS")
    assert _rediagnose_command(plant, ["transport_delay", "speed_friction"]).endswith(
        "--effects transport_delay,speed_friction --candidates YOUR_CANDIDATES.py --out NEW_DIAGNOSIS")
