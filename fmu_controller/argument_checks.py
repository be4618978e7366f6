"""Checks of the arguments a caller passes to the controller's numerics, naming what is wrong."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

__all__ = ["number_array", "real_number", "whole_number"]


def real_number(value: Any, *, what: str) -> float:
    """``value`` as a finite Python float, or an error naming ``what``.

    Takes an int, a float or a numpy number of any width (``np.float32(0.1)``, ``np.int64(2)``, what a
    notebook's arrays give).

    Raises
    ------
    TypeError
        A bool, a string, None, an array or anything else that is not a real number.
    ValueError
        NaN or an infinity.
    """
    if isinstance(value, float):  # float and np.float64: the common case, every step
        x = value
    elif isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        x = float(value)
    else:
        raise TypeError(f"{what} must be a number, got {type(value).__name__} {value!r:.60}")
    if not math.isfinite(x):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return float(x)


def whole_number(value: Any, *, what: str) -> int:
    """``value`` as a Python int (an int or a numpy integer), or a TypeError naming ``what`` (a
    bool, a float such as 2.0, a string)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{what} must be an integer, got {type(value).__name__} {value!r:.60}")
    return int(value)


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
