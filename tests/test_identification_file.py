"""``tapmuscle identify --json`` read back as a controller's theta0 (tapmuscle/io/identification_file.py):
its period, units and model are checked, and a scenario's ``controller.identification`` runs the
controller FMU on it as the direct loop runs on the same model."""

from __future__ import annotations

import json
import math
import re
import warnings

import numpy as np
import pytest

import tapmuscle as tm
from fmu_controller.displacement_control import ControllerSettings, DisplacementController
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.reference import SineReference
from fmu_plant import Plant
from tapmuscle.cli.main import main
from tapmuscle.closed_loop import run_closed_loop
from tapmuscle.cosim import ScenarioError, co_simulate, load_scenario
from tapmuscle.cosim.run import run_scenario
from tapmuscle.io.identification_file import IdentificationFileError, read_identification
from tapmuscle.provenance import software


@pytest.fixture(scope="module")
def id_files(tmp_path_factory):
    """Identification files at 0.05 s (no box: off Ts = 0.1 s) and 0.1 s (Table 2's box)."""
    folder = tmp_path_factory.mktemp("idfile")
    out = {}
    for ts in (0.05, 0.1):
        rec = folder / f"rec{ts}.csv"
        assert main(["record", "--input", "sine:bias=5,amp=3,freq=0.1", "--duration", "240", "--ts", str(ts),
                     "--out", str(rec), "--quiet"]) == 0
        out[ts] = folder / f"id{ts}.json"
        assert main(["identify", str(rec), "--json", str(out[ts])]) == 0
    return out


def test_the_file_gives_theta_period_and_box(id_files):
    m = read_identification(id_files[0.1])
    doc = json.loads(id_files[0.1].read_text())
    assert m.ts_s == 0.1 and m.theta == doc["theta"] and list(m.theta) == list(ASYMMETRIC.names)
    assert doc["software"] == software()  # what identified it, for a result that differs elsewhere
    assert m.box_lower == doc["constraint"]["lower"] and m.box_lower["b1"] == 0.607 and m.box_upper["b1"] == 1.184
    m05 = tm.read_identification(id_files[0.05])
    assert m05.ts_s == 0.05 and m05.box_lower == {} and m05.box_upper == {}
    m05.check_period(0.05)
    m05.check_period(0.05 * (1 + 1e-9))
    with pytest.raises(IdentificationFileError, match="identified at ts_s = 0.05 s"):
        m05.check_period(0.05 * (1 + 1e-4))  # 5 us a sample: a clock's drift, not the same period
    with pytest.raises(IdentificationFileError, match=r"identified at ts_s = 0.05 s, the controller samples at 0.2 s"):
        m05.check_period(0.2)
    # simulate_closed_loop without ts_s runs at the file's period (it said "the controller samples at 0.1 s")
    run = tm.simulate_closed_loop("ampc_servo", None, duration_s=1.0, theta0=m05, watch=False)
    assert run["t_s"][1] == pytest.approx(0.05)



def test_a_one_sided_box_goes_from_identify_to_the_controller(id_files, tmp_path):
    """`identify --box a1=-inf:1.26`: the file keeps the finite bound only (strict JSON, read back as the
    one-sided box), and a strict-JSON writer's "-inf" / "inf" is read as no bound on that side."""
    rec = id_files[0.1].parent / "rec0.1.csv"
    path = tmp_path / "one_sided.json"
    assert main(["identify", str(rec), "--box", "a1=-inf:1.26", "--json", str(path)]) == 0
    doc = json.loads(path.read_text(), parse_constant=lambda name: pytest.fail(f"not strict JSON: {name}"))
    assert doc["constraint"]["lower"] == {} and doc["constraint"]["upper"] == {"a1": 1.26}
    model = read_identification(path)
    assert model.box_lower == {} and model.box_upper == {"a1": 1.26}
    doc["constraint"]["lower"] = {"a1": "-inf", "b1": 0.6}
    doc["constraint"]["upper"] = {"a1": 1.26, "b1": "inf"}
    path.write_text(json.dumps(doc))
    model = read_identification(path)
    assert model.box_lower == {"b1": 0.6} and model.box_upper == {"a1": 1.26}
    doc["constraint"]["lower"] = {"a1": "inf"}  # the wrong side's infinity is no bound of any kind
    path.write_text(json.dumps(doc))
    with pytest.raises(IdentificationFileError, match=r"'constraint.lower' must map parameter names to numbers"):
        read_identification(path)

def test_a_small_stroke_in_mm_is_read(id_files, tmp_path):
    """identify normalises by magnitude: a stroke under about 19 mm gets l_scale 0.1, its theta still in
    mm (not refused as 'other units')."""
    doc = json.loads(id_files[0.1].read_text()) | {"scaling": {"l_scale": 0.1, "u_scale": 1.0}}
    (tmp_path / "small.json").write_text(json.dumps(doc))
    assert read_identification(tmp_path / "small.json").theta == doc["theta"]


@pytest.mark.parametrize("change, message", [
    (lambda d: d | {"model": "standard"}, "the controllers use the asymmetric model"),
    (lambda d: {k: v for k, v in d.items() if k != "ts_s"}, r"key 'ts_s' missing: not a `tapmuscle identify --json` file"),
    (lambda d: d | {"theta": {k: v for k, v in d["theta"].items() if k != "xi32"}}, "missing: xi32"),
    (lambda d: d | {"theta": d["theta"] | {"b1": "0.6"}}, r"theta.b1' must be a finite number, got '0.6'"),
    # the controller FMU's range: a scenario named its own key for it, not the file
    (lambda d: d | {"theta": d["theta"] | {"a1": 1e7}}, r"theta.a1' = 10000000.0 is outside -1e\+06..1e\+06, the "
                                                       r"controllers' range of theta0"),
    (lambda d: d | {"theta": d["theta"] | {"theta_a1": 1.2}}, r"missing: none; extra: theta_a1"),  # a prefix
    (lambda d: d | {"theta": d["theta"] | {"b1": True}}, r"theta.b1' must be a finite number, got True"),
    (lambda d: d | {"theta": d["theta"] | {"xi31": -1e7}}, r"theta.xi31' = -10000000.0 is outside -1e\+06"),
    (lambda d: d | {"ts_s": -0.1}, "'ts_s' must be a positive number of seconds"),
    (lambda d: d | {"ts_s": 0}, "'ts_s' must be a positive number of seconds"),
    (lambda d: {"verdict": "mismatch"}, "keys 'model', 'theta', 'ts_s' missing: not a `tapmuscle identify --json` file"),
])
def test_a_file_that_cannot_be_a_theta0_is_refused_naming_the_key(id_files, tmp_path, change, message):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(change(json.loads(id_files[0.1].read_text()))))
    with pytest.raises(IdentificationFileError, match=message):
        read_identification(bad)


def test_no_file_or_no_json_is_named(tmp_path):
    with pytest.raises(IdentificationFileError, match="no such identification file"):
        read_identification(tmp_path / "none.json")
    (tmp_path / "x.json").write_text("{\n oops")
    with pytest.raises(IdentificationFileError, match=r"x.json: not valid JSON \(line 2"):
        read_identification(tmp_path / "x.json")
    assert issubclass(IdentificationFileError, tm.TapmuscleError)


@pytest.mark.filterwarnings("ignore::tapmuscle.errors.FmuLogWarning")  # whether the guard fires: CPU-dependent
def test_a_scenario_runs_the_controller_on_the_identified_model(built_fmus, id_files, tmp_path):
    """``controller.identification`` at 0.05 s (no box: the FMU's box_* = -inf/inf) gives the direct
    loop with that theta0 and an empty box, bit for bit; another step_s is refused naming both."""
    path = tmp_path / "own_rig.toml"
    path.write_text(f'duration_s = 20.0\nstep_s = 0.05\nseed = 1\n[controller]\nmethod = "ampc_servo"\n'
                    f'identification = "{id_files[0.05]}"\n')
    scenario = load_scenario(path)
    assert scenario.controller.parameters["box_lower.b1"] == -math.inf
    assert scenario.controller.parameters_file == id_files[0.05]  # summary.json's scenario_spec names it
    cols = co_simulate(scenario, built_fmus)
    model = read_identification(id_files[0.05])
    plant = Plant(seed=1)
    settings = ControllerSettings(method="ampc_servo", ts_s=0.05, box_lower={}, box_upper={})
    direct = run_closed_loop(plant, DisplacementController(settings, model.theta),
                             SineReference(frequency_hz=0.1, ts_s=0.05), duration_s=20.0)
    assert np.array_equal(cols["u_v"], direct["u_v"]) and np.array_equal(cols["l_mm"], direct["l_mm"])
    # summary.json is strict JSON (a JavaScript or jq reader refuses Python's -Infinity): no box is "-inf"
    run_scenario(scenario, tmp_path / "run", built_fmus, plots=False)
    doc = json.loads((tmp_path / "run" / "summary.json").read_text(),
                     parse_constant=lambda name: pytest.fail(f"summary.json holds {name}"))
    assert doc["scenario_spec"]["controller"]["parameters"]["box_lower.b1"] == "-inf"
    path.write_text(path.read_text().replace("step_s = 0.05", "step_s = 0.1"))
    with pytest.raises(ScenarioError, match=r"controller.identification': .*identified at ts_s = 0.05 s, the "
                                            r"controller samples at 0.1 s"):
        load_scenario(path)


def test_the_models_start_values_put_it_in_the_controller_fmu_in_fmpy(built_fmus, id_files, tmp_path):
    """``model.fmu_start_values()`` is what a user of fmpy or of a master of their own sets: fed the
    readings of the direct loop run on the same model, the controller FMU in ``fmpy.simulate_fmu`` gives
    that loop's commands bit for bit (one process). A fixed method takes no box (a scenario with one
    warned of box_* it had set itself, "not used by method 2"); a box on other parameters than a1, a2,
    b1 is refused naming the file."""
    from fmpy import simulate_fmu

    model = read_identification(id_files[0.05])
    values = model.fmu_start_values()
    assert values["Ts"] == 0.05 and values["box_lower.b1"] == -math.inf and values["box_upper.a1"] == math.inf
    assert {k for k in values if k.startswith("theta0.")} == {f"theta0.{n}" for n in ASYMMETRIC.names}
    assert not any(k.startswith("box_") for k in model.fmu_start_values("mpc_servo"))
    direct = tm.simulate_closed_loop("ampc_servo", None, ts_s=0.05, duration_s=12.0, theta0=model, seed=3)
    readings = np.array(list(zip(direct["t_s"], direct["l_mm"])), dtype=[("time", float), ("l", float)])
    res = simulate_fmu(str(built_fmus["AMPCController"]), start_values={**values, "input_delay_samples": 0},
                       input=readings, stop_time=12.0, output_interval=0.05, output=["u"])
    # fmpy records a co-simulation FMU's outputs at the end of each step: u(k), set in the step from t_k,
    # is its row of t_k+1
    assert len(res) == len(direct["u_v"]) and np.array_equal(res["u"][1:], direct["u_v"][:-1])
    path = tmp_path / "s.toml"
    path.write_text(f'duration_s = 5.0\nstep_s = 0.05\n[controller]\nmethod = "mpc_servo"\nidentification = "{id_files[0.05]}"\n')
    assert not any(k.startswith("box_") for k in load_scenario(path).controller.parameters)
    doc = json.loads(id_files[0.05].read_text())
    wide = tmp_path / "wide.json"
    wide.write_text(json.dumps(doc | {"constraint": {"lower": {"A1": -1.0}, "upper": {}}}))
    with pytest.raises(IdentificationFileError, match=r"wide.json: its constraint region bounds A1; the controller "
                                                      r"FMU's C bounds only a1, a2, b1"):
        read_identification(wide).fmu_start_values()
    assert not any(k.startswith("box_") for k in read_identification(wide).fmu_start_values("mpc_ucp"))
    with pytest.raises(IdentificationFileError, match="unknown method 'ampc'"):
        model.fmu_start_values("ampc")


def test_the_model_itself_is_a_theta0_for_the_simulated_loop(id_files):
    """``simulate_closed_loop(theta0=model)`` checks a period given against the model's (a 0.05-s model
    at 0.1 s ran silently: 26 mm of MPC-servo error), takes the model's period when none is given, and
    its box; a controller given the model object is told to pass its .theta."""
    model = read_identification(id_files[0.05])
    with pytest.raises(IdentificationFileError, match="identified at ts_s = 0.05 s, the controller samples at 0.1 s"):
        tm.simulate_closed_loop("mpc_servo", None, duration_s=3.0, theta0=model, ts_s=0.1)
    run = tm.simulate_closed_loop("ampc_servo", None, ts_s=0.05, duration_s=10.0, theta0=model, seed=2)
    settings = ControllerSettings(method="ampc_servo", ts_s=0.05, box_lower=model.box_lower, box_upper=model.box_upper)
    same = tm.simulate_closed_loop("ampc_servo", None, ts_s=0.05, duration_s=10.0, theta0=model.theta,
                                   settings=settings, seed=2)
    assert np.array_equal(run["u_v"], same["u_v"])
    with pytest.raises(TypeError, match=r"got IdentifiedModel \(pass its .theta\)"):
        DisplacementController(settings, model)


def test_a_model_refined_in_closed_loop_is_written_for_the_controller(tmp_path):
    """write_identification writes what read_identification and a scenario read (there was no way to
    hand a refined theta to a scenario but 15 theta0.* keys), bit for bit; a bad theta or period is
    refused naming the file, and nothing is written."""
    from tapmuscle.io.identification_file import write_identification

    theta = np.array(tm.THETA0_44N) * (1.0 + 1e-3 * np.arange(15))
    path = tmp_path / "refined.json"
    write_identification(path, theta, ts_s=0.05, box_lower={"b1": 0.01}, note="refined in closed loop")
    model = read_identification(path)
    assert np.array_equal(np.array(list(model.theta.values())), theta) and model.ts_s == 0.05
    assert model.box_lower == {"b1": 0.01} and model.box_upper == {}
    assert json.loads(path.read_text())["notes"] == ["refined in closed loop"]
    assert json.loads(path.read_text())["software"] == software()
    for bad_theta, ts, message in ((theta[:14], 0.1, "must be 15 values"), (theta, 0.0, "ts_s must be a positive"),
                                   (theta, 100, r"ts_s = 100 s is outside the 0.001..10 s .* a period in milliseconds")):
        with pytest.raises(IdentificationFileError, match=message):
            write_identification(tmp_path / "bad.json", bad_theta, ts_s=ts)
    assert not (tmp_path / "bad.json").exists()
    write_identification(path, theta, ts_s=np.float32(0.1))  # a notebook's number
    assert read_identification(path).ts_s == float(np.float32(0.1))
    # 1 ms as a 1-kHz log's times written to the millisecond give it (a hair short) is 1 ms
    write_identification(path, theta, ts_s=0.0009999999999994458)
    assert read_identification(path).ts_s == 0.0009999999999994458


@pytest.mark.parametrize("lower, upper, message", [
    ({"a1": (1.0, 2.0)}, {}, r"the lower bound of a1 must be a number, got \(1.0, 2.0\) \(one number a side"),
    ({"a1": 2.0}, {"a1": 1.0}, r"a lower bound above its upper one: a1 \(2 > 1\)"),
    ({"zz": 1.0}, {}, r"unknown parameter 'zz' in the lower bounds \(the model's parameters: a1, a2"),
    ({"a1": float("nan")}, {"a1": 2.0}, "the lower bound of a1 must be a number, got nan"),
    ({}, {"b1": -np.inf}, r"the upper bound of b1 is -inf, which no value satisfies"),
])
def test_a_box_that_no_reader_or_controller_takes_is_not_written(tmp_path, lower, upper, message):
    """Each was written: a pair (tm.identify's box style) made a file read_identification refused; the
    others read back and failed later in the controller, without the file's name. An infinite bound
    on its own side is no bound."""
    from tapmuscle.io.identification_file import write_identification

    path = tmp_path / "id.json"
    with pytest.raises(IdentificationFileError, match=rf"{path}: box_lower, box_upper: {message}"):
        write_identification(path, tm.THETA0_44N, ts_s=0.1, box_lower=lower, box_upper=upper)
    assert not path.exists()
    write_identification(path, tm.THETA0_44N, ts_s=0.1, box_lower={"a1": -np.inf, "b1": 0.6}, box_upper={"a1": np.inf})
    model = read_identification(path)
    assert model.box_lower == {"b1": 0.6} and model.box_upper == {}


def test_a_box_in_a_file_is_checked_as_the_controller_would(id_files, tmp_path):
    """A crossed or unknown bound read from a file is refused naming the file, not at the controller."""
    doc = json.loads(id_files[0.1].read_text())
    for box, message in (({"lower": {"a1": 2.0}, "upper": {"a1": 1.0}}, "a lower bound above its upper one: a1"),
                         ({"lower": {"zz": 1.0}}, "unknown parameter 'zz' in the lower bounds")):
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps(doc | {"constraint": box}))
        with pytest.raises(IdentificationFileError, match=rf"{bad}: key 'constraint': {message}"):
            read_identification(bad)


def test_a_model_identified_under_a_transport_delay_brings_it_to_the_controller(tmp_path):
    """identify --input-delay-samples 2 writes the delay; read back, a scenario's controller and
    simulate_closed_loop's default settings take it as input_delay_samples (a scenario's own
    parameter overrides it: a parallel master adds a sample); files without the key read as 0, and a
    delay outside 0..25 is refused naming the key."""
    from tapmuscle.io.identification_file import write_identification

    path = tmp_path / "delayed.json"
    write_identification(path, tm.THETA0_44N, ts_s=0.1, input_delay_samples=2)
    model = read_identification(path)
    assert model.input_delay_samples == 2
    run = tm.simulate_closed_loop("ampc_servo", None, duration_s=2.0, theta0=model)
    settings = ControllerSettings(method="ampc_servo", input_delay_samples=2, box_lower={}, box_upper={})
    same = tm.simulate_closed_loop("ampc_servo", None, duration_s=2.0, theta0=model.theta, settings=settings)
    assert np.array_equal(run["u_v"], same["u_v"])
    # run as a parallel master does, the loop has a sample more: 3 (with 2 it would run at 8.3 mm on a 0.2-s rig)
    run = tm.simulate_closed_loop("ampc_servo", None, duration_s=2.0, theta0=model, loop_delay_samples=1)
    same = tm.simulate_closed_loop("ampc_servo", None, duration_s=2.0, theta0=model.theta, loop_delay_samples=1,
                                   settings=ControllerSettings(method="ampc_servo", input_delay_samples=3,
                                                               box_lower={}, box_upper={}))
    assert np.array_equal(run["u_v"], same["u_v"])
    # at the longest delay compensated, the parallel master's sample is one too many: said so, by file
    write_identification(tmp_path / "longest.json", tm.THETA0_44N, ts_s=0.02, input_delay_samples=25)
    with pytest.raises(ValueError, match=r"longest.json: identified under a transport delay of 25 samples, and "
                                         r"loop_delay_samples = 1 adds one: 26 samples, beyond the 25"):
        tm.simulate_closed_loop("ampc_servo", None, ts_s=0.02, duration_s=1.0,
                                theta0=read_identification(tmp_path / "longest.json"), loop_delay_samples=1)
    scenario = tmp_path / "s.toml"
    scenario.write_text(f'duration_s = 5.0\n[controller]\nidentification = "{path}"\n')
    assert load_scenario(scenario).controller.parameters["input_delay_samples"] == 2
    scenario.write_text(scenario.read_text() + "[controller.parameters]\ninput_delay_samples = 3\n")
    assert load_scenario(scenario).controller.parameters["input_delay_samples"] == 3
    doc = json.loads(path.read_text())
    del doc["input_delay_samples"]
    path.write_text(json.dumps(doc))
    assert read_identification(path).input_delay_samples == 0
    scenario.write_text(f'duration_s = 5.0\n[controller]\nidentification = "{path}"\n')
    assert "input_delay_samples" not in load_scenario(scenario).controller.parameters  # the FMU's default
    path.write_text(json.dumps(doc | {"input_delay_samples": 2.0}))  # a JSON writer's number for 2
    assert read_identification(path).input_delay_samples == 2
    path.write_text(json.dumps(doc | {"input_delay_samples": 26}))
    with pytest.raises(IdentificationFileError, match=r"key 'input_delay_samples': input_delay_samples must be a "
                                                      r"number of samples 0 .. 25, got 26"):
        read_identification(path)
    with pytest.raises(IdentificationFileError, match="got 1.5"):
        write_identification(tmp_path / "bad.json", tm.THETA0_44N, ts_s=0.1, input_delay_samples=1.5)
    assert not (tmp_path / "bad.json").exists()


@pytest.mark.parametrize("scaling, said", [({"l_scale": 0.001, "u_scale": 1.0}, r"largest displacement is under about 1\.9 "
                                            r"\(scaling\.l_scale = 0\.001: metres\?\)"),
                                           ({"l_scale": 1000.0, "u_scale": 1.0}, r"over about 1900 .*micrometres\?"),
                                           # the decades at the edges (decade_scale writes exact powers of ten)
                                           ({"l_scale": 100.0, "u_scale": 1.0}, r"over about 1900 .*l_scale = 100: micro"),
                                           ({"l_scale": 0.01, "u_scale": 1.0}, r"under about 1\.9 .*l_scale = 0\.01: metres"),
                                           ({"l_scale": 1.0, "u_scale": 100.0}, r"about 190 or more .*u_scale = 100: milli"),
                                           ({"l_scale": 1.0, "u_scale": 1000.0}, r"largest command is about 190 or more .*millivolts\?"),
                                           ({"l_scale": 1.0, "u_scale": 0.01}, r"largest command is under about 0\.19 .*0\.\.1"),
                                           # a command logged in % of opening or V x 10: 22 mm of AMPC-servo error
                                           ({"l_scale": 1.0, "u_scale": 10.0}, r"largest command is about 19 or more \(scaling"
                                            r"\.u_scale = 10: % of the valve's opening, or volts x 10\? The valve takes"),
                                           ({"l_scale": 0.1, "u_scale": 0.1}, None), ({"l_scale": 10.0}, None),
                                           ({"l_scale": 1.0, "u_scale": 1.0}, None)])
def test_a_model_identified_off_mm_and_v_is_read_with_a_warning_naming_the_file(tmp_path, scaling, said):
    """identify normalises any unit and writes its powers of ten as ``scaling``; the controllers need
    mm and V. A file whose scaling says metres, micrometres or millivolts is read with a warning that
    names it (an MPC-servo loop on a model in metres: 22 mm of Eq. (21) error, its warnings blaming the
    readings); a small stroke in mm (scale 0.1) or an absolute position (10) is read without one."""
    from tapmuscle.io.identification_file import write_identification

    path = tmp_path / "model.json"
    write_identification(path, tm.THETA0_44N, ts_s=0.1)
    path.write_text(json.dumps(json.loads(path.read_text()) | {"scaling": scaling}))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_identification(path)
    texts = [str(w.message) for w in caught]
    if said is None:
        assert texts == []
    else:
        assert len(texts) == 1 and texts[0].startswith(f"{path}: identified on a recording whose "), texts
        assert re.search(said, texts[0]) and "the controllers need Eq. (1) in mm and V" in texts[0]


def test_a_theta_written_at_the_papers_period_carries_table_2_unless_it_lies_outside(tmp_path):
    """A theta refined in closed loop and written without a box ran AMPC-servo unconstrained (0.295
    against 0.243 mm on a user's rig): at Ts = 0.1 s the file carries Table 2's box, as identify
    writes it there; none at another Ts, none with a warning naming the parameter where theta lies
    outside Table 2, and none where asked (None) or one side given."""
    from fmu_controller.rls import TABLE2_LOWER, TABLE2_UPPER
    from tapmuscle.io.identification_file import write_identification

    def box(name, **kw):
        write_identification(tmp_path / name, tm.THETA0_44N if "theta" not in kw else kw.pop("theta"), **kw)
        model = read_identification(tmp_path / name)
        return model.box_lower, model.box_upper

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert box("paper.json", ts_s=0.1) == (TABLE2_LOWER, TABLE2_UPPER)
        assert box("fast.json", ts_s=0.05) == ({}, {})
        assert box("none.json", ts_s=0.1, box_lower=None, box_upper=None) == ({}, {})
        assert box("one.json", ts_s=0.1, box_lower={"b1": 0.01}) == ({"b1": 0.01}, {})
    outside = dict(zip(tm.ASYMMETRIC.names, tm.THETA0_44N)) | {"a1": 1.1}
    with pytest.warns(UserWarning, match=r"outside\.json: no constraint box written: theta's a1 = 1\.1 \(Table 2: "
                                         r"1\.208 \.\. 1\.26\) lies outside Table 2's box"):
        assert box("outside.json", ts_s=0.1, theta=outside) == ({}, {})
    with pytest.raises(IdentificationFileError, match=r"box_lower must be a mapping, None or 'auto', got 'table2'"):
        write_identification(tmp_path / "bad.json", tm.THETA0_44N, ts_s=0.1, box_lower="table2")
