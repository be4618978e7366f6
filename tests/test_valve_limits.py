"""What a command at the valve's limits tells (Eq. (19)): the laws' helpers agree with each other and
with their definitions on a grid of references, readings and commands."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from fmu_controller.valve_limits import (GUARD_JUMP_FRACTION, HELD_AGAINST_MM, VALVE_MAX_V, VALVE_MIN_V,
                                         full_range_jump, held_against_cause, held_against_error, limit_side,
                                         pinned_side, pushed_at_limit)

R_MM = (-5.0, 0.0, 1.0, 1.999, 2.0, 30.0)
U_V = (VALVE_MIN_V, VALVE_MIN_V + 1e-10, 1e-6, 5.0, VALVE_MAX_V - 1e-10, VALVE_MAX_V)


@pytest.mark.parametrize("bounds", [(VALVE_MIN_V, VALVE_MAX_V), (2.0, 8.0)])
def test_pushed_pinned_and_the_limit_side_agree(bounds):
    """Pushed into a limit exactly where pinned to a side, that side is the limit's, and the error
    pushes towards it; within 1 nV of a limit counts as at it (the QP leaves rounding errors)."""
    lo, hi = bounds
    for r, l, u in itertools.product(R_MM, (0.0, 1.0), (lo, lo + 1e-10, 0.5 * (lo + hi), hi - 1e-10, hi)):
        side = pinned_side(r, l, u, lo, hi)
        assert pushed_at_limit(r, l, u, lo, hi) == (side != 0)
        if side:
            assert side == limit_side(u, lo, hi) and np.sign(r - l) == side
        assert limit_side(u, lo, hi) == (-1 if u <= lo + 1e-9 else 1 if u >= hi - 1e-9 else 0)


def test_held_against_the_error_is_the_opposite_limit_by_two_millimetres_elementwise():
    grid = np.array(list(itertools.product(R_MM, (0.0,), U_V)))
    r, l, u = grid.T
    held = held_against_error(r, l, u, VALVE_MIN_V, VALVE_MAX_V)
    for (ri, li, ui), h in zip(grid, held):
        side = limit_side(ui, VALVE_MIN_V, VALVE_MAX_V)
        assert bool(held_against_error(ri, li, ui, VALVE_MIN_V, VALVE_MAX_V)) == h
        # at a limit, with the error pushing away from it by HELD_AGAINST_MM or more
        assert h == (side != 0 and -side * (ri - li) >= HELD_AGAINST_MM), (ri, li, ui)
        # never both: a command held against the error is not pushed into its limit
        assert not (h and pushed_at_limit(ri, li, ui, VALVE_MIN_V, VALVE_MAX_V))


def test_a_full_range_jump_is_the_guards_fraction_of_the_range():
    span = VALVE_MAX_V - VALVE_MIN_V
    assert full_range_jump(VALVE_MAX_V, VALVE_MIN_V, VALVE_MIN_V, VALVE_MAX_V)
    assert full_range_jump(GUARD_JUMP_FRACTION * span, 0.0, VALVE_MIN_V, VALVE_MAX_V)
    assert not full_range_jump(GUARD_JUMP_FRACTION * span * (1 - 1e-9), 0.0, VALVE_MIN_V, VALVE_MAX_V)
    assert full_range_jump(0.0, 8.0, 0.0, 8.0) and not full_range_jump(0.0, 7.0, 0.0, 8.0)  # the law's own range


def test_the_cause_names_a_negative_gain_and_the_name_given():
    assert "b1 > 0" in held_against_cause(-0.2) and "theta0.b1 = -0.2 < 0" in held_against_cause(-0.2)
    assert "model.b1 = -1" in held_against_cause(-1.0, "model.b1")
    assert "wrong way round" in held_against_cause(0.4)
