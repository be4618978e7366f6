"""The start-up mode's probing signal (fmu_controller.probing)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import max_len_seq

from fmu_controller.probing import MLS_BITS, PROBING_HOLD_SAMPLES, max_length_sequence, probe_v


def test_the_sequence_is_scipys_maximum_length_sequence():
    ours = max_length_sequence(MLS_BITS)
    assert ours == tuple(int(b) for b in max_len_seq(MLS_BITS)[0])
    assert len(ours) == 127 and sum(ours) == 64  # an m-sequence has 2^(n-1) ones


def test_the_sequence_is_white_and_the_signal_balanced():
    """The laws that make it a probing input: the circular autocorrelation of the +-1 sequence is
    N at lag 0 and -1 at every other lag, and one period of the probe averages to A/N."""
    s = 2.0 * np.array(max_length_sequence()) - 1.0
    n = len(s)
    acf = np.array([s @ np.roll(s, lag) for lag in range(n)])
    assert acf[0] == n and np.all(acf[1:] == -1.0)
    period = [probe_v(j, 0.5) for j in range(n * PROBING_HOLD_SAMPLES)]
    assert set(period) == {-0.5, 0.5}
    assert abs(np.mean(period) - 0.5 / n) < 1e-12


def test_each_bit_is_held_and_the_sequence_repeats():
    n = len(max_length_sequence())
    h = PROBING_HOLD_SAMPLES
    for j in range(0, 3 * n * h, h):
        assert len({probe_v(j + i, 1.0) for i in range(h)}) == 1
    assert [probe_v(j, 1.0) for j in range(n * h)] == [probe_v(j + n * h, 1.0) for j in range(n * h)]


def test_only_the_tabulated_register_length():
    with pytest.raises(ValueError, match="nbits"):
        max_length_sequence(8)
