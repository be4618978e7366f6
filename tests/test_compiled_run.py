"""Plant.step_many's compiled loop (fmu_plant/compiled_run.py, ``Model.run``) is its Python loop, bit
for bit: readings, state, effect memory, saved state and errors.

Bit identity is the contract, as for the compiled sub-step (test_rosenbrock_compiled.py): a
diagnosis gives the same verdicts and figures whichever loop ran. The Python loop is reached here by
replacing the plant's sub-step loop with itself on the instance, which step_many honours.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fmu_plant import Plant, PlantParams
from fmu_plant.compiled_run import LIBRARY_ORDER, runnable
from fmu_plant.effect_library import Backlash, SensorDrift, TransportDelay, ValveDeadZone, effects_from_params
from fmu_plant.parameters import BacklashParams, DelayParams, SensorDriftParams
from fmu_plant.rosenbrock import COMPILED

needs_compiled = pytest.mark.skipif(not COMPILED, reason="the compiled sub-step is not installed")

#: Noise-free sensors: the compiled loop draws no random numbers.
NOISE_FREE = {"sensor.encoder_noise_std_mm": 0.0, "sensor.pressure_noise_std_mpa": 0.0}


def _python_loop(plant: Plant) -> Plant:
    """``plant`` with its sub-step loop replaced by itself: step_many then runs its Python loop."""
    advance = plant._advance_substeps
    plant._advance_substeps = lambda *args: advance(*args)
    return plant


def _random_effects(rng: np.random.Generator) -> dict[str, float]:
    """A random subset of the library's effects with random magnitudes (every port, memory and corner)."""
    v: dict[str, float] = {}
    if rng.random() < 0.6:
        v["delay.delay_s"] = float(rng.choice([0.1, 0.2, rng.uniform(0.01, 1.5)]))
    if rng.random() < 0.3:
        k1 = rng.uniform(2.0, 6.0)
        v |= {"input_map.out_at_0_v": rng.uniform(0.0, 1.0), "input_map.knot1_in_v": k1, "input_map.knot1_out_v": 5.0,
              "input_map.knot2_in_v": k1 + rng.uniform(0.1, 2.0), "input_map.knot2_out_v": 5.0,
              "input_map.out_at_10_v": rng.uniform(9.0, 10.0)}
    if rng.random() < 0.4:
        v |= {"dead_zone.center_v": rng.uniform(3.0, 7.0), "dead_zone.width_v": rng.uniform(0.1, 1.5)}
    if rng.random() < 0.5:
        start = rng.uniform(0.0, 6.0)
        v |= {"supply_variation.sag_mpa": rng.uniform(0.01, 0.06), "supply_variation.start_s": start,
              "supply_variation.end_s": start + rng.uniform(0.5, 5.0),
              "supply_variation.ramp_s": float(rng.choice([0.0, 0.3, 2.0])),
              "supply_variation.recovery_ramp_s": float(rng.choice([0.0, 0.7]))}
        if rng.random() < 0.3:
            v |= {"supply_variation.ripple_mpa": 0.01, "supply_variation.ripple_period_s": rng.uniform(0.5, 3.0)}
    if rng.random() < 0.3:
        v["load_mismatch.extra_n"] = rng.uniform(-60.0, 30.0)
    if rng.random() < 0.3:
        v["backlash.slack_mm"] = rng.uniform(0.1, 1.5)
    if rng.random() < 0.3:
        v |= {"sensor_drift.offset_mm": rng.uniform(-1.0, 1.0), "sensor_drift.rate_mm_per_min": rng.uniform(-1.0, 1.0)}
    if rng.random() < 0.5:  # the recording's quantisation, noise-free
        v |= {"sensor.encoder_resolution_mm": 0.0, "sensor.pressure_resolution_mpa": 0.0}
    return v


def _bits(values) -> bytes:
    """The IEEE-754 bytes of ``values`` (== would take -0.0 for 0.0)."""
    return np.asarray(values, dtype=float).tobytes()


def _same_readings(got: tuple[np.ndarray, np.ndarray], expected: tuple[np.ndarray, np.ndarray]) -> bool:
    return all(g.dtype == e.dtype and _bits(g) == _bits(e) for g, e in zip(got, expected, strict=True))


def _same(a: Plant, b: Plant) -> bool:
    """The same state, time, readings, saved state (JSON keeps the sign of a zero) and flows."""
    return (_bits(a.state) == _bits(b.state) and _bits(a.measurement) == _bits(b.measurement)
            and json.dumps(a.get_state(), sort_keys=True) == json.dumps(b.get_state(), sort_keys=True)
            and _bits(a.flows_l_min()) == _bits(b.flows_l_min()))


@needs_compiled
@pytest.mark.parametrize("seed", range(8))
def test_the_compiled_loop_is_the_python_loop_bit_for_bit(seed):
    """Random effects, commands (beyond 0..10 V, held and changing), step lengths, loads; a saved state
    restored halfway; step() between the batches."""
    rng = np.random.default_rng(seed)
    for case in range(6):
        params = PlantParams().with_values(**(_random_effects(rng) | NOISE_FREE))
        fast, slow = Plant(params, seed=1), _python_loop(Plant(params, seed=1))
        assert fast._run is not None and fast._advance_substeps is fast._run_replaces
        assert slow._advance_substeps is not slow._run_replaces
        saved = None
        for k in range(10):
            n = int(rng.integers(1, 90))
            u = rng.uniform(-1.0, 11.0, n) if k % 2 else np.repeat(rng.uniform(0.0, 10.0, n), 3)[:n]
            dt = float(rng.choice([0.1, 0.05, 0.2, 0.013]))
            load = None if k % 3 else rng.choice([44.0, 68.0, 10.0], n)
            got, expected = fast.step_many(u, dt, load_n=load), slow.step_many(u, dt, load_n=load)
            assert _same_readings(got, expected), (seed, case, k, params)
            assert _same(fast, slow), (seed, case, k)
            if k == 4:
                saved = fast.get_state()
            if k == 7:
                fast.set_state(saved)
                slow.set_state(saved)
            if k == 8:
                assert _bits(fast.step(6.5, 0.1)) == _bits(slow.step(6.5, 0.1))


@needs_compiled
def test_a_plant_with_an_effect_continues_from_the_state_of_one_without_it():
    """The diagnosis's checkpoints: the delay keeps its own (reset) memory, the rest is the state."""
    base = Plant(PlantParams().with_values(**NOISE_FREE), seed=0)
    base.step_many(5.0 + np.sin(np.arange(60) * 0.2), 0.1)
    state = base.get_state()
    params = PlantParams().with_values(**(NOISE_FREE | {"delay.delay_s": 0.25, "supply_variation.sag_mpa": 0.03,
                                                         "supply_variation.start_s": 7.0, "supply_variation.end_s": 9.0}))
    fast, slow = Plant(params), _python_loop(Plant(params))
    fast.set_state(state)
    slow.set_state(state)
    u = 6.0 + 2.0 * np.sin(np.arange(100) * 0.13)
    assert _same_readings(fast.step_many(u, 0.1), slow.step_many(u, 0.1))
    assert _same(fast, slow)


@needs_compiled
@pytest.mark.parametrize("values", [
    {"muscle.rest_length_mm": 1e-12},  # too many sub-steps of min_substep_s
    {"muscle.rest_length_mm": 1e-12, "delay.delay_s": 0.05},  # ... within a step cut by the delay
    {"muscle.rest_length_mm": 1e-12, "supply_variation.sag_mpa": 0.05, "supply_variation.start_s": 0.03,
     "supply_variation.end_s": 1.0},
], ids=["too-many", "too-many-delayed", "too-many-sag"])
def test_an_integration_that_fails_fails_alike(values):
    """The same error, at the same time, the plant left at the start of the failing step, the readings
    of the steps before it kept in measurement."""
    params = PlantParams().with_values(**(values | NOISE_FREE))
    fast, slow = Plant(params), _python_loop(Plant(params))
    u = 5.0 + 3.0 * np.sin(np.arange(50) * 0.13)
    errors = []
    for plant in (fast, slow):
        with pytest.raises(FloatingPointError, match="too many sub-steps") as info:
            plant.step_many(u, 0.1)
        errors.append(str(info.value))
    assert errors[0] == errors[1]
    assert _same(fast, slow)


@needs_compiled
@pytest.mark.parametrize("delay_s", [0.0, 0.15])
def test_a_broken_down_integration_fails_alike(delay_s):
    params = PlantParams().with_values(**(NOISE_FREE | ({"delay.delay_s": delay_s} if delay_s else {})))
    fast, slow = Plant(params), _python_loop(Plant(params))
    errors = []
    for plant in (fast, slow):
        plant.step_many([5.0, 6.0, 7.0], 0.1)
        plant.state = [0.5, math.nan, 10.0, 0.0, 0.0]  # as if the numbers had overflowed
        with pytest.raises(FloatingPointError, match=r"t = 0.3 s: the state \(0.5, nan, 10, 0, 0\)") as info:
            plant.step_many([7.5, 8.0], 0.1)
        errors.append(str(info.value))
    assert errors[0] == errors[1]
    assert fast.t_s == slow.t_s == pytest.approx(0.3) and fast.u_v == slow.u_v == 7.5
    assert fast.get_state()["effects"] == slow.get_state()["effects"]


def test_the_compiled_loop_runs_only_what_it_inlines():
    quiet = PlantParams().with_values(**NOISE_FREE).sensor
    every = PlantParams().with_values(**{"delay.delay_s": 0.1, "backlash.slack_mm": 0.5, "sensor_drift.offset_mm": 1.0,
                                         "dead_zone.width_v": 0.5, "load_mismatch.extra_n": 3.0,
                                         "supply_variation.ripple_mpa": 0.01, "input_map.out_at_0_v": 0.5})
    effects = effects_from_params(every)
    assert [type(e) for e in effects] == list(LIBRARY_ORDER)
    assert runnable(effects, quiet) and runnable([], quiet)
    assert not runnable([], PlantParams().sensor)  # sensor noise: the Python loop draws it
    assert not runnable(effects[::-1], quiet)  # another order
    assert not runnable([TransportDelay(DelayParams(delay_s=0.1))] * 2, quiet)  # twice

    class MyDrift(SensorDrift):
        pass

    assert not runnable([MyDrift(SensorDriftParams(offset_mm=1.0))], quiet)  # a subclass
    patched = Backlash(BacklashParams(slack_mm=0.4))
    patched.measurement = lambda t_s, l_mm: l_mm  # a hook replaced on the instance
    assert not runnable([patched], quiet)
    assert Plant(PlantParams().with_values(**NOISE_FREE), effects=[patched])._run is None
    assert Plant(PlantParams())._run is None  # the default rig's sensors are noisy
    assert (Plant(PlantParams().with_values(**NOISE_FREE))._run is not None) == COMPILED


def test_a_library_effect_changed_on_its_class_runs_the_python_loop(monkeypatch):
    """A notebook's patch of ValveDeadZone.valve_gate on the class must reach the compiled
    step_many as it reaches step, not be bypassed by an inlined copy of the library's gate (13.7 mm apart): a library class whose functions
    are not those it was imported with runs the Python loop, so both give the patched physics."""
    quiet = PlantParams().with_values(**NOISE_FREE, **{"dead_zone.center_v": 5.0, "dead_zone.width_v": 1.0})
    assert runnable(effects_from_params(quiet), quiet.sensor)
    monkeypatch.setattr(ValveDeadZone, "valve_gate", lambda self, t_s, u_v: 0.5)
    assert not runnable(effects_from_params(quiet), quiet.sensor)
    u = np.linspace(2.0, 8.0, 60)
    stepped = Plant(quiet)
    one_by_one = np.array([stepped.step(v, 0.1).l_mm for v in u])
    np.testing.assert_array_equal(Plant(quiet).step_many(u, 0.1)[0], one_by_one)
    monkeypatch.undo()
    assert runnable(effects_from_params(quiet), quiet.sensor)
