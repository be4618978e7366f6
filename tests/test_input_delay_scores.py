"""The input-delay hypotheses' scores and their decision rule (``input_delay_samples = -1``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fmu_controller.input_delay_scores import (DELAY_CHECK_SAMPLES, DELAY_CLEAR_RATIO, DELAY_DECIDE_BY_SAMPLES,
                                               DELAY_FORGET, DELAY_MIN_SAMPLES, DELAY_RATIO, DELAY_TIE_RATIO,
                                               DelayScores)
from fmu_controller.preliminary_model import THETA0_44N

THETA0 = np.array(THETA0_44N)


def _scores(ms, compared=DELAY_MIN_SAMPLES, ts_s=0.1):
    s = DelayScores(THETA0, len(ms) - 1, ts_s)
    s.set_state(ms, compared, None)
    return s


def test_nothing_is_decided_before_the_minimum_of_samples():
    assert _scores([1.0, 0.01, 1.0, 1.0, 1.0, 1.0], compared=DELAY_MIN_SAMPLES - 1).verdict(True) is None
    assert _scores([1.0, 0.01, 1.0, 1.0, 1.0, 1.0]).verdict(True) == 1


@pytest.mark.parametrize("servo", [False, True])
def test_each_master_is_decided_once_it_explains_the_data_by_the_ratio(servo):
    """Sequential (0) or parallel (1) where one is DELAY_RATIO times better; neither before it, unless
    DELAY_DECIDE_BY_SAMPLES have been scored, when the better is taken."""
    worse = [1.0, 1.0, 1.0, 1.0]  # the longer delays: no better
    assert _scores([1.0, 0.99 / DELAY_RATIO] + worse).verdict(servo) == 1
    assert _scores([0.99 / DELAY_RATIO, 1.0] + worse).verdict(servo) == 0
    assert _scores([1.0, 1.01 / DELAY_RATIO] + worse).verdict(servo) is None
    assert _scores([1.01 / DELAY_RATIO, 1.0] + worse).verdict(servo) is None
    late = DELAY_DECIDE_BY_SAMPLES
    assert _scores([1.0, 0.999] + [2.0] * 4, compared=late).verdict(servo) == 1
    assert _scores([0.999, 1.0] + [2.0] * 4, compared=late).verdict(servo) == 0


def test_a_delay_between_two_samples_is_the_longer_for_the_servo_law_only():
    """1 and 2 within DELAY_TIE_RATIO: the servo law compensates 2, the coincidence point keeps 1."""
    ms = [2.0, 1.0, 1.0 * DELAY_TIE_RATIO * 0.999, 3.0, 4.0, 5.0]
    assert _scores(ms).verdict(True) == 2
    assert _scores(ms).verdict(False) == 1
    assert _scores(ms).longer_if_tied(4, True) == 4  # 5 scores far worse


def test_a_transport_delay_is_decided_where_the_scores_fall_to_it_from_zero():
    """The valley from 0 through 1: 3 decided at its ratio; a delay behind a bump at 1 is a chatter's
    alias, not taken (0 is, the loop's own) unless it beats 0 and 1 by DELAY_CLEAR_RATIO."""
    valley = [3.0, 2.0, 1.5, 0.9, 1.4, 2.5]
    assert list(_scores(valley).valley_beyond_one()) == [2, 3]
    assert _scores(valley).verdict(False) == 3
    bump = [1.31, 1.86, 1.0, 1.39, 1.24, 1.42]  # a fixed predictor's chatter of two samples
    assert list(_scores(bump).valley_beyond_one()) == []
    assert _scores(bump).verdict(False) == 0
    clear = [1.31, 1.86, 1.31 / DELAY_CLEAR_RATIO * 0.99, 1.39, 1.24, 1.42]
    assert _scores(clear).verdict(False) == 2


def test_the_evidence_against_a_set_delay():
    s = _scores([1.0, 0.5, 2.0, 2.0, 2.0, 2.0], compared=DELAY_CHECK_SAMPLES)
    assert s.checked and s.evidence(0) == (1, 2.0) and s.evidence(1) is None
    assert _scores([1.0, 1.0 / DELAY_RATIO, 2.0, 2.0, 2.0, 2.0]).evidence(0) is None  # not better by the ratio
    assert _scores([1.0, 0.0, 2.0, 2.0, 2.0, 2.0]).evidence(0) == (1, math.inf)
    assert not _scores([1.0] * 6, compared=DELAY_CHECK_SAMPLES - 1).checked


@pytest.mark.parametrize("ts_s", [0.02, 0.1, 0.2])
def test_the_memory_and_the_counts_span_the_same_seconds_at_any_period(ts_s):
    s = DelayScores(THETA0, 5, ts_s)
    assert s.check_n * ts_s == pytest.approx(DELAY_CHECK_SAMPLES * 0.1, abs=ts_s)
    assert s.min_n * ts_s == pytest.approx(DELAY_MIN_SAMPLES * 0.1, abs=ts_s)
    # a step of the mean's memory: 1/forget samples, DELAY_FORGET's 50 samples at 0.1 s
    assert ts_s / s._forget == pytest.approx(0.1 / DELAY_FORGET)


def test_a_scored_sequence_continues_bit_for_bit_from_its_saved_state():
    """Scores of a run, saved half-way and restored into fresh scores, go on as the original."""
    rng = np.random.default_rng(0)
    l = 30.0 + np.cumsum(rng.normal(0.0, 0.3, 80))
    outs = [(float(u), float(u)) for u in rng.uniform(0.0, 10.0, 80 + 6)]
    a = DelayScores(THETA0, 5, 0.1)
    a.start(float(l[0]))
    for k in range(1, 40):
        a.score(float(l[k]), outs[k:k + 6][::-1])
    b = DelayScores(THETA0, 5, 0.1)
    saved = a.get_state()
    b.set_state(saved["delay_scores"], saved["compared"], saved["delay_models"])
    for k in range(40, 80):
        a.score(float(l[k]), outs[k:k + 6][::-1])
        b.score(float(l[k]), outs[k:k + 6][::-1])
    assert a.ms == b.ms and a.compared == b.compared == 79
    assert all(m > 0.0 for m in a.ms)


@pytest.mark.parametrize("scores, compared, match", [
    ([1.0] * 5, 0, r"delay_scores \(6 finite numbers >= 0\)"),
    ([1.0] * 5 + [math.nan], 0, "delay_scores"),
    ([1.0] * 5 + [-1.0], 0, "delay_scores"),
    ([1.0] * 6, -1, "compared"),
])
def test_a_state_no_scores_could_have_saved_is_refused_and_changes_nothing(scores, compared, match):
    s = _scores([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    with pytest.raises(ValueError, match=match):
        s.set_state(scores, compared, None)
    with pytest.raises(ValueError, match="delay_models must hold 6"):
        s.set_state([1.0] * 6, 0, [s.get_state()["delay_models"][0]])
    assert s.ms == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0] and s.compared == DELAY_MIN_SAMPLES
