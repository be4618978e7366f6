"""A fixed, named collection of the diagnosis's building blocks (its effects, its constants).

:data:`~tapmuscle.diagnosis.candidates.CANDIDATES` and
:data:`~tapmuscle.diagnosis.calibration.NOMINAL_PARAMETERS` are the defaults of
:func:`~tapmuscle.diagnosis.diagnose.diagnose`'s ``candidates`` and ``calibration``; written out, they
made its signature (``help``, a notebook's Shift-Tab) 9,500 characters long. A :class:`Catalogue` is
the tuple of them, shown by its name and size.
"""

from __future__ import annotations

import types
from typing import Any, Iterable, Sequence

__all__ = ["Catalogue", "by_name"]


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


def by_name(items: Any, known: Sequence[Any], what: str, kind: str, *, hint: str = "") -> list[Any]:
    """``items`` as objects of the type of ``known``'s: each one as given, or its name (``name``, or
    ``key`` for a nominal parameter) looked up in ``known``; a single name or object counts as one.

    Raises
    ------
    ValueError
        An unknown name (the known ones listed).
    TypeError
        An item that is neither a name nor an object of ``known``'s type.

    Parameters
    ----------
    items : sequence, str or object
        Names or objects (one alone counts as one).
    known : sequence
        The known objects, looked up by their ``name`` (``key``).
    what : str
        The argument's name, for messages.
    kind : str
        What the items are, in words, for messages.
    hint : str, optional
        Appended to an unknown name's message.
    """
    cls = type(known[0])
    attr = "key" if hasattr(known[0], "key") else "name"
    if isinstance(items, (str, cls)):
        items = (items,)
    elif not isinstance(items, Sequence):
        raise TypeError(f"{what} must be a sequence of {kind} names or {cls.__name__} objects, got "
                        f"{type(items).__name__} {items!r:.60}")
    table = {getattr(k, attr): k for k in known}
    out = []
    for item in items:
        if isinstance(item, cls):
            out.append(item)
        elif isinstance(item, str):
            if item not in table:
                raise ValueError(f"{what}: unknown {kind} {item!r}; known: {', '.join(table)}{hint}")
            out.append(table[item])
        else:
            shown = repr(item) if len(repr(item)) <= 60 else repr(item)[:57] + "..."
            module = (f" (a module: pass the {cls.__name__} objects it holds)"
                      if isinstance(item, types.ModuleType) else "")
            raise TypeError(f"{what}: {type(item).__name__} {shown} must be a {cls.__name__} or the name of one{module}")
    return out
