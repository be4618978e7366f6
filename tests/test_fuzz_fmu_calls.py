"""Seeded fuzz of FMI call sequences on both FMUs: bad values, bad step sizes, state rewinds in any
order. Every call returns OK or an FMI error status (fmpy raises FMICallException), the host process
survives, an output read is never NaN, and a refused call changes nothing."""

from __future__ import annotations

import math
import random

import pytest
from fmpy.fmi1 import FMICallException
from fmpy_helpers import instantiate, open_fmu

BAD = [math.nan, math.inf, -math.inf, -1e300, 1e300]


@pytest.fixture(scope="module")
def fmus(built_fmus):
    return {name: open_fmu(path) for name, path in built_fmus.items()}


def _values(rng, good_lo, good_hi):
    return rng.choice(BAD) if rng.random() < 0.2 else rng.uniform(good_lo, good_hi)


@pytest.mark.parametrize("name, inputs, outputs", [
    ("MusclePlant", {"u": (0.0, 10.0), "load_force": (30.0, 80.0)}, ["l", "p"]),
    ("AMPCController", {"l": (0.0, 80.0), "r": (5.0, 65.0)}, ["u"]),
])
@pytest.mark.parametrize("seed", range(3))
def test_random_call_sequences_keep_the_fmu_sane(fmus, name, inputs, outputs, seed):
    fmu = fmus[name]
    vr = fmu[3]
    inputs = {k: v for k, v in inputs.items() if k in vr}
    rng = random.Random(seed)
    f = instantiate(fmu, name=f"fuzz{seed}")
    t, states, refused, done = 0.0, [], 0, 0
    for _ in range(250):
        op = rng.random()
        try:
            if op < 0.35:
                key = rng.choice(list(inputs))
                f.setReal([vr[key]], [_values(rng, *inputs[key])])
            elif op < 0.75:
                dt = rng.choice([0.1, 0.1, 0.05, 0.2]) if rng.random() < 0.85 else rng.choice([0.0, -0.1, math.nan,
                                                                                              1e-14, 1e9])
                before = f.getReal([vr[o] for o in outputs])
                try:
                    f.doStep(t, dt)
                except FMICallException:
                    refused += 1
                    assert f.getReal([vr[o] for o in outputs]) == before  # a refused step changes nothing
                    continue
                t += dt
                done += 1
            elif op < 0.85:
                states.append((f.getFMUstate(), t))
            elif states:
                state, t = rng.choice(states)
                f.setFMUstate(state)
        except FMICallException:
            refused += 1
        values = f.getReal([vr[o] for o in outputs])
        assert all(math.isfinite(v) for v in values), (name, values)
    for state, _ in states:
        f.freeFMUstate(state)
    f.terminate()
    f.freeInstance()
    assert done > 10 and refused > 0  # both paths exercised


@pytest.mark.parametrize("name, fixed, output", [("MusclePlant", "friction.base_n", "l"),
                                                 ("AMPCController", "servo.R", "u")])
def test_calls_out_of_the_fmi_state_machine_are_errors(fmus, name, fixed, output):
    """FMI 2.0's co-simulation state machine: no step before fmi2ExitInitializationMode or after
    fmi2Terminate, no fixed parameter after initialisation. Each such call returns fmi2Error with a
    logged reason; reading outputs stays allowed and finite."""
    from fmpy.fmi2 import FMU2Slave

    path, md, folder, vr = fmus[name]
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=f"sm-{name}")
    f.instantiate(loggingOn=False)
    with pytest.raises(FMICallException, match="status 3"):
        f.doStep(0.0, 0.1)  # instantiated, not initialised
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    with pytest.raises(FMICallException, match="status 3"):
        f.doStep(0.0, 0.1)  # in initialisation mode
    f.exitInitializationMode()
    with pytest.raises(FMICallException, match="status 3"):
        f.setReal([vr[fixed]], [1.0])  # a fixed parameter after initialisation
    f.doStep(0.0, 0.1)
    f.terminate()
    with pytest.raises(FMICallException, match="status 3"):
        f.doStep(0.1, 0.1)  # terminated
    assert math.isfinite(f.getReal([vr[output]])[0])
    f.freeInstance()
