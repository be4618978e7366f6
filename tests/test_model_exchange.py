"""Model exchange: the DC motor's C FMU built as a model-exchange-only FMU, stepped by
:class:`tapmuscle.cosim.model_exchange.ModelExchangeStepper` (fmpy's CVode, inputs held over each
step) and diagnosed by ``tapmuscle diagnose`` as its co-simulation build is."""

from __future__ import annotations

import ctypes
import math
import re

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp

from tapmuscle.cosim.master import FmuInstance
from tapmuscle.cosim.spec import ScenarioError
from tapmuscle.cosim.model_exchange import DEFAULT_RELATIVE_TOLERANCE, ModelExchangeError, ModelExchangeStepper
from tapmuscle.diagnosis.foreign_demo import ForeignCase, record_foreign_case
from tapmuscle.diagnosis.foreign_diagnose import diagnose_foreign
from tapmuscle.diagnosis.foreign_fmus import build_dc_motor_fmu
from tapmuscle.diagnosis.foreign_fmus.dc_motor import VARIABLES
from tapmuscle.diagnosis.foreign_model import read_interface

pytestmark = [pytest.mark.c_host, pytest.mark.foreign]

H = 0.05  # s
P = {v.name: v.start for v in VARIABLES if v.causality == "parameter"}


@pytest.fixture(scope="module")
def builds(tmp_path_factory):
    root = tmp_path_factory.mktemp("dc_motor_me")
    return {"me": build_dc_motor_fmu(root / "me", interfaces=("ModelExchange",)),
            "cs": build_dc_motor_fmu(root / "cs"),
            "both": build_dc_motor_fmu(root / "both", interfaces=("CoSimulation", "ModelExchange"))}


def _instance(path, **parameters: float) -> FmuInstance:
    inst = FmuInstance(path, "me_test", role="foreign plant", model_exchange=True)
    inst.set_parameters(parameters, where="test: '")
    return inst


def test_model_exchange_builds_validate_and_offer_what_was_asked(builds):
    for kind, path in builds.items():
        assert validate_fmu(str(path)) == [], kind
        md = read_model_description(str(path))
        assert (md.modelExchange is not None) == (kind in ("me", "both"))
        assert (md.coSimulation is not None) == (kind in ("cs", "both"))
    md = read_model_description(str(builds["me"]))
    assert md.numberOfContinuousStates == 3 and md.numberOfEventIndicators == 0
    assert [d.variable.name for d in md.derivatives] == ["der(i)", "der(omega)", "der(theta)"]
    assert read_interface(builds["me"]).model_exchange and not read_interface(builds["both"]).model_exchange
    with pytest.raises(ValueError, match="interfaces"):
        build_dc_motor_fmu(builds["me"].parent, interfaces=("Scheduled",))


def test_stepper_follows_a_tight_scipy_solution(builds):
    """Random voltage steps for 10 s: CVode (rtol 1e-7) follows the same ODE solved at 1e-12."""
    rng = np.random.default_rng(3)
    volts = np.repeat(rng.uniform(-12.0, 12.0, 20), 10)
    inst = _instance(builds["me"])
    inst.fmu.setReal([inst.vr("V")], [volts[0]])
    inst.start()
    stepper = ModelExchangeStepper(inst.fmu, inst.unpacked.model_description)
    got = np.empty((len(volts), 3))
    for k, v in enumerate(volts):
        inst.fmu.setReal([inst.vr("V")], [float(v)])
        stepper.do_step(k * H, H)
        got[k] = inst.fmu.getReal([inst.vr("i"), inst.vr("omega"), inst.vr("theta")])
    inst.free()

    def rhs(t, x, v):
        i, w, _ = x
        return [(v - P["R"] * i - P["K"] * w) / P["L"],
                (P["K"] * i - P["b"] * w - P["Tc"] * math.tanh(w / P["omega_s"])) / P["J"], w]

    x, want = [0.0, 0.0, 0.0], np.empty_like(got)
    for k in range(len(volts)):
        x = solve_ivp(rhs, (k * H, (k + 1) * H), x, method="DOP853", rtol=1e-12, atol=1e-12, args=(volts[k],)).y[:, -1]
        want[k] = x
    # CVode controls the local error to rtol * |x| + rtol * nominal (1) per internal step; the global
    # error over 200 restarts measured 13 rtol of the largest value here: 100 rtol leaves room for
    # another CPU's rounding, and a solver 10x less accurate than asked fails
    scale = np.abs(want).max(axis=0)
    assert np.all(np.abs(got - want).max(axis=0) / scale < 100 * DEFAULT_RELATIVE_TOLERANCE)


def test_a_failing_integration_names_the_call_and_prints_nothing(builds, capfd):
    inst = _instance(builds["me"], J=1e-300, L=1e-300)  # the states overflow at once
    inst.fmu.setReal([inst.vr("V")], [10.0])
    inst.start()
    stepper = ModelExchangeStepper(inst.fmu, inst.unpacked.model_description)
    with pytest.raises(ModelExchangeError, match="fmi2SetContinuousStates failed"):
        stepper.do_step(0.0, H)
    assert any("is not finite" in m for m in inst.messages)
    with pytest.raises(ModelExchangeError, match="must be finite and > 0"):
        stepper.do_step(0.0, 0.0)
    inst.free()
    assert capfd.readouterr().err == ""  # SUNDIALS' own handler would print to stderr


def test_model_exchange_calls_on_a_co_simulation_instance_are_refused(builds):
    inst = FmuInstance(builds["both"], "cs_test", role="foreign plant")
    inst.start()
    derivatives = (ctypes.c_double * 3)()
    status = inst.fmu.dll.fmi2GetDerivatives(ctypes.c_void_p(inst.fmu.component), derivatives, ctypes.c_size_t(3))
    assert status == 3  # fmi2Error
    assert any("fmi2GetDerivatives: this instance was created for co-simulation" in m for m in inst.messages)
    inst.free()


def test_a_model_exchange_only_fmu_as_a_co_simulation_instance_is_told_what_to_do(builds):
    with pytest.raises(ScenarioError, match=re.escape(
            "has no co-simulation interface (a model-exchange FMU): scenarios, sweeps and check step "
            "co-simulation FMUs, so export it for co-simulation (tapmuscle diagnose --plant takes a "
            "model-exchange plant)")):
        FmuInstance(builds["me"], "cs_test", role="foreign plant")


@pytest.mark.slow
def test_a_model_exchange_fmu_is_diagnosed_as_its_co_simulation_build(builds, tmp_path):
    case = ForeignCase("t_me", "DcMotor", "transport_delay[V]", {"V:delay_s": 0.15}, {}, "steps", True, [7, 0])
    rec, m = record_foreign_case(case, builds["cs"], tmp_path / "rec", duration_s=60.0)
    got = {}
    for kind in ("cs", "me"):
        got[kind] = diagnose_foreign(rec, builds[kind], tmp_path / kind, map_path=m, calibrate=False, plots=False,
                                     effects=["transport_delay[V]", "output_drift[omega]"], echo=lambda s: None)
    (d_cs, doc_cs), (d_me, doc_me) = got["cs"], got["me"]
    assert d_me.named == d_cs.named == ["transport_delay[V]"]
    assert doc_me["fmi_interface"] == "model exchange" and doc_cs["fmi_interface"] == "co-simulation"
    # the two integrators differ by ~1e-5 rad/s against 0.05 rad/s of sensor noise
    assert d_me.findings[0].parameters["V:delay_s"] == pytest.approx(d_cs.findings[0].parameters["V:delay_s"], abs=2e-3)
    assert d_me.fit_after_percent == pytest.approx(d_cs.fit_after_percent, abs=0.05)
    assert d_me.fit_after_percent >= 95.0
