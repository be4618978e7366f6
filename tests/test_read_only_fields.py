"""The settings dataclasses with mapping fields (Algorithm 1's box C by parameter name) are values: a
bound cannot be changed in place, equal settings hash alike, and copies and pickles come back equal
and as read-only (a process pool or a Dask worker takes them)."""

from __future__ import annotations

import copy
import pickle
from dataclasses import replace

import pytest

from fmu_controller.displacement_control import ControllerSettings
from fmu_controller.rls import RLSSettings


@pytest.mark.parametrize("cls", [ControllerSettings, RLSSettings])
def test_a_bound_cannot_be_changed_in_place_nor_through_the_callers_dict(cls):
    mine = {"b1": 0.5, "a1": 1.0}
    settings = cls(box_lower=mine)
    with pytest.raises(TypeError):
        settings.box_lower["b1"] = 5.0  # type: ignore[index]
    mine["b1"] = 5.0  # the caller's dict stays the caller's
    assert settings.box_lower["b1"] == 0.5 and settings == cls(box_lower={"b1": 0.5, "a1": 1.0})


@pytest.mark.parametrize("cls", [ControllerSettings, RLSSettings])
def test_equal_settings_hash_alike_and_copies_and_pickles_come_back_equal_and_read_only(cls):
    settings = cls(box_lower={"b1": 0.5}, box_upper={"b1": 1.5, "a2": -0.2})
    assert hash(settings) == hash(cls(box_lower={"b1": 0.5}, box_upper={"a2": -0.2, "b1": 1.5}))
    assert settings != cls() and len({settings, cls(), replace(settings)}) == 2
    for back in (copy.copy(settings), copy.deepcopy(settings), pickle.loads(pickle.dumps(settings)), replace(settings)):
        assert back == settings and hash(back) == hash(settings)
        with pytest.raises(TypeError):
            back.box_upper["b1"] = 0.0  # type: ignore[index]


def test_controller_settings_of_other_fields_are_unequal_and_hash_as_values():
    """The hash covers every field, not only the bounds: settings that differ elsewhere are told apart
    in a set (a sweep's distinct controller configurations)."""
    a, b = ControllerSettings(method="ampc_servo"), ControllerSettings(method="mpc_servo")
    assert a != b and len({a, b, ControllerSettings(method="mpc_servo")}) == 2
