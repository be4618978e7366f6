"""The MusclePlant FMU in fmpy: same numbers as the direct plant, FMI errors not crashes, exact state."""

import gc
import json
import math
import re

import pytest
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from fmpy_helpers import instantiate, open_fmu

from fmu_plant import Plant, PlantParams


@pytest.fixture(scope="module")
def fmu(built_fmus):
    return open_fmu(built_fmus["MusclePlant"])


def _instance(fmu, name="i", reals=None, ints=None, **kw):
    return instantiate(fmu, name, reals, ints, **kw)


def open_fresh(fmu, name):
    """An instantiated FMU2Slave of ``fmu``: no fmi2SetupExperiment, no initialisation."""
    from fmpy.fmi2 import FMU2Slave

    path, md, folder, _ = fmu
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    f.instantiate(loggingOn=True)
    return f


def _sine(k):
    return 5 + 3 * math.sin(2 * math.pi * 0.1 * k * 0.1)


def test_fmpy_validation_reports_no_problems(fmu):
    assert validate_fmu(str(fmu[0])) == []


def test_fmu_equals_the_direct_plant_bit_for_bit(fmu):
    vr = fmu[3]
    f = _instance(fmu, reals={"load_force": 68.0, "friction.rate_gain": 0.3}, ints={"seed": 5})
    direct = Plant(PlantParams().with_values(**{"friction.rate_gain": 0.3}), seed=5)
    direct.update(load_n=68.0)
    for k in range(200):
        f.setReal([vr["u"], vr["load_force"]], [_sine(k), 68.0])
        f.doStep(k * 0.1, 0.1)
        m = direct.step(_sine(k), 0.1)
        assert f.getReal([vr["l"], vr["p"]]) == [m.l_mm, m.p_mpa]
    f.terminate()
    f.freeInstance()


@pytest.mark.parametrize("ts", [0.1, 0.02])
def test_fmpy_simulate_fmu_gives_the_direct_plant_bits_with_noise_free_sensors(fmu, ts):
    """simulate_fmu computes each step as the difference of two times (0.10000000000000003 s at
    t = 0.2 s); the plant integrates the step meant, so with noise-free sensors (no 0.01-mm rounding to
    hide a difference at the solver's tolerance) the readings equal the direct plant's bit for bit, as
    they do in a master whose steps are exact."""
    import numpy as np
    from fmpy import simulate_fmu

    rng = np.random.default_rng(3)
    u = np.repeat(rng.uniform(2.0, 8.0, 30), 20)  # held commands, 20 samples each
    params = PlantParams().noise_free()
    t = np.arange(len(u)) * ts
    rows = np.array(list(zip(np.repeat(t, 2)[1:], np.repeat(u, 2)[:-1])), dtype=[("time", float), ("u", float)])
    steps = np.diff(np.arange(len(u)) * ts)
    assert np.any(steps != ts)  # the master's steps are not all Ts itself
    res = simulate_fmu(str(fmu[0]), start_values=params.dotted(), input=rows, stop_time=t[-1],
                       output_interval=ts, output=["l"])
    plant = Plant(params)
    direct = [plant.step(u_k, ts).l_mm for u_k in u[:-1]]
    assert res["l"][1:].tolist() == direct


def test_a_seed_is_unsigned_64_bit_in_the_fmu_as_directly(fmu):
    """Seeds ride as two FMI Integers (low and high 32 bits, bit patterns): the FMU's noise equals the
    direct plant's for seeds across the whole range, and different seeds give different noise (a
    seed of 2**32 must not be cut to 0, nor 2**31 refused)."""
    from fmu_plant.seed import SEED_MAX, split_seed

    vr = fmu[3]
    runs = {}
    for seed in (0, 2 ** 31, 2 ** 32, 2 ** 63, SEED_MAX):
        low, high = split_seed(seed)
        f = _instance(fmu, name=f"s{seed}", ints={"seed": low, "seed_high": high})
        direct = Plant(PlantParams(), seed=seed)
        out = []
        for k in range(40):
            f.setReal([vr["u"]], [_sine(k)])
            f.doStep(k * 0.1, 0.1)
            m = direct.step(_sine(k), 0.1)
            got = f.getReal([vr["l"]])[0]
            assert got == m.l_mm, seed
            out.append(got)
        f.terminate()
        f.freeInstance()
        runs[seed] = out
    assert len({tuple(v) for v in runs.values()}) == len(runs)  # five seeds, five noise sequences


def _run(f, vr, k0):
    """30 samples of the sine command from sample ``k0``: ``[l, p]`` after each step."""
    out = []
    for k in range(k0, k0 + 30):
        f.setReal([vr["u"]], [_sine(k)])
        f.doStep(k * 0.1, 0.1)
        out.append(f.getReal([vr["l"], vr["p"]]))
    return out


def test_state_rewind_and_serialisation_are_bit_identical(fmu):
    vr = fmu[3]
    f = _instance(fmu)

    def run(k0):
        return _run(f, vr, k0)

    run(0)
    state = f.getFMUstate()
    a = run(30)
    f.setFMUstate(state)
    assert run(30) == a
    f.setFMUstate(f.deSerializeFMUstate(f.serializeFMUstate(state)))
    assert run(30) == a
    f.terminate()
    f.freeInstance()


def test_a_state_of_an_instance_with_other_parameters_steps_with_them(fmu):
    """Restored into an instance with the default rig, a state of a 300-mm muscle with more friction
    must not report the state's parameters but step the default rig (74.58 mm at 6 s against 57.29): the
    plant is built again from the state's parameters, so both instances run alike, bit for bit."""
    vr = fmu[3]
    a = _instance(fmu, "a", reals={"muscle.rest_length_mm": 300.0, "friction.base_n": 20.0})
    b = _instance(fmu, "b")
    _run(a, vr, 0)
    _run(b, vr, 0)
    state = a.serializeFMUstate(a.getFMUstate())
    expected = _run(a, vr, 30)
    b.setFMUstate(b.deSerializeFMUstate(state))
    assert b.getReal([vr["muscle.rest_length_mm"]]) == [300.0]
    assert _run(b, vr, 30) == expected
    for f in (a, b):
        f.terminate()
        f.freeInstance()


@pytest.mark.parametrize("name, value, message", [("u", math.nan, "u = nan is not finite"),
                                                  ("u", math.inf, "u = inf is not finite"),
                                                  ("u", 50.0, "u = 50.0 is outside"),
                                                  ("load_force", -3.0, "load_force = -3.0 is outside"),
                                                  ("supply_pressure", 7.0, "supply_pressure = 7.0 is outside")])
def test_bad_input_is_discarded_with_a_message_and_outputs_stay(fmu, capfd, name, value, message):
    vr = fmu[3]
    f = _instance(fmu)
    f.setReal([vr["u"]], [6.0])
    f.doStep(0.0, 0.5)
    before = f.getReal([vr["l"], vr["p"]])
    f.setReal([vr[name]], [value])
    with pytest.raises(FMICallException, match="discard"):
        f.doStep(0.5, 0.1)
    assert message in capfd.readouterr().out
    assert f.getReal([vr["l"], vr["p"]]) == before and all(math.isfinite(x) for x in before)
    f.setReal([vr["u"], vr["load_force"], vr["supply_pressure"]], [6.0, 44.0, 0.25])
    f.doStep(0.5, 0.1)  # recovers
    f.terminate()
    f.freeInstance()


def test_bad_step_size_and_bad_parameter(fmu, capfd):
    f = _instance(fmu)
    with pytest.raises(FMICallException, match="discard"):
        f.doStep(0.0, -0.1)
    assert "step size = -0.1" in capfd.readouterr().out
    f.terminate()
    f.freeInstance()
    g = _instance(fmu, reals={"valve.cv_max": -1.0}, rejected=True)  # fmi2ExitInitializationMode: fmi2Error
    assert "cv_max" in capfd.readouterr().out
    with pytest.raises(FMICallException, match="error"):
        g.doStep(0.0, 0.1)
    g.terminate()
    g.freeInstance()


def test_several_instances_and_reinstantiation(fmu):
    vr = fmu[3]
    a, b = _instance(fmu, "a"), _instance(fmu, "b", reals={"load_force": 68.0})
    for k in range(100):
        a.setReal([vr["u"]], [6.0])
        b.setReal([vr["u"]], [6.0])
        a.doStep(k * 0.1, 0.1)
        b.doStep(k * 0.1, 0.1)
    la, lb = a.getReal([vr["l"]])[0], b.getReal([vr["l"]])[0]
    assert la - lb > 3.0  # the heavier load hangs lower: the instances do not share state
    for f in (a, b):
        f.terminate()
        f.freeInstance()
    c = _instance(fmu, "c")
    c.setReal([vr["u"]], [6.0])
    for k in range(100):
        c.doStep(k * 0.1, 0.1)
    assert c.getReal([vr["l"]])[0] == pytest.approx(la, abs=0.1)
    c.terminate()
    c.freeInstance()


def _live_slaves():
    gc.collect()
    return sum(type(o).__name__ == "MusclePlant" for o in gc.get_objects())


def test_real_access_to_a_non_real_variable_is_an_fmi_error(fmu):
    vr = fmu[3]
    f = _instance(fmu, reals={"load_force": 50.0, "friction.rate_gain": 0.3})
    # parameters, inputs and outputs all read back through the value-reference table
    assert f.getReal([vr["friction.rate_gain"], vr["load_force"], vr["u"]]) == [0.3, 50.0, 0.0]
    f.setReal([vr["u"]], [4.5])
    assert f.getReal([vr["u"]]) == [4.5]
    f.terminate()
    f.freeInstance()
    # a wrong reference is fmi2Error (the instance is fine), not pythonfmu's fmi2Fatal for an exception,
    # which unguarded would also free the slave twice at fmi2FreeInstance (fmi_slave.base docstring)
    before = _live_slaves()
    for i in range(12):
        f = _instance(fmu, f"bad{i}")
        bad = [lambda: f.getReal([vr["seed"]]), lambda: f.setReal([vr["seed"]], [1.0]),
               lambda: f.getReal([max(vr.values()) + 1]), lambda: f.getInteger([vr["u"]])][i % 4]
        with pytest.raises(FMICallException, match=r"\(error\)"):
            bad()
        f.doStep(0.0, 0.1)  # the slave is still alive and consistent
        assert 0.0 <= f.getReal([vr["l"]])[0] < 400.0
        f.terminate()
        f.freeInstance()
        _ = [{"a": list(range(50))} for _ in range(2000)]  # reuse freed memory
    assert _live_slaves() == before  # freed once each: no crash above, no leak


def _edited_state(field, value):
    """A serialised state of ``f`` with ``numerics[field] = value`` (a corrupted field)."""
    def edit(f):
        doc = json.loads(bytes(f.serializeFMUstate(f.getFMUstate())).decode())
        doc["numerics"][field] = value
        return json.dumps(doc).encode()
    return edit


@pytest.mark.parametrize("bad, message", [
    (lambda f: b"not json", "not an FMU state of this FMU"),
    (lambda f: b'{"variables": {}}', "not an FMU state of this FMU (unexpected content: another FMU, or another build of "
                                      "this one); nothing was changed"),
    (lambda f: b'{"variables": {}, "numerics": [1], "failed": false}', "not an FMU state of this FMU"),
    # a zero step scale would hang the next fmi2DoStep
    *[(_edited_state(k, v), f"state field {k}") for k, v in [
        ("kink_scale_s", float("nan")), ("kink_scale_s", 0.0), ("kink_scale_s", -1.0), ("t_s", float("inf")),
        ("state", [1.0]), ("gate", 2.0)]],
])
def test_a_foreign_or_corrupted_fmu_state_is_refused_and_changes_nothing(fmu, capfd, bad, message):
    """fmi2Error naming the problem, and the instance continues as if nothing had happened."""
    vr = fmu[3]
    f, ref = _instance(fmu, "f"), _instance(fmu, "ref")
    for g in (f, ref):
        g.setReal([vr["u"]], [6.0])
        g.doStep(0.0, 0.1)
    with pytest.raises(FMICallException, match=r"\(error\)"):
        f.setFMUstate(f.deSerializeFMUstate(bad(f)))
    assert message in capfd.readouterr().out
    for k in range(1, 20):
        for g in (f, ref):
            g.doStep(k * 0.1, 0.1)
    assert f.getReal([vr["l"], vr["p"]]) == ref.getReal([vr["l"], vr["p"]])
    for g in (f, ref):
        g.terminate()
        g.freeInstance()


def test_a_rounding_remainder_step_is_accepted_and_changes_nothing(fmu):
    """A master whose accumulated time leaves a remainder asks for a last step of 1e-14 .. 2e-12 s:
    fmi2OK, outputs unchanged; the next regular step continues."""
    vr = fmu[3]
    f = _instance(fmu)
    f.setReal([vr["u"], vr["load_force"], vr["supply_pressure"]], [6.0, 44.0, 0.25])
    f.doStep(0.0, 0.1)
    before = f.getReal([vr["l"], vr["p"]])
    for h in (1e-14, 2e-12, 9.9e-10):
        f.doStep(0.1, h)  # raises on any status but OK
        assert f.getReal([vr["l"], vr["p"]]) == before
    f.doStep(0.1, 0.1)
    assert f.getReal([vr["l"], vr["p"]]) != before
    f.terminate()
    f.freeInstance()


def test_both_fmus_declare_a_default_experiment(built_fmus):
    from fmpy import read_model_description

    for path in built_fmus.values():
        de = read_model_description(str(path)).defaultExperiment
        assert de is not None and float(de.startTime) == 0.0 and float(de.stepSize) == 0.1, path
        assert float(de.stopTime) == 60.0


def test_every_output_stays_within_its_declared_range_at_the_parameters_extremes(fmu, built_fmus):
    """A host may check outputs against their declared min..max: an encoder drifting at the
    parameters' extreme rate for 20 minutes (l -170 mm), a 100-MPa sensor on a 1-MPa supply (p above 1 MPa
    with noise) stay inside; the controller FMU accepts such a reading of l."""
    path, md, _, vr = fmu
    declared = {v.name: (v.min, v.max) for v in md.modelVariables if v.causality == "output"}
    f = _instance(fmu, reals={"sensor_drift.offset_mm": -100.0, "sensor_drift.rate_mm_per_min": -10.0,
                              "sensor.pressure_range_mpa": 100.0, "sensor.pressure_noise_std_mpa": 0.01,
                              "supply_pressure": 1.0, "u": 10.0})
    seen = {name: [] for name in declared}
    for k in range(20):
        f.doStep(k * 60.0, 60.0)
        for name, value in zip(declared, f.getReal([vr[n] for n in declared])):
            seen[name].append(value)
    f.terminate()
    f.freeInstance()
    assert min(seen["l"]) < -150.0 and max(seen["p"]) > 1.0  # the extremes reach past -100 mm and 1 MPa
    for name, (lo, hi) in declared.items():
        assert lo is None or float(lo) <= min(seen[name]), (name, lo, min(seen[name]))
        assert hi is None or max(seen[name]) <= float(hi), (name, hi, max(seen[name]))
    controller = open_fmu(built_fmus["AMPCController"])
    c = instantiate(controller, "c")
    for l_mm in (min(seen["l"]), 1200.0):  # a drifted reading, a 5000-mm muscle's contraction
        c.setReal([controller[3]["l"]], [l_mm])
        c.doStep(0.0, 0.1)  # fmpy raises on a Discard or an Error
        c.reset()
        c.setupExperiment(startTime=0.0)
        c.enterInitializationMode()
        c.exitInitializationMode()
    c.terminate()
    c.freeInstance()


def test_fmi_call_order_and_fixed_parameters_are_enforced(fmu, capfd):
    """A fixed parameter set after initialisation is refused with fmi2Error (the dynamics would ignore
    it) and keeps its value; fmi2DoStep after fmi2Terminate is fmi2Error; fmi2Reset makes both fine."""
    vr = fmu[3]
    f = _instance(fmu)
    with pytest.raises(FMICallException, match="error"):
        f.setReal([vr["valve.cv_max"]], [1.2])
    assert "parameter valve.cv_max is fixed" in capfd.readouterr().out
    assert f.getReal([vr["valve.cv_max"]]) == [1.5]
    f.doStep(0.0, 0.1)
    f.terminate()
    with pytest.raises(FMICallException, match="error"):
        f.doStep(0.1, 0.1)
    assert "fmi2DoStep after fmi2Terminate" in capfd.readouterr().out
    f.reset()
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setReal([vr["valve.cv_max"]], [1.2])
    assert f.exitInitializationMode() == 0
    f.doStep(0.0, 0.1)
    assert f.getReal([vr["valve.cv_max"]]) == [1.2]
    f.terminate()
    f.freeInstance()


def test_initialisation_and_termination_out_of_fmi_order_are_refused(fmu, capfd):
    """FMI 2.0's state machine: fmi2ExitInitializationMode without fmi2EnterInitializationMode is
    fmi2Error, fmi2Terminate before the instance steps fmi2Warning (hosts' clean-up calls it), and
    neither changes anything: the instance then initialises and steps as a fresh one."""
    vr = fmu[3]
    f = open_fresh(fmu, "order")
    with pytest.raises(FMICallException, match="error"):
        f.exitInitializationMode()
    assert "fmi2ExitInitializationMode before fmi2EnterInitializationMode" in capfd.readouterr().out
    with pytest.raises(FMICallException, match="error"):
        f.doStep(0.0, 0.1)  # not initialised by the refused call
    assert f.terminate() == 1  # fmi2Warning: a host's clean-up of an instance it only inspected
    assert "fmi2Terminate before fmi2ExitInitializationMode" in capfd.readouterr().out
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    assert f.terminate() == 1  # in initialisation mode; the instance is not marked terminated
    assert f.exitInitializationMode() == 0
    g = _instance(fmu, "reference")
    for k in range(5):
        for inst in (f, g):
            inst.setReal([vr["u"]], [_sine(k)])
            inst.doStep(k * 0.1, 0.1)
    assert f.getReal([vr["l"], vr["p"]]) == g.getReal([vr["l"], vr["p"]])
    for inst in (f, g):
        inst.terminate()
        inst.freeInstance()


def test_a_message_with_a_percent_sign_reaches_the_host_intact(fmu, capfd):
    """The loader passes pythonfmu's text on literally (formatting a '%' in it would crash the host)."""
    g = _instance(fmu, reals={"valve.cv_max": -1.0}, rejected=True)
    out = capfd.readouterr().out
    assert "valve.cv_max = -1.0 is outside" in out and "%" in out, out
    g.terminate()
    g.freeInstance()


def test_a_terminated_instance_is_not_initialised_again_without_reset(fmu, capfd):
    """After fmi2Terminate FMI 2.0 allows only the getters, fmi2Reset and fmi2FreeInstance: a host that
    reuses the instance without fmi2Reset (fmpy's simulate_fmu(fmu_instance=...) without reset()) gets
    fmi2Error and a message naming fmi2Reset, and no run starts from the last run's outputs."""
    vr = fmu[3]
    f = _instance(fmu)
    f.setReal([vr["u"]], [8.0])
    for k in range(30):
        f.doStep(k * 0.1, 0.1)
    l_end = f.getReal([vr["l"]])[0]
    assert l_end > 50.0
    f.terminate()
    capfd.readouterr()
    for call in (lambda: f.setupExperiment(startTime=0.0), f.enterInitializationMode, f.exitInitializationMode,
                 lambda: f.setReal([vr["u"]], [5.0])):
        with pytest.raises(FMICallException, match="error"):
            call()
    out = capfd.readouterr().out
    assert out.count("after fmi2Terminate: call fmi2Reset first") == 4, out
    assert f.getReal([vr["l"], vr["u"]]) == [l_end, 8.0]  # nothing was done
    f.reset()  # and then all of it is fine, from the start values
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    assert f.exitInitializationMode() == 0
    assert f.getReal([vr["l"]]) == [0.0]
    f.terminate()
    f.freeInstance()


def test_an_output_cannot_be_written_after_initialisation(fmu, capfd):
    """FMI 2.0 step mode: only inputs (and tunable parameters) are settable; a host that mixes up two value
    references gets fmi2Error naming the output, and the output keeps the plant's value."""
    vr = fmu[3]
    f = _instance(fmu)
    f.doStep(0.0, 0.1)
    before = f.getReal([vr["l"]])
    for _ in range(2):  # also once the input lists are compiled (the fast path)
        with pytest.raises(FMICallException, match="error"):
            f.setReal([vr["u"], vr["l"]], [5.0, 123.0])
        assert "fmi2SetReal: l is an output" in capfd.readouterr().out
        f.setReal([vr["u"]], [5.0])
    assert f.getReal([vr["l"], vr["u"]]) == [before[0], 5.0]  # nothing of the refused call was written
    f.terminate()
    f.freeInstance()


@pytest.mark.parametrize("name, value, message", [
    ("valve.cv_max", math.nan, "parameter valve.cv_max = nan is not finite"),
    ("valve.cv_max", 0.0, "valve.cv_max must be > 0.0, got 0.0"),  # the dataclass's check, in the FMU's name
    ("input_map.knot2_in_v", 1.0, "input_map.knot2_in_v (1.0) must exceed"),
])
def test_a_rejected_plant_parameter_is_named_as_the_fmu_names_it(fmu, capfd, name, value, message):
    reals = {name: value, "input_map.knot1_in_v": 2.0} if name.startswith("input_map") else {name: value}
    f = _instance(fmu, reals=reals, rejected=True)
    out = capfd.readouterr().out
    assert message in out and "Params." not in out, out
    f.terminate()
    f.freeInstance()


@pytest.mark.parametrize("parameter, value, inp, inp_value", [
    ("load.load_n", 68.0, "load_force", 44.0), ("supply.supply_pressure_mpa", 0.15, "supply_pressure", 0.25)])
def test_a_load_or_supply_parameter_sets_its_input_left_at_its_start(fmu, capfd, parameter, value, inp, inp_value):
    """The inputs ``load_force`` and ``supply_pressure`` set these in the FMU (they change during a run).
    A plant file's value copied into a host's parameter dialog, with the input left at its start value
    (unconnected): the parameter takes the input's place, as the rig the file describes (an FMU
    container must not make that a failure, nor Ecos run at the start value without a word). Against an input set
    to another value, the input wins and a warning names it."""
    vr = fmu[3]

    def l_after(reals, rejected=False):
        f = _instance(fmu, reals=reals, rejected=rejected)
        for k in range(30):
            f.setReal([vr["u"]], [5.0])
            f.doStep(0.1 * k, 0.1)
        l_mm = f.getReal([vr["l"]])[0]
        f.terminate()
        f.freeInstance()
        return l_mm

    copied = l_after({parameter: value})  # status OK: said, not warned
    out = capfd.readouterr().out
    assert f"parameter {parameter} = {value!r} sets the input {inp}, left at its start value {inp_value!r}" in out
    assert copied == l_after({inp: value}) != l_after({})  # the file's rig, not the start value's
    other = 0.5 * (value + inp_value)  # the input set to a third value: it wins, and the parameter is said unused
    assert l_after({parameter: value, inp: other}, rejected=True) == l_after({inp: other})
    assert f"parameter {parameter} = {value!r} is not used: the input {inp} (= {other!r})" in capfd.readouterr().out
    l_after({parameter: value, inp: value})  # both agree: nothing said
    assert "is not used" not in capfd.readouterr().out
    assert vr[inp] != vr[parameter]


def test_an_initialised_instance_is_not_initialised_again_without_reset(fmu, capfd):
    """FMI 2.0 allows fmi2SetupExperiment and the initialisation calls only before step mode: a host
    that initialises a stepping instance again (fmpy's simulate_fmu(fmu_instance=..., terminate=False)
    twice) gets fmi2Error naming fmi2Reset, and the instance steps on where it was."""
    vr = fmu[3]
    f, g = _instance(fmu, "f"), _instance(fmu, "g")
    first = _run(f, vr, 0)
    assert _run(g, vr, 0) == first
    capfd.readouterr()
    for call in (lambda: f.setupExperiment(startTime=0.0), f.enterInitializationMode, f.exitInitializationMode):
        with pytest.raises(FMICallException, match="error"):
            call()
    out = capfd.readouterr().out
    assert out.count("after fmi2ExitInitializationMode: the instance is initialised (step mode); to run again "
                     "from the start call fmi2Reset first") == 3, out
    assert _run(f, vr, 30) == _run(g, vr, 30)  # nothing was done
    for h in (f, g):
        h.terminate()
        h.freeInstance()


def test_a_state_from_step_mode_restores_into_an_instance_not_yet_initialised(fmu):
    """fmpy's simulate_fmu(fmu_state=...) restores a state into a fresh instance instead of
    initialising it (FMI 2.0 allows fmi2SetFMUstate there): the plant is built from the state's
    parameters and steps on bit for bit; so after fmi2Reset, in a terminated instance, and where the
    host then makes the initialisation calls, which keep the restored run."""
    vr = fmu[3]
    a = _instance(fmu, "a", reals={"friction.base_n": 20.0})
    _run(a, vr, 0)
    state = a.serializeFMUstate(a.getFMUstate())
    expected = _run(a, vr, 30)
    fresh = open_fresh(fmu, "fresh")
    fresh.setFMUstate(fresh.deSerializeFMUstate(state))
    assert fresh.getReal([vr["friction.base_n"]]) == [20.0]
    assert _run(fresh, vr, 30) == expected
    fresh.reset()  # instantiated again
    fresh.setFMUstate(fresh.deSerializeFMUstate(state))
    assert _run(fresh, vr, 30) == expected
    fresh.terminate()  # and from terminated: the state's mode is step mode
    fresh.setFMUstate(fresh.deSerializeFMUstate(state))
    assert _run(fresh, vr, 30) == expected
    by_the_book = open_fresh(fmu, "book")  # restored, then taken through FMI 2.0's initialisation calls
    by_the_book.setFMUstate(by_the_book.deSerializeFMUstate(state))
    by_the_book.setupExperiment(startTime=3.0)
    by_the_book.enterInitializationMode()
    by_the_book.setFMUstate(by_the_book.deSerializeFMUstate(state))  # again, in initialization mode
    assert by_the_book.exitInitializationMode() == 0
    assert _run(by_the_book, vr, 30) == expected
    with pytest.raises(FMICallException, match="error"):  # once stepping, as any stepping instance
        by_the_book.enterInitializationMode()
    by_the_book.terminate()
    by_the_book.freeInstance()
    for f in (a, fresh):
        f.terminate()
        f.freeInstance()


def test_a_state_from_before_initialisation_is_refused_in_step_mode(fmu, capfd):
    """A state saved in initialization mode holds parameters and no plant: restored into a stepping
    instance it is refused with fmi2Error (the host would step a plant that is not there, or go on from
    where it was with the outputs and time of the start); restored into an instance before
    initialisation it sets the parameters, and that instance runs as any."""
    vr = fmu[3]
    f = open_fresh(fmu, "f")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setReal([vr["friction.base_n"]], [20.0])
    early = f.getFMUstate()
    f.exitInitializationMode()
    expected = _run(f, vr, 0)
    capfd.readouterr()
    with pytest.raises(FMICallException, match="error"):
        f.setFMUstate(early)
    assert "this FMU state was saved before fmi2ExitInitializationMode" in capfd.readouterr().out
    g = _instance(fmu, "g", reals={"friction.base_n": 20.0})
    _run(g, vr, 0)
    assert _run(f, vr, 30) == _run(g, vr, 30)  # nothing was changed
    h = open_fresh(fmu, "h")
    h.setFMUstate(h.deSerializeFMUstate(f.serializeFMUstate(early)))
    h.setupExperiment(startTime=0.0)
    h.enterInitializationMode()
    assert h.getReal([vr["friction.base_n"]]) == [20.0]
    assert h.exitInitializationMode() == 0
    assert _run(h, vr, 0) == expected
    # the state restores its mode: a host may leave initialisation next, without entering it again
    i = open_fresh(fmu, "i")
    i.setFMUstate(i.deSerializeFMUstate(f.serializeFMUstate(early)))
    assert i.exitInitializationMode() == 0
    assert _run(i, vr, 0) == expected
    f.freeFMUstate(early)
    for x in (f, g, h, i):
        x.terminate()
        x.freeInstance()


@pytest.mark.parametrize("name, value", [("load_force", -5.0), ("supply_pressure", 1.5)])
def test_a_bad_load_or_supply_input_at_initialisation_is_refused_at_the_steps(fmu, capfd, name, value):
    """An input out of range at fmi2ExitInitializationMode is an input's error, not a parameter's: a
    warning there, fmi2Discard from the steps until it is mended, and then the run of a mended input
    from the start, bit for bit (the rig at rest on its stop is the same under any load)."""
    vr = fmu[3]
    good = {"load_force": 68.0, "supply_pressure": 0.3}
    f = _instance(fmu, "f", reals=good | {name: value}, rejected=True)
    out = capfd.readouterr().out
    assert (f"input {name} = {value!r} is outside" in out and "every fmi2DoStep returns fmi2Discard until the "
            "input is in range" in out), out
    with pytest.raises(FMICallException, match="discard"):
        f.doStep(0.0, 0.1)
    f.setReal([vr[name]], [good[name]])
    g = _instance(fmu, "g", reals=good)
    assert _run(f, vr, 0) == _run(g, vr, 0)
    for x in (f, g):
        x.terminate()
        x.freeInstance()


def test_the_parameters_an_input_sets_say_so_in_the_model_description(fmu):
    """A tool's parameter dialog shows load.load_n beside the others: its description names the input that
    sets it in the FMU and when the parameter takes the input's place; no other parameter's says so."""
    _, md, _, _ = fmu
    shared = {v.name: v.description for v in md.modelVariables if "in the FMU its input" in (v.description or "")}
    assert shared.keys() == {"load.load_n", "supply.supply_pressure_mpa"}
    assert shared["load.load_n"].endswith("; in the FMU its input load_force sets it: this value is used in its "
                                          "place while load_force is left at its start value (a plant file's)")
    assert "its input supply_pressure sets it" in shared["supply.supply_pressure_mpa"]


def test_an_open_lower_bound_is_said_in_the_description(fmu):
    """FMI's min cannot be open: a parameter that must be above its declared min (the bladder's radius,
    the valve's Cv) says so in its description, which a tool's dialog shows beside the range, and the
    set of such parameters is exactly those whose check refuses the limit itself."""
    from dataclasses import fields

    from fmu_plant import PlantParams

    _, md, _, _ = fmu
    said = {v.name for v in md.modelVariables if "(the declared min itself is refused)" in (v.description or "")}
    defaults = PlantParams()
    open_lo = {f"{g.name}.{f.name}" for g in fields(defaults) for f in fields(getattr(defaults, g.name))
               if f.metadata.get("lo_open")}
    assert said == open_lo and {"muscle.radius_mm", "valve.cv_max"} <= said
    radius = next(v for v in md.modelVariables if v.name == "muscle.radius_mm")
    assert float(radius.min) == 0.0 and radius.description.endswith("; must be > 0 (the declared min itself is refused)")
    with pytest.raises(ValueError, match="radius_mm must be > 0"):
        PlantParams().with_values(**{"muscle.radius_mm": 0.0})


@pytest.mark.parametrize("name, bound, outward", [("load_force", 500.0, 1.0), ("u", 11.0, 1.0), ("u", -1.0, -1.0),
                                                   ("supply_pressure", 0.0, -1.0)])
def test_an_input_a_rounding_beyond_its_bound_is_the_bound(fmu, capfd, name, bound, outward):
    """A host interpolating a signal held at a bound computes it an ulp or so beyond (fmpy gives
    500.00000000000006 for 500 N, which must not end the run at an fmi2Discard): the step is taken at the bound,
    the same to the bit; a value a millionth beyond is still refused."""
    vr = fmu[3]
    runs = {}
    for value in (bound, math.nextafter(bound, outward * math.inf), bound + outward * 1e-10 * max(1.0, abs(bound))):
        f = _instance(fmu)
        f.setReal([vr[name]], [value])
        f.doStep(0.0, 0.5)
        runs[value] = tuple(f.getReal([vr["l"], vr["p"]]))
        f.terminate()
        f.freeInstance()
    assert len(runs) == 3 and len(set(runs.values())) == 1, runs
    f = _instance(fmu)
    f.setReal([vr[name]], [bound + outward * 1e-6])
    with pytest.raises(FMICallException, match="discard"):
        f.doStep(0.0, 0.5)
    assert f"{name} = " in capfd.readouterr().out
    f.terminate()
    f.freeInstance()


def test_a_stiff_rig_says_once_that_its_trajectory_may_be_far_off(fmu, capfd):
    """friction.presliding_mm = 1e-7 (in range) is stiffer than solver.min_substep_s resolves: the steps
    return fmi2OK with a trajectory 0.33 mm off (3e-8 mm: frozen at 0 mm; 1e-9 mm: readings of kilometres
    before the breakdown's fmi2Error), so the FMU warns once, at the first such sub-step; the summary
    counts saturated commands against the valve's own range."""
    vr = fmu[3]
    said = {}
    for name, reals in (("nominal", {"valve.u_max_v": 5.0}), ("stiff", {"friction.presliding_mm": 1e-7})):
        f = _instance(fmu, reals=reals)
        for k in range(100):
            f.setReal([vr["u"]], [8.0 if k < 50 else 0.0])
            f.doStep(0.1 * k, 0.1)
        f.terminate()
        f.freeInstance()
        said[name] = capfd.readouterr().out
    assert "over their error tolerances" not in said["nominal"]
    assert said["stiff"].count("over their error tolerances") == 1, said["stiff"]
    assert re.search(r"t = \d+(\.\d+)? s: the plant's integration accepted \d+ sub-steps? of solver\.min_substep_s = "
                     r"1e-05 s over their error tolerances", said["stiff"]), said["stiff"]
    assert "command outside the amplifier's 0..5 V (saturated there) in 50 steps" in said["nominal"], said["nominal"]
    assert "braid lock" not in said["nominal"] + said["stiff"]  # at 44 N


def test_a_load_below_the_braid_lock_is_said_once(fmu, capfd):
    """Below muscle.braid_lock_force_n (40 N) the model's unpowered muscle contracts by itself (2.1 mm at
    20 N from rest at 0 V): said once, at the first step with such a load, and not while the load is
    above it."""
    vr = fmu[3]
    f = _instance(fmu)
    for k in range(60):
        f.setReal([vr["u"], vr["load_force"]], [0.0, 44.0 if k < 20 else 20.0])
        f.doStep(0.1 * k, 0.1)
    l_end = f.getReal([vr["l"]])[0]
    f.terminate()
    f.freeInstance()
    out = capfd.readouterr().out
    assert out.count("braid lock") == 1 and "t = 2 s: load_force = 20 N is below the braid lock's 40 N" in out, out
    assert 1.0 < l_end < 3.0  # contracting towards 2.1 mm at 0 V
