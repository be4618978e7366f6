"""The guards on a controller's readings, alone (the closed-loop cases are in test_displacement_control.py)."""

from __future__ import annotations

import math

import pytest

from fmu_controller.reading_guards import (HELD_READINGS_MAX, REPEAT_MOVE_MM, SPIKE_MM, STUCK_AT_LIMIT_S,
                                           ReadingGuard)

TS = 0.1
MAX_JUMP = 40.0  # 400 mm/s at 0.1 s


def _guard(**kw):
    return ReadingGuard(kw.pop("max_jump", MAX_JUMP), TS, 6, 0.0, 10.0)


def _settled(guard, n=200, error=0.1):
    """``n`` ordinary samples of a muscle moving 1 mm a sample, predicted to ``error`` mm; the last
    reading used, and the next sample."""
    l = 0.0
    for k in range(1, n + 1):
        l += 1.0
        assert guard.check(l, k, l - error, l - 1.0, l - 2.0, 35.0, 5.0, True) == l
    return l, n + 1


def test_a_glitch_is_replaced_by_the_prediction_until_it_lasts_as_a_new_level():
    g = _guard()
    l, k = _settled(g)
    for i in range(HELD_READINGS_MAX):
        assert g.check(l + 100.0, k + i, l + 1.0, l, l - 1.0, 35.0, 5.0, True) == l + 1.0
        assert g.reading_held == (l + 100.0, l + 1.0, l) and g.spike_limit_mm is None
    assert g.check(l + 100.0, k + HELD_READINGS_MAX, l + 1.0, l, l - 1.0, 35.0, 5.0, True) == l + 100.0
    assert g.reading_held is None


def test_a_spike_is_held_once_and_only_where_the_guards_act():
    g = _guard()
    l, k = _settled(g)
    spike = l + 1.0 + 2 * SPIKE_MM
    assert g.check(spike, k, l + 1.0, l, l - 1.0, 35.0, 5.0, False) == spike  # in the start-up: used
    g = _guard()
    l, k = _settled(g)
    assert g.check(spike, k, l + 1.0, l, l - 1.0, 35.0, 5.0, True) == l + 1.0
    assert g.reading_held == (spike, l + 1.0, l) and g.spike_limit_mm == SPIKE_MM


def test_a_repeat_is_stale_only_the_first_time_and_where_the_prediction_moves():
    g = _guard()
    l, k = _settled(g)
    moved = l + 1.0 + REPEAT_MOVE_MM
    assert g.check(l, k, moved, l, l - 1.0, 35.0, 5.0, True) == moved
    assert g.reading_held == (l, moved, l)
    # the same reading again: a muscle that stopped, used (the last one used was the prediction)
    assert g.check(l, k + 1, moved + 1.0, moved, l, 35.0, 5.0, True) == l and g.reading_held is None
    g = _guard()
    l, k = _settled(g)
    assert g.check(l, k, l + 0.5, l, l - 1.0, 35.0, 5.0, True) == l  # the prediction moves too little
    assert g.reading_held is None


def test_a_stuck_reading_is_told_once_after_both_limits_and_is_used():
    g = _guard(max_jump=0.0)
    n = math.ceil(STUCK_AT_LIMIT_S / TS)
    told = []
    for k in range(4 * n):
        u = 0.0 if k <= n else 10.0
        assert g.check(12.5, k, math.nan, 12.5, 12.5, 35.0, u, False) == 12.5
        if g.reading_stuck is not None:
            told.append((k, g.reading_stuck))
    # n samples after the lower limit (k = 1 .. n), then n after the upper: told at 2n, unchanged 2n samples
    assert told == [(2 * n, (12.5, 2 * n * TS))]


@pytest.mark.parametrize("field, value", [("held_in_a_row", HELD_READINGS_MAX + 1), ("still", [1.0, 2, 3, 4, False]),
                                          ("spike", [-1.0, 0.0, 0, 0.0, 0.0])])
def test_a_state_no_guard_could_have_saved_is_refused_naming_the_field_and_changes_nothing(field, value):
    g = _guard()
    _settled(g, n=30)
    saved = g.get_state()
    with pytest.raises(ValueError, match=f"state field {field} ="):
        g.set_state({**saved, field: value})
    assert g.get_state() == saved
