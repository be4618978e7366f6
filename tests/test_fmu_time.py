"""Time in both FMUs: the start time of fmi2SetupExperiment is the FMU's time, a step must start at it.

The plant's clock starts at the start time, so its time-based effects (a supply sag's ``start_s``, a
transport delay) count in the host's time; the controller samples at ``tStart + k Ts`` and counts
everything else in samples from there. A run started at ``tStart`` is then the run started at 0,
``tStart`` later:

* bit for bit where no effect reads the time (the plant integrates over the step sizes only, the
  controller counts samples), for a host that passes the same step sizes (``t = tStart + k h``,
  ``h`` fixed, as here);
* to rounding where an effect does: the plant's clock ``tStart + h + h + ...`` and the effect's
  arithmetic on it (``t - start_s``, the sub-step that ends on a sag's corner, ``t_change + delay``)
  round differently at another magnitude (one ulp of 6 s is four of 1 s), so the state differs in
  its last bits and a reading may land on the neighbouring quantum of its sensor. Nothing is
  amplified: the comparison below allows one quantum per reading.

A step that does not start at the FMU's time (a gap, or back) is fmi2Error naming both times; the
instance answers later calls and continues at its time; FMU states carry the time.
"""

import math

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmpy_helpers import open_fmu
from pythonfmu.enums import Fmi2Status

from fmu_controller.controller_slave import AMPCController
from fmu_plant.parameters import PlantParams
from fmu_plant.plant_slave import MusclePlant

H = 0.1
_SENSOR = PlantParams().sensor
QUANTUM = (_SENSOR.encoder_resolution_mm, _SENSOR.pressure_resolution_mpa)  # one step of each reading


@pytest.fixture(scope="module")
def fmus(built_fmus):
    return {name: open_fmu(path) for name, path in built_fmus.items()}


def _start(fmu, t0, name="t", reals=None, ints=None):
    """An initialised FMU2Slave whose experiment starts at ``t0``."""
    path, md, folder, vr = fmu
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    f.instantiate(loggingOn=True)
    f.setupExperiment(startTime=t0)
    f.enterInitializationMode()
    for key, value in (reals or {}).items():
        f.setReal([vr[key]], [value])
    for key, value in (ints or {}).items():
        f.setInteger([vr[key]], [value])
    assert f.exitInitializationMode() == 0
    return f


def _free(*fs):
    for f in fs:
        f.terminate()
        f.freeInstance()


def _u(k):
    return 5.0 + 4.0 * math.sin(0.3 * k)


def _plant_run(fmu, t0, reals, n=120, u=_u):
    """Readings ``(l, p)`` at ``t0 + k H``, k = 0..n, under the command ``u(k)``."""
    vr = fmu[3]
    f = _start(fmu, t0, reals=reals)
    out = [f.getReal([vr["l"], vr["p"]])]
    for k in range(n):
        f.setReal([vr["u"]], [u(k)])
        f.doStep(t0 + k * H, H)
        out.append(f.getReal([vr["l"], vr["p"]]))
    _free(f)
    return np.array(out)


def _sag(start_s):
    return {"supply_variation.sag_mpa": 0.15, "supply_variation.start_s": start_s,
            "supply_variation.end_s": start_s + 2.0, "supply_variation.ramp_s": 0.1}


@pytest.mark.parametrize("t0", [5.0, -3.0, 1234.5])
def test_without_a_time_based_effect_a_later_start_is_the_same_run_bit_for_bit(fmus, t0):
    plant = fmus["MusclePlant"]
    assert np.array_equal(_plant_run(plant, t0, {}), _plant_run(plant, 0.0, {}))


def test_a_supply_sag_happens_at_its_host_time_whatever_the_start_time(fmus):
    """start_s = 6, end_s = 8: with start time 5 the supply sags at host times 6..8 s (not at
    11..13 s, as it would on a plant clock that started at 0), and the run is the start-time-0 run with the sag at
    1..3 s, 5 s later, to one sensor quantum (module docstring)."""
    plant = fmus["MusclePlant"]
    quiet = {"sensor.pressure_noise_std_mpa": 0.0}
    t = 5.0 + H * np.arange(121)
    late = _plant_run(plant, 5.0, {**quiet, **_sag(6.0)}, u=lambda k: 6.0)
    none = _plant_run(plant, 5.0, quiet, u=lambda k: 6.0)
    sagging = t[np.abs(late[:, 1] - none[:, 1]) > 0.05]  # the pressure drops by up to 0.15 MPa
    assert sagging.min() >= 6.0 and sagging.max() <= 8.0 + 0.5, sagging  # +0.5: the recovery
    assert sagging.min() <= 6.5 and sagging.max() >= 7.9, sagging
    # the shift, under a moving command (here two pressure readings land on the neighbouring quantum)
    late, early = _plant_run(plant, 5.0, _sag(6.0)), _plant_run(plant, 0.0, _sag(1.0))
    diff = np.abs(late - early)
    assert (diff <= np.array(QUANTUM) * (1 + 1e-9)).all(), diff.max(axis=0)
    assert (diff == 0).mean() > 0.95  # most readings identical; a few on the neighbouring quantum


@pytest.mark.parametrize("t0", [5.0, -3.0])
def test_a_transport_delay_starts_its_memory_at_the_start_time(fmus, t0):
    """The delay line starts at the start time with the initial command: a plant started at a negative
    time must not ignore every command change (as a line that takes them for older than its start would)."""
    plant = fmus["MusclePlant"]
    delayed = {"delay.delay_s": 0.25, "sensor.pressure_noise_std_mpa": 0.0}
    late, early = _plant_run(plant, t0, delayed), _plant_run(plant, 0.0, delayed)
    assert np.abs(late - early).max(axis=0).tolist() <= list(QUANTUM)
    assert np.abs(early - _plant_run(plant, 0.0, {"sensor.pressure_noise_std_mpa": 0.0}))[:, 0].max() > 1.0


def _closed_loop(fmus, t0, n=300):
    """The sequential master algorithm of tapmuscle.cosim.master, in fmpy: controller, then plant, at
    ``t0 + k H``; rows ``(l, u, r_k)``."""
    plant, ctrl = fmus["MusclePlant"], fmus["AMPCController"]
    p, c = _start(plant, t0, "plant"), _start(ctrl, t0, "ctrl", ints={"input_delay_samples": 0})
    pv, cv = plant[3], ctrl[3]
    rows = []
    for k in range(n):
        t = t0 + k * H
        l = p.getReal([pv["l"]])[0]
        c.setReal([cv["l"]], [l])
        c.doStep(t, H)
        u, r = c.getReal([cv["u"], cv["r_k"]])
        p.setReal([pv["u"]], [u])
        p.doStep(t, H)
        rows.append((l, u, r))
    assert c.getInteger([cv["samples"]]) == [n]
    _free(p, c)
    return np.array(rows)


def test_the_closed_loop_started_at_5_s_tracks_as_started_at_0(fmus):
    """AMPC-servo with its start-up mode, 30 s: the controller must not refuse its first step at 5 s
    ("skips the sample time 0 s"); the loop is the start-time-0 loop, bit for bit."""
    late, early = _closed_loop(fmus, 5.0), _closed_loop(fmus, 0.0)
    assert np.array_equal(late, early)
    tail = late[200:]  # 20..30 s after the start
    assert np.abs(tail[:, 2] - tail[:, 0]).mean() < 0.5  # tracks the sine (about 0.09 mm here)


@pytest.mark.parametrize("name, step_input", [("MusclePlant", ("u", 6.0)), ("AMPCController", ("l", 20.0))])
def test_a_step_that_does_not_start_at_the_fmus_time_is_an_error_naming_both(fmus, capfd, name, step_input):
    fmu = fmus[name]
    vr = fmu[3]
    outputs = [vr["l"], vr["p"]] if name == "MusclePlant" else [vr["u"], vr["l_pred"]]
    f = _start(fmu, 5.0)
    f.setReal([vr[step_input[0]]], [step_input[1]])
    with pytest.raises(FMICallException, match="error"):
        f.doStep(0.0, H)  # the start time is 5 s
    out = capfd.readouterr().out
    assert "currentCommunicationPoint = 0 s, but the FMU's time is 5 s (the start time): 5 s back" in out, out
    f.doStep(5.0, H)
    f.doStep(5.0 + H, H)
    before = f.getReal(outputs)
    for t, what in [(5.5, "a gap of 0.3 s"), (5.1, "0.1 s back")]:  # the FMU is at 5.2 s
        with pytest.raises(FMICallException, match="error"):
            f.doStep(t, H)
        out = capfd.readouterr().out
        assert f"currentCommunicationPoint = {t} s, but the FMU's time is 5.2 s (the end of the last step)" in out, out
        assert what in out, out
        assert f.getReal(outputs) == before  # nothing was done
    f.doStep(5.0 + 2 * H, H)  # the instance continues at its time
    assert all(math.isfinite(v) for v in f.getReal(outputs))
    _free(f)


@pytest.mark.parametrize("t0", [1e9, 1.8e9])
@pytest.mark.parametrize("name, step_input", [("MusclePlant", ("u", 6.0)), ("AMPCController", ("l", 20.0))])
def test_at_a_unix_time_start_a_gap_is_still_a_gap(fmus, capfd, t0, name, step_input):
    """A HIL master starting at a Unix time: the tolerance for a master's rounding stays a fraction of
    the step (1e-9 of |t| alone was 1-2 s there, and a 0.5-s gap passed), while its own rounding of
    t0 + n h passes."""
    fmu = fmus[name]
    f = _start(fmu, t0)
    f.setReal([fmu[3][step_input[0]]], [step_input[1]])
    for n in range(3):
        f.doStep(t0 + n * H, H)  # t0 + n h rounds at 2.4e-7 s here
    capfd.readouterr()
    with pytest.raises(FMICallException, match="error"):
        f.doStep(t0 + 3 * H + 0.5, H)
    assert "a gap of 0.5 s" in capfd.readouterr().out
    f.doStep(t0 + 3 * H, H)
    _free(f)


def test_at_a_unix_time_start_half_steps_sample_every_other_step(fmus):
    """The controller stepped at Ts/2 from t0 = 1e9 s: one sample per two steps, on the grid t0 + k Ts
    (a tolerance of 1 s took every half step for a sample time and ran ahead of the host's clock)."""
    vr = fmus["AMPCController"][3]
    runs = {}
    for t0 in (0.0, 1e9):
        f = _start(fmus["AMPCController"], t0)
        f.setReal([vr["l"]], [20.0])
        seen = []
        for n in range(120):
            f.doStep(t0 + n * H / 2, H / 2)
            seen.append((f.getInteger([vr["samples"]])[0], *f.getReal([vr["r_k"], vr["u"]])))
        runs[t0] = seen
        _free(f)
    assert [s[0] for s in runs[1e9]] == [n // 2 + 1 for n in range(120)]
    assert runs[1e9] == runs[0.0]  # the same samples, the built-in sine at the same phase


@pytest.mark.parametrize("name, step_input", [("MusclePlant", ("u", 6.0)), ("AMPCController", ("l", 20.0))])
def test_after_restoring_a_state_the_fmus_time_is_the_restored_one(fmus, capfd, name, step_input):
    fmu = fmus[name]
    vr = fmu[3]
    f = _start(fmu, -2.0)  # a negative start time too: the plant's clock runs from -2 s
    f.setReal([vr[step_input[0]]], [step_input[1]])

    def run(k0, k1):
        out = []
        for k in range(k0, k1):
            f.setReal([vr[step_input[0]]], [step_input[1] + 0.1 * k])
            f.doStep(-2.0 + k * H, H)
            out.append(f.getReal([vr["l"] if name == "MusclePlant" else vr["u"]]))
        return out

    run(0, 5)
    state = f.getFMUstate()
    a = run(5, 15)
    for restored in (state, f.deSerializeFMUstate(f.serializeFMUstate(state))):
        f.setFMUstate(restored)
        with pytest.raises(FMICallException, match="error"):  # the time before the restore is gone
            f.doStep(-2.0 + 15 * H, H)
        assert "the FMU's time is -1.5 s" in capfd.readouterr().out
        assert run(5, 15) == a
    f.freeFMUstate(state)
    _free(f)


def test_the_start_time_must_be_finite_and_takes_effect_at_initialisation():
    """A non-finite one is logged as an error (the loader returns fmi2Error) and the start time stays;
    one set while running is refused likewise (FMI 2.0 allows it before initialisation only) and the run
    keeps its clock; the next run, after fmi2Reset (pythonfmu: a new slave object), takes its own."""
    for cls in (MusclePlant, AMPCController):
        slave = cls(instance_name="t0")
        slave.setup_experiment(math.nan, None, None)
        assert [m.status for m in slave.log_queue] == [Fmi2Status.error]
        assert "startTime = nan is not finite" in slave.log_queue[0].msg
        slave.setup_experiment(2.5, 10.0, None)
        slave.enter_initialization_mode()
        slave.exit_initialization_mode()
        slave.log_queue.clear()
        slave.setup_experiment(7.0, None, None)
        assert [m.status for m in slave.log_queue] == [Fmi2Status.error]
        assert "fmi2SetupExperiment after fmi2ExitInitializationMode" in slave.log_queue[0].msg
        slave.log_queue.clear()
        assert slave.do_step(2.5, H) and not slave.log_queue  # this run keeps its clock
        after_reset = cls(instance_name="t0")
        after_reset.setup_experiment(7.0, None, None)
        after_reset.enter_initialization_mode()
        after_reset.exit_initialization_mode()
        assert [m.category for m in after_reset.log_queue] == ["logEvents"]  # its set-up, status OK
        after_reset.log_queue.clear()
        assert after_reset.do_step(7.0, H) and not after_reset.log_queue


def test_messages_at_a_unix_time_start_name_the_time_to_the_sample(fmus, capfd):
    """From t0 = 1e9 s the FMUs' messages give the time to the sample (twelve significant digits), not
    to six, which wrote "t = 1e+09 s" in every message of a run."""
    vr = fmus["AMPCController"][3]
    f = _start(fmus["AMPCController"], 1e9)
    f.setReal([vr["l"]], [20.0])
    for n in range(100):
        f.doStep(1e9 + n * H, H)
    _free(f)
    out = capfd.readouterr().out
    assert "t = 1000000006 s: the start-up mode's law on theta0 is over" in out, out
    assert "t = 1000000010 s: 10 s from t = 1000000000 s: 100 samples" in out, out
    assert "e+09" not in out
