"""The score test of extra least-squares parameters (:mod:`tapmuscle.diagnosis.score_test`)."""

from __future__ import annotations

import numpy as np
import pytest

from tapmuscle.diagnosis.score_test import score_gain


def _sse_after(b: np.ndarray, cols: np.ndarray) -> float:
    """Least-squares residual sum of squares of ``b + cols @ x`` over ``x`` (the exact refit)."""
    x = np.linalg.lstsq(cols, -b, rcond=None)[0]
    r = b + cols @ x
    return float(r @ r)


@pytest.mark.parametrize("seed", range(20))
def test_on_a_linear_problem_the_gain_is_the_exact_reduction_of_the_refit(seed):
    # the statistic is exact when the residual is linear in the parameters: it must equal the drop of
    # the refitted sum of squares when the columns are added (to rounding)
    rng = np.random.default_rng(seed)
    m, p, q = 200, int(rng.integers(0, 6)), int(rng.integers(1, 3))
    A, E = rng.normal(size=(m, p)), rng.normal(size=(m, q))
    b = rng.normal(size=m) + E @ rng.normal(size=q) + (A @ rng.normal(size=p) if p else 0.0)
    before = _sse_after(b, A) if p else float(b @ b)
    expected = before - _sse_after(b, np.hstack([A, E]))
    got = score_gain(b, A, E)
    # two algorithms (QR + bounded least squares against lstsq) on well-conditioned random problems:
    # they agree to ~1e-13 of the sum of squares on any BLAS; a wrong formula is off by O(1)
    assert got == pytest.approx(expected, rel=1e-6, abs=1e-6 * before)
    assert 0.0 <= got <= before * (1.0 + 1e-6)


@pytest.mark.parametrize("seed", range(10))
def test_columns_the_constants_already_span_gain_nothing(seed):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(150, 4))
    b = rng.normal(size=150)
    E = A @ rng.normal(size=(4, 2))
    assert score_gain(b, A, E) == pytest.approx(0.0, abs=1e-6 * float(b @ b))


def test_a_parameter_at_its_lower_bound_gains_only_by_growing():
    # the residual asks for a negative step along e: allowed for a free parameter, refused for one at
    # its lower bound (a play, a delay switched off); a positive step is granted either way
    rng = np.random.default_rng(3)
    A, e = rng.normal(size=(100, 2)), rng.normal(size=(100, 1))
    b = 0.7 * e[:, 0] + 0.01 * rng.normal(size=100)  # minimised by x_e = -0.7
    free = score_gain(b, A, e)
    assert free > 0.5 * float(b @ b)
    assert score_gain(b, A, e, [True]) == pytest.approx(0.0, abs=1e-6 * float(b @ b))
    assert score_gain(-b, A, e, [True]) == pytest.approx(free, rel=1e-6)


def test_a_zero_column_gains_nothing_and_does_not_fail():
    rng = np.random.default_rng(4)
    assert score_gain(rng.normal(size=50), rng.normal(size=(50, 3)), np.zeros((50, 1))) == 0.0
