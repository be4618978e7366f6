"""The FMUs' events (category ``logEvents``, status OK; fmi_slave.base.SafeSlave.event): the run's set-up,
the controller's changes of mode and a summary at fmi2Terminate that agrees with the outputs, also
across an FMU state restored into another instance. (Which of them reach a host is the loader's
filter: tests/test_fmi_shim.py.)"""

import math
import re

from pythonfmu.enums import Fmi2Status

from fmu_controller.controller_slave import AMPCController
from fmu_plant.plant_slave import MusclePlant

TS = 0.1


def _events(slave) -> list[str]:
    got = [m.msg for m in slave.log_queue if m.category == "logEvents"]
    assert all(m.status == Fmi2Status.ok for m in slave.log_queue if m.category == "logEvents")
    # no percent sign in any message: fmpy prints the text as it arrives, where a C host formats it
    assert not [m.msg for m in slave.log_queue if "%" in m.msg]
    slave.log_queue.clear()
    return got


def _start(slave, **params):
    slave.setup_experiment(0.0, None, None)
    slave.enter_initialization_mode()
    for name, value in params.items():
        vr = next(vr for vr, var in slave.vars.items() if var.name == name)
        (slave.set_integer if isinstance(value, int) else slave.set_real)([vr], [value])
    slave.exit_initialization_mode()
    return slave


def _loop(ctrl, plant, k0: int, k1: int, rows: list) -> None:
    """Sequential master (controller, then plant) from sample k0 to k1."""
    for k in range(k0, k1):
        ctrl.l = plant.l
        assert ctrl.do_step(k * TS, TS)
        plant.u = ctrl.u
        assert plant.do_step(k * TS, TS)
        rows.append((plant.l, plant.p, ctrl.pred_error, ctrl.saturated))


def test_a_closed_loop_logs_its_set_up_its_changes_of_mode_and_a_summary_that_agrees_with_its_outputs():
    ctrl = _start(AMPCController(instance_name="c"), **{"servo.R": 20.0})
    plant = _start(MusclePlant(instance_name="p"), **{"delay.delay_s": 0.0, "friction.rate_gain": 1.1})
    (c_setup,), (p_setup,) = _events(ctrl), _events(plant)
    assert c_setup.startswith("initialised at t = 0 s: method 4 ampc_servo, Ts = 0.1 s, servo.Hp = 5, servo.Hu = 5; "
                              "input delay decided from the data (input_delay_samples = -1); start-up mode 12 s;")
    assert c_setup.endswith("parameters away from their start values: servo.R = 20.0")
    # delay.delay_s = 0 is its start value: not listed, and no transport delay is switched on
    assert "left-out effects switched on: none" in p_setup
    assert p_setup.endswith("parameters away from their start values: friction.rate_gain = 1.1")
    rows: list = []
    changes = []
    for k in range(300):
        _loop(ctrl, plant, k, k + 1, rows)
        changes += [(round(k * TS, 6), e) for e in _events(ctrl)]
        assert not _events(plant)  # the plant has no change of mode
    said = [e.split(": ", 1)[1] for _, e in changes]
    assert said[0].startswith("input_delay_samples = -1 decided for 0 samples: the undelayed law from now (a "
                              "sequential master); the adaptive estimate starts again from theta0"), said
    assert said[1].startswith("the start-up mode's law on theta0 is over") and said[2].startswith("the start-up is over")
    # from the decision, which restarts the estimator: the law on theta0 for startup_s / 2, the blend to startup_s
    t_decided, t_warm, t_blend = (t for t, _ in changes)
    assert abs(t_warm - t_decided - 6.0) < 1e-9 and abs(t_blend - t_decided - 12.0) < 1e-9 and t_decided < 6.0
    ctrl.terminate()
    plant.terminate()
    (c_end,), (p_end,) = _events(ctrl), _events(plant)
    l, p, e, sat = (list(c) for c in zip(*rows))
    rms = math.sqrt(sum(x * x for x in e[1:]) / (len(e) - 1))
    assert c_end.startswith(f"fmi2Terminate at t = 30 s: 30 s from t = 0 s: 300 samples; an input limit (0-10 V or "
                            f"Eq. 19) active in {sum(sat)} of them; one-step prediction error "
                            f"l(k) - l(k|k-1): RMS {rms:.3g} mm, largest {max(map(abs, e)):.3g} mm; the law for an "
                            "input delay of 0 samples; Algorithm 1 since the estimator's start: the estimate projected "
                            "onto the box C in "), c_end
    assert p_end == (f"fmi2Terminate at t = 30 s: 30 s from t = 0 s: 300 steps; readings l {min(l):.4g}..{max(l):.4g} "
                     f"mm, p {min(p):.4g}..{max(p):.4g} MPa; command outside the amplifier's 0..10 V (saturated "
                     "there) in 0 steps")


def _restored(states) -> tuple:
    """A fresh controller and plant with ``states`` (theirs, from ``_get_fmu_state``) set."""
    ctrl, plant = AMPCController(instance_name="c2"), MusclePlant(instance_name="p2")
    ctrl._set_fmu_state(states[0])
    plant._set_fmu_state(states[1])
    return ctrl, plant


def _ends(ctrl, plant) -> tuple[list[str], list[str]]:
    """The events of fmi2Terminate of both (earlier ones dropped)."""
    _events(ctrl), _events(plant)
    ctrl.terminate()
    plant.terminate()
    return _events(ctrl), _events(plant)


def test_a_state_restored_into_another_instance_carries_what_the_summary_counts():
    """Rewind: the summary of a run continued from a state in a fresh instance is the straight run's."""
    ends = []
    for restore in (False, True):
        ctrl, plant = _start(AMPCController(instance_name="c")), _start(MusclePlant(instance_name="p"))
        _loop(ctrl, plant, 0, 80, [])
        if restore:
            ctrl, plant = _restored((ctrl._get_fmu_state(), plant._get_fmu_state()))
        _loop(ctrl, plant, 80, 150, [])
        ends.append(_ends(ctrl, plant))
    assert ends[0] == ends[1]
    assert re.search(r": 150 samples; .*: 150 steps;", " ".join(ends[1][0] + ends[1][1]))


def test_an_instance_that_failed_to_initialise_logs_no_set_up_and_no_summary():
    ctrl = _start(AMPCController(instance_name="c"), **{"servo.R": -1.0})
    assert any(m.status == Fmi2Status.warning and "servo.R" in m.msg for m in ctrl.log_queue)
    assert not _events(ctrl)
    ctrl.terminate()
    assert not _events(ctrl)


def test_a_refused_input_is_what_the_set_up_says_not_the_default():
    plant = MusclePlant(instance_name="p")
    plant.setup_experiment(0.0, None, None)
    plant.enter_initialization_mode()
    plant.load_force = 600.0
    plant.exit_initialization_mode()
    (setup,) = _events(plant)
    assert setup.startswith("initialised at t = 0 s: input load_force = 600") and "(refused: fmi2Discard" in setup, setup
    assert "44 N" not in setup


def test_a_state_of_a_build_without_the_tally_counts_from_the_restore_and_says_so():
    ctrl, plant = _start(AMPCController(instance_name="c")), _start(MusclePlant(instance_name="p"))
    _loop(ctrl, plant, 0, 30, [])
    states = ctrl._get_fmu_state(), plant._get_fmu_state()
    del states[0]["numerics"]["tally"], states[1]["numerics"]["fmu_tally"]  # as an earlier build saved them
    ctrl, plant = _restored(states)
    _loop(ctrl, plant, 30, 40, [])
    (c_end,), (p_end,) = _ends(ctrl, plant)
    assert ": 10 samples since a restored state; " in c_end and ": 10 steps since a restored state; " in p_end


def test_a_run_without_a_start_up_mode_and_with_its_delay_set_reports_no_change_of_mode():
    ctrl = _start(AMPCController(instance_name="c"), startup_s=0.0, input_delay_samples=0)
    plant = _start(MusclePlant(instance_name="p"))
    _events(ctrl)
    _loop(ctrl, plant, 0, 50, [])
    assert _events(ctrl) == []
