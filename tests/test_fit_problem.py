"""``Problem``'s margins of "as good" on the training blocks (tapmuscle/diagnosis/fit_problem.py)."""

import numpy as np
import pytest

from tapmuscle.diagnosis.fit_problem import Problem
from tapmuscle.diagnosis.residual_analysis import interleaved_split


def _problem(noise_mm: float = 0.01) -> Problem:
    t = np.arange(1801) * 0.1
    train, test = interleaved_split(t.size, 0.1, 10.0)
    return Problem(np.zeros_like(t), t, np.zeros_like(t), 0.1, train, test, None, noise_mm)


def test_as_good_is_the_plateau_near_the_noise_and_ten_samples_of_the_residual_above_it():
    pr = _problem(0.01)
    # near the noise: ten samples' noise variance (1e-3 mm^2) is the wider margin
    assert pr.as_good(0.05, 900) == pr.plateau(0.05) == pytest.approx(0.051)
    # model error (seed 3's field case 047: 2013 mm^2 over 900 training samples): ten samples' worth
    assert pr.as_good(2013.0, 900) == pytest.approx(2013.0 + 10.0 * 2013.0 / 900.0)
    assert pr.plateau(2013.0) == pytest.approx(2013.0 * 1.001)
    # never narrower than the plateau, rising with the cost, and fewer samples widen it
    bests = np.geomspace(1e-4, 1e5, 60)
    for n in (1, 10, 900):
        margins = np.array([pr.as_good(b, n) for b in bests])
        assert np.all(margins >= [pr.plateau(b) for b in bests])
        assert np.all(np.diff(margins) > 0)
    assert pr.as_good(100.0, 10) > pr.as_good(100.0, 900)
    assert pr.as_good(100.0, 0) == pytest.approx(100.0 + 10.0 * 100.0)  # no samples counted: one
