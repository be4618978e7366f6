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


def test_a_parameter_at_its_upper_bound_gains_only_by_falling():
    # the mirror image: an amplifier map's output at 10 V may only fall; with two columns, the bound
    # holds on its own column while the other stays free
    rng = np.random.default_rng(5)
    A, E = rng.normal(size=(120, 3)), rng.normal(size=(120, 2))
    b = -0.5 * E[:, 0] + 0.01 * rng.normal(size=120)  # minimised by x_0 = +0.5, x_1 = 0
    free = score_gain(b, A, E)
    assert free > 0.5 * float(b @ b)
    # the free column only takes its chance correlation with the bound one (~1/sqrt(120) in amplitude)
    assert score_gain(b, A, E, nonpositive=[True, False]) < 0.05 * free
    assert score_gain(b, A, E, nonpositive=[False, True]) == pytest.approx(free, rel=1e-3)
    assert score_gain(-b, A, E, nonpositive=[True, False]) == pytest.approx(free, rel=1e-6)
    # pinned both ways (bounds lo == hi): no step at all
    assert score_gain(b, A, E[:, :1], [True], [True]) == 0.0


def test_bound_flags_of_the_wrong_length_are_refused_naming_them():
    rng = np.random.default_rng(6)
    with pytest.raises(ValueError, match="nonpositive has 1 entries for 2"):
        score_gain(rng.normal(size=30), rng.normal(size=(30, 2)), rng.normal(size=(30, 2)), nonpositive=[True])


def test_a_zero_column_gains_nothing_and_does_not_fail():
    rng = np.random.default_rng(4)
    assert score_gain(rng.normal(size=50), rng.normal(size=(50, 3)), np.zeros((50, 1))) == 0.0
