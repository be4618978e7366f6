"""The score (Lagrange-multiplier) test of extra parameters in a least-squares fit.

The search re-fits only a few candidate effects jointly with the calibrated constants per round (each
joint fit costs tens of simulations). A candidate's own fit on the calibrated constants predicts its
joint fit badly when the constants have absorbed part of the effect (a play that the presliding range
mimics): the own fit then finds nothing, although the joint fit would. The score test predicts the joint
fit from where the search stands: with the residual ``b`` and the constants' Jacobian ``A`` of the
current fit, and the Jacobian ``E`` of the effect's parameters (one simulation per parameter), the
linearised joint step lowers the sum of squares by

.. math::

    \\Delta = \\min_{\\delta_c} \\lVert b + A\\delta_c \\rVert^2
             - \\min_{\\delta_c,\\,\\delta_e} \\lVert b + A\\delta_c + E\\delta_e \\rVert^2
           = \\lVert M b \\rVert^2 - \\min_{\\delta_e} \\lVert M b + M E \\delta_e \\rVert^2,
    \\qquad M = I - A (A^\\top A)^{-1} A^\\top,

which is the Lagrange-multiplier statistic ``g' H^-1 g`` (``g = E'Mb``, ``H = E'ME``) times the noise
variance (Rao 1948; Seber and Wild, *Nonlinear Regression*, 2003, section 5.9.1). An effect parameter
switched off at its lower bound (a play, a delay) can only grow: its step is constrained to be
non-negative; one at its upper bound (an amplifier map's output at 10 V) can only fall, and its step
is non-positive (bounded linear least squares). A step across a bound is no fit the search can make.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.optimize import lsq_linear

from tapmuscle.diagnosis.reproducible import snap_relative, sse

__all__ = ["score_gain"]


def score_gain(b: np.ndarray, A: np.ndarray, E: np.ndarray, nonnegative: Sequence[bool] | None = None,
               nonpositive: Sequence[bool] | None = None) -> float:
    """Sum of squares the linearised joint step on the columns ``E`` removes beyond the step on ``A`` alone.

    Parameters
    ----------
    b : ndarray, shape (m,)
        The current residual (data rows, then any prior rows) [mm].
    A : ndarray, shape (m, p)
        Jacobian of ``b`` with respect to the coordinates already fitted (the calibrated constants).
    E : ndarray, shape (m, q)
        Jacobian of ``b`` with respect to the extra parameters (zero on the prior rows of ``A``).
    nonnegative : sequence of bool, optional
        Per extra parameter: its step may not be negative (it sits at its lower bound).
    nonpositive : sequence of bool, optional
        Per extra parameter: its step may not be positive (it sits at its upper bound).

    Returns
    -------
    float
        :math:`\\Delta \\ge 0` of the module docstring [mm^2]; 0 where ``E`` adds no direction ``A``
        lacks.
    """
    b = np.asarray(b, float)
    A = np.asarray(A, float).reshape(len(b), -1)
    E = np.asarray(E, float).reshape(len(b), -1)
    if A.shape[1]:
        Q, _ = np.linalg.qr(A)
        Mb, ME = b - Q @ (Q.T @ b), E - Q @ (Q.T @ E)
    else:
        Mb, ME = b, E
    if not np.all(np.isfinite(ME)) or float(np.sum(ME ** 2)) <= 1e-24 * max(float(np.sum(E ** 2)), 1e-300):
        return 0.0
    q = E.shape[1]
    for name, flags in (("nonnegative", nonnegative), ("nonpositive", nonpositive)):
        if flags is not None and len(flags) != q:
            raise ValueError(f"{name} has {len(flags)} entries for {q} extra parameters")
    lo = np.array([0.0 if nn else -np.inf for nn in (nonnegative or [False] * q)])
    hi = np.array([0.0 if npos else np.inf for npos in (nonpositive or [False] * q)])
    free = lo < hi  # a parameter pinned at both bounds cannot step at all
    if not np.any(free):
        return 0.0
    step = lsq_linear(ME[:, free], -Mb, bounds=(lo[free], hi[free]), method="bvls").x
    rest = Mb + ME[:, free] @ step
    # the QR's last bits are the BLAS's: rounded, the gain ranks the same on every CPU
    return max(0.0, snap_relative(sse(Mb) - sse(rest)))
