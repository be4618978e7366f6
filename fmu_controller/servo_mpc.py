"""MPC with servo mechanism, section 3.2 (Eq. (15)-(20), Table 5).

Predictor: the linearised plant Eq. (2), ``l(k+1) = a1 l(k) + a2 l(k-1) +
b1 u_c(k)``, in the non-minimal state space Eq. (17) with ``x(k) = [l(k),
l(k-1)]``, plus the discrete integrator Eq. (18), ``x_s(k+1) = x_s(k) + r(k) -
l(k)``.  The decision variables are the input moves ``Delta u_c(k+i|k)``,
``i = 0..Hu-1`` (Eq. (16)); beyond ``Hu - 1`` the input is held.  Cost Eq. (15)::

    J = sum_{i=1..Hp} Q(i)  (l_hat(k+i|k) - r(k+i))^2
      + sum_{i=0..Hu-1} R(i) Delta u_c(k+i|k)^2
      + sum_{i=1..Hp} Qs(i) x_s(k+i|k)^2         (Eq. (15)'s Q_c; Table 5's Qs)

with ``x_s(k+i|k) = x_s(k) + sum_{j=0..i-1} (r(k+j) - l_hat(k+j|k))`` and
``l_hat(k|k) = l(k)`` (measured).  Input constraint Eq. (19)::

    u_min <= u_c(k+i|k) - offset <= u_max,   i = 0..Hu-1,

where ``offset = H(k) / b1`` is the hysteresis-cancellation term of Eq. (5)
(``H(k) = y_hy(k) + y_hy(k-1)``), given by the caller and the same for all
``i`` as printed in the paper.  ``u_c(k) = u_c(k-1) + Delta u_c(k)`` (Eq. (20)).

Condensed QP
------------
Eq. (15)-(19) as a QP in the moves ``D`` with data ``z``: :mod:`fmu_controller.servo_qp`
(:class:`~fmu_controller.servo_qp.CondensedServoQP` builds and updates its matrices).

Solution strategy
-----------------
``P`` is positive definite (``R > 0``), so the QP has a unique minimiser and
the unconstrained minimiser ``D* = -P^{-1} K z`` (normal equations,
precomputed as the matrix ``-P^{-1} K`` per model by a Cholesky solve) *is*
the QP optimum whenever its input plan ``u_c(k-1) + S D*`` satisfies
Eq. (19).  :meth:`ServoMPC.solve` therefore evaluates ``D*`` first and returns
it when it is feasible (status ``"solved"``, 0 iterations).  This is exact, not
an approximation: no solver tolerance is involved, and the result is what the
active-set refinement below would return for an OSQP answer with no active
bound.  Its warm start for a later OSQP solve is ``D*`` with zero multipliers
(the exact primal-dual optimum).  Only when ``D*`` violates a bound is the
constrained QP handed to OSQP; in the closed loop that is the rare case
(saturation of the valve, about 2 % of the samples of the 0.1 Hz sine run).
``ServoMPCSettings(always_osqp=True)`` skips the shortcut (reference path for
tests); :attr:`ServoMPC.osqp_solves` counts the OSQP calls.

OSQP gets ``P`` and ``S`` once at construction with a fixed (dense
upper-triangular / dense lower-triangular) sparsity pattern.  A model change
(:meth:`ServoMPC.update_model`, adaptive MPC) only recomputes the small dense
matrices in numpy; they are pushed into OSQP (``update(Px=..., Ax=...)``)
lazily, by the next solve that actually needs OSQP, and only if OSQP holds a
different model (the first OSQP solve always pushes, so every model OSQP uses
went through the same update path and results do not depend on history).

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
from typing import Any, Mapping, Sequence

import numpy as np
import osqp
import scipy.sparse as sp
from scipy.linalg.lapack import dgesv as _dgesv

from .servo_qp import CondensedServoQP
from .argument_checks import real_number
from .servo_settings import TABLE5_SERVO, ServoMPCResult, ServoMPCSettings, integrator_step

_cumsum = np.add.accumulate  # = np.cumsum for 1-d arrays, less call overhead

__all__ = [
    "TABLE5_SERVO",
    "ServoMPCSettings",
    "ServoMPCResult",
    "ServoMPC",
    "integrator_step",
]


# |b1| below this makes the predictor (and offset = H/b1) meaningless.
_B1_MIN = 1e-9
# smallest eigenvalue of the QP Hessian, relative to the largest, that OSQP's LDL factorisation takes
_PD_RTOL = 1e-12
# An OSQP answer that is not "solved" is still used if it violates Eq. (19)
# by at most this much [V] and is not worse than the clipped fallback.
_FEAS_TOL_V = 1e-4
# A bound counts as active within this distance [V] (solver tolerances are
# ~1e-7; the plan is projected onto the box anyway).
_ACTIVE_TOL_V = 1e-6
# OSQP's default initial rho; restored before a solve if adaptive rho moved it
# so that each solve depends only on (model, warm start, data).
_RHO0 = 0.1
# OSQP treats a bound beyond this as infinite and refuses (printing to stdout) an update with a lower
# bound at +inf or an upper one at -inf: QP data of that size only arise from a diverged estimate.
_OSQP_INFTY = osqp.constant("OSQP_INFTY")


# ---------------------------------------------------------------------------
# Controller
# ---------------------------------------------------------------------------
def _restored_servo(settings: ServoMPCSettings, state: Mapping[str, Any]) -> ServoMPC:
    """A :class:`ServoMPC` set up with ``settings`` at ``state`` (copying, unpickling)."""
    servo = ServoMPC(settings, a1=state["a1"], a2=state["a2"], b1=state["b1"])
    servo.set_state(state)
    return servo


class ServoMPC:
    """MPC with servo mechanism (section 3.2) on a condensed QP (closed form / OSQP).

    Lifecycle (as osqp): the constructor builds the QP for the initial model
    and calls OSQP ``setup`` once; :meth:`update_model` replaces ``(a1, a2,
    b1)`` (AMPC, Fig. 6); :meth:`solve` once per sample.  A solve returns the
    exact closed-form optimum when it satisfies Eq. (19) and calls OSQP
    otherwise (module docstring, "Solution strategy").

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
        self._nz = 4 + hp + 1  # z = [l, l_prev, uc_prev, xs, r(k..k+Hp)]
        self._nres = 2 * hp + hu  # residual rows of Eq. (15)
        Q, Qs, R = settings.weights()
        self._u_min, self._u_max = settings.u_min_v, settings.u_max_v
        self._shortcut = not settings.always_osqp
        self._S = np.tril(np.ones((hu, hu)))       # u_c(k+i) = uc_prev + (S D)_i (Eq. (20))
        self._ones_hu = np.ones(hu)
        self._zeros_hu = np.zeros(hu)
        self._zeros_hu.setflags(write=False)       # shared zero dual warm start
        self._zeros_list = [0.0] * hu

        self._qp = CondensedServoQP(hp, hu, Q, Qs, R)
        self._B = self._qp.B  # updated in place by the QP's set_model

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
        try:
            with np.errstate(over="ignore", invalid="ignore"):  # an overflow is the error below, not a warning
                self._set_model(self._a1, self._a2, self._b1)
            if not np.all(np.isfinite(self._qp.gram)):
                raise ValueError("its matrices overflow")
            # OSQP's factorisation needs P positive definite in floating point; a model whose
            # predictions dwarf the move weight R loses R to rounding (OSQP would print "non-convex")
            eig = np.linalg.eigvalsh(self._qp.matrices()[0])
            if not eig[0] > _PD_RTOL * eig[-1]:
                raise ValueError(f"its Hessian is not numerically positive definite (eigenvalues {eig[0]:.3g} .. {eig[-1]:.3g})")
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
        except (np.linalg.LinAlgError, osqp.OSQPException, ValueError) as exc:
            # a model whose predictions over Hp samples overflow the QP's numbers (a far-off or unstable
            # initial model): named, rather than the solver's bare error code
            raise ValueError(f"the servo QP (Eq. (15)-(20)) cannot be set up for the initial model a1 = {self._a1!r}, "
                             f"a2 = {self._a2!r}, b1 = {self._b1!r} over Hp = {hp} samples ({type(exc).__name__}: {exc}); "
                             f"is the model (theta0) far off the rig's?") from None
        # Model held by OSQP.  None: push before the first OSQP solve, so that
        # every model OSQP solves with went through _push_model (not setup).
        self._osqp_model: tuple[float, float, float] | None = None
        self._x_ws = np.zeros(hu)
        self._y_ws = self._zeros_hu
        self._rho_dirty = False
        self._osqp_solves = 0

    # -- model -----------------------------------------------------------
    @property
    def model(self) -> tuple[float, float, float]:
        """Current predictor ``(a1, a2, b1)`` of Eq. (2)."""
        return (self._a1, self._a2, self._b1)

    @property
    def osqp_solves(self) -> int:
        """How many solves so far called OSQP (diagnostic; not part of :meth:`get_state`)."""
        return self._osqp_solves

    def update_model(self, a1: float, a2: float, b1: float) -> None:
        """Replace the predictor of Eq. (2)/(17) (adaptive MPC, section 3.3).

        Recomputes the small dense QP matrices in numpy; OSQP receives them
        (``update(Px=..., Ax=...)``, same sparsity pattern) only when a later
        solve needs OSQP.  Nothing is done if ``(a1, a2, b1)`` is unchanged.
        The next solve equals that of a freshly built controller with these
        parameters and the same warm start.  Raises ``ValueError`` for
        non-finite values or ``|b1| < 1e-9``; the old model is kept then.
        """
        new = self._check_model(a1, a2, b1)
        if new == (self._a1, self._a2, self._b1):
            return
        self._set_model(*new)
        self._a1, self._a2, self._b1 = new

    def update_model_unchecked(self, a1: float, a2: float, b1: float) -> None:
        """:meth:`update_model` without the finiteness checks (fast path): ``a1, a2, b1`` are python
        floats known to be finite (the controller's RLS output); ``|b1|`` is still checked."""
        if a1 == self._a1 and a2 == self._a2 and b1 == self._b1:
            return
        if not abs(b1) >= _B1_MIN:
            self._check_model(a1, a2, b1)  # raises the documented ValueError
        self._set_model(a1, a2, b1)
        self._a1, self._a2, self._b1 = a1, a2, b1

    @staticmethod
    def _check_model(a1: float, a2: float, b1: float) -> tuple[float, float, float]:
        a1 = real_number(a1, what="a1")
        a2 = real_number(a2, what="a2")
        b1 = real_number(b1, what="b1")
        if abs(b1) < _B1_MIN:
            raise ValueError(f"b1 must satisfy |b1| >= {_B1_MIN:g}, got {b1!r}")
        return a1, a2, b1

    def _set_model(self, a1: float, a2: float, b1: float) -> None:
        """The condensed QP for ``(a1, a2, b1)`` (numpy only; OSQP gets it in :meth:`_push_model`)."""
        self._qp.set_model(a1, a2, b1)
        self._K_unc = self._qp.K_unc

    @property
    def _Gall(self) -> np.ndarray:
        """Weighted residual rows of ``B``, move columns (OSQP path and :meth:`cost` only)."""
        return self._qp.G_weighted

    @property
    def _W(self) -> np.ndarray:
        """Weighted residual rows of ``B``, data columns."""
        return self._qp.W_weighted

    def _qp_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """``(P, K)`` of the condensed QP for the current model (cached)."""
        return self._qp.matrices()

    def _Px(self) -> np.ndarray:
        return self._qp.matrices()[0][self._p_rows, self._p_cols]

    def _push_model(self) -> None:
        # OSQP recomputes its Ruiz scaling from (P, A, q) on a matrix update
        # after un-scaling the old data.  Zeroing q first and rewriting A with
        # its exact values makes that scaling depend on the model only, so a
        # solve never depends on the history of updates.  (osqp's update()
        # applies q before the matrices.)
        self._prob.update(q=self._zeros_hu, Px=self._Px(), Ax=self._Ax)
        self._osqp_model = (self._a1, self._a2, self._b1)
        # the warm start is kept in unscaled coordinates and re-applied at solve

    # -- helpers ---------------------------------------------------------
    def _data(self, l_mm, l_prev_mm, uc_prev_v, xs, r_future_mm, offset_v) -> tuple[np.ndarray, float, float]:
        """Validated data: ``v = [D slot (Hu, uninitialised); z]``, ``uc_prev``, ``offset``."""
        h = self._hu
        v = np.empty(h + self._nz)
        v[h] = real_number(l_mm, what="l_mm")
        v[h + 1] = real_number(l_prev_mm, what="l_prev_mm")
        v[h + 2] = uc_prev = real_number(uc_prev_v, what="uc_prev_v")
        v[h + 3] = real_number(xs, what="xs")
        offset = real_number(offset_v, what="offset_v")
        try:
            r = np.asarray(r_future_mm, dtype=float)  # no copy for a float array (the caller's case)
        except (TypeError, ValueError):
            raise ValueError(f"r_future_mm must be a sequence of numbers, got {r_future_mm!r}") from None
        if r.shape != (self._hp + 1,):
            raise ValueError(
                f"r_future_mm must hold r(k), ..., r(k+Hp): length Hp+1 = {self._hp + 1}, got shape {r.shape}")
        # a finite sum implies finite terms; the elementwise test only if it is not
        if not math.isfinite(sum(r.tolist())) and not np.isfinite(r).all():
            raise ValueError(f"r_future_mm must be finite, got {r.tolist()}")
        v[h + 4:] = r
        return v, uc_prev, offset

    def _cost(self, D: np.ndarray, wz: np.ndarray) -> float:
        # Eq. (15) from the residuals (no cancellation of large constants)
        res = wz + self._Gall.dot(D)  # sqrt-weighted residual
        return float(res.dot(res))

    def _project(self, D: np.ndarray, uc_prev: float, offset: float) -> tuple[np.ndarray, np.ndarray, bool]:
        """Clip the plan so ``u_c(k+i) - offset`` obeys Eq. (19); return moves, inputs, changed."""
        plan = _cumsum(D)
        plan += uc_prev
        lo, hi = self._u_min + offset, self._u_max + offset
        pl = plan.tolist()
        if min(pl) >= lo and max(pl) <= hi:
            return D, plan, False  # keep the exact moves
        clipped = np.minimum(np.maximum(plan, lo), hi)
        moves = clipped.copy()     # = np.diff(clipped, prepend=uc_prev)
        moves[1:] -= clipped[:-1]
        moves[0] -= uc_prev
        return moves, clipped, True

    def _at_bound(self, plan: np.ndarray, offset: float) -> bool:
        return bool(plan.min() - offset <= self._u_min + _ACTIVE_TOL_V
                    or plan.max() - offset >= self._u_max - _ACTIVE_TOL_V)

    def _result(self, v, out, plan, offset, status, iters, constrained, t0) -> ServoMPCResult:
        """Result for the moves ``v[:Hu]`` (data ``v[Hu:]``), ``out = B v`` and the input plan.

        ``plan`` None: the plan rows of ``out``; else the (clipped/refined) plan that was
        checked against Eq. (19).
        """
        hp, nres = self._hp, self._nres
        res = out[:nres]
        cost = float(res.dot(res))
        for a in (v, out) if plan is None else (v, out, plan):
            a.flags.writeable = False  # views taken below inherit read-only
        if plan is None:
            plan = out[nres + 2 * hp:]
        # (positional: the dataclass __init__ is measurably slower with keywords)
        return ServoMPCResult(float(plan[0]), v[:self._hu], plan, out[nres:nres + hp], out[nres + hp:nres + 2 * hp],
                              cost, offset, status, int(iters), bool(constrained),
                              time.perf_counter() - t0)

    def _refine(self, D, plan, y, z, wz, q, lower, upper, offset) -> tuple[np.ndarray, np.ndarray]:
        """Exact minimiser on OSQP's active set (what OSQP's polishing does).

        ADMM stops at ~eps accuracy; next to a bound with a large multiplier
        that shows in the cost.  Guess the active rows as OSQP's polish does
        (``z - l < -y`` lower, ``u - z < y`` upper), solve the equality-
        constrained QP ``[P A_a^T; A_a 0] [D; nu] = [-q; b_a]`` and keep it only
        if it is feasible and not costlier: a wrong guess cannot do harm.
        """
        hu = self._hu
        uc_prev = float(z[2])
        lo, hi = self._u_min + offset, self._u_max + offset
        # small vectors: plain floats are cheaper than numpy here
        cum = _cumsum(D).tolist()  # S D, the constrained quantity
        low_b, up_b, yl = lower.tolist(), upper.tolist(), y.tolist()
        act, b_act = [], []
        for i in range(hu):
            if cum[i] - low_b[i] < -yl[i]:
                act.append(i)
                b_act.append(low_b[i])
            elif up_b[i] - cum[i] < yl[i]:
                act.append(i)
                b_act.append(up_b[i])
        if not act:
            cand = self._K_unc.dot(z)  # = -P^{-1} q, as unconstrained_solution
            cand_plan = _cumsum(cand)
            cand_plan += uc_prev
            cp = cand_plan.tolist()
            if min(cp) >= lo and max(cp) <= hi:
                return cand, cand_plan  # feasible global minimiser: optimal, no comparison needed
        else:
            n = hu + len(act)
            kkt = np.zeros((n, n))
            kkt[:hu, :hu] = self._qp_matrices()[0]
            S_act = self._S[act]
            kkt[hu:, :hu] = S_act
            kkt[:hu, hu:] = S_act.T
            rhs = np.concatenate([-q, b_act])
            _, _, sol, info = _dgesv(kkt, rhs)  # LU, as np.linalg.solve
            if info != 0:  # singular
                return D, plan
            cand = sol[:hu]
            if not math.isfinite(sum(cand.tolist())):
                return D, plan
            cand_plan = _cumsum(cand)
            cand_plan += uc_prev
            cp = cand_plan.tolist()
        tol = 1e-9 * (1.0 + abs(offset) + abs(uc_prev) + self._u_max - self._u_min)
        if min(cp) < lo - tol or max(cp) > hi + tol:
            return D, plan
        cand, cand_plan, _ = self._project(cand, uc_prev, offset)
        if self._cost(cand, wz) <= self._cost(D, wz):
            return cand, cand_plan
        return D, plan

    def _solve_osqp(self, v: np.ndarray, uc_prev: float, offset: float, t0: float) -> ServoMPCResult:
        """The constrained QP by OSQP (+ refinement / fallback), see :meth:`solve`."""
        hu = self._hu
        z = v[hu:]
        if self._osqp_model != (self._a1, self._a2, self._b1):
            self._push_model()
        wz = self._W.dot(z)
        q = self._qp_matrices()[1].dot(z)
        # Eq. (19) on u_c(k+i) = uc_prev + (S D)_i
        lo = self._u_min + offset - uc_prev
        hi = self._u_max + offset - uc_prev
        if not max(abs(lo), abs(hi), float(np.abs(q).max())) < _OSQP_INFTY:
            return self._fallback(v, None, uc_prev, offset, "data beyond OSQP's range", 0, t0)
        lower = lo * self._ones_hu
        upper = hi * self._ones_hu
        prob = self._prob
        prob.update(q=q, l=lower, u=upper)
        if self._rho_dirty:
            prob.update_settings(rho=_RHO0)
            self._rho_dirty = False
        if self.settings.warm_start:
            # explicit warm start from our own copies: OSQP's internal iterate
            # would carry roundoff from earlier solves or restores
            prob.warm_start(x=self._x_ws, y=self._y_ws)
        self._osqp_solves += 1
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
            self._y_ws = np.array(y, dtype=float) if y is not None and np.isfinite(y).all() else self._zeros_hu
            D, plan, _ = self._project(self._x_ws, uc_prev, offset)
            if self.settings.refine:
                D, plan = self._refine(D, plan, self._y_ws, z, wz, q, lower, upper, offset)
            v[:hu] = D
            return self._result(v, self._B.dot(v), plan, offset, status, info.iter,
                                self._at_bound(plan, offset), t0)

        return self._fallback(v, fallback, uc_prev, offset, status, info.iter, t0)

    def _fallback(self, v, fallback, uc_prev, offset, why, iters, t0) -> ServoMPCResult:
        """The unconstrained plan clipped to Eq. (19) (``fallback``, if already computed)."""
        hu = self._hu
        if fallback is None:
            fallback = self._project(self._K_unc @ v[hu:], uc_prev, offset)
        D, plan, changed = fallback
        # restart the next solve from the feasible fallback plan, not a bad iterate; a plan beyond
        # OSQP's range is no start (its iterates overflow: "problem non convex" on sane data next)
        self._x_ws = np.array(D, dtype=float) if float(np.abs(D).max()) < _OSQP_INFTY else self._zeros_hu
        self._y_ws = self._zeros_hu
        v[:hu] = D
        return self._result(v, self._B.dot(v), plan, offset, f"fallback: {why}", iters,
                            changed or self._at_bound(plan, offset), t0)

    # -- public ------------------------------------------------------------
    def cost(self, delta_uc_v: Sequence[float], *, l_mm: float, l_prev_mm: float, uc_prev_v: float,
             xs: float, r_future_mm: Sequence[float], offset_v: float = 0.0) -> float:
        """Eq. (15) for the moves ``delta_uc_v`` (length Hu) and the data of :meth:`solve`.

        ``offset_v`` does not enter Eq. (15); it is accepted (and validated)
        so that the same keyword set works for all three methods.
        """
        v, _, _ = self._data(l_mm, l_prev_mm, uc_prev_v, xs, r_future_mm, offset_v)
        D = np.asarray(delta_uc_v, dtype=float)
        if D.shape != (self._hu,):
            raise ValueError(f"delta_uc_v must have length Hu = {self._hu}, got shape {D.shape}")
        return self._cost(D, self._W @ v[self._hu:])

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
        v, uc_prev, offset = self._data(l_mm, l_prev_mm, uc_prev_v, xs, r_future_mm, offset_v)
        hu = self._hu
        D = self._K_unc @ v[hu:]
        if clip:
            D, plan, changed = self._project(D, uc_prev, offset)
            v[:hu] = D
            return self._result(v, self._B.dot(v), plan, offset, "unconstrained clipped", 0,
                                changed or self._at_bound(plan, offset), t0)
        v[:hu] = D
        out = self._B.dot(v)
        return self._result(v, out, None, offset, "unconstrained", 0,
                            self._at_bound(out[self._nres + 2 * self._hp:], offset), t0)

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
            If the closed-form unconstrained minimiser satisfies Eq. (19) it is
            the exact optimum and is returned without calling OSQP (status
            ``"solved"``, ``iterations == 0``; warm start: that plan with zero
            multipliers).  Otherwise OSQP solves the QP; its plan is refined on
            its active set (``settings.refine``) and projected onto Eq. (19)
            (changes of the order of the solver tolerance), so ``u(k)`` lies in
            ``[u_min_v, u_max_v]`` up to rounding.  If OSQP does not report
            "solved", its plan is kept only if finite, within 1e-4 V of
            Eq. (19) and not costlier than the clipped unconstrained plan;
            otherwise that clipped plan is returned with status
            ``"fallback: <osqp status>"``.  QP data beyond OSQP's infinity
            (1e30: a bound or linear term of that size, only from a diverged
            model or state) skip OSQP for the same clipped plan, status
            ``"fallback: data beyond OSQP's range"``.  Never NaN.

        Raises
        ------
        ValueError
            Non-finite argument (named in the message) or ``r_future_mm`` not of
            length ``Hp + 1``.  The controller state is unchanged then.
        """
        t0 = time.perf_counter()
        v, uc_prev, offset = self._data(l_mm, l_prev_mm, uc_prev_v, xs, r_future_mm, offset_v)
        if self._shortcut:
            hu = self._hu
            D = v[:hu]
            self._K_unc.dot(v[hu:], out=D)  # D* = -P^{-1} K z
            out = self._B.dot(v)            # cost, predictions, input plan of D*
            pl = out[-hu:].tolist()
            p_min, p_max = min(pl), max(pl)
            if p_min >= self._u_min + offset and p_max <= self._u_max + offset:
                # feasible unconstrained minimiser of a strictly convex QP: the optimum
                result = self._result(v, out, None, offset, "solved", 0,
                                      p_min - offset <= self._u_min + _ACTIVE_TOL_V
                                      or p_max - offset >= self._u_max - _ACTIVE_TOL_V, t0)
                self._x_ws = result.delta_uc_v  # read-only; the KKT multipliers are 0
                self._y_ws = self._zeros_hu
                return result
        return self._solve_osqp(v, uc_prev, offset, t0)

    def solve_unchecked(self, l_mm: float, l_prev_mm: float, uc_prev_v: float, xs: float,
                    r_future: list[float], offset_v: float) -> tuple[float, float, bool]:
        """:meth:`solve` for the controller's hot path: ``(uc_v, l_hat(k+1|k), constrained)``.

        Arguments are python floats (``r_future`` a list of ``Hp + 1`` of them),
        the measured ones already checked finite.  The same computation as
        :meth:`solve`, bit for bit, without building a :class:`ServoMPCResult`
        when the closed-form minimiser is feasible (the common case); when a bound
        of Eq. (19) binds, the OSQP path of :meth:`solve` runs on the same data,
        and if a derived argument is not finite, :meth:`solve` itself (which raises).
        """
        if self._shortcut and math.isfinite(uc_prev_v + xs + offset_v) and len(r_future) == self._hp + 1:
            hu = self._hu
            v = np.array(self._zeros_list + [l_mm, l_prev_mm, uc_prev_v, xs] + r_future)
            D = v[:hu]
            self._K_unc.dot(v[hu:], out=D)  # D* = -P^{-1} K z
            out = self._B.dot(v)            # predictions, input plan of D*
            pl = out[-hu:].tolist()
            p_min, p_max = min(pl), max(pl)
            if p_min >= self._u_min + offset_v and p_max <= self._u_max + offset_v:
                self._x_ws = D  # the KKT multipliers are 0
                self._y_ws = self._zeros_hu
                return pl[0], float(out[self._nres]), (p_min - offset_v <= self._u_min + _ACTIVE_TOL_V
                                                       or p_max - offset_v >= self._u_max - _ACTIVE_TOL_V)
            res = self._solve_osqp(v, uc_prev_v, offset_v, time.perf_counter())
            return res.uc_v, float(res.predicted_l_mm[0]), res.constrained
        res = self.solve(l_mm=l_mm, l_prev_mm=l_prev_mm, uc_prev_v=uc_prev_v, xs=xs,
                         r_future_mm=np.array(r_future), offset_v=offset_v)
        return res.uc_v, float(res.predicted_l_mm[0]), res.constrained

    def __reduce__(self) -> tuple[Any, ...]:
        # the OSQP solver can be neither pickled nor shared by two copies: set up anew, then the state
        return (_restored_servo, (self.settings, self.get_state()))

    # -- state -----------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Plain-dict snapshot (python floats and lists) for FMU state save/rewind.

        Holds the model ``(a1, a2, b1)`` and the warm-start primal/dual vectors;
        after :meth:`set_state` the next :meth:`solve` results are
        bit-identical (except ``solve_time_s``).
        """
        return {
            "a1": self._a1, "a2": self._a2, "b1": self._b1,
            "x_warm": self._x_ws.tolist(),
            "y_warm": self._y_ws.tolist(),
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
