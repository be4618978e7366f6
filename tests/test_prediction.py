"""Tests for fmu_controller.prediction (simulation, k-step prediction, fit, identification)."""

import math

import numpy as np
import pytest

from fmu_controller.hysteresis_model import (
    ASYMMETRIC,
    STANDARD,
    ModelState,
    regressor,
    virtual_hysteresis_sequence,
)
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.prediction import (
    N_INITIAL,
    delay_samples_for,
    held_command_runaway,
    fit_percent,
    run_rls,
    predict_ahead,
    rescale_theta,
    simulate,
    theta_scale_factors,
)
from fmu_controller.rls import RLSSettings
from synthetic import TABLE3, NO_BOX, excitation, generate

THETA = ASYMMETRIC.from_dict(TABLE3)


def _predict_loop(theta, structure, u, l, h):
    """Reference h-step predictor: one ModelState per origin, v from predicted l."""
    v = virtual_hysteresis_sequence(theta, l, u)
    out = l.copy()
    for o in range(N_INITIAL - 1, l.size - h):
        state = ModelState(structure, l_init=l[o - 2:o + 1], v_init=v[o - 2:o + 1], u_init=u[o])
        for j in range(h):
            l_next = float(state.phi() @ theta)
            state.update(l_next, u[o + j + 1] if o + j + 1 < l.size else 0.0, theta)
        out[o + h] = l_next
    return out


@pytest.fixture(scope="module")
def record():
    u = excitation(3000)
    return u, generate(THETA, ASYMMETRIC, u)


# ---------------------------------------------------------------------------
# fit
# ---------------------------------------------------------------------------
def test_fit_percent_reference_values():
    rng = np.random.default_rng(0)
    y = rng.normal(size=200) + 3.0
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0, abs=1e-12)
    # NRMSE definition
    yhat = y + 0.1 * rng.normal(size=200)
    expected = 100 * (1 - np.linalg.norm(y - yhat) / np.linalg.norm(y - y.mean()))
    assert fit_percent(y, yhat) == pytest.approx(expected, rel=1e-12)
    # start excludes the leading samples (and the mean is over compared samples)
    bad_head = yhat.copy()
    bad_head[:10] = 1e3
    tail = y[10:]
    expected_tail = 100 * (1 - np.linalg.norm(tail - yhat[10:]) / np.linalg.norm(tail - tail.mean()))
    assert fit_percent(y, bad_head, start=10) == pytest.approx(expected_tail, rel=1e-12)
    assert fit_percent(y, bad_head) < 0


def test_fit_percent_validation():
    with pytest.raises(ValueError, match="constant"):
        fit_percent(np.ones(10), np.ones(10))
    with pytest.raises(ValueError, match="yhat must have length 10"):
        fit_percent(np.arange(10.0), np.arange(9.0))
    with pytest.raises(ValueError, match="yhat must be finite"):
        fit_percent(np.arange(3.0), [0.0, np.nan, 1.0])
    with pytest.raises(ValueError, match="start"):
        fit_percent(np.arange(10.0), np.arange(10.0), start=9)


# ---------------------------------------------------------------------------
# simulate / predict_ahead
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("structure", [ASYMMETRIC, STANDARD])
def test_simulate_reproduces_the_model(structure):
    theta = THETA[: structure.n_params]
    u = excitation(800, seed=2)
    l = generate(theta, structure, u)
    res = simulate(theta, structure, u, l[:4], output_range=(l.min(), l.max()))
    assert res.start == 4 and res.horizon is None and not res.diverged
    np.testing.assert_allclose(res.l_hat, l, rtol=1e-10, atol=1e-10)
    assert fit_percent(l, res.l_hat, start=res.start) == pytest.approx(100.0, abs=1e-6)


def test_predict_ahead_horizon_one_is_phi_theta(record):
    u, l = record
    l_meas = l + np.random.default_rng(3).normal(scale=0.05, size=l.size)  # not the model's own output
    res = predict_ahead(THETA, ASYMMETRIC, u, l_meas, 1)
    assert res.start == 4 and res.horizon == 1
    v = virtual_hysteresis_sequence(THETA, l_meas, u)
    phi = regressor(l_meas[3:-1], l_meas[2:-2], l_meas[1:-3], u[3:-1], v[2:-2], v[1:-3])
    np.testing.assert_allclose(res.l_hat[4:], phi @ THETA, rtol=1e-13, atol=1e-12)
    np.testing.assert_array_equal(res.l_hat[:4], l_meas[:4])


@pytest.mark.parametrize("h", [2, 3, 5])
def test_predict_ahead_matches_reference_loop_and_simulate(record, h):
    u, l = record
    u, l = u[:400], l[:400] + np.random.default_rng(h).normal(scale=0.05, size=400)
    res = predict_ahead(THETA, ASYMMETRIC, u, l, h)
    assert res.start == 3 + h
    ref = _predict_loop(THETA, ASYMMETRIC, u, l, h)
    np.testing.assert_allclose(res.l_hat, ref, rtol=1e-12, atol=1e-10)
    # origin k-h = 3 is the free-run simulation from l(0..3)
    sim = simulate(THETA, ASYMMETRIC, u, l[:4])
    assert res.l_hat[3 + h] == pytest.approx(sim.l_hat[3 + h], rel=1e-12)


def test_prediction_fits_on_model_data(record):
    u, l = record
    for h in (1, 3, 5):
        assert fit_percent(l, predict_ahead(THETA, ASYMMETRIC, u, l, h).l_hat, start=3 + h) == pytest.approx(100, abs=1e-8)
    # 0.1 mm measurement noise (10x the encoder resolution) costs only a few percent
    noisy = l + np.random.default_rng(4).normal(scale=0.1, size=l.size)
    for h in (1, 3, 5):
        assert 95.0 < fit_percent(noisy, predict_ahead(THETA, ASYMMETRIC, u, noisy, h).l_hat, start=3 + h) < 100.0


def test_simulate_divergence_guard():
    u = excitation(500, seed=5)
    unstable = ASYMMETRIC.from_dict({"a1": 2.5, "a2": -0.2, "b1": 1.0, "xi31": 1e-2})
    res = simulate(unstable, ASYMMETRIC, u, [20.0, 20.0, 20.0, 20.0], output_range=(0.0, 70.0))
    assert res.diverged
    assert np.all(np.isfinite(res.l_hat))
    assert res.l_hat.min() >= -700.0 and res.l_hat.max() <= 770.0
    assert res.l_hat.max() == 770.0 or res.l_hat.min() == -700.0  # clamped at a guard bound
    pred = predict_ahead(unstable, ASYMMETRIC, u, res.l_hat, 50, output_range=(0.0, 70.0))
    assert pred.diverged and np.all(np.isfinite(pred.l_hat))
    # default range from l_init is widened: span >= max(|lo|, |hi|, 1 mm)
    ok = simulate(THETA, ASYMMETRIC, u, [20.0, 20.0, 20.0, 20.0])
    assert not ok.diverged


def test_a_model_runs_away_under_the_first_held_command_whose_free_run_leaves_the_guard():
    """The paper's fixed predictor stays from rest at 2 and 5 V held for 30 s (the range it was identified
    on) and runs away at 8 V, beyond it (its cubic g(l) past 70 mm); a larger a1 runs away at 2 V
    already; the first command of those given that runs away is named; a stable linear model (l -> 10 u,
    100 mm at 10 V) never runs away."""
    assert held_command_runaway(THETA0_44N, ASYMMETRIC, (2.0, 5.0), 300) is None
    assert held_command_runaway(THETA0_44N, ASYMMETRIC, (2.0, 5.0, 8.0), 300) == 8.0
    steeper = np.array(THETA0_44N)
    steeper[0] += 0.1
    assert held_command_runaway(steeper, ASYMMETRIC, (2.0, 5.0, 8.0), 300) == 2.0
    assert held_command_runaway(steeper, ASYMMETRIC, (8.0, 2.0), 300) == 8.0
    linear = ASYMMETRIC.from_dict({"a1": 0.9, "a2": 0.0, "b1": 1.0})
    assert held_command_runaway(linear, ASYMMETRIC, np.linspace(0.0, 10.0, 11), 3000) is None
    # the guard is ten spans of RUNAWAY_RANGE_MM either side, up to 1100 mm: 100 mm at 10 V stays, 1200 at 120 V not
    assert held_command_runaway(linear, ASYMMETRIC, (10.0, 120.0), 3000) == 120.0


def test_prediction_input_validation(record):
    u, l = record
    with pytest.raises(ValueError, match="l_init must have length 4"):
        simulate(THETA, ASYMMETRIC, u, l[:3])
    with pytest.raises(ValueError, match="theta must have length 15"):
        simulate(THETA[:11], ASYMMETRIC, u, l[:4])
    bad_u = u.copy()
    bad_u[7] = np.nan
    with pytest.raises(ValueError, match="u must be finite"):
        simulate(THETA, ASYMMETRIC, bad_u, l[:4])
    with pytest.raises(ValueError, match="horizon"):
        predict_ahead(THETA, ASYMMETRIC, u, l, 0)
    with pytest.raises(ValueError, match="u must have length"):
        predict_ahead(THETA, ASYMMETRIC, u[:-1], l, 1)
    with pytest.raises(ValueError, match="output_range"):
        simulate(THETA, ASYMMETRIC, u, l[:4], output_range=(5.0, 5.0))
    with pytest.raises(ValueError, match="need more than"):
        predict_ahead(THETA, ASYMMETRIC, u[:6], l[:6], 3)
    with pytest.raises(ValueError, match="l_scale"):
        rescale_theta(THETA, ASYMMETRIC, 0.0, 1.0)


# ---------------------------------------------------------------------------
# identification
# ---------------------------------------------------------------------------
def test_identify_recovers_all_parameters_with_prior_pinning_a1_a2(record):
    # v is computed with the running estimate (section 2.3): a pseudo-linear
    # regression.  a1, a2 are pinned by the prior (the null direction), and
    # forgetting discards the early samples whose v used a poor estimate.
    u, l = record
    p0 = np.full(15, 1e6)
    p0[:2] = 1e-12
    theta0 = np.zeros(15)
    theta0[:2] = THETA[:2]
    res = run_rls(ASYMMETRIC, u, l, RLSSettings(p0=p0, theta0=theta0, forgetting=0.995, **NO_BOX))
    np.testing.assert_allclose(res.theta, THETA, rtol=1e-3)
    assert np.max(np.abs(res.errors[-500:])) < 1e-3
    assert res.theta_history.shape == (3000, 15) and res.start == N_INITIAL
    np.testing.assert_array_equal(res.theta_history[:4], np.tile(theta0, (4, 1)))
    np.testing.assert_array_equal(res.errors[:4], 0.0)
    np.testing.assert_array_equal(res.theta_history[-1], res.theta)
    assert res.n_projections == 0 and res.n_resets == 0


def test_identify_errors_are_a_priori(record):
    u, l = record
    u, l = u[:300], l[:300]
    res = run_rls(ASYMMETRIC, u, l, RLSSettings(**NO_BOX))
    state = ModelState(ASYMMETRIC, l_init=l[1:4], v_init=virtual_hysteresis_sequence(np.zeros(15), l[:4], u[:4])[1:4], u_init=u[3])
    for k in range(4, 300):
        phi = state.phi()
        assert res.errors[k] == pytest.approx(l[k] - phi @ res.theta_history[k - 1], rel=1e-12, abs=1e-12)
        state.update(l[k], u[k], res.theta_history[k])


def test_identify_with_paper_settings(record):
    # P(-1) = 1e3 I, theta(0) = 0, Table 2 box from 120 s (section 2.4)
    u, l = record
    res = run_rls(ASYMMETRIC, u, l)
    lower = np.array([1.208, -0.334, 0.607])
    upper = np.array([1.260, -0.278, 1.184])
    hist = res.theta_history[:, :3]
    inside = np.all((hist >= lower) & (hist <= upper), axis=1)
    assert inside[1200:].all() and not inside[1199]
    assert res.n_projections > 0
    fits = [fit_percent(l, predict_ahead(res.theta, ASYMMETRIC, u, l, h).l_hat, start=3 + h) for h in (1, 3, 5)]
    sim = simulate(res.theta, ASYMMETRIC, u, l[:4], output_range=(l.min(), l.max()))
    assert fits[0] > 97.5 and fits[1] > 95.0 and fits[2] > 93.0
    assert not sim.diverged and fit_percent(l, sim.l_hat, start=4) > 85.0


# ---------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------
def test_theta_scale_factors_values():
    f = dict(zip(ASYMMETRIC.names, theta_scale_factors(ASYMMETRIC, 10.0, 2.0)))
    assert f["a1"] == f["a2"] == f["A1"] == f["A2"] == f["c1"] == f["c2"] == 1.0
    assert f["b1"] == 5.0
    assert f["beta1"] == f["gamma2"] == f["xi21"] == pytest.approx(0.1)
    assert f["xi31"] == f["xi32"] == pytest.approx(0.01)
    assert theta_scale_factors(STANDARD, 10.0, 2.0).size == 11


def test_rescale_theta_gives_identical_predictions(record):
    u, l = record
    ls, us = 20.0, 5.0
    theta_scaled = THETA / theta_scale_factors(ASYMMETRIC, ls, us)
    back = rescale_theta(theta_scaled, ASYMMETRIC, ls, us)
    np.testing.assert_allclose(back, THETA, rtol=1e-15)
    for h in (1, 5):
        scaled = predict_ahead(theta_scaled, ASYMMETRIC, u / us, l / ls, h).l_hat * ls
        raw = predict_ahead(back, ASYMMETRIC, u, l, h).l_hat
        np.testing.assert_allclose(scaled, raw, rtol=1e-11)
    sim_scaled = simulate(theta_scaled, ASYMMETRIC, u / us, l[:4] / ls).l_hat * ls
    np.testing.assert_allclose(sim_scaled, l, rtol=1e-9)


def test_identify_on_scaled_and_raw_data_agree(record):
    # RLS is equivariant under scaling when P(-1) and the box are transformed too:
    # P_raw = diag(f) P_scaled diag(f) / l_scale^2, box_raw = f * box_scaled
    u, l = record
    ls, us = 20.0, 5.0
    f = theta_scale_factors(ASYMMETRIC, ls, us)
    lower_raw = np.full(15, -np.inf)
    upper_raw = np.full(15, np.inf)
    lower_raw[:3] = [1.208, -0.334, 0.607]
    upper_raw[:3] = [1.260, -0.278, 1.184]
    common = dict(constraint_start_s=120.0)
    raw = run_rls(ASYMMETRIC, u, l, RLSSettings(p0=1e3 * f**2 / ls**2, box_lower=lower_raw, box_upper=upper_raw, **common))
    scaled = run_rls(ASYMMETRIC, u / us, l / ls, RLSSettings(p0=1e3, box_lower=lower_raw / f, box_upper=upper_raw / f, **common))
    assert raw.n_projections == scaled.n_projections > 0
    theta_back = rescale_theta(scaled.theta, ASYMMETRIC, ls, us)
    np.testing.assert_allclose(theta_back, raw.theta, rtol=1e-7, atol=1e-13)
    p_raw = predict_ahead(raw.theta, ASYMMETRIC, u, l, 1).l_hat
    p_back = predict_ahead(theta_back, ASYMMETRIC, u, l, 1).l_hat
    assert np.max(np.abs(p_raw - p_back)) < 1e-6  # mm


@pytest.mark.parametrize("delay_s, ts_s, samples", [(0.0, 0.1, 0), (0.02, 0.1, 0), (0.025, 0.1, 0), (0.03, 0.1, 1),
                                                    (0.11, 0.1, 1), (0.15, 0.1, 2), (0.2, 0.1, 2), (0.275, 0.1, 3),
                                                    (0.15, 0.02, 8), (2.0, 0.1, 20), (0.3, 0.1, 3)])
def test_a_delay_in_samples_is_the_whole_number_near_it_or_else_the_longer_of_two(delay_s, ts_s, samples):
    # within a quarter of a sample of a whole number: that number; between: the longer
    assert delay_samples_for(delay_s, ts_s) == samples


@pytest.mark.parametrize("delay_s, ts_s, named", [(-0.1, 0.1, "delay_s"), (math.nan, 0.1, "delay_s"),
                                                  (0.1, 0.0, "ts_s"), (0.1, math.inf, "ts_s")])
def test_a_delay_in_samples_refuses_what_is_no_delay_or_period(delay_s, ts_s, named):
    with pytest.raises(ValueError, match=f"^{named} must be"):
        delay_samples_for(delay_s, ts_s)
