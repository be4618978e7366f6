"""Settings and result of the MPC with servo mechanism (section 3.2, Table 5), and Eq. (18).

:class:`ServoMPCSettings` are the horizons, the weights of Eq. (15), the input range of Eq. (19)
and the solver options, validated at construction (errors name the field); :class:`ServoMPCResult`
is one solve of :class:`~fmu_controller.servo_mpc.ServoMPC`; :func:`integrator_step` is the
discrete integrator of Eq. (18).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from .argument_checks import real_number, whole_number

#: Longest prediction horizon accepted [samples] (Table 5: 5; 5 s at Ts = 0.1 s); the controller FMU
#: declares the same range for servo.Hp, servo.Hu and ucp.Hp.
MAX_HORIZON = 50
#: Largest weight Q, Qs or R of Eq. (15) (Table 5: 2-15), six decades above Table 5's scale: their
#: ratios set the law, and far beyond it the QP is ill-conditioned (an R of 1e300 holds the command at
#: 0 V, a Qs of 1e300 fails the QP's set-up). The controller FMU declares the same range.
MAX_WEIGHT = 1e6
#: OSQP iterations per solve by default (``ServoMPCSettings.max_iter``) and at most (the controller FMU's
#: ``servo.max_iter`` range): far more than a warm-started Table 5 QP takes; the bound of a step's
#: worst-case compute time at long horizons (docs/control.md, "In a real-time loop").
DEFAULT_OSQP_ITER = 4000
MAX_OSQP_ITER = 100_000

__all__ = ["MAX_HORIZON", "MAX_WEIGHT", "DEFAULT_OSQP_ITER", "MAX_OSQP_ITER", "TABLE5_SERVO", "ServoMPCSettings",
           "ServoMPCResult", "integrator_step", "positive_int"]

#: Table 5, "MPC/AMPC with servo mechanism" column.
TABLE5_SERVO: Mapping[str, Any] = MappingProxyType({
    "hp": 5, "hu": 5, "q": (5.0, 5.0, 5.0, 5.0, 5.0), "qs": 2.0, "r": 15.0,
})


# ---------------------------------------------------------------------------
# Settings
# ---------------------------------------------------------------------------
def positive_int(name: str, value: Any) -> int:
    """``value`` as an int >= 1 (an int or a numpy integer), naming ``name`` otherwise.

    Parameters
    ----------
    name : str
        How the error message names the value.
    value : int or numpy integer
        The value to check.
    """
    n = whole_number(value, what=name)
    if n < 1:
        raise ValueError(f"{name} must be >= 1, got {value!r}")
    return n


def _freeze_weight(name: str, value: Any, n: int, n_name: str, *, strict: bool) -> float | tuple[float, ...]:
    """Scalar weight or per-step tuple of length ``n``; >= 0 (> 0 if ``strict``), <= :data:`MAX_WEIGHT`."""
    if np.ndim(value) == 0:
        w = real_number(value, what=name)
        if w < 0 or (strict and w == 0):
            raise ValueError(f"{name} must be {'> 0' if strict else '>= 0'}, got {value!r}")
        if w > MAX_WEIGHT:
            raise ValueError(f"{name} must be <= {MAX_WEIGHT:g}, got {value!r}")
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
    if (arr > MAX_WEIGHT).any():
        raise ValueError(f"{name} must be <= {MAX_WEIGHT:g} elementwise, got {arr.tolist()}")
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
    """Integrator weight ``Qs(i)`` [1/mm^2] (Eq. (15)'s ``Q_c(i)``), scalar or ``Hp`` values for i = 1..Hp;
    Table 5: 2."""
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
    max_iter: int = DEFAULT_OSQP_ITER
    """OSQP iteration limit per solve, 1 .. :data:`MAX_OSQP_ITER`; on hitting it the fallback rules of
    :meth:`ServoMPC.solve` apply (the last iterate where feasible and no worse than the clipped
    unconstrained plan, else that plan). It bounds a step's worst-case compute time: at Hp = Hu = 50,
    18 ms at 4000 and 3.4 ms at 400 (docs/control.md, "In a real-time loop")."""
    warm_start: bool = True
    """Warm-start OSQP from the previous solution (primal and dual)."""
    refine: bool = True
    """Refine OSQP's answer on its active set of Eq. (19) (exact KKT solve, kept only if
    feasible and not costlier); stands in for OSQP's polishing, which is off."""
    always_osqp: bool = False
    """Solve every sample with OSQP, also when the closed-form unconstrained minimiser
    satisfies Eq. (19) and is therefore already the exact optimum (module docstring,
    "Solution strategy").  A reference/diagnostic path: results agree to solver
    tolerance (to rounding with ``refine``), it is only slower."""

    def __post_init__(self) -> None:
        hp = positive_int("hp", self.hp)
        hu = positive_int("hu", self.hu)
        if hp > MAX_HORIZON:
            # the condensed QP grows as Hp^2 (tabulated once) and each solve as Hu^3: bounded so a typo
            # cannot stall an FMU's instantiation
            raise ValueError(f"hp must be <= {MAX_HORIZON} samples, got {hp}")
        if hu > hp:
            # moves after k+Hp-1 would not affect any prediction in Eq. (15)
            raise ValueError(f"hu must be <= hp = {hp}, got {self.hu!r}")
        object.__setattr__(self, "hp", hp)
        object.__setattr__(self, "hu", hu)
        object.__setattr__(self, "q", _freeze_weight("q", self.q, hp, "hp", strict=False))
        object.__setattr__(self, "qs", _freeze_weight("qs", self.qs, hp, "hp", strict=False))
        if not (np.any(self.q) or np.any(self.qs)):
            # Eq. (15) without a tracking term: the QP's optimum is never to move, the valve stays shut
            raise ValueError(f"q and qs must not both be 0: Eq. (15) would have no tracking term (q = {self.q!r}, "
                             f"qs = {self.qs!r})")
        # R > 0 keeps the QP Hessian positive definite for every model
        object.__setattr__(self, "r", _freeze_weight("r", self.r, hu, "hu", strict=True))
        u_min = real_number(self.u_min_v, what="u_min_v")
        u_max = real_number(self.u_max_v, what="u_max_v")
        if not u_min < u_max:
            raise ValueError(f"u_max_v must be > u_min_v = {u_min}, got {self.u_max_v!r}")
        object.__setattr__(self, "u_min_v", u_min)
        object.__setattr__(self, "u_max_v", u_max)
        for name in ("eps_abs", "eps_rel"):
            eps = real_number(getattr(self, name), what=name)
            if eps < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, eps)
        if self.eps_abs == 0 and self.eps_rel == 0:
            raise ValueError(f"eps_abs must be > 0 when eps_rel is 0, got {self.eps_abs!r}")
        object.__setattr__(self, "max_iter", positive_int("max_iter", self.max_iter))
        if self.max_iter > MAX_OSQP_ITER:
            raise ValueError(f"max_iter must be at most {MAX_OSQP_ITER}, got {self.max_iter!r}")
        if not isinstance(self.warm_start, (bool, np.bool_)):
            raise ValueError(f"warm_start must be a bool, got {self.warm_start!r}")
        object.__setattr__(self, "warm_start", bool(self.warm_start))
        if not isinstance(self.refine, (bool, np.bool_)):
            raise ValueError(f"refine must be a bool, got {self.refine!r}")
        object.__setattr__(self, "refine", bool(self.refine))
        if not isinstance(self.always_osqp, (bool, np.bool_)):
            raise ValueError(f"always_osqp must be a bool, got {self.always_osqp!r}")
        object.__setattr__(self, "always_osqp", bool(self.always_osqp))

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
        ``"solved"`` for an optimal plan: OSQP's status, or the exact closed-form
        optimum when no bound of Eq. (19) is violated by it (then
        ``iterations == 0``, see the module docstring); other OSQP statuses;
        ``"fallback: <osqp status>"`` when the clipped unconstrained plan was
        used; ``"unconstrained"`` / ``"unconstrained clipped"`` from
        :meth:`ServoMPC.unconstrained_solution`.
    iterations : int
        OSQP iterations (0 for the closed form, i.e. whenever OSQP was not called).
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
    """Discrete integrator Eq. (18): ``x_s(k+1) = x_s(k) + r(k) - l(k)`` [mm].

    Parameters
    ----------
    xs : float
        Integrator state ``x_s(k)`` [mm].
    r_mm : float
        Reference ``r(k)`` [mm].
    l_mm : float
        Measured contraction ``l(k)`` [mm].
    """
    return float(xs) + float(r_mm) - float(l_mm)
