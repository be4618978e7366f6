"""Recursive least squares, Eq. (4), with the box projection of Algorithm 1.

The estimator is generic in the regressor but is set up with a
:class:`~fmu_controller.hysteresis_model.ModelStructure` so that constraint
boxes can be given by parameter name (Table 2 bounds ``a1, a2, b1``).

Units follow the data: with ``l`` in mm and ``u`` in V, ``b1`` is in mm/V and
the Table 2 box applies as is.  If the data are rescaled, rescale the box too
(see :func:`fmu_controller.prediction.theta_scale_factors`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal, Mapping, Sequence

import numpy as np
from scipy.optimize import lsq_linear

from .hysteresis_model import ModelStructure

__all__ = [
    "TABLE2_LOWER",
    "TABLE2_UPPER",
    "RLSSettings",
    "ConstrainedRLS",
    "project_onto_box",
]

#: Table 2: constrained region of the linear model (a1, a2 [-], b1 [mm/V]).
TABLE2_LOWER: Mapping[str, float] = MappingProxyType({"a1": 1.208, "a2": -0.334, "b1": 0.607})
TABLE2_UPPER: Mapping[str, float] = MappingProxyType({"a1": 1.260, "a2": -0.278, "b1": 1.184})

# bound once: the per-sample update is dominated by call overhead
_dot = np.dot
_subtract = np.subtract
_add = np.add
_multiply = np.multiply
_divide = np.divide

# Up to this many boxed coordinates the projection uses the exact small-box
# solvers (active-set iterations, enumeration of 3^m candidates as fallback);
# beyond, scipy's BVLS active-set solver.
_MAX_ENUMERATED = 4


# ---------------------------------------------------------------------------
# Settings
# ---------------------------------------------------------------------------
BoundSpec = Mapping[str, float] | Sequence[float] | np.ndarray


def _freeze_vector(name: str, value, *, allow_inf: bool) -> tuple[float, ...]:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D sequence, got shape {arr.shape}")
    bad = np.isnan(arr) if allow_inf else ~np.isfinite(arr)
    if bad.any():
        raise ValueError(f"{name} must be {'non-NaN' if allow_inf else 'finite'}, got {arr.tolist()}")
    return tuple(float(x) for x in arr)


def _freeze_bound(name: str, value) -> Mapping[str, float] | tuple[float, ...]:
    if isinstance(value, Mapping):
        out = {}
        for key, x in value.items():
            if not isinstance(key, str):
                raise ValueError(f"{name} keys must be parameter names, got {key!r}")
            x = float(x)
            if math.isnan(x):
                raise ValueError(f"{name}[{key!r}] must not be NaN")
            out[key] = x
        return MappingProxyType(out)
    return _freeze_vector(name, value, allow_inf=True)


@dataclass(frozen=True, kw_only=True)
class RLSSettings:
    """Settings of the (constrained) RLS estimator, Eq. (4) and Algorithm 1.

    Parameters
    ----------
    p0 : float or sequence of float
        Initial covariance ``P(-1)``: scalar (times identity) or diagonal.
        Paper: ``1e3`` for identification (section 2.4); Tables 5 and 8 give
        diagonals for the AMPC.  Must be finite and > 0.
    theta0 : sequence of float, optional
        Initial estimate ``theta(0)``; default zeros (section 2.4).
    forgetting : float
        Exponential forgetting factor ``lambda`` in (0, 1]; 1.0 (default)
        is the paper's Eq. (4).
    box_lower, box_upper : mapping name -> float, or sequence of float
        Constraint region ``C`` of Algorithm 1 (a box).  Mappings give bounds
        by parameter name (others unbounded); sequences give all entries
        (use +/-inf for unbounded).  Default: Table 2 on ``a1, a2, b1``.
    constraint_start_s : float
        Time in s from which the projection is applied (section 2.4: the
        constrained RLS "runs after 120 s").  0 = always, ``inf`` = never.
    ts_s : float
        Sampling period in s (0.1 s in the paper).
    on_covariance_loss : {"reset", "raise"}
        What to do if ``P`` loses positive definiteness (non-finite entry or
        a diagonal <= 0) or ``theta`` becomes non-finite after an update:
        ``"reset"`` discards that update, keeps ``theta(k-1)`` and resets
        ``P`` to ``P(-1)``; ``"raise"`` raises ``FloatingPointError``.
    """

    p0: float | Sequence[float] = 1e3
    theta0: Sequence[float] | None = None
    forgetting: float = 1.0
    box_lower: BoundSpec = field(default_factory=lambda: dict(TABLE2_LOWER))
    box_upper: BoundSpec = field(default_factory=lambda: dict(TABLE2_UPPER))
    constraint_start_s: float = 120.0
    ts_s: float = 0.1
    on_covariance_loss: Literal["reset", "raise"] = "reset"

    def __post_init__(self) -> None:
        # p0
        if np.ndim(self.p0) == 0:
            p0 = float(self.p0)
            if not (math.isfinite(p0) and p0 > 0):
                raise ValueError(f"p0 must be finite and > 0, got {self.p0!r}")
        else:
            p0 = _freeze_vector("p0", self.p0, allow_inf=False)
            if min(p0) <= 0:
                raise ValueError(f"p0 must be > 0 elementwise, got {list(p0)}")
        object.__setattr__(self, "p0", p0)
        # theta0
        if self.theta0 is not None:
            object.__setattr__(self, "theta0", _freeze_vector("theta0", self.theta0, allow_inf=False))
        # scalars
        lam = float(self.forgetting)
        if not (0.0 < lam <= 1.0):
            raise ValueError(f"forgetting must be in (0, 1], got {self.forgetting!r}")
        object.__setattr__(self, "forgetting", lam)
        ts = float(self.ts_s)
        if not (math.isfinite(ts) and ts > 0):
            raise ValueError(f"ts_s must be finite and > 0, got {self.ts_s!r}")
        object.__setattr__(self, "ts_s", ts)
        start = float(self.constraint_start_s)
        if math.isnan(start) or start < 0:
            raise ValueError(f"constraint_start_s must be >= 0 (inf = never), got {self.constraint_start_s!r}")
        object.__setattr__(self, "constraint_start_s", start)
        if self.on_covariance_loss not in ("reset", "raise"):
            raise ValueError(
                f"on_covariance_loss must be 'reset' or 'raise', got {self.on_covariance_loss!r}"
            )
        # box
        lower = _freeze_bound("box_lower", self.box_lower)
        upper = _freeze_bound("box_upper", self.box_upper)
        object.__setattr__(self, "box_lower", lower)
        object.__setattr__(self, "box_upper", upper)
        for name, bound, bad in (("box_lower", lower, math.inf), ("box_upper", upper, -math.inf)):
            items = bound.items() if isinstance(bound, Mapping) else enumerate(bound)
            for key, x in items:
                if x == bad:
                    raise ValueError(f"{name}[{key!r}] = {x} leaves no feasible value")
        if isinstance(lower, Mapping) != isinstance(upper, Mapping):
            raise ValueError("box_lower and box_upper must both be mappings or both be sequences")
        if isinstance(lower, Mapping):
            for key in set(lower) & set(upper):
                if lower[key] > upper[key]:
                    raise ValueError(
                        f"box_lower[{key!r}]={lower[key]} > box_upper[{key!r}]={upper[key]}"
                    )
        else:
            if len(lower) != len(upper):
                raise ValueError(
                    f"box_lower and box_upper lengths differ: {len(lower)} != {len(upper)}"
                )
            for i, (lo, hi) in enumerate(zip(lower, upper)):
                if lo > hi:
                    raise ValueError(f"box_lower[{i}]={lo} > box_upper[{i}]={hi}")
        # lengths of all vector-valued settings must agree with each other
        lengths = {
            name: len(val)
            for name, val in (("p0", p0), ("theta0", self.theta0), ("box_lower", lower))
            if isinstance(val, tuple)
        }
        if len(set(lengths.values())) > 1:
            raise ValueError(f"inconsistent vector lengths in settings: {lengths}")

    def __hash__(self) -> int:
        # mapping-valued bounds are unhashable as stored; hash their items
        def key(b):
            return tuple(sorted(b.items())) if isinstance(b, Mapping) else b
        return hash((self.p0, self.theta0, self.forgetting, key(self.box_lower),
                     key(self.box_upper), self.constraint_start_s, self.ts_s,
                     self.on_covariance_loss))

    @property
    def constraint_start_index(self) -> float:
        """First sample index ``k`` (``t = k Ts >= constraint_start_s``) with projection.

        ``inf`` if the constraint never starts.
        """
        if math.isinf(self.constraint_start_s):
            return math.inf
        # tolerate float noise like 120 / 0.1 = 1200.0000000000002
        return float(math.ceil(self.constraint_start_s / self.ts_s - 1e-9))

    def resolve(self, structure: ModelStructure) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Concrete ``(P0, theta0, lower, upper)`` arrays for ``structure``."""
        n = structure.n_params
        if isinstance(self.p0, tuple):
            if len(self.p0) != n:
                raise ValueError(f"p0 has {len(self.p0)} entries, expected {n} for the {structure.kind} model")
            P0 = np.diag(np.array(self.p0))
        else:
            P0 = self.p0 * np.eye(n)
        if self.theta0 is None:
            theta0 = np.zeros(n)
        else:
            if len(self.theta0) != n:
                raise ValueError(f"theta0 has {len(self.theta0)} entries, expected {n}")
            theta0 = np.array(self.theta0)
        lower = self._resolve_bound("box_lower", self.box_lower, structure, -np.inf)
        upper = self._resolve_bound("box_upper", self.box_upper, structure, np.inf)
        return P0, theta0, lower, upper

    @staticmethod
    def _resolve_bound(name, bound, structure, fill) -> np.ndarray:
        n = structure.n_params
        if isinstance(bound, Mapping):
            arr = np.full(n, fill)
            for key, x in bound.items():
                if key not in structure.names:
                    raise ValueError(f"{name} names unknown parameter {key!r} for the {structure.kind} model")
                arr[structure.index(key)] = x
            return arr
        if len(bound) != n:
            raise ValueError(f"{name} has {len(bound)} entries, expected {n}")
        return np.array(bound)


# ---------------------------------------------------------------------------
# Projection (Algorithm 1)
# ---------------------------------------------------------------------------
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


class _BoxProjector:
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
        self.small = 0 < m <= _MAX_ENUMERATED  # else BVLS
        # plain-float copies for the scalar hot path
        self._cl = self.c.tolist()
        self._lo = self.lower_c.tolist()
        self._hi = self.upper_c.tolist()
        self._lo_tol = self.lower_tol.tolist()
        self._hi_tol = self.upper_tol.tolist()
        self._fixed = [lo == hi for lo, hi in zip(self._lo, self._hi)]
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
        c = self.c
        L = np.linalg.cholesky(Pcc)
        Linv = np.linalg.solve(L, np.eye(c.size))          # |L^{-1} d|^2 = d^T Pcc^{-1} d
        # lsq_linear needs lb < ub strictly; a pinned parameter gets a 1-ulp box
        ub = np.where(self.upper_c > self.lower_c, self.upper_c,
                      np.nextafter(self.lower_c, np.inf))
        res = lsq_linear(Linv, Linv @ theta_hat[c], bounds=(self.lower_c, ub),
                         method="bvls", tol=1e-14)
        d_c = res.x - theta_hat[c]
        theta = theta_hat + P[:, c] @ np.linalg.solve(Pcc, d_c)
        theta[c] = np.clip(res.x, self.lower_c, self.upper_c)
        return theta


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
    return _BoxProjector(lower, upper)(theta_hat, P)


# ---------------------------------------------------------------------------
# Estimator
# ---------------------------------------------------------------------------
class ConstrainedRLS:
    """Constrained RLS of Algorithm 1 around the Eq. (4) update.

    Lifecycle (as osqp): ``rls = ConstrainedRLS(); rls.setup(structure,
    settings)`` (or pass both to the constructor), then ``update(phi, y)``
    once per sample.

    Step ``k`` (``y = l(k)``, ``phi = phi(k-1)``), Goodwin & Sin form [15]::

        s        = phi^T P(k-2) phi
        theta(k) = theta(k-1) + P(k-2) phi / (lambda + s) * (y - phi^T theta(k-1))
        P(k-1)   = [P(k-2) - P(k-2) phi phi^T P(k-2) / (lambda + s)] / lambda

    With ``lambda = 1`` this is Eq. (4) and the gain equals ``P(k-1) phi``.
    Note: the printed Eq. (4) has ``P(k-1)`` in *both* numerator and
    denominator of the gain; read literally that is ``P(k-2) phi / (1 + 2 s)``,
    which is not the least-squares gain, so it is taken as a typo for the
    standard form above (``P(k-1) phi = P(k-2) phi / (1 + s)``).

    Then, if ``k Ts >= constraint_start_s`` and ``theta(k)`` is outside the box
    ``C``, ``theta(k)`` is replaced by :func:`project_onto_box` with the updated
    ``P(k-1)`` (Algorithm 1).  ``P`` is not modified by the projection.

    Parameters
    ----------
    structure : ModelStructure, optional
        Model variant (names for the box, dimension).
    settings : RLSSettings, optional
        Defaults to ``RLSSettings()`` (paper values).
    k0 : int
        Sample index of the measurement preceding the first update
        (Algorithm 1 Step 1: ``k = 0``); sets the clock for
        ``constraint_start_s``.
    """

    def __init__(
        self,
        structure: ModelStructure | None = None,
        settings: RLSSettings | None = None,
        *,
        k0: int = 0,
    ) -> None:
        self._ready = False
        if structure is not None:
            self.setup(structure, settings, k0=k0)

    def setup(
        self,
        structure: ModelStructure,
        settings: RLSSettings | None = None,
        *,
        k0: int = 0,
    ) -> None:
        """(Re)initialise: ``theta = theta(0)``, ``P = P(-1)``, step ``k = k0``."""
        if not isinstance(structure, ModelStructure):
            raise ValueError(f"structure must be a ModelStructure, got {structure!r}")
        if settings is None:
            settings = RLSSettings()
        if not isinstance(settings, RLSSettings):
            raise ValueError(f"settings must be RLSSettings, got {settings!r}")
        if int(k0) != k0:
            raise ValueError(f"k0 must be an integer, got {k0!r}")
        self.structure = structure
        self.settings = settings
        self._n = structure.n_params
        self._P0, self._theta0, lower, upper = settings.resolve(structure)
        self._lower, self._upper = lower, upper
        self._projector = _BoxProjector(lower, upper)
        self._boxed = self._projector.c.size > 0
        self._phi_shape = (self._n,)
        self._ones_nn = np.ones(self._n * self._n)
        self._lam = settings.forgetting
        self._start = settings.constraint_start_index
        self._theta = self._theta0.copy()
        self._P = self._P0.copy()
        self._k = int(k0)
        self._n_projections = 0
        self._n_resets = 0
        self._ready = True

    # -- properties ------------------------------------------------------
    @property
    def theta(self) -> np.ndarray:
        """Current estimate ``theta(k)`` (copy)."""
        self._check_ready()
        return self._theta.copy()

    @property
    def P(self) -> np.ndarray:
        """Current covariance ``P(k-1)`` (copy)."""
        self._check_ready()
        return self._P.copy()

    @property
    def step(self) -> int:
        """Sample index ``k`` of the latest measurement used."""
        self._check_ready()
        return self._k

    @property
    def lower(self) -> np.ndarray:
        """Lower bounds of ``C`` (copy; -inf = unbounded)."""
        return self._lower.copy()

    @property
    def upper(self) -> np.ndarray:
        """Upper bounds of ``C`` (copy; +inf = unbounded)."""
        return self._upper.copy()

    @property
    def n_projections(self) -> int:
        """Number of updates where the projection changed ``theta``."""
        return self._n_projections

    @property
    def n_resets(self) -> int:
        """Number of covariance resets (``on_covariance_loss="reset"``)."""
        return self._n_resets

    def constraint_active(self, k: int | None = None) -> bool:
        """Whether the projection applies at sample ``k`` (default: next update)."""
        self._check_ready()
        k = self._k + 1 if k is None else k
        return k >= self._start

    # -- update ----------------------------------------------------------
    def update(self, phi: Sequence[float] | np.ndarray, y: float) -> np.ndarray:
        """One step of Eq. (4) and, if active, the projection of Algorithm 1.

        Parameters
        ----------
        phi : array_like, shape (n_params,)
            Regressor ``phi(k-1)`` (section 2.3).
        y : float
            Measurement ``l(k)`` in mm.

        Returns
        -------
        ndarray
            ``theta(k)`` (copy).
        """
        if not self._ready:
            self._check_ready()
        phi = np.asarray(phi, dtype=float)
        if phi.shape != self._phi_shape:
            raise ValueError(f"phi must have shape ({self._n},), got {phi.shape}")
        # phi.phi is a sum of squares: finite iff every entry is finite, unless
        # it overflows; only then pay for the element-wise test
        if not math.isfinite(_dot(phi, phi)) and not np.isfinite(phi).all():
            raise ValueError(f"phi must be finite, got non-finite entries at {np.flatnonzero(~np.isfinite(phi)).tolist()}")
        y = float(y)
        if not math.isfinite(y):
            raise ValueError(f"y must be finite, got {y}")
        return self._advance(phi, y).copy()

    def _advance(self, phi: np.ndarray, y: float) -> np.ndarray:
        """:meth:`update` for validated input: ``phi`` a finite float array of shape
        ``(n_params,)``, ``y`` a finite float.  Returns the estimator's own ``theta(k)``
        array (not a copy; the estimator never modifies it in place).

        This runs every sample, so it is written for few numpy calls on the
        tiny arrays (their per-call overhead dominates): scalar checks where
        they are exact, and the rank-1 covariance update in place.
        """
        P = self._P
        lam = self._lam
        Pphi = _dot(P, phi)
        denom = lam + _dot(phi, Pphi)
        err = y - _dot(phi, self._theta)
        theta = _add(self._theta, _multiply(Pphi, err / denom))  # ufuncs: cheaper than the operators
        # P_new = (P - Pphi Pphi^T / denom) / lam, in place on a fresh array;
        # (Pphi_i Pphi_j) / denom is bit-symmetric, so P stays exactly
        # symmetric (set_state symmetrises its input once)
        P_new = _dot(Pphi[:, None], Pphi[None, :])  # = np.multiply.outer(Pphi, Pphi) exactly (k = 1), cheaper
        _divide(P_new, denom, out=P_new)
        _subtract(P, P_new, out=P_new)
        if lam != 1.0:
            P_new /= lam

        # one sum catches any inf/NaN entry (inf - inf -> NaN as well); done as
        # a BLAS dot with ones, cheaper than .sum() on this tiny array.  Then
        # all diagonal entries are finite and a plain min() is exact
        th = theta.tolist()
        total = _dot(P_new.reshape(-1), self._ones_nn) + sum(th)
        if not (math.isfinite(total) and min(P_new.diagonal().tolist()) > 0.0):
            if self.settings.on_covariance_loss == "raise":
                raise FloatingPointError(
                    f"RLS covariance lost positive definiteness at step k={self._k + 1} "
                    f"(min diag {P_new.diagonal().min()!r}); rescale the data or reduce p0"
                )
            # documented rule: drop this update, restart P from P(-1)
            self._k += 1
            self._P = self._P0.copy()
            self._n_resets += 1
            return self._theta

        self._k += 1
        if self._boxed and self._k >= self._start and not self._projector.inside(th):
            # the active set usually persists from sample to sample: try the one the
            # previous estimate sits on first (a function of theta(k-1), so of the state)
            theta = self._projector.project(theta, P_new, th, self._projector.hint_from(self._theta))
            self._n_projections += 1
        self._theta = theta
        self._P = P_new
        return theta

    # -- state -----------------------------------------------------------
    def get_state(self) -> dict:
        """Plain-dict snapshot (copies) for FMU state save/rewind."""
        self._check_ready()
        return {
            "theta": self._theta.copy(),
            "P": self._P.copy(),
            "k": self._k,
            "n_projections": self._n_projections,
            "n_resets": self._n_resets,
        }

    def set_state(self, state: Mapping) -> None:
        """Restore a :meth:`get_state` snapshot; continued updates are bit-identical."""
        self._check_ready()
        theta = np.array(state["theta"], dtype=float)
        P = np.array(state["P"], dtype=float)
        if theta.shape != (self._n,):
            raise ValueError(f"state['theta'] must have shape ({self._n},), got {theta.shape}")
        if P.shape != (self._n, self._n):
            raise ValueError(f"state['P'] must have shape ({self._n}, {self._n}), got {P.shape}")
        if not (np.isfinite(theta).all() and np.isfinite(P).all()):
            raise ValueError("state['theta'] and state['P'] must be finite")
        # update() keeps P exactly symmetric given a symmetric start; a
        # get_state() snapshot is, so its round trip stays bit-identical
        if not np.array_equal(P, P.T):
            P = 0.5 * (P + P.T)
        self._theta = theta
        self._P = P
        self._k = int(state["k"])
        self._n_projections = int(state.get("n_projections", 0))
        self._n_resets = int(state.get("n_resets", 0))

    def _check_ready(self) -> None:
        if not self._ready:
            raise RuntimeError("ConstrainedRLS.setup(structure, settings) has not been called")
