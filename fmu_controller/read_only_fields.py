"""Frozen settings dataclasses whose fields include mappings (a constraint box by parameter name).

A frozen dataclass stops ``settings.box_lower = ...`` but not ``settings.box_lower["b1"] = 0.1``
on a dict field, and its generated hash fails on the dict. The settings keep such a field as a
read-only view (:func:`read_only`); :func:`settings_hash` and :func:`settings_reduce` give the
class a hash of its values and a pickle (and ``copy.deepcopy``), which a read-only view cannot
take, so that settings are equal, hashable and picklable values, shipped to worker processes and
Dask workers as they are.
"""

from __future__ import annotations

from dataclasses import fields
from types import MappingProxyType
from typing import Any, Mapping

__all__ = ["read_only", "settings_hash", "settings_reduce"]


def read_only(mapping: Mapping[str, float]) -> Mapping[str, float]:
    """A read-only view of a copy of ``mapping`` (the caller's own dict stays the caller's).

    Parameters
    ----------
    mapping : mapping of str to float
        The values, by name (a bound by parameter name).
    """
    return MappingProxyType(dict(mapping))


def _hashable(value: Any) -> Any:
    return tuple(sorted(value.items())) if isinstance(value, Mapping) else value


def settings_hash(settings: Any) -> int:
    """The hash of a frozen dataclass's field values, mappings by their items.

    Parameters
    ----------
    settings : frozen dataclass instance
        The settings to hash (their ``__hash__``).
    """
    return hash((type(settings).__name__,) + tuple(_hashable(getattr(settings, f.name)) for f in fields(settings)))


def _rebuilt(cls: type, values: Mapping[str, Any]) -> Any:
    """``cls(**values)``: the settings again, checked as a new instance is (unpickling, copying)."""
    return cls(**values)


def settings_reduce(settings: Any) -> tuple[Any, ...]:
    """``__reduce__`` of a frozen dataclass with read-only mapping fields: rebuilt from plain dicts.

    Parameters
    ----------
    settings : frozen dataclass instance
        The settings to pickle or copy (their ``__reduce__``).
    """
    values = {f.name: getattr(settings, f.name) for f in fields(settings) if f.init}
    return (_rebuilt, (type(settings), {k: dict(v) if isinstance(v, Mapping) else v for k, v in values.items()}))
