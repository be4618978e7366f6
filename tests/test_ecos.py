"""The FMUs in Ecos (``ecospy``), a third-party co-simulation engine that steps every FMU in parallel.

``ecospy``'s native library needs Intel TBB (``libtbb.so.12``), which Debian ships as ``libtbb12``; the
test extra installs it from the package index instead (the ``tbb`` wheel puts ``libtbb.so.12`` under
the interpreter's prefix), and the fixture below loads it into the process before ``ecospy``, so that
nothing outside pip is needed. Like libcosim (tests/test_third_party_masters.py), Ecos is a Jacobi
master: at a macro step of ``Ts`` the controller's command reaches the plant one sample late, so its
trajectories must equal the direct loop with ``loop_delay_samples=1`` to rounding (the same code in the
same process).
"""

import ctypes
from importlib import metadata

import numpy as np
import pytest

from fmu_controller.displacement_control import ControllerSettings, DisplacementController
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.reference import SineReference
from fmu_plant import Plant
from tapmuscle.closed_loop import run_closed_loop
from tracking import tracking_error_mm

TS_S = 0.1


def _load_tbb() -> None:
    """Load the tbb wheel's ``libtbb.so.12`` with global symbols (what ``ecospy``'s library links)."""
    try:
        files = [f for f in metadata.files("tbb") or () if f.name == "libtbb.so.12"]
    except metadata.PackageNotFoundError:
        pytest.fail("the test extra's 'tbb' is not installed (pip install -e '.[test]'); ecospy needs libtbb.so.12")
    if not files:
        pytest.fail("the 'tbb' package has no libtbb.so.12 on this platform")
    ctypes.CDLL(str(files[0].locate()), mode=ctypes.RTLD_GLOBAL)


@pytest.fixture(scope="module")
def ecos():
    _load_tbb()
    import ecospy  # noqa: F401 - the import needs libtbb loaded
    from ecospy import EcosSimulation, EcosSimulationStructure

    return EcosSimulation, EcosSimulationStructure


def _closed_loop(ecos, fmus, input_delay_samples, n: int = 450) -> dict[str, np.ndarray]:
    EcosSimulation, EcosSimulationStructure = ecos
    ss = EcosSimulationStructure()
    ss.add_model("plant", str(fmus["MusclePlant"]))
    ss.add_model("ctrl", str(fmus["AMPCController"]))
    ss.make_real_connection("plant::l", "ctrl::l")
    ss.make_real_connection("ctrl::u", "plant::u")
    # None: nothing set, the FMU's default (-1: the controller detects the delay)
    ss.add_parameter_set("init", {} if input_delay_samples is None else {"ctrl::input_delay_samples": input_delay_samples})
    sim = EcosSimulation(structure=ss, step_size=TS_S)
    try:
        sim.init(parameter_set="init")
        rows = []
        for _ in range(n):
            sim.step()
            rows.append((sim.get_real("plant::l"), sim.get_real("plant::u"), sim.get_real("ctrl::r_k")))
        sim.terminate()
    finally:
        sim.free()
    a = np.array(rows)
    return {"l_mm": a[:, 0], "u_v": a[:, 1], "r_k_mm": a[:, 2]}


@pytest.fixture(scope="module")
def ecos_runs(ecos, built_fmus):
    return {d: _closed_loop(ecos, built_fmus, d) for d in (0, 1, None)}


@pytest.mark.parametrize("delay", [0, 1, None])
def test_ecos_closed_loop_is_the_direct_loop_with_one_sample_of_delay(ecos_runs, delay):
    """Row k of Ecos is after its (k+1)-th step: l(k+1), and the u the plant got at t_k+1."""
    run = ecos_runs[delay]
    c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=-1 if delay is None else delay),
                               THETA0_44N)
    direct = run_closed_loop(Plant(seed=0), c, SineReference(), duration_s=45.1, loop_delay_samples=1)
    n = len(run["l_mm"])
    np.testing.assert_allclose(run["l_mm"], direct["l_mm"][1:n + 1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(run["u_v"], direct["u_v"][1:n + 1], rtol=0, atol=1e-9)


def test_ecos_tracks_with_the_delay_compensated_or_detected(ecos_runs):
    """Built-in 35 + 30 sin(2 pi 0.1 t) mm at h = Ts, mean |r - l| after the start-up mode (20 s on):
    over a mm with 0 (an oscillation), a fraction of a mm with 1 and with nothing set (the
    default starts with the delayed law and keeps it; measured 1.23, 0.130 and 0.130 mm, the same as libcosim's; the bounds
    leave half again for another CPU's rounding, which the closed loop amplifies)."""
    err = {}
    for d, run in ecos_runs.items():
        t = (np.arange(len(run["l_mm"])) + 1) * TS_S
        err[d] = tracking_error_mm(t, run["l_mm"])
        assert run["u_v"].min() >= 0.0 and run["u_v"].max() <= 10.0
    assert err[0] > 1.0 and err[0] > 5 * err[1] and err[1] < 0.2 and err[None] < 0.3, err


def test_plant_alone_in_ecos_equals_fmpy(ecos, built_fmus):
    """l(10 s) at u = 5 V: Ecos and fmpy run the same FMU to the same number."""
    from fmpy import simulate_fmu

    EcosSimulation, EcosSimulationStructure = ecos
    ss = EcosSimulationStructure()
    ss.add_model("plant", str(built_fmus["MusclePlant"]))
    ss.add_parameter_set("init", {"plant::u": 5.0})
    sim = EcosSimulation(structure=ss, step_size=TS_S)
    try:
        sim.init(parameter_set="init")
        for _ in range(100):
            sim.step()
        l_ecos = sim.get_real("plant::l")
        sim.terminate()
    finally:
        sim.free()
    res = simulate_fmu(str(built_fmus["MusclePlant"]), start_values={"u": 5.0}, stop_time=10.0,
                       output_interval=TS_S, output=["l"])
    assert l_ecos > 1.0  # the muscle contracted: the comparison is not between zeros
    assert abs(l_ecos - float(res["l"][-1])) <= 1e-9


@pytest.mark.parametrize("parameter_set, limit_mm", [("parallel_master", 0.25), (None, 0.25)])
def test_ecos_runs_the_ssp_and_tracks(ecos, built_fmus, tmp_path, parameter_set, limit_mm):
    """Ecos's SSP loader runs TapMuscleLoop.ssp: with its parameter set ``parallel_master`` (the
    controller's input_delay_samples = 1) as libcosim does (0.138 mm over 20-30 s); with no set the
    controller's default -1 keeps the delayed law it starts with (0.138 mm, as with 1)."""
    from build_scripts.ssp import write_ssp

    EcosSimulation, _ = ecos
    sim = EcosSimulation(step_size=TS_S, ssp_path=str(write_ssp(built_fmus, tmp_path)))
    try:
        if parameter_set is None:
            sim.init()
        else:
            sim.init(parameter_set=parameter_set)
        rows = []
        for _ in range(300):
            sim.step()
            rows.append((sim.get_real("plant::l"), sim.get_real("plant::u")))
        sim.terminate()
    finally:
        sim.free()
    a = np.array(rows)
    t = (np.arange(len(a)) + 1) * TS_S
    err = tracking_error_mm(t, a[:, 0])
    assert a[:, 1].min() >= 0.0 and a[:, 1].max() <= 10.0
    assert err < limit_mm, err


def test_ecos_applies_both_rig_sets_of_a_twin_ssp_by_their_one_name(ecos, built_fmus, tmp_path):
    """Ecos applies only the sets of the name ``init(parameter_set=...)`` gives: a rig's plant file in
    the SSP (``tapmuscle build --ssp --params``) gives the plant and the controller sets of one name,
    ``rig``, so that name sets both (the file's constants and transport delay, the controller's
    compensation of it and of the parallel step); with no name, neither."""
    from build_scripts.ssp import RIG_SET, write_ssp
    from fmu_plant import PlantParams

    EcosSimulation, _ = ecos
    rig = PlantParams().with_values(**{"valve.cv_max": 1.3, "delay.delay_s": 0.2})
    path = write_ssp(built_fmus, tmp_path, rig=rig.dotted(), rig_delay_samples=2)
    seen = {}
    for name in (RIG_SET, None):
        sim = EcosSimulation(step_size=TS_S, ssp_path=str(path))
        try:
            sim.init(parameter_set=name) if name else sim.init()
            sim.step()
            seen[name] = (sim.get_real("plant::valve.cv_max"), sim.get_real("plant::delay.delay_s"),
                          sim.get_integer("controller::input_delay_samples"))
            sim.terminate()
        finally:
            sim.free()
    assert seen == {RIG_SET: (1.3, 0.2, 3), None: (1.5, 0.0, -1)}
