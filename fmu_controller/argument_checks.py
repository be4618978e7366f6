"""Checks of the arguments a caller passes to the controller's numerics, naming what is wrong."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

__all__ = ["number_array", "real_number", "whole_number", "sampling_period", "in_sampling_range", "MUSCLE_TS_RANGE_S"]

#: Sampling periods [s] of a muscle recording or loop (those of ``tapmuscle record --ts``): the
#: muscle's responses take tenths of a second, so a period beyond 10 s is milliseconds meant (``100``
#: for 0.1 s), and one below 1 ms a data acquisition faster than the muscle needs (merge its samples).
MUSCLE_TS_RANGE_S = (1e-3, 10.0)


def real_number(value: Any, *, what: str) -> float:
    """``value`` as a finite Python float, or an error naming ``what``.

    Takes an int, a float or a numpy number of any width (``np.float32(0.1)``, ``np.int64(2)``, what a
    notebook's arrays give).

    Parameters
    ----------
    value : int, float or numpy number
        The value to check.
    what : str
        How the error message names the argument.

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


def in_sampling_range(ts_s: float) -> int:
    """Where a period [s] lies against :data:`MUSCLE_TS_RANGE_S`: -1 below, 0 within, 1 above (NaN
    above). A relative 1e-9 either side is within: a period measured from times written as text
    (1 ms logged as 0.001, 0.002, ...) comes out a hair short of 1 ms and is still 1 ms.

    Parameters
    ----------
    ts_s : float
        Sampling period [s].
    """
    lo, hi = MUSCLE_TS_RANGE_S
    if ts_s < lo * (1.0 - 1e-9):
        return -1
    return 0 if ts_s <= hi * (1.0 + 1e-9) else 1


def sampling_period(value: Any, *, what: str = "ts_s") -> float:
    """``value`` as a sampling period [s] within :data:`MUSCLE_TS_RANGE_S` (:func:`in_sampling_range`),
    or an error naming ``what``: a ``TypeError`` for a non-number, a ``ValueError`` for NaN, <= 0 or
    a period outside the range (above: milliseconds meant? below: samples to merge).

    Parameters
    ----------
    value : float
        The sampling period to check [s].
    what : str, optional
        How the error message names the argument; default ``"ts_s"``.
    """
    ts = real_number(value, what=what)
    lo, hi = MUSCLE_TS_RANGE_S
    if ts <= 0:
        raise ValueError(f"{what} must be a positive finite sampling period [s], got {value!r}")
    where = in_sampling_range(ts)
    if where > 0:
        raise ValueError(f"{what} = {value!r} s is outside the {lo:g}..{hi:g} s of the muscle's sampling "
                         "(tapmuscle record --ts): a period in milliseconds? Give it in seconds")
    if where < 0:
        raise ValueError(f"{what} = {value!r} s is outside the {lo:g}..{hi:g} s of the muscle's sampling "
                         "(tapmuscle record --ts): a data acquisition faster than the muscle needs? Merge its "
                         "samples (tapmuscle import --decimate N, tm.read_rig_log(..., decimate=N), tm.decimated)")
    return ts


def whole_number(value: Any, *, what: str) -> int:
    """``value`` as a Python int (an int or a numpy integer), or a TypeError naming ``what`` (a
    bool, a float such as 2.0, a string).

    Parameters
    ----------
    value : int or numpy integer
        The value to check.
    what : str
        How the error message names the argument.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{what} must be an integer, got {type(value).__name__} {value!r:.60}")
    return int(value)


def number_array(values: Any, *, what: str, expected: str) -> np.ndarray:
    """``values`` as a float array, or an error naming ``what`` and what was ``expected``.

    Parameters
    ----------
    values : array_like
        The sequence to convert.
    what : str
        How the error message names the argument.
    expected : str
        What the error message says the argument must be (e.g. ``"a sequence of numbers"``).

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
