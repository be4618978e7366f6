"""fmi_slave.base.SafeSlave's Real I/O: the same values and errors as pythonfmu's own get_real/set_real."""

import random

import pytest
from pythonfmu.enums import Fmi2Status
from pythonfmu import Fmi2Slave, Real

from fmu_controller.controller_slave import AMPCController
from fmu_plant.plant_slave import MusclePlant


def _reals(slave):
    return [vr for vr, var in slave.vars.items() if isinstance(var, Real)]


@pytest.mark.parametrize("cls", [AMPCController, MusclePlant])
def test_get_and_set_real_agree_with_pythonfmu_on_random_lists(cls):
    """Random value-reference lists (repeats included), each read twice (the second read goes through
    the compiled reader of attribute-backed lists) around random writes: the values always equal
    pythonfmu's generic Fmi2Slave.get_real, so a reader never returns stale values."""
    slave = cls(instance_name="io")
    reals, rng = _reals(slave), random.Random(3)
    # a host may set these (the outputs computed at initialisation it may not: refused, below)
    attribute_backed = [vr for vr in reals if slave.vars[vr].name in slave._attribute_reals
                        and vr not in slave._calculated]
    assert len(attribute_backed) >= 3  # inputs and outputs; the plant has 3, the controller 7
    for _ in range(200):
        vrs = rng.choices(attribute_backed if rng.random() < 0.7 else reals, k=rng.randint(1, 6))
        for _ in range(2):
            assert slave.get_real(vrs) == Fmi2Slave.get_real(slave, vrs)
        # an input or output written through set_real is read back exactly
        vr = rng.choice(attribute_backed)
        meta = slave.variable_meta.get(slave.vars[vr].name, {})  # an output's start value must be in range
        lo = -5.0 if meta.get("min") is None else max(-5.0, meta["min"])
        hi = 5.0 if meta.get("max") is None else min(5.0, meta["max"])
        value = rng.uniform(lo, hi - 1.0)
        for _ in range(2):
            slave.set_real([vr], [value])
            assert slave.get_real([vr]) == [value] == Fmi2Slave.get_real(slave, [vr])
            value += 1.0
    assert slave._readers and slave._writers  # the fast paths were taken


def test_a_wrong_value_reference_is_a_logged_error_also_after_fast_paths_exist():
    """Not an exception (pythonfmu would answer fmi2Fatal, and the instance is fine): an error-level
    message naming the reference (the loader returns fmi2Error), zeros read, nothing written."""
    slave = AMPCController(instance_name="io")
    vr = {var.name: v for v, var in slave.vars.items()}
    fast = [vr["u"], vr["theta.b1"]]
    assert slave.get_real(fast) == slave.get_real(fast)
    slave.set_real([vr["l"]], [3.0])
    slave.set_real([vr["l"]], [4.0])
    for bad in ([vr["u"], vr["samples"]], [vr["samples"]], [vr["u"], 10_000]):
        slave.log_queue.clear()
        assert slave.get_real(bad) == [0.0] * len(bad)
        slave.set_real([vr["l"], *bad], [9.0] * (len(bad) + 1))
        msgs = [(m.status, m.msg) for m in slave.log_queue]
        assert [s for s, _ in msgs] == [Fmi2Status.error] * 2
        assert all(f"value reference {bad[-1] if bad[-1] == 10_000 else vr['samples']} is not a variable of type Real"
                   in m for _, m in msgs), msgs
    assert slave.get_real([vr["l"]]) == [4.0]  # the bad write wrote nothing, not even the good l
    slave.log_queue.clear()
    assert slave.get_integer([vr["u"]]) == [0] and slave.get_boolean([vr["l"]]) == [False]
    assert slave.get_integer([vr["samples"]]) == [0] and len(slave.log_queue) == 2


def test_theta_outputs_follow_the_estimate_and_its_saved_state():
    """theta.* are attributes named like the variables (pythonfmu's default accessor would read ``b1``);
    with the paper's start the law uses the estimate from the first sample."""
    slave = AMPCController(instance_name="theta")
    vr = {var.name: v for v, var in slave.vars.items()}
    slave.set_real([vr["startup_s"]], [0.0])
    # undelayed: the command of the first sample reaches the first regressor (the delayed law's
    # first regressor holds 0 V, so from l = 0 the second sample would move nothing)
    slave.set_integer([vr["input_delay_samples"]], [0])
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    slave.l = 0.0
    assert slave.do_step(0.0, 0.1)
    state = slave._get_fmu_state()
    before = slave.get_real([vr["theta.b1"], vr["theta.a1"]])
    slave.l = 12.0
    assert slave.do_step(0.1, 0.1)
    after = slave.get_real([vr["theta.b1"], vr["theta.a1"]])
    assert after != before  # AMPC-servo (the default) adapts
    assert after == [float(slave._controller.theta[2]), float(slave._controller.theta[0])]
    slave._set_fmu_state(state)
    assert slave.get_real([vr["theta.b1"], vr["theta.a1"]]) == before


def test_the_compiled_lists_are_bounded_and_later_lists_still_read_right():
    slave = AMPCController(instance_name="many")
    reals = [vr for vr in _reals(slave) if slave.vars[vr].name in slave._attribute_reals]
    lists = [[a, b] for a in reals for b in reals][:3 * slave._MAX_COMPILED]
    for vrs in lists * 2:
        assert slave.get_real(vrs) == Fmi2Slave.get_real(slave, vrs)
        slave.set_real(vrs, [1.5, 2.5])
    assert len(slave._readers) == slave._MAX_COMPILED
    # lists with an output are written through the checked path (an output is settable only before
    # initialisation), so only the input-only lists are compiled
    assert set(slave._writers) == {tuple(v) for v in lists if not set(v) & slave._outputs}


def test_outputs_computed_at_initialisation_cannot_be_set_and_take_their_parameters():
    """theta.* (from theta0.*), samples, input_delay and the plant's readings are initial = calculated:
    a host setting one before initialisation gets an error naming it and nothing is written; after
    initialisation each holds what its parameters give (a declared start value would be wrong)."""
    ctrl = AMPCController(instance_name="c")
    vr = {var.name: v for v, var in ctrl.vars.items()}
    assert {ctrl.vars[v].name for v in ctrl._calculated} == {"samples", "input_delay", *ctrl._theta_outputs}
    ctrl.setup_experiment(0.0, None, None)
    ctrl.enter_initialization_mode()
    ctrl.set_real([vr["theta0.a1"]], [1.23])
    ctrl.set_real([vr["u"], vr["theta.a1"]], [4.0, 9.0])
    ctrl.set_integer([vr["samples"]], [7])
    said = [m.msg for m in ctrl.log_queue if m.status == Fmi2Status.error]
    assert len(said) == 2 and "output theta.a1 is computed at initialisation" in said[0] and "output samples" in said[1]
    # the refused call wrote nothing; in Initialization Mode theta.* already reads what theta0.* gives
    assert ctrl.get_real([vr["u"], vr["theta.a1"]]) == [0.0, 1.23]
    ctrl.set_real([vr["u"]], [4.0])  # an exact start value: taken
    ctrl.exit_initialization_mode()
    assert ctrl.get_real([vr["u"], vr["theta.a1"]]) == [4.0, 1.23] and ctrl.get_integer([vr["samples"]]) == [0]
    plant = MusclePlant(instance_name="p")
    vr = {var.name: v for v, var in plant.vars.items()}
    assert {plant.vars[v].name for v in plant._calculated} == {"l", "p"}
    plant.setup_experiment(0.0, None, None)
    plant.enter_initialization_mode()
    plant.set_real([vr["sensor_drift.offset_mm"]], [5.0])
    in_init = plant.get_real([vr["l"], vr["p"]])
    assert abs(in_init[0] - 5.0) < 0.05  # the offset, within the encoder's noise
    plant.exit_initialization_mode()
    assert plant.get_real([vr["l"], vr["p"]]) == in_init  # what the run starts from, bit for bit


@pytest.mark.parametrize("h", [0.1, 0.02, 0.05, 0.001, 0.25, 1.0])
@pytest.mark.parametrize("start", [0.0, 3.7])
def test_a_step_computed_as_a_difference_of_times_is_integrated_as_the_step_meant(h, start):
    """fmpy's simulate_fmu steps ``(start + (n+1) h) - (start + n h)``: over an hour of such steps every
    one is integrated as ``h`` itself."""
    from fmi_slave.base import intended_step

    n = int(3600 / h) if h >= 0.02 else 20000
    times = [start + k * h for k in range(n + 1)]
    steps = [b - a for a, b in zip(times, times[1:])]
    assert any(s != h for s in steps) or h in (0.25, 1.0)  # binary fractions subtract exactly
    assert all(intended_step(a, s) == h for a, s in zip(times, steps))


@pytest.mark.parametrize("t, h", [(0.0, 0.1 / 3), (5.0, 0.1 / 3), (1.0, 1e-9 + 2e-13), (7.2, 3e-12),
                                  (0.0, 0.1 + 1e-15), (1e7, 0.1 + 2e-9)])
def test_a_step_off_a_whole_nanosecond_by_more_than_rounding_is_integrated_as_given(t, h):
    from fmi_slave.base import intended_step

    assert intended_step(t, h) == h


def test_an_fmu_whose_own_packages_this_process_loaded_from_elsewhere_is_refused(tmp_path):
    """An FMU built before its code was kept in a private package ships fmu_plant (and fmi_slave, ...)
    at the top of its resources and imports them by those names: in a process that imported this
    tapmuscle first it would run this version's code against its own modelDescription's value
    references. Its instantiation is refused naming both folders; a slave made without resources, or
    with resources that ship no such package (a build of this version), is not."""
    from fmi_slave.base import check_own_code

    resources = tmp_path / "resources"
    (resources / "fmu_plant").mkdir(parents=True)
    (resources / "fmu_plant" / "__init__.py").write_text("")
    with pytest.raises(ValueError, match=r"this FMU's own fmu_plant \(.*resources/fmu_plant\) is not the one this "
                                         r"process runs \(.*fmu_plant, imported before the FMU\): an FMU built by an "
                                         r"earlier tapmuscle .* build it again"):
        MusclePlant(instance_name="old", resources=str(resources))
    check_own_code(None)
    check_own_code(str(tmp_path))  # no plain package there
    MusclePlant(instance_name="direct")
