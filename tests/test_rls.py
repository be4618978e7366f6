"""Tests for fmu_controller.rls (Eq. (4), Algorithm 1, Remark 1)."""

import copy
import math
import pickle
import warnings

import numpy as np
import pytest
from scipy.optimize import lsq_linear, minimize

from fmu_controller.hysteresis_model import (
    ASYMMETRIC,
    STANDARD,
    identifiable_combinations,
    null_direction,
    regressor,
    virtual_hysteresis_sequence,
)
from fmu_controller.rls import (
    TABLE2_LOWER,
    TABLE2_UPPER,
    ConstrainedRLS,
    Regressors,
    RLSSettings,
    BoxProjector,
    project_onto_box,
)
from synthetic import TABLE3, NO_BOX, excitation, generate


def _true_regressors(theta, structure, u, l):
    v = virtual_hysteresis_sequence(theta, l, u)
    phi = regressor(l[3:-1], l[2:-2], l[1:-3], u[3:-1], v[2:-2], v[1:-3], structure)
    return phi, l[4:]


def _random_spd(rng, n, log_cond=4.0):
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (q * 10.0 ** rng.uniform(-log_cond / 2, log_cond / 2, n)) @ q.T


# ---------------------------------------------------------------------------
# Eq. (4)
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("structure", [ASYMMETRIC, STANDARD])
def test_rls_recovers_identifiable_parameters(structure):
    theta_true = ASYMMETRIC.from_dict(TABLE3)[: structure.n_params]
    u = excitation(3000)
    l = generate(theta_true, structure, u)
    assert np.all(np.isfinite(l)) and 0 < l.min() and l.max() < 250  # bounded, mm-scale
    phi, y = _true_regressors(theta_true, structure, u, l)
    assert np.max(np.abs(phi @ theta_true - y)) < 1e-10  # data follow the regression form exactly
    rls = ConstrainedRLS(structure, RLSSettings(p0=1e6, **NO_BOX))
    for p, yy in zip(phi, y):
        rls.update(p, yy)
    est = identifiable_combinations(rls.theta, structure)
    true = identifiable_combinations(theta_true, structure)
    for key in true:
        assert est[key] == pytest.approx(true[key], rel=1e-4), key
    # the unidentifiable direction keeps its prior value (theta0 = 0)
    assert abs(null_direction(structure) @ rls.theta) < 1e-8


def test_rls_equals_regularised_batch_least_squares():
    rng = np.random.default_rng(2)
    n, N = 15, 400
    phi = rng.normal(size=(N, n))
    y = phi @ rng.normal(size=n) + 0.1 * rng.normal(size=N)
    p0 = rng.uniform(0.5, 50.0, n)
    theta0 = rng.normal(size=n)
    rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=p0, theta0=theta0, **NO_BOX))
    for p, yy in zip(phi, y):
        rls.update(p, yy)
    info = np.diag(1 / p0) + phi.T @ phi
    theta_batch = np.linalg.solve(info, theta0 / p0 + phi.T @ y)
    np.testing.assert_allclose(rls.theta, theta_batch, rtol=0, atol=1e-9)
    np.testing.assert_allclose(rls.P, np.linalg.inv(info), rtol=0, atol=1e-12)
    assert np.array_equal(rls.P, rls.P.T)  # kept exactly symmetric


def test_gain_is_goodwin_sin_not_literal_printed_eq4():
    rng = np.random.default_rng(3)
    rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=rng.uniform(1, 10, 15), **NO_BOX))
    for _ in range(5):
        rls.update(rng.normal(size=15), rng.normal())
    phi, y = rng.normal(size=15), rng.normal()
    theta_prev, P_prev = rls.theta, rls.P
    err = y - phi @ theta_prev
    theta = rls.update(phi, y)
    P_new = rls.P
    # G&S: gain = P(k-2) phi / (1 + phi^T P(k-2) phi) = P(k-1) phi
    np.testing.assert_allclose(theta - theta_prev, P_new @ phi * err, rtol=1e-10)
    np.testing.assert_allclose(theta - theta_prev, P_prev @ phi / (1 + phi @ P_prev @ phi) * err, rtol=1e-10)
    # the printed Eq. (4) read literally (P(k-1) in numerator and denominator) differs
    literal = P_new @ phi / (1 + phi @ P_new @ phi) * err
    assert np.max(np.abs(literal - (theta - theta_prev))) > 1e-3 * np.max(np.abs(theta - theta_prev))


def test_forgetting_tracks_parameter_jump_faster():
    rng = np.random.default_rng(4)
    n, N, jump = 15, 1400, 1000
    theta_a, theta_b = rng.normal(size=n), rng.normal(size=n)
    phi = rng.normal(size=(N, n))
    y = np.where(np.arange(N) < jump, phi @ theta_a, phi @ theta_b) + 0.01 * rng.normal(size=N)
    errors = {}
    for lam in (1.0, 0.98):
        rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(forgetting=lam, **NO_BOX))
        for p, yy in zip(phi[: jump + 200], y[: jump + 200]):
            rls.update(p, yy)
        errors[lam] = np.linalg.norm(rls.theta - theta_b)
    assert errors[0.98] < 0.05 * errors[1.0]
    assert errors[0.98] < 0.05 * np.linalg.norm(theta_b - theta_a)


def _ceiling_ratio(P: np.ndarray, p0: np.ndarray) -> float:
    """Largest eigenvalue of P(0)^-1/2 P P(0)^-1/2 (<= 1 means P <= P(0))."""
    s = 1.0 / np.sqrt(p0)
    return float(np.linalg.eigvalsh(P * s[:, None] * s[None, :])[-1])


@pytest.mark.parametrize("seed", range(3))
def test_covariance_ceiling_stops_wind_up_and_keeps_p_positive_definite(seed):
    # Forgetting with a regressor that excites only 5 of 15 directions: P grows as lambda^-k in the
    # other ten (wind-up). The ceiling holds P <= P(0) at every step and leaves P positive definite.
    rng = np.random.default_rng(seed)
    p0 = rng.uniform(1.0, 100.0, 15)
    basis = np.linalg.qr(rng.normal(size=(15, 5)))[0]
    theta = rng.normal(size=15)
    runs = {}
    for ceiling in (False, True):
        rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=tuple(p0), forgetting=0.98, covariance_ceiling=ceiling,
                                                     **NO_BOX))
        worst = 0.0
        for _ in range(600):
            phi = basis @ rng.normal(size=5) * rng.uniform(0.1, 10.0)
            rls.update(phi, float(phi @ theta) + 0.01 * rng.normal())
            worst = max(worst, _ceiling_ratio(rls.P, p0))
            np.linalg.cholesky(rls.P)  # positive definite
            assert np.array_equal(rls.P, rls.P.T)
        runs[ceiling] = (worst, rls)
    assert runs[False][0] > 1e3  # without the ceiling: wound up (0.98^-600 ~ 1e5 in the idle directions)
    assert runs[True][0] <= 1.0 + 1e-9
    assert runs[True][1].n_ceilings > 0
    # the excited directions are still learned: the estimate's error there is small
    err = basis.T @ (runs[True][1].theta - theta)
    assert np.linalg.norm(err) < 0.05 * np.linalg.norm(basis.T @ theta)


def test_covariance_ceiling_is_inactive_without_forgetting():
    # With lambda = 1, P only shrinks, so the ceiling never acts: the estimates are bit-identical.
    rng = np.random.default_rng(7)
    phi = rng.normal(size=(800, 15)) * rng.uniform(0.1, 50.0, 15)
    y = phi @ rng.normal(size=15) + 0.01 * rng.normal(size=800)
    out = []
    for ceiling in (False, True):
        rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=(200.0,) * 3 + (50.0,) * 12, covariance_ceiling=ceiling,
                                                     **NO_BOX))
        for p, yy in zip(phi, y):
            rls.update(p, yy)
        out.append((rls.theta, rls.P, rls.n_ceilings))
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
    assert out[1][2] == 0


def test_covariance_loss_resets_with_the_ceiling_on_too():
    """The ceiling acts on a valid covariance only: a lost one takes the documented reset."""
    rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=2.0, forgetting=0.98, covariance_ceiling=True, **NO_BOX))
    rls.update(np.ones(15), 1.0)
    theta_before, clipped = rls.theta, rls.n_ceilings
    assert np.array_equal(rls.update(np.full(15, 1e160), 1.0), theta_before)
    assert rls.n_resets == 1 and rls.n_ceilings == clipped and np.array_equal(rls.P, 2.0 * np.eye(15))


def test_covariance_ceiling_must_be_boolean():
    with pytest.raises(ValueError, match="covariance_ceiling"):
        RLSSettings(covariance_ceiling=1)


@pytest.mark.parametrize("numpy_errors", ["default", "raise"])
def test_covariance_loss_reset_and_raise(numpy_errors):
    """The documented rule, whatever numpy's error handling in the caller's thread (a notebook's
    ``np.seterr(all="raise")`` would make the overflow a numpy FloatingPointError), and without warnings
    (it is handled: n_resets counts it)."""
    phi = np.full(15, 1e160)  # finite, but phi^T P phi overflows
    with warnings.catch_warnings(), np.errstate(**({"all": "raise"} if numpy_errors == "raise" else {})):
        warnings.simplefilter("error")
        rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=2.0, **NO_BOX))
        rls.update(np.ones(15), 1.0)
        theta_before = rls.theta
        out = rls.update(phi, 1.0)
        assert rls.n_resets == 1
        assert np.array_equal(out, theta_before)  # update discarded
        assert np.array_equal(rls.P, 2.0 * np.eye(15))  # P reset to P(-1)
        strict = ConstrainedRLS(ASYMMETRIC, RLSSettings(on_covariance_loss="raise", **NO_BOX))
        with pytest.raises(FloatingPointError, match="positive definiteness"):
            strict.update(phi, 1.0)



@pytest.mark.parametrize("rule", ["reset", "raise"])
def test_a_covariance_too_singular_to_weigh_the_projection_is_a_covariance_loss(rule):
    """Forgetting without the ceiling winds P up until the block of P that Algorithm 1's projection
    (Eq. 6) inverts is singular in floating point (a closed loop with forgetting = 0.95 gets there):
    that is the covariance lost, handled by the documented rule, not numpy's LinAlgError."""
    rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=2.0, on_covariance_loss=rule, constraint_start_s=0.0))
    P = np.eye(15)
    P[:3, :3] = 1.0  # a1, a2, b1 (the boxed ones) move together only: their block has rank 1
    theta = np.array(rls.theta)
    theta[:3] = (1.5, -0.1, 1.5)  # outside Table 2's box
    rls.set_state({"theta": theta, "P": P, "k": 5})
    phi = np.zeros(15)  # no information: theta stays outside, P is P
    if rule == "raise":
        with pytest.raises(FloatingPointError, match="the projection's block of P is singular"):
            rls.update(phi, 0.0)
        return
    out = rls.update(phi, 0.0)
    assert rls.n_resets == 1 and rls.n_projections == 0 and rls.step == 6
    assert np.array_equal(out, theta) and np.array_equal(rls.P, 2.0 * np.eye(15))
    # the next update projects with P(-1): back inside the box
    inside = rls.update(phi, 0.0)
    assert rls.n_projections == 1 and 1.208 <= inside[0] <= 1.260 and 0.607 <= inside[2] <= 1.184

def test_get_set_state_round_trip_is_bit_identical():
    theta_true = ASYMMETRIC.from_dict(TABLE3)
    u = excitation(1000, seed=5)
    l = generate(theta_true, ASYMMETRIC, u)
    phi, y = _true_regressors(theta_true, ASYMMETRIC, u, l)
    # constraint active from sample 300 so projections happen in the replayed part
    settings = RLSSettings(constraint_start_s=30.0, forgetting=0.995)
    rls = ConstrainedRLS(ASYMMETRIC, settings)
    for p, yy in zip(phi[:400], y[:400]):
        rls.update(p, yy)
    snap = rls.get_state()
    snap_copy = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in snap.items()}
    first = []
    for p, yy in zip(phi[400:700], y[400:700]):
        first.append((rls.update(p, yy), rls.P))
    assert rls.n_projections > 0
    for key, value in snap.items():  # snapshot was a copy, untouched by later updates
        assert np.array_equal(value, snap_copy[key])
    other = ConstrainedRLS(ASYMMETRIC, settings)
    other.set_state(snap)
    for (theta_a, P_a), p, yy in zip(first, phi[400:700], y[400:700]):
        theta_b = other.update(p, yy)
        assert np.array_equal(theta_a, theta_b) and np.array_equal(P_a, other.P)
    assert other.get_state()["k"] == rls.step


def test_update_returns_copies():
    rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(**NO_BOX))
    out = rls.update(np.ones(15), 1.0)
    out[:] = 99.0
    assert np.all(rls.theta != 99.0)
    P = rls.P
    P[:] = 0.0
    assert np.all(np.diag(rls.P) > 0)


# ---------------------------------------------------------------------------
# Algorithm 1: projection
# ---------------------------------------------------------------------------
def _metric(P, a, b):
    d = a - b
    return float(d @ np.linalg.solve(P, d))


def _reference_projection(theta_hat, P, lower, upper):
    """Brute force: BVLS on the full problem min |L^{-1}(theta - theta_hat)|^2."""
    L = np.linalg.cholesky(P)
    Linv = np.linalg.inv(L)
    res = lsq_linear(Linv, Linv @ theta_hat, bounds=(lower, upper), method="bvls", tol=1e-15)
    return res.x


def _random_case(rng, n_boxed_max=4):
    n = int(rng.integers(2, 16))
    P = _random_spd(rng, n, log_cond=rng.uniform(0, 6))
    theta_hat = rng.normal(scale=3.0, size=n)
    m = int(rng.integers(1, min(n_boxed_max, n) + 1))
    boxed = rng.choice(n, size=m, replace=False)
    lower, upper = np.full(n, -np.inf), np.full(n, np.inf)
    centre = theta_hat[boxed] + rng.normal(scale=2.0, size=m)
    half = rng.uniform(0.05, 2.0, m)
    lower[boxed], upper[boxed] = centre - half, centre + half
    one_sided = rng.random(m) < 0.25
    lower[boxed[one_sided & (rng.random(m) < 0.5)]] = -np.inf
    upper[boxed[one_sided]] = np.where(np.isinf(lower[boxed[one_sided]]), upper[boxed[one_sided]], np.inf)
    theta0 = theta_hat + rng.normal(size=n)  # some point of C for Remark 1
    theta0 = np.clip(theta0, np.where(np.isinf(lower), -1e9, lower), np.where(np.isinf(upper), 1e9, upper))
    return theta_hat, P, lower, upper, theta0


@pytest.mark.parametrize("n_boxed_max", [4, 7])  # 7 exercises the BVLS fallback
def test_projection_properties_random(n_boxed_max):
    rng = np.random.default_rng(10 + n_boxed_max)
    n_projected = 0
    for _ in range(200):
        theta_hat, P, lower, upper, theta0 = _random_case(rng, n_boxed_max)
        theta = project_onto_box(theta_hat, P, lower, upper)
        # inside C
        assert np.all(theta >= lower - 1e-9) and np.all(theta <= upper + 1e-9)
        inside = np.all(theta_hat >= lower) and np.all(theta_hat <= upper)
        if inside:
            assert np.array_equal(theta, theta_hat)
            continue
        n_projected += 1
        # Remark 1, Eq. (10): distance to theta0 in C is not increased
        assert _metric(P, theta, theta0) <= _metric(P, theta_hat, theta0) * (1 + 1e-9) + 1e-12
        # minimiser: no worse than brute-force BVLS on the full problem, and the same point
        ref = _reference_projection(theta_hat, P, lower, upper)
        f, f_ref = _metric(P, theta, theta_hat), _metric(P, ref, theta_hat)
        assert f <= f_ref * (1 + 1e-8) + 1e-12
        L = np.linalg.cholesky(P)
        assert np.linalg.norm(np.linalg.solve(L, theta - ref)) <= 1e-6 * (1 + math.sqrt(f_ref))
    assert n_projected > 150


@pytest.mark.parametrize("n_boxed", [4, 7])  # 7: the BVLS branch
def test_projection_with_fixed_parameters_is_the_minimiser(n_boxed):
    """A box with parameters fixed (lower == upper) beyond 4 boxed coordinates: BVLS would get a one-ulp box
    for each and stop early in 14 of 200 cases, off the minimum (307.424 against 307.244), so the fixed
    ones are taken out first. Property: within the box, no worse than L-BFGS-B, and the KKT
    conditions of the Eq. (6) metric hold."""
    rng = np.random.default_rng(7)
    for _ in range(150):
        n = n_boxed + int(rng.integers(0, 4))
        P = _random_spd(rng, n, log_cond=rng.uniform(0, 4))
        theta_hat = rng.normal(scale=3.0, size=n)
        lower, upper = np.full(n, -np.inf), np.full(n, np.inf)
        lower[:n_boxed], upper[:n_boxed] = -np.abs(rng.normal(size=n_boxed)), np.abs(rng.normal(size=n_boxed))
        for j in rng.choice(n_boxed, size=int(rng.integers(1, 3)), replace=False):
            lower[j] = upper[j] = rng.normal(scale=0.3)
        theta = project_onto_box(theta_hat, P, lower, upper)
        assert np.all(theta >= lower) and np.all(theta <= upper)
        W = np.linalg.inv(P)
        res = minimize(lambda t: (t - theta_hat) @ W @ (t - theta_hat), x0=np.clip(theta_hat, lower, upper),
                       jac=lambda t: 2 * W @ (t - theta_hat), method="L-BFGS-B",
                       bounds=list(zip(np.where(np.isinf(lower), None, lower), np.where(np.isinf(upper), None, upper))),
                       options=dict(ftol=1e-16, gtol=1e-13, maxiter=20000))
        assert _metric(P, theta, theta_hat) <= res.fun * (1 + 1e-8) + 1e-10
        grad = W @ (theta - theta_hat)  # zero where free; out of the box on a bound (fixed: either sign)
        tol = 1e-6 * (1 + np.max(np.abs(grad)))
        # on a bound to rounding (BVLS ends a few ulp inside)
        with np.errstate(invalid="ignore"):  # an unbounded side: inf - inf, compared False
            at_lo = (theta <= lower + 1e-12 * (1 + np.abs(lower))) & (lower < upper)
            at_hi = (theta >= upper - 1e-12 * (1 + np.abs(upper))) & (lower < upper)
        free = ~at_lo & ~at_hi & (lower < upper)
        assert np.all(np.abs(grad[free]) <= tol)
        assert np.all(grad[at_lo] >= -tol) and np.all(grad[at_hi] <= tol)


def test_projection_is_minimiser_vs_scipy_minimize():
    rng = np.random.default_rng(20)
    for _ in range(20):
        theta_hat, P, lower, upper, _ = _random_case(rng)
        if np.all(theta_hat >= lower) and np.all(theta_hat <= upper):
            continue
        W = np.linalg.inv(P)
        res = minimize(
            lambda t: (t - theta_hat) @ W @ (t - theta_hat),
            x0=np.clip(theta_hat, lower, upper),
            jac=lambda t: 2 * W @ (t - theta_hat),
            bounds=list(zip(np.where(np.isinf(lower), None, lower), np.where(np.isinf(upper), None, upper))),
            method="L-BFGS-B",
            options=dict(ftol=1e-15, gtol=1e-12, maxiter=20000),
        )
        ours = project_onto_box(theta_hat, P, lower, upper)
        assert _metric(P, ours, theta_hat) <= res.fun * (1 + 1e-7) + 1e-10


def test_projection_is_not_elementwise_clip():
    P = np.array([[1.0, 0.9], [0.9, 1.0]])
    theta_hat = np.array([2.0, 0.0])
    lower, upper = np.array([-np.inf, -np.inf]), np.array([1.0, np.inf])
    theta = project_onto_box(theta_hat, P, lower, upper)
    # theta_1 follows the correlation: 0 + 0.9 * (1 - 2)
    np.testing.assert_allclose(theta, [1.0, -0.9], atol=1e-14)
    clipped = np.clip(theta_hat, lower, upper)
    assert _metric(P, theta, theta_hat) == pytest.approx(1.0)
    assert _metric(P, clipped, theta_hat) == pytest.approx(1 / 0.19)
    # both coordinates boxed: the clip corner is not the optimum either
    P2 = np.array([[1.0, -0.8], [-0.8, 1.0]])
    th2 = np.array([3.0, 0.5])
    lo2, hi2 = np.array([0.0, 0.0]), np.array([1.0, 1.0])
    proj = project_onto_box(th2, P2, lo2, hi2)
    ref = _reference_projection(th2, P2, lo2, hi2)
    np.testing.assert_allclose(proj, ref, atol=1e-10)
    assert not np.allclose(proj, np.clip(th2, lo2, hi2))


def test_active_set_fast_path_equals_full_enumeration():
    # the KKT-verified active-set iterations (hot path) against the batched
    # enumeration of all 3^m - 1 active sets (fallback), on 1-3 boxed coordinates
    rng = np.random.default_rng(40)
    n_outside = n_fast = 0
    for case in range(500):
        n = int(rng.integers(3, 16))
        m = int(rng.integers(1, 4))
        P = _random_spd(rng, n, log_cond=rng.uniform(0, 5))
        P = 0.5 * (P + P.T)
        theta_hat = rng.normal(scale=3.0, size=n)
        # as in the controller (a1, a2, b1 = leading block) or scattered
        boxed = np.arange(m) if case % 2 else rng.choice(n, size=m, replace=False)
        lower, upper = np.full(n, -np.inf), np.full(n, np.inf)
        centre = theta_hat[boxed] + rng.normal(scale=2.0, size=m) * (rng.random() < 0.8)
        half = rng.uniform(0.05, 2.0, m) * (rng.random(m) > 0.1)  # some lower == upper
        lower[boxed], upper[boxed] = centre - half, centre + half
        one_sided = rng.random(m) < 0.2
        lower[boxed[one_sided & (rng.random(m) < 0.5)]] = -np.inf
        upper[boxed[one_sided & np.isfinite(lower[boxed])]] = np.inf
        proj = BoxProjector(lower, upper)
        th = theta_hat.tolist()
        if proj.inside(th):
            assert np.array_equal(proj(theta_hat, P), theta_hat)
            continue
        n_outside += 1
        full = proj._enumerate(theta_hat, P)
        forced = BoxProjector(lower, upper)
        forced.max_iterations = 0  # no active-set candidate: the fallback path
        assert np.array_equal(forced(theta_hat, P), full)
        fast = proj._active_set(theta_hat, P, th)
        if fast is None:  # unverified: the public path falls back to the enumeration
            assert np.array_equal(proj(theta_hat, P), full)
            continue
        n_fast += 1
        assert np.array_equal(proj(theta_hat, P), fast)
        # same active set (coordinates exactly on a bound), same point
        for out in (fast, full):
            assert np.all(out >= lower) and np.all(out <= upper)
        assert np.array_equal((fast == lower) | (fast == upper), (full == lower) | (full == upper))
        np.testing.assert_allclose(fast, full, rtol=1e-12, atol=1e-12)
    assert n_outside > 250
    assert n_fast >= n_outside - 5  # the fast path settles (nearly) all cases itself


def test_active_set_hint_changes_the_work_not_the_answer():
    # the estimator first tries the active set theta(k-1) lies on; any hint that passes the KKT
    # test gives the same point, bit for bit, as the cold start from the violated coordinates
    rng = np.random.default_rng(41)
    n_hinted = 0
    for case in range(400):
        n, m = int(rng.integers(4, 16)), int(rng.integers(1, 4))
        P = _random_spd(rng, n, log_cond=rng.uniform(0, 5))
        P = 0.5 * (P + P.T)
        theta_hat = rng.normal(scale=3.0, size=n)
        lower, upper = np.full(n, -np.inf), np.full(n, np.inf)
        centre = theta_hat[:m] + rng.normal(scale=2.0, size=m)
        half = rng.uniform(0.05, 2.0, m)
        lower[:m], upper[:m] = centre - half, centre + half
        proj = BoxProjector(lower, upper)
        th = theta_hat.tolist()
        if proj.inside(th):
            continue
        cold = proj._active_set(theta_hat, P, th)
        if cold is None:
            continue
        for hint in (proj.hint_from(cold), [int(x) for x in rng.integers(-1, 2, m)]):
            hinted = proj._active_set(theta_hat, P, th, hint)
            assert hinted is not None and np.array_equal(hinted, cold), (case, hint)
            n_hinted += 1
    assert n_hinted > 300


def test_estimator_with_hints_equals_cold_projections():
    # the whole constrained estimator, with and without the hint, on data that keep it on the box
    theta_true = ASYMMETRIC.from_dict(TABLE3)
    u = excitation(1500)
    l = generate(theta_true, ASYMMETRIC, u)
    phi, y = _true_regressors(theta_true, ASYMMETRIC, u, l)
    y = y + np.random.default_rng(7).normal(0, 0.05, y.size)
    settings = RLSSettings(p0=(200.0,) * 3 + (50.0,) * 8 + (20.0,) * 4, constraint_start_s=0.0,
                           theta0=tuple(np.clip(theta_true, -5, 5)))
    hinted, cold = ConstrainedRLS(ASYMMETRIC, settings), ConstrainedRLS(ASYMMETRIC, settings)
    cold._projector.hint_from = lambda theta: None
    for p, yy in zip(phi, y):
        assert np.array_equal(hinted.update(p, yy), cold.update(p, yy))
    assert np.array_equal(hinted.P, cold.P)
    assert hinted.n_projections == cold.n_projections > 100


def test_projection_ill_conditioned_all_pinned():
    # cond(P) = 2e6: the optimum pins both coordinates with |P^-1 d| ~ 1e6, so
    # recomputing its pinned coordinates is off by ~1e-10; that must not reject it
    P = np.array([[1.0, 1 - 1e-6], [1 - 1e-6, 1.0]])
    theta_hat = np.zeros(2)
    lower, upper = np.array([1.0, -2.0]), np.array([2.0, -1.0])
    ref = _reference_projection(theta_hat, P, lower, upper)
    proj = BoxProjector(lower, upper)
    for theta in (project_onto_box(theta_hat, P, lower, upper), proj._enumerate(theta_hat, P)):
        assert theta.tolist() == [1.0, -1.0] == ref.tolist()
        assert _metric(P, theta, theta_hat) == pytest.approx(_metric(P, ref, theta_hat), rel=1e-9)


def test_projection_input_validation():
    P = np.eye(3)
    with pytest.raises(ValueError, match="lower"):
        project_onto_box(np.zeros(3), P, [0, 0, 2], [1, 1, 1])
    with pytest.raises(ValueError, match="P must have shape"):
        project_onto_box(np.zeros(3), np.eye(2), [0] * 3, [1] * 3)
    with pytest.raises(ValueError, match="theta_hat"):
        project_onto_box([0, np.nan, 0], P, [0] * 3, [1] * 3)
    with pytest.raises(ValueError, match="upper"):
        project_onto_box(np.zeros(3), P, [0] * 3, [1, np.nan, 1])


def test_constraint_starts_at_120_s_and_keeps_table2_box():
    settings = RLSSettings()
    assert settings.constraint_start_index == 1200
    rng = np.random.default_rng(30)
    rls = ConstrainedRLS(ASYMMETRIC, settings)
    lower, upper = rls.lower, rls.upper
    assert lower[:3].tolist() == [1.208, -0.334, 0.607] and upper[:3].tolist() == [1.260, -0.278, 1.184]
    assert np.all(np.isinf(lower[3:])) and np.all(np.isinf(upper[3:]))
    outside_before = 0
    for k in range(1, 1400):
        theta = rls.update(rng.normal(size=15), rng.normal() * 5)  # theta ~ 0: outside the box
        assert rls.step == k
        if k < 1200:
            outside_before += not (np.all(theta >= lower) and np.all(theta <= upper))
        else:
            assert np.all(theta >= lower) and np.all(theta <= upper)
    assert outside_before == 1199
    # projected at 1200; afterwards only when an update leaves C again
    assert 0 < rls.n_projections <= 200


# ---------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------
def test_settings_validation_names_offending_value():
    with pytest.raises(ValueError, match="p0"):
        RLSSettings(p0=0.0)
    with pytest.raises(ValueError, match="p0"):
        RLSSettings(p0=[1.0] * 14 + [-1.0])
    with pytest.raises(ValueError, match="p0"):
        RLSSettings(p0=math.inf)
    with pytest.raises(ValueError, match="forgetting"):
        RLSSettings(forgetting=0.0)
    with pytest.raises(ValueError, match="forgetting"):
        RLSSettings(forgetting=1.01)
    with pytest.raises(ValueError, match=r"box_lower\['a1'\]"):
        RLSSettings(box_lower={"a1": 2.0}, box_upper={"a1": 1.0})
    with pytest.raises(ValueError, match=r"box_lower\[1\]"):
        RLSSettings(box_lower=[0.0, 2.0], box_upper=[1.0, 1.0])
    with pytest.raises(ValueError, match="box_upper"):
        RLSSettings(box_upper={"b1": math.nan})
    with pytest.raises(ValueError, match=r"box_lower\['a1'\] = inf"):
        RLSSettings(box_lower={"a1": math.inf}, box_upper={})
    with pytest.raises(ValueError, match="theta0"):
        RLSSettings(theta0=[0.0, math.nan])
    with pytest.raises(ValueError, match="ts_s"):
        RLSSettings(ts_s=0.0)
    with pytest.raises(ValueError, match="constraint_start_s"):
        RLSSettings(constraint_start_s=-1.0)
    with pytest.raises(ValueError, match="on_covariance_loss"):
        RLSSettings(on_covariance_loss="ignore")
    with pytest.raises(ValueError, match="inconsistent vector lengths"):
        RLSSettings(p0=[1.0] * 15, theta0=[0.0] * 11)
    with pytest.raises(TypeError):
        RLSSettings(1e3)  # keyword-only
    # defaults are Table 2 and the frozen settings are hashable
    s = RLSSettings()
    assert dict(s.box_lower) == dict(TABLE2_LOWER) and dict(s.box_upper) == dict(TABLE2_UPPER)
    assert hash(s) == hash(RLSSettings()) and s == RLSSettings()


@pytest.mark.parametrize("settings", [RLSSettings(), RLSSettings(p0=[2.0] * 3, theta0=[0.1, 0.2, 0.3], forgetting=0.99,
                                                                 box_lower=[-1.0, -math.inf, 0.0],
                                                                 box_upper=[1.0, 2.0, math.inf])])
def test_settings_copy_and_pickle_as_equal_settings_with_read_only_bounds(settings):
    """A worker process or a deepcopy takes the settings (their bounds are read-only views, which
    pickle cannot take as they are); what comes back is equal and as read-only."""
    for back in (copy.copy(settings), copy.deepcopy(settings), pickle.loads(pickle.dumps(settings))):
        assert back == settings and hash(back) == hash(settings)
        with pytest.raises(TypeError):  # a mapping proxy or a tuple, as the settings made it
            back.box_lower[0 if isinstance(back.box_lower, tuple) else "a1"] = 0.0  # type: ignore[index]


def test_setup_validation_against_structure():
    with pytest.raises(ValueError, match="'xi21'"):
        ConstrainedRLS(STANDARD, RLSSettings(box_lower={"xi21": 0.0}, box_upper={}))
    with pytest.raises(ValueError, match="theta0"):
        ConstrainedRLS(STANDARD, RLSSettings(theta0=[0.0] * 15))
    with pytest.raises(ValueError, match="p0"):
        ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=[1.0] * 11))
    with pytest.raises(RuntimeError, match="setup"):
        ConstrainedRLS().update(np.zeros(15), 0.0)


def test_update_input_validation():
    rls = ConstrainedRLS(ASYMMETRIC)
    phi = np.ones(15)
    phi[4] = np.nan
    with pytest.raises(ValueError, match=r"phi must be finite.*\[4\]"):
        rls.update(phi, 1.0)
    with pytest.raises(ValueError, match=r"phi must have shape \(15,\)"):
        rls.update(np.ones(11), 1.0)
    with pytest.raises(ValueError, match="y must be finite"):
        rls.update(np.ones(15), math.inf)
    with pytest.raises(ValueError, match="state\\['P'\\]"):
        rls.set_state({"theta": np.zeros(15), "P": np.eye(11), "k": 0})
    assert rls.step == 0  # rejected updates leave the estimator untouched


def test_update_projects_with_updated_covariance():
    # Algorithm 1: theta(k) = projection of the Eq. (4) estimate in the P(k-1) metric
    rng = np.random.default_rng(31)
    constrained = ConstrainedRLS(ASYMMETRIC, RLSSettings(constraint_start_s=0.0))
    free = ConstrainedRLS(ASYMMETRIC, RLSSettings(**NO_BOX))
    for _ in range(40):
        phi, y = rng.normal(size=15), 5 * rng.normal()
        free.set_state(constrained.get_state())
        theta_free = free.update(phi, y)
        theta = constrained.update(phi, y)
        assert np.array_equal(constrained.P, free.P)  # projection leaves P alone
        expected = project_onto_box(theta_free, free.P, constrained.lower, constrained.upper)
        np.testing.assert_allclose(theta, expected, rtol=0, atol=1e-12)
    assert constrained.n_projections > 0


def test_an_estimator_of_ones_own_regressors_is_told_about_the_default_box_and_the_set_up():
    """RLSSettings() bounds a1, a2, b1 by name (Table 2): with a model of other parameters the error
    says so and how to drop it; an estimator not set up answers lower/upper/n_projections with
    the set-up's RuntimeError (not a bare AttributeError), as theta does."""
    with pytest.raises(ValueError, match=r"box_lower names unknown parameter 'a1' for the regressor model \(its "
                                         r"parameters: x, y\) \(RLSSettings' default box is Table 2's .* pass "
                                         r"box_lower=\{\}, box_upper=\{\}\)"):
        ConstrainedRLS(Regressors(("x", "y")), RLSSettings())
    rls = ConstrainedRLS(Regressors(("x", "y")), RLSSettings(box_lower={}, box_upper={}))
    assert np.isneginf(rls.lower).all() and rls.n_projections == 0
    for name in ("lower", "upper", "n_projections", "n_resets", "theta"):
        with pytest.raises(RuntimeError, match=r"setup\(structure, settings\) has not been called"):
            getattr(ConstrainedRLS(), name)


def test_rls_with_forgetting_is_exponentially_weighted_regularised_least_squares():
    """Eq. (4) with a forgetting factor lambda < 1 is the batch least squares whose samples weigh
    lambda^(N-1-k) and whose prior weighs lambda^N P(0)^-1 (theta and P both; the batch tests above
    hold at lambda = 1 only)."""
    from fmu_controller.hysteresis_model import ASYMMETRIC
    from fmu_controller.rls import ConstrainedRLS, RLSSettings
    rng = np.random.default_rng(5)
    n, N, lam = 15, 300, 0.97
    phi = rng.normal(size=(N, n))
    y = phi @ rng.normal(size=n) + 0.1 * rng.normal(size=N)
    p0, theta0 = rng.uniform(0.5, 50.0, n), rng.normal(size=n)
    rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(p0=p0, theta0=theta0, forgetting=lam, box_lower={}, box_upper={},
                                                  constraint_start_s=math.inf))
    for p, yy in zip(phi, y):
        rls.update(p, yy)
    w = lam ** np.arange(N - 1, -1, -1)           # lambda^(N-1-k)
    info = lam ** N * np.diag(1 / p0) + (phi * w[:, None]).T @ phi
    theta = np.linalg.solve(info, lam ** N * theta0 / p0 + (phi * w[:, None]).T @ y)
    np.testing.assert_allclose(rls.theta, theta, rtol=0, atol=1e-8)
    np.testing.assert_allclose(rls.P, np.linalg.inv(info), rtol=1e-8, atol=1e-12)


def test_a_box_given_by_name_is_checked_once_for_every_caller():
    """identify's (lower, upper) pairs, an identification file's two maps: one check
    (box_projection.named_box). A numpy pair and a numpy infinity are numbers; an infinity on its
    own side is no bound; what no value satisfies, a crossed bound, NaN and an unknown name are
    refused naming the caller's setting."""
    from fmu_controller.box_projection import box_from_pairs, named_box

    names = ("a1", "a2", "b1")
    assert box_from_pairs({"a1": np.array([0.5, 1.5]), "b1": (np.float32(-np.inf), np.float64(1.2))}, names=names) == \
        ({"a1": 0.5}, {"a1": 1.5, "b1": 1.2})
    assert named_box({"a1": -np.inf}, {"a1": np.inf}, names=names, what="C") == ({}, {})
    for lower, upper, message in (({"a1": 2.0}, {"a1": 1.0}, r"C: a lower bound above its upper one: a1 \(2 > 1\)"),
                                  ({"a1": np.nan}, {}, "C: the lower bound of a1 must be a number, got nan"),
                                  ({"a1": np.inf}, {}, "C: the lower bound of a1 is inf, which no value satisfies"),
                                  ({"zz": 1.0}, {}, r"C: unknown parameter 'zz' in the lower bounds \(the model's "
                                                    r"parameters: a1, a2, b1\)"),
                                  ({"a1": True}, {}, "C: the lower bound of a1 must be a number, got True")):
        with pytest.raises(ValueError, match=message):
            named_box(lower, upper, names=names, what="C")
    for box, message in (({"a1": 1.0}, r"box: a1 must be a pair \(lower, upper\) of numbers, got 1.0"),
                         ({"a1": "0:1"}, "box: a1 must be a pair"), ({"a1": (0, 1, 2)}, "box: a1 must be a pair"),
                         ([("a1", (0, 1))], "box must map parameter names to")):
        with pytest.raises(ValueError, match=message):
            box_from_pairs(box, names=names)
    # a random box's bounds come back as given, each side within the other
    rng = np.random.default_rng(0)
    for _ in range(50):
        lo = dict(zip(names, rng.normal(size=3)))
        hi = {k: v + rng.uniform(0, 2) for k, v in lo.items()}
        got_lo, got_hi = box_from_pairs({k: (lo[k], hi[k]) for k in names}, names=names)
        assert got_lo == lo and got_hi == hi and all(got_lo[k] <= got_hi[k] for k in names)
