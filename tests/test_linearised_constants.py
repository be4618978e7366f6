"""The calibrated constants' linearised MAP step (:mod:`tapmuscle.diagnosis.linearised_constants`)."""

from __future__ import annotations

import numpy as np
import pytest

from fmu_plant import PlantParams
from tapmuscle.diagnosis.linearised_constants import LinearisedConstants


#: The relative rounding of :meth:`LinearisedConstants.left_mm2`'s result (24 significant bits).
SNAPPED = 2.0 ** -23


def _random(seed: int, *, k: int = 4, n: int = 120, wide: bool = True) -> tuple[LinearisedConstants, np.ndarray]:
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(n, k))
    x = rng.normal(scale=0.5, size=k)
    lower, upper = (-1e3 * np.ones(k), 1e3 * np.ones(k)) if wide else (x - rng.uniform(0.0, 0.3, k), x + rng.uniform(0.0, 0.3, k))
    lin = LinearisedConstants(PlantParams(), jac, x, rng.random(k) < 0.7, lower, upper, float(rng.uniform(0.05, 2.0)))
    return lin, rng.normal(size=n)


def _map_step_sse(lin: LinearisedConstants, r: np.ndarray, rows: np.ndarray) -> float:
    """The unbounded MAP step in closed form (normal equations)."""
    p = lin.prior.astype(bool)
    A = lin.jacobian[rows]
    P = np.diag(p.astype(float)) * lin.sigma_mm ** 2
    d = np.linalg.solve(A.T @ A + P, -(A.T @ r + P @ lin.x))
    e = r + A @ d
    return float(e @ e + lin.sigma_mm ** 2 * np.sum((lin.x + d)[p] ** 2))


@pytest.mark.parametrize("seed", range(15))
def test_without_active_bounds_it_is_the_map_steps_error(seed):
    lin, r = _random(seed)
    rows = np.arange(len(r))
    # two solvers (bounded least squares on the stacked rows, normal equations) of a well-conditioned
    # problem agree to ~1e-12 of its size, and the result is rounded to 24 significant bits (2**-24
    # relative, for the same bits on every CPU); a missing prior row or a sign error is off by O(1)
    assert lin.left_mm2(r, rows) == pytest.approx(_map_step_sse(lin, r, rows), rel=SNAPPED)


@pytest.mark.parametrize("seed", range(15))
def test_the_step_never_leaves_more_than_no_step_and_bounds_only_raise_it(seed):
    # a law of any minimisation: the step's result is at most the start's (d = 0 is feasible), and a
    # smaller feasible set cannot do better
    lin, r = _random(seed)
    tight, _ = _random(seed, wide=False)
    tight = LinearisedConstants(lin.at, lin.jacobian, lin.x, lin.prior, tight.lower, tight.upper, lin.sigma_mm)
    rows = np.arange(len(r))
    no_step = float(r @ r + lin.sigma_mm ** 2 * np.sum(lin.x[lin.prior] ** 2))
    free, bounded = lin.left_mm2(r, rows), tight.left_mm2(r, rows)
    # each result is rounded to 24 significant bits
    assert free <= no_step * (1 + SNAPPED)
    assert free <= bounded * (1 + SNAPPED) and bounded <= no_step * (1 + SNAPPED)


def test_a_constant_at_its_bound_only_steps_inwards():
    # one constant, at its upper bound, whose data ask for a step further up: it cannot take it
    jac = np.ones((50, 1))
    r = -np.ones(50)  # r + J d is smallest at d = +1
    at_bound = LinearisedConstants(PlantParams(), jac, np.array([2.0]), np.array([False]), np.array([-4.0]),
                                   np.array([2.0]), 0.1)
    inside = LinearisedConstants(PlantParams(), jac, np.array([0.0]), np.array([False]), np.array([-4.0]),
                                 np.array([2.0]), 0.1)
    assert inside.left_mm2(r, np.arange(50)) == pytest.approx(0.0, abs=1e-12)
    # the outward range left for the solver is 1e-9 sd: the error stays that of no step to ~1e-7,
    # rounded to 24 significant bits
    assert at_bound.left_mm2(r, np.arange(50)) == pytest.approx(50.0, rel=1e-7 + SNAPPED)


def test_only_the_chosen_rows_count():
    lin, r = _random(3, n=80)
    rows = np.arange(10, 60, 3)
    assert lin.left_mm2(r[rows], rows) == pytest.approx(_map_step_sse(lin, r[rows], rows), rel=SNAPPED)


@pytest.mark.parametrize("bad, match", [
    (dict(x=np.zeros(3)), "x has shape"),
    (dict(lower=np.zeros(5)), "lower has shape"),
    (dict(sigma_mm=0.0), "sigma_mm"),
    (dict(sigma_mm=float("nan")), "sigma_mm"),
])
def test_inconsistent_parts_are_named(bad, match):
    good = dict(at=PlantParams(), jacobian=np.ones((6, 4)), x=np.zeros(4), prior=np.ones(4, bool),
                lower=-np.ones(4), upper=np.ones(4), sigma_mm=1.0)
    with pytest.raises(ValueError, match=match):
        LinearisedConstants(**(good | bad))


def test_residual_and_rows_must_agree():
    lin, r = _random(0)
    with pytest.raises(ValueError, match="19 residual values for 20 rows"):
        lin.left_mm2(r[:19], np.arange(20))


def test_rows_beyond_the_jacobian_are_named():
    lin, r = _random(0, n=50)
    with pytest.raises(ValueError, match="rows 40..55 reach beyond the Jacobian's 50 samples"):
        lin.left_mm2(np.zeros(16), np.arange(40, 56))
