"""One source of the physics: the simulator's fused right-hand side and Jacobian are the equations of
the documented modules (fmu_plant/equations.py), at thousands of states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fmu_plant import Plant, PlantParams
from fmu_plant.equations import rig_derivatives
from fmu_plant.parameters import GRAVITY_M_S2
from fmu_plant.rosenbrock import build_model

VARIANTS = {
    "default": PlantParams(),
    "rate dependent, 68 N": PlantParams().with_values(**{"friction.rate_gain": 0.8, "load.load_n": 68.0}),
    "other constants": PlantParams().with_values(**{"valve.cv_max": 1.2, "valve.characteristic_exponent": 1.0,
                                                    "muscle.braid_lock_force_n": 0.0, "friction.asymmetry": -0.2,
                                                    "muscle.threshold_pressure_mpa": 0.06}),
    "laminar exponent, drain": PlantParams().with_values(**{"friction.rate_exponent": 0.5, "friction.rate_gain": 0.4,
                                                            "valve.leak_fraction": 0.2,
                                                            "supply.drain_pressure_mpa": 0.05}),
}


def _states(rng: np.random.Generator, n: int) -> list[tuple[float, ...]]:
    states = []
    for _ in range(n):
        x = rng.uniform(-0.1, 1.1)
        p = rng.choice([rng.uniform(-0.01, 0.26), 0.25 + rng.uniform(-0.003, 0.003), rng.uniform(-0.003, 0.003)])
        l = rng.choice([rng.uniform(0.5, 148.0), rng.uniform(-0.5, 0.5), rng.uniform(148.0, 160.0)])
        v = rng.choice([rng.uniform(-80.0, 80.0), 0.0, rng.uniform(-1e-3, 1e-3)])
        z = rng.uniform(-30.0, 30.0)
        states.append((x, p, l, v, z))
    return states


@pytest.mark.parametrize("name", list(VARIANTS))
def test_the_simulator_integrates_the_documented_equations(name):
    params = VARIANTS[name]
    plant = Plant(params)
    rng = np.random.default_rng(7)
    for state in _states(rng, 2000):
        u, ps, w = rng.uniform(-1.0, 11.0), rng.uniform(0.15, 0.3), params.load.load_n
        fast = plant.derivatives(state, u, ps, w)
        ref = rig_derivatives(params, state, u, ps, w)
        # the same arithmetic in another order: agreement to a few ulps of the largest term
        np.testing.assert_allclose(fast, ref, rtol=1e-10, atol=1e-9, err_msg=f"state {state}, u {u}, ps {ps}")


def test_the_gated_valve_is_the_documented_one():
    params = PlantParams()
    rhs, _, _, set_gate, _ = build_model(params)
    inv_mass = 1e3 / (44.0 / GRAVITY_M_S2 + params.load.moving_mass_kg)
    for gate in (0.0, 0.3, 1.0):
        set_gate(gate)
        for state in _states(np.random.default_rng(3), 200):
            fast = rhs(*state, 0.25, 44.0, inv_mass)
            ref = rig_derivatives(params, state, 5.0, 0.25, 44.0, gate=gate)[1:]
            np.testing.assert_allclose(fast, ref, rtol=1e-10, atol=1e-9)


def test_the_jacobian_is_that_of_the_documented_equations():
    """The entries the Rosenbrock scheme uses, against central differences of rig_derivatives, away
    from the kinks (laminar band, stop, zero speed) where the derivative jumps."""
    params = VARIANTS["rate dependent, 68 N"]
    _, jacobian, *_ = build_model(params)
    w, ps = params.load.load_n, 0.25
    inv_mass = 1e3 / (w / GRAVITY_M_S2 + params.load.moving_mass_kg)
    rng = np.random.default_rng(11)
    names = ["dp/dp", "dp/dv", "dp/dl", "dv/dp", "dv/dl", "dv/dv", "dv/dz", "dz/dp", "dz/dv", "dz/dz"]
    index = {"p": 1, "l": 2, "v": 3, "z": 4}
    checked = 0
    while checked < 300:
        state = (rng.uniform(0.05, 0.95), rng.uniform(0.07, 0.23), rng.uniform(5.0, 120.0),
                 rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 60.0), rng.uniform(-20.0, 20.0))
        if abs(ps - state[1]) < 0.01:
            continue
        out = jacobian(*state, ps, w, inv_mass)
        for name, value in zip(names, out[4:]):
            row, col = name[1], index[name[-1]]
            h = 1e-6 * max(1.0, abs(state[col]))
            up, down = list(state), list(state)
            up[col] += h
            down[col] -= h
            fd = (rig_derivatives(params, tuple(up), 5.0, ps, w)[index[row]]
                  - rig_derivatives(params, tuple(down), 5.0, ps, w)[index[row]]) / (2 * h)
            assert math.isclose(value, fd, rel_tol=1e-5, abs_tol=1e-6 * max(1.0, abs(fd))), \
                f"{name} at {state}: scheme {value!r}, equations {fd!r}"
        checked += 1


def test_an_edit_to_the_physics_would_be_caught(monkeypatch):
    """The check is not vacuous: a changed friction law in friction.py differs from the fast path."""
    import fmu_plant.equations as equations

    def doubled(fp, z_n, v_mm_s, p_mpa, contact):
        from fmu_plant.friction import friction_rate_n_s
        return 2.0 * friction_rate_n_s(fp, z_n, v_mm_s, p_mpa, contact)

    monkeypatch.setattr(equations, "friction_rate_n_s", doubled)
    params = PlantParams()
    state = (0.5, 0.15, 60.0, 10.0, 3.0)
    fast = Plant(params).derivatives(state, 5.0, 0.25, 44.0)
    assert not np.allclose(fast, rig_derivatives(params, state, 5.0, 0.25, 44.0), rtol=1e-10, atol=1e-9)


def test_a_trial_state_far_beyond_the_extension_stop_is_infinite_not_an_overflow():
    """A Rosenbrock stage of a large sub-step can land far below l = 0, where the braid lock's
    ``exp(-l / l_lock)`` overflows: both definitions give an infinite force there (the integrator then
    rejects the sub-step) instead of raising OverflowError, which broke an experiment design."""
    params = PlantParams()
    lock_mm = params.muscle.braid_lock_length_mm
    far = (0.5, 0.1, -800.0 * lock_mm, 5.0, 0.0)  # moving up: not resting on the stop
    assert math.isinf(rig_derivatives(params, far, 5.0, 0.25, 44.0)[3])
    rhs, jac, *_ = build_model(params)
    inv_mass = 1e3 / (44.0 / GRAVITY_M_S2 + params.load.moving_mass_kg)
    assert math.isinf(rhs(*far, 0.25, 44.0, inv_mass)[2])
    # just inside the limit the force is finite and both agree
    near = (0.5, 0.1, -650.0 * lock_mm, 5.0, 0.0)
    assert math.isfinite(rig_derivatives(params, near, 5.0, 0.25, 44.0)[3])
