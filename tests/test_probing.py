"""The start-up mode's probing signal (fmu_controller.probing)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import max_len_seq

from fmu_controller.probing import MLS_BITS, MLS_LENGTH, PROBING_HOLD_SAMPLES, max_length_sequence, probe_v, probing_phases


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


def test_a_phase_starts_the_sequence_at_another_bit():
    for phase in (1, 13, 111, MLS_LENGTH - 1):
        shifted = [probe_v(j, 0.5, phase) for j in range(4 * MLS_LENGTH)]
        assert shifted == [probe_v(j + PROBING_HOLD_SAMPLES * phase, 0.5) for j in range(4 * MLS_LENGTH)]
    assert [probe_v(j, 0.5, MLS_LENGTH) for j in range(40)] == [probe_v(j, 0.5) for j in range(40)]


def _correlation(phases, warm):
    probes = np.array([[probe_v(j, 1.0, p) for j in range(1, warm)] for p in phases])
    c = np.corrcoef(probes)
    return np.max(np.abs(c - np.eye(len(phases))))


@pytest.mark.parametrize("warm", [60, 120, 30])
def test_the_phases_chosen_probe_unlike_each_other_over_the_warm_up(warm):
    # a phase at random repeats much of another over a short warm-up (0 and 96 over 60 samples: 0.66);
    # the chosen pair is the least alike of all 126 (greedy from 0, so the pair is exact)
    pair = probing_phases(2, warm)
    assert pair[0] == 0 and len(set(pair)) == 2
    assert _correlation(pair, warm) == pytest.approx(min(_correlation((0, p), warm) for p in range(1, MLS_LENGTH)))
    assert _correlation(pair, warm) < 0.1
    four = probing_phases(4, warm)
    assert len(set(four)) == 4 and _correlation(four, warm) < 0.25
    assert _correlation((0, 96), 60) > 0.6  # why a phase is not any phase


def test_short_warm_ups_take_phases_whose_probes_differ():
    # over 4 or 8 samples (two or three bits) many probes are constant: compared by sign, the first two
    # chosen differ
    for warm in (5, 9):
        phases = probing_phases(3, warm)
        probes = [[probe_v(j, 1.0, p) for j in range(1, warm)] for p in phases]
        assert probes[0] != probes[1]
    assert probing_phases(2, np.int64(60)) == probing_phases(2) == (0, 109)


@pytest.mark.parametrize("count, warm", [(0, 60), (128, 60), (2.0, 60), (True, 60), (2, 4), (2, 60.0)])
def test_probing_phases_refuses_what_is_no_count_or_warm_up(count, warm):
    with pytest.raises(ValueError, match="must be an integer"):
        probing_phases(count, warm)
