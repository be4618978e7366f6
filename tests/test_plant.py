"""The physical plant: determinism, sub-stepping, physical bounds, lifecycle, effects, errors."""

import copy
import math
import re
import pickle

import numpy as np
import pytest

from fmu_plant import Effect, Plant, PlantParams
from fmu_plant.parameters import CV_TO_SI_WATER


def _run(plant, u, n, dt=0.1):
    return np.array([plant.step(u(k * dt) if callable(u) else u, dt).l_mm for k in range(n)])


def sine(t):
    return 5 + 3 * math.sin(2 * math.pi * 0.1 * t)


def test_same_seed_is_bit_identical_and_other_seed_differs():
    a = _run(Plant(seed=3), sine, 300)
    b = _run(Plant(seed=3), sine, 300)
    c = _run(Plant(seed=4), sine, 300)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.max(np.abs(a - c)) < 0.2  # only the noise differs


def test_reset_restarts_the_same_run():
    p = Plant(seed=1)
    a = _run(p, sine, 200)
    p.reset()
    assert p.t_s == 0.0 and p.l_mm == 0.0
    assert np.array_equal(a, _run(p, sine, 200))


@pytest.mark.slow
@pytest.mark.parametrize("dt", [0.001, 0.01, 0.1, 0.5, 1.0])
def test_any_communication_step_gives_the_same_trajectory(dt):
    """Stable and consistent for communication steps from 1 ms to 1 s (true state, no noise)."""
    quiet = PlantParams().with_values(**{"sensor.encoder_noise_std_mm": 0.0})
    ref = Plant(quiet)
    fine = {}
    for k in range(int(round(30 / 0.001))):
        ref.step(6.0 if k * 0.001 < 10 else 3.0, 0.001)
        fine[round((k + 1) * 0.001, 6)] = ref.l_mm
    p = Plant(quiet)
    worst = 0.0
    for k in range(int(round(30 / dt))):
        p.step(6.0 if k * dt < 10 else 3.0, dt)
        assert math.isfinite(p.l_mm) and 0.0 <= p.l_mm < 150.0
        worst = max(worst, abs(p.l_mm - fine[round((k + 1) * dt, 6)]))
    assert worst < 0.05, worst


def test_pressure_and_flow_stay_physical():
    p = Plant(seed=0)
    ps = p.params.supply.supply_pressure_mpa
    q_limit = 1.6 * CV_TO_SI_WATER * math.sqrt(ps * 1e6) * 6e4  # Cv 1.6 at the full supply drop [L/min]
    rng = np.random.default_rng(0)
    for _ in range(600):
        p.step(float(rng.uniform(0, 10)), 0.1)
        assert -1e-6 <= p.p_mpa <= ps + 1e-6
        q_in, q_out = p.flows_l_min()
        assert abs(q_in) <= q_limit and abs(q_out) <= q_limit
        assert 0.0 <= p.l_mm < 150.0


def test_heavier_load_lowers_the_muscle_and_load_may_change_during_a_run():
    light, heavy = Plant(seed=0), Plant(seed=0)
    heavy.update(load_n=68.0)
    _run(light, 5.0, 300), _run(heavy, 5.0, 300)
    assert light.l_mm - heavy.l_mm > 5.0
    # A load step during a run: friction holds part of it (the step moves down the falling branch).
    before = light.l_mm
    light.update(load_n=68.0)
    _run(light, 5.0, 300)
    assert before - light.l_mm > 1.0
    assert light.load_n == 68.0


def test_lower_supply_pressure_lowers_the_muscle():
    a, b = Plant(seed=0), Plant(seed=0)
    b.update(supply_pressure_mpa=0.2)
    _run(a, 6.0, 300), _run(b, 6.0, 300)
    assert a.l_mm - b.l_mm > 2.0


def test_get_set_state_replays_bit_identically():
    p = Plant(seed=7)
    _run(p, sine, 100)
    saved = p.get_state()
    a = _run(p, sine, 100)
    p.set_state(saved)
    assert np.array_equal(a, _run(p, sine, 100))


@pytest.mark.parametrize("how", [copy.copy, copy.deepcopy, lambda p: pickle.loads(pickle.dumps(p))],
                         ids=["copy", "deepcopy", "pickle"])
def test_a_copied_or_unpickled_plant_steps_on_alone_bit_for_bit(how):
    """A notebook branching an experiment: the copy and the original, stepped with different commands,
    each go on as it would alone (a dead band acts through the valve gate, which the sub-step's closure
    holds: a shared closure would move both by millimetres), and an own effect is copied with its state."""
    params = PlantParams().with_values(**{"dead_zone.width_v": 2.0})
    rng = np.random.default_rng(3)
    before, a, b = (rng.uniform(0.0, 10.0, 60) for _ in range(3))

    def run(plant, commands):
        return [plant.step(u, 0.1).l_mm for u in commands]

    p = Plant(params, seed=1, effects=[_Ramp()])
    run(p, before)
    alone_a, alone_b = Plant(params, seed=1, effects=[_Ramp()]), Plant(params, seed=1, effects=[_Ramp()])
    for alone in (alone_a, alone_b):
        run(alone, before)
    q = how(p)
    assert q is not p and q.effects[-1] is not p.effects[-1]
    got_p, got_q = [], []
    for u, v in zip(a, b):  # interleaved, as two branches of a notebook would be stepped
        got_p.append(p.step(u, 0.1).l_mm)
        got_q.append(q.step(v, 0.1).l_mm)
    assert got_p == run(alone_a, a) and got_q == run(alone_b, b)
    assert max(abs(x - y) for x, y in zip(got_p, got_q)) > 1.0  # the branches did differ
    assert type(how(_OwnPlant(seed=2))) is _OwnPlant  # a subclass stays one


class _OwnPlant(Plant):
    """A user's subclass, with the plant's arguments."""


class _Ramp(Effect):
    """An own effect with a state: a reading offset that grows by 0.01 mm a reading."""
    name = "reading_ramp"

    def __init__(self):
        self.readings = 0

    def measurement(self, t_s, l_mm):
        self.readings += 1
        return l_mm + 0.01 * self.readings

    def get_state(self):
        return {"readings": self.readings}

    def set_state(self, state):
        self.readings = int(state["readings"])


class _Offset(Effect):
    name = "command_offset"

    def valve_command(self, t_s, u_v):
        return u_v + 1.0


def test_identity_effect_changes_nothing_and_an_effect_plugs_into_a_port():
    base = _run(Plant(seed=0), 4.0, 200)
    assert np.array_equal(base, _run(Plant(seed=0, effects=[Effect()]), 4.0, 200))
    shifted = _run(Plant(seed=0, effects=[_Offset()]), 4.0, 200)
    reference = _run(Plant(seed=0), 5.0, 200)
    assert np.array_equal(shifted, reference)


def test_a_hook_set_on_an_effect_instance_acts_as_one_in_its_class():
    # the plant calls only the hooks an effect replaces: on the instance counts too
    offset = Effect()
    offset.valve_command = lambda t_s, u_v: u_v + 1.0
    assert np.array_equal(_run(Plant(seed=0, effects=[offset]), 4.0, 200), _run(Plant(seed=0), 5.0, 200))


class _SupplyRamp(Effect):
    """The supply falls by 0.02 MPa/s: a port signal that changes within a step."""

    name = "supply_ramp"

    def supply_pressure(self, t_s, p_mpa):
        return p_mpa - 0.02 * t_s


class _HeldSupplyRamp(_SupplyRamp):
    def held(self, t0_s, t1_s):
        return True  # wrongly: to show that held decides the sampling


def test_ports_that_vary_within_a_step_are_sampled_at_every_sub_step_unless_declared_held():
    # 1-s steps: many sub-steps each, so sampling once per step visibly changes the trajectory
    every = _run(Plant(seed=0, effects=[_SupplyRamp()]), 9.0, 12, dt=1.0)
    once = _run(Plant(seed=0, effects=[_HeldSupplyRamp()]), 9.0, 12, dt=1.0)
    assert np.max(np.abs(every - once)) > 0.02
    # a held effect whose port hook was replaced on the instance is sampled at every sub-step again
    patched = _HeldSupplyRamp()
    patched.supply_pressure = lambda t_s, p_mpa: p_mpa - 0.02 * t_s
    assert np.array_equal(_run(Plant(seed=0, effects=[patched]), 9.0, 12, dt=1.0), every)


def test_a_held_effect_is_sampled_once_per_stretch_between_breakpoints():
    from fmu_plant.effect_library import TransportDelay
    from fmu_plant.parameters import DelayParams

    calls = []

    class CountedDelay(TransportDelay):
        def valve_command(self, t_s, u_v):
            calls.append(t_s)
            return super().valve_command(t_s, u_v)

    plant = Plant(seed=0, effects=[CountedDelay(DelayParams(delay_s=0.25))])
    for k in range(20):
        plant.step(4.0 + (k % 2), 0.1)  # a new command every step: one delayed change inside each step
    # from the third step (0.2 .. 0.3 s) on, each is cut once, where the change made 0.25 s before
    # arrives: two stretches, one sampling each (the sub-steps within them sample nothing)
    assert calls[:4] == pytest.approx([0.0, 0.1, 0.2, 0.25], abs=1e-15) and len(calls) == 2 + 2 * 18


def test_rate_dependence_resists_fast_motion_and_can_be_switched_off():
    def swing(rate_gain):
        prm = PlantParams().with_values(**{"friction.rate_gain": rate_gain, "sensor.encoder_noise_std_mm": 0.0})
        p = Plant(prm)
        t = np.arange(600) * 0.1
        l = _run(p, lambda tt: 5 + 2 * math.sin(2 * math.pi * 0.2 * tt), 600)
        keep = t > 20
        return np.ptp(l[keep])
    # friction that grows with speed resists fast motion: a smaller 0.2 Hz swing with it on
    assert swing(0.0) - swing(1.5) > 1.0


@pytest.mark.parametrize("u, dt, match", [(math.nan, 0.1, "u_v"), (math.inf, 0.1, "u_v"),
                                          (5.0, 0.0, "dt_s"), (5.0, -1.0, "dt_s"),
                                          (5.0, math.nan, "dt_s"), (5.0, 1e6, "dt_s"), ("x", 0.1, "u_v")])
def test_bad_step_arguments_raise_and_leave_the_state_alone(u, dt, match):
    p = Plant(seed=0)
    _run(p, 6.0, 10)
    before = p.get_state()
    with pytest.raises(ValueError, match=match):
        p.step(u, dt)
    assert p.get_state() == before


@pytest.mark.parametrize("kw, match", [({"load_n": -1.0}, "load_n"), ({"load_n": math.nan}, "load_n"),
                                       ({"supply_pressure_mpa": 2.0}, "supply_pressure_mpa"),
                                       # numbers only: float() also takes "68" (68 N) and True (1 N)
                                       ({"load_n": "68"}, "load_n must be a number, got str '68'"),
                                       ({"load_n": True}, "load_n must be a number, got bool True"),
                                       ({"load_n": bytearray(b"68")}, "load_n must be a number, got bytearray"),
                                       ({"load_n": np.array("68")}, "load_n must be a number, got ndarray"),
                                       ({"supply_pressure_mpa": np.bool_(True)}, "supply_pressure_mpa must be a number"),
                                       ({"supply_pressure_mpa": np.array(True)}, "supply_pressure_mpa must be a number")])
def test_bad_updates_raise(kw, match):
    with pytest.raises(ValueError, match=match):
        Plant().update(**kw)


def test_bad_parameters_name_the_field():
    with pytest.raises(ValueError, match="cv_max"):
        PlantParams().with_values(**{"valve.cv_max": -1.0})
    with pytest.raises(ValueError, match="nonsense"):
        PlantParams().with_values(**{"valve.nonsense": 1.0})
    with pytest.raises(ValueError, match="braid_angle_deg"):
        PlantParams().with_values(**{"muscle.braid_angle_deg": math.inf})


def test_parameters_round_trip_through_a_dict():
    p = PlantParams().with_values(**{"load.load_n": 68.0, "friction.rate_gain": 0.0})
    assert PlantParams.from_dict(p.to_dict()) == p


def test_docs_list_every_parameter_with_its_value():
    """docs/plant.md's parameter table is the dataclasses' defaults (regenerate it when tuning)."""
    from dataclasses import fields
    from pathlib import Path

    text = Path(__file__).resolve().parents[1].joinpath("docs", "plant.md").read_text(encoding="utf-8")
    p = PlantParams()
    for group in fields(p):
        sub = getattr(p, group.name)
        for f in fields(sub):
            assert f"| `{group.name}.{f.name}` | {getattr(sub, f.name):g} |" in text, f"{group.name}.{f.name}"


#: Every library effect at once, each with a value that acts in a 40-s run (the delay cuts every step).
_ALL_EFFECTS = {"delay.delay_s": 0.13, "dead_zone.center_v": 4.0, "dead_zone.width_v": 0.5,
                "supply_variation.sag_mpa": 0.03, "supply_variation.start_s": 15.0, "supply_variation.end_s": 25.0,
                "load_mismatch.extra_n": 5.0, "backlash.slack_mm": 0.5, "sensor_drift.rate_mm_per_min": 1.0,
                "input_map.out_at_0_v": 0.6, "input_map.out_at_10_v": 9.4}


@pytest.mark.parametrize("values", [{}, _ALL_EFFECTS, _ALL_EFFECTS | {"sensor.encoder_noise_std_mm": 0.0,
                                                                     "sensor.pressure_noise_std_mpa": 0.0}],
                         ids=["nominal", "every-effect", "every-effect-noise-free"])
def test_step_many_is_step_in_a_loop_bit_for_bit(values):
    """The batch loop is a speed path, not another model: the same readings, state, noise draws and
    effect states as one step() per command, with the load changing where load_n says (noise-free, its
    loop is the compiled one where that is installed)."""
    params = PlantParams().with_values(**values)
    rng = np.random.default_rng(5)
    u = np.clip(5.0 + np.cumsum(rng.normal(0.0, 0.4, 400)), -1.0, 11.0)  # also beyond the valve's range
    load = np.where(np.arange(400) < 200, 44.0, 68.0)
    one = Plant(params, seed=9)
    by_step = []
    for u_k, w_k in zip(u, load):
        if w_k != one.load_n:
            one.update(load_n=w_k)
        by_step.append(one.step(u_k, 0.1))
    many = Plant(params, seed=9)
    l_mm, p_mpa = many.step_many(u[:150], 0.1, load_n=load[:150])
    l2, p2 = many.step_many(list(u[150:]), 0.1, load_n=list(load[150:]))
    assert np.array_equal(np.concatenate([l_mm, l2]), [m.l_mm for m in by_step])
    assert np.array_equal(np.concatenate([p_mpa, p2]), [m.p_mpa for m in by_step])
    assert many.measurement == by_step[-1] and many.state == one.state
    assert many.get_state() == one.get_state()


@pytest.mark.parametrize("kw,match", [
    ({"u_v": [5.0, math.nan]}, r"u_v\[1\] must be finite, got nan"),
    ({"u_v": [[5.0]]}, r"u_v must be a sequence of numbers \(one-dimensional\), got shape \(1, 1\)"),
    ({"u_v": ["five"]}, r"u_v must be a sequence of numbers"),
    ({"dt_s": 0.0}, r"dt_s must be within"),
    ({"load_n": [44.0, 44.0, 600.0]}, r"load_n\[2\] must be within 0..500 N, got 600.0"),
    ({"load_n": [44.0, math.inf, 44.0]}, r"load_n\[1\] must be finite"),
    ({"load_n": [44.0]}, r"load_n has 1 values for 3 commands"),
])
def test_step_many_refuses_bad_input_by_index_and_leaves_the_plant_alone(kw, match):
    plant = Plant(seed=2)
    plant.step(6.0, 0.1)
    before = plant.get_state()
    args = {"u_v": [5.0, 6.0, 7.0], "dt_s": 0.1, **kw}
    with pytest.raises(ValueError, match=match):
        plant.step_many(args.pop("u_v"), args.pop("dt_s"), **args)
    assert plant.get_state() == before


def test_step_many_holds_one_load_given_as_a_number():
    """``load_n=68.0`` is 68 N throughout, bit for bit as one value per command; what is neither a
    number nor one per command is refused saying what it takes."""
    u = np.linspace(3.0, 8.0, 60)
    by_number = Plant(seed=4)
    l_mm, p_mpa = by_number.step_many(u, 0.1, load_n=68.0)
    by_values = Plant(seed=4)
    l2, p2 = by_values.step_many(u, 0.1, load_n=np.full(60, 68.0))
    assert by_number.load_n == 68.0 and np.array_equal(l_mm, l2) and np.array_equal(p_mpa, p2)
    assert not np.array_equal(l_mm, Plant(seed=4).step_many(u, 0.1, load_n=44.0)[0])  # the load acts
    plant = Plant(seed=4)
    for bad, match in ((np.ones((60, 1)), r"load_n must be a number, or one number per command \(one-dimensional\), "
                                          r"got shape \(60, 1\)"),
                       ("44", r"load_n must be a number, or one number per command, got '44'"),
                       (600.0, r"load_n must be within 0..500 N, got 600.0"),
                       (math.nan, r"load_n must be within 0..500 N, got nan")):
        with pytest.raises(ValueError, match=match):
            plant.step_many(u, 0.1, load_n=bad)
    assert plant.t_s == 0.0


def test_step_many_of_no_commands_changes_nothing():
    plant = Plant(seed=2)
    l_mm, p_mpa = plant.step_many([], 0.1)
    assert l_mm.shape == p_mpa.shape == (0,) and plant.t_s == 0.0 and plant.measurement.t_s == 0.0


def test_with_values_takes_numpy_scalars_as_the_numbers_they_hold():
    """``for load in np.arange(40, 70, 4): params.with_values(**{"load.load_n": load})`` must not be refused."""
    import numpy as np

    from fmu_plant import PlantParams

    p = PlantParams().with_values(**{"load.load_n": np.int64(68), "valve.cv_max": np.float32(1.25),
                                     "friction.base_n": np.array(7.5)})
    assert (p.load.load_n, p.valve.cv_max, p.friction.base_n) == (68, 1.25, 7.5)
    assert type(p.load.load_n) is int and type(p.valve.cv_max) is float
    assert p == PlantParams().with_values(**{"load.load_n": 68, "valve.cv_max": 1.25, "friction.base_n": 7.5})


def test_a_load_below_the_braid_lock_is_warned_by_the_direct_runs_as_by_the_plant_fmu():
    """The plant FMU says that a load under muscle.braid_lock_force_n makes the model's muscle contract
    by itself; `tapmuscle record --load 25` and tm.simulate must say so too. Every direct run warns once
    at its end, naming the lightest load, and not at the paper's loads or with a lock set below the load."""
    import warnings

    import tapmuscle as tm

    def said(**kwargs):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            run = kwargs.pop("run")(**kwargs)
        return [str(w.message) for w in caught if "braid lock" in str(w.message)], run

    light, _ = said(run=tm.simulate, command="step", duration_s=2.0, load_n=25.0)
    assert len(light) == 1 and light[0].startswith("load_n = 25 N is below the braid lock's 40 N"), light
    closed, _ = said(run=tm.simulate_closed_loop, duration_s=2.0, load_n=lambda t: 44.0 if t < 1.0 else 30.0)
    assert len(closed) == 1 and "30 N is below the braid lock's 40 N" in closed[0]
    assert said(run=tm.simulate, command="step", duration_s=1.0, load_n=44.0)[0] == []
    unlocked = PlantParams().with_values(**{"muscle.braid_lock_force_n": 20.0})
    assert said(run=tm.simulate, command="step", duration_s=1.0, load_n=25.0, params=unlocked)[0] == []


@pytest.mark.parametrize("u_v", [3.0, 7.0])
def test_the_valve_flows_balance_the_pressure_at_rest(u_v):
    """Settled under a held command the muscle's pressure is steady: what the supply side lets in the
    drain side lets out (mass balance; 3 and 7 V, where the spool is not symmetric)."""
    from fmu_plant import Plant
    p = Plant(seed=0)
    for _ in range(600):
        p.step(u_v, 0.1)                                 # settled: dp/dt = 0, dl/dt = 0
    q_in, q_out = p.flows_l_min()
    assert q_in > 0 and q_in == pytest.approx(q_out, rel=1e-3)


def test_a_breakdown_names_the_parameters_off_their_defaults_and_a_drain_above_the_supply_is_refused():
    """A plant whose numbers break down must not say 'extreme parameters?' and leave the user to guess which:
    the message names those off their defaults. A drain above the supply (the drain is the
    atmosphere) must not be accepted and run (1 MPa drain: 132 mm, 0.99 MPa at 0 V)."""
    from fmu_plant import Plant, PlantParams

    plant = Plant(PlantParams().with_values(**{"friction.rate_ref_mm_s": 1e-300, "friction.rate_exponent": 2.0}))
    with pytest.raises(FloatingPointError, match=r"went non-finite at the shortest sub-step \(extreme parameters\? off "
                                                 r"their defaults: friction\.rate_ref_mm_s=1e-300, "
                                                 r"friction\.rate_exponent=2\)"):
        plant.step(10.0, 0.1)
    assert plant.t_s == 0.0
    with pytest.raises(ValueError, match=r"supply\.drain_pressure_mpa \(0\.5\) must not exceed supply_pressure_mpa "
                                         r"\(0\.2\): the drain is the atmosphere"):
        PlantParams().with_values(**{"supply.drain_pressure_mpa": 0.5, "supply.supply_pressure_mpa": 0.2})
    PlantParams().with_values(**{"supply.drain_pressure_mpa": 0.25})  # equal to the supply: allowed


def test_every_parameters_bounds_hold_its_default_and_refuse_what_lies_beyond():
    """PlantParams.bounds is what the dataclasses enforce: the default inside, a value just past a
    finite bound refused by with_values, naming the parameter."""
    p = PlantParams()
    for key, value in p.dotted().items():
        lo, hi = PlantParams.bounds(key)
        assert lo <= value <= hi, key
        for beyond in (hi + max(1e-9, 1e-6 * abs(hi)), lo - max(1e-9, 1e-6 * abs(lo))):
            if math.isfinite(beyond):
                with pytest.raises(ValueError, match=re.escape(key)):
                    p.with_values(**{key: beyond})
        assert PlantParams.unit(key), key
    with pytest.raises(ValueError, match=r"unknown plant parameter 'valve.cvmax'; valve has: cv_max"):
        PlantParams.bounds("valve.cvmax")


def test_noise_free_changes_the_sensors_noise_and_resolution_alone():
    p = PlantParams().with_values(**{"load.load_n": 68.0})
    changed = {k for k, v in p.noise_free().dotted().items() if v != p.dotted()[k]}
    assert changed == {"sensor.encoder_noise_std_mm", "sensor.encoder_resolution_mm",
                       "sensor.pressure_noise_std_mpa", "sensor.pressure_resolution_mpa"}
    assert all(p.noise_free().value(k) == 0.0 for k in changed)


@pytest.mark.parametrize("exact", [0.0, -0.0, 0])
def test_noise_free_of_sensors_already_exact_is_the_same_parameters_with_float_zeros(exact):
    """A set already noise-free comes back as it is (the simulator asks every run for it); one whose
    zeros are written otherwise (an int 0 read from a file, -0.0) comes back with +0.0 floats."""
    keys = ("sensor.encoder_noise_std_mm", "sensor.encoder_resolution_mm", "sensor.pressure_noise_std_mpa",
            "sensor.pressure_resolution_mpa")
    p = PlantParams().with_values(**{"load.load_n": 68.0, **{k: exact for k in keys}})
    q = p.noise_free()
    assert q == p and q.noise_free() is q
    zeros = [getattr(q.sensor, k.split(".")[1]) for k in keys]
    assert all(type(z) is float and z == 0.0 and math.copysign(1.0, z) == 1.0 for z in zeros)
    assert (q is p) == (type(exact) is float and math.copysign(1.0, exact) == 1.0)
