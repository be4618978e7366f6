"""The hand-written C FMU of a DC motor (tapmuscle/diagnosis/foreign_fmus): built with gcc, run
through fmpy's raw FMI 2.0 calls. Its numbers (steady state, a transient against scipy), fmi2Reset
and FMU states reproducing runs bit for bit, refused values reported through the host's logger,
and communication steps of any length."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2OK, fmi2True
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from tapmuscle.diagnosis.foreign_fmus import build_dc_motor_fmu
from tapmuscle.diagnosis.foreign_fmus.dc_motor import VARIABLES

pytestmark = [pytest.mark.c_host, pytest.mark.foreign]

H = 0.05  # s, communication step
DEFAULTS = {v.name: v.start for v in VARIABLES if v.causality == "parameter"}
VR = {v.name: v.value_reference for v in VARIABLES}
OUTPUTS = [VR["omega"], VR["i"], VR["theta"]]


@pytest.fixture(scope="module")
def fmu_path(tmp_path_factory) -> Path:
    return build_dc_motor_fmu(tmp_path_factory.mktemp("dc_motor"))


@pytest.fixture(scope="module")
def unzipped(fmu_path, tmp_path_factory) -> tuple[str, object]:
    folder = extract(str(fmu_path), unzipdir=str(tmp_path_factory.mktemp("dc_motor_unzipped")))
    return folder, read_model_description(folder)


class Logged:
    """An fmpy host whose logger keeps every message as ``(status, category, text)``."""

    def __init__(self, unzipped, logging_on: bool = False) -> None:
        folder, md = unzipped
        self.messages: list[tuple[int, str, str]] = []
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                             instanceName="motor")
        callbacks = fmi2CallbackFunctions()
        # A bare ctypes logger, without fmpy.logging.addLoggerProxy: that proxy keeps one target per
        # process, so adding it here would redirect every other fmpy instance's messages to this list.
        # DcMotor formats its messages itself, so the text arrives complete without the proxy.
        callbacks.logger = fmi2CallbackLoggerTYPE(self._log)
        # no allocateMemory/freeMemory: the FMU declares canNotUseMemoryManagementFunctions
        self.fmu.instantiate(callbacks=callbacks, loggingOn=logging_on)  # the FMU2Slave keeps callbacks alive

    def _log(self, env, instance_name, status, category, message) -> None:
        self.messages.append((status, category.decode(), message.decode()))

    def texts(self) -> str:
        return "\n".join(text for _, _, text in self.messages)


@pytest.fixture
def host(unzipped):
    h = Logged(unzipped)
    yield h
    h.fmu.freeInstance()


def initialize(fmu: FMU2Slave, **parameters: float) -> None:
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    for name, value in parameters.items():
        fmu.setReal([VR[name]], [value])
    fmu.exitInitializationMode()


def run(fmu: FMU2Slave, volts: np.ndarray, t0: float = 0.0) -> np.ndarray:
    """Apply ``volts[k]`` over step k (raw fmi2DoStep calls); rows ``(omega, i, theta)`` after each step."""
    out = np.empty((len(volts), 3))
    for k, v in enumerate(volts):
        fmu.setReal([VR["V"]], [float(v)])
        assert fmu.fmi2DoStep(fmu.component, t0 + k * H, H, fmi2True) == fmi2OK
        out[k] = fmu.getReal(OUTPUTS)
    return out


def random_steps(n: int, seed: int = 1) -> np.ndarray:
    """A random step signal in [-12, 12] V that holds each level for 0.5 to 2 s."""
    rng = np.random.default_rng(seed)
    levels = []
    while len(levels) < n:
        levels += [rng.uniform(-12.0, 12.0)] * int(rng.integers(10, 41))
    return np.array(levels[:n])


def test_model_description_validates(fmu_path):
    assert validate_fmu(str(fmu_path)) == []


def test_start_values_are_the_fmu_defaults(host, unzipped):
    """The XML's value references and start values agree with the C enum and defaults."""
    _, md = unzipped
    assert [(v.name, v.valueReference) for v in md.modelVariables] == [(v.name, v.value_reference) for v in VARIABLES]
    starts = {v.name: float(v.start) for v in md.modelVariables if v.start is not None}
    initialize(host.fmu)
    assert host.fmu.getReal([VR[name] for name in starts]) == list(starts.values())
    assert host.fmu.getReal(OUTPUTS) == [0.0, 0.0, 0.0]


def test_steady_state_speed(host):
    """omega settles where K i = b omega + Tc tanh(omega/omega_s) with i = (V - K omega)/R.

    30 s rather than 10: with the default parameters the slow mode is exp(-0.70 t), so at 10 s omega
    is still about 1e-3 short of its end value; at 30 s the transient is below 1e-9. RK4's fixed
    point is the ODE's equilibrium, so the result has no integration error left.
    """
    p, V = DEFAULTS, 12.0
    initialize(host.fmu)
    omega = run(host.fmu, np.full(round(30.0 / H), V))[-1, 0]

    def torque_balance(w: float) -> float:
        i = (V - p["K"] * w) / p["R"]
        return p["K"] * i - p["b"] * w - p["Tc"] * math.tanh(w / p["omega_s"])

    expected = brentq(torque_balance, 0.0, V / p["K"], xtol=1e-14, rtol=1e-15)
    assert omega == pytest.approx(expected, rel=1e-6)
    assert expected == pytest.approx(82.86, rel=1e-3)  # (K V/R - Tc) / (K^2/R + b)


def test_transient_matches_scipy(host):
    """Random voltage steps for 10 s: the RK4 substeps follow a tight scipy solution of the same ODE."""
    p = DEFAULTS
    volts = random_steps(round(10.0 / H))
    initialize(host.fmu)
    got = run(host.fmu, volts)

    def rhs(t, x, v):
        i, w, _ = x
        return [(v - p["R"] * i - p["K"] * w) / p["L"],
                (p["K"] * i - p["b"] * w - p["Tc"] * math.tanh(w / p["omega_s"])) / p["J"],
                w]

    x, want = [0.0, 0.0, 0.0], np.empty_like(got)
    for k in range(len(volts)):  # one solve per step: the input is piecewise constant
        x = solve_ivp(rhs, (k * H, (k + 1) * H), x, method="DOP853", rtol=1e-12, atol=1e-12,
                      args=(volts[k],)).y[:, -1]
        want[k] = x[1], x[0], x[2]
    scale = np.abs(want).max(axis=0)
    assert np.abs(got - want).max(axis=0) / scale == pytest.approx([0, 0, 0], abs=1e-6)


def test_reset_reproduces_the_run_bit_for_bit(host):
    volts = random_steps(200, seed=2)
    initialize(host.fmu)
    first = run(host.fmu, volts)
    host.fmu.terminate()
    host.fmu.reset()
    initialize(host.fmu)
    assert np.array_equal(run(host.fmu, volts), first)

    host.fmu.reset()  # parameters are back to the defaults and can be set again
    initialize(host.fmu, Tc=0.05)
    assert host.fmu.getReal([VR["Tc"]]) == [0.05]
    assert not np.array_equal(run(host.fmu, volts), first)
    host.fmu.reset()
    assert host.fmu.getReal([VR["Tc"]]) == [DEFAULTS["Tc"]]


def test_fmu_state_restores_the_run_bit_for_bit(host):
    volts = random_steps(80, seed=3)  # 4 s
    initialize(host.fmu)
    run(host.fmu, volts[:40])  # to t = 2 s
    state = host.fmu.getFMUstate()
    first = run(host.fmu, volts[40:], t0=2.0)
    host.fmu.setFMUstate(state)
    again = run(host.fmu, volts[40:], t0=2.0)
    host.fmu.freeFMUstate(state)
    assert np.array_equal(again, first)
    assert np.abs(first).max() > 1.0  # the motor did move


def test_bad_parameter_is_refused_and_logged(unzipped):
    """Errors reach the logger although logging is off; a refused call changes nothing."""
    h = Logged(unzipped, logging_on=False)
    h.fmu.setupExperiment(startTime=0.0)
    h.fmu.enterInitializationMode()
    with pytest.raises(FMICallException) as info:
        h.fmu.setReal([VR["L"], VR["R"]], [0.02, -1.0])
    assert info.value.status == 3  # fmi2Error
    assert h.fmu.getReal([VR["L"], VR["R"]]) == [DEFAULTS["L"], DEFAULTS["R"]]
    status, category, text = h.messages[-1]
    assert (status, category) == (3, "logStatusError")
    assert "R = -1" in text and "must be > 0" in text
    h.fmu.freeInstance()


def test_nan_input_is_refused_and_logged(host):
    initialize(host.fmu)
    with pytest.raises(FMICallException):
        host.fmu.setReal([VR["V"]], [float("nan")])
    assert "V = nan refused: must be finite" in host.texts()
    assert host.fmu.getReal([VR["V"]]) == [0.0]


def test_parameters_are_fixed_after_initialization(host):
    initialize(host.fmu)
    with pytest.raises(FMICallException):
        host.fmu.setReal([VR["J"]], [0.02])
    assert "J = 0.02 refused" in host.texts()


@pytest.mark.parametrize("h", [0.013, 1e-12, 1.0])
def test_any_positive_communication_step(host, h):
    initialize(host.fmu)
    host.fmu.setReal([VR["V"]], [12.0])
    t = 0.0
    for _ in range(5):
        assert host.fmu.fmi2DoStep(host.fmu.component, t, h, fmi2True) == fmi2OK
        t += h
    omega, i, _ = host.fmu.getReal(OUTPUTS)
    assert i > 0.0 and omega > 0.0  # current builds up first, then the speed
    assert host.messages == []


@pytest.mark.parametrize("h", [0.0, -0.05, float("nan")])
def test_non_positive_communication_step_is_refused(host, h):
    initialize(host.fmu)
    with pytest.raises(FMICallException):
        host.fmu.doStep(0.0, h)
    assert "fmi2DoStep: communication step" in host.texts()


def test_diverging_state_is_an_error_that_keeps_the_last_state(host):
    """L = 1e-7 H makes the electrical mode far too fast for 0.5 ms RK4 substeps."""
    initialize(host.fmu, L=1e-7)
    host.fmu.setReal([VR["V"]], [12.0])
    with pytest.raises(FMICallException):
        for k in range(100):
            host.fmu.doStep(k * H, H)
    assert "the state became non-finite" in host.texts()
    assert all(math.isfinite(x) for x in host.fmu.getReal(OUTPUTS))
    host.fmu.reset()  # the way out of the error state
    initialize(host.fmu)
    assert host.fmu.getReal(OUTPUTS) == [0.0, 0.0, 0.0]
