"""Tests for fmu_controller.hysteresis_model (Eq. (1) in regression form)."""

import math

import numpy as np
import pytest

from fmu_controller.hysteresis_model import (
    ASYMMETRIC,
    PARAMETER_NAMES_ASYMMETRIC,
    PARAMETER_NAMES_STANDARD,
    STANDARD,
    ModelState,
    ModelStructure,
    hysteresis_term,
    identifiable_combinations,
    linear_residual,
    null_direction,
    regressor,
    virtual_hysteresis,
    virtual_hysteresis_sequence,
)
from synthetic import TABLE3, excitation


# ---------------------------------------------------------------------------
def test_structures_and_names():
    assert len(PARAMETER_NAMES_ASYMMETRIC) == 15
    assert PARAMETER_NAMES_STANDARD == PARAMETER_NAMES_ASYMMETRIC[:11]
    assert ASYMMETRIC.n_params == 15 and ASYMMETRIC.names == PARAMETER_NAMES_ASYMMETRIC
    assert STANDARD.n_params == 11 and STANDARD.kind == "standard"
    assert ModelStructure(kind="standard") == STANDARD
    assert ASYMMETRIC.index("xi32") == 14
    with pytest.raises(ValueError, match="kind"):
        ModelStructure(kind="symmetric")
    with pytest.raises(ValueError, match="'xi21'"):
        STANDARD.index("xi21")
    with pytest.raises(TypeError):
        ModelStructure("asymmetric")  # keyword-only


def test_to_from_dict_round_trip():
    theta = ASYMMETRIC.from_dict(TABLE3)
    assert theta[2] == 0.607 and theta[13] == -6.413e-5
    assert ASYMMETRIC.to_dict(theta) == TABLE3
    assert STANDARD.from_dict({"b1": 2.0}).tolist() == [0, 0, 2.0] + [0] * 8
    with pytest.raises(ValueError, match="'bogus'"):
        ASYMMETRIC.from_dict({"bogus": 1.0})
    with pytest.raises(ValueError, match="theta"):
        ASYMMETRIC.to_dict(np.zeros(11))


def test_regressor_matches_paper_vector():
    # phi(k-1) for l(k-1)=3, l(k-2)=2, l(k-3)=5, u(k-1)=7, v(k-2)=-0.5, v(k-3)=0.25
    phi = regressor(3.0, 2.0, 5.0, 7.0, -0.5, 0.25)
    dl1, dl2 = 3.0 - 2.0, 2.0 - 5.0
    expected = [
        3.0, 2.0, 7.0, dl1, dl2,
        abs(dl1) * -0.5, abs(dl2) * 0.25,
        dl1 * 0.5, dl2 * 0.25,
        -0.5, 0.25,
        9.0, 4.0, 27.0, 8.0,
    ]
    np.testing.assert_array_equal(phi, expected)
    np.testing.assert_array_equal(regressor(3.0, 2.0, 5.0, 7.0, -0.5, 0.25, STANDARD), expected[:11])
    # vectorised call broadcasts
    many = regressor(np.array([3.0, 1.0]), 2.0, 5.0, 7.0, -0.5, 0.25)
    assert many.shape == (2, 15)
    np.testing.assert_array_equal(many[0], expected)


def test_sign_convention_absorbs_eq1_minus():
    # theta["beta1"] multiplies +|dl(k-1)| v(k-2): positive coefficient, positive term
    theta = ASYMMETRIC.from_dict({"beta1": 1.0})
    state = ModelState(ASYMMETRIC, l_init=(0.0, 1.0, 4.0), v_init=(0.0, 2.0, 0.0), u_init=0.0)
    # phi(k): |dl(k)| v(k-1) = |4 - 1| * 2 = 6
    assert state.phi() @ theta == pytest.approx(6.0)


def test_model_state_phi_matches_regressor_and_v_definition():
    rng = np.random.default_rng(3)
    theta = ASYMMETRIC.from_dict(TABLE3)
    state = ModelState(ASYMMETRIC, l_init=(10.0, 11.0, 12.5), v_init=(0.1, -0.2, 0.3), u_init=4.0)
    l_hist, v_hist, u_prev = [10.0, 11.0, 12.5], [0.1, -0.2, 0.3], 4.0
    for _ in range(50):
        np.testing.assert_array_equal(
            state.phi(), regressor(l_hist[-1], l_hist[-2], l_hist[-3], u_prev, v_hist[-2], v_hist[-3])
        )
        l_new, u_new = rng.uniform(5, 30), rng.uniform(0, 10)
        v = state.update(l_new, u_new, theta)
        # section 2.3: v(k) = l(k) - [a1 l(k-1) + a2 l(k-2) + b1 u(k-1)]
        assert v == pytest.approx(l_new - (1.26 * l_hist[-1] - 0.288 * l_hist[-2] + 0.607 * u_prev), abs=1e-12)
        assert v == virtual_hysteresis(theta, l_new, l_hist[-1], l_hist[-2], u_prev)
        l_hist.append(l_new)
        v_hist.append(v)
        u_prev = u_new
    assert state.l == tuple(l_hist[-3:]) and state.v == tuple(v_hist[-3:]) and state.u == u_prev


def test_virtual_hysteresis_sequence_matches_scalar():
    rng = np.random.default_rng(4)
    theta = ASYMMETRIC.from_dict(TABLE3)
    l, u = rng.uniform(0, 40, 30), rng.uniform(0, 10, 30)
    v = virtual_hysteresis_sequence(theta, l, u)
    assert v[0] == 0.0 and v[1] == 0.0
    # one expression (linear_residual) serves the record, the scalar and the model state: equal bit for bit
    state = ModelState(ASYMMETRIC, l_init=(l[0], l[0], l[1]), u_init=float(u[1]))
    for k in range(2, 30):
        assert v[k] == virtual_hysteresis(theta, l[k], l[k - 1], l[k - 2], u[k - 1])
        assert v[k] == state.observe(l[k], theta)
        state.apply(float(u[k]))
    assert np.array_equal(linear_residual(l[2:], l[1:-1], l[:-2], u[1:-1], *theta[:3]), v[2:])
    assert linear_residual(3.0, 2.0, 1.0, 5.0, 0.5, 0.25, 0.1) == 3.0 - (1.0 + 0.25 + 0.5)


@pytest.mark.parametrize("structure", [ASYMMETRIC, STANDARD])
def test_within_model_v_equals_previous_hysteresis_term(structure):
    # index subtlety: inside the regression model v(k+1) = H(k), not y_hy(k+1) of Eq. (1)
    theta = ASYMMETRIC.from_dict(TABLE3)[: structure.n_params]
    u = excitation(200, seed=0)
    state = ModelState(structure, l_init=(20.0, 20.0, 20.0), u_init=u[0])
    for k in range(1, 200):
        h = hysteresis_term(theta, state)
        l_next = float(state.phi() @ theta)
        v_next = state.update(l_next, u[k], theta)
        assert v_next == pytest.approx(h, rel=1e-10, abs=1e-10)


@pytest.mark.parametrize("structure", [ASYMMETRIC, STANDARD])
def test_hysteresis_cancellation_linearises_the_model(structure):
    # Eq. (3)/(5): u = u_c - H/b1  =>  l(k+1) = a1 l(k) + a2 l(k-1) + b1 u_c(k)  (Eq. (2))
    theta = ASYMMETRIC.from_dict(TABLE3)[: structure.n_params]
    a1, a2, b1 = theta[:3]
    rng = np.random.default_rng(5)
    state = ModelState(structure, l_init=(20.0, 21.0, 22.0), v_init=(0.5, -0.3, 0.2))
    max_err, max_uncancelled = 0.0, 0.0
    for _ in range(300):
        l_k, l_km1 = state.l[2], state.l[1]
        u_c = rng.uniform(-1.0, 2.0)
        h = hysteresis_term(theta, state)
        state.apply(u_c - h / b1)
        l_next = float(state.phi() @ theta)
        linear = a1 * l_k + a2 * l_km1 + b1 * u_c
        max_err = max(max_err, abs(l_next - linear) / (1 + abs(linear)))
        max_uncancelled = max(max_uncancelled, abs(h))
        state.observe(l_next, theta)
    assert max_err < 1e-12
    assert max_uncancelled > 0.1  # the hysteresis term was not trivially zero


def test_hysteresis_term_uses_no_input():
    theta = ASYMMETRIC.from_dict(TABLE3)
    s1 = ModelState(ASYMMETRIC, l_init=(1.0, 2.0, 3.5), v_init=(0.2, 0.4, -0.1), u_init=0.0)
    s2 = ModelState(ASYMMETRIC, l_init=(1.0, 2.0, 3.5), v_init=(0.2, 0.4, -0.1), u_init=9.0)
    assert hysteresis_term(theta, s1) == hysteresis_term(theta, s2)
    # equals phi(k)^T theta minus the linear part
    expected = s2.phi() @ theta - (theta[0] * 3.5 + theta[1] * 2.0 + theta[2] * 9.0)
    assert hysteresis_term(theta, s2) == pytest.approx(expected, rel=1e-12)
    with pytest.raises(ValueError, match="theta"):
        hysteresis_term(theta[:11], s1)


def test_null_direction_and_identifiable_combinations():
    rng = np.random.default_rng(6)
    n = null_direction(ASYMMETRIC)
    assert n.tolist() == [-1, 1, 0, 1] + [0] * 11
    phis = regressor(*(rng.normal(size=(6, 100)) * 10))
    assert np.max(np.abs(phis @ n)) < 1e-12
    theta = ASYMMETRIC.from_dict(TABLE3)
    combos = identifiable_combinations(theta)
    assert list(combos)[:3] == ["a1+A1", "a2-A1", "b1"]
    assert len(combos) == 14 and "a1" not in combos and "A1" not in combos
    assert combos["a1+A1"] == pytest.approx(1.434) and combos["a2-A1"] == pytest.approx(-0.462)
    moved = identifiable_combinations(theta + 0.37 * n)
    for key in combos:
        assert moved[key] == pytest.approx(combos[key], abs=1e-14)
    assert len(identifiable_combinations(theta[:11], STANDARD)) == 10


def test_model_state_lifecycle_errors_and_validation():
    with pytest.raises(ValueError, match="l_init"):
        ModelState(ASYMMETRIC, l_init=(1.0, 2.0))
    with pytest.raises(ValueError, match="v_init"):
        ModelState(ASYMMETRIC, l_init=(1.0, 2.0, 3.0), v_init=(0.0, math.nan, 0.0))
    state = ModelState(ASYMMETRIC, l_init=(1.0, 2.0, 3.0))
    with pytest.raises(RuntimeError, match="apply"):
        state.phi()
    with pytest.raises(ValueError, match="u must be finite"):
        state.apply(math.inf)
    state.apply(1.0)
    with pytest.raises(ValueError, match="l must be finite"):
        state.observe(math.nan, np.zeros(15))


def test_model_state_get_set_state_round_trip():
    theta = ASYMMETRIC.from_dict(TABLE3)
    u = excitation(60, seed=7)
    a = ModelState(ASYMMETRIC, l_init=(20.0, 20.5, 21.0), u_init=u[0])
    for k in range(1, 30):
        a.update(float(a.phi() @ theta), u[k], theta)
    snap = a.get_state()
    b = ModelState(ASYMMETRIC, l_init=(0.0, 0.0, 0.0))
    b.set_state(snap)
    for k in range(30, 60):
        pa, pb = a.phi(), b.phi()
        assert np.array_equal(pa, pb)
        a.update(float(pa @ theta), u[k], theta)
        b.update(float(pb @ theta), u[k], theta)


@pytest.mark.parametrize("structure", [ASYMMETRIC, STANDARD])
def test_controller_hot_path_helpers_equal_the_public_methods(structure):
    # the controller steps ModelState through plain-float helpers; they must give exactly what
    # phi(), observe() and hysteresis_term() give, so the two paths cannot drift apart
    theta = ASYMMETRIC.from_dict(TABLE3)[: structure.n_params]
    u = excitation(300)
    a = ModelState(structure, l_init=(20.0, 20.5, 21.0), u_init=float(u[0]))
    b = ModelState(structure, l_init=(20.0, 20.5, 21.0), u_init=float(u[0]))
    t = theta.tolist()
    for k in range(1, 300):
        phi = a.phi()
        assert b.phi_list() == phi.tolist()
        l = float(phi @ theta) + 0.01 * math.sin(k)
        assert b.observe_unchecked(l, t[0], t[1], t[2]) == a.observe(l, theta)
        assert b.hysteresis_unchecked(t) == hysteresis_term(theta, a)
        a.apply(float(u[k]))
        b.apply(float(u[k]))
        assert a.get_state() == b.get_state()
    b.observe_unchecked(30.0, *t[:3])
    with pytest.raises(RuntimeError, match="apply"):  # u(k) not applied after l(k)
        b.observe_unchecked(30.1, *t[:3])
    with pytest.raises(RuntimeError, match="apply"):
        b.phi_list()
    with pytest.raises(ValueError, match="non-finite v"):
        ModelState(structure, l_init=(1.0, 1.0, 1.0), u_init=1.0).observe_unchecked(1.0, math.inf, 0.0, 0.0)


def test_a_parameter_vector_from_either_form_a_caller_holds():
    """By name or in order, the same vector; what cannot be one is named, never guessed."""
    theta = ASYMMETRIC.from_dict(TABLE3)
    assert np.array_equal(ASYMMETRIC.as_theta(TABLE3), theta)
    assert np.array_equal(ASYMMETRIC.as_theta(list(theta)), theta)
    assert np.array_equal(ASYMMETRIC.as_theta({"b1": 0.5}, default=0.0), [0, 0, 0.5] + [0] * 12)
    with pytest.raises(ValueError, match=r"theta0 names 1 of the 15 parameters; missing: a1, a2, A1"):
        ASYMMETRIC.as_theta({"b1": 0.5}, what="theta0")
    with pytest.raises(ValueError, match=r"unknown parameter 'B1' .* expected names from a1, a2, b1"):
        ASYMMETRIC.as_theta({**TABLE3, "B1": 1.0})
    with pytest.raises(TypeError, match=r"theta0 must be a mapping name -> value or 15 values .* got str 'a1'"):
        ASYMMETRIC.as_theta("a1", what="theta0")
    with pytest.raises(TypeError, match=r"got NoneType None"):
        ASYMMETRIC.as_theta(None)
    with pytest.raises(ValueError, match=r"must be 11 values \(a1, .*c2\) for the standard model, got shape \(15,\)"):
        STANDARD.as_theta(theta)
    with pytest.raises(ValueError, match=r"theta: gamma1 = nan is not finite"):
        ASYMMETRIC.as_theta({**TABLE3, "gamma1": float("nan")})
    with pytest.raises(ValueError, match=r"theta\['c1'\] = 'big' is not a number"):
        ASYMMETRIC.as_theta({**TABLE3, "c1": "big"})
