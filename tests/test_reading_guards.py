"""The guards on a controller's readings, alone (the closed-loop cases are in test_displacement_control.py)."""

from __future__ import annotations

import math

import pytest

from fmu_controller.reading_guards import (HELD_READINGS_MAX, REPEAT_MOVE_MM, SPIKE_MM, STUCK_AT_LIMIT_S,
                                           ReadingGuard, real_move_message, settle_samples)

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
                                          ("spike", [-1.0, 0.0, 0, 0.0, 0.0]), ("last_held", ["glitch", 3, 1.0]),
                                          ("last_held", ["spike", -1, 1.0]), ("last_held", ["repeat", 3, math.nan])])
def test_a_state_no_guard_could_have_saved_is_refused_naming_the_field_and_changes_nothing(field, value):
    g = _guard()
    _settled(g, n=30)
    saved = g.get_state()
    with pytest.raises(ValueError, match=f"state field {field} ="):
        g.set_state({**saved, field: value})
    assert g.get_state() == saved


def _held(kind):
    """A guard that has just held a spike (``kind`` "spike": 2 SPIKE_MM above its prediction) or a stale
    repeat ("repeat": the prediction 2 REPEAT_MOVE_MM on), after a settled run of 1 mm a sample; the held
    reading, the prediction used instead, and the next sample."""
    g = _guard()
    l, k = _settled(g)
    predicted = l + (1.0 if kind == "spike" else 2 * REPEAT_MOVE_MM)
    held = predicted + 2 * SPIKE_MM if kind == "spike" else l
    assert g.check(held, k, predicted, l, l - 1.0, 35.0, 5.0, True) == predicted
    assert g.reading_held == (held, predicted, l) and g.held_reading_real is None
    return g, held, predicted, k + 1


@pytest.mark.parametrize("kind", ["spike", "repeat"])
def test_a_held_reading_the_next_one_stays_by_is_told_the_muscles_own_and_the_guards_wait(kind):
    """A supply lost moves the muscle off its model's track within a sample (the reading after a spike
    stays by it) or stops it (the reading after a repeat repeats it): the hold was the muscle's own."""
    g, held, used, k = _held(kind)
    nxt = held - 0.01 if kind == "spike" else held  # a muscle that went there (the encoder's noise), or stopped
    predicted = used + 1.0  # the model's track, from the value used
    assert g.check(nxt, k, predicted, used, held, 35.0, 5.0, True) == nxt
    assert g.held_reading_real == (kind, held, nxt, predicted)
    message = real_move_message(*g.held_reading_real)
    assert f"l = {held:g} mm, was the muscle's own" in message and f"{abs(nxt - predicted):.3g} mm from" in message
    assert ("as a one-sample spike" in message) == (kind == "spike")
    assert ("as a stale sample" in message) == (kind == "repeat")
    # the guards wait a reference step's transient: a spike and a stale repeat within it are used, a
    # spike after it is held
    wait = settle_samples(TS)
    l = nxt
    for i in range(1, wait + 4):
        if i in (5, 10):  # a spike, a repeat
            reading, predicted = (l + 1.0 + 2 * SPIKE_MM, l + 1.0) if i == 5 else (l, l + 2 * REPEAT_MOVE_MM)
        elif i == wait + 3:
            reading, predicted = l + 1.0 + 2 * SPIKE_MM, l + 1.0
        else:
            reading, predicted = l + 1.0, l + 0.9
        got = g.check(reading, k + i, predicted, l, l - 1.0, 35.0, 5.0, True)
        assert (got == reading) == (i < wait + 3) and g.held_reading_real is None
        l = got if i not in (5, 10) else predicted  # the far ones off the track: the next ordinary from it


@pytest.mark.parametrize("kind", ["spike", "repeat"])
def test_a_held_reading_the_next_one_leaves_for_the_models_track_stays_the_sensors(kind):
    g, held, used, k = _held(kind)
    predicted = used + 1.0
    nxt = predicted + 0.3  # back on the track: the sensor's spike, the DAQ's stale sample
    assert g.check(nxt, k, predicted, used, held, 35.0, 5.0, True) == nxt
    assert g.held_reading_real is None
    # and only the sample after it is judged
    g, held, used, k = _held(kind)
    state = g.get_state()
    g.set_state({**state, "last_held": [kind, k - 2, held]})
    assert g.check(held, k, used + 1.0, used, held, 35.0, 5.0, True) is not None and g.held_reading_real is None


@pytest.mark.parametrize("kind", ["spike", "repeat"])
def test_a_state_saved_between_a_hold_and_its_verdict_gives_the_same_verdict(kind):
    g, held, used, k = _held(kind)
    saved = g.get_state()
    assert saved["last_held"] == [kind, k - 1, held]
    again = _guard()
    again.set_state(saved)
    for guard in (g, again):
        guard.check(held, k, used + 1.0, used, held, 35.0, 5.0, True)
    assert g.held_reading_real == again.held_reading_real == (kind, held, held, used + 1.0)
    assert g.get_state() == again.get_state()
    # a state saved without the field (an earlier build's): no verdict pending
    old = {key: value for key, value in saved.items() if key != "last_held"}
    again.set_state(old)
    again.check(held, k, used + 1.0, used, held, 35.0, 5.0, True)
    assert again.held_reading_real is None


def test_a_reading_out_of_reach_of_a_used_spike_but_within_reach_of_the_one_before_is_used():
    """A 30-mm spike used (the guard waiting, or its limit above 30 mm); the law answers it, and the next
    reading is more than a sample's reach (40 mm) from the spike but 12 mm from the reading before it:
    the spike missed its prediction by more than that, so it was the odd one out, and the reading is
    the muscle's (holding it, and the two after, as glitches sent the valve to a limit for 0.3 s and the
    muscle 45 mm past the reference)."""
    g = _guard()
    l, k = _settled(g)
    state = g.get_state()
    g.set_state({**state, "spike": [3.5, *state["spike"][1:]]})  # a loop whose errors ran high: limit 35 mm
    spike = l - 30.0
    assert g.check(spike, k, l + 1.0, l, l - 1.0, 35.0, 5.0, True) == spike  # under the limit: used
    nxt = l + 12.0
    assert abs(nxt - spike) > MAX_JUMP and abs(nxt - l) < MAX_JUMP
    assert g.check(nxt, k + 1, spike - 1.0, spike, l, 35.0, 10.0, True) == nxt and g.reading_held is None
    # a reading beyond reach of both is a glitch still
    g = _guard()
    l, k = _settled(g)
    assert g.check(spike, k, l + 1.0, l, l - 1.0, 35.0, 5.0, False) == spike
    assert g.check(l + 45.0, k + 1, spike - 1.0, spike, l, 35.0, 10.0, True) == spike - 1.0


def test_spikes_every_few_samples_do_not_raise_the_spike_limit_out_of_their_reach():
    """30-mm spikes every 20 samples of a settled run (errors 0.1 mm), none held while the guard is
    off: counted whole they raised the running mean to several millimetres and the limit (10 times it)
    above 30 mm; counted as at most SPIKE_MEAN_CAP times the mean, the limit stays near SPIKE_MM."""
    from fmu_controller.reading_guards import SPIKE_MEAN_CAP, SPIKE_SPREAD

    g = _guard()
    l, k = _settled(g, n=50)
    for i in range(400):
        l += 1.0
        reading = l - 30.0 if i % 20 == 0 else l
        g.check(reading, k + i, l - 0.1, l - 1.0, l - 2.0, 35.0, 5.0, False)
    mean = g.get_state()["spike"][0]
    assert SPIKE_MEAN_CAP == 5.0 and mean < 0.5 and max(SPIKE_MM, SPIKE_SPREAD * mean) < 30.0
