"""Checks of the arguments a caller passes to the controller's numerics, naming what is wrong."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["number_array"]


def number_array(values: Any, *, what: str, expected: str) -> np.ndarray:
    """``values`` as a float array, or an error naming ``what`` and what was ``expected``.

    Raises
    ------
    TypeError
        A string, None or anything that is not a sequence (a string is not taken as its characters).
    ValueError
        A sequence holding something that is not a number.
    """
    if isinstance(values, (str, bytes)) or values is None or not np.iterable(values):
        raise TypeError(f"{what} must be {expected}; got {type(values).__name__} {values!r:.60}")
    try:
        return np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must hold numbers, got {values!r:.60}") from None
