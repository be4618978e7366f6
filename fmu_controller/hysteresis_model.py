"""Linear + (asymmetric) Bouc-Wen muscle model of Eq. (1) in regression form.

Units: displacement ``l`` in mm, valve voltage ``u`` in V, one sample = ``Ts``
(0.1 s in the paper).

Regression form (section 2.3)
-----------------------------
The one-step model is ``l(k) = phi(k-1)^T theta`` with the 15-vector

==  ===========================  ===========
 #  phi(k-1) entry               theta entry
==  ===========================  ===========
 0  l(k-1)                       a1
 1  l(k-2)                       a2
 2  u(k-1)                       b1
 3  dl(k-1)                      A1
 4  dl(k-2)                      A2
 5  |dl(k-1)| v(k-2)             beta1
 6  |dl(k-2)| v(k-3)             beta2
 7  dl(k-1) |v(k-2)|             gamma1
 8  dl(k-2) |v(k-3)|             gamma2
 9  v(k-2)                       c1
10  v(k-3)                       c2
11  l^2(k-1)                     xi21
12  l^2(k-2)                     xi22
13  l^3(k-1)                     xi31
14  l^3(k-2)                     xi32
==  ===========================  ===========

with ``dl(k) = l(k) - l(k-1)``.  The standard Bouc-Wen model ("conventional
model" of Table 3) is Eq. (1) without ``g(l)``: the first 11 entries.

Virtual hysteresis variable
---------------------------
``v(k)`` is the paper's ``y_hy(k)``.  It cannot be measured, so section 2.3
defines it as the residual of the linear part, evaluated with the *current*
parameter estimate::

    v(k) = l(k) - [a1 l(k-1) + a2 l(k-2) + b1 u(k-1)]

Index subtlety: under Eq. (1) taken literally, ``l(k) - linear part`` equals
``y_hy(k-1) + y_hy(k-2)``, not ``y_hy(k)``.  The regression therefore does not
reproduce Eq. (1) exactly; its ``v`` is the paper's virtual variable
(an approximation, ref. [16] of the paper).  This module follows section 2.3,
so within the model ``v(k) = H(k-1)`` (see :func:`hysteresis_term`).

Sign convention
---------------
``theta`` holds *regression coefficients*.  Eq. (1)'s minus signs on
``beta_i`` and ``gamma_i`` are absorbed: ``theta["beta1"]`` multiplies
``+|dl(k-1)| v(k-2)``, i.e. ``theta["beta1"] = -beta_1`` of Eq. (1).
(Table 3's values give a bounded response only when read this way.)

Identifiability
---------------
``phi[3] = phi[0] - phi[1]`` identically, so for given regressors ``a1``,
``a2`` and ``A1`` enter the one-step prediction only as ``a1 + A1`` and
``a2 - A1``: the direction ``n = -e_a1 + e_a2 + e_A1`` (:func:`null_direction`)
is invisible to the regression.  The regressors themselves move along it a
little (the Bouc-Wen state ``v`` is the linear part's residual, computed with
``a1, a2, b1``), so the data pin the split only weakly (docs/identification.md,
"Identifiability").  The constraint box of Algorithm 1 (Table 2) and the RLS
prior ``(theta(0), P(-1))`` pin it.  :func:`identifiable_combinations` reports the
identifiable quantities.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Mapping, Sequence

import numpy as np

from .argument_checks import number_array

__all__ = [
    "PARAMETER_NAMES_ASYMMETRIC",
    "PARAMETER_NAMES_STANDARD",
    "LINEAR_NAMES",
    "THETA_UNITS",
    "ModelStructure",
    "ASYMMETRIC",
    "STANDARD",
    "regressor",
    "regressor_terms",
    "linear_residual",
    "virtual_hysteresis",
    "virtual_hysteresis_sequence",
    "hysteresis_term",
    "null_direction",
    "identifiable_combinations",
    "ModelState",
]

PARAMETER_NAMES_ASYMMETRIC: tuple[str, ...] = (
    "a1", "a2", "b1",
    "A1", "A2",
    "beta1", "beta2",
    "gamma1", "gamma2",
    "c1", "c2",
    "xi21", "xi22", "xi31", "xi32",
)
PARAMETER_NAMES_STANDARD: tuple[str, ...] = PARAMETER_NAMES_ASYMMETRIC[:11]
#: Parameters of the linear part of Eq. (1) / the linearised plant Eq. (2).
LINEAR_NAMES: tuple[str, ...] = ("a1", "a2", "b1")
#: Each parameter's unit, from its regressor (module docstring) with ``l``, ``dl`` and ``v`` in mm and
#: ``u`` in V: ``theta_i phi_i`` is a displacement [mm]. "1" is dimensionless.
THETA_UNITS: dict[str, str] = {
    "a1": "1", "a2": "1", "b1": "mm/V", "A1": "1", "A2": "1",
    "beta1": "1/mm", "beta2": "1/mm", "gamma1": "1/mm", "gamma2": "1/mm", "c1": "1", "c2": "1",
    "xi21": "1/mm", "xi22": "1/mm", "xi31": "1/mm^2", "xi32": "1/mm^2",
}


@dataclass(frozen=True, kw_only=True)
class ModelStructure:
    """Which variant of Eq. (1) is used.

    Parameters
    ----------
    kind : {"asymmetric", "standard"}
        ``"asymmetric"``: Eq. (1) with the cubic ``g(l)`` (15 parameters,
        "proposed model" of Table 3).  ``"standard"``: Eq. (1) without
        ``g(l)`` (11 parameters, "conventional model").

    Attributes
    ----------
    names : tuple of str
        Parameter names in regressor order (see module docstring).
    n_params : int
        ``len(names)``.
    """

    kind: Literal["asymmetric", "standard"] = "asymmetric"
    names: tuple[str, ...] = field(init=False)
    n_params: int = field(init=False)

    def __post_init__(self) -> None:
        if self.kind == "asymmetric":
            names = PARAMETER_NAMES_ASYMMETRIC
        elif self.kind == "standard":
            names = PARAMETER_NAMES_STANDARD
        else:
            raise ValueError(
                f"kind must be 'asymmetric' or 'standard', got {self.kind!r}"
            )
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "n_params", len(names))

    @property
    def asymmetric(self) -> bool:
        """True if the polynomial ``g(l)`` of Eq. (1) is included."""
        return self.kind == "asymmetric"

    def index(self, name: str) -> int:
        """Position of parameter ``name`` in ``theta``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(
                f"unknown parameter name {name!r} for {self.kind} model; "
                f"expected one of {self.names}"
            ) from None

    def to_dict(self, theta: Sequence[float] | np.ndarray) -> dict[str, float]:
        """Map a parameter vector to ``{name: value}``."""
        values = _as_theta(theta, self)
        return {n: float(x) for n, x in zip(self.names, values)}

    def from_dict(
        self, params: Mapping[str, float], *, default: float = 0.0
    ) -> np.ndarray:
        """Build ``theta`` from ``{name: value}``; missing names get ``default``.

        Values are regression coefficients (see module docstring for signs).
        """
        return self.as_theta(params, what="params", default=default)

    def as_theta(self, values: Mapping[str, float] | Sequence[float] | np.ndarray, *, what: str = "theta",
                 default: float | None = None) -> np.ndarray:
        """A parameter vector from either form a caller holds: ``{name: value}`` (as
        ``IdentificationReport.theta_dict``) or the values in :attr:`names` order (as ``.theta``).

        Parameters
        ----------
        values : mapping or sequence of float
            The parameters by name, or all ``n_params`` of them in order.
        what : str
            The argument's name, for the error messages.
        default : float, optional
            Value of the names a mapping leaves out; None: a mapping must name every parameter.

        Raises
        ------
        TypeError
            ``values`` is neither a mapping nor a sequence of numbers (a string, ``None``, ...).
        ValueError
            An unknown or missing name, a sequence of another length, or a value that is not finite.
        """
        if isinstance(values, Mapping):
            unknown = [n for n in values if n not in self.names]
            if unknown:
                raise ValueError(f"{what}: unknown parameter {unknown[0]!r} for the {self.kind} model; "
                                 f"expected names from {', '.join(self.names)}")
            missing = [n for n in self.names if n not in values]
            if missing and default is None:
                raise ValueError(f"{what} names {len(values)} of the {self.n_params} parameters; missing: "
                                 f"{', '.join(missing)} (or give all {self.n_params} values in order)")
            try:
                theta = np.array([values.get(n, default) for n in self.names], dtype=float)
            except (TypeError, ValueError):
                bad = next(n for n in values if not _is_number(values[n]))
                raise ValueError(f"{what}[{bad!r}] = {values[bad]!r} is not a number") from None
        else:
            if isinstance(getattr(values, "theta", None), Mapping):  # a model object that holds theta
                raise TypeError(f"{what} must be a mapping name -> value or {self.n_params} values, got "
                                f"{type(values).__name__} (pass its .theta)")
            theta = number_array(values, what=what, expected=f"a mapping name -> value or {self.n_params} values "
                                                               f"in the order {', '.join(self.names)}")
            if theta.shape != (self.n_params,):
                raise ValueError(f"{what} must be {self.n_params} values ({', '.join(self.names)}) for the "
                                 f"{self.kind} model, got shape {theta.shape}")
        bad_i = np.nonzero(~np.isfinite(theta))[0]
        if bad_i.size:
            i = int(bad_i[0])
            raise ValueError(f"{what}: {self.names[i]} = {float(theta[i])!r} is not finite")
        return theta


#: Eq. (1) with ``g(l)``: the paper's proposed model (15 parameters).
ASYMMETRIC = ModelStructure(kind="asymmetric")
#: Eq. (1) without ``g(l)``: the conventional standard Bouc-Wen model (11).
STANDARD = ModelStructure(kind="standard")


def _is_number(value: object) -> bool:
    try:
        float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return True


def _as_theta(theta: Sequence[float] | np.ndarray, structure: ModelStructure) -> np.ndarray:
    arr = np.asarray(theta, dtype=float)
    if arr.shape != (structure.n_params,):
        raise ValueError(
            f"theta must have shape ({structure.n_params},) for the "
            f"{structure.kind} model, got {arr.shape}"
        )
    return arr


def regressor_terms(l0: float | np.ndarray, l1: float | np.ndarray, l2: float | np.ndarray, u0: float | np.ndarray,
                    v1: float | np.ndarray, v2: float | np.ndarray) -> list[float | np.ndarray]:
    """The 15 entries of the asymmetric model's ``phi(k)`` (section 2.3, Eq. (1)) as a list, in
    :data:`PARAMETER_NAMES_ASYMMETRIC`'s order; for floats and arrays alike (:func:`regressor` stacks
    and selects them).

    ``l0 = l(k)``, ``l1 = l(k-1)``, ``l2 = l(k-2)`` [mm], ``u0 = u(k)`` [V], ``v1 = v(k-1)``,
    ``v2 = v(k-2)`` [mm] (the virtual hysteresis variable).

    Parameters
    ----------
    l0, l1, l2 : float or ndarray
        Contraction ``l(k)``, ``l(k-1)``, ``l(k-2)`` [mm].
    u0 : float or ndarray
        Command ``u(k)`` [V].
    v1, v2 : float or ndarray
        Virtual hysteresis variable ``v(k-1)``, ``v(k-2)`` [mm].
    """
    d0 = l0 - l1
    d1 = l1 - l2
    return [
        l0, l1, u0,
        d0, d1,
        abs(d0) * v1, abs(d1) * v2,
        d0 * abs(v1), d1 * abs(v2),
        v1, v2,
        l0 * l0, l1 * l1,
        l0 * l0 * l0, l1 * l1 * l1,
    ]


def regressor(
    l0: float | np.ndarray,
    l1: float | np.ndarray,
    l2: float | np.ndarray,
    u0: float | np.ndarray,
    v1: float | np.ndarray,
    v2: float | np.ndarray,
    structure: ModelStructure = ASYMMETRIC,
) -> np.ndarray:
    """Regressor ``phi(k)`` of section 2.3, so that ``l(k+1) = phi(k)^T theta``.

    Parameters
    ----------
    l0, l1, l2 : float or ndarray
        ``l(k)``, ``l(k-1)``, ``l(k-2)`` in mm.
    u0 : float or ndarray
        ``u(k)`` in V.
    v1, v2 : float or ndarray
        Virtual hysteresis variable ``v(k-1)``, ``v(k-2)`` in mm.
    structure : ModelStructure
        Selects 15 (asymmetric) or 11 (standard) entries.

    Returns
    -------
    ndarray
        Shape ``(..., n_params)`` (inputs broadcast against each other).
    """
    terms = regressor_terms(
        *(np.asarray(x, dtype=float) for x in (l0, l1, l2, u0, v1, v2))
    )[: structure.n_params]
    return np.stack(np.broadcast_arrays(*terms), axis=-1)


def linear_residual(
    l_new: float | np.ndarray,
    l0: float | np.ndarray,
    l1: float | np.ndarray,
    u0: float | np.ndarray,
    a1: float,
    a2: float,
    b1: float,
) -> float | np.ndarray:
    """What the linear part of Eq. (1) leaves of a displacement: ``l_new - (a1 l0 + a2 l1 + b1 u0)``.

    The one expression of the virtual hysteresis variable of section 2.3 that the estimator, the
    predictors and the controllers all evaluate, so that they agree bit for bit.

    Parameters
    ----------
    l_new : float or ndarray
        The displacement the linear part is to explain, ``l(k+1)`` [mm].
    l0, l1 : float or ndarray
        ``l(k)``, ``l(k-1)`` [mm].
    u0 : float or ndarray
        ``u(k)`` [V].
    a1, a2, b1 : float
        The linear part of ``theta`` (Eq. (1)'s first three parameters).

    Returns
    -------
    float or ndarray
        ``v(k+1)`` [mm], of the inputs' broadcast shape.
    """
    return l_new - (a1 * l0 + a2 * l1 + b1 * u0)


def virtual_hysteresis(
    theta: Sequence[float] | np.ndarray,
    l0: float,
    l1: float,
    l2: float,
    u1: float,
) -> float:
    """Virtual hysteresis variable of section 2.3 (paper's ``y_hy(k)``).

    ``v(k) = l(k) - [a1 l(k-1) + a2 l(k-2) + b1 u(k-1)]``, the residual of the
    linear part of Eq. (1), evaluated with the (current) estimate ``theta``.

    Parameters
    ----------
    theta : array_like
        Parameter vector; only ``a1, a2, b1`` (entries 0..2) are used.
    l0, l1, l2 : float
        ``l(k)``, ``l(k-1)``, ``l(k-2)`` in mm.
    u1 : float
        ``u(k-1)`` in V.

    Returns
    -------
    float
        ``v(k)`` in mm.
    """
    return float(linear_residual(l0, l1, l2, u1, theta[0], theta[1], theta[2]))


def virtual_hysteresis_sequence(
    theta: Sequence[float] | np.ndarray, l: np.ndarray, u: np.ndarray
) -> np.ndarray:
    """``v(k)`` of :func:`virtual_hysteresis` for a whole record, fixed ``theta``.

    Parameters
    ----------
    theta : array_like
        Parameter vector (entries 0..2 used).
    l : ndarray, shape (N,)
        Displacement in mm.
    u : ndarray, shape (N,)
        Valve voltage in V.

    Returns
    -------
    ndarray, shape (N,)
        ``v[k]`` for ``k >= 2``; ``v[0] = v[1] = 0`` because ``l(-1)``,
        ``l(-2)`` do not exist.
    """
    l = np.asarray(l, dtype=float)
    u = np.asarray(u, dtype=float)
    v = np.zeros_like(l)
    v[2:] = linear_residual(l[2:], l[1:-1], l[:-2], u[1:-1], theta[0], theta[1], theta[2])
    return v


def null_direction(structure: ModelStructure = ASYMMETRIC) -> np.ndarray:
    """Unit-free direction ``n`` with ``phi^T n = 0`` for every regressor.

    ``n = -e_a1 + e_a2 + e_A1`` because ``phi[3] = phi[0] - phi[1]``
    (``dl(k-1) = l(k-1) - l(k-2)``).  Moving ``theta`` along ``n`` does not
    change the one-step regression, so data alone cannot fix it.

    Parameters
    ----------
    structure : ModelStructure, optional
        Model variant (its parameter names and their number); default the asymmetric model.
    """
    n = np.zeros(structure.n_params)
    n[structure.index("a1")] = -1.0
    n[structure.index("a2")] = 1.0
    n[structure.index("A1")] = 1.0
    return n


def identifiable_combinations(
    theta: Sequence[float] | np.ndarray, structure: ModelStructure = ASYMMETRIC
) -> dict[str, float]:
    """Parameter combinations the regression can determine from ``l`` alone.

    Returns ``{"a1+A1": ..., "a2-A1": ..., "b1": ..., "A2": ..., ...}``: the
    two combinations that replace ``a1, a2, A1`` followed by all remaining
    parameters in regressor order.  Together they are invariant along
    :func:`null_direction`.

    Parameters
    ----------
    theta : sequence of float or ndarray
        Parameters of Eq. (1), in ``structure``'s order.
    structure : ModelStructure, optional
        Model variant; default the asymmetric model.
    """
    p = structure.to_dict(theta)
    out = {"a1+A1": p["a1"] + p["A1"], "a2-A1": p["a2"] - p["A1"]}
    for name in structure.names:
        if name not in ("a1", "a2", "A1"):
            out[name] = p[name]
    return out


def hysteresis_term(theta: Sequence[float] | np.ndarray, state: "ModelState") -> float:
    """Predicted hysteresis contribution ``H(k)`` to ``l(k+1)``.

    ``H(k) = theta_h^T phi_h(k)``, where ``phi_h(k)`` is ``phi(k)`` without
    the linear entries ``l(k), l(k-1), u(k)`` (entries 4..15, 1-based) and
    ``theta_h`` the matching ``A, beta, gamma, c, xi``.  It uses only data
    available at time ``k`` (``l(k), l(k-1), l(k-2), v(k-1), v(k-2)``), so it
    can be evaluated before ``u(k)`` is chosen.

    ``H(k)`` is the paper's ``y_hy(k) + y_hy(k-1)`` of the hysteresis
    cancellation input, Eq. (3) / Eq. (5)::

        u(k) = u_c(k) - H(k) / b1

    which makes the model's ``l(k+1) = a1 l(k) + a2 l(k-1) + b1 u_c(k)``,
    the linearised plant of Eq. (2).

    Parameters
    ----------
    theta : array_like, shape (n_params,)
        Regression coefficients.
    state : ModelState
        History *after* :meth:`ModelState.observe` of ``l(k)``.

    Returns
    -------
    float
        ``H(k)`` in mm.
    """
    t = theta.tolist() if isinstance(theta, np.ndarray) else list(theta)
    if len(t) != state.structure.n_params:
        raise ValueError(
            f"theta must have length {state.structure.n_params}, got {len(t)}"
        )
    return float(state.hysteresis_unchecked(t))


def _finite_triplet(name: str, values: Sequence[float]) -> tuple[float, float, float]:
    vals = tuple(float(x) for x in values)
    if len(vals) != 3:
        raise ValueError(f"{name} must have 3 entries (oldest first), got {len(vals)}")
    if not all(math.isfinite(x) for x in vals):
        raise ValueError(f"{name} must be finite, got {vals}")
    return vals  # type: ignore[return-value]


class ModelState:
    """Step-by-step history for the regressor of Eq. (1) (section 2.3).

    Holds ``l(k), l(k-1), l(k-2)``, ``v(k), v(k-1), v(k-2)`` and ``u(k)``
    as Python floats: that is all ``phi(k)`` and the next ``v(k+1)`` need,
    and plain floats keep a step in the microsecond range.

    Lifecycle per sample ``k`` (adaptive controller)::

        phi = state.phi()                  # phi(k-1), needs u(k-1) applied
        theta = rls.update(phi, l_k)       # Eq. (4) / Algorithm 1
        state.observe(l_k, theta)          # pushes l(k), v(k) with theta(k)
        H = hysteresis_term(theta, state)  # H(k) for Eq. (5)
        state.apply(u_k)                   # u(k) actually sent to the valve

    Offline, :meth:`update` does ``observe`` then ``apply``.

    Parameters
    ----------
    structure : ModelStructure
        Model variant.
    l_init : sequence of 3 float
        ``(l(k-2), l(k-1), l(k))`` in mm, oldest first.
    v_init : sequence of 3 float, optional
        ``(v(k-2), v(k-1), v(k))`` in mm, oldest first.  Default zeros
        (the virtual variable is unknown before data exist).
    u_init : float, optional
        ``u(k)`` in V if already known; otherwise call :meth:`apply` before
        :meth:`phi`.
    """

    __slots__ = ("structure", "_n", "_l0", "_l1", "_l2", "_v0", "_v1", "_v2", "_u", "_has_u")

    def __init__(
        self,
        structure: ModelStructure = ASYMMETRIC,
        *,
        l_init: Sequence[float],
        v_init: Sequence[float] = (0.0, 0.0, 0.0),
        u_init: float | None = None,
    ) -> None:
        if not isinstance(structure, ModelStructure):
            raise ValueError(f"structure must be a ModelStructure, got {structure!r}")
        self.structure = structure
        self._n = structure.n_params
        self._l2, self._l1, self._l0 = _finite_triplet("l_init", l_init)
        self._v2, self._v1, self._v0 = _finite_triplet("v_init", v_init)
        self._u = 0.0
        self._has_u = False
        if u_init is not None:
            self.apply(u_init)

    # -- lifecycle -------------------------------------------------------
    def observe(self, l: float, theta: Sequence[float] | np.ndarray) -> float:
        """Push the new measurement ``l(k+1)`` and compute ``v(k+1)``.

        ``v(k+1) = l(k+1) - [a1 l(k) + a2 l(k-1) + b1 u(k)]`` with ``theta``
        the current estimate (section 2.3).  Requires ``u(k)`` applied.

        Returns
        -------
        float
            The new ``v(k+1)`` in mm.
        """
        l = float(l)
        if not math.isfinite(l):
            raise ValueError(f"l must be finite, got {l}")
        return self.observe_unchecked(l, float(theta[0]), float(theta[1]), float(theta[2]))

    def apply(self, u: float) -> None:
        """Record the input ``u(k)`` in V applied after the latest ``l(k)``."""
        u = float(u)
        if not math.isfinite(u):
            raise ValueError(f"u must be finite, got {u}")
        self._u = u
        self._has_u = True

    def update(self, l: float, u: float, theta: Sequence[float] | np.ndarray) -> float:
        """``observe(l, theta)`` then ``apply(u)``; returns the new ``v``."""
        v = self.observe(l, theta)
        self.apply(u)
        return v

    def observe_unchecked(self, l: float, a1: float, a2: float, b1: float) -> float:
        """:meth:`observe` without its checks (the controller's per-sample fast path): ``l`` a finite
        python float and ``a1, a2, b1`` the linear part of ``theta``; same arithmetic, bit for bit."""
        if not self._has_u:
            raise RuntimeError("apply(u) must be called before observe(l)")
        v = linear_residual(l, self._l0, self._l1, self._u, a1, a2, b1)
        if not math.isfinite(v):
            raise ValueError(f"theta gives a non-finite v: {v}")
        self._l2, self._l1, self._l0 = self._l1, self._l0, l
        self._v2, self._v1, self._v0 = self._v1, self._v0, v
        self._has_u = False
        return v

    def hysteresis_unchecked(self, t: list[float]) -> float:
        """:func:`hysteresis_term` without its checks (fast path): ``t`` is ``theta`` as a list of
        ``n_params`` python floats; same arithmetic, bit for bit."""
        l0, l1, l2 = self._l0, self._l1, self._l2
        v1, v2 = self._v1, self._v2
        d0 = l0 - l1
        d1 = l1 - l2
        h = (
            t[3] * d0 + t[4] * d1
            + t[5] * abs(d0) * v1 + t[6] * abs(d1) * v2
            + t[7] * d0 * abs(v1) + t[8] * d1 * abs(v2)
            + t[9] * v1 + t[10] * v2
        )
        if self._n == 15:  # asymmetric: g(l)
            h += t[11] * l0 * l0 + t[12] * l1 * l1 + t[13] * l0 ** 3 + t[14] * l1 ** 3
        return h

    @property
    def last_l(self) -> float:
        """``l(k)`` [mm], the latest displacement observed (the initial one before any)."""
        return self._l0

    @property
    def history(self) -> tuple[float, float, float, float, float, float]:
        """``(l(k-2), l(k-1), l(k), v(k-2), v(k-1), v(k))`` [mm]: the displacements and virtual
        hysteresis outputs the state holds (the controller's one-sample-ahead evaluation saves
        and restores them with :meth:`restore_history`)."""
        return self._l2, self._l1, self._l0, self._v2, self._v1, self._v0

    def restore_history(self, history: tuple[float, float, float, float, float, float]) -> None:
        """Put back a :attr:`history` taken earlier (the input ``u`` is not part of it)."""
        self._l2, self._l1, self._l0, self._v2, self._v1, self._v0 = history

    @property
    def l_prev_mm(self) -> float:
        """``l(k-1)`` [mm]: the displacement before the last one observed."""
        return self._l1

    def phi_list(self) -> list[float]:
        """:meth:`phi` as a list of python floats (fast path: no array is built)."""
        if not self._has_u:
            raise RuntimeError("apply(u) must be called before phi()")
        terms = regressor_terms(self._l0, self._l1, self._l2, self._u, self._v1, self._v2)
        return terms if self._n == 15 else terms[:self._n]

    # -- queries ---------------------------------------------------------
    def phi(self) -> np.ndarray:
        """Current regressor ``phi(k)`` (``l(k+1) = phi(k)^T theta``)."""
        if not self._has_u:
            raise RuntimeError("apply(u) must be called before phi()")
        terms = regressor_terms(
            self._l0, self._l1, self._l2, self._u, self._v1, self._v2
        )
        return np.array(terms[: self.structure.n_params])

    @property
    def l(self) -> tuple[float, float, float]:
        """``(l(k-2), l(k-1), l(k))`` in mm, oldest first."""
        return (self._l2, self._l1, self._l0)

    @property
    def v(self) -> tuple[float, float, float]:
        """``(v(k-2), v(k-1), v(k))`` in mm, oldest first."""
        return (self._v2, self._v1, self._v0)

    @property
    def u(self) -> float | None:
        """``u(k)`` in V, or None if not applied yet."""
        return self._u if self._has_u else None

    def get_state(self) -> dict:
        """Plain-dict snapshot (for FMU state save/rewind)."""
        return {
            "l": self.l,
            "v": self.v,
            "u": self.u,
        }

    def set_state(self, state: Mapping) -> None:
        """Restore a snapshot from :meth:`get_state` (bit-identical)."""
        l2, l1, l0 = _finite_triplet("state['l']", state["l"])
        v2, v1, v0 = _finite_triplet("state['v']", state["v"])
        u = state["u"]
        if u is not None and not math.isfinite(float(u)):
            raise ValueError(f"state['u'] must be finite or None, got {u}")
        self._l2, self._l1, self._l0 = l2, l1, l0
        self._v2, self._v1, self._v0 = v2, v1, v0
        self._has_u = u is not None
        self._u = float(u) if u is not None else 0.0
