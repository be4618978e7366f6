"""The AMPCController FMU in fmpy: the direct controller's numbers, FMI errors not crashes, exact state."""

import math
import re
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
import pytest
from pythonfmu.enums import Fmi2Status
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from fmpy_helpers import instantiate, open_fmu

from fmu_controller.controller_slave import AMPCController
from fmu_controller.loop_watch import DIVERGED_MM as _DIVERGED_MM, DIVERGED_V as _DIVERGED_V
from fmu_controller.displacement_control import AUTO_INPUT_DELAY_SAMPLES, ControllerSettings, DisplacementController
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.reference import SineReference

THETA = [f"theta.{n}" for n in ASYMMETRIC.names]


@pytest.fixture(scope="module")
def fmu(built_fmus):
    return open_fmu(built_fmus["AMPCController"])


def _instance(fmu, name="c", reals=None, ints=None, **kw):
    return instantiate(fmu, name, reals, ints, **kw)


def _free(*fs):
    for f in fs:
        f.terminate()
        f.freeInstance()


def _l(k):
    """A plausible measured displacement [mm] (the controller does not care where it comes from)."""
    return 35 + 28 * math.sin(2 * math.pi * 0.1 * k * 0.1 - 0.2) + 0.3 * math.sin(1.7 * k)


def test_fmpy_validation_reports_no_problems(fmu):
    assert validate_fmu(str(fmu[0])) == []


def test_model_description_declares_units_ranges_integer_choices_and_no_feedthrough(fmu):
    root = ET.fromstring(zipfile.ZipFile(fmu[0]).read("modelDescription.xml"))
    svs = {sv.get("name"): sv for sv in root.iter("ScalarVariable")}
    assert svs["u"][0].get("unit") == "V" and svs["u"][0].get("min") == "0.0" and svs["u"][0].get("max") == "10.0"
    assert svs["l"][0].get("unit") == "mm" and svs["Ts"][0].get("unit") == "s"
    assert {u.get("name") for u in root.iter("Unit")} >= {"mm", "V", "s", "Hz"}
    mm = next(u for u in root.iter("Unit") if u.get("name") == "mm")[0]
    assert mm.get("m") == "1" and float(mm.get("factor")) == 1e-3
    # choices are Integers with their codes in the description (libcosim cannot set Enumerations)
    method = svs["method"][0]
    assert method.tag == "Integer" and (method.get("start"), method.get("min"), method.get("max")) == ("4", "1", "4")
    assert "1 mpc_ucp" in svs["method"].get("description") and "4 ampc_servo" in svs["method"].get("description")
    assert svs["reference_source"][0].tag == "Integer" and root.find("TypeDefinitions") is None
    outputs = root.find("ModelStructure/Outputs")
    assert len(outputs) == sum(sv.get("causality") == "output" for sv in svs.values())
    assert all(u.get("dependencies") == "" for u in outputs)
    assert root.get("generationDateAndTime") is None
    cs = root.find("CoSimulation")
    assert cs.get("canGetAndSetFMUstate") == "true" and cs.get("canSerializeFMUstate") == "true"


def test_the_documented_table_gives_every_declared_range(fmu):
    """docs/fmu.md's AMPCController table: each row's "declared range" is its variables' min..max in
    modelDescription.xml (several distinct ranges in the row's order, joined by commas; none where
    nothing is declared), and every parameter and input of the FMU is in some row."""
    from pathlib import Path

    variables = {v.name: v for v in fmu[1].modelVariables}

    def names(cell):
        out = []
        found = re.findall(r"`([^`]+)`", cell)
        if "…" in cell:  # `theta.a1` … `theta.xi32`: every one of Eq. (1)'s 15 in between
            found = [f"{found[0].rpartition('.')[0]}.{p}" for p in ASYMMETRIC.names]
        for n in found:
            head, _, tail = n.rpartition(".")
            out += [f"{head}.{t}" for t in tail.split("/")] if "/" in tail else [n]
        return [n for n in out if n in variables]

    def declared(v):
        if v.type not in ("Real", "Integer") or (v.min is None and v.max is None):
            return ""
        return f"{'-inf' if v.min is None else f'{float(v.min):g}'}..{'inf' if v.max is None else f'{float(v.max):g}'}"

    lines = (Path(__file__).resolve().parents[1] / "docs" / "fmu.md").read_text().splitlines()
    start = lines.index("| variable | causality | unit | start | declared range | meaning |")
    rows, covered = 0, set()
    for line in lines[start + 2:]:
        if not line.startswith("| "):
            break
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]  # "\|" inside a cell is text
        listed = names(cells[0])
        assert listed, f"a row naming no variable of the FMU: {cells[0]}"
        expected = ", ".join(dict.fromkeys(declared(variables[n]) for n in listed))
        assert cells[4] == ("" if expected.strip(", ") == "" else expected), cells[0]
        covered |= set(listed)
        rows += 1
    assert rows >= 35
    settable = {v.name for v in variables.values() if v.causality in ("parameter", "input")}
    assert settable <= covered, sorted(settable - covered)


@pytest.mark.parametrize("method_code, method", [(1, "mpc_ucp"), (2, "mpc_servo"), (3, "ampc_ucp"), (4, "ampc_servo")])
def test_fmu_equals_the_direct_controller_bit_for_bit(fmu, method_code, method):
    vr = fmu[3]
    f = _instance(fmu, ints={"method": method_code}, reals={"sine.frequency": 0.2})
    # the FMU's defaults, input_delay_samples = -1 included
    direct = DisplacementController(ControllerSettings(method=method, input_delay_samples=-1), THETA0_44N)
    ref = SineReference(frequency_hz=0.2)
    direct.reset(_l(0))
    for k in range(150):
        f.setReal([vr["l"]], [_l(k)])
        f.doStep(k * 0.1, 0.1)
        step = direct.step(_l(k), ref.preview(k, direct.settings.preview_samples))
        got = f.getReal([vr["u"], vr["uc"], vr["l_pred"], vr["H"], vr["xs"], vr["r_k"]] + [vr[t] for t in THETA])
        assert got == [step.u_v, step.uc_v, step.predicted_next_mm, step.hysteresis_mm, step.xs_mm,
                       float(ref.at(k))] + step.theta.tolist()
    _free(f)


@pytest.mark.parametrize("delay", [1, 3])
@pytest.mark.parametrize("correction, weight", [(0, 4.0), (1, 4.0), (1, 1.0)])
def test_delay_correction_parameter_is_the_direct_controllers(fmu, correction, weight, delay):
    """``input_delay_samples = 1`` or 3 (a rig's transport delay) with ``delay_correction`` 0 or 1 and
    ``delay_move_weight`` 4 (the default) or 1: the FMU's commands are the direct controller's with
    the same settings, bit for bit (the correction acts from the 21st sample, so 60 samples compare
    both)."""
    vr = fmu[3]
    f = _instance(fmu, reals={"delay_move_weight": weight},
                  ints={"input_delay_samples": delay, "delay_correction": correction})
    direct = DisplacementController(ControllerSettings(input_delay_samples=delay, delay_correction=bool(correction),
                                                       delay_move_weight=weight), THETA0_44N)
    ref = SineReference()
    direct.reset(_l(0))
    got, want = [], []
    for k in range(60):
        f.setReal([vr["l"]], [_l(k)])
        f.doStep(k * 0.1, 0.1)
        got.append(f.getReal([vr["u"], vr["l_pred"]]))
        step = direct.step(_l(k), ref.preview(k, direct.settings.preview_samples))
        want.append([step.u_v, step.predicted_next_mm])
    assert got == want
    _free(f)


@pytest.mark.parametrize("ints", [{}, {"input_delay_samples": 1}, {"input_delay_samples": 4}])
def test_state_rewind_and_serialisation_are_bit_identical(fmu, ints):
    """ampc_servo: theta-hat, P, Bouc-Wen state, integrator, QP warm start; with an input delay also
    the commands in flight and the delay predictor's correction (active after 20 samples)."""
    vr = fmu[3]
    f = _instance(fmu, ints=ints)

    def run(k0):
        out = []
        for k in range(k0, k0 + 40):
            f.setReal([vr["l"]], [_l(k)])
            f.doStep(k * 0.1, 0.1)
            out.append(f.getReal([vr["u"], vr["xs"]] + [vr[t] for t in THETA]))
        return out

    run(0)
    state = f.getFMUstate()
    a = run(40)
    assert a[0][2:] != a[-1][2:]  # theta-hat moved: the replay checks real adaptive state
    f.setFMUstate(state)
    assert run(40) == a
    f.setFMUstate(f.deSerializeFMUstate(f.serializeFMUstate(state)))
    assert run(40) == a
    _free(f)


def test_a_state_of_an_instance_with_another_method_steps_with_it(fmu):
    """A state of an MPC-UCP instance restored into an AMPC-servo one: not refused with a TypeError
    about its content; the controller is built again from the state's parameters and runs as the
    instance it came from, bit for bit."""
    vr = fmu[3]
    a = _instance(fmu, "a", ints={"method": 1})
    b = _instance(fmu, "b")

    def run(f, k0):
        out = []
        for k in range(k0, k0 + 30):
            f.setReal([vr["l"]], [_l(k)])
            f.doStep(k * 0.1, 0.1)
            out.append(f.getReal([vr["u"], vr["xs"]]))
        return out

    run(a, 0)
    run(b, 0)
    state = a.serializeFMUstate(a.getFMUstate())
    expected = run(a, 30)
    b.setFMUstate(b.deSerializeFMUstate(state))
    assert run(b, 30) == expected
    _free(a, b)


def test_steps_shorter_than_ts_hold_the_outputs_and_sample_on_the_grid(fmu):
    vr = fmu[3]
    coarse, fine = _instance(fmu, "coarse"), _instance(fmu, "fine")
    for k in range(30):
        coarse.setReal([vr["l"]], [_l(k)])
        coarse.doStep(k * 0.1, 0.1)
        u_coarse = coarse.getReal([vr["u"]])
        for j in range(4):  # four 25 ms steps per sample; l is read at the sample instant only
            fine.setReal([vr["l"]], [_l(k) if j == 0 else -50.0 + j])
            fine.doStep(k * 0.1 + j * 0.025, 0.025)
            assert fine.getReal([vr["u"]]) == u_coarse
    assert fine.getInteger([vr["samples"]]) == [30]
    _free(coarse, fine)


@pytest.mark.parametrize("name, value, message", [("l", math.nan, "l = nan is not finite"),
                                                  ("l", math.inf, "l = inf is not finite"),
                                                  ("l", 9000.0, "l = 9000.0 is outside -1000..5000")])
def test_bad_input_is_discarded_with_a_message_and_state_stays(fmu, capfd, name, value, message):
    vr = fmu[3]
    f, ref = _instance(fmu, "bad"), _instance(fmu, "ref")
    for g in (f, ref):
        g.setReal([vr["l"]], [_l(0)])
        g.doStep(0.0, 0.1)
    before = f.getReal([vr["u"]])
    f.setReal([vr[name]], [value])
    with pytest.raises(FMICallException, match="discard"):
        f.doStep(0.1, 0.1)
    assert message in capfd.readouterr().out
    assert f.getReal([vr["u"]]) == before
    for g in (f, ref):  # the refused step changed nothing: both continue identically
        g.setReal([vr["l"]], [_l(1)])
        g.doStep(0.1, 0.1)
    assert f.getReal([vr["u"]] + [vr[t] for t in THETA]) == ref.getReal([vr["u"]] + [vr[t] for t in THETA])
    _free(f, ref)


def test_external_reference_is_checked(fmu, capfd):
    vr = fmu[3]
    f = _instance(fmu, ints={"reference_source": 2})
    f.setReal([vr["l"], vr["r"]], [10.0, math.nan])
    with pytest.raises(FMICallException, match="discard"):
        f.doStep(0.0, 0.1)
    assert "r = nan is not finite" in capfd.readouterr().out
    _free(f)


@pytest.mark.parametrize("t0, h, message", [(0.0, 0.0, "step size = 0.0"), (0.0, -1.0, "step size = -1.0"),
                                            (0.0, 0.3, "exceeds the sampling period"),
                                            # a rounding's worth over Ts: the message shows the difference
                                            (0.0, 0.10000001, "step size 0.10000001 s exceeds the sampling period Ts = 0.1 s"),
                                            (0.05, 0.0500001, "from t = 0.05 s to 0.1000001 s passes the sample time 0.1 s"),
                                            (0.0, 1e9, "step size = 1000000000.0")])
def test_bad_step_sizes_are_discarded(fmu, capfd, t0, h, message):
    f = _instance(fmu)
    if t0:
        f.doStep(0.0, t0)
    with pytest.raises(FMICallException, match="discard"):
        f.doStep(t0, h)
    assert message in capfd.readouterr().out
    _free(f)


@pytest.mark.parametrize("reals, ints, message", [
    ({}, {"method": 7}, "parameter method = 7 is outside its declared range 1..4 (controller: 1 mpc_ucp"),
    ({}, {"servo.Hp": 51}, "parameter servo.Hp = 51 is outside its declared range 1..50"),
    ({}, {"input_delay_samples": 26}, "parameter input_delay_samples = 26 is outside its declared range -1..25"),
    ({}, {"servo.Hp": 5000}, "parameter servo.Hp = 5000 is outside"),  # would take minutes to set up
    ({}, {"servo.Hu": 9}, "parameter servo.Hu must be <= servo.Hp = 5, got 9"),
    ({"servo.R": 0.0}, {}, "parameter servo.R must be > 0, got 0.0"),
    ({"u_min": 6.0, "u_max": 5.0}, {}, "parameter u_max must be > u_min = 6.0, got 5.0"),
    ({"P0.a1": -1.0}, {}, "parameter P0.a1 = -1.0 is outside its declared range 0..inf"),
    ({"Ts": 0.0}, {}, "parameter Ts = 0.0 is outside"),
    ({"servo.R": math.nan}, {}, "parameter servo.R = nan is not finite"),
    ({"delay_move_weight": 0.0}, {}, "delay_move_weight must be within 0 .. 1000 (0 excluded"),
    ({"delay_move_weight": 2000.0}, {}, "parameter delay_move_weight = 2000.0 is outside its declared range 0..1000"),
    ({"box_lower.b1": 2.0}, {}, "box_lower.b1 = 2.0 exceeds box_upper.b1"),
    ({"theta0.b1": 0.0}, {}, "theta0.b1 = 0.0 must not be ~0"),
    ({"sine.offset": 4000.0, "sine.amplitude": 1500.0}, {}, "sine.offset +- sine.amplitude = 4000 +- 1500 mm leaves"),
    ({"sine.amplitude": -1.0}, {}, "parameter sine.amplitude = -1.0 is outside its declared range 0..3000"),
    ({"theta0.a1": 1.1}, {"method": 4}, "theta0's a1 = 1.1 lies outside the constraint region C, 1.208..1.26"),
    ({"sine.frequency": 6.0}, {}, "sine.frequency = 6 Hz is above the Nyquist frequency 0.5/Ts = 5 Hz"),
    # beyond the limit the predictions would overflow at the second step (an internal error with a traceback)
    ({"theta0.A1": 1e50}, {}, "parameter theta0.A1 = 1e+50 is outside its declared range -1e+06..1e+06"),
    ({"theta0.a2": -2e6}, {"method": 2}, "parameter theta0.a2 = -2000000.0 is outside its declared range"),
    # the settings' errors name the FMU's parameters, not ControllerSettings' fields
    ({"startup_s": 1e4}, {}, "parameter startup_s = 10000.0 is outside its declared range"),
    # R = 1e300 would hold the command at 0 V for the whole run without a word
    ({"servo.R": 1e300}, {}, "parameter servo.R = 1e+300 is outside its declared range 0..1e+06"),
    # the law for a delay of 2 or more (-1 may decide one) runs with R x delay_move_weight: refused here,
    # not as an internal error at the decision
    ({"servo.R": 3e5}, {}, "parameter servo.R x delay_move_weight = 300000 x 16, the move weight of the law for a "
                            "delay of 2 samples or more, is not one: r must be <= 1e+06"),
])
def test_bad_parameters_are_an_error_and_every_step_too(fmu, capfd, reals, ints, message):
    """fmi2Error, not Discard (a host answers Discard with a smaller step, forever); the instance stays
    usable for getting values and freeing."""
    f = _instance(fmu, reals=reals, ints=ints, rejected=True)
    assert message in capfd.readouterr().out
    with pytest.raises(FMICallException, match="error"):
        f.doStep(0.0, 0.1)
    assert "the FMU was not initialised (see the initialisation's message); fmi2Reset or instantiate again" in capfd.readouterr().out
    assert all(math.isfinite(x) for x in f.getReal([fmu[3]["u"], fmu[3]["l_pred"]]))
    _free(f)


def test_several_instances_and_reinstantiation(fmu):
    vr = fmu[3]
    # 100 samples: past the start-up mode's warm-up (theta0 in the law until 6 s), into its blend
    a, b = _instance(fmu, "a", ints={"method": 4}), _instance(fmu, "b", ints={"method": 2})
    for k in range(100):
        for g in (a, b):
            g.setReal([vr["l"]], [_l(k)])
            g.doStep(k * 0.1, 0.1)
    ta, tb = a.getReal([vr[t] for t in THETA]), b.getReal([vr[t] for t in THETA])
    assert tb == list(THETA0_44N) and ta != tb  # the fixed predictor did not adapt, the adaptive one did
    _free(a, b)
    c = _instance(fmu, "c", ints={"method": 4})
    for k in range(100):
        c.setReal([vr["l"]], [_l(k)])
        c.doStep(k * 0.1, 0.1)
    assert c.getReal([vr[t] for t in THETA]) == ta
    _free(c)


@pytest.mark.parametrize("delay", [0, -1, 1, 3])
def test_external_advanced_reference_gives_the_exact_preview(monkeypatch, delay):
    """Fed r(t + H Ts), H = Hp plus the input delay (one for -1, the default, which starts with the
    delayed law), the controller's preview holds exactly r(k..k+H) once H samples have arrived."""
    seen = []
    original = DisplacementController.step

    def spy(self, l_mm, preview):
        seen.append(np.array(preview, dtype=float))
        return original(self, l_mm, preview)

    monkeypatch.setattr(DisplacementController, "step", spy)
    slave = AMPCController(instance_name="spy")
    slave._int_par["reference_source"] = 3
    slave._int_par["input_delay_samples"] = delay
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    ref = SineReference(frequency_hz=0.1)
    ahead = 5 + {0: 0, -1: 1, 1: 1, 3: 3}[delay]
    for k in range(20):
        slave.l, slave.r = _l(k), float(ref.at(k + ahead))
        assert slave.do_step(k * 0.1, 0.1)
    for k in range(ahead, 20):
        np.testing.assert_array_equal(seen[k][:ahead + 1], ref.preview(k, ahead))
        # -1 takes a preview for any delay it may decide: beyond what the host feeds, its last value held
        assert len(seen[k]) == 6 + (AUTO_INPUT_DELAY_SAMPLES if delay == -1 else delay)
        assert set(seen[k][ahead:]) == {seen[k][ahead]}
    assert slave.r_k == float(ref.at(19))


def test_a_rounding_remainder_step_is_accepted(fmu):
    """OMSimulator ends a run with a step of its time's rounding remainder (1e-14 .. 2e-12 s): OK,
    the command holds, and the sampling continues on the regular grid."""
    vr = fmu[3]
    f = _instance(fmu)
    f.setReal([vr["l"]], [10.0])
    f.doStep(0.0, 0.1)
    u0 = f.getReal([vr["u"]])[0]
    f.doStep(0.1, 1e-14)
    assert f.getReal([vr["u"]])[0] == u0 and f.getInteger([vr["samples"]])[0] == 1
    f.doStep(0.1 + 1e-14, 0.1 - 1e-14)  # the sample at 0.1 s is taken within the time tolerance
    assert f.getInteger([vr["samples"]])[0] == 2
    _free(f)


@pytest.mark.parametrize("k", [0, 1, 2, 5])
@pytest.mark.parametrize("tiny", [2e-10, 5e-10, 9.9e-10])
def test_a_step_too_short_to_integrate_at_a_sample_time_leaves_the_sample_to_the_next(fmu, k, tiny):
    """Any step below 1e-9 s is an accepted no-op: the next regular step, starting that much after the
    sample time, takes the sample (refused as skipping it, the instance could not go on)."""
    vr = fmu[3]
    f = _instance(fmu)
    f.setReal([vr["l"]], [10.0])
    t = 0.0
    for _ in range(k):
        f.doStep(t, 0.1)
        t += 0.1
    f.doStep(t, tiny)
    assert f.getInteger([vr["samples"]])[0] == k
    f.doStep(t + tiny, 0.1)  # fmpy raises on a Discard
    assert f.getInteger([vr["samples"]])[0] == k + 1
    _free(f)


@pytest.mark.parametrize("forgetting", [0.5, 1.0])
def test_a_diverging_adaptive_estimate_is_said_once(fmu, capfd, forgetting):
    """forgetting = 0.5 (its declared minimum) without the covariance ceiling: on this project's CPU the
    estimate diverges once the start-up mode hands over (the servo's u_c beyond 1e60 V within 20 s of a
    sine; whether and when is chaotic, another floating-point path may stay finite longer). The
    controller says so exactly when it happens, once, its command stays within u_min..u_max, and the
    solver prints nothing."""
    vr = fmu[3]
    f = _instance(fmu, reals={"forgetting": forgetting})
    capfd.readouterr()
    u, uc, l_pred = [], [], []
    for k in range(200):
        f.setReal([vr["l"]], [35.0 + 28.0 * math.sin(2 * math.pi * 0.1 * (k * 0.1 - 0.3))])
        f.doStep(k * 0.1, 0.1)  # fmpy raises on fmi2Error; a warning goes to the log
        u_k, uc_k, l_k = f.getReal([vr["u"], vr["uc"], vr["l_pred"]])
        u.append(u_k)
        uc.append(uc_k)
        l_pred.append(l_k)
    diverged = max(map(abs, uc)) > _DIVERGED_V or not all(_DIVERGED_MM[0] <= x <= _DIVERGED_MM[1] for x in l_pred)
    out = capfd.readouterr().out
    assert out.count("its estimate diverges (forgetting = ") == (1 if diverged else 0), out[-2000:]
    assert "ERROR in osqp" not in out  # the QP's data beyond OSQP's range never reach it
    assert not diverged or forgetting < 1.0
    assert all(0.0 <= x <= 10.0 for x in u)
    f.terminate()
    f.freeInstance()


@pytest.mark.parametrize("guard", [1, 0])
def test_the_startup_guard_parameter_reaches_the_controller_and_its_firing_is_logged(guard):
    """``startup_guard`` is the controller's ``ControllerSettings.startup_guard``; when the guard ends
    the warm-up on theta0 the host's log says so once, as a warning, with the time."""
    from fmu_controller.controller_slave import AMPCController

    slave = AMPCController(instance_name="guarded")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["startup_guard"]], [guard])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    assert slave._controller.settings.startup_guard is bool(guard)
    real_step = slave._controller.step

    def step(l, r):
        out = real_step(l, r)
        if slave._k == 3 and guard:
            slave._controller._guarded_at = 3  # as _watch_jump does on the third full-range jump
        return out

    slave._controller.step = step
    for k in range(6):
        slave.l = 30.0
        assert slave.do_step(k * 0.1, 0.1)
    msgs = [(m.status, m.msg) for m in slave.log_queue if "jumped across its range" in m.msg]
    assert len(msgs) == guard
    if guard:
        assert msgs[0][0] == Fmi2Status.warning and msgs[0][1].startswith("t = 0.3 s: the valve command jumped "
                                                                          "across its range 3 times")


@pytest.mark.parametrize("startup_s", [0.0, 12.0])
def test_the_divergence_warning_names_its_figures_and_parameters(startup_s):
    """The warning's rule on a step whose prediction is far off (made so: deterministic on any CPU).
    In the start-up mode's warm-up the law runs on theta0, not on the estimate: the warning says so
    (it must not blame the estimate and the forgetting factor for a theta0 or readings in another unit)."""
    import dataclasses

    from fmu_controller.controller_slave import AMPCController

    slave = AMPCController(instance_name="diverging")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_real([vr["forgetting"], vr["startup_s"]], [0.9, startup_s])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    real_step = slave._controller.step
    far = {3: 1e9, 4: -2e4}  # k -> predicted_next_mm
    slave._controller.step = lambda l, r: dataclasses.replace(real_step(l, r), predicted_next_mm=far.get(slave._k, 30.0))
    for k in range(6):
        slave.l = 30.0
        assert slave.do_step(k * 0.1, 0.1)
    msgs = [(m.status, m.msg) for m in slave.log_queue if "far outside the rig's" in m.msg]
    assert len(msgs) == 1 and msgs[0][0] == Fmi2Status.warning  # once, at k = 3
    assert "t = 0.3 s" in msgs[0][1] and "l_pred = 1e+09 mm" in msgs[0][1]
    if startup_s == 0.0:
        assert "its estimate diverges" in msgs[0][1] and "forgetting = 0.9, covariance_ceiling = 0" in msgs[0][1]
    else:
        assert "the prior model theta0, which the start-up mode's warm-up runs the law on" in msgs[0][1]
        assert "diverges" not in msgs[0][1] and "(now 30 mm)" in msgs[0][1]
    assert slave.l_pred == 30.0 and 0.0 <= slave.u <= 10.0


@pytest.mark.parametrize("name, value, message", [("u", math.nan, "it must be within 0..10"),
                                                  ("u", 42.0, "it must be within 0..10"),
                                                  ("l_pred", math.inf, "it must be finite")])
def test_an_outputs_start_value_is_finite_and_within_its_range(fmu, capfd, name, value, message):
    """FMI 2.0 lets a host set an output's start value before initialisation (initial = exact); a parallel
    master passes it on at t = 0, so a NaN there would stop the run. Refused with an error naming it;
    a valid start value is taken."""
    from fmpy.fmi2 import FMU2Slave

    path, md, folder, vr = fmu
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="start")
    f.instantiate(loggingOn=True)
    with pytest.raises(FMICallException, match="error"):
        f.setReal([vr[name]], [value])
    assert f"output {name} = {value!r} as its start value: {message}; nothing was written" in capfd.readouterr().out
    assert f.getReal([vr[name]]) == [0.0]
    f.setReal([vr["u"]], [5.0])
    assert f.getReal([vr["u"]]) == [5.0]
    f.freeInstance()


def test_an_infinite_bound_on_its_own_side_is_no_bound():
    """box_lower.* = -inf and box_upper.* = inf leave C open (an unconstrained identification's theta0,
    which the FMU must take rather than refuse every infinity); an infinity on the wrong side is refused."""
    from fmu_controller.controller_slave import AMPCController

    slave = AMPCController(instance_name="open")
    vr = {var.name: v for v, var in slave.vars.items()}
    names = [f"box_{side}.{n}" for side in ("lower", "upper") for n in ("a1", "a2", "b1")]
    slave.set_real([vr[n] for n in names], [-math.inf] * 3 + [math.inf] * 3)
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    lower, upper = slave._controller.settings.constraint_region()
    assert np.isneginf(lower).all() and np.isposinf(upper).all()
    wrong = AMPCController(instance_name="wrong")
    wrong.set_real([vr["box_upper.b1"]], [-math.inf])
    wrong.enter_initialization_mode()
    wrong.exit_initialization_mode()
    assert wrong._controller is None
    assert any("parameter box_upper.b1 = -inf is not a bound: a finite number, or inf (no upper bound)" in m.msg
               for m in wrong.log_queue)


def test_after_rejected_parameters_a_reset_and_valid_ones_run(fmu, capfd):
    """The rejection names both ways out (fmi2Reset or a new instance), and fmi2Reset works."""
    f = _instance(fmu, ints={"servo.Hu": 9}, rejected=True)
    assert "(fmi2Reset or instantiate again, and set valid parameters)" in capfd.readouterr().out
    f.reset()
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setInteger([fmu[3]["servo.Hu"]], [3])
    assert f.exitInitializationMode() == 0
    f.setReal([fmu[3]["l"]], [35.0])
    f.doStep(0.0, 0.1)
    assert 0.0 <= f.getReal([fmu[3]["u"]])[0] <= 10.0
    _free(f)


def test_a_model_whose_predictions_overflow_is_an_error_naming_theta0_not_a_traceback():
    """theta0.xi31 within its declared range still makes the servo law's predicted hysteresis overflow
    (it multiplies l**3): fmi2Error naming theta0, no traceback, finite outputs."""
    slave = AMPCController(instance_name="overflow")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["method"]], [2])
    slave.set_real([vr["theta0.xi31"]], [1e6])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    slave.l = 35.0
    assert not slave.do_step(0.0, 0.1)
    (message,) = [m for m in slave.log_queue if m.status == Fmi2Status.error]
    assert message.msg.startswith("t = 0 s: numerical overflow (") and "Traceback" not in message.msg
    assert "theta0 is far from a model of a muscle (set away from its start: theta0.xi31)" in message.msg
    assert all(math.isfinite(x) for x in (slave.u, slave.l_pred, slave.uc))


def test_a_settings_error_names_the_fmu_parameters():
    """ControllerSettings' checks run after the declared ranges: their messages name the FMU's
    parameters (delay_move_weight, servo.R), not the Python fields (ControllerSettings.delay_move_weight)."""
    slave = AMPCController(instance_name="names")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_real([vr["delay_move_weight"]], [0.0])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    (message,) = [m.msg for m in slave.log_queue if "initialisation failed" in m.msg]
    assert "parameter delay_move_weight must be within 0 .. 1000 (0 excluded; 1: servo.R as it is), got 0.0" in message
    assert "ControllerSettings" not in message and "servo.r " not in message


#: Valid values away from the start values of the parameters only some methods use.
_METHOD_ONLY_VALUES = {"ucp.Hp": 3, "servo.Hp": 8, "servo.Hu": 3, "servo.Q": 2.0, "servo.Qs": 1.0, "servo.R": 30.0,
                       "hysteresis_notch": 0, "anti_windup": 0, "delay_move_weight": 2.0, "P0.a1": 1.0,
                       "forgetting": 0.98, "covariance_ceiling": 1, "box_lower.a1": 1.0, "box_upper.b1": 1.5,
                       "probing_v": 0.1, "probing_phase": 111, "startup_guard": 0}
_USED_BY = {"ucp.Hp": {1, 3}, **dict.fromkeys(("servo.Hp", "servo.Hu", "servo.Q", "servo.Qs", "servo.R",
                                               "hysteresis_notch", "anti_windup", "delay_move_weight"), {2, 4})}


@pytest.mark.parametrize("method", [1, 2, 3, 4])
def test_a_parameter_the_method_does_not_use_is_named_and_changes_nothing(method):
    """Tuning servo.Hp for an UCP method, or the estimator for a fixed one, does nothing, which must not pass without a word. At
    the first step a warning names each such parameter; setting it leaves every command bit for bit as
    it was (which proves the list), and a parameter the method uses is not named (some of those only act
    later, under forgetting or at the box's edge: the commands are compared for those that act at once)."""
    from fmu_controller.controller_slave import AMPCController

    def run(name=None):
        slave = AMPCController(instance_name="unused")
        vr = {var.name: v for v, var in slave.vars.items()}
        slave.set_integer([vr["method"]], [method])
        slave.set_integer([vr["input_delay_samples"]], [2])  # so that delay_move_weight acts where it is used
        if name is not None:
            value = _METHOD_ONLY_VALUES[name]
            (slave.set_integer if isinstance(value, int) else slave.set_real)([vr[name]], [value])
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        commands = []
        for k in range(40):
            slave.l = _l(k)
            assert slave.do_step(k * 0.1, 0.1)
            commands.append(slave.u)
        warned = [m.msg for m in slave.log_queue if "not used by method" in m.msg]
        return commands, warned

    default, warned = run()
    assert warned == []
    for name, value in _METHOD_ONLY_VALUES.items():
        used = method in _USED_BY.get(name, {3, 4})
        commands, warned = run(name)
        if used:
            assert warned == [], name
            if name in ("ucp.Hp", "servo.Hp", "servo.R", "probing_v", "probing_phase"):  # those that act within 4 s
                assert commands != default, name
        else:
            (message,) = warned
            assert f"method {method} " in message and f"{name} = {value!r} (the " in message, message
            assert commands == default, name


def test_the_paper_defaults_at_another_period_are_warned_of():
    """THETA0_44N and Table 2's box hold for Ts = 0.1 s; at 0.2 s they must not run without a word (2.7 mm of
    Eq. (21) error, the valve hitting both limits). A warning at the first step names both while they
    are the defaults (not at initialisation, where hosts take a warning for rejected parameters)."""
    from fmu_controller.controller_slave import AMPCController

    def messages(reals):
        slave = AMPCController(instance_name="ts")
        vr = {var.name: v for v, var in slave.vars.items()}
        slave.set_real([vr[k] for k in reals], list(reals.values()))
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        assert slave._controller is not None
        assert not [m for m in slave.log_queue if "not the paper's" in m.msg]  # a warning there means rejected
        slave.l = 0.0
        assert slave.do_step(0.0, reals["Ts"])
        return [m for m in slave.log_queue if "not the paper's 0.1 s" in m.msg]

    assert messages({"Ts": 0.1}) == []
    (both,) = messages({"Ts": 0.2})
    assert both.status == Fmi2Status.warning and "theta0.* are THETA0_44N" in both.msg and "Table 2's" in both.msg
    (box,) = messages({"Ts": 0.2, "theta0.b1": 0.7})
    assert "THETA0_44N" not in box.msg and "box_lower.*/box_upper.* are Table 2's" in box.msg
    opened = {f"box_{s}.{n}": (-math.inf if s == "lower" else math.inf) for s in ("lower", "upper") for n in ("a1", "a2", "b1")}
    assert messages({"Ts": 0.2, "theta0.b1": 0.7, **opened}) == []


def test_a_command_pinned_at_a_valve_limit_is_logged_once():
    """Readings in metres (0.03 for 30 mm) leave the valve at 10 V for the whole run, which must not pass without a word:
    after 10 s at a limit the error pushes into, a warning says so once, naming r, l and the unit."""
    from fmu_controller.controller_slave import AMPCController

    slave = AMPCController(instance_name="metres")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    for k in range(300):
        slave.l = 0.03
        assert slave.do_step(k * 0.1, 0.1)
    msgs = [m for m in slave.log_queue if "has sat at the valve's" in m.msg]
    assert len(msgs) == 1 and msgs[0].status == Fmi2Status.warning
    assert "10 V for 10 s" in msgs[0].msg and "(now 0.03 mm)" in msgs[0].msg and "metres?" in msgs[0].msg
    tracked = AMPCController(instance_name="mm")  # a reachable reference: never pinned that long
    tracked.enter_initialization_mode()
    tracked.exit_initialization_mode()
    from fmu_plant import Plant

    plant = Plant(seed=0)
    for k in range(450):
        tracked.l = plant.measurement.l_mm
        assert tracked.do_step(k * 0.1, 0.1)
        plant.step(tracked.u, 0.1)
    assert not [m for m in tracked.log_queue if "has sat at the valve's" in m.msg]


@pytest.mark.parametrize("method", [1, 2, 3, 4])
def test_a_command_held_at_a_limit_against_the_error_is_logged_once(method):
    """A negative theta0.b1 (a fixed method; an adaptive one without a box, whose b1 keeps theta0's sign)
    holds the valve at 0 V for a whole run while l stays 35 mm below r, which must not pass with no message: after 10 s at a
    limit the error pushes away from (from 5 s on for the adaptive ones, whose start-up probes), a
    warning names theta0.b1 once. The same loop with the default
    theta0 says nothing of it at either load."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant

    def run(load_n, **par):
        slave = AMPCController(instance_name="held")
        slave._int_par["method"] = method
        slave._par.update(par)
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        plant = Plant(seed=0)
        plant.reset(seed=0, load_n=load_n)
        for k in range(300):
            slave.l = plant.measurement.l_mm
            assert slave.do_step(k * 0.1, 0.1)
            plant.step(slave.u, 0.1)
        return [m for m in slave.log_queue if "where the other way would close the gap" in m.msg]

    open_box = {f"box_{s}.{n}": (-math.inf if s == "lower" else math.inf) for s in ("lower", "upper") for n in ("a1", "a2", "b1")}
    (held,) = run(44.0, **{"theta0.b1": -0.8, **open_box})
    assert held.status == Fmi2Status.warning and "theta0.b1 = -0.8 < 0 inverts the law" in held.msg
    assert 10.0 <= float(held.msg.split()[2]) <= 20.0  # after the adaptive start-up's probing, if any
    assert "valve's 0 V for 10 s" in held.msg and "below the reference" in held.msg
    assert run(44.0) == [] and run(68.0) == []


def test_a_sampling_period_typed_in_milliseconds_is_logged_and_the_time_at_a_limit_is_true():
    """Ts = 50 (meant: 50 ms) stepped by a host at 0.05 s samples once and holds its command for 50 s;
    the only message must not claim at t = 0 that the command has sat at 10 V for 10 s. The first step
    says Ts is in seconds and asks about milliseconds; the time at a limit counts from the first sample
    there to the present one (50 s, said at t = 50 s). Ts = 0.1 s stepped at 1 ms (a fast FMU beside
    it in the host) and Ts = 2 s stepped at 0.5 s are said nothing of."""
    from fmu_controller.controller_slave import AMPCController

    def run(ts, h, n):
        slave = AMPCController(instance_name="ms")
        slave._par["Ts"] = ts
        slave._int_par["reference_source"] = 2  # external_held: the built-in sine refuses Ts = 50 s (Nyquist)
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        for k in range(n):
            slave.l, slave.r = 1.0, 60.0
            assert slave.do_step(k * h, h)
        return [m for m in slave.log_queue if m.status == Fmi2Status.warning]

    said = run(50.0, 0.05, 1001)
    ms = [m.msg for m in said if "typed in milliseconds" in m.msg]
    assert len(ms) == 1 and ms[0].startswith("t = 0 s: Ts = 50 s, and the host steps at 0.05 s") and "(1000 steps a sample)" in ms[0]
    assert "is it 0.05 s typed in milliseconds?" in ms[0]
    pinned = [m.msg for m in said if "has sat at the valve's" in m.msg]
    assert len(pinned) == 1 and pinned[0].startswith("t = 50 s: the command has sat at the valve's 10 V for 50 s"), pinned
    for ts, h, n in ((0.1, 0.001, 200), (2.0, 0.5, 8)):
        assert not [m.msg for m in run(ts, h, n) if "milliseconds" in m.msg]


def test_a_law_that_slams_the_valve_is_logged_once():
    """A fixed predictor from an open-loop identification makes the MPCs slam the valve end to end for a
    whole run at Ts != 0.1 s, which must not pass without a word: 20 full-range jumps within 10 s are logged once. A divergence
    at forgetting = 1 does not advise on forgetting factors."""
    import dataclasses

    from fmu_controller.controller_slave import AMPCController

    for method, who in ((2, "the fixed predictor theta0"), (4, "the adaptive law")):
        slave = AMPCController(instance_name="slam")
        vr = {var.name: v for v, var in slave.vars.items()}
        slave.set_integer([vr["method"]], [method])
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        real_step = slave._controller.step
        slave._controller.step = lambda l, r: dataclasses.replace(real_step(l, r), u_v=10.0 * (slave._k % 2))
        for k in range(100):
            slave.l = 30.0
            assert slave.do_step(k * 0.1, 0.1)
        msgs = [m for m in slave.log_queue if "jumped across the valve's range" in m.msg]
        assert len(msgs) == 1 and msgs[0].status == Fmi2Status.warning
        assert msgs[0].msg.startswith("t = 2 s: the command has jumped across the valve's range 20 times in 10 s")
        assert who in msgs[0].msg
    slave = AMPCController(instance_name="paper_rls")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_real([vr["startup_s"]], [0.0])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    real_step = slave._controller.step
    slave._controller.step = lambda l, r: dataclasses.replace(real_step(l, r), predicted_next_mm=1e9)
    slave.l = 30.0
    assert slave.do_step(0.0, 0.1)
    (msg,) = [m.msg for m in slave.log_queue if "far outside the rig's" in m.msg]
    assert "its estimate diverges (theta0 or the box C far from this rig" in msg and "forgetting" not in msg


@pytest.mark.parametrize("set_delay, parallel, shown", [(0, False, None), (1, True, None), (0, True, 1), (1, False, 0)])
def test_an_input_delay_set_wrong_for_the_master_is_warned_of(set_delay, parallel, shown):
    """input_delay_samples = 0 in a parallel master (AMPC-servo: Eq. (21) 1.95 mm against 0.15 with 1)
    or 1 in a sequential one (0.74 against 0.08 mm) must not run without a word. The first 30 s are scored
    as -1 scores them, and a delay the measurements show DELAY_RATIO times better is named once."""
    from fmu_plant import Plant, PlantParams

    slave = AMPCController(instance_name="set")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["input_delay_samples"]], [set_delay])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant, u_prev = Plant(PlantParams(), seed=0), 0.0
    for k in range(400):
        slave.l = plant.measurement.l_mm
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(u_prev if parallel else slave.u, 0.1)  # a parallel master: the plant gets u one step late
        u_prev = slave.u
    said = [m for m in slave.log_queue if "the measurements show an input delay" in m.msg]
    if shown is None:
        assert said == []
    else:
        (message,) = said
        assert message.status == Fmi2Status.warning and message.msg.startswith(
            f"t = 30 s: the measurements show an input delay of {shown} sample{'s' if shown != 1 else ''}, not the "
            f"{set_delay} set")
        assert f"set input_delay_samples = -1 to decide it from the start, or {shown} (scores from" in message.msg
        assert ("one sample late: a parallel master at h = Ts" if shown == 1
                else "within its sample: a sequential master") in message.msg


def test_minus_one_deciding_the_longest_delay_it_scores_says_the_valve_may_act_later_still():
    """-1 scores the delays 0..5 only: on a rig whose valve acts 0.7 s late (7 samples) it decides 5 at
    5 s, and says once that the delay may be longer and how to set it (up to 25); a rig it can tell
    (0.2 s, 2 samples) is not warned of."""
    from fmu_plant import Plant, PlantParams

    for delay_s, warned in ((0.7, True), (0.2, False)):
        slave = AMPCController(instance_name="long")
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        plant = Plant(PlantParams().with_values(**{"delay.delay_s": delay_s}), seed=0)
        for k in range(120):
            slave.l = plant.measurement.l_mm
            assert slave.do_step(k * 0.1, 0.1)
            plant.step(slave.u, 0.1)
        said = [m for m in slave.log_queue if "the valve may act later still" in m.msg]
        assert slave.input_delay == (5 if warned else 2)
        assert len(said) == warned
        if warned:
            assert said[0].status == Fmi2Status.warning and said[0].msg.startswith(
                "t = 5 s: input_delay_samples = -1 decided for 5 samples (0.5 s), the longest it decides")
            assert "Set input_delay_samples to the rig's delay over Ts = 0.1 s, rounded (up to 25, 2.5 s" in said[0].msg


def test_a_set_delay_shown_short_by_the_longest_delay_scored_is_not_told_to_take_that_one():
    """input_delay_samples = 0 on a rig whose valve acts 0.7 s late: the first 30 s show the longest delay
    scored, 5 samples, which the rig's may exceed; the warning says so and asks for the rig's delay
    over Ts, not for 5 or -1 (which decides 5 at most)."""
    from fmu_plant import Plant, PlantParams

    slave = AMPCController(instance_name="short")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["input_delay_samples"]], [0])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = Plant(PlantParams().with_values(**{"delay.delay_s": 0.7}), seed=0)
    for k in range(310):
        slave.l = plant.measurement.l_mm
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    (msg,) = [m.msg for m in slave.log_queue if "the measurements show an input delay" in m.msg]
    assert "an input delay of 5 samples or more (the longest scored), not the 0 set" in msg, msg
    assert "set input_delay_samples to the rig's delay over Ts, rounded (5 or more, up to 25;" in msg, msg
    assert "-1 to decide it" not in msg


def test_a_set_delay_of_the_cap_runs():
    """input_delay_samples = 25 (0.5 s at Ts = 0.02 s) is within the declared range and runs; the
    preview of the built-in sine is Hp + 25 samples long."""
    slave = AMPCController(instance_name="cap")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["input_delay_samples"]], [25])
    slave.set_real([vr["Ts"]], [0.02])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    assert slave._hp == 5 + 25
    for k in range(60):
        slave.l = 30.0
        assert slave.do_step(k * 0.02, 0.02)
    assert slave.input_delay == 25 and 0.0 <= slave.u <= 10.0


@pytest.mark.parametrize("ints, said, not_said", [
    ({"method": 4, "input_delay_samples": -1}, ["a model poor for this rig (theta0, the box C) or a delay"],
     ["fixed predictor", "servo.Hp", "0 samples set"]),
    ({"method": 4, "input_delay_samples": 0, "servo.Hp": 40},
     ["more delay in the loop than the 0 samples set", "a long prediction horizon servo.Hp = 40"], ["fixed predictor"]),
    ({"method": 1, "input_delay_samples": -1, "servo.Hp": 40}, ["the fixed predictor theta0 poor"],
     ["servo.Hp", "0 samples set", "a model poor"]),
])
def test_a_limit_cycles_causes_are_those_the_settings_leave_possible(ints, said, not_said):
    """What the limit-cycle warning lists once the law compensates no delay (0 set, or -1 decided 0):
    the delay only where 0 was set, the fixed predictor for methods 1 and 2, a servo horizon longer
    than Table 5's for a servo method; else the generic cause."""
    slave = AMPCController(instance_name="causes")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr[k] for k in ints], list(ints.values()))
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    causes = "; ".join(slave._watch.limit_cycle_causes(42.0))
    assert all(s in causes for s in said) and not any(s in causes for s in not_said), causes


def test_a_heavy_move_weight_is_named_among_a_limit_cycles_causes():
    """MPC-servo with servo.R = 10^4 (Table 5: 15) swings the valve limit to limit (17 mm of Eq. (21)
    error): the QP moves the valve only once the integrator's cost has grown. The warning must not name a delay
    and the fixed predictor only; it names servo.R, which Table 5's R does not make it do."""
    from fmu_plant import Plant

    def causes(r):
        slave = AMPCController(instance_name="heavy")
        slave._int_par["method"] = 2
        slave._par["servo.R"] = r
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        plant = Plant(seed=0)
        for k in range(700):  # said at 61 s (the delay decided at 26.5 s, then a window of 10 s)
            slave.l = plant.measurement.l_mm
            assert slave.do_step(k * 0.1, 0.1)
            plant.step(slave.u, 0.1)
        return [m.msg for m in slave.log_queue if "a limit cycle" in m.msg]

    (msg,) = causes(1e4)
    assert "a heavy move weight servo.R = 10000 (Table 5: 15)" in msg and "lower servo.R" in msg
    assert causes(15.0) == []
    table5 = AMPCController(instance_name="t5")
    table5._int_par["method"] = 2
    table5.enter_initialization_mode()
    table5.exit_initialization_mode()
    assert not any("heavy move weight" in c for c in table5._watch.limit_cycle_causes(42.0))


def test_an_overflow_names_theta0_only_where_it_was_set():
    slave = AMPCController(instance_name="hint")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    assert slave.overflow_hint().endswith("theta0 is far from a model of a muscle")


@pytest.mark.parametrize("delay", [0, -1])
def test_a_fixed_predictors_limit_cycle_names_the_predictor_and_no_delay_the_data_ruled_out(delay):
    """MPC-servo on THETA0_44N after a step 35 -> 80 mm swings the valve limit to limit for good
    (Eq. (21) 9.3 mm; AMPC-servo tracks it to 0.01 mm). The warning must not blame an uncompensated delay and
    advise -1, which decides 0 and changes nothing: it names the fixed predictor, and the delay only
    where 0 was set rather than decided."""
    from fmu_plant import Plant, PlantParams

    slave = AMPCController(instance_name="fixed")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["method"], vr["input_delay_samples"], vr["reference_source"]], [2, delay, 2])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = Plant(PlantParams(), seed=0)
    for k in range(450):
        slave.l, slave.r = plant.measurement.l_mm, 35.0 if k < 200 else 80.0
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    (msg,) = [m.msg for m in slave.log_queue if "a limit cycle" in m.msg]
    assert "the fixed predictor theta0 poor where the loop runs now (l = " in msg
    assert "an adaptive method (3, 4), or theta0 identified over this range" in msg
    assert ("more delay in the loop than the 0 samples set" in msg) == (delay == 0), msg
    assert "servo.Hp" not in msg


@pytest.mark.parametrize("delay, said", [(0, 1), (2, 0), (-1, 0)])
def test_a_limit_cycle_from_an_uncompensated_delay_is_logged_once(delay, said):
    """A rig whose valve acts 0.2 s late makes the undelayed law swing the valve between its limits
    17-19 times in 10 s (Eq. (21) 7.4 mm), which must not pass without a word: after the start-up, 6 swings within 10 s
    are logged once, naming input_delay_samples; with the delay set (2) or decided (-1) the loop
    tracks and nothing is said."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant, PlantParams

    slave = AMPCController(instance_name="delayed")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["input_delay_samples"]], [delay])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    assert slave.input_delay == -1  # before the first sample
    plant = Plant(PlantParams().with_values(**{"delay.delay_s": 0.2}), seed=0)
    for k in range(600):
        slave.l = plant.measurement.l_mm
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    msgs = [m for m in slave.log_queue if "a limit cycle" in m.msg]
    assert len(msgs) == said, [m.msg for m in msgs]
    assert slave.input_delay == (2 if delay == -1 else delay)  # the output says what the law ran for
    if said:
        assert msgs[0].status == Fmi2Status.warning and "input_delay_samples = 0)" in msgs[0].msg
        assert 12.0 <= float(msgs[0].msg.split(" ")[2]) <= 20.0  # just after the 12-s start-up


@pytest.mark.parametrize("method", [3, 4])
def test_the_papers_start_is_not_taken_for_a_limit_cycle(method):
    """The paper's start (startup_s = 0) of the adaptive methods swings the valve between its limits 6
    times in its first 1-1.5 s on the rig without any delay: that transient is no limit cycle, and
    nothing is said (else it would be, at t = 0.9-1.6 s, in every cell)."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant

    slave = AMPCController(instance_name="paper_start")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["method"], vr["input_delay_samples"]], [method, 0])
    slave.set_real([vr["startup_s"]], [0.0])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = Plant(seed=0)
    swings = 0
    for k in range(300):
        slave.l = plant.measurement.l_mm
        assert slave.do_step(k * 0.1, 0.1)
        swings += k < 20 and slave.u in (0.0, 10.0)
        plant.step(slave.u, 0.1)
    assert swings >= 6  # the start does hit the limits: the case is not vacuous
    assert not [m.msg for m in slave.log_queue if "a limit cycle" in m.msg]


@pytest.mark.parametrize("method, delay, gentler", [
    (4, 3, "raise delay_move_weight (servo.R times it for a delay of 2 or more) (docs"),
    (4, 8, "raise delay_move_weight (servo.R times it for a delay of 2 or more), and raise servo.Hp to the delay "
           "or more (now 5 < 8 samples) (docs"),
    (4, 1, "raise servo.R (docs"),
    (2, 3, "raise delay_move_weight (servo.R times it for a delay of 2 or more), and make the fixed theta0 under"),
    (1, 3, "raise ucp.Hp (a later coincidence point), and make the fixed theta0 under the delay (docs")])
def test_a_limit_cycle_with_the_delay_set_is_not_blamed_on_a_missing_compensation(method, delay, gentler):
    """With a delay set (or decided), swings between the limits mean that delay is off or the law too
    aggressive for it: the message says so, not to set the delay the user has set, and names what makes
    this method's law gentler at this delay (delay_move_weight is not named for every method and delay:
    it does nothing for the unique coincidence point and for a delay of 1)."""
    import dataclasses

    from fmu_controller.controller_slave import AMPCController

    slave = AMPCController(instance_name="set")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_integer([vr["input_delay_samples"], vr["method"]], [delay, method])
    slave.set_real([vr["startup_s"]], [0.0])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    real_step = slave._controller.step
    # limit to limit every 4 samples, passing through 5 V: no full-range jump, a swing each time
    slave._controller.step = lambda l, r: dataclasses.replace(real_step(l, r), u_v=(0.0, 5.0, 10.0, 5.0)[slave._k % 4])
    for k in range(140):
        slave.l = 30.0
        assert slave.do_step(k * 0.1, 0.1)
    (msg,) = [m.msg for m in slave.log_queue if "a limit cycle" in m.msg]
    assert msg.startswith("t = 11 s: ")  # the first 10 s after the estimator's start are not judged
    assert (f"a limit cycle (input_delay_samples = {delay}): the loop's delay differs from the one the law "
            "compensates") in msg
    assert gentler in msg, msg
    # -1 decides no delay beyond 5 samples: from 5 on it is not offered as the check
    assert ("check the delay (-1 decides it)" in msg) == (delay < 5), msg
    assert ("check the delay (-1 decides delays up to 5 samples: a longer one is set, the rig's delay over Ts "
            "rounded, up to 25)" in msg) == (delay >= 5), msg


def test_a_rewind_logs_what_the_run_from_there_logs():
    """The monitors' memory is part of the FMU state: restored before the pinned command was said, it
    is said again on the way; restored after, not twice."""
    from fmu_controller.controller_slave import AMPCController

    slave = AMPCController(instance_name="rewind")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()

    def run(k0, k1):
        for k in range(k0, k1):
            slave.l = 0.03  # metres: pinned at 10 V
            assert slave.do_step(k * 0.1, 0.1)

    run(0, 50)
    early = slave._get_fmu_state()
    run(50, 200)
    late = slave._get_fmu_state()
    said = lambda: len([m for m in slave.log_queue if "has sat at the valve's" in m.msg])  # noqa: E731
    assert said() == 1
    slave._set_fmu_state(early)
    run(50, 200)
    assert said() == 2
    slave._set_fmu_state(late)
    run(200, 300)
    assert said() == 2


def test_minus_ones_decision_of_a_delay_is_logged_once_a_run_and_again_after_a_rewind_before_it():
    """The controller slave and a plant with a 0.2-s delay, stepped as a sequential master: -1 decides 2
    samples at 5 s and logs it once, as a warning, with no event beside it; restored to a state before
    the decision the run logs it again, restored after it not."""
    from fmu_plant import Plant, PlantParams

    slave = AMPCController(instance_name="delay")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = Plant(PlantParams().with_values(**{"delay.delay_s": 0.2}), seed=0)

    def run(k0, k1):
        for k in range(k0, k1):
            slave.l = plant.measurement.l_mm
            assert slave.do_step(k * 0.1, 0.1)
            plant.step(slave.u, 0.1)

    def decided():
        return [m for m in slave.log_queue if "input_delay_samples = -1 decided for" in m.msg]

    run(0, 40)
    early, plant_early = slave._get_fmu_state(), plant.get_state()
    run(40, 80)
    late, plant_late = slave._get_fmu_state(), plant.get_state()
    (msg,) = decided()
    assert msg.status == Fmi2Status.warning and "decided for 2 samples (0.2 s): a transport delay" in msg.msg
    slave._set_fmu_state(early)
    plant.set_state(plant_early)
    run(40, 80)
    assert len(decided()) == 2
    slave._set_fmu_state(late)
    plant.set_state(plant_late)
    run(80, 120)
    assert len(decided()) == 2


def test_a_step_that_passes_a_sample_time_is_discarded_and_the_host_can_step_to_it(fmu, capfd):
    """A step over [0.07, 0.14] s contains the sample time 0.1 s: refused with fmi2Discard at once, where
    the host can still step to the sample (once past it, every later step would be refused), the state
    unchanged; stepping to 0.1 s and on gives the commands of steps on the grid."""
    vr = fmu[3]
    f, g = _instance(fmu, "f"), _instance(fmu, "g")
    f.setReal([vr["l"]], [_l(0)])
    f.doStep(0.0, 0.07)
    capfd.readouterr()
    with pytest.raises(FMICallException, match="discard"):
        f.doStep(0.07, 0.07)
    assert ("the step from t = 0.07 s to 0.14 s passes the sample time 0.1 s (k = 1) without ending there; end "
            "the step at 0.1 s") in capfd.readouterr().out
    f.doStep(0.07, 0.03)
    for k in range(1, 20):
        f.setReal([vr["l"]], [_l(k)])
        f.doStep(k * 0.1, 0.1)
    for k in range(20):
        g.setReal([vr["l"]], [_l(k)])
        g.doStep(k * 0.1, 0.1)
    assert f.getReal([vr["u"], vr["xs"]]) == g.getReal([vr["u"], vr["xs"]])
    assert f.getInteger([vr["samples"]]) == [20]
    _free(f, g)


def test_fmpy_starts_a_run_from_a_saved_state_in_a_fresh_instance(fmu):
    """simulate_fmu(fmu_state=...) restores the state into an instance that was never initialised (FMI
    2.0 allows it there): the run goes on as the saved instance's, bit for bit, with the state's method."""
    import fmpy

    vr = fmu[3]
    a = _instance(fmu, "a", ints={"method": 2})
    for k in range(80):
        a.setReal([vr["l"]], [_l(k)])
        a.doStep(k * 0.1, 0.1)
    state = a.serializeFMUstate(a.getFMUstate())
    expected = []
    for k in range(80, 90):
        a.setReal([vr["l"]], [_l(k)])
        a.doStep(k * 0.1, 0.1)
        expected.append(tuple(a.getReal([vr["u"], vr["xs"]])))
    times = np.round(np.arange(80, 90) * 0.1, 10)
    signal = np.array(list(zip(times, [_l(k) for k in range(80, 90)])), dtype=[("time", float), ("l", float)])
    result = fmpy.simulate_fmu(str(fmu[0]), fmu_state=state, start_time=8.0, stop_time=9.0, output_interval=0.1,
                               input=signal, output=["u", "xs", "method"])
    assert list(zip(result["u"][1:], result["xs"][1:])) == expected  # row i: after the step at 8.0 + (i - 1) 0.1 s
    assert len({xs for _, xs in expected}) > 5  # a state that moves
    assert set(result["method"]) == {2}
    _free(a)


def test_a_stepping_controller_is_not_initialised_again_and_keeps_its_outputs(fmu, capfd):
    """A second initialisation without fmi2Reset is refused with fmi2Error (FMI 2.0 allows it only before
    step mode; a next run would start from this one's u and x_s), and the instance keeps its outputs."""
    vr = fmu[3]
    f = _instance(fmu)
    for k in range(10):
        f.setReal([vr["l"]], [_l(k)])
        f.doStep(k * 0.1, 0.1)
    before = f.getReal([vr["u"], vr["xs"]])
    capfd.readouterr()
    for call in (lambda: f.setupExperiment(startTime=0.0), f.enterInitializationMode, f.exitInitializationMode):
        with pytest.raises(FMICallException, match="error"):
            call()
    assert capfd.readouterr().out.count("call fmi2Reset first") == 3
    assert f.getReal([vr["u"], vr["xs"]]) == before and f.getInteger([vr["samples"]]) == [10]
    _free(f)


def test_another_fmus_state_is_refused_naming_its_variables(fmu, built_fmus, capfd):
    """The plant's state (serialised) into the controller: fmi2Error naming variables it has and lacks,
    and the controller steps on unchanged."""
    plant = open_fmu(built_fmus["MusclePlant"])
    p = instantiate(plant, "p")
    p.doStep(0.0, 0.1)
    foreign = p.serializeFMUstate(p.getFMUstate())
    vr = fmu[3]
    f, g = _instance(fmu, "f"), _instance(fmu, "g")
    capfd.readouterr()
    with pytest.raises(FMICallException, match="error"):
        f.setFMUstate(f.deSerializeFMUstate(foreign))
    out = capfd.readouterr().out
    assert "not an FMU state of this FMU: a state of another FMU or another build of this one (it has " in out, out
    assert "backlash.slack_mm" in out and "lacks H, P0.A1" in out
    for k in range(20):
        for h in (f, g):
            h.setReal([vr["l"]], [_l(k)])
            h.doStep(k * 0.1, 0.1)
    assert f.getReal([vr["u"], vr["xs"]]) == g.getReal([vr["u"], vr["xs"]])
    _free(f, g, p)


def test_a_state_keeps_its_runs_start_time(fmu):
    """The sample times t0 + k Ts count from the start time of the run that saved the state, also in an
    instance restored without fmi2SetupExperiment (fmpy's fmu_state=) or set up with another start."""
    from fmpy.fmi2 import FMU2Slave

    path, md, folder, vr = fmu

    def fresh(name, start=None):
        f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName=name)
        f.instantiate(loggingOn=True)
        if start is not None:
            f.setupExperiment(startTime=start)
            f.enterInitializationMode()
            f.exitInitializationMode()
        return f

    def run(f, k0, n=10):
        out = []
        for k in range(k0, k0 + n):
            f.setReal([vr["l"]], [_l(k)])
            f.doStep(2.0 + k * 0.1, 0.1)
            out.append(f.getReal([vr["u"], vr["xs"]]))
        return out

    a = fresh("a", start=2.0)
    run(a, 0, 30)
    state = a.serializeFMUstate(a.getFMUstate())
    expected = run(a, 30)
    for b in (fresh("b"), fresh("c", start=7.0)):
        b.setFMUstate(b.deSerializeFMUstate(state))
        assert run(b, 30) == expected
        _free(b)
    _free(a)


def test_a_reading_taken_for_a_sensor_glitch_is_logged_and_counted():
    """A reading 50 mm off for one sample: the FMU logs it as a warning naming the reading, the bound
    and the prediction used; the run summary counts it; with max_speed = 0 it is used and not said."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant

    def run(**par):
        slave = AMPCController(instance_name="glitch")
        slave._par.update(par)
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        plant = Plant(seed=0)
        for k in range(400):
            slave.l = plant.measurement.l_mm + (50.0 if k == 300 else 0.0)
            assert slave.do_step(k * 0.1, 0.1)
            plant.step(slave.u, 0.1)
        return slave, [m for m in slave.log_queue if "taken for a sensor glitch" in m.msg]

    slave, (msg,) = run()
    assert msg.status == Fmi2Status.warning and msg.msg.startswith("t = 30 s: the reading l = ")
    assert "max_speed x Ts = 400 x 0.1 = 40 mm" in msg.msg and "the prediction" in msg.msg
    assert "1 readings taken for sensor glitches and held (max_speed)" in slave.run_summary()
    off, said = run(max_speed=0.0)
    assert said == [] and "sensor glitches" not in off.run_summary()


def test_a_stale_repeat_of_the_reading_is_logged_and_counted():
    """The reading of t = 30 s, the sine's fastest point, delivered again at the next sample: the FMU
    logs it as a stale sample with the prediction used, and the run summary counts it."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant

    slave = AMPCController(instance_name="stale")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant, fed, stale = Plant(seed=0), None, None
    for k in range(400):
        fed = fed if k == 301 else plant.measurement.l_mm
        stale = fed if k == 301 else stale
        slave.l = fed
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    (msg,) = [m for m in slave.log_queue if "stale sample" in m.msg]
    assert msg.status == Fmi2Status.warning and msg.msg.startswith(f"t = 30.1 s: the reading l = {stale:g} mm repeats the last")
    assert "1 readings taken for sensor glitches and held (max_speed)" in slave.run_summary()


def test_a_spike_under_the_speed_bound_is_logged_as_a_spike_and_counted():
    """A reading 25 mm off for one sample, within the 40 mm the muscle could move: the FMU holds it as a
    one-sample spike, logs the reading, the prediction used and the limit it exceeded, and counts it."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant

    slave = AMPCController(instance_name="spike")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = Plant(seed=0)
    for k in range(400):
        slave.l = plant.measurement.l_mm + (-25.0 if k == 300 else 0.0)
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    (msg,) = [m.msg for m in slave.log_queue if "spike" in m.msg]
    assert re.match(r"t = 30 s: the reading l = [\d.]+ mm is 2[45]\.\d+ mm from the one-step prediction [\d.]+ mm, more than "
                    r"the 5 mm it has lately come within \(the larger of 5 mm and 10 times the mean error\): taken for a "
                    r"one-sample spike of the sensor", msg), msg
    assert "1 readings taken for sensor glitches and held (max_speed)" in slave.run_summary()
    assert "muscle's own" not in slave.run_summary() and not [m for m in slave.log_queue if "muscle's own" in m.msg]


def test_a_held_reading_the_next_one_finds_the_muscles_own_is_logged_so_and_counted():
    """The tap shut at t = 30 s: the muscle drains and its reading at 30.1 s is 15 mm off the prediction,
    held as a spike (one sample cannot tell); the reading at 30.2 s stays by it, and the FMU logs that
    the held one was the muscle's own move, the run summary counts it among the held ones."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant

    slave = AMPCController(instance_name="tap")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = Plant(seed=0)
    for k in range(400):
        if k == 300:
            plant.update(supply_pressure_mpa=0.0)
        slave.l = plant.measurement.l_mm
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    (held,) = [m for m in slave.log_queue if "taken for a one-sample spike" in m.msg]
    (own,) = [m for m in slave.log_queue if "was the muscle's own" in m.msg]
    assert held.msg.startswith("t = 30.1 s: the reading l = ") and own.status == Fmi2Status.warning
    reading = re.match(r"t = 30.1 s: the reading l = ([\d.]+) mm", held.msg)[1]
    assert own.msg.startswith(f"t = 30.2 s: the reading held one sample before as a one-sample spike of the sensor, "
                              f"l = {reading} mm, was the muscle's own")
    assert ("1 readings taken for sensor glitches and held (max_speed), 1 of them found the muscle's own move by the "
            "reading after") in slave.run_summary()


def test_a_stuck_reading_is_logged_once_and_counted():
    """Readings frozen from t = 20 s: the FMU logs one warning naming the reading and how long it has
    not changed, the run summary counts the stretch; an unfrozen run says neither."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant

    def run(freeze):
        slave = AMPCController(instance_name="stuck")
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        plant = Plant(seed=0)
        frozen = None
        for k in range(400):
            reading = plant.measurement.l_mm
            if freeze and k >= 200:
                frozen = reading if frozen is None else frozen
                reading = frozen
            slave.l = reading
            assert slave.do_step(k * 0.1, 0.1)
            plant.step(slave.u, 0.1)
        return slave, frozen, [m for m in slave.log_queue if "has not changed at all" in m.msg]

    slave, frozen, (msg,) = run(True)
    assert msg.status == Fmi2Status.warning and f"the reading l = {frozen:g} mm has not changed" in msg.msg
    assert "the sensor is stuck" in msg.msg
    assert "the reading stuck 1 time (unchanged while the valve went end to end)" in slave.run_summary()
    healthy, _, said = run(False)
    assert said == [] and "stuck" not in healthy.run_summary()


def test_servo_max_iter_bounds_the_qp_and_reaches_the_law():
    """The FMU's servo.max_iter is ServoMPCSettings.max_iter (the bound of a step's worst-case time);
    the declared range is the settings' own."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_controller.servo_settings import DEFAULT_OSQP_ITER, MAX_OSQP_ITER, ServoMPCSettings

    slave = AMPCController(instance_name="iter")
    slave._int_par.update({"servo.max_iter": 400, "servo.Hp": 50, "servo.Hu": 50})
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    assert slave._controller.settings.servo.max_iter == 400
    assert AMPCController(instance_name="d")._int_par["servo.max_iter"] == DEFAULT_OSQP_ITER == ServoMPCSettings().max_iter
    with pytest.raises(ValueError, match="max_iter must be at most 100000"):
        ServoMPCSettings(max_iter=MAX_OSQP_ITER + 1)


def test_the_transient_of_a_reference_step_is_not_called_a_limit_cycle():
    """A 25-mm step of r (35 -> 60 mm at 30 s): AMPC-UCP's transient swings the valve limit to limit six
    times, which the log must not call a limit cycle blaming the model; the swings of a reference step's
    transient are not counted for 3 s after it. A loop that keeps swinging after that is still told
    (MPC-servo at 80 mm, where the fixed predictor is poor: 25 swings in 10 s, logged), also where the
    reference steps every 5 s (a rig's 0.2-s delay the law does not compensate)."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant, PlantParams

    def swings_said(method, r_after):
        slave = AMPCController(instance_name="step")
        slave._int_par.update({"method": method, "reference_source": 2})  # external_held
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        plant = Plant(seed=0)
        for k in range(900):
            slave.l = plant.measurement.l_mm
            slave.r = 35.0 if k < 300 else r_after
            assert slave.do_step(k * 0.1, 0.1)
            plant.step(slave.u, 0.1)
        return [m.msg for m in slave.log_queue if "a limit cycle" in m.msg]

    assert swings_said(3, 60.0) == []
    (said,) = swings_said(2, 80.0)
    assert float(said.split()[2]) > 33.0 and "the fixed predictor theta0 poor where the loop runs now" in said
    # a limit cycle under a reference that steps every 5 s is told all the same
    slave = AMPCController(instance_name="cycling")
    slave._int_par.update({"input_delay_samples": 0, "reference_source": 2})
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = Plant(PlantParams().with_values(**{"delay.delay_s": 0.2}), seed=0)
    for k in range(1200):
        slave.l = plant.measurement.l_mm
        slave.r = 35.0 if int(k * 0.1 // 5.0) % 2 == 0 else 60.0
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    assert len([m for m in slave.log_queue if "a limit cycle" in m.msg]) == 1


def test_a_sensor_that_keeps_glitching_is_logged_ten_times_and_counted_in_full():
    """Twelve glitches: the first ten are logged one by one (the tenth says further ones are not), the
    run summary counts all twelve."""
    from fmu_controller.controller_slave import AMPCController
    from fmu_plant import Plant

    slave = AMPCController(instance_name="glitches")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = Plant(seed=0)
    for k in range(400):
        slave.l = plant.measurement.l_mm + (50.0 if k >= 100 and k % 20 == 0 and k < 340 else 0.0)
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    said = [m.msg for m in slave.log_queue if "taken for a sensor glitch" in m.msg]
    assert len(said) == 10 and "further ones are counted in the run summary" in said[-1]
    assert not any("further ones" in m for m in said[:-1])
    assert "12 readings taken for sensor glitches and held (max_speed)" in slave.run_summary()
