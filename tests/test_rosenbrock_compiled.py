"""The compiled ROS34PW2 sub-step (fmu_plant/_ros34pw2.c) is the Python one, bit for bit.

Bit identity is the contract here, not a tolerance: the compiled copy does the same IEEE-754
operations in the same order, so every simulation, documented figure and FMU result is the same
whichever sub-step ran (the FMUs carry the Python one). The install builds it where a C compiler is;
CI sets ``TAPMUSCLE_REQUIRE_COMPILED=1`` so that a silently failed build fails here instead of
making the suite slow.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from fmu_plant import Plant, PlantParams
from fmu_plant import plant as plant_module
from fmu_plant import rosenbrock
from fmu_plant.rosenbrock import COMPILED, build_model
from test_equations import VARIANTS, _states

if not COMPILED:
    if os.environ.get("TAPMUSCLE_REQUIRE_COMPILED") == "1":
        raise ImportError("TAPMUSCLE_REQUIRE_COMPILED=1 but fmu_plant._ros34pw2 did not build (setup.py)")
    pytest.skip("the compiled sub-step is not installed (no C compiler at install time)", allow_module_level=True)


def _same(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("name", list(VARIANTS))
def test_a_sub_step_is_the_python_one_bit_for_bit(name):
    prm = VARIANTS[name]
    _, _, step_py, gate_py, _ = build_model(prm, compiled=False)
    _, _, step_c, gate_c, _ = build_model(prm, compiled=True)
    rng = np.random.default_rng(11)
    checked = 0
    for gate in (1.0, 0.3, 0.0):
        gate_py(gate)
        gate_c(gate)
        for state in _states(rng, 1000):
            # any spool target, supply and load, steps from 1 us to 30 ms (both sides of the
            # spurious-reversal threshold)
            args = (*state, rng.uniform(-0.1, 1.1), rng.uniform(0.15, 0.3), rng.uniform(0.0, 90.0),
                    10.0 ** rng.uniform(-6.0, -1.5))
            try:
                expected = step_py(*args)
            except (ZeroDivisionError, OverflowError):  # Python raises where C returns inf: not compared
                continue
            got = step_c(*args)
            assert _same(got, expected), f"{name}, gate {gate}: attempt{args} = {got}, Python {expected}"
            checked += 1
    assert checked > 2900


# A dead band (the valve gate switches), a delay and a supply sag: every port the sub-steps sample
# (the compiled loop calls back into the effects); a drift and a play act on the measurement alone
# (the loop holds the ports, as without effects).
RUNS = {
    "ports": {"dead_zone.center_v": 5.0, "dead_zone.width_v": 1.0, "delay.delay_s": 0.2,
              "supply_variation.sag_mpa": 0.03, "supply_variation.start_s": 10.0,
              "supply_variation.end_s": 20.0, "friction.rate_gain": 0.5},
    "measurement only": {"sensor_drift.rate_mm_per_min": 1.5, "backlash.slack_mm": 0.4},
}


@pytest.mark.parametrize("name", list(RUNS))
def test_a_run_with_effects_is_the_python_one_bit_for_bit(monkeypatch, name):
    prm = PlantParams().with_values(**RUNS[name])
    u = 5.0 + 4.5 * np.sin(2 * np.pi * 0.2 * np.arange(300) * 0.1) * np.sign(np.sin(np.arange(300) * 0.05))

    def run() -> np.ndarray:
        plant = Plant(prm, seed=3)
        return np.array([[m.l_mm, m.p_mpa, *plant.state] for m in (plant.step(float(uk), 0.1) for uk in u)])

    compiled = run()
    original = plant_module.build_model
    monkeypatch.setattr(plant_module, "build_model", lambda p: original(p, compiled=False))
    python = run()
    assert np.array_equal(compiled, python)
    assert np.ptp(compiled[:, 0]) > 50.0  # the run moved the muscle over most of its stroke


def test_the_compiled_model_checks_its_inputs():
    compiled = rosenbrock._ros34pw2
    with pytest.raises(ValueError, match=f"takes {len(compiled.NAMES)} constants"):
        compiled.Model([1.0, 2.0])
    _, _, step, *_ = build_model(PlantParams(), compiled=True)
    with pytest.raises(TypeError, match="takes 9 arguments"):
        step(0.0, 0.0, 0.0)
    with pytest.raises(TypeError):
        step(0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.25, "44", 1e-3)
    _, _, _, _, advance = build_model(PlantParams(), compiled=True)
    with pytest.raises(TypeError, match="takes 14 arguments"):
        advance(0.0, 0.0, 0.0)
    state = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.004, 0.25, 5.0, 0.25, 44.0, 0.0, 0.1)
    with pytest.raises(TypeError, match="must return a tuple"):
        advance(*state, lambda t: [5.0, 0.25, 44.0])
    with pytest.raises(ZeroDivisionError):  # an effect's error comes through, not a crash
        advance(*state, lambda t: 1 / 0)


def test_a_broken_down_step_returns_the_start_and_the_time_as_the_python_loop_does():
    prm = PlantParams()
    _, _, _, _, advance_c = build_model(prm, compiled=True)
    _, _, _, _, advance_py = build_model(prm, compiled=False)
    state = (0.5, math.nan, 10.0, 0.0, 0.0, 0.5, 0.004, 0.25, 5.0, 0.25, 44.0, 1.0, 0.1, None)
    got, expected = advance_c(*state), advance_py(*state)
    assert _same(got, expected) and got[-1] == 1.0 and math.isnan(got[1]), (got, expected)


def test_a_sub_step_built_for_another_python_is_named_and_the_plant_fmu_says_so(tmp_path, monkeypatch):
    """An FMU built by CPython 3.11 in a 3.13 host: the shipped binary is not this interpreter's, the
    Python sub-step runs (2.5 times slower, which must not go unsaid). The package notices the foreign binary,
    and the plant FMU says so once at initialisation, as an information (the results are the same)."""
    import shutil
    import subprocess
    import sys

    from pythonfmu.enums import Fmi2Status

    from fmu_plant import plant_slave

    pkg = tmp_path / "fmu_plant"
    shutil.copytree(os.path.dirname(rosenbrock.__file__), pkg, ignore=shutil.ignore_patterns("__pycache__"),
                    copy_function=shutil.copyfile)
    pkg.chmod(0o755)  # writable whatever the checkout's modes
    (own,) = [p for p in pkg.iterdir() if p.name.startswith("_ros34pw2.") and p.suffix in (".so", ".pyd")]
    foreign = "_ros34pw2.cpython-399-x86_64-linux-gnu.so"
    own.rename(pkg / foreign)
    probe = ("import fmu_plant.rosenbrock as r; print(r.COMPILED, r.COMPILED_FOR_ANOTHER_PYTHON, "
             "r.__file__.startswith(sys.argv[1]))")
    out = subprocess.run([sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); " + probe, str(tmp_path)],
                         capture_output=True, text=True, check=True, env={**os.environ, "PYTHONPATH": ""}).stdout
    assert out.split() == ["False", foreign, "True"]
    assert rosenbrock.COMPILED_FOR_ANOTHER_PYTHON is None  # this installation's own is in use

    monkeypatch.setattr(plant_slave, "COMPILED_FOR_ANOTHER_PYTHON", foreign)
    slave = plant_slave.MusclePlant(instance_name="foreign")
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    (msg,) = [m for m in slave.log_queue if foreign in m.msg]
    assert msg.status == Fmi2Status.ok and "the same results, about 2.5 times slower" in msg.msg
    assert f"CPython {sys.version_info.major}.{sys.version_info.minor}" in msg.msg


def test_a_power_beyond_floats_range_breaks_down_in_python_as_in_the_compiled_sub_step():
    """A speed reference of 1e-300 mm/s under an exponent of 2: Python's float power raises a bare
    OverflowError, which must not leave the Python sub-step where the compiled one's pow gives inf and the step
    breaks down; both return the step's start and the same failure time."""
    prm = PlantParams().with_values(**{"friction.rate_ref_mm_s": 1e-300, "friction.rate_exponent": 2.0})
    _, _, _, _, advance_c = build_model(prm, compiled=True)
    _, _, _, _, advance_py = build_model(prm, compiled=False)
    state = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.004, 0.25, 10.0, 0.25, 44.0, 0.0, 0.1, None)
    got, expected = advance_c(*state), advance_py(*state)
    assert _same(got, expected) and got[-1] == got[-1] and 0.0 < got[-1] < 0.1, (got, expected)
