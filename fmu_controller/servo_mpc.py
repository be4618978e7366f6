"""MPC with servo mechanism, section 3.2 (Eq. (15)-(20), Table 5).

Predictor: the linearised plant Eq. (2), ``l(k+1) = a1 l(k) + a2 l(k-1) +
b1 u_c(k)``, in the non-minimal state space Eq. (17) with ``x(k) = [l(k),
l(k-1)]``, plus the discrete integrator Eq. (18), ``x_s(k+1) = x_s(k) + r(k) -
l(k)``.  The decision variables are the input moves ``Delta u_c(k+i|k)``,
``i = 0..Hu-1`` (Eq. (16)); beyond ``Hu - 1`` the input is held.  Cost Eq. (15)::

    J = sum_{i=1..Hp} Q(i)  (l_hat(k+i|k) - r(k+i))^2
      + sum_{i=0..Hu-1} R(i) Delta u_c(k+i|k)^2
      + sum_{i=1..Hp} Qs(i) x_s(k+i|k)^2

with ``x_s(k+i|k) = x_s(k) + sum_{j=0..i-1} (r(k+j) - l_hat(k+j|k))`` and
``l_hat(k|k) = l(k)`` (measured).  Input constraint Eq. (19)::

    u_min <= u_c(k+i|k) - offset <= u_max,   i = 0..Hu-1,

where ``offset = H(k) / b1`` is the hysteresis-cancellation term of Eq. (5)
(``H(k) = y_hy(k) + y_hy(k-1)``), given by the caller and the same for all
``i`` as printed in the paper.  ``u_c(k) = u_c(k-1) + Delta u_c(k)`` (Eq. (20)).

Condensed QP
------------
Let ``D = [Delta u_c(k|k), ..., Delta u_c(k+Hu-1|k)]`` and the data vector
``z = [l(k), l(k-1), u_c(k-1), x_s(k), r(k), ..., r(k+Hp)]``.  With the impulse
response ``h_n = C A^n B`` and step response ``s_i = sum_{n<i} h_n``::

    l_hat(k+i|k) = C A^i x(k) + s_i u_c(k-1) + sum_{m<min(i,Hu)} s_{i-m} D_m
    L   = F z + G D                      (Hp predictions, G[i-1, m] = s_{i-m})
    X_s = S0 z - H D,   H = M G          (M: strictly lower-triangular ones)

so ``J = 0.5 D^T P D + (K z)^T D + const`` with
``P = 2 (G^T Q G + R + H^T Qs H)`` and ``K = 2 (G^T Q E0 - H^T Qs S0)``
(``E0 = F - [r(k+1..k+Hp) selector]``).  Internally Eq. (15) is kept as the
weighted sum of squares of the stacked residual ``[E0 z + G D; S0 z - H D; D]``
with weights ``[Q; Qs; R]``, from which ``P``, ``K`` and the cost are formed.
The constraint matrix is the cumulative-sum matrix ``S`` (``u_c(k+i|k) =
u_c(k-1) + (S D)_i``).  ``P`` depends on ``(a1, a2, b1)`` only, ``S`` never
changes; both are handed to OSQP once with a fixed (dense upper-triangular /
dense lower-triangular) sparsity pattern and updated in place by
:meth:`ServoMPC.update_model` (adaptive MPC).  The unconstrained minimiser
``D* = -P^{-1} K z`` is precomputed as a matrix per model.

OSQP runs with polishing off (osqp 1.1 prints "Polishing not needed ..." even
with ``verbose=False``); instead its answer is
refined in numpy on its active set (``ServoMPCSettings.refine``), which makes
the returned plan exact to rounding rather than to ``eps_abs``.

Units: ``l`` and ``r`` in mm, ``u_c``, ``offset`` and ``u`` in V, ``b1`` in
mm/V, ``x_s`` in mm (sum of errors over samples), ``Q`` and ``Qs`` in 1/mm^2,
``R`` in 1/V^2.

After :meth:`ServoMPC.solve` the caller applies the valve voltage of Eq. (5),
``u(k) = u_c(k) - offset``, and carries ``u_c(k)`` into the next sample as
``uc_prev_v`` and ``x_s(k+1)`` (:func:`integrator_step`) as ``xs``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping, Sequence

import numpy as np
import osqp
import scipy.sparse as sp

__all__ = [
    "TABLE5_SERVO",
    "ServoMPCSettings",
    "ServoMPCResult",
    "ServoMPC",
    "integrator_step",
]

#: Table 5, "MPC/AMPC with servo mechanism" column.
TABLE5_SERVO: Mapping[str, Any] = MappingProxyType({
    "hp": 5, "hu": 5, "q": (5.0, 5.0, 5.0, 5.0, 5.0), "qs": 2.0, "r": 15.0,
})

# |b1| below this makes the predictor (and offset = H/b1) meaningless.
_B1_MIN = 1e-9
# An OSQP answer that is not "solved" is still used if it violates Eq. (19)
# by at most this much [V] and is not worse than the clipped fallback.
_FEAS_TOL_V = 1e-4
# A bound counts as active within this distance [V] (solver tolerances are
# ~1e-7; the plan is projected onto the box anyway).
_ACTIVE_TOL_V = 1e-6
# OSQP's default initial rho; restored before a solve if adaptive rho moved it
# so that each solve depends only on (model, warm start, data).
_RHO0 = 0.1


# ---------------------------------------------------------------------------
# Settings
# ---------------------------------------------------------------------------
def _positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be >= 1, got {value!r}")
    return int(value)


def _finite_float(name: str, value: Any) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return x


def _freeze_weight(name: str, value: Any, n: int, n_name: str, *, strict: bool) -> float | tuple[float, ...]:
    """Scalar weight or per-step tuple of length ``n``; >= 0 (> 0 if ``strict``)."""
    if np.ndim(value) == 0:
        w = _finite_float(name, value)
        if w < 0 or (strict and w == 0):
            raise ValueError(f"{name} must be {'> 0' if strict else '>= 0'}, got {value!r}")
        return w
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real scalar or sequence, got {value!r}") from None
    if arr.ndim != 1 or arr.size != n:
        raise ValueError(f"{name} must be a scalar or a sequence of length {n_name} = {n}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    if (arr < 0).any() or (strict and (arr == 0).any()):
        raise ValueError(f"{name} must be {'> 0' if strict else '>= 0'} elementwise, got {arr.tolist()}")
    return tuple(float(x) for x in arr)


@dataclass(frozen=True, kw_only=True)
class ServoMPCSettings:
    """Settings of the MPC with servo mechanism (section 3.2, Table 5).

    Construction is keyword-only and validated; a bad value raises
    ``ValueError`` naming the field.  Sequence weights are stored as tuples.
    """

    hp: int = 5
    """Prediction horizon ``Hp`` [samples] of Eq. (15); Table 5: 5."""
    hu: int = 5
    """Control horizon ``Hu`` [samples], ``1 <= Hu <= Hp``; Table 5: 5."""
    q: float | tuple[float, ...] = 5.0
    """Tracking weight ``Q(i)`` [1/mm^2], scalar or ``Hp`` values for i = 1..Hp; Table 5: {5, 5, 5, 5, 5}."""
    qs: float | tuple[float, ...] = 2.0
    """Integrator weight ``Qs(i)`` [1/mm^2], scalar or ``Hp`` values for i = 1..Hp; Table 5: 2."""
    r: float | tuple[float, ...] = 15.0
    """Move weight ``R(i)`` [1/V^2], > 0, scalar or ``Hu`` values for i = 0..Hu-1; Table 5: 15."""
    u_min_v: float = 0.0
    """Lower bound [V] of ``u_c - offset`` in Eq. (19) (valve input voltage)."""
    u_max_v: float = 10.0
    """Upper bound [V] of ``u_c - offset`` in Eq. (19)."""
    eps_abs: float = 1e-7
    """OSQP absolute tolerance (>= 0; not both tolerances 0)."""
    eps_rel: float = 1e-7
    """OSQP relative tolerance (>= 0)."""
    max_iter: int = 4000
    """OSQP iteration limit per solve; on hitting it the fallback rules of :meth:`ServoMPC.solve` apply."""
    warm_start: bool = True
    """Warm-start OSQP from the previous solution (primal and dual)."""
    refine: bool = True
    """Refine OSQP's answer on its active set of Eq. (19) (exact KKT solve, kept only if
    feasible and not costlier); stands in for OSQP's polishing, which is off."""

    def __post_init__(self) -> None:
        hp = _positive_int("hp", self.hp)
        hu = _positive_int("hu", self.hu)
        if hu > hp:
            # moves after k+Hp-1 would not affect any prediction in Eq. (15)
            raise ValueError(f"hu must be <= hp = {hp}, got {self.hu!r}")
        object.__setattr__(self, "hp", hp)
        object.__setattr__(self, "hu", hu)
        object.__setattr__(self, "q", _freeze_weight("q", self.q, hp, "hp", strict=False))
        object.__setattr__(self, "qs", _freeze_weight("qs", self.qs, hp, "hp", strict=False))
        # R > 0 keeps the QP Hessian positive definite for every model
        object.__setattr__(self, "r", _freeze_weight("r", self.r, hu, "hu", strict=True))
        u_min = _finite_float("u_min_v", self.u_min_v)
        u_max = _finite_float("u_max_v", self.u_max_v)
        if not u_min < u_max:
            raise ValueError(f"u_max_v must be > u_min_v = {u_min}, got {self.u_max_v!r}")
        object.__setattr__(self, "u_min_v", u_min)
        object.__setattr__(self, "u_max_v", u_max)
        for name in ("eps_abs", "eps_rel"):
            eps = _finite_float(name, getattr(self, name))
            if eps < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, eps)
        if self.eps_abs == 0 and self.eps_rel == 0:
            raise ValueError(f"eps_abs must be > 0 when eps_rel is 0, got {self.eps_abs!r}")
        object.__setattr__(self, "max_iter", _positive_int("max_iter", self.max_iter))
        if not isinstance(self.warm_start, (bool, np.bool_)):
            raise ValueError(f"warm_start must be a bool, got {self.warm_start!r}")
        object.__setattr__(self, "warm_start", bool(self.warm_start))
        if not isinstance(self.refine, (bool, np.bool_)):
            raise ValueError(f"refine must be a bool, got {self.refine!r}")
        object.__setattr__(self, "refine", bool(self.refine))

    def weights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(Q, Qs, R)`` as arrays of lengths ``(Hp, Hp, Hu)``."""
        return (np.broadcast_to(np.asarray(self.q, dtype=float), (self.hp,)).copy(),
                np.broadcast_to(np.asarray(self.qs, dtype=float), (self.hp,)).copy(),
                np.broadcast_to(np.asarray(self.r, dtype=float), (self.hu,)).copy())


# ---------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ServoMPCResult:
    """Output of :meth:`ServoMPC.solve` (arrays are read-only).

    Attributes
    ----------
    uc_v : float
        Control input ``u_c(k)`` [V] of Eq. (20).  The valve voltage is
        ``u(k) = u_c(k) - offset_v`` (Eq. (5)), see :attr:`u_v`.
    delta_uc_v : ndarray, shape (Hu,)
        Planned moves ``Delta u_c(k+i|k)`` [V], ``i = 0..Hu-1`` (Eq. (16));
        ``delta_uc_v[0] = uc_v - uc_prev``.
    uc_plan_v : ndarray, shape (Hu,)
        Planned inputs ``u_c(k+i|k)`` [V], ``i = 0..Hu-1``.
    predicted_l_mm : ndarray, shape (Hp,)
        ``l_hat(k+i|k)`` [mm], ``i = 1..Hp`` (Eq. (17)).
    predicted_xs : ndarray, shape (Hp,)
        ``x_s(k+i|k)`` [mm], ``i = 1..Hp`` (Eq. (18)).
    cost : float
        Value of Eq. (15) at the returned plan.
    offset_v : float
        The hysteresis-cancellation offset ``H(k)/b1`` [V] used in Eq. (19).
    status : str
        OSQP status (``"solved"``, ...); ``"fallback: <osqp status>"`` when the
        clipped unconstrained plan was used; ``"unconstrained"`` /
        ``"unconstrained clipped"`` from :meth:`ServoMPC.unconstrained_solution`.
    iterations : int
        OSQP iterations (0 for the closed form).
    constrained : bool
        Some ``u_c(k+i|k) - offset`` is at a bound of Eq. (19) (or, for an
        unclipped unconstrained plan, at or beyond one).
    solve_time_s : float
        Wall-clock time of the call [s] (not part of the reproducible output).
    """

    uc_v: float
    delta_uc_v: np.ndarray
    uc_plan_v: np.ndarray
    predicted_l_mm: np.ndarray
    predicted_xs: np.ndarray
    cost: float
    offset_v: float
    status: str
    iterations: int
    constrained: bool
    solve_time_s: float

    @property
    def u_v(self) -> float:
        """Valve voltage ``u(k) = u_c(k) - offset`` [V] of Eq. (5)."""
        return self.uc_v - self.offset_v

    @property
    def fallback(self) -> bool:
        """Whether OSQP failed and the clipped unconstrained plan was returned."""
        return self.status.startswith("fallback")


def integrator_step(xs: float, r_mm: float, l_mm: float) -> float:
    """Discrete integrator Eq. (18): ``x_s(k+1) = x_s(k) + r(k) - l(k)`` [mm]."""
    return float(xs) + float(r_mm) - float(l_mm)


# ---------------------------------------------------------------------------
# Controller
# ---------------------------------------------------------------------------
class ServoMPC:
    """MPC with servo mechanism (section 3.2) on an OSQP-solved condensed QP.

    Lifecycle (as osqp): the constructor builds the QP for the initial model
    and calls OSQP ``setup`` once; :meth:`update_model` replaces ``(a1, a2,
    b1)`` in place (AMPC, Fig. 6); :meth:`solve` once per sample.

    Each solve depends only on the model, the warm-start vectors of
    :meth:`get_state` and its arguments (OSQP's scaling, rho and iterate are
    reset to functions of those), so a restored controller repeats results
    bit for bit.

    Parameters
    ----------
    settings : ServoMPCSettings, optional
        Defaults to ``ServoMPCSettings()`` (Table 5).
    a1, a2 : float
        Predictor coefficients of Eq. (2) [-].
    b1 : float
        Predictor input gain of Eq. (2) [mm/V], ``|b1| >= 1e-9``.
    """

    def __init__(self, settings: ServoMPCSettings | None = None, *, a1: float, a2: float, b1: float) -> None:
        if settings is None:
            settings = ServoMPCSettings()
        if not isinstance(settings, ServoMPCSettings):
            raise ValueError(f"settings must be ServoMPCSettings, got {settings!r}")
        self.settings = settings
        hp, hu = settings.hp, settings.hu
        self._hp, self._hu = hp, hu
        nz = self._nz = 4 + hp + 1  # z = [l, l_prev, uc_prev, xs, r(k..k+Hp)]
        Q, Qs, R = settings.weights()
        self._u_min, self._u_max = settings.u_min_v, settings.u_max_v
        self._M = np.tril(np.ones((hp, hp)), -1)   # x_s(k+i) sums l_hat(k+1..k+i-1)
        self._S = np.tril(np.ones((hu, hu)))       # u_c(k+i) = uc_prev + (S D)_i
        self._ones_hu = np.ones(hu)
        self._zeros_hu = np.zeros(hu)
        # G[i-1, m] = s_{i-m}; s_0 = 0 covers m >= i
        i, m = np.meshgrid(np.arange(1, hp + 1), np.arange(hu), indexing="ij")
        self._g_idx = np.maximum(i - m, 0)

        # Eq. (15) as a weighted sum of squares of the stacked residual
        # rho = W z + Gall D = [l_hat - r(k+1..k+Hp); x_s(k+1..k+Hp); D],
        # weights w = [Q; Qs; R].  Model-free parts of W:
        self._w = np.concatenate([Q, Qs, R])
        self._W0 = np.zeros((2 * hp + hu, nz))
        self._W0[np.arange(hp), 5 + np.arange(hp)] = -1.0          # - r(k+i)
        self._W0[hp:2 * hp, 0] = -1.0                              # - l(k|k)
        self._W0[hp:2 * hp, 3] = 1.0                               # + x_s(k)
        self._W0[hp:2 * hp, 4:4 + hp] = np.tril(np.ones((hp, hp)))  # + r(k..k+i-1)
        self._Gall = np.zeros((2 * hp + hu, hu))
        self._Gall[2 * hp:] = np.eye(hu)

        # Fixed CSC patterns: P dense upper triangle, A = S dense lower
        # triangle.  Explicit (data, indices, indptr) so that an entry that
        # happens to be 0 is still stored and the pattern never changes.
        self._p_rows = np.concatenate([np.arange(j + 1) for j in range(hu)])
        self._p_cols = np.concatenate([np.full(j + 1, j) for j in range(hu)])
        p_indptr = np.concatenate([[0], np.cumsum(np.arange(1, hu + 1))])
        a_rows = np.concatenate([np.arange(j, hu) for j in range(hu)])
        a_indptr = np.concatenate([[0], np.cumsum(np.arange(hu, 0, -1))])
        self._Ax = np.ones(a_rows.size)  # rewritten with every P update, see _push_model

        self._a1, self._a2, self._b1 = self._check_model(a1, a2, b1)
        self._set_model(self._a1, self._a2, self._b1)

        P = sp.csc_matrix((self._Px(), self._p_rows.copy(), p_indptr), shape=(hu, hu))
        A = sp.csc_matrix((self._Ax.copy(), a_rows, a_indptr), shape=(hu, hu))
        self._prob = osqp.OSQP()
        # q = 0 at setup, as in every later matrix update (see _push_model)
        self._prob.setup(
            P, np.zeros(hu), A,
            np.full(hu, self._u_min), np.full(hu, self._u_max),
            verbose=False, polishing=False, rho=_RHO0,
            eps_abs=settings.eps_abs, eps_rel=settings.eps_rel,
            max_iter=settings.max_iter, warm_starting=settings.warm_start,
        )
        self._x_ws = np.zeros(hu)
        self._y_ws = np.zeros(hu)
        self._rho_dirty = False

    # -- model -----------------------------------------------------------
    @property
    def model(self) -> tuple[float, float, float]:
        """Current predictor ``(a1, a2, b1)`` of Eq. (2)."""
        return (self._a1, self._a2, self._b1)

    def update_model(self, a1: float, a2: float, b1: float) -> None:
        """Replace the predictor of Eq. (2)/(17) (adaptive MPC, section 3.3).

        The QP matrices are rewritten in place (OSQP ``update(Px=..., Ax=...)``,
        same sparsity pattern); the next solve equals that of a freshly built
        controller with these parameters and the same warm start.  Raises
        ``ValueError`` for non-finite values or ``|b1| < 1e-9``; the old model
        is kept then.
        """
        new = self._check_model(a1, a2, b1)
        if new == (self._a1, self._a2, self._b1):
            return
        self._set_model(*new)
        self._a1, self._a2, self._b1 = new
        self._push_model()

    @staticmethod
    def _check_model(a1: float, a2: float, b1: float) -> tuple[float, float, float]:
        a1 = _finite_float("a1", a1)
        a2 = _finite_float("a2", a2)
        b1 = _finite_float("b1", b1)
        if abs(b1) < _B1_MIN:
            raise ValueError(f"b1 must satisfy |b1| >= {_B1_MIN:g}, got {b1!r}")
        return a1, a2, b1

    def _set_model(self, a1: float, a2: float, b1: float) -> None:
        """Condensed matrices of the module docstring for ``(a1, a2, b1)``."""
        hp = self._hp
        # rows C A^n = [p_n, q_n], n = 0..Hp, by [p, q] A = [a1 p + q, a2 p];
        # impulse response h_n = C A^n B = b1 p_n, step response s_i = sum_{n<i} h_n
        p, q = [1.0], [0.0]
        for _ in range(hp):
            p.append(a1 * p[-1] + q[-1])
            q.append(a2 * p[-2])
        s = np.concatenate([[0.0], np.cumsum(b1 * np.array(p[:hp]))])
        G = s[self._g_idx]
        F = np.zeros((hp, self._nz))                   # free response l_hat = F z + G D
        F[:, 0] = p[1:]
        F[:, 1] = q[1:]
        F[:, 2] = s[1:]
        W = self._W0.copy()
        W[:hp] += F
        W[hp:2 * hp] -= self._M @ F
        Gall = self._Gall.copy()
        Gall[:hp] = G
        Gall[hp:2 * hp] = -(self._M @ G)

        wG = self._w[:, None] * Gall
        P = 2.0 * (Gall.T @ wG)             # 2 (G^T Q G + H^T Qs H + R)
        P = 0.5 * (P + P.T)                 # bit-symmetric triangle for OSQP
        K = 2.0 * (wG.T @ W)                # q = K z
        # unconstrained minimiser D* = -P^{-1} K z (normal equations); P is SPD (R > 0)
        self._K_unc = -np.linalg.solve(P, K)
        self._P, self._K, self._F, self._G, self._W, self._Gall_m = P, K, F, G, W, Gall

    def _Px(self) -> np.ndarray:
        return self._P[self._p_rows, self._p_cols]

    def _push_model(self) -> None:
        # OSQP recomputes its Ruiz scaling from (P, A, q) on a matrix update
        # after un-scaling the old data.  Zeroing q first and rewriting A with
        # its exact values makes that scaling depend on the model only, so a
        # solve never depends on the history of updates.
        self._prob.update(q=self._zeros_hu)
        self._prob.update(Px=self._Px(), Ax=self._Ax)
        # the warm start is kept in unscaled coordinates and re-applied at solve

    # -- helpers ---------------------------------------------------------
    def _data(self, l_mm, l_prev_mm, uc_prev_v, xs, r_future_mm, offset_v) -> tuple[np.ndarray, float]:
        z = np.empty(self._nz)
        z[0] = _finite_float("l_mm", l_mm)
        z[1] = _finite_float("l_prev_mm", l_prev_mm)
        z[2] = _finite_float("uc_prev_v", uc_prev_v)
        z[3] = _finite_float("xs", xs)
        offset = _finite_float("offset_v", offset_v)
        try:
            r = np.asarray(r_future_mm, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"r_future_mm must be a sequence of numbers, got {r_future_mm!r}") from None
        if r.shape != (self._hp + 1,):
            raise ValueError(
                f"r_future_mm must hold r(k), ..., r(k+Hp): length Hp+1 = {self._hp + 1}, got shape {r.shape}")
        if not np.isfinite(r).all():
            raise ValueError(f"r_future_mm must be finite, got {r.tolist()}")
        z[4:] = r
        return z, offset

    def _cost(self, D: np.ndarray, wz: np.ndarray) -> float:
        # Eq. (15) from the residuals (no cancellation of large constants)
        res = wz + self._Gall_m @ D
        return float(self._w @ (res * res))

    def _project(self, D: np.ndarray, uc_prev: float, offset: float) -> tuple[np.ndarray, np.ndarray, bool]:
        """Clip the plan so ``u_c(k+i) - offset`` obeys Eq. (19); return moves, inputs, changed."""
        plan = D.cumsum()
        plan += uc_prev
        lo, hi = self._u_min + offset, self._u_max + offset
        if plan.min() >= lo and plan.max() <= hi:
            return D, plan, False  # keep the exact moves
        clipped = np.minimum(np.maximum(plan, lo), hi)
        return np.diff(clipped, prepend=uc_prev), clipped, True

    def _at_bound(self, plan: np.ndarray, offset: float) -> bool:
        return bool(plan.min() - offset <= self._u_min + _ACTIVE_TOL_V
                    or plan.max() - offset >= self._u_max - _ACTIVE_TOL_V)

    def _result(self, D, plan, z, wz, offset, status, iters, constrained, t0) -> ServoMPCResult:
        pred_l = self._F @ z + self._G @ D
        pred_xs = wz[self._hp:2 * self._hp] + self._Gall_m[self._hp:2 * self._hp] @ D
        D = np.array(D, dtype=float)
        for a in (D, plan, pred_l, pred_xs):
            a.setflags(write=False)
        return ServoMPCResult(
            uc_v=float(plan[0]), delta_uc_v=D, uc_plan_v=plan, predicted_l_mm=pred_l,
            predicted_xs=pred_xs, cost=self._cost(D, wz), offset_v=offset, status=status,
            iterations=int(iters), constrained=bool(constrained),
            solve_time_s=time.perf_counter() - t0,
        )

    def _refine(self, D, plan, y, z, wz, q, lower, upper, offset) -> tuple[np.ndarray, np.ndarray]:
        """Exact minimiser on OSQP's active set (what OSQP's polishing does).

        ADMM stops at ~eps accuracy; next to a bound with a large multiplier
        that shows in the cost.  Guess the active rows as OSQP's polish does
        (``z - l < -y`` lower, ``u - z < y`` upper), solve the equality-
        constrained QP ``[P A_a^T; A_a 0] [D; nu] = [-q; b_a]`` and keep it only
        if it is feasible and not costlier: a wrong guess cannot do harm.
        """
        cum = D.cumsum()  # S D, the constrained quantity
        low = cum - lower < -y
        up = upper - cum < y
        act = np.flatnonzero(low | up)
        hu = self._hu
        uc_prev = z[2]
        if act.size == 0:
            cand = self._K_unc @ z  # = -P^{-1} q, as unconstrained_solution
            cand_plan = cand.cumsum()
            cand_plan += uc_prev
            if cand_plan.min() >= self._u_min + offset and cand_plan.max() <= self._u_max + offset:
                return cand, cand_plan  # feasible global minimiser: optimal, no comparison needed
        else:
            n = hu + act.size
            kkt = np.zeros((n, n))
            kkt[:hu, :hu] = self._P
            kkt[hu:, :hu] = self._S[act]
            kkt[:hu, hu:] = self._S[act].T
            rhs = np.concatenate([-q, np.where(low[act], lower[act], upper[act])])
            try:
                cand = np.linalg.solve(kkt, rhs)[:hu]
            except np.linalg.LinAlgError:
                return D, plan
            if not np.isfinite(cand).all():
                return D, plan
            cand_plan = uc_prev + cand.cumsum()
        tol = 1e-9 * (1.0 + abs(offset) + abs(uc_prev) + self._u_max - self._u_min)
        if (cand_plan < self._u_min + offset - tol).any() or (cand_plan > self._u_max + offset + tol).any():
            return D, plan
        cand, cand_plan, _ = self._project(cand, uc_prev, offset)
        if self._cost(cand, wz) <= self._cost(D, wz):
            return cand, cand_plan
        return D, plan

    # -- public ------------------------------------------------------------
    def cost(self, delta_uc_v: Sequence[float], *, l_mm: float, l_prev_mm: float, uc_prev_v: float,
             xs: float, r_future_mm: Sequence[float], offset_v: float = 0.0) -> float:
        """Eq. (15) for the moves ``delta_uc_v`` (length Hu) and the data of :meth:`solve`.

        ``offset_v`` does not enter Eq. (15); it is accepted (and validated)
        so that the same keyword set works for all three methods.
        """
        z, _ = self._data(l_mm, l_prev_mm, uc_prev_v, xs, r_future_mm, offset_v)
        D = np.asarray(delta_uc_v, dtype=float)
        if D.shape != (self._hu,):
            raise ValueError(f"delta_uc_v must have length Hu = {self._hu}, got shape {D.shape}")
        return self._cost(D, self._W @ z)

    def unconstrained_solution(self, *, l_mm: float, l_prev_mm: float, uc_prev_v: float, xs: float,
                               r_future_mm: Sequence[float], offset_v: float = 0.0,
                               clip: bool = False) -> ServoMPCResult:
        """Closed-form minimiser of Eq. (15) without Eq. (19) (normal equations).

        ``D* = -P^{-1} K z`` (module docstring).  With ``clip=True`` the planned
        inputs are clipped so that every ``u_c(k+i|k) - offset`` lies in
        ``[u_min_v, u_max_v]`` and the moves recomputed from them: a feasible,
        generally suboptimal plan, the fallback of :meth:`solve`.  Arguments
        as in :meth:`solve`; the controller state is not touched.
        """
        t0 = time.perf_counter()
        z, offset = self._data(l_mm, l_prev_mm, uc_prev_v, xs, r_future_mm, offset_v)
        wz = self._W @ z
        D = self._K_unc @ z
        if clip:
            D, plan, changed = self._project(D, z[2], offset)
            return self._result(D, plan, z, wz, offset, "unconstrained clipped", 0,
                                changed or self._at_bound(plan, offset), t0)
        plan = z[2] + D.cumsum()
        return self._result(D, plan, z, wz, offset, "unconstrained", 0, self._at_bound(plan, offset), t0)

    def solve(self, *, l_mm: float, l_prev_mm: float, uc_prev_v: float, xs: float,
              r_future_mm: Sequence[float], offset_v: float = 0.0) -> ServoMPCResult:
        """Minimise Eq. (15) subject to Eq. (19) for sample ``k``.

        Parameters
        ----------
        l_mm, l_prev_mm : float
            Measured ``l(k)`` and ``l(k-1)`` [mm] (state of Eq. (17)).
        uc_prev_v : float
            ``u_c(k-1)`` [V], the previous :attr:`ServoMPCResult.uc_v`.
        xs : float
            Integrator state ``x_s(k)`` [mm] of Eq. (18) (see :func:`integrator_step`).
        r_future_mm : sequence of float, length Hp + 1
            ``r(k), r(k+1), ..., r(k+Hp)`` [mm]: ``r(k)`` feeds the integrator,
            the rest the tracking term.
        offset_v : float
            ``H(k)/b1`` [V] of Eq. (5), shifting the bounds of Eq. (19).

        Returns
        -------
        ServoMPCResult
            Apply ``u(k) = uc_v - offset_v`` (Eq. (5), :attr:`ServoMPCResult.u_v`).
            OSQP's plan is refined on its active set (``settings.refine``) and
            projected onto Eq. (19) (changes of the order of the solver
            tolerance), so ``u(k)`` lies in ``[u_min_v, u_max_v]`` up to
            rounding.  If OSQP does not report "solved", its plan is kept only
            if finite, within 1e-4 V of Eq. (19) and not costlier than the
            clipped unconstrained plan; otherwise that clipped plan is returned
            with status ``"fallback: <osqp status>"``.  Never NaN.

        Raises
        ------
        ValueError
            Non-finite argument (named in the message) or ``r_future_mm`` not of
            length ``Hp + 1``.  The controller state is unchanged then.
        """
        t0 = time.perf_counter()
        z, offset = self._data(l_mm, l_prev_mm, uc_prev_v, xs, r_future_mm, offset_v)
        uc_prev = z[2]
        wz = self._W @ z
        q = self._K @ z
        # Eq. (19) on u_c(k+i) = uc_prev + (S D)_i
        lower = (self._u_min + offset - uc_prev) * self._ones_hu
        upper = (self._u_max + offset - uc_prev) * self._ones_hu
        prob = self._prob
        prob.update(q=q, l=lower, u=upper)
        if self._rho_dirty:
            prob.update_settings(rho=_RHO0)
            self._rho_dirty = False
        if self.settings.warm_start:
            # explicit warm start from our own copies: OSQP's internal iterate
            # would carry roundoff from earlier solves or restores
            prob.warm_start(x=self._x_ws, y=self._y_ws)
        res = prob.solve(raise_error=False)
        info = res.info
        if info.rho_updates:
            self._rho_dirty = True
        status = str(info.status)
        x = res.x
        finite = x is not None and bool(np.isfinite(x).all())

        use_osqp = finite and status == "solved"
        fallback = None
        if finite and not use_osqp:
            # inaccurate / max-iter answers are kept only if feasible enough
            # and no worse than the documented fallback
            plan = uc_prev + x.cumsum()
            viol = max(float(np.max(self._u_min + offset - plan)), float(np.max(plan - self._u_max - offset)))
            fallback = self._project(self._K_unc @ z, uc_prev, offset)
            use_osqp = viol <= _FEAS_TOL_V and self._cost(x, wz) <= self._cost(fallback[0], wz)

        if use_osqp:
            self._x_ws = np.array(x, dtype=float)
            y = res.y
            self._y_ws = np.array(y, dtype=float) if y is not None and np.isfinite(y).all() else np.zeros(self._hu)
            D, plan, _ = self._project(self._x_ws, uc_prev, offset)
            if self.settings.refine:
                D, plan = self._refine(D, plan, self._y_ws, z, wz, q, lower, upper, offset)
            return self._result(D, plan, z, wz, offset, status, info.iter, self._at_bound(plan, offset), t0)

        if fallback is None:
            fallback = self._project(self._K_unc @ z, uc_prev, offset)
        D, plan, changed = fallback
        # restart the next solve from the feasible fallback plan, not a bad iterate
        self._x_ws = np.array(D, dtype=float)
        self._y_ws = np.zeros(self._hu)
        return self._result(D, plan, z, wz, offset, f"fallback: {status}", info.iter,
                            changed or self._at_bound(plan, offset), t0)

    # -- state -----------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Plain-dict snapshot (python floats and lists) for FMU state save/rewind.

        Holds the model ``(a1, a2, b1)`` and the warm-start primal/dual vectors;
        after :meth:`set_state` the next :meth:`solve` results are
        bit-identical (except ``solve_time_s``).
        """
        return {
            "a1": self._a1, "a2": self._a2, "b1": self._b1,
            "x_warm": [float(v) for v in self._x_ws],
            "y_warm": [float(v) for v in self._y_ws],
        }

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a :meth:`get_state` snapshot (same settings assumed).

        Validated first; on ``ValueError`` nothing changes.
        """
        model = self._check_model(state["a1"], state["a2"], state["b1"])
        vecs = []
        for name in ("x_warm", "y_warm"):
            v = np.array(state[name], dtype=float)
            if v.shape != (self._hu,):
                raise ValueError(f"state[{name!r}] must have length Hu = {self._hu}, got shape {v.shape}")
            if not np.isfinite(v).all():
                raise ValueError(f"state[{name!r}] must be finite, got {v.tolist()}")
            vecs.append(v)
        self.update_model(*model)
        self._x_ws, self._y_ws = vecs
        # OSQP's rho may have been adapted since the snapshot: reset before solving
        self._rho_dirty = True
