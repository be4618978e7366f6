"""Recursive least squares, Eq. (4), with the box projection of Algorithm 1.

The estimator is generic in the regressor but is set up with a
:class:`~fmu_controller.hysteresis_model.ModelStructure` so that constraint
boxes can be given by parameter name (Table 2 bounds ``a1, a2, b1``).

Units follow the data: with ``l`` in mm and ``u`` in V, ``b1`` is in mm/V and
the Table 2 box applies as is.  If the data are rescaled, rescale the box too
(see :func:`fmu_controller.prediction.theta_scale_factors`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Literal, Mapping, Sequence

import numpy as np

from .box_projection import BoxProjector, project_onto_box
from .hysteresis_model import ModelStructure
from .read_only_fields import read_only, settings_hash, settings_reduce

__all__ = [
    "Regressors",
    "TABLE2_LOWER",
    "TABLE2_UPPER",
    "RLSSettings",
    "ConstrainedRLS",
    "project_onto_box",
    "CEILING_CLIP",
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



@dataclass(frozen=True)
class Regressors:
    """The named entries of a regressor vector that is not Eq. (1)'s (an estimator beside the paper's
    model, e.g. :class:`~fmu_controller.delay_predictor.DelayPredictor`), for :class:`ConstrainedRLS`.

    Parameters
    ----------
    names : tuple of str
        One name per regressor entry, in order.
    """

    names: tuple[str, ...]

    def __post_init__(self) -> None:
        if not self.names or len(set(self.names)) != len(self.names) \
                or not all(isinstance(n, str) and n for n in self.names):
            raise ValueError(f"Regressors.names must be distinct non-empty strings, got {self.names!r}")

    @property
    def kind(self) -> str:
        return "regressor"

    @property
    def n_params(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Position of entry ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown regressor {name!r}; expected one of {self.names}") from None


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
        return read_only(out)
    return _freeze_vector(name, value, allow_inf=True)


#: Where ``covariance_ceiling`` puts the eigenvalues of ``P(-1)^-1/2 P P(-1)^-1/2`` that crossed 1: a
#: little below the ceiling, so that the clip is needed about once per ``ln(1/0.9)/ln(1/lambda)`` samples.
CEILING_CLIP = 0.9


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
        What to do if ``P`` loses positive definiteness (non-finite entry,
        a diagonal <= 0, or a block Algorithm 1's projection must invert that
        is singular in floating point: forgetting without the ceiling winds
        ``P`` up so far) or ``theta`` becomes non-finite after an update:
        ``"reset"`` discards that update, keeps ``theta(k-1)`` and resets
        ``P`` to ``P(-1)``; ``"raise"`` raises ``FloatingPointError``. Either
        way numpy's error handling in the caller (``np.seterr``) plays no part:
        the update computes with IEEE arithmetic (an overflow to inf).
    covariance_ceiling : bool
        Keep ``P(k) <= P(-1)`` (in the matrix order): the estimator never
        becomes more uncertain than it was at the start. With forgetting
        (``lambda < 1``), ``P`` grows as ``lambda^-k`` in every direction the
        regressor does not excite (covariance wind-up, Astrom and Wittenmark,
        *Adaptive Control*, section 11.2); the ceiling stops that growth at
        ``P(-1)`` and leaves the excited directions, where forgetting keeps
        ``P`` small but non-zero, untouched: when an update leaves ``P`` above
        ``P(-1)`` in some direction, the eigenvalues of ``P(-1)^-1/2 P P(-1)^-1/2``
        above :data:`CEILING_CLIP` are set to it. Default False
        (the paper's Eq. (4) has no ceiling and no forgetting).
    """

    p0: float | Sequence[float] = 1e3
    theta0: Sequence[float] | None = None
    forgetting: float = 1.0
    box_lower: BoundSpec = field(default_factory=lambda: dict(TABLE2_LOWER))
    box_upper: BoundSpec = field(default_factory=lambda: dict(TABLE2_UPPER))
    constraint_start_s: float = 120.0
    ts_s: float = 0.1
    on_covariance_loss: Literal["reset", "raise"] = "reset"
    covariance_ceiling: bool = False

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
        if not isinstance(self.covariance_ceiling, bool):
            raise ValueError(f"covariance_ceiling must be True or False, got {self.covariance_ceiling!r}")
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
        return settings_hash(self)

    def __reduce__(self) -> tuple[Any, ...]:
        return settings_reduce(self)

    @property
    def constraint_start_index(self) -> float:
        """First sample index ``k`` (``t = k Ts >= constraint_start_s``) with projection.

        ``inf`` if the constraint never starts.
        """
        if math.isinf(self.constraint_start_s):
            return math.inf
        # tolerate float noise like 120 / 0.1 = 1200.0000000000002
        return float(math.ceil(self.constraint_start_s / self.ts_s - 1e-9))

    def resolve(self, structure: ModelStructure | Regressors) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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
                    table2 = (" (RLSSettings' default box is Table 2's on a1, a2, b1: for a model without them pass "
                              "box_lower={}, box_upper={})" if dict(bound) in (TABLE2_LOWER, TABLE2_UPPER) else "")
                    raise ValueError(f"{name} names unknown parameter {key!r} for the {structure.kind} model "
                                     f"(its parameters: {', '.join(structure.names)}){table2}")
                arr[structure.index(key)] = x
            return arr
        if len(bound) != n:
            raise ValueError(f"{name} has {len(bound)} entries, expected {n}")
        return np.array(bound)


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
    structure : ModelStructure or Regressors, optional
        Model variant (names for the box, dimension), or the names of another regressor.
    settings : RLSSettings, optional
        Defaults to ``RLSSettings()`` (paper values).
    k0 : int
        Sample index of the measurement preceding the first update
        (Algorithm 1 Step 1: ``k = 0``); sets the clock for
        ``constraint_start_s``.
    """

    def __init__(
        self,
        structure: ModelStructure | Regressors | None = None,
        settings: RLSSettings | None = None,
        *,
        k0: int = 0,
    ) -> None:
        self._ready = False
        if structure is not None:
            self.setup(structure, settings, k0=k0)

    def setup(
        self,
        structure: ModelStructure | Regressors,
        settings: RLSSettings | None = None,
        *,
        k0: int = 0,
    ) -> None:
        """(Re)initialise: ``theta = theta(0)``, ``P = P(-1)``, step ``k = k0``."""
        if not isinstance(structure, (ModelStructure, Regressors)):
            raise ValueError(f"structure must be a ModelStructure or Regressors, got {structure!r}")
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
        self._projector = BoxProjector(lower, upper)
        self._boxed = self._projector.c.size > 0
        self._phi_shape = (self._n,)
        self._ones_nn = np.ones(self._n * self._n)
        self._lam = settings.forgetting
        # covariance_ceiling: P(-1)'s diagonal scales the eigenvalue clip
        self._ceiling = settings.covariance_ceiling
        self._p0_sqrt = np.sqrt(self._P0.diagonal())
        self._eye = np.eye(self._n)
        self._n_ceilings = 0
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
        """Current covariance ``P(k-1)`` (copy): after the update of the latest sample ``k``, the one the
        next update's gain takes (Eq. (4); Algorithm 1 names the start ``P(-1)``, Tables 5 and 8 ``P(0)``)."""
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
        self._check_ready()
        return self._lower.copy()

    @property
    def upper(self) -> np.ndarray:
        """Upper bounds of ``C`` (copy; +inf = unbounded)."""
        self._check_ready()
        return self._upper.copy()

    @property
    def n_projections(self) -> int:
        """Number of updates where the projection changed ``theta``."""
        self._check_ready()
        return self._n_projections

    @property
    def n_resets(self) -> int:
        """Number of covariance resets (``on_covariance_loss="reset"``)."""
        self._check_ready()
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
            Measurement ``y(k)`` the regressors explain (Eq. (1): ``l(k)``, in the data's unit, mm on
            the rig).

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
        # it overflows (IEEE: to inf, whatever np.seterr says); only then pay for the element-wise test
        with np.errstate(over="ignore"):
            squares = _dot(phi, phi)
        if not math.isfinite(squares) and not np.isfinite(phi).all():
            raise ValueError(f"phi must be finite, got non-finite entries at {np.flatnonzero(~np.isfinite(phi)).tolist()}")
        y = float(y)
        if not math.isfinite(y):
            raise ValueError(f"y must be finite, got {y}")
        return self.update_unchecked(phi, y).copy()

    def update_unchecked(self, phi: np.ndarray, y: float) -> np.ndarray:
        """:meth:`update` without its checks (the controller's per-sample fast path): ``phi`` a
        finite float array of shape ``(n_params,)``, ``y`` a finite float.  Returns the estimator's own ``theta(k)``
        array (not a copy; the estimator never modifies it in place).

        This runs every sample, so it is written for few numpy calls on the
        tiny arrays (their per-call overhead dominates): scalar checks where
        they are exact, and the rank-1 covariance update in place.

        It computes with IEEE arithmetic whatever numpy's error handling in the calling thread (a
        notebook's ``np.seterr(all="raise")``, a host's): an overflow is the covariance loss handled
        below (``on_covariance_loss``), neither a numpy exception nor a warning.
        """
        with np.errstate(over="ignore", invalid="ignore"):
            return self._update(phi, y)

    def _update(self, phi: np.ndarray, y: float) -> np.ndarray:
        """:meth:`update_unchecked`'s arithmetic."""
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
            return self._covariance_lost(f"min diag {P_new.diagonal().min()!r}")
        ceilings = self._n_ceilings  # an update dropped below is not counted as clipped either
        if self._ceiling and lam != 1.0:  # a valid P only; with lambda = 1, P only shrinks from P(-1)
            P_new = self._limit(P_new)

        if self._boxed and self._k + 1 >= self._start and not self._projector.inside(th):
            # the active set usually persists from sample to sample: try the one the
            # previous estimate sits on first (a function of theta(k-1), so of the state)
            try:
                theta = self._projector.project(theta, P_new, th, self._projector.hint_from(self._theta))
            except np.linalg.LinAlgError:
                self._n_ceilings = ceilings
                return self._covariance_lost("the projection's block of P is singular")
            self._n_projections += 1
        self._k += 1
        self._theta = theta
        self._P = P_new
        return theta

    def _covariance_lost(self, why: str) -> np.ndarray:
        """``on_covariance_loss`` for the update at step ``k + 1``: raise, or drop it and restart ``P``
        from ``P(-1)`` (the documented rule), keeping ``theta(k-1)``."""
        if self.settings.on_covariance_loss == "raise":
            raise FloatingPointError(f"RLS covariance lost positive definiteness at step k={self._k + 1} "
                                     f"({why}); rescale the data or reduce p0")
        self._k += 1
        self._P = self._P0.copy()
        self._n_resets += 1
        return self._theta

    def _limit(self, P: np.ndarray) -> np.ndarray:
        """``P`` kept at or below ``P(-1)`` (``covariance_ceiling``), exactly symmetric.

        ``S = P(-1)^-1/2 P P(-1)^-1/2 <= I`` is tested by a Cholesky factorisation of ``I - S``
        (it succeeds only if ``I - S`` is positive definite). If it fails, the eigenvalues of ``S``
        above :data:`CEILING_CLIP` are set to it: the idle directions then take
        ``ln(1/CEILING_CLIP) / ln(1/lambda)`` samples (105 at ``lambda`` = 0.999) to reach the
        ceiling again, so the eigendecomposition runs about once per hundred samples, not at each.
        """
        s = self._p0_sqrt
        S = P / s[:, None] / s[None, :]
        try:
            np.linalg.cholesky(self._eye - S)
            return P
        except np.linalg.LinAlgError:
            pass
        w, V = np.linalg.eigh(S)
        np.minimum(w, CEILING_CLIP, out=w)
        S = (V * w) @ V.T
        P = S * s[:, None] * s[None, :]
        self._n_ceilings += 1
        return 0.5 * (P + P.T)

    @property
    def n_ceilings(self) -> int:
        """Number of updates where ``covariance_ceiling`` clipped ``P``."""
        return self._n_ceilings

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
            "n_ceilings": self._n_ceilings,
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
        self._n_ceilings = int(state.get("n_ceilings", 0))

    def _check_ready(self) -> None:
        if not self._ready:
            raise RuntimeError("ConstrainedRLS.setup(structure, settings) has not been called")
