"""A fixed, named collection of the diagnosis's building blocks (its effects, its constants).

:data:`~tapmuscle.diagnosis.candidates.CANDIDATES` and
:data:`~tapmuscle.diagnosis.calibration.NOMINAL_PARAMETERS` are the defaults of
:func:`~tapmuscle.diagnosis.diagnose.diagnose`'s ``candidates`` and ``calibration``; written out, they
made its signature (``help``, a notebook's Shift-Tab) 9,500 characters long. A :class:`Catalogue` is
the tuple of them, shown by its name and size.
"""

from __future__ import annotations

from typing import Any, Iterable

__all__ = ["Catalogue"]


class Catalogue(tuple):
    """A tuple shown as its name and length (``CANDIDATES (9)``); equal to, and used as, the plain
    tuple of its items.

    Parameters
    ----------
    name : str
        The name it is shown as.
    items : iterable
        Its items.
    """

    _name: str

    def __new__(cls, name: str, items: Iterable[Any]) -> Catalogue:
        self = super().__new__(cls, items)
        self._name = name
        return self

    def __repr__(self) -> str:
        return f"{self._name} ({len(self)})"

    def __reduce__(self) -> tuple[Any, ...]:
        # worker processes get the same catalogue
        return (Catalogue, (self._name, tuple(self)))
