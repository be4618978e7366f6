"""Arithmetic whose result is the same on every CPU, for the sums and searches the diagnosis decides on.

The diagnosis takes discrete decisions on floating-point numbers: a compass search moves when a
cost is lower, a start is kept when its training error is smaller, an effect is claimed when a
held-out test passes. The plant simulation is scalar Python arithmetic, which no vector unit or
BLAS touches, but numpy's ``@``, ``dot``, ``norm`` and ``convolve`` and LAPACK's
factorisations go through the BLAS, whose kernel (chosen for the CPU at run time: Haswell,
SkylakeX, Nehalem, Neoverse, ...) sums in a different order. The last bits then differ, a search
takes the other branch at a near tie, and the differences grow from there: the same recording
gave another verdict on another CPU.

So every number a decision depends on is computed here:

* :func:`sse` and :func:`dot` are correctly rounded (``math.fsum`` of the exactly rounded products),
  hence independent of the order of summation and of the CPU;
* :func:`broyden_update` updates a Jacobian along a step with the product ``J dx`` summed
  elementwise, not in the BLAS;
* :func:`moving_sum` sums windows by a running sum in index order (``numpy.cumsum``), not by
  ``numpy.convolve``;
* :func:`snap` puts the points an optimiser proposes (whose linear algebra runs in the BLAS) on a
  fixed binary grid before they are simulated, and :func:`snap_relative` rounds a scalar that came
  out of a factorisation to :data:`GRID_BITS` significant bits: last-bit differences then vanish,
  unless they straddle a grid line. The chance of that is the difference over the grid's spacing:
  for a step of a least-squares problem with condition number 1e4 (the calibration's, with its prior
  rows), a relative difference of about 2e-12 against a spacing of 6e-8, some 4e-5 per point. A
  diagnosis proposes a few hundred points, so about one in a hundred may still part somewhere.

What this does not make reproducible: a least-squares problem whose Jacobian is singular (a
parameter with no effect on the training samples, such as an effect's joint parameter that no
training sample sees). The solver's step in the null space is then decided by rounding noise in
the BLAS, and snapping cannot hold it; the input map's fit has damping rows for this reason.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["sse", "dot", "norm", "broyden_update", "moving_sum", "snap", "snap_relative", "GRID_BITS"]

#: :func:`snap`'s grid is ``2**-GRID_BITS`` in the snapped coordinate (6e-8 prior sds, or volts: far
#: below any tolerance of the searches and finite-difference steps, far above the 1e-16 relative
#: noise of a BLAS kernel times a condition number).
GRID_BITS = 24


def sse(r: np.ndarray) -> float:
    """The sum of squares of ``r``, correctly rounded (the same on every CPU).

    Parameters
    ----------
    r : ndarray
        The values.
    """
    r = np.asarray(r, float).ravel()
    return math.fsum((r * r).tolist())


def dot(a: np.ndarray, b: np.ndarray) -> float:
    """The inner product of two vectors of equal length, correctly rounded (the same on every CPU).

    Parameters
    ----------
    a, b : ndarray
        The vectors.
    """
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    if a.shape != b.shape:
        raise ValueError(f"dot of vectors of lengths {a.size} and {b.size}")
    return math.fsum((a * b).tolist())


def norm(r: np.ndarray) -> float:
    """The Euclidean norm of ``r`` from :func:`sse`.

    Parameters
    ----------
    r : ndarray
        The values.
    """
    return math.sqrt(sse(r))


def broyden_update(J: np.ndarray, dx: np.ndarray, df: np.ndarray) -> np.ndarray:
    r"""Broyden's (1965) rank-one secant update of a Jacobian along one step.

    .. math:: J_+ = J + \frac{(\Delta f - J \Delta x)\,\Delta x^T}{\Delta x^T \Delta x}

    so that ``J_+ dx = df``. ``J dx`` is an elementwise sum per row and ``dx' dx`` is :func:`sse`,
    so the update is the same on every CPU.

    Parameters
    ----------
    J : ndarray, shape (m, n)
        The Jacobian at the step's start.
    dx : ndarray, shape (n,)
        The step in the coordinates.
    df : ndarray, shape (m,)
        The change of the residual along it.

    Returns
    -------
    ndarray
        The updated Jacobian (``J`` itself for a zero step).
    """
    dd = sse(dx)
    if dd == 0.0:
        return J
    return J + np.outer(df - np.sum(J * dx, axis=1), dx) / dd


def moving_sum(x: np.ndarray, k: int, *, centred: bool = False) -> np.ndarray:
    """Sums of ``k`` consecutive values, by a running sum in index order.

    Parameters
    ----------
    x : array_like
        The values (1-D).
    k : int
        Window length, ``1 <= k``; without ``centred`` at most ``len(x)``.
    centred : bool
        False: the ``len(x) - k + 1`` sums ``x[i] + ... + x[i + k - 1]`` (``numpy.convolve(x, ones(k),
        mode="valid")``). True: ``len(x)`` sums of ``x[i - k // 2] .. x[i + (k - 1) // 2]`` cut at the
        ends (``mode="same"``).
    """
    x = np.asarray(x, float).ravel()
    if k < 1 or (not centred and k > x.size):
        raise ValueError(f"moving_sum window k={k} for {x.size} values")
    c = np.concatenate(([0.0], np.cumsum(x)))
    if centred:
        i = np.arange(x.size)
        return c[np.minimum(x.size, i + (k - 1) // 2 + 1)] - c[np.maximum(0, i - k // 2)]
    return c[k:] - c[:-k]


def snap(x: np.ndarray, bits: int = GRID_BITS) -> np.ndarray:
    """``x`` rounded to the nearest multiple of ``2**-bits`` (exactly: scaling by a power of two and
    rounding to an integer are exact in binary floating point).

    Parameters
    ----------
    x : ndarray
        The values.
    bits : int, optional
        The grid is ``2**-bits``; default :data:`GRID_BITS`.
    """
    return np.ldexp(np.round(np.ldexp(np.asarray(x, float), bits)), -bits)


def snap_relative(v: float, bits: int = GRID_BITS) -> float:
    """``v`` rounded to ``bits`` significant bits (0, inf and nan unchanged).

    Parameters
    ----------
    v : float
        The value.
    bits : int, optional
        Significant bits kept; default :data:`GRID_BITS`.
    """
    if v == 0.0 or not math.isfinite(v):
        return float(v)
    m, e = math.frexp(v)
    return math.ldexp(round(math.ldexp(m, bits)), e - bits)
