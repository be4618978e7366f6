"""The cyclic garbage collector paused around a bulk parse (tapmuscle/io/gc_paused.py): off inside,
back to the state it had after, also when the block raises or was entered with it off."""

from __future__ import annotations

import gc

import pytest

from tapmuscle.io.gc_paused import gc_paused


@pytest.fixture
def collector_state():
    enabled = gc.isenabled()
    yield
    (gc.enable if enabled else gc.disable)()


@pytest.mark.parametrize("before", [True, False])
def test_the_collector_is_off_inside_and_as_it_was_after(collector_state, before):
    (gc.enable if before else gc.disable)()
    with gc_paused():
        assert not gc.isenabled()
    assert gc.isenabled() is before
    with pytest.raises(KeyError), gc_paused():
        raise KeyError("x")
    assert gc.isenabled() is before


def test_as_a_decorator_it_keeps_the_function_and_its_signature(collector_state):
    @gc_paused()
    def parse(path: str, *, strict: bool = True) -> bool:
        """Doc."""
        return gc.isenabled()

    gc.enable()
    assert parse("x") is False and gc.isenabled()
    assert parse.__doc__ == "Doc." and list(parse.__wrapped__.__code__.co_varnames[:2]) == ["path", "strict"]
