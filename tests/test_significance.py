"""The diagnosis's held-out tests: an effect's significance and two explanations' distinguishability
are on the scale of a standard normal under the null, and tell a real difference from noise."""

from __future__ import annotations

import numpy as np

from tapmuscle.diagnosis.significance import distinguishable, significance_test


def test_distinguishable_separates_a_real_difference_from_noise():
    rng = np.random.default_rng(3)
    n = 900
    noise = 0.01 * rng.standard_normal(n)
    wiggle = 0.002 * np.sin(np.arange(n) / 7.0)  # well within the noise
    ok, ev = distinguishable(noise, noise + wiggle, 0.01)
    assert not ok and ev["sse_ratio"] < 1.1
    ok, ev = distinguishable(noise, noise + 0.05 * np.sin(np.arange(n) / 7.0), 0.01)
    assert ok and ev["p_value"] < 1e-3
    # a localised difference (an effect present in a tenth of the held-out samples) counts as well
    local = np.where((np.arange(n) > 300) & (np.arange(n) < 390), 0.05, 0.0)
    assert distinguishable(noise, noise + local, 0.01)[0]


def test_significance_z_is_standard_normal_when_the_held_out_residual_is_noise():
    """The held-out test's z is on the scale of a standard normal under the null (its level alpha
    means what it says): over 400 noise draws, mean within 0.2 of 0 and sd within 10 % of 1."""
    rng = np.random.default_rng(2)
    d = 0.02 * np.sin(np.arange(900) / 9.0)
    z = [significance_test(e0, e0 - d, 0.01, 1e-3)["z"] for e0 in (0.01 * rng.standard_normal(900) for _ in range(400))]
    assert abs(np.mean(z)) < 0.2 and 0.9 < np.std(z) < 1.1, (np.mean(z), np.std(z))


def test_distinguishable_z_is_shifted_standard_normal():
    """Two explanations that differ by delta: z less its expectation |delta| / (2 sigma) has the sd of
    a standard normal over noise draws (within 15 %)."""
    rng = np.random.default_rng(3)
    delta = 0.004 * np.sin(np.arange(900) / 9.0)
    shift = np.linalg.norm(delta) / (2 * 0.01)
    z = [distinguishable(e, e + delta, 0.01, min_ratio=0.0)[1]["z"] - shift
         for e in (0.01 * rng.standard_normal(900) for _ in range(400))]
    assert abs(np.mean(z)) < 0.2 and 0.85 < np.std(z) < 1.15
