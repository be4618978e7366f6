"""The foreign ThermalTwoMass FMU (tapmuscle.diagnosis.foreign_fmus.thermal): valid, exact, resettable.

Every run drives the FMU through fmpy's raw FMU2Slave calls, as a host would. The FMU integrates
each communication step exactly (closed-form matrix exponential), so its temperatures agree with a
tight reference ODE solution to that solver's accuracy, not to a step-size error.
"""

from __future__ import annotations

import math
import subprocess
import sys

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                       fmi2CallbackLoggerTYPE)
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp

from tapmuscle.cosim.extraction_folder import claimed_folder
from tapmuscle.cosim.pythonfmu_exit import release_at_exit
from tapmuscle.diagnosis.foreign_fmus.thermal import FMU_NAME, build_thermal_fmu

pytestmark = [pytest.mark.fmu, pytest.mark.foreign]

DEFAULTS = {"C1": 500.0, "C2": 800.0, "G12": 2.0, "G1a": 1.0, "G2a": 0.5, "T_amb": 20.0, "T1_0": 20.0, "T2_0": 20.0}
NAMES = ["P1", "P2", "T1", "T2", *DEFAULTS]  # in value-reference order
VR = {name: i for i, name in enumerate(NAMES)}


class Host:
    """An fmpy FMU2Slave of the FMU with a logger that keeps the messages ``(status, category, text)``."""

    def __init__(self, fmu: tuple, name: str = "thermal") -> None:
        path, md, folder = fmu
        self.messages: list[tuple[int, str | None, str]] = []
        self._callbacks = fmi2CallbackFunctions()  # kept alive as long as the instance
        self._callbacks.logger = fmi2CallbackLoggerTYPE(lambda env, inst, status, cat, msg: self.messages.append(
            (status, None if cat is None else cat.decode(), msg.decode())))
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        self.slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                               instanceName=name)
        # this test process hosts it: without the release pythonfmu's binary may corrupt the heap at exit
        release_at_exit(folder, md.coSimulation.modelIdentifier)
        self.slave.instantiate(callbacks=self._callbacks, loggingOn=True)

    def initialise(self, **parameters: float) -> int:
        """setupExperiment, parameters, enter/exit initialisation; the status of the exit."""
        s = self.slave
        s.setupExperiment(startTime=0.0)
        for name, value in parameters.items():
            s.setReal([VR[name]], [value])
        s.enterInitializationMode()
        return s.exitInitializationMode()

    def run(self, P1: float, P2: float, h: float, n: int, record: set[int] = frozenset()) -> dict[int, list[float]]:
        """``n`` steps of ``h`` at constant inputs: ``{k: [T1, T2]}`` after step k for k in ``record`` and n."""
        s, out = self.slave, {}
        for k in range(1, n + 1):
            s.setReal([VR["P1"], VR["P2"]], [P1, P2])
            s.doStep((k - 1) * h, h)
            if k in record or k == n:
                out[k] = s.getReal([VR["T1"], VR["T2"]])
        return out

    def free(self) -> None:
        self.slave.terminate()
        self.slave.freeInstance()


def reference(P1: float, P2: float, p: dict[str, float] = DEFAULTS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, b, steady state)`` of dT/dt = A T + b for constant inputs."""
    A = np.array([[-(p["G12"] + p["G1a"]) / p["C1"], p["G12"] / p["C1"]],
                  [p["G12"] / p["C2"], -(p["G12"] + p["G2a"]) / p["C2"]]])
    b = np.array([(P1 + p["G1a"] * p["T_amb"]) / p["C1"], (P2 + p["G2a"] * p["T_amb"]) / p["C2"]])
    return A, b, np.linalg.solve(A, -b)


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    """``(path, model description, extracted folder)`` of a freshly built FMU."""
    out = tmp_path_factory.mktemp("thermal")
    path = build_thermal_fmu(out)
    assert path == out / FMU_NAME and path.is_file()
    assert sorted(p.name for p in out.iterdir()) == [FMU_NAME]  # the temporary build folder is gone
    # where the project extracts FMUs: pythonfmu's own binary cannot open a folder named beyond ASCII
    return path, fmpy.read_model_description(str(path)), fmpy.extract(str(path), claimed_folder("tm_thermal_test_"))


@pytest.fixture
def host(fmu):
    h = Host(fmu)
    yield h
    h.free()


def test_validates_and_describes_the_model(fmu):
    path, md, _ = fmu
    assert validate_fmu(str(path)) == []
    variables = {v.name: v for v in md.modelVariables}
    assert [v.name for v in sorted(md.modelVariables, key=lambda v: v.valueReference)] == NAMES
    assert {n: (variables[n].causality, variables[n].variability, variables[n].unit) for n in ("P1", "P2", "T1", "T2")} == {
        "P1": ("input", "continuous", "W"), "P2": ("input", "continuous", "W"),
        "T1": ("output", "continuous", "degC"), "T2": ("output", "continuous", "degC")}
    for name, default in DEFAULTS.items():
        v = variables[name]
        assert (v.causality, v.variability, float(v.start)) == ("parameter", "fixed", default)
    assert variables["C1"].unit == "J/K" and variables["G12"].unit == "W/K" and variables["T_amb"].unit == "degC"
    assert [u.name for u in md.unitDefinitions] == ["W", "J/K", "W/K", "degC"]
    de = md.defaultExperiment  # fmpy < 0.3.28 parses these to float, newer keep the literal string
    assert (float(de.startTime), float(de.stopTime), float(de.stepSize)) == (0.0, 600.0, 1.0)
    # no direct feedthrough: the outputs are the states
    assert [u.dependencies for u in md.outputs] == [[], []]
    assert md.coSimulation.modelIdentifier == "ThermalTwoMass"


def test_matches_the_ode_and_its_steady_state(host):
    """P1 = 50 W, P2 = 0 from 20 degC, h = 1 s. At 100 s against solve_ivp (rtol 1e-10): the FMU is exact,
    so the difference is the reference solver's error (~1e-10 K), well inside 1e-7 K. At 3000 s
    against the closed-form transient (the slow time constant is 918 s: the state is still 1.0 K
    and 1.3 K below steady state). At 12000 s (13 slow time constants) against the steady state to 1e-3 K."""
    assert host.initialise() == 0
    out = host.run(50.0, 0.0, 1.0, 12000, record={100, 3000})
    A, b, steady = reference(50.0, 0.0)
    ode = solve_ivp(lambda t, T: A @ T + b, (0.0, 100.0), [20.0, 20.0], method="DOP853", rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(out[100], ode.y[:, -1], rtol=0, atol=1e-7)
    w, V = np.linalg.eig(A)
    transient = steady + V @ (np.exp(w * 3000.0) * np.linalg.solve(V, np.array([20.0, 20.0]) - steady))
    # 3000 exact steps accumulate about n eps |T| = 3000 x 2.2e-16 x 55 K ~ 4e-11 K of rounding (less:
    # the dynamics are stable), and the eigen-decomposition adds ~1e-13 K: 1e-9 K leaves 25x for
    # another CPU's libm and BLAS
    np.testing.assert_allclose(out[3000], transient, rtol=0, atol=1e-9)
    assert np.max(np.abs(np.array(out[3000]) - steady)) > 0.9  # 3000 s is not steady yet
    np.testing.assert_allclose(out[12000], steady, rtol=0, atol=1e-3)
    np.testing.assert_allclose(steady, [20.0 + 250.0 / 7.0, 20.0 + 200.0 / 7.0], rtol=1e-12)


def test_exact_for_any_step_size(fmu):
    """Inputs held constant: 1000 steps of 0.1 s end where 100 steps of 1 s do, to rounding: it
    accumulates about n eps |T| = 1000 x 2.2e-16 x 50 K ~ 1e-11 K, and another CPU's libm may differ
    in the last bits, hence 1e-9 K."""
    results = []
    for h, n in ((1.0, 100), (0.1, 1000)):
        host = Host(fmu)
        host.initialise(T1_0=35.0, T2_0=12.0)
        results.append(host.run(30.0, 15.0, h, n)[n])
        host.free()
    np.testing.assert_allclose(results[0], results[1], rtol=0, atol=1e-9)


def test_reset_restores_defaults_and_repeats_runs(host):
    assert host.initialise() == 0
    first = host.run(50.0, 10.0, 1.0, 300, record={1, 50, 200})
    assert host.slave.reset() == 0
    # pythonfmu's fmi2Reset constructs a new slave: parameters, inputs and outputs at their defaults
    assert host.slave.getReal([VR[n] for n in ("P1", "P2", "T1", "T2", *DEFAULTS)]) == [0.0, 0.0, 20.0, 20.0,
                                                                                         *DEFAULTS.values()]
    assert host.initialise() == 0
    assert host.run(50.0, 10.0, 1.0, 300, record={1, 50, 200}) == first  # bit for bit
    assert host.slave.reset() == 0
    assert host.initialise(C1=1000.0) == 0
    assert host.slave.getReal([VR["C1"]]) == [1000.0]
    heavier = host.run(50.0, 10.0, 1.0, 300, record={1, 50, 200})
    assert heavier[300][0] < first[300][0] - 1.0  # twice the capacity: mass 1 warms markedly slower
    assert not [m for m in host.messages if m[0] > 0]


def test_both_inputs_act(fmu):
    rise = {}
    for inputs in ((50.0, 0.0), (0.0, 50.0)):
        host = Host(fmu)
        host.initialise()
        rise[inputs] = np.array(host.run(*inputs, 1.0, 600)[600]) - 20.0
        host.free()
    only_p2, only_p1 = rise[(0.0, 50.0)], rise[(50.0, 0.0)]
    assert only_p2[1] > only_p2[0] > 0.5
    assert only_p1[0] > only_p1[1] > 0.5
    # the network is reciprocal: the heat P2 puts into mass 1 equals, per watt, what P1 puts into mass 2 ...
    _, _, s1 = reference(50.0, 0.0)
    _, _, s2 = reference(0.0, 50.0)
    assert math.isclose(s1[1] - 20.0, s2[0] - 20.0, rel_tol=1e-12)


def test_bad_parameter_refuses_every_step_and_reset_recovers(host):
    assert host.initialise(C1=0.0) == 0  # pythonfmu cannot return fmi2Error without an fmi2Fatal
    assert (3, "logStatusError") == host.messages[-1][:2] and "C1 = 0.0 J/K must be > 0" in host.messages[-1][2]
    with pytest.raises(FMICallException) as info:
        host.slave.doStep(0.0, 1.0)
    assert info.value.status == 2  # fmi2Discard
    assert "not initialised: bad parameter: C1" in host.messages[-1][2]
    host.slave.reset()
    assert host.initialise(G12=-1.0) == 0 and "G12 = -1.0 W/K must be >= 0" in host.messages[-1][2]
    host.slave.reset()
    assert host.initialise(T_amb=math.nan) == 0 and "T_amb = nan is not finite" in host.messages[-1][2]
    host.slave.reset()
    assert host.initialise() == 0
    host.run(50.0, 0.0, 1.0, 10)


def test_bad_input_and_late_parameter(host):
    host.initialise()
    before = host.run(50.0, 0.0, 1.0, 10)[10]
    host.slave.setReal([VR["P2"]], [math.inf])
    with pytest.raises(FMICallException) as info:
        host.slave.doStep(10.0, 1.0)
    assert info.value.status == 2 and "input P2 = inf W is not finite" in host.messages[-1][2]
    assert host.slave.getReal([VR["T1"], VR["T2"]]) == before  # unchanged
    with pytest.raises(FMICallException):
        host.slave.doStep(10.0, 0.0)
    assert "step size 0.0 must be finite and > 0" in host.messages[-1][2]
    host.slave.setReal([VR["C1"]], [1.0])  # fixed: ignored after initialisation, with a warning
    assert host.messages[-1][0] == 1 and "C1 = 1.0 ignored" in host.messages[-1][2]
    assert host.slave.getReal([VR["C1"]]) == [500.0]
    host.run(50.0, 0.0, 1.0, 1)


HOSTILE = r'''
import sys, gc, fmpy
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from tapmuscle.cosim.extraction_folder import claimed_folder
from tapmuscle.cosim.pythonfmu_exit import release_at_exit
path = sys.argv[1]
md = fmpy.read_model_description(path)
folder = fmpy.extract(path, claimed_folder("tm_thermal_test_"))
statuses = set()
for i in range(40):
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="x")
    # pythonfmu's binary corrupts the heap at exit otherwise (rarely an abort, unrelated to the calls below)
    release_at_exit(folder, md.coSimulation.modelIdentifier)
    f.instantiate()
    for call in (lambda: f.getReal([99]), lambda: f.setReal([99], [1.0]), lambda: f.getInteger([0])):
        try:
            call()
        except FMICallException as exc:
            statuses.add(exc.status)
    f.freeInstance()
    gc.collect()
print(sorted(statuses))
'''


def test_host_errors_are_fatal_status_not_a_crash(fmu):
    """An unknown or non-Real value reference: fmi2Fatal, and freeing the instance afterwards is safe
    (without the slave's work-around pythonfmu 0.7 frees live objects and the process segfaults)."""
    path = fmu[0]
    done = subprocess.run([sys.executable, "-c", HOSTILE, str(path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "[4]"
