r"""The projection of Algorithm 1: the RLS estimate onto the constraint box, in the P^-1 metric.

Algorithm 1 replaces an estimate ``theta_hat`` outside the constraint region ``C`` (a box on some
coordinates, Table 2) by

.. math::  \theta = \arg\min_{\theta \in C} (\theta - \hat\theta)^T P^{-1} (\theta - \hat\theta)

(the metric of Eq. (6): the Euclidean distance in Remark 1's coordinates ``rho = P^-1/2 theta``,
Eq. (7), where Algorithm 1 projects orthogonally). Only the boxed coordinates need a small quadratic program: with the others
free, the minimiser of the rest is the conditional mean given the boxed ones, so the problem reduces
to the Schur complement on the boxed coordinates. :class:`BoxProjector` solves that small QP
exactly (active-set iterations warm-started from the last active set, enumeration of the 3^m
candidates as a fallback; scipy's BVLS beyond :data:`MAX_ENUMERATED` boxed coordinates);
:func:`project_onto_box` is the one-shot form. :class:`~fmu_controller.rls.ConstrainedRLS` calls it
every sample the estimate leaves the box.
"""

from __future__ import annotations

import itertools
import math
import numbers
from typing import Any, Mapping, Sequence

import numpy as np

__all__ = ["BoxProjector", "project_onto_box", "named_box", "box_from_pairs", "MAX_ENUMERATED"]

_dot = np.dot

# Up to this many boxed coordinates the projection uses the exact small-box
# solvers (active-set iterations, enumeration of 3^m candidates as fallback);
# beyond, scipy's BVLS active-set solver.
MAX_ENUMERATED = 4


def _solve_spd_small(A: list[list[float]], b: list[float]) -> list[float] | None:
    """Solve ``A x = b`` for a tiny s.p.d. ``A`` (nested lists) in plain floats.

    Gaussian elimination without pivoting (= LDL^T, backward stable for s.p.d.
    matrices).  Returns ``None`` if a pivot is not > 0, i.e. ``A`` is not
    numerically positive definite; the caller then falls back to LAPACK.
    For k <= 4 this is several times cheaper than ``np.linalg.solve``.
    """
    k = len(b)
    if k == 2:  # unrolled, the same operations in the same order as below
        a00 = A[0][0]
        if not a00 > 0.0:
            return None
        a01 = A[0][1]
        f = A[1][0] / a00
        a11 = A[1][1] - f * a01
        if not a11 > 0.0:
            return None
        b0 = b[0]
        x1 = (b[1] - f * b0) / a11
        return [(b0 - a01 * x1) / a00, x1]
    A = [row[:] for row in A]
    b = b[:]
    for j in range(k):
        piv = A[j][j]
        if not piv > 0.0:
            return None
        Aj = A[j]
        for i in range(j + 1, k):
            f = A[i][j] / piv
            Ai = A[i]
            for col in range(j + 1, k):
                Ai[col] -= f * Aj[col]
            b[i] -= f * b[j]
    x = [0.0] * k
    for i in range(k - 1, -1, -1):
        s = b[i]
        Ai = A[i]
        for col in range(i + 1, k):
            s -= Ai[col] * x[col]
        x[i] = s / Ai[i]
    return x


class BoxProjector:
    """Exact P^{-1}-metric projection onto a fixed box (precomputed plan).

    Minimise ``(theta - th)^T P^{-1} (theta - th)`` s.t. ``lower <= theta <= upper``.
    Let ``c`` be the boxed coordinates.  For fixed ``theta_c`` the free part is
    optimal at ``theta_f - th_f = P_fc P_cc^{-1} d_c`` and the reduced cost is
    ``d_c^T P_cc^{-1} d_c`` (Schur complement), so only ``P_cc`` matters.
    For an active set ``S`` of ``c`` pinned to bounds ``v_S``, the rest of ``c``
    is again optimal at ``d_F = P_FS w_S`` with ``w_S = P_SS^{-1} d_S``,
    ``d_S = v_S - th_S`` (``w_F = 0``), and the full step is
    ``theta = th + P[:, c] w``.

    Two exact solvers of the reduced box QP (``m = |c|`` unknowns):

    * :meth:`_active_set` (used first, ``m <= 4``): primal-dual active-set
      iterations in plain floats, starting from the coordinates that ``th``
      violates.  The gradient of the reduced cost at the candidate is
      ``P_cc^{-1} d_c = w``, so the KKT conditions are cheap to check: ``w_i
      >= 0`` for ``i`` pinned at its lower bound, ``w_i <= 0`` at its upper
      bound (any sign if ``lower_i == upper_i``), and the free coordinates
      inside the box.  The problem is strictly convex, so a KKT point is *the*
      minimiser.  Wrongly pinned coordinates are released and violated ones
      pinned, for at most :attr:`max_iterations` candidates without
      repeating one.  The estimator first tries a hint, the active set its
      previous estimate lies on (:meth:`hint_from`); it passes the KKT test
      in most samples of the closed loop (the box face persists), and as the
      result is a function of the accepted active set alone, the hint saves
      iterations without changing the answer.
    * :meth:`_enumerate` (fallback if the iterations do not verify a KKT point,
      and the reference in the tests): all ``3^m - 1`` active sets in one
      batched ``np.linalg.solve``; every feasible candidate is an upper bound
      of the optimum, so the cheapest feasible one is the exact minimiser.
      Candidate ``j`` uses the padded system ``[[P_SS, 0], [0, I]] w = [d_S,
      0]``; then ``d_c = P_cc w`` and cost ``= w . d``.

    Beyond ``m = 4`` BVLS (``scipy.optimize.lsq_linear``) is used instead.

    Parameters
    ----------
    lower, upper : ndarray
        Bounds of the box C of Algorithm 1, one entry per parameter (``-inf``/``+inf`` where
        unbounded); the coordinates with a finite bound on either side are the boxed ones ``c``.
    """

    #: candidates tried by the active-set iterations before falling back
    max_iterations = 8

    def __init__(self, lower: np.ndarray, upper: np.ndarray) -> None:
        self.lower = lower
        self.upper = upper
        self.c = np.flatnonzero(np.isfinite(lower) | np.isfinite(upper))
        m = self.c.size
        self.lower_c = lower[self.c]
        self.upper_c = upper[self.c]
        # rounding slack for the candidate feasibility test (then clipped)
        self.lower_tol = self.lower_c - 1e-12 * (1.0 + np.abs(self.lower_c))
        self.upper_tol = self.upper_c + 1e-12 * (1.0 + np.abs(self.upper_c))
        n = lower.size
        self.flat_cc = (self.c[:, None] * n + self.c[None, :]).ravel()
        self.small = 0 < m <= MAX_ENUMERATED  # else BVLS
        # plain-float copies for the scalar hot path
        self._cl = self.c.tolist()
        self._lo = self.lower_c.tolist()
        self._hi = self.upper_c.tolist()
        self._lo_tol = self.lower_tol.tolist()
        self._hi_tol = self.upper_tol.tolist()
        self._fixed = [lo == hi for lo, hi in zip(self._lo, self._hi)]
        self._fixed_mask = np.array(self._fixed, dtype=bool)  # BVLS takes these out
        # rows P[c, :] (= columns, P symmetric) as a cheap view if c is a range
        contiguous = m > 0 and self._cl == list(range(self._cl[0], self._cl[0] + m))
        self._contiguous = contiguous
        self._rows = slice(self._cl[0], self._cl[0] + m) if contiguous else self.c
        self._m = m
        self._all_m = range(m)
        self._tables = None  # enumeration tables, built on first fallback

    def inside(self, th: list[float]) -> bool:
        """``theta`` (given as ``theta.tolist()``) is in the box (exact, no slack)."""
        for i, lo, hi in zip(self._cl, self._lo, self._hi):
            if not lo <= th[i] <= hi:
                return False
        return True

    def __call__(self, theta_hat: np.ndarray, P: np.ndarray) -> np.ndarray:
        th = theta_hat.tolist()
        if self.c.size == 0 or self.inside(th):
            return theta_hat.copy()
        return self.project(theta_hat, P, th)

    def project(self, theta_hat: np.ndarray, P: np.ndarray, th: list[float],
                hint: list[int] | None = None) -> np.ndarray:
        """Projection of ``theta_hat`` (outside the box; ``th = theta_hat.tolist()``).

        ``hint``: an active set to try first (see :meth:`_active_set`).
        """
        if not self.small:
            m = self.c.size
            return self._bvls(theta_hat, P, np.ascontiguousarray(P).take(self.flat_cc).reshape(m, m))
        theta = self._active_set(theta_hat, P, th, hint)
        return self._enumerate(theta_hat, P) if theta is None else theta

    def hint_from(self, theta: np.ndarray) -> list[int]:
        """Active-set guess from an earlier estimate: -1/+1 where it lies exactly on its lower/upper bound."""
        t = theta[self._rows].tolist()
        return [-1 if ti == l else (1 if ti == h else 0) for ti, l, h in zip(t, self._lo, self._hi)]

    def _candidate(self, state: list[int], th_c: list[float], Pcc: list[list[float]]):
        """Evaluate one active set (``state``: 0 free, -1 at lower, +1 at upper bound).

        Returns ``(new_state, x, w)``: the candidate's boxed coordinates ``x``, its
        multipliers ``w = P_cc^{-1} d_c`` and the state the KKT test asks for
        (equal to ``state`` iff the candidate is the minimiser); ``None`` if the
        pinned block of ``P`` is not numerically positive definite.  One or two
        pinned coordinates (the usual cases) take unrolled code with the same
        operations in the same order as the general loop.
        """
        lo, hi, fixed = self._lo, self._hi, self._fixed
        lo_tol, hi_tol = self._lo_tol, self._hi_tol
        all_m = self._all_m
        S = [i for i in all_m if state[i]]
        new = state[:]
        x = th_c[:]
        w = [0.0] * self._m
        nS = len(S)
        if nS == 1:
            i0 = S[0]
            s0 = state[i0]
            v0 = lo[i0] if s0 < 0 else hi[i0]
            p = Pcc[i0][i0]
            if not p > 0.0:
                return None
            w0 = (v0 - th_c[i0]) / p
            x[i0] = v0
            w[i0] = w0
            if s0 * w0 > 0.0 and not fixed[i0]:
                new[i0] = 0
            for i in all_m:
                if i != i0:
                    xi = th_c[i] + Pcc[i][i0] * w0
                    x[i] = xi
                    if xi < lo_tol[i]:
                        new[i] = -1
                    elif xi > hi_tol[i]:
                        new[i] = 1
            return new, x, w
        if nS == 2:
            i0, i1 = S
            s0, s1 = state[i0], state[i1]
            v0 = lo[i0] if s0 < 0 else hi[i0]
            v1 = lo[i1] if s1 < 0 else hi[i1]
            # _solve_spd_small on [[P00, P01], [P10, P11]] w = [v0 - th0, v1 - th1]
            P0, P1 = Pcc[i0], Pcc[i1]
            a00 = P0[i0]
            if not a00 > 0.0:
                return None
            a01 = P0[i1]
            f = P1[i0] / a00
            a11 = P1[i1] - f * a01
            if not a11 > 0.0:
                return None
            d0 = v0 - th_c[i0]
            w1 = ((v1 - th_c[i1]) - f * d0) / a11
            w0 = (d0 - a01 * w1) / a00
            x[i0], x[i1] = v0, v1
            w[i0], w[i1] = w0, w1
            if s0 * w0 > 0.0 and not fixed[i0]:
                new[i0] = 0
            if s1 * w1 > 0.0 and not fixed[i1]:
                new[i1] = 0
            for i in all_m:
                if not state[i]:
                    Pi = Pcc[i]
                    xi = th_c[i] + Pi[i0] * w0 + Pi[i1] * w1
                    x[i] = xi
                    if xi < lo_tol[i]:
                        new[i] = -1
                    elif xi > hi_tol[i]:
                        new[i] = 1
            return new, x, w
        v = [lo[i] if state[i] < 0 else hi[i] for i in S]
        wS = _solve_spd_small([[Pcc[i][j] for j in S] for i in S],
                              [vi - th_c[i] for vi, i in zip(v, S)])
        if wS is None:
            return None
        # KKT: multiplier signs of the pinned, bounds of the free ones
        for i, vi, wi in zip(S, v, wS):
            x[i] = vi  # exactly on the bound
            w[i] = wi
            if state[i] * wi > 0.0 and not fixed[i]:
                new[i] = 0
        for i in all_m:
            if not state[i]:
                xi = th_c[i]
                Pi = Pcc[i]
                for j, wj in zip(S, wS):
                    xi += Pi[j] * wj
                x[i] = xi
                if xi < lo_tol[i]:
                    new[i] = -1
                elif xi > hi_tol[i]:
                    new[i] = 1
        return new, x, w

    def _active_set(self, theta_hat: np.ndarray, P: np.ndarray, th: list[float],
                    hint: list[int] | None = None) -> np.ndarray | None:
        """Exact projection by KKT-verified active-set iterations; ``None`` if unverified.

        Plain-float code: for ``m <= 4`` this beats any numpy formulation.  The
        iterations start from the coordinates that ``th`` violates.  A ``hint``
        (e.g. the previous step's active set, :meth:`hint_from`) is tried first
        and kept only if it passes the KKT test; the result is a function of the
        accepted active set alone, so a hint changes the work, not the answer
        (the problem is strictly convex: its KKT point is unique).
        """
        lo, hi = self._lo, self._hi
        rows = self._rows
        if self._contiguous:
            th_c = th[rows]
            Pcc = P[rows, rows].tolist()  # nested m x m: Pcc[i][j]
        else:
            th_c = [th[i] for i in self._cl]
            Pcc = P.take(self.flat_cc).reshape(self._m, self._m).tolist()
        state = [-1 if t < l else (1 if t > h else 0) for t, l, h in zip(th_c, lo, hi)]
        if hint is not None and hint != state and any(hint):
            cand = self._candidate(hint, th_c, Pcc)
            if cand is not None and cand[0] == hint:
                return self._finish(theta_hat, P, cand[1], cand[2])
        seen = []
        for _ in range(self.max_iterations):
            cand = self._candidate(state, th_c, Pcc)
            if cand is None:
                return None
            new, x, w = cand
            if new == state:  # KKT point = the minimiser
                return self._finish(theta_hat, P, x, w)
            seen.append(state)
            if new in seen:
                return None
            state = new
        return None

    def _finish(self, theta_hat: np.ndarray, P: np.ndarray, x: list[float], w: list[float]) -> np.ndarray:
        """``theta = theta_hat + P[:, c] w`` with the boxed coordinates ``x`` (clipped)."""
        rows = self._rows
        # P symmetric: rows of P instead of columns
        theta = _dot(np.array(w), P[rows])
        theta += theta_hat
        # pinned ones exactly on the bound, free ones: clip the rounding residue
        # (= min(max(x_i, lo_i), hi_i), without the builtin calls)
        lo, hi = self._lo, self._hi
        for i in self._all_m:
            xi = x[i]
            if lo[i] > xi:
                x[i] = lo[i]
            elif hi[i] < xi:
                x[i] = hi[i]
        if self._contiguous:
            theta[rows] = x
        else:
            theta[self.c] = x
        return theta

    def _enumerate(self, theta_hat: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Exact projection by enumerating all ``3^m - 1`` active sets (batched)."""
        if self._tables is None:
            # state per boxed coordinate: 0 free, 1 at lower, 2 at upper; a
            # one-sided bound appears twice (harmless duplicate candidate)
            m = self.c.size
            lo = np.where(np.isfinite(self.lower_c), self.lower_c, self.upper_c)
            hi = np.where(np.isfinite(self.upper_c), self.upper_c, self.lower_c)
            states = np.array(list(itertools.product((0, 1, 2), repeat=m))[1:])
            pinned = states > 0                                     # (J, m)
            values = np.where(states == 1, lo, np.where(states == 2, hi, 0.0))
            mask_ss = pinned[:, :, None] & pinned[:, None, :]       # (J, m, m)
            free = ~pinned
            eye_ff = (free[:, :, None] & free[:, None, :]) * np.eye(m)
            self._tables = (pinned, values, mask_ss, eye_ff)
        pinned, values, mask_ss, eye_ff = self._tables
        c = self.c
        m = c.size
        Pcc = np.ascontiguousarray(P).take(self.flat_cc).reshape(m, m)
        th_c = theta_hat[c]
        d = np.where(pinned, values - th_c, 0.0)                    # (J, m)
        A = Pcc * mask_ss + eye_ff                                  # (J, m, m)
        w = np.linalg.solve(A, d[:, :, None])[:, :, 0]              # (J, m)
        cost = np.einsum("jm,jm->j", w, d)
        theta_c = th_c + w @ Pcc                                    # Pcc symmetric
        # pinned coordinates are on their bound by construction; testing their
        # recomputed value (off by rounding ~ cond(P_cc) eps |w|) could wrongly
        # reject the optimum, so only the free ones are tested
        in_box = (theta_c >= self.lower_tol) & (theta_c <= self.upper_tol)
        ok = (pinned | in_box).all(axis=1)
        j = int(np.argmin(np.where(ok, cost, np.inf)))
        # theta = th + P[:, c] P_cc^{-1} d_c  with  P_cc^{-1} d_c = w_j
        theta = theta_hat + P[:, c] @ w[j]
        # pinned: exactly the bound; free: clip the rounding residue
        theta[c] = np.where(pinned[j], values[j], np.clip(theta[c], self.lower_c, self.upper_c))
        return theta

    def _bvls(self, theta_hat: np.ndarray, P: np.ndarray, Pcc: np.ndarray) -> np.ndarray:
        """Beyond ``m = 4``: BVLS on the boxed block, its fixed coordinates (lower == upper) taken out.

        With ``x_f`` fixed, the nearest ``x_r`` in the ``Pcc^{-1}`` metric is that of the conditional
        problem, centre ``t_r + P_rf P_ff^{-1} (x_f - t_f)`` and metric ``S^{-1}``, ``S = P_rr - P_rf
        P_ff^{-1} P_fr`` (a Schur complement): BVLS then has strict bounds only (a fixed coordinate's
        one-ulp box made ``lsq_linear`` stop early, off the optimum). A result that fails the KKT
        conditions is solved again by ``lsq_linear``'s ``trf`` method, and the cheaper one kept.
        """
        c = self.c
        fixed = self._fixed_mask
        t = theta_hat[c]
        x = np.empty(c.size)
        x[fixed] = self.lower_c[fixed]
        r = ~fixed
        if r.any():
            centre, S = t[r], Pcc[np.ix_(r, r)]
            if fixed.any():
                gain = np.linalg.solve(Pcc[np.ix_(fixed, fixed)], Pcc[np.ix_(fixed, r)]).T   # P_rf P_ff^-1
                centre = centre + gain @ (x[fixed] - t[fixed])
                S = S - gain @ Pcc[np.ix_(fixed, r)]
            L = np.linalg.cholesky(S)
            Linv = np.linalg.solve(L, np.eye(S.shape[0]))   # |L^{-1} d|^2 = d^T S^{-1} d
            lo, hi = self.lower_c[r], self.upper_c[r]
            # imported here: scipy.optimize is a third of the controller FMU's start-up, and the
            # Table 2 box (3 coordinates) never comes this way
            from scipy.optimize import lsq_linear

            best = None
            for method in ("bvls", "trf"):  # trf where BVLS stops off the optimum (its tolerance on the cost)
                xr = np.clip(lsq_linear(Linv, Linv @ centre, bounds=(lo, hi), method=method, tol=1e-14).x, lo, hi)
                resid = Linv @ (xr - centre)
                if best is None or resid @ resid < best[0]:
                    best = (float(resid @ resid), xr)
                if _kkt_holds(Linv.T @ resid, xr, lo, hi):
                    break
            x[r] = best[1]
        d_c = x - t
        theta = theta_hat + P[:, c] @ np.linalg.solve(Pcc, d_c)
        theta[c] = np.clip(x, self.lower_c, self.upper_c)
        return theta


def _kkt_holds(grad: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """KKT conditions of ``min f`` over ``lo <= x <= hi`` at ``x`` with gradient ``grad`` (to rounding):
    zero where ``x`` is inside, pointing out of the box where it is on a bound."""
    scale = 1e-9 * (1.0 + float(np.max(np.abs(grad))))
    with np.errstate(invalid="ignore"):  # an infinite bound: inf - inf, compared False as it should
        at_lo = x <= np.where(np.isfinite(lo), lo + 1e-12 * (1.0 + np.abs(lo)), lo)  # BVLS ends ulps inside
        at_hi = x >= np.where(np.isfinite(hi), hi - 1e-12 * (1.0 + np.abs(hi)), hi)
    inside = ~(at_lo | at_hi)
    return bool(np.all(np.abs(grad[inside]) <= scale) and np.all(grad[at_lo] >= -scale)
                and np.all(grad[at_hi] <= scale))


def named_box(lower: Mapping[str, Any], upper: Mapping[str, Any], *, names: Sequence[str], what: str
              ) -> tuple[dict[str, float], dict[str, float]]:
    """The box C of Algorithm 1 given by parameter name, as two maps of ``names`` to finite bounds,
    or a ``ValueError`` naming ``what``: a side that is not a mapping, a name not in ``names``, a
    bound that is not a real number (any numpy width) or is NaN, an infinity on the side it bars
    every value from, a lower bound above its upper one. An infinity on its own side is no bound
    and left out.

    Parameters
    ----------
    lower, upper : mapping of str to float
        Lower and upper bounds by parameter name; a parameter not named is unbounded on that
        side.
    names : sequence of str
        The model's parameter names, in order.
    what : str
        How the error message names the box.
    """
    out = []
    for side, given, unbounded in (("lower", lower, -math.inf), ("upper", upper, math.inf)):
        if not isinstance(given, Mapping):
            raise ValueError(f"{what}: the {side} bounds must map parameter names to numbers, got "
                             f"{type(given).__name__} {given!r:.60}")
        bounds = {}
        for name, value in given.items():
            if name not in names:
                raise ValueError(f"{what}: unknown parameter {name!r} in the {side} bounds (the model's parameters: "
                                 f"{', '.join(names)})")
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or math.isnan(value):
                pair = (" (one number a side: box_lower and box_upper, not tm.identify's (lower, upper) pairs)"
                        if isinstance(value, (tuple, list, np.ndarray)) else "")
                raise ValueError(f"{what}: the {side} bound of {name} must be a number, got {value!r:.60}{pair}")
            x = float(value)
            if x != unbounded:
                if math.isinf(x):
                    raise ValueError(f"{what}: the {side} bound of {name} is {x!r}, which no value satisfies")
                bounds[name] = x
        out.append(bounds)
    crossed = [f"{n} ({out[0][n]:g} > {out[1][n]:g})" for n in out[0] if n in out[1] and out[0][n] > out[1][n]]
    if crossed:
        raise ValueError(f"{what}: a lower bound above its upper one: {', '.join(crossed)}")
    return out[0], out[1]


def box_from_pairs(box: Mapping[str, Any], *, names: Sequence[str], what: str = "box"
                   ) -> tuple[dict[str, float], dict[str, float]]:
    """:func:`named_box` of ``{name: (lower, upper)}`` (``tm.identify``'s ``box``; a pair may be a
    tuple, a list or a numpy array of two numbers).

    Parameters
    ----------
    box : mapping of str to (float, float)
        ``{name: (lower, upper)}``.
    names : sequence of str
        The model's parameter names, in order.
    what : str, optional
        How the error message names the box; default ``"box"``.
    """
    if not isinstance(box, Mapping):
        raise ValueError(f"{what} must map parameter names to (lower, upper) pairs, got {type(box).__name__} {box!r:.60}")
    lower, upper = {}, {}
    for name, pair in box.items():
        values = None if isinstance(pair, (str, bytes)) else np.asarray(pair, dtype=object)
        if values is None or values.shape != (2,):
            raise ValueError(f"{what}: {name} must be a pair (lower, upper) of numbers, got {pair!r:.60}")
        lower[name], upper[name] = values[0], values[1]
    return named_box(lower, upper, names=names, what=what)


def _check_box(lower, upper, n) -> tuple[np.ndarray, np.ndarray]:
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    for name, arr in (("lower", lower), ("upper", upper)):
        if arr.shape != (n,):
            raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
        if np.isnan(arr).any():
            raise ValueError(f"{name} must not contain NaN")
    bad = np.flatnonzero(lower > upper)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"lower[{i}]={lower[i]} > upper[{i}]={upper[i]}")
    return lower, upper


def project_onto_box(
    theta_hat: Sequence[float] | np.ndarray,
    P: np.ndarray,
    lower: Sequence[float] | np.ndarray,
    upper: Sequence[float] | np.ndarray,
) -> np.ndarray:
    """Projection of Algorithm 1: nearest point of the box ``C`` in the ``P^{-1}`` metric.

    Solves ``min (theta - theta_hat)^T P^{-1} (theta - theta_hat)`` subject to
    ``lower <= theta <= upper``, i.e. the orthogonal projection of
    ``rho = P^{-1/2} theta_hat`` onto the image of ``C`` (Algorithm 1).  This is
    *not* an element-wise clip: unboxed parameters move too, along the
    correlations in ``P``.  By Remark 1 (Eqs. (6)-(10)) the Lyapunov-like
    distance to any ``theta0 in C`` does not increase.

    Exact: for up to 4 boxed coordinates, KKT-verified active-set iterations
    on the boxed block of ``P`` (enumeration of all active sets if those do
    not verify); BVLS (``scipy.optimize.lsq_linear``) beyond that.  Never
    forms ``P^{-1}``.

    Parameters
    ----------
    theta_hat : array_like, shape (n,)
        Unconstrained estimate from Eq. (4).
    P : ndarray, shape (n, n)
        Symmetric positive definite covariance ``P(k-1)`` (the updated one).
    lower, upper : array_like, shape (n,)
        Box bounds; +/-inf for unbounded entries.

    Returns
    -------
    ndarray, shape (n,)
        Projected estimate, always a new array (equal to ``theta_hat`` if it
        is already in ``C``).
    """
    theta_hat = np.asarray(theta_hat, dtype=float)
    if theta_hat.ndim != 1:
        raise ValueError(f"theta_hat must be 1-D, got shape {theta_hat.shape}")
    n = theta_hat.size
    if not np.all(np.isfinite(theta_hat)):
        raise ValueError("theta_hat must be finite")
    P = np.asarray(P, dtype=float)
    if P.shape != (n, n):
        raise ValueError(f"P must have shape ({n}, {n}), got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("P must be finite")
    lower, upper = _check_box(lower, upper, n)
    return BoxProjector(lower, upper)(theta_hat, P)
