"""``tapmuscle diagnose`` on FMUs that are not tapmuscle's: the DC motor in C and the thermal two-mass
model in pythonfmu (tapmuscle/diagnosis/foreign_fmus), with boundary effects concealed in recordings
made through the same FMUs (docs/diagnosis.md, "Foreign plant FMUs")."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tapmuscle.diagnosis.boundary_effects import (backlash, dead_band_map, fractional_delay, identity_map,
                                                  input_map, map_knots)
from tapmuscle.diagnosis.foreign_demo import ForeignCase, build_demo_fmus, foreign_cases, record_foreign_case
from tapmuscle.diagnosis.boundary_candidates import BoundarySpace, nominal_values
from tapmuscle.diagnosis.foreign_diagnose import diagnose_foreign, diagnose_foreign_outputs
from tapmuscle.diagnosis.foreign_model import ForeignFmuError, ForeignSimulator, read_interface
from tapmuscle.diagnosis.signal_map import SignalMapError, read_signal_map
from tapmuscle.io.recording import read_columns
from tapmuscle.provenance import software

pytestmark = [pytest.mark.c_host, pytest.mark.foreign]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return build_demo_fmus(tmp_path_factory.mktemp("foreign_fmus"))


def _case(plant: str, effect: str | None, truth: dict, errors: dict, seed: int = 7, record_p2: bool = True):
    return ForeignCase(f"t_{plant}_{effect}", plant, effect, truth, errors, "steps", record_p2, [seed, 0])


# ------------------------------------------------------------------------------ boundary effects
def test_fractional_delay_interpolates_between_whole_samples():
    u = np.arange(10.0)
    assert np.array_equal(fractional_delay(u, 0.2, 0.1), np.r_[0.0, 0.0, np.arange(8.0)])
    d = fractional_delay(u, 0.25, 0.1)  # 2.5 samples: the mean of the samples 2 and 3 back
    assert d[5] == pytest.approx(2.5)


@pytest.mark.parametrize("seed", range(5))
def test_every_map_coordinate_set_is_monotone(seed):
    rng = np.random.default_rng(seed)
    values = dict(zip(("map_k1_in", "map_gap", "map_out_lo", "map_rise1", "map_rise2", "map_rise3"),
                      rng.uniform(-3, 15, 6)))
    u = np.linspace(-1, 11, 500)
    assert np.all(np.diff(input_map(u, values, 0.0, 10.0)) >= 0.0)


def test_identity_and_dead_band_maps():
    u = np.linspace(0, 10, 101)
    assert np.allclose(input_map(u, identity_map(0.0, 10.0), 0.0, 10.0), u)
    m = input_map(u, dead_band_map(5.0, 1.2, 0.0, 10.0), 0.0, 10.0)
    assert np.allclose(m[(u > 4.4) & (u < 5.6)], 5.0)  # inside the band: the centre
    assert np.allclose(m[u >= 5.6], u[u >= 5.6] - 0.6) and np.allclose(m[u <= 4.4], u[u <= 4.4] + 0.6)
    xs, _ = map_knots(dead_band_map(5.0, 1.2, 0.0, 10.0), 0.0, 10.0)
    assert xs[1] == pytest.approx(4.4) and xs[2] == pytest.approx(5.6)


def test_backlash_holds_within_the_play():
    u = np.r_[np.linspace(0, 5, 51), np.linspace(5, 4, 11)]
    out = backlash(u, 1.0)
    assert out[50] == pytest.approx(4.5)
    assert np.allclose(out[51:], 4.5)  # a 1-unit reversal stays inside the play


# ------------------------------------------------------------------------------ the mapping
def test_map_errors_name_the_file_and_key(fmus, tmp_path):
    iface = read_interface(fmus["DcMotor"])
    cols = ["t_s", "volts", "speed"]
    cases = {
        '[inputs]\nVx = "volts"\n[outputs]\nomega = "speed"\n': "has no Real input 'Vx'",
        '[inputs]\nV = "missing"\n[outputs]\nomega = "speed"\n': "no column 'missing'",
        '[inputs]\nV = { column = "volts", unit = "mV" }\n[outputs]\nomega = "speed"\n': "is in 'mV'",
        '[inputs]\nV = "volts"\n[outputs]\nomega = "speed"\n[parameters]\nQ = 1\n': "no tunable or fixed Real parameter 'Q'",
        'ts_s = -1\n[inputs]\nV = "volts"\n[outputs]\nomega = "speed"\n': "ts_s = -1",
        '[inputs]\nV = "volts"\n': "[outputs] is missing",
    }
    for text, message in cases.items():
        p = tmp_path / "map.toml"
        p.write_text(text)
        with pytest.raises(SignalMapError, match=r"map\.toml") as info:
            read_signal_map(p, iface, cols)
        assert message in str(info.value)


def test_a_sine_locked_to_the_split_gets_balanced_blocks_as_for_the_muscle(fmus, tmp_path):
    """Seed 2's case 006 drives the motor with a sine sum whose training blocks see 0.21 more of its
    rise than the held-out ones (``direction_imbalance``) at 10 s: the setup takes the first
    balanced length, 9 s, as ``diagnose`` does for the muscle; a length given is kept."""
    from tapmuscle.diagnosis.foreign_diagnose import ForeignSetup
    from tapmuscle.diagnosis.residual_analysis import SPLIT_BALANCE, direction_imbalance

    case = foreign_cases(8, 2)[6]
    assert case.plant == "DcMotor" and case.excitation == "sines"
    rec, m = record_foreign_case(case, fmus["DcMotor"], tmp_path / "rec")
    setup = ForeignSetup(rec, fmus["DcMotor"], map_path=m, echo=lambda s: None)
    assert direction_imbalance(setup.u, setup.ts, 10.0) > SPLIT_BALANCE
    assert setup.block_s == 9.0 and direction_imbalance(setup.u, setup.ts, 9.0) <= SPLIT_BALANCE
    assert ForeignSetup(rec, fmus["DcMotor"], map_path=m, block_s=10.0, echo=lambda s: None).block_s == 10.0


# ------------------------------------------------------------------------------ diagnoses
@pytest.mark.slow
def test_delay_on_the_c_motor_is_named_and_fitted(fmus, tmp_path):
    case = _case("DcMotor", "transport_delay[V]", {"V:delay_s": 0.15}, {"K": 0.1, "Tc": -0.15})
    # 90 s of voltage steps (half the demo's): the delay to a few milliseconds, calibration included,
    # in a quarter of the time
    rec, m = record_foreign_case(case, fmus["DcMotor"], tmp_path / "rec", duration_s=90.0)
    d, doc = diagnose_foreign(rec, fmus["DcMotor"], tmp_path / "out", map_path=m, echo=lambda s: None)
    assert d.named == ["transport_delay[V]"]
    delay = d.findings[0].parameters["V:delay_s"]
    assert abs(delay - 0.15) < 0.01  # a fifth of a sample
    assert d.fit_after_percent >= 95.0 and d.fit_before_percent < 95.0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["calibrated_parameters.json", "diagnosis.json",
                                                                     "overlay.png", "report.md"]
    cal = json.loads((tmp_path / "out" / "calibrated_parameters.json").read_text())
    assert cal["boundary_effects"]["V:delay_s"] == pytest.approx(delay)
    assert doc["output"] == {"variable": "omega", "column": "meas", "unit": "rad/s"}


def test_clean_thermal_recording_claims_nothing(fmus, tmp_path):
    case = _case("ThermalTwoMass", None, {}, {"C1": 0.12, "G12": -0.1})
    rec, m = record_foreign_case(case, fmus["ThermalTwoMass"], tmp_path / "rec")
    d, _ = diagnose_foreign(rec, fmus["ThermalTwoMass"], tmp_path / "out", map_path=m, plots=False, echo=lambda s: None)
    assert d.verdict in ("no_significant_mismatch", "calibration_only") and not d.named
    assert d.fit_after_percent >= 99.0


@pytest.mark.slow
def test_unrecorded_second_input_is_found_as_a_secondary_input(fmus, tmp_path):
    case = _case("ThermalTwoMass", "secondary_input[P2]", {"P2:change": 20.0, "P2:start_s": 400.0, "P2:end_s": 700.0},
                 {"G1a": 0.1}, record_p2=False)
    rec, m = record_foreign_case(case, fmus["ThermalTwoMass"], tmp_path / "rec")
    d, _ = diagnose_foreign(rec, fmus["ThermalTwoMass"], tmp_path / "out", map_path=m, plots=False, echo=lambda s: None)
    assert "secondary_input[P2]" in d.named
    p = next(f.parameters for f in d.findings if f.effect == "secondary_input[P2]")
    # The plant's 170-900 s time constants smooth a 300-s heater window: its edges trade with its
    # height, so only where and which way are asserted (the window overlaps the truth's, heat added).
    overlap = min(p["P2:end_s"], 700.0) - max(p["P2:start_s"], 400.0)
    union = max(p["P2:end_s"], 700.0) - min(p["P2:start_s"], 400.0)
    assert overlap / union >= 0.3
    assert p["P2:change"] > 5.0


def test_columns_matched_by_name_and_the_mapping_printed(fmus, tmp_path):
    case = _case("DcMotor", None, {}, {})
    rec, _ = record_foreign_case(case, fmus["DcMotor"], tmp_path / "rec")
    text = rec.read_text().replace("time_s,V_rec,meas", "t_s,V,omega")
    rec.write_text(text)
    lines = []
    d, doc = diagnose_foreign(rec, fmus["DcMotor"], tmp_path / "out", plots=False, echo=lines.append)
    assert "input  V <- column V [V]" in "\n".join(lines) and "one simulation of the 3601-sample" in "\n".join(lines)
    assert doc["mapping"]["source"] == "matched by name"
    assert d.verdict in ("no_significant_mismatch", "calibration_only")


def test_bad_inputs_fail_cleanly_and_leave_no_output(fmus, tmp_path):
    case = _case("DcMotor", None, {}, {})
    rec, m = record_foreign_case(case, fmus["DcMotor"], tmp_path / "rec")
    out = tmp_path / "out"
    # a recording sampled otherwise than the map states
    m2 = tmp_path / "m2.toml"
    m2.write_text(m.read_text().replace("ts_s = 0.05", "ts_s = 0.1"))
    with pytest.raises(SignalMapError, match="sampled every 0.05 s, but .*m2.toml states ts_s = 0.1 s"):
        diagnose_foreign(rec, fmus["DcMotor"], out, map_path=m2, echo=lambda s: None)
    # not an FMU
    bad = tmp_path / "bad.fmu"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ForeignFmuError, match="bad.fmu"):
        diagnose_foreign(rec, bad, out, map_path=m, echo=lambda s: None)
    # an FMU that cannot run the recording with the map's parameters (the C FMU refuses R <= 0)
    m3 = tmp_path / "m3.toml"
    m3.write_text(m.read_text() + "\n[parameters]\nR = -1.0\n")
    with pytest.raises(ForeignFmuError, match="cannot re-simulate .* R = -1"):
        diagnose_foreign(rec, fmus["DcMotor"], out, map_path=m3, echo=lambda s: None)
    # a recording too short for the held-out blocks: the error names the file, as the command line does
    lines = Path(rec).read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[:head + 201]) + "\n")
    with pytest.raises(ValueError, match=rf"^{re.escape(str(short))}: .*the diagnosis needs at least"):
        diagnose_foreign(short, fmus["DcMotor"], out, map_path=m, echo=lambda s: None)
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_parameters_the_fmu_cannot_run_raise_simulation_error_and_the_instance_recovers(fmus, tmp_path):
    """The C motor returns fmi2Error when its state diverges (an electrical time constant L/R far below
    its 0.5 ms internal step): the simulator names the parameters and the FMU's message, the
    search turns that into a rejected candidate (or a large finite residual inside a fit), and the
    next run works on a fresh instance."""
    from tapmuscle.diagnosis.foreign_diagnose import ForeignSetup
    from tapmuscle.diagnosis.fit_problem import SimulationError

    case = _case("DcMotor", None, {}, {})
    rec, m = record_foreign_case(case, fmus["DcMotor"], tmp_path / "rec")
    setup = ForeignSetup(rec, fmus["DcMotor"], map_path=m, echo=lambda s: None)
    with pytest.raises(SimulationError, match=r"L = 1e-07"):
        setup.sim.run(setup.nominal.with_values(L=1e-7))
    y = setup.sim.run(setup.nominal)[0]  # the instance recovers: re-created after the failure
    assert np.all(np.isfinite(y))
    setup.sim.close()


@pytest.mark.slow
def test_cli_runs_a_foreign_fmu_and_reports_bad_map_without_traceback(fmus, tmp_path):
    """The command line on the C motor. The FMU's constants are the recording's (calibration with an
    effect on a foreign FMU is the delay test's, above), so the command runs without its calibration
    step: the whole search over every boundary effect takes seconds (with calibration, 1-2 minutes)."""
    case = _case("DcMotor", "output_drift[omega]", {"omega:offset": 1.0, "omega:drift_per_min": 0.6}, {})
    rec, m = record_foreign_case(case, fmus["DcMotor"], tmp_path / "rec")
    r = subprocess.run([sys.executable, "-m", "tapmuscle.cli", "diagnose", "--recording", str(rec), "--plant",
                        str(fmus["DcMotor"]), "--map", str(m), "--out", str(tmp_path / "out"), "--quiet", "--no-plots",
                        "--no-calibration"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "output_drift[omega]" in r.stdout and "one simulation of the 3601-sample recording" in r.stdout
    doc = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert doc["split"]["block_s"] == 10.0  # the default blocks
    assert doc["software"] == software()
    assert [f["effect"] for f in doc["findings"]] == ["output_drift[omega]"]
    drift = doc["findings"][0]["parameters"]
    # 0.05 rad/s of sensor noise over 3 minutes: the slope to a few thousandths of its 0.6 rad/s/min
    assert math.isclose(drift["omega:drift_per_min"], 0.6, abs_tol=0.02)
    assert math.isclose(drift["omega:offset"], 1.0, abs_tol=0.02)
    m.write_text(m.read_text().replace('column = "meas"', 'column = "nope"'))
    r = subprocess.run([sys.executable, "-m", "tapmuscle.cli", "diagnose", "--recording", str(rec), "--plant",
                        str(fmus["DcMotor"]), "--map", str(m), "--out", str(tmp_path / "out2"), "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "no column 'nope'" in r.stderr and not (tmp_path / "out2").exists()


def test_demo_cases_are_seeded_and_cover_both_fmus():
    a, b = foreign_cases(16, 3), foreign_cases(16, 3)
    assert a == b
    assert {c.plant for c in a} == {"DcMotor", "ThermalTwoMass"}
    assert sum(c.effect is None for c in a) == 4


@pytest.mark.slow
def test_the_recordings_units_name_what_the_fmu_leaves_without_one(fmus):
    """An FMU that declares no units (a hand-written pythonfmu plant): the candidates' parameters took
    "(unit)" although the signal map gave the recording's units."""
    from dataclasses import replace

    from tapmuscle.diagnosis.boundary_candidates import boundary_candidates

    iface = read_interface(fmus["DcMotor"])
    bare = replace(iface, inputs=tuple(replace(v, unit=None) for v in iface.inputs),
                   outputs=tuple(replace(v, unit=None) for v in iface.outputs))
    t = np.arange(100) * 0.05
    sim = ForeignSimulator(bare, t, 0.05, {"V": np.ones(100)}, "omega", {"V": (0.0, 2.0)}, units={"V": "V", "omega": "rad/s"})
    specs = {spec.key: spec.unit for c in boundary_candidates(sim) for spec in c.parameters}
    assert specs["V:backlash"] == "V" and specs["omega:offset"] == "rad/s" and specs["omega:drift_per_min"] == "rad/s/min"
    assert "(unit)" not in specs.values()
    sim = replace(sim, units={})
    assert {spec.unit for c in boundary_candidates(sim) for spec in c.parameters} >= {"(unit)"}


def test_every_mapped_output_diagnosed_with_a_summary(fmus, tmp_path):
    """Speed and current both measured, a delay on the voltage: an input effect, so it is named on
    both outputs, and the summary says so; a bad --output names the mapped ones."""
    case = _case("DcMotor", "transport_delay[V]", {"V:delay_s": 0.15}, {})
    rec, m = record_foreign_case(case, fmus["DcMotor"], tmp_path / "rec", duration_s=60.0)
    cols, _ = read_columns(rec)
    t = cols["time_s"]
    sim = ForeignSimulator(read_interface(fmus["DcMotor"]), t, 0.05, {"V": cols["V_rec"]}, "i",
                           {"V": (0.0, 12.0)})
    current = sim.run(nominal_values(sim, BoundarySpace(sim)).with_values(**{"V:delay_s": 0.15}))[0]
    sim.close()
    current = current + np.random.default_rng(5).normal(0.0, 0.02, len(current))
    lines = rec.read_text().splitlines()
    body = [ln for ln in lines if not ln.startswith("#")]
    rec.write_text("\n".join([lines[0], body[0] + ",cur"] + [f"{row},{c:.6g}" for row, c in zip(body[1:], current)])
                   + "\n")
    m.write_text(m.read_text() + 'i = { column = "cur", unit = "A" }\n')
    with pytest.raises(SignalMapError, match="'theta': not a mapped output .*mapped: omega, i"):
        diagnose_foreign_outputs(rec, fmus["DcMotor"], tmp_path / "bad", map_path=m, outputs=["theta"],
                                 echo=lambda s: None)
    assert not (tmp_path / "bad").exists()
    results = diagnose_foreign_outputs(rec, fmus["DcMotor"], tmp_path / "out", map_path=m, calibrate=False,
                                       plots=False, effects=["transport_delay[V]", "output_drift[omega]",
                                                             "output_drift[i]"], echo=lambda s: None)
    assert list(results) == ["omega", "i"]
    for variable, (d, doc) in results.items():
        assert d.named == ["transport_delay[V]"], variable
        assert doc["output"]["variable"] == variable
        assert abs(d.findings[0].parameters["V:delay_s"] - 0.15) < 0.01
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["input_effects"] == {"transport_delay[V]": {"named_on": ["omega", "i"], "on_every_output": True}}
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["i", "omega", "summary.json", "summary.md"]
    assert "named on omega, i (every output)" in (tmp_path / "out" / "summary.md").read_text()
    r = subprocess.run([sys.executable, "-m", "tapmuscle.cli", "diagnose", "--recording", str(rec), "--plant",
                        str(fmus["DcMotor"]), "--map", str(m), "--output", "all", "--out", str(tmp_path / "cli"),
                        "--quiet", "--no-plots", "--no-calibration", "--effects", "transport_delay[V]"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "== output omega" in r.stdout and "== output i" in r.stdout and "(every output)" in r.stdout


def test_a_goal_without_cases_is_not_scored_as_missed():
    """Two clean recordings only: the 'named' goal has no case, so it is neither met nor missed."""
    from tapmuscle.diagnosis.foreign_demo import foreign_scores_markdown, score_foreign

    results = [{"case": {"name": f"clean_{k}", "effect": None}, "verdict": "no_significant_mismatch",
                "named": [], "ambiguous": [], "fit_after_percent": 99.0} for k in range(2)]
    scores = score_foreign(results)
    assert scores["named"] == [0, 0] and scores["rates"]["named"] is None and scores["clean"] == [2, 2]
    table = foreign_scores_markdown(scores)
    assert "| concealed effect named | 0 / 0 | - | >= 90 % | - (no case) |" in table
    assert "| clean -> nothing claimed | 2 / 2 | 100.0 % |" in table and "**no**" not in table
