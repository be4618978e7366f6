"""Tests for fmu_controller.servo_mpc (section 3.2, Eq. (15)-(20), Table 5).

The reference costs here are written directly from Eq. (15) by simulating the
state space Eq. (17) and the integrator Eq. (18) forward; they do not use the
controller's condensed matrices.
"""

import copy
import dataclasses
import json
import math
import pickle
import re

import numpy as np
import pytest
from scipy.optimize import minimize

from fmu_controller.servo_qp import CondensedServoQP
from fmu_controller.servo_mpc import (
    TABLE5_SERVO,
    ServoMPC,
    ServoMPCResult,
    ServoMPCSettings,
    integrator_step,
)

# Table 2 region of the linear model (a1, a2, b1 [mm/V])
MODEL = (1.21, -0.28, 0.607)


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def forward_cost(D, *, a1, a2, b1, l, lp, ucp, xs, r, settings):
    """Eq. (15) by forward simulation of Eq. (17), (18), (20); also returns predictions."""
    Q, Qs, R = settings.weights()
    hp, hu = settings.hp, settings.hu
    x = (l, lp)               # x(k) = [l(k), l(k-1)]
    uc, s = ucp, xs
    J = float(np.sum(R * np.asarray(D) ** 2))
    pred = []
    for i in range(hp):       # from k+i to k+i+1
        if i < hu:
            uc = uc + D[i]    # Eq. (20); held after Hu-1
        s = s + r[i] - x[0]   # Eq. (18) with l_hat(k|k) = l(k)
        x = (a1 * x[0] + a2 * x[1] + b1 * uc, x[0])
        J += Q[i] * (x[0] - r[i + 1]) ** 2 + Qs[i] * s ** 2
        pred.append(x[0])
    return J, np.array(pred)


def random_case(rng, hp, *, big=False):
    """Data near an operating point; ``big`` gives large reference jumps."""
    l = rng.uniform(20, 50)
    amp = 40.0 if big else 0.3
    return dict(
        l_mm=l, l_prev_mm=l + rng.normal(0, 0.2), uc_prev_v=rng.uniform(4, 6),
        xs=rng.normal(0, 0.3 if not big else 20.0),
        r_future_mm=l + amp * rng.normal(size=hp + 1),
        offset_v=0.0 if not big else rng.normal(0, 3.0),
    )


def brute_force(mpc, case):
    a1, a2, b1 = mpc.model
    kw = dict(a1=a1, a2=a2, b1=b1, l=case["l_mm"], lp=case["l_prev_mm"], ucp=case["uc_prev_v"],
              xs=case["xs"], r=case["r_future_mm"], settings=mpc.settings)
    res = minimize(lambda D: forward_cost(D, **kw)[0], np.zeros(mpc.settings.hu), method="BFGS",
                   options={"gtol": 1e-10, "maxiter": 10_000})
    return res.x, kw


def closed_loop(model, plant, ref, n, *, l0=0.0, settings=None):
    """Plant l(k+1) = a1 l(k) + a2 l(k-1) + b1 u(k) under the controller; offset 0."""
    mpc = ServoMPC(settings, a1=model[0], a2=model[1], b1=model[2])
    hp = mpc.settings.hp
    l = {-1: l0, 0: l0}
    uc, xs = 0.0, 0.0
    u_log = []
    for k in range(n):
        res = mpc.solve(l_mm=l[k], l_prev_mm=l[k - 1], uc_prev_v=uc, xs=xs,
                        r_future_mm=[ref(k + i) for i in range(hp + 1)])
        assert not res.fallback
        u = res.u_v  # Eq. (5) with offset 0
        u_log.append(u)
        l[k + 1] = plant[0] * l[k] + plant[1] * l[k - 1] + plant[2] * u
        xs = integrator_step(xs, ref(k), l[k])
        uc = res.uc_v
    return l, np.array(u_log)


def numbers(res: ServoMPCResult):
    """Everything reproducible in a result (not the wall-clock time)."""
    return (res.uc_v, res.delta_uc_v.tobytes(), res.uc_plan_v.tobytes(), res.predicted_l_mm.tobytes(),
            res.predicted_xs.tobytes(), res.cost, res.status, res.iterations, res.constrained)


# ---------------------------------------------------------------------------
# settings
# ---------------------------------------------------------------------------
def test_defaults_are_table5():
    s = ServoMPCSettings()
    Q, Qs, R = s.weights()
    assert (s.hp, s.hu) == (TABLE5_SERVO["hp"], TABLE5_SERVO["hu"]) == (5, 5)
    np.testing.assert_array_equal(Q, TABLE5_SERVO["q"])
    np.testing.assert_array_equal(Qs, [2.0] * 5)
    np.testing.assert_array_equal(R, [15.0] * 5)
    assert (s.u_min_v, s.u_max_v) == (0.0, 10.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.hp = 3
    with pytest.raises(TypeError):
        ServoMPCSettings(5)  # keyword-only


@pytest.mark.parametrize("kwargs, name", [
    (dict(hp=0), "hp"), (dict(hp=2.5), "hp"), (dict(hp=True), "hp"), (dict(hu=6), "hu"),
    (dict(q=(5.0, 5.0)), "q"), (dict(q=-1.0), "q"), (dict(qs=float("nan")), "qs"),
    (dict(r=0.0), "r"), (dict(r=(1.0, 1.0, 1.0, 1.0, 0.0)), "r"), (dict(r="x"), "r"),
    (dict(r=1e300), "r must be <= 1e"), (dict(qs=2e6), "qs must be <= 1e"), (dict(q=[1.0, 1.0, 1.0, 1.0, 1e7]), "q must be <= 1e"),
    (dict(u_min_v=10.0), "u_max_v"), (dict(u_max_v=math.inf), "u_max_v"),
    (dict(eps_abs=-1e-3), "eps_abs"), (dict(eps_abs=0.0, eps_rel=0.0), "eps_abs"),
    (dict(max_iter=0), "max_iter"), (dict(warm_start=1), "warm_start"), (dict(refine=None), "refine"),
    (dict(always_osqp=1), "always_osqp"),
    (dict(q=0.0, qs=0.0), "q and qs must not both be 0"), (dict(q=(0.0,) * 5, qs=0.0), "q and qs must not both be 0"),
])
def test_settings_validation_names_field(kwargs, name):
    # a value of the wrong kind (2.5 or True for an integer, a string) is a TypeError, a bad value a ValueError
    wrong_kind = any(isinstance(v, (bool, str)) or (k in ("hp", "hu") and isinstance(v, float))
                     for k, v in kwargs.items())
    with pytest.raises(TypeError if wrong_kind else ValueError, match=name):
        ServoMPCSettings(**kwargs)


def test_per_step_weights_are_tuples():
    s = ServoMPCSettings(hp=4, hu=2, q=[1, 2, 3, 4], qs=np.array([0.0, 1, 0, 1]), r=(3, 4))
    assert s.q == (1.0, 2.0, 3.0, 4.0) and s.r == (3.0, 4.0) and isinstance(s.qs, tuple)
    hash(s)


# ---------------------------------------------------------------------------
# unconstrained optimum: OSQP = normal equations = brute force
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("settings", [
    ServoMPCSettings(),
    ServoMPCSettings(hp=7, hu=3, q=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0), qs=0.5, r=(4.0, 9.0, 20.0)),
], ids=["table5", "hp7-hu3-per-step"])
@pytest.mark.parametrize("seed", range(4))
def test_interior_solution_matches_closed_form_and_brute_force(settings, seed):
    rng = np.random.default_rng(seed)
    model = (rng.uniform(1.208, 1.260), rng.uniform(-0.334, -0.278), rng.uniform(0.607, 1.184))
    mpc = ServoMPC(settings, a1=model[0], a2=model[1], b1=model[2])
    case = random_case(rng, settings.hp)
    res = mpc.solve(**case)
    unc = mpc.unconstrained_solution(**case)
    assert res.status == "solved" and not res.constrained and not unc.constrained
    np.testing.assert_allclose(res.delta_uc_v, unc.delta_uc_v, atol=1e-5, rtol=0)

    D_bf, kw = brute_force(mpc, case)
    np.testing.assert_allclose(res.delta_uc_v, D_bf, atol=1e-5, rtol=0)
    np.testing.assert_allclose(unc.delta_uc_v, D_bf, atol=1e-5, rtol=0)
    # the condensed cost and predictions agree with the forward simulation
    J, pred = forward_cost(res.delta_uc_v, **kw)
    assert res.cost == pytest.approx(J, rel=1e-10, abs=1e-9)
    np.testing.assert_allclose(res.predicted_l_mm, pred, rtol=0, atol=1e-10)
    assert res.uc_v == pytest.approx(case["uc_prev_v"] + res.delta_uc_v[0], abs=1e-12)
    np.testing.assert_allclose(res.uc_plan_v, case["uc_prev_v"] + np.cumsum(res.delta_uc_v), atol=1e-12)


def test_integrator_prediction_follows_eq18():
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    rng = np.random.default_rng(7)
    case = random_case(rng, 5)
    res = mpc.solve(**case)
    r, l_hat = np.asarray(case["r_future_mm"]), np.concatenate([[case["l_mm"]], res.predicted_l_mm])
    expected = case["xs"] + np.cumsum(r[:5] - l_hat[:5])
    np.testing.assert_allclose(res.predicted_xs, expected, atol=1e-10)
    assert res.predicted_xs[0] == pytest.approx(integrator_step(case["xs"], r[0], case["l_mm"]), abs=1e-12)


# ---------------------------------------------------------------------------
# constrained optimum
# ---------------------------------------------------------------------------
def test_constrained_cases_feasible_and_no_worse_than_clipping():
    rng = np.random.default_rng(2024)
    n_constrained = n_strictly_better = 0
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    raw = ServoMPC(ServoMPCSettings(refine=False), a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    for _ in range(50):
        model = (rng.uniform(1.208, 1.260), rng.uniform(-0.334, -0.278), rng.uniform(0.607, 1.184))
        mpc.update_model(*model)
        raw.update_model(*model)
        case = random_case(rng, 5, big=True)
        if rng.random() < 0.3:
            case["offset_v"] = rng.choice([-1.0, 1.0]) * rng.uniform(6.0, 15.0)  # pushes u_c out of range
        res = mpc.solve(**case)
        assert res.status == "solved"
        u_plan = res.uc_plan_v - case["offset_v"]
        assert u_plan.min() >= -1e-4 and u_plan.max() <= 10 + 1e-4
        assert 0.0 <= res.u_v <= 10.0 + 1e-12
        clipped = mpc.unconstrained_solution(**case, clip=True)
        u_clip = clipped.uc_plan_v - case["offset_v"]
        assert u_clip.min() >= -1e-9 and u_clip.max() <= 10 + 1e-9
        assert res.cost <= clipped.cost * (1 + 1e-9) + 1e-9
        # the active-set refinement only removes ADMM's ~eps_abs inaccuracy
        res_raw = raw.solve(**case)
        np.testing.assert_allclose(res_raw.uc_plan_v, res.uc_plan_v, atol=1e-5, rtol=0)
        assert res_raw.cost == pytest.approx(res.cost, rel=1e-7)
        assert res.cost <= res_raw.cost * (1 + 1e-12)
        n_constrained += res.constrained
        n_strictly_better += res.cost < clipped.cost * (1 - 1e-6)
    # the property is exercised: most cases hit a bound, clipping is often suboptimal
    assert n_constrained >= 35
    assert n_strictly_better >= 10


def test_constrained_optimum_matches_independent_nlp():
    # SLSQP on the forward-simulated cost with Eq. (19) written on the input sequence
    rng = np.random.default_rng(11)
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    for _ in range(5):
        case = random_case(rng, 5, big=True)
        res = mpc.solve(**case)
        a1, a2, b1 = mpc.model
        kw = dict(a1=a1, a2=a2, b1=b1, l=case["l_mm"], lp=case["l_prev_mm"], ucp=case["uc_prev_v"],
                  xs=case["xs"], r=case["r_future_mm"], settings=mpc.settings)
        off, ucp = case["offset_v"], case["uc_prev_v"]
        cons = [{"type": "ineq", "fun": lambda D: ucp + np.cumsum(D) - off},
                {"type": "ineq", "fun": lambda D: 10.0 - (ucp + np.cumsum(D) - off)}]
        x0 = np.diff(np.clip(np.full(5, ucp), off, off + 10), prepend=ucp)
        scale = forward_cost(x0, **kw)[0]  # SLSQP's line search needs an O(1) objective
        ref = minimize(lambda D: forward_cost(D, **kw)[0] / scale, x0, method="SLSQP", constraints=cons,
                       options={"ftol": 1e-15, "maxiter": 1000})
        assert ref.success
        assert res.cost == pytest.approx(ref.fun * scale, rel=1e-7)
        assert res.cost <= ref.fun * scale * (1 + 1e-12)
        np.testing.assert_allclose(res.uc_plan_v, ucp + np.cumsum(ref.x), atol=1e-3)


def test_offset_shifts_bounds():
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    case = dict(l_mm=30.0, l_prev_mm=30.0, uc_prev_v=4.0, xs=0.0, r_future_mm=[30.0] * 6)
    base = mpc.solve(**case, offset_v=0.0)
    assert not base.constrained
    shifted = mpc.solve(**case, offset_v=-2.0)  # u = u_c + 2 must stay <= 10: fine
    assert not shifted.constrained
    pushed = mpc.solve(**case, offset_v=6.0)    # u_c >= 6 although ~3.46 V would hold 30 mm
    assert pushed.constrained
    assert pushed.uc_v == pytest.approx(6.0, abs=1e-6) and pushed.u_v >= 0.0


# ---------------------------------------------------------------------------
# model update (AMPC)
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("warm", [False, True])
def test_update_model_equals_fresh_controller(warm):
    settings = ServoMPCSettings(warm_start=warm)
    rng = np.random.default_rng(5)
    mpc = ServoMPC(settings, a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    for j in range(12):
        model = (rng.uniform(1.1, 1.3), rng.uniform(-0.4, -0.2), rng.uniform(0.3, 1.5))
        if j == 5:
            model = (0.0, 0.0, 0.9)   # degenerate predictor: the fixed pattern must cope
        case = random_case(rng, 5, big=bool(j % 2))
        warm_vectors = mpc.get_state()
        mpc.update_model(*model)
        assert mpc.model == model
        got = mpc.solve(**case)
        fresh = ServoMPC(settings, a1=model[0], a2=model[1], b1=model[2])
        if warm:  # same starting iterate as the updated controller
            fresh.set_state(warm_vectors | dict(a1=model[0], a2=model[1], b1=model[2]))
        want = fresh.solve(**case)
        np.testing.assert_allclose(got.delta_uc_v, want.delta_uc_v, atol=1e-6, rtol=0)
        np.testing.assert_allclose(got.predicted_l_mm, want.predicted_l_mm, atol=1e-6, rtol=0)
        assert got.cost == pytest.approx(want.cost, rel=1e-9)
        assert got.constrained == want.constrained


def test_model_update_in_place_leaves_no_stale_entries():
    # update_model rewrites only the model-dependent entries of the condensed matrix B in place;
    # after any sequence of models every derived matrix must equal that of a fresh controller
    rng = np.random.default_rng(15)
    weights = ServoMPCSettings().weights()
    qp = CondensedServoQP(5, 5, *weights)
    qp.set_model(*MODEL)
    models = [(rng.uniform(1.1, 1.3), rng.uniform(-0.4, -0.2), rng.uniform(0.3, 1.5)) for _ in range(6)]
    for model in models[:3] + [(0.0, 0.0, 0.9), (2.0, -1.5, -0.7)] + models[3:]:
        qp.set_model(*model)
        fresh = CondensedServoQP(5, 5, *weights)
        fresh.set_model(*model)
        for name in ("B", "gram", "K_unc"):
            assert np.array_equal(getattr(qp, name), getattr(fresh, name)), (model, name)
        assert all(np.array_equal(a, b) for a, b in zip(qp.matrices(), fresh.matrices()))
        # and B is the tabulated affine map of the step response and the rows C A^n
        x = np.zeros(16)
        p, q, srun = 1.0, 0.0, 0.0
        for n in range(5):
            srun += model[2] * p
            p, q = model[0] * p + q, model[1] * p
            x[n], x[5 + n], x[10 + n] = srun, p, q
        x[-1] = 1.0
        np.testing.assert_allclose(qp.B.ravel(), qp.T @ x, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("hp, hu", [(20, 20), (50, 5), (50, 50)])
def test_long_horizons_form_b_directly_as_the_tabulated_map_would(monkeypatch, hp, hu):
    """Beyond MAX_TABULATED the map T (4.7 million entries at Hp = Hu = 50: 1.1 s and 115 MB to build,
    and tens of ms a product under a multi-threaded BLAS on a busy machine, 16 s for a 45-s AMPC-servo
    run) is not built: B is formed from the step response directly, and equals the tabulated B to
    rounding, as do the unconstrained moves."""
    import fmu_controller.servo_qp as servo_qp

    rng = np.random.default_rng(3)
    weights = (rng.uniform(1, 10, hp), rng.uniform(0, 5, hp), rng.uniform(5, 50, hu))
    direct = CondensedServoQP(hp, hu, *weights)
    assert not direct.tabulated and direct._T is None
    monkeypatch.setattr(servo_qp, "MAX_TABULATED", 10 ** 9)
    tabulated = CondensedServoQP(hp, hu, *weights)
    assert tabulated.tabulated
    for model in [MODEL, (1.25, -0.31, 0.7), (0.9, 0.05, 0.2)]:
        direct.set_model(*model)
        tabulated.set_model(*model)
        scale = np.abs(tabulated.B).max()
        np.testing.assert_allclose(direct.B, tabulated.B, rtol=0, atol=1e-13 * scale)
        # -P^{-1} K: B's rounding times P's condition number (2.6e6 at Hu = 50, Table 5's weights), against the gains' size
        gain = np.abs(tabulated.K_unc).max()
        cond = np.linalg.cond(tabulated.gram[:, :hu])
        np.testing.assert_allclose(direct.K_unc, tabulated.K_unc, rtol=0, atol=100 * cond * 1e-16 * gain)
    np.testing.assert_array_equal(direct.T, tabulated.T)  # built on demand: the same integer map, weighted


def test_update_model_does_not_depend_on_warm_start_much():
    # warm vs cold start land on the same optimum (refined on the active set)
    rng = np.random.default_rng(6)
    warm = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    for j in range(12):
        model = (rng.uniform(1.208, 1.260), rng.uniform(-0.334, -0.278), rng.uniform(0.607, 1.184))
        case = random_case(rng, 5, big=bool(j % 2))
        warm.update_model(*model)
        got = warm.solve(**case)
        cold = ServoMPC(a1=model[0], a2=model[1], b1=model[2]).solve(**case)
        np.testing.assert_allclose(got.delta_uc_v, cold.delta_uc_v, atol=1e-6, rtol=0)


# ---------------------------------------------------------------------------
# closed loop
# ---------------------------------------------------------------------------
def test_closed_loop_sine_tracking():
    # section 4.1 reference: 35 mm offset, 30 mm amplitude, 0.1 Hz, Ts = 0.1 s; Eq. (21)
    def ref(k: int) -> float:
        return 35.0 + 30.0 * math.sin(2 * math.pi * 0.1 * k * 0.1)
    l, u = closed_loop(MODEL, MODEL, ref, 402)
    e_bar = np.mean([abs(ref(k) - l[k]) for k in range(101, 402)])
    assert e_bar < 0.5
    assert u.min() >= 0.0 and u.max() <= 10.0


@pytest.mark.parametrize("gain", [1.2, 0.8])
def test_integrator_removes_steady_state_error_under_mismatch(gain):
    plant = (MODEL[0], MODEL[1], MODEL[2] * gain)
    l, u = closed_loop(MODEL, plant, lambda k: 40.0, 300)
    assert abs(40.0 - l[300]) < 0.05
    assert u.min() >= 0.0 and u.max() <= 10.0
    # the servo term does it: with Qs = 0 the same mismatch leaves a >1 mm offset
    l_p, _ = closed_loop(MODEL, plant, lambda k: 40.0, 300, settings=ServoMPCSettings(qs=0.0))
    assert abs(40.0 - l_p[300]) > 1.0


# ---------------------------------------------------------------------------
# state, robustness, output hygiene
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("refine, always_osqp", [(True, False), (False, False), (True, True)])
def test_get_set_state_bit_identical(refine, always_osqp):
    settings = ServoMPCSettings(refine=refine, always_osqp=always_osqp)
    rng = np.random.default_rng(99)
    steps = []
    for j in range(40):
        model = (rng.uniform(1.208, 1.260), rng.uniform(-0.334, -0.278), rng.uniform(0.607, 1.184))
        if j % 4 == 1:
            model = steps[-1][0]  # also steps without a model change
        steps.append((model, random_case(rng, 5, big=bool(j % 3 == 0))))
    a = ServoMPC(settings, a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    snaps, out = [], []
    for model, case in steps:
        snaps.append(a.get_state())
        a.update_model(*model)
        out.append(numbers(a.solve(**case)))
    snaps.append(a.get_state())
    json.dumps(snaps[-1])  # plain python values
    for start in (0, 2, 13, 39):
        b = ServoMPC(settings, a1=1.25, a2=-0.3, b1=1.0)  # different history and model
        b.set_state(snaps[start])
        for i in range(start, len(steps)):
            b.update_model(*steps[i][0])
            assert numbers(b.solve(**steps[i][1])) == out[i]
            assert b.get_state() == snaps[i + 1]  # warm-start vectors too
    # restoring into the same controller works as well
    a.set_state(snaps[20])
    a.update_model(*steps[20][0])
    assert numbers(a.solve(**steps[20][1])) == out[20]
    assert a.get_state() == snaps[21]
    # a copy (or a pickled one) solves on as the original, with a solver of its own
    a.set_state(snaps[20])
    for twin in (copy.copy(a), copy.deepcopy(a), pickle.loads(pickle.dumps(a))):
        twin.update_model(*steps[25][0])  # the copy moves first: the original must not follow
        twin.solve(**steps[25][1])
        twin.set_state(snaps[20])
        for i in range(20, 24):
            a.update_model(*steps[i][0])
            twin.update_model(*steps[i][0])
            assert numbers(a.solve(**steps[i][1])) == numbers(twin.solve(**steps[i][1])) == out[i]
        a.set_state(snaps[20])


def test_osqp_prints_nothing(capfd):
    rng = np.random.default_rng(3)
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    tight = ServoMPC(ServoMPCSettings(max_iter=3), a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    for j in range(50):
        mpc.update_model(rng.uniform(1.208, 1.260), rng.uniform(-0.334, -0.278), rng.uniform(0.607, 1.184))
        case = random_case(rng, 5, big=bool(j % 2))
        mpc.solve(**case)
        tight.solve(**case)
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_fallback_when_osqp_fails(monkeypatch):
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    case = dict(l_mm=10.0, l_prev_mm=10.0, uc_prev_v=1.0, xs=0.0, r_future_mm=[10.0] + [60.0] * 5)
    real_solve = mpc._prob.solve

    def broken(**kw):
        res = real_solve(**kw)
        res.x[:] = np.nan
        res.info.status = "maximum iterations reached"
        return res

    monkeypatch.setattr(mpc._prob, "solve", broken)
    res = mpc.solve(**case)
    clipped = mpc.unconstrained_solution(**case, clip=True)
    assert res.fallback and res.status == "fallback: maximum iterations reached"
    assert np.isfinite(res.delta_uc_v).all() and math.isfinite(res.cost)
    np.testing.assert_array_equal(res.uc_plan_v, clipped.uc_plan_v)
    assert res.constrained and 0.0 <= res.u_v <= 10.0
    monkeypatch.undo()
    assert mpc.solve(**case).status == "solved"  # recovers from the reset warm start


@pytest.mark.parametrize("uc_prev_v, offset_v", [(-3.8e24, 2.0e60), (2.0e60, -2.4e26), (1e29, 5e29)])
def test_data_beyond_osqp_infinity_fall_back_silently(capfd, uc_prev_v, offset_v):
    """A diverged estimate's state (figures from an AMPC-servo run with forgetting 0.5): OSQP would refuse
    the update and print to stdout; the clipped plan is returned instead, silent and within Eq. (19)."""
    mpc = ServoMPC(ServoMPCSettings(always_osqp=True), a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    case = dict(l_mm=31.5, l_prev_mm=31.0, uc_prev_v=uc_prev_v, xs=0.0, r_future_mm=[30.0] * 6, offset_v=offset_v)
    res = mpc.solve(**case)
    assert res.status == "fallback: data beyond OSQP's range" and res.iterations == 0
    np.testing.assert_array_equal(res.uc_plan_v, mpc.unconstrained_solution(**case, clip=True).uc_plan_v)
    assert np.isfinite(res.delta_uc_v).all() and res.u_v == res.uc_v - offset_v
    back = dict(case, uc_prev_v=1.0, offset_v=0.0, r_future_mm=[10.0] + [60.0] * 5)
    assert mpc.solve(**back).status == "solved"  # sane data reach OSQP again
    assert capfd.readouterr() == ("", "")


def test_iteration_limit_never_returns_nan():
    rng = np.random.default_rng(8)
    mpc = ServoMPC(ServoMPCSettings(max_iter=2, warm_start=False), a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    for _ in range(20):
        case = random_case(rng, 5, big=True)
        res = mpc.solve(**case)
        assert res.status != "solved"
        assert np.isfinite(res.delta_uc_v).all() and np.isfinite(res.predicted_l_mm).all()
        u = res.uc_plan_v - case["offset_v"]
        assert u.min() >= -1e-4 and u.max() <= 10 + 1e-4
        assert res.cost <= mpc.unconstrained_solution(**case, clip=True).cost * (1 + 1e-12)


@pytest.mark.parametrize("field, value", [
    ("l_mm", math.nan), ("l_prev_mm", math.inf), ("uc_prev_v", math.nan), ("xs", -math.inf),
    ("offset_v", math.nan), ("r_future_mm", [30.0, 30.0, math.nan, 30.0, 30.0, 30.0]),
    ("r_future_mm", [30.0] * 5), ("r_future_mm", [30.0] * 7), ("r_future_mm", "abc"),
])
def test_bad_solve_input_names_it(field, value):
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    case = dict(l_mm=30.0, l_prev_mm=30.0, uc_prev_v=4.0, xs=0.0, r_future_mm=[30.0] * 6, offset_v=0.0)
    before = mpc.get_state()
    case[field] = value
    with pytest.raises(ValueError, match=field):
        mpc.solve(**case)
    with pytest.raises(ValueError, match=field):
        mpc.unconstrained_solution(**case)
    assert mpc.get_state() == before


@pytest.mark.parametrize("kwargs, name", [
    (dict(a1=math.nan), "a1"), (dict(a2=math.inf), "a2"), (dict(b1=0.0), "b1"),
    (dict(b1=1e-12), "b1"), (dict(b1=math.nan), "b1"),
])
def test_bad_model_names_it(kwargs, name):
    model = dict(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2]) | kwargs
    with pytest.raises(ValueError, match=name):
        ServoMPC(**model)
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    state = mpc.get_state()
    with pytest.raises(ValueError, match=name):
        mpc.update_model(model["a1"], model["a2"], model["b1"])
    with pytest.raises(ValueError, match=name):
        mpc.set_state(state | kwargs)
    assert mpc.model == MODEL and mpc.get_state() == state  # old model kept


def test_settings_type_checked():
    with pytest.raises(ValueError, match="settings"):
        ServoMPC({"hp": 5}, a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])


# ---------------------------------------------------------------------------
# solution strategy: closed-form shortcut, OSQP only when a bound is violated
# ---------------------------------------------------------------------------
def mixed_case(rng, hp):
    """Interior and constrained cases: small and large reference jumps, offsets beyond the range."""
    case = random_case(rng, hp, big=bool(rng.random() < 0.5))
    if rng.random() < 0.25:
        case["offset_v"] = rng.choice([-1.0, 1.0]) * rng.uniform(3.0, 15.0)
    return case


@pytest.mark.parametrize("settings", [
    dict(), dict(refine=False), dict(warm_start=False),
    dict(hp=7, hu=3, q=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0), qs=0.5, r=(4.0, 9.0, 20.0)),
], ids=["table5", "no-refine", "cold", "hp7-hu3-per-step"])
def test_shortcut_matches_osqp_reference(settings):
    # the same sequence of model updates and data through the default controller and
    # through the reference path that sends every sample to OSQP
    fast_settings = ServoMPCSettings(**settings)
    ref_settings = ServoMPCSettings(**settings, always_osqp=True)
    hp = fast_settings.hp
    rng = np.random.default_rng(20)
    fast = ServoMPC(fast_settings, a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    ref = ServoMPC(ref_settings, a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    n_interior = n_constrained = n_exact = 0
    # With refinement both paths return the exact optimum (to rounding) whenever the active
    # set guessed from ADMM's iterates is right. Those iterates' last bits depend on the CPU
    # and BLAS, so on some machines one path's guess misses and that path keeps OSQP's answer,
    # accurate to eps_abs = 1e-7 in the multipliers' scale: the plans then agree to ~1e-6, not
    # to rounding. Every case must agree to OSQP's accuracy and almost every one exactly;
    # refine=False leaves OSQP's answer at eps accuracy everywhere.
    exact, atol = 1e-9, 1e-5
    for _ in range(100):
        model = (rng.uniform(1.208, 1.260), rng.uniform(-0.334, -0.278), rng.uniform(0.607, 1.184))
        fast.update_model(*model)
        ref.update_model(*model)
        case = mixed_case(rng, hp)
        n_calls = fast.osqp_solves
        got, want = fast.solve(**case), ref.solve(**case)
        assert ref.osqp_solves > 0 and want.iterations > 0
        assert got.status == want.status == "solved"
        np.testing.assert_allclose(got.delta_uc_v, want.delta_uc_v, atol=atol, rtol=0)
        np.testing.assert_allclose(got.uc_plan_v, want.uc_plan_v, atol=atol, rtol=0)
        np.testing.assert_allclose(got.predicted_l_mm, want.predicted_l_mm, atol=10 * atol, rtol=0)
        np.testing.assert_allclose(got.predicted_xs, want.predicted_xs, atol=10 * atol, rtol=0)
        n_exact += bool(np.max(np.abs(got.uc_plan_v - want.uc_plan_v)) <= exact)
        assert got.cost == pytest.approx(want.cost, rel=1e-6, abs=1e-9)
        assert got.cost <= want.cost * (1 + 1e-12) + 1e-12  # never worse than the reference
        assert got.constrained == want.constrained
        u = got.uc_plan_v - case["offset_v"]
        assert u.min() >= -1e-9 and u.max() <= 10 + 1e-9
        if got.iterations == 0:
            # shortcut: exactly the closed-form unconstrained minimiser, OSQP not called
            assert fast.osqp_solves == n_calls
            unc = fast.unconstrained_solution(**case)
            np.testing.assert_array_equal(got.delta_uc_v, unc.delta_uc_v)
            n_interior += 1
        else:
            assert fast.osqp_solves == n_calls + 1
            n_constrained += 1
    # both paths are exercised, with active bounds on the OSQP path
    assert n_interior >= 25 and n_constrained >= 25
    if fast_settings.refine:
        assert n_exact >= 90, n_exact


def test_osqp_path_taken_only_when_a_bound_is_violated():
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    case = dict(l_mm=30.0, l_prev_mm=30.0, uc_prev_v=4.0, xs=0.0, r_future_mm=[30.0] * 6)
    interior = mpc.solve(**case, offset_v=0.0)
    assert mpc.osqp_solves == 0
    assert (interior.status, interior.iterations, interior.constrained) == ("solved", 0, False)
    assert mpc.get_state()["y_warm"] == [0.0] * 5  # interior optimum: zero multipliers
    # u_c >= 6 V although ~3.46 V would hold 30 mm: the closed form violates Eq. (19)
    unc = mpc.unconstrained_solution(**case, offset_v=6.0)
    assert unc.uc_plan_v.min() < 6.0
    pushed = mpc.solve(**case, offset_v=6.0)
    assert mpc.osqp_solves == 1
    assert pushed.status == "solved" and pushed.iterations > 0 and pushed.constrained
    assert pushed.uc_v == pytest.approx(6.0, abs=1e-9)
    assert min(mpc.get_state()["y_warm"]) < 0  # OSQP's multiplier of the active lower bound
    ref = ServoMPC(ServoMPCSettings(always_osqp=True), a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    want = ref.solve(**case, offset_v=6.0)
    np.testing.assert_allclose(pushed.uc_plan_v, want.uc_plan_v, atol=1e-9, rtol=0)
    # back inside the bounds: no OSQP again
    assert mpc.solve(**case, offset_v=0.0).iterations == 0 and mpc.osqp_solves == 1


def test_model_reaches_osqp_lazily(monkeypatch):
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    pushes = []
    real_update = mpc._prob.update

    def counting_update(**kw):
        if "Px" in kw:
            pushes.append(kw["Px"].copy())
        return real_update(**kw)

    monkeypatch.setattr(mpc._prob, "update", counting_update)
    interior = dict(l_mm=30.0, l_prev_mm=30.0, uc_prev_v=4.0, xs=0.0, r_future_mm=[30.0] * 6)
    bound = dict(interior, offset_v=6.0)
    models = [(1.22, -0.30, 0.70), (1.24, -0.29, 0.90)]
    for model in models * 3:          # model changes with interior solves only
        mpc.update_model(*model)
        assert mpc.solve(**interior).iterations == 0
    assert pushes == []               # OSQP was not needed, so never updated
    got = mpc.solve(**bound)          # first OSQP solve: the current model is pushed once
    assert len(pushes) == 1 and got.iterations > 0
    mpc.update_model(*models[1])      # unchanged model: nothing to do
    mpc.solve(**bound)
    assert len(pushes) == 1
    mpc.update_model(*models[0])      # A -> B -> A between OSQP solves: OSQP holds the right model
    mpc.update_model(*models[1])
    mpc.solve(**bound)
    assert len(pushes) == 1
    mpc.update_model(*models[0])
    again = mpc.solve(**bound)
    assert len(pushes) == 2
    fresh = ServoMPC(a1=models[0][0], a2=models[0][1], b1=models[0][2])
    want = fresh.solve(**bound)
    np.testing.assert_allclose(again.uc_plan_v, want.uc_plan_v, atol=1e-9, rtol=0)
    assert again.cost == pytest.approx(want.cost, rel=1e-12)


def test_result_arrays_read_only_and_warm_start_unaffected():
    mpc = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    case = dict(l_mm=30.0, l_prev_mm=30.0, uc_prev_v=4.0, xs=0.0, r_future_mm=[30.0] * 6)
    for offset in (0.0, 6.0):  # shortcut and OSQP path
        res = mpc.solve(**case, offset_v=offset)
        for a in (res.delta_uc_v, res.uc_plan_v, res.predicted_l_mm, res.predicted_xs):
            with pytest.raises(ValueError):
                a[0] = 1.0
        assert res.delta_uc_v.shape == (5,) and res.uc_plan_v.shape == (5,)
        assert res.predicted_l_mm.shape == (5,) and res.predicted_xs.shape == (5,)


def test_lean_solve_equals_solve():
    # the controller's hot path returns exactly solve()'s u_c, l_hat(k+1|k) and bound flag, and
    # leaves the same warm start, on interior and constrained (OSQP) samples alike
    rng = np.random.default_rng(21)
    a = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    b = ServoMPC(a1=MODEL[0], a2=MODEL[1], b1=MODEL[2])
    n_osqp = 0
    for j in range(60):
        model = (rng.uniform(1.208, 1.260), rng.uniform(-0.334, -0.278), rng.uniform(0.607, 1.184))
        a.update_model(*model)
        b.update_model_unchecked(*model)
        case = random_case(rng, 5, big=bool(j % 3 == 0))
        want = a.solve(**case)
        got = b.solve_unchecked(case["l_mm"], case["l_prev_mm"], case["uc_prev_v"], case["xs"],
                            case["r_future_mm"].tolist(), case["offset_v"])
        assert got == (want.uc_v, float(want.predicted_l_mm[0]), want.constrained), j
        assert a.get_state() == b.get_state(), j
        n_osqp = b.osqp_solves
    assert 5 < n_osqp < 60  # both paths were taken
    with pytest.raises(ValueError, match="offset_v"):
        b.solve_unchecked(30.0, 30.0, 5.0, 0.0, [30.0] * 6, float("nan"))


# 1e100 overflows the predictions over Hp; 1e20 and 1e6 stay finite, but the move weight R is lost to
# rounding next to them (on any CPU: R is 1e-40 of 1e20**2), so no factorisation can take the Hessian
@pytest.mark.parametrize("a1", [1e100, -1e100, 1e20, 1e6])
def test_an_initial_model_the_qp_cannot_hold_is_named_without_solver_output(a1, capfd):
    with pytest.raises(ValueError, match=re.escape(f"initial model a1 = {a1!r}, a2 = -0.33, b1 = 0.8 over Hp = 5 samples")):
        ServoMPC(ServoMPCSettings(), a1=a1, a2=-0.33, b1=0.8)
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # the ValueError is the whole report (no OSQP "non-convex" on stderr)
