"""What recording the diagnosis takes: the blocks and the duration it needs, said as durations."""

from __future__ import annotations

import numpy as np
import pytest

from tapmuscle.diagnosis.usable_recording import validated_recording


def _sine_recording(n, ts_s):
    t = np.arange(n) * ts_s
    return t, 5.0 + 3.0 * np.sin(2 * np.pi * 0.1 * t)


def test_a_quarter_of_the_recording_is_a_block_at_1_ms_too():
    """20 s recorded at 1 ms (``tapmuscle record --ts 0.001``, times written as text) reads back as a
    period of 0.99999999999989 ms, so its duration as 19.9999999999978 s: 5-s blocks, a quarter of
    it, must not be refused as 'at most 5 s'. A block really too long is."""
    t = np.array([float(repr(k * 1e-3)) for k in range(20001)])
    u = 5.0 + 3.0 * np.sin(0.6 * t)
    validated_recording(t, u, u, 5.0)
    with pytest.raises(ValueError, match=r"--block\) = 5.01 s: a 20-s recording needs blocks of .* at most 5 s"):
        validated_recording(t, u, u, 5.01)


@pytest.mark.parametrize("n, ts_s, block_s, words", [
    # 20 s at 0.1 s: too few samples whatever the blocks, and too short for the default ones
    (201, 0.1, None, "the recording lasts 20 s (201 samples at 0.1 s); the diagnosis needs at least 40 s with its "
                     "default 10-s blocks (two training and two held-out blocks at least); shorter blocks (block_s, "
                     "--block) lower that to four times their length, but not below 29.9 s at this sampling period "
                     "(300 samples, for the residual tests)"),
    # 30 s at 0.1 s: samples enough; the default blocks, which the user did not choose, are named as such
    (301, 0.1, None, "the recording lasts 30 s (301 samples at 0.1 s); the diagnosis needs at least 40 s with its "
                     "default 10-s blocks (two training and two held-out blocks at least); shorter blocks (block_s, "
                     "--block) lower that to four times their length: this recording takes blocks of at most 7.5 s"),
    # 1 s at 1 kHz is 1001 samples, far from 40 s: the sample count is not the limit
    (1001, 0.001, None, "the recording lasts 1 s (1001 samples at 0.001 s); the diagnosis needs at least 40 s"),
    # blocks given: only the samples' floor, as a duration at this period
    (201, 0.1, 5.0, "the recording lasts 20 s (201 samples at 0.1 s); the diagnosis needs at least 29.9 s at this "
                    "sampling period (300 samples, for the residual tests)"),
    # a period of 1 s: 300 samples are longer than four default blocks, and the blocks are not mentioned
    (299, 1.0, None, "the recording lasts 298 s (299 samples at 1 s); the diagnosis needs at least 299 s at this "
                     "sampling period (300 samples, for the residual tests)"),
])
def test_a_short_recording_is_refused_with_the_duration_it_needs(n, ts_s, block_s, words):
    """The minimum is a duration (four blocks, 300 samples), not a sample count, and it is said as one."""
    t, u = _sine_recording(n, ts_s)
    with pytest.raises(ValueError) as refused:
        validated_recording(t, u, u, block_s)
    assert str(refused.value).startswith(words)
    # at the limits it states, the recording is taken
    if n == 301:
        validated_recording(t, u, u, 7.5)
    if n == 1001:
        validated_recording(t, u, u, 0.25)
    validated_recording(*_sine_recording(401, 0.1), _sine_recording(401, 0.1)[1], None)
    validated_recording(*_sine_recording(300, 0.1), _sine_recording(300, 0.1)[1], 7.475)
