"""The effects library (fmu_plant/effect_library.py): off by default, each acts as its physics says,
exact breakpoints, state save/restore."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fmu_plant import Plant, PlantParams
from fmu_plant.effect_library import InputMap, effects_from_params, input_map_v
from fmu_plant.parameters import InputMapParams
from fmu_plant.open_loop import run_open_loop

QUIET = {"sensor.encoder_noise_std_mm": 0.0, "sensor.encoder_resolution_mm": 0.0}


def _run(overrides: dict, signal=lambda t: 5 + 3 * math.sin(2 * math.pi * 0.1 * t), duration=30.0, ts=0.1):
    plant = Plant(PlantParams().with_values(**QUIET, **overrides), seed=0)
    return run_open_loop(plant, signal, duration_s=duration, ts_s=ts)


def test_every_effect_is_off_by_default_and_the_default_plant_is_unchanged():
    assert effects_from_params(PlantParams()) == []
    assert Plant().effects == ()
    # an identity input map with knots elsewhere is left out too
    assert effects_from_params(PlantParams().with_values(**{
        "input_map.knot1_in_v": 1.7, "input_map.knot1_out_v": 1.7, "input_map.knot2_in_v": 8.2,
        "input_map.knot2_out_v": 8.2})) == []


def test_a_whole_sample_delay_equals_the_command_shifted_by_one_sample():
    sig = lambda t: 5 + 3 * math.sin(2 * math.pi * 0.1 * t)  # noqa: E731
    delayed = _run({"delay.delay_s": 0.1}, sig)
    shifted = _run({}, lambda t: 0.0 if t < 0.05 else sig(t - 0.1))
    assert np.max(np.abs(delayed["l_mm"] - shifted["l_mm"])) < 1e-9


def test_a_fractional_delay_equals_a_finer_sampled_shift():
    """0.25 s at Ts = 0.1 s (breakpoints inside steps) == a 0.05 s-sampled run with the command 5 samples late."""
    levels = [2.0, 7.0, 4.0, 8.0, 3.0]
    step = lambda t: levels[min(int(t // 5.0), 4)]  # noqa: E731
    coarse = _run({"delay.delay_s": 0.25}, step, duration=25.0, ts=0.1)
    fine = _run({}, lambda t: 0.0 if t < 0.25 - 1e-9 else step(t - 0.25), duration=25.0, ts=0.05)
    assert np.max(np.abs(coarse["l_mm"] - fine["l_mm"][::2])) < 0.02  # solver tolerance, not a sample (~ 5 mm)
    undelayed = _run({}, step, duration=25.0, ts=0.1)
    assert np.max(np.abs(coarse["l_mm"] - undelayed["l_mm"])) > 1.0


def test_dead_zone_shuts_the_muscle_in():
    """Step into the band: the pressure stays where it was (only the leak moves it), outside it follows."""
    signal = lambda t: 7.0 if t < 10.0 else 5.0  # noqa: E731
    free = _run({}, signal, duration=20.0)
    dz = _run({"dead_zone.center_v": 5.0, "dead_zone.width_v": 1.0}, signal, duration=20.0)
    assert np.allclose(free["l_mm"][:100], dz["l_mm"][:100], atol=1e-9)
    drop_free = free["l_mm"][100] - free["l_mm"][110]  # the first second after the step
    drop_dz = dz["l_mm"][100] - dz["l_mm"][110]
    assert drop_free > 5.0 and abs(drop_dz) < 0.2 * drop_free


def test_supply_sag_acts_only_in_its_window():
    sag = {"supply_variation.sag_mpa": 0.04, "supply_variation.start_s": 10.0, "supply_variation.end_s": 20.0}
    base = _run({}, duration=40.0)
    sagged = _run(sag, duration=40.0)
    assert np.array_equal(base["l_mm"][:101], sagged["l_mm"][:101])
    assert np.max(base["l_mm"][110:200] - sagged["l_mm"][110:200]) > 2.0  # less contraction during the sag


def test_the_sag_recovers_over_its_own_ramp():
    """``recovery_ramp_s`` sets the recovery alone; negative (the default) is ``ramp_s``, as before."""
    from fmu_plant.effect_library import SupplyPressureVariation
    from fmu_plant.parameters import SupplyVariationParams
    same = SupplyPressureVariation(SupplyVariationParams(sag_mpa=0.04, start_s=10.0, end_s=20.0, ramp_s=2.0))
    own = SupplyPressureVariation(SupplyVariationParams(sag_mpa=0.04, start_s=10.0, end_s=20.0, ramp_s=2.0,
                                                        recovery_ramp_s=8.0))
    assert same.sag_mpa(11.0) == own.sag_mpa(11.0) == pytest.approx(0.02)  # the fall: 2 s either way
    assert same.sag_mpa(21.0) == pytest.approx(0.02) and same.sag_mpa(22.0) == 0.0
    assert own.sag_mpa(22.0) == pytest.approx(0.03) and own.sag_mpa(26.0) == pytest.approx(0.01)
    assert own.sag_mpa(28.0) == 0.0
    assert own.breakpoints(0.0, 100.0, 5.0) == [10.0, 12.0, 20.0, 28.0]
    sag = {"supply_variation.sag_mpa": 0.04, "supply_variation.start_s": 10.0, "supply_variation.end_s": 20.0}
    assert np.array_equal(_run(sag, duration=30.0)["l_mm"],
                          _run({**sag, "supply_variation.recovery_ramp_s": 1.0}, duration=30.0)["l_mm"])


def test_a_sag_said_to_hold_over_a_stretch_gives_one_value_throughout_it():
    """``held`` lets the plant sample the supply once per stretch: wherever it says True, every
    instant of the stretch (its ends, their neighbouring floats, points between) must give the same
    bits, and it must say True on the plateau and before and after the sag, where the time goes."""
    from fmu_plant.effect_library import SupplyPressureVariation
    from fmu_plant.parameters import SupplyVariationParams
    rng = np.random.default_rng(3)
    said = 0
    for _ in range(300):
        start = float(rng.choice([0.0, 10.0, rng.uniform(0.0, 50.0)]))
        p = SupplyVariationParams(sag_mpa=float(rng.uniform(0.001, 0.2)), start_s=start,
                                  end_s=start + float(rng.choice([0.0, 3.0, rng.uniform(0.0, 40.0)])),
                                  ramp_s=float(rng.choice([0.0, 1.0, 0.3, rng.uniform(0.0, 5.0)])),
                                  recovery_ramp_s=float(rng.choice([-1.0, 0.0, rng.uniform(0.0, 5.0)])))
        sag = SupplyPressureVariation(p)
        corners = sag.breakpoints(-1.0, 1e9, 5.0)
        for _ in range(40):
            t0 = float(rng.choice([*corners, rng.uniform(-1.0, 100.0)]))
            t1 = t0 + float(rng.choice([1e-9, 0.01, 0.1, rng.uniform(0.0, 2.0)]))
            if not sag.held(t0, t1):
                continue
            said += 1
            ts = [t0, t1, np.nextafter(t0, np.inf), np.nextafter(t1, -np.inf), *rng.uniform(t0, t1, 8)]
            values = {sag.supply_pressure(float(t), 0.25) for t in ts}
            assert len(values) == 1, (p, t0, t1, values)
        plateau = p.start_s + p.ramp_s + 0.5
        if plateau + 0.1 <= p.end_s:
            assert sag.held(plateau, plateau + 0.1)
        assert sag.held(p.start_s - 0.2, p.start_s - 0.1) and sag.held(p.end_s + p.recovery_s + 0.5, 1e6)
    assert said > 4000
    rippled = SupplyPressureVariation(SupplyVariationParams(ripple_mpa=0.01))
    assert not rippled.held(0.0, 0.1)


def test_load_mismatch_is_the_same_as_a_heavier_load():
    a = _run({"load_mismatch.extra_n": 10.0})
    b = _run({"load.load_n": 54.0})
    assert np.max(np.abs(a["l_mm"] - b["l_mm"])) < 1e-9


def test_sensor_drift_and_backlash_act_on_the_reading_only():
    base = _run({})
    drift = _run({"sensor_drift.offset_mm": 0.5, "sensor_drift.rate_mm_per_min": 1.2})
    assert np.allclose(drift["l_mm"] - base["l_mm"], 0.5 + 1.2 / 60 * base["t_s"], atol=1e-9)
    assert np.array_equal(drift["p_mpa"], base["p_mpa"])
    play = _run({"backlash.slack_mm": 2.0})
    gap = play["l_mm"] - base["l_mm"]
    assert np.max(np.abs(gap)) <= 1.0 + 1e-9 and np.max(np.abs(gap)) > 0.9
    assert np.array_equal(play["p_mpa"], base["p_mpa"])


@pytest.mark.parametrize("effects", [
    {"delay.delay_s": 0.17, "backlash.slack_mm": 0.6, "dead_zone.width_v": 0.5},
    "input_map",  # the band below, with a delay
], ids=["delay-backlash-dead_zone", "input_map-delay"])
def test_state_with_effects_restores_bit_identically(effects):
    if effects == "input_map":
        effects = {**BAND, "delay.delay_s": 0.13}
    plant = Plant(PlantParams().with_values(**effects), seed=3)
    for k in range(40):
        plant.step(5 + 3 * math.sin(0.3 * k), 0.1)
    saved = plant.get_state()
    ahead = [plant.step(5 + 2 * math.cos(0.2 * k), 0.1).l_mm for k in range(60)]
    plant.set_state(saved)
    again = [plant.step(5 + 2 * math.cos(0.2 * k), 0.1).l_mm for k in range(60)]
    assert ahead == again


@pytest.mark.parametrize("saved_with", [
    {"backlash.slack_mm": 2.0, "sensor_drift.offset_mm": 1.0},
    {"backlash.slack_mm": 2.0},
])
def test_a_state_restores_into_a_plant_with_an_extra_effect_ahead_by_name(saved_with):
    """A checkpoint of a plant with a play (and a drift) continues in a plant that also has a valve band,
    which comes first in the effect order: the play keeps its saved slider, and the plant steps as the
    one it was saved from until the band's commands are reached (the diagnosis's window searches)."""
    cmd = [6.0 + 0.5 * math.sin(0.3 * k) for k in range(80)]  # never in the band at 2.5 +- 0.25 V
    plant = Plant(PlantParams().with_values(**saved_with), seed=0)
    for u in cmd[:50]:
        plant.step(u, 0.1)
    saved, slider_mm = plant.get_state(), plant.effects[0].y_mm
    assert slider_mm > 10.0  # the play's slider has moved from its start
    ahead = [plant.step(u, 0.1).l_mm for u in cmd[50:]]
    extra = Plant(PlantParams().with_values(**saved_with, **{"dead_zone.center_v": 2.5, "dead_zone.width_v": 0.5}),
                  seed=0)
    assert [e.name for e in extra.effects][0] == "valve_dead_zone"
    extra.set_state(saved)
    assert extra.effects[1].y_mm == slider_mm
    assert [extra.step(u, 0.1).l_mm for u in cmd[50:]] == ahead


def test_a_state_with_an_effect_the_plant_lacks_is_refused_by_name():
    saved = Plant(PlantParams().with_values(**{"backlash.slack_mm": 2.0}), seed=0).get_state()
    with pytest.raises(ValueError, match="effect 'backlash', which this plant does not have"):
        Plant(PlantParams(), seed=0).set_state(saved)


def test_effect_parameters_are_validated():
    with pytest.raises(ValueError, match="end_s"):
        PlantParams().with_values(**{"supply_variation.start_s": 50.0, "supply_variation.end_s": 10.0})
    with pytest.raises(ValueError, match="delay_s"):
        PlantParams().with_values(**{"delay.delay_s": -0.1})
    with pytest.raises(ValueError, match="recovery_ramp_s"):
        PlantParams().with_values(**{"supply_variation.recovery_ramp_s": -2.0})


#: A command dead band of 1.2 V centred at 5 V, the outer parts of slope 1.
BAND = {"input_map.out_at_0_v": 0.6, "input_map.knot1_in_v": 4.4, "input_map.knot1_out_v": 5.0,
        "input_map.knot2_in_v": 5.6, "input_map.knot2_out_v": 5.0, "input_map.out_at_10_v": 9.4}


def _map(overrides: dict) -> InputMapParams:
    return PlantParams().with_values(**overrides).input_map


def test_input_map_values_on_a_grid():
    grid = np.linspace(0.0, 10.0, 101)
    assert [input_map_v(u, InputMapParams()) for u in grid] == pytest.approx(grid, abs=1e-12)
    band = np.array([input_map_v(u, _map(BAND)) for u in grid])
    expected = np.where(grid < 4.4, grid + 0.6, np.where(grid > 5.6, grid - 0.6, 5.0))
    assert band == pytest.approx(expected, abs=1e-12)
    # gain 0.85, offset +0.5 V
    gain = _map({"input_map.out_at_0_v": 0.5, "input_map.knot1_in_v": 2.0, "input_map.knot1_out_v": 2.2,
                 "input_map.knot2_in_v": 6.0, "input_map.knot2_out_v": 5.6, "input_map.out_at_10_v": 9.0})
    assert [input_map_v(u, gain) for u in grid] == pytest.approx(0.85 * grid + 0.5, abs=1e-12)
    # commands outside 0..10 V continue the outer segments, and the result is clipped to 0..10 V
    assert input_map_v(-0.3, _map(BAND)) == pytest.approx(0.3)
    assert input_map_v(-1.0, _map(BAND)) == 0.0 and input_map_v(11.0, _map(BAND)) == 10.0
    steep = _map({"input_map.out_at_0_v": 0.0, "input_map.knot1_in_v": 1.0, "input_map.knot1_out_v": 2.0,
                  "input_map.knot2_in_v": 4.0, "input_map.knot2_out_v": 9.0, "input_map.out_at_10_v": 10.0})
    assert input_map_v(10.5, steep) == 10.0
    assert isinstance(effects_from_params(PlantParams().with_values(**BAND))[0], InputMap)


def test_input_map_is_the_same_as_the_mapped_command():
    """The plant with the map == the plant without it, driven by the mapped command."""
    sig = lambda t: 5 + 3 * math.sin(2 * math.pi * 0.1 * t)  # noqa: E731
    mapped = _run(BAND, sig)
    by_hand = _run({}, lambda t: input_map_v(sig(t), _map(BAND)))
    assert np.array_equal(mapped["l_mm"], by_hand["l_mm"])
    assert np.max(np.abs(mapped["l_mm"] - _run({}, sig)["l_mm"])) > 5.0
    # after a transport delay the map acts on the delayed command (it comes first in the chain)
    delayed = PlantParams().with_values(**BAND, **{"delay.delay_s": 0.2, "dead_zone.width_v": 0.4})
    assert [e.name for e in effects_from_params(delayed)] == ["transport_delay", "input_map", "valve_dead_zone"]


def test_input_map_parameters_are_validated_naming_the_field():
    for overrides, field in [({"input_map.knot1_in_v": 0.0}, "knot1_in_v"),
                             ({"input_map.knot2_in_v": 10.0}, "knot2_in_v"),
                             ({"input_map.knot1_in_v": 7.0}, "knot2_in_v"),
                             ({"input_map.out_at_0_v": -0.1}, "out_at_0_v"),
                             ({"input_map.knot1_out_v": 10.5}, "knot1_out_v"),
                             ({"input_map.knot1_out_v": 8.0}, "knot2_out_v"),
                             ({"input_map.out_at_10_v": 6.0}, "out_at_10_v"),
                             ({"input_map.out_at_0_v": float("nan")}, "out_at_0_v")]:
        with pytest.raises(ValueError, match=rf"input_map\.{field}"):
            PlantParams().with_values(**overrides)
    PlantParams().with_values(**BAND)  # a flat stretch is monotone (non-decreasing)


