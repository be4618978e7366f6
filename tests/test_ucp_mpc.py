"""Unique-coincidence-point MPC (Eq. 11-14)."""

import numpy as np
import pytest

from fmu_controller.hysteresis_model import ASYMMETRIC, ModelState
from fmu_controller.ucp_mpc import UCPSettings, predict_held_input, ucp_move

THETA = np.array([1.21, -0.285, 0.7, 0.05, 0.04, 0.01, -0.01, -0.005, 0.004, 0.05, 0.02,
                  0.002, -0.002, -2e-5, 2e-5])


def _state(l=30.0, u=5.0):
    s = ModelState(ASYMMETRIC, l_init=(l - 1, l - 0.5, l - 0.2), u_init=u)
    s.observe(l, THETA)
    return s


def test_move_puts_the_model_on_the_reference_at_hp():
    s = _state()
    res = ucp_move(UCPSettings(hp=2), s, THETA, u_prev_v=5.0, r_target_mm=32.0)
    assert not res.saturated
    assert predict_held_input(s, THETA, res.u_v, 2)[-1] == pytest.approx(32.0, abs=0.05)
    assert res.predicted_mm[-1] == pytest.approx(32.0, abs=0.05)


def test_linear_model_is_exact():
    theta = np.zeros(15)
    theta[:3] = (1.2, -0.3, 0.6)
    s = ModelState(ASYMMETRIC, l_init=(10, 10, 10), u_init=1.0)
    s.observe(10.0, theta)
    res = ucp_move(UCPSettings(hp=3), s, theta, u_prev_v=1.0, r_target_mm=12.0)
    assert predict_held_input(s, theta, res.u_v, 3)[-1] == pytest.approx(12.0, abs=1e-9)


def test_input_limits_hold():
    s = _state()
    hi = ucp_move(UCPSettings(), s, THETA, u_prev_v=5.0, r_target_mm=500.0)
    lo = ucp_move(UCPSettings(), s, THETA, u_prev_v=5.0, r_target_mm=-500.0)
    assert hi.u_v == 10.0 and lo.u_v == 0.0 and hi.saturated and lo.saturated


def test_degenerate_step_response_falls_back_to_linear_part():
    theta = THETA.copy()
    theta[2] = 0.0  # the model says the input does nothing
    s = _state()
    res = ucp_move(UCPSettings(), s, theta, u_prev_v=5.0, r_target_mm=31.0)
    assert np.isfinite(res.u_v) and 0.0 <= res.u_v <= 10.0
    assert abs(res.step_response_mm_per_v) >= 1e-3


@pytest.mark.parametrize("kw, match", [({"hp": 0}, "hp"), ({"u_min_v": 5, "u_max_v": 1}, "u_max_v"),
                                       ({"min_step_response_mm_per_v": -1.0}, "min_step_response_mm_per_v")])
def test_bad_settings(kw, match):
    with pytest.raises(ValueError, match=match):
        UCPSettings(**kw)


def test_held_input_prediction_equals_stepping_the_model():
    # predict_held_input runs in plain floats; it must equal stepping a ModelState copy exactly
    rng = np.random.default_rng(3)
    for _ in range(50):
        s = _state(l=float(rng.uniform(10, 60)), u=float(rng.uniform(0, 10)))
        u = float(rng.uniform(0, 10))
        sim = ModelState(ASYMMETRIC, l_init=s.l, v_init=s.v, u_init=u)
        want = []
        for _ in range(4):
            nxt = float(sim.phi() @ THETA)
            sim.observe(nxt, THETA)
            sim.apply(u)
            want.append(nxt)
        assert predict_held_input(s, THETA, u, 4).tolist() == want
    with pytest.raises(ValueError, match="u must be finite"):
        predict_held_input(_state(), THETA, float("nan"), 2)


@pytest.mark.parametrize("a1", [0.9, 3.0])  # a stable linear part; an unstable one as well
def test_a_prediction_that_diverges_still_gives_a_finite_move_within_the_limits(a1):
    """A long horizon with a cubic g(l) far outside its fitted range overflows (the controller FMU
    stopped with 'l must be finite, got nan' at ucp.Hp = 20): the move falls back on the linear part,
    and with that unstable too, holds the command."""
    theta = ASYMMETRIC.from_dict({"a1": a1, "a2": 0.0, "b1": 0.5, "xi31": 5.0, "xi32": 5.0})
    settings = UCPSettings(hp=50)
    with np.errstate(all="raise"):  # no overflow warning reaches the host either
        res = ucp_move(settings, _state(), theta, u_prev_v=5.0, r_target_mm=40.0)
    assert 0.0 <= res.u_v <= 10.0 and np.all(np.isfinite(res.predicted_mm)) and res.predicted_mm.shape == (50,)
    assert np.isfinite(res.free_response_mm) and np.isfinite(res.step_response_mm_per_v)
    if a1 < 1.0:  # the linear part's move: r reached at Hp in the linear model
        assert res.predicted_mm[-1] == pytest.approx(40.0, abs=1e-6) or res.saturated


def test_ampc_ucp_with_a_long_horizon_runs_through():
    import tapmuscle as tm

    s = tm.ControllerSettings(method="ampc_ucp", ucp=UCPSettings(hp=20), input_delay_samples=-1)
    run = tm.simulate_closed_loop("ampc_ucp", None, duration_s=45.0, settings=s)
    assert np.all(np.isfinite(run["u_v"])) and run["u_v"].min() >= 0.0 and run["u_v"].max() <= 10.0
    # the loop is poor at this horizon (docs/control.md: UCP's error grows with Hp; 16 mm measured, the
    # valve limit to limit), but it stays on the muscle: within its stroke and below the reference's
    # own 30-mm amplitude (a generous bound: a limit-to-limit loop differs from CPU to CPU)
    assert np.all(np.isfinite(run["l_mm"])) and -5.0 < run["l_mm"].min() and run["l_mm"].max() < 110.0
    assert tm.eq21_error_mm(run["r_mm"], run["l_mm"]) < 30.0


def test_the_former_name_of_the_step_response_floor_is_accepted_with_a_deprecation_warning():
    with pytest.warns(DeprecationWarning, match="min_step_response_mm_per_v"):
        s = UCPSettings(min_step_response_mm=0.02)
    assert s.min_step_response_mm_per_v == 0.02 and s == UCPSettings(min_step_response_mm_per_v=0.02)
