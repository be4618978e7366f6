"""Calibration before accusation: re-estimate the nominal plant constants that a recording can identify.

Every real rig's constants differ from the simulator's by 10-20 %: the valves' flow coefficient,
the bladder's stiffness, the braid angle, the friction levels. Such errors leave a structured
residual that a search for left-out physics would otherwise blame on some effect (an encoder
drift, a supply sag). So the diagnosis first fits the nominal constants, and judges the candidate
effects against the calibrated plant.

Method
------
* **Parameters.** :data:`NOMINAL_PARAMETERS`: the rig's physical constants (not its operating
  conditions, load and supply pressure, whose mismatch are effects of the vocabulary). Each is
  fitted in the scaled coordinate ``x = (theta - theta_nominal) / (prior_rel * theta_nominal)``.
* **Estimate.** Maximum a posteriori with a Gaussian prior of ``prior_rel`` (20 %) relative
  standard deviation around the nominal value: least squares of the training residual (held-out
  blocks are never used) stacked with ``sigma * x`` (:func:`fit_parameters`, scipy's trust-region
  reflective ``least_squares`` within the fields' bounds). The prior is what keeps the directions
  the data cannot see (two constants that trade off exactly) at their nominal values, so the fit
  is well posed with all constants free.
* **Jacobian.** Forward differences (one simulation per parameter) at the start, then Broyden's
  rank-one secant updates from the points the solver accepts, with a fresh forward-difference
  Jacobian every :data:`FRESH_JACOBIAN_EVERY` iterations (simulations are the whole cost).
* **Identifiability** from the Fisher information at the estimate, ``F = J'J / sigma^2`` in the
  scaled coordinates at the recording's white-noise level ``sigma``, and the posterior covariance
  ``C = (F + I)^-1`` (``I`` is the prior's information). A constant is *identifiable* when the data
  shrink its standard deviation to at most :data:`IDENTIFIABLE_SD_SHRINK` of the prior's
  (20 % -> 5 %): its marginal posterior then owes little to the prior, whether the constant is
  insensitive or trades off with another (both give a large marginal variance). This is a property
  of the experiment (what a correct model could tell from these data), so a left-out effect still
  in the residual does not hide the constants.
* **Intervals.** The 95 % interval is ``estimate +- 1.96 sd`` from the data-only covariance
  ``(J'J / sigma_eff^2)^-1`` of the identifiable constants, with ``sigma_eff`` the final residual's
  standard deviation inflated for its autocorrelation (AR(1) variance factor
  ``(1 + rho_1) / (1 - rho_1)``), so that a structured residual does not pretend to more
  information than it holds; a constant left at nominal gets its prior's interval. The constants
  left at nominal are only known to their prior, and an identifiable constant that trades with one
  of them has absorbed its error: their prior variance is carried into the interval ("consider
  covariance", Tapley, Schutz and Born 2004, section 6.3): with ``J_c`` the residual's Jacobian in
  the considered constants (prior sd units), ``A = (J'J)^-1 J' J_c`` is how far the estimate moves
  per prior sd of theirs, and ``A A'`` adds to the data-only covariance. Every interval is clipped
  to the parameter's bounds (the inflated level can otherwise reach a negative flow coefficient).
* **Left alone.** A constant that is not identifiable is put back to its nominal value, listed as
  such, and the identifiable ones are polished once more without it, so the calibrated plant file
  changes only what the recording pins down.

References: Brun, Reichert and Kuensch (2001), *Practical identifiability analysis of large
environmental simulation models*, Water Resour. Res. 37(4) (sensitivity-based identifiability);
Broyden (1965) secant update; Tapley, Schutz and Born (2004), *Statistical Orbit Determination*,
Elsevier, section 6.3 (consider covariance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from scipy import optimize

from fmu_plant import PlantParams
from fmu_plant.parameters import EFFECT_GROUPS

from tapmuscle.diagnosis.catalogue import Catalogue
from tapmuscle.diagnosis.reproducible import broyden_update, dot, snap, snap_relative, sse


__all__ = ["NominalParameter", "NOMINAL_PARAMETERS", "nominal_parameter", "FittedParameter", "Fit", "CalibrationRow",
           "Calibration", "fit_parameters", "calibrate", "calibration_rows", "nominal_coords",
           "effective_sigma", "fit_covariance", "fitted_intervals", "PRIOR_BOUND_SDS", "AT_BOUND_SDS"]

#: The solver keeps a nominal constant within this many prior sds of its nominal value (80 % of it at a
#: 20 % prior). A constant at this bound stands in for an effect the model lacks (a valve band taken up
#: by a per-MPa friction at a fifth of its value); 3 sds, which would leave more of such an effect in the
#: residual, was measured on the field suite and not kept (docs/diagnosis.md, method step 4).
PRIOR_BOUND_SDS = 4.0
#: A calibrated constant within this many prior sds of a bound is reported as at it.
AT_BOUND_SDS = 0.05
#: A fresh forward-difference Jacobian every this many solver iterations (Broyden updates between).
FRESH_JACOBIAN_EVERY = 5
#: A constant is identifiable when its posterior sd is at most this fraction of its prior sd.
IDENTIFIABLE_SD_SHRINK = 0.25
#: Forward-difference step in scaled coordinates (x = 1 is one prior sd, 20 %): 1 % of the nominal value.
FD_STEP = 0.05
#: The residual of a point the model refuses, in multiples of the start residual's largest magnitude
#: (as :data:`~tapmuscle.diagnosis.fit_problem.FAILED_RESIDUAL_SCALE` for a failed simulation).
REFUSED_RESIDUAL_SCALE = 1e3


@dataclass(frozen=True)
class NominalParameter:
    """A nominal constant of the plant that calibration may re-estimate."""

    key: str
    """Plant parameter (``group.field``), as the plant FMU names it."""
    unit: str
    """Its unit (``"-"`` if it has none)."""
    prior_rel: float = 0.2
    """Prior standard deviation relative to the nominal value [-] (rigs differ by 10-20 %)."""


#: The rig's physical constants the calibration re-estimates (docs/diagnosis.md, step 4).
NOMINAL_PARAMETERS: tuple[NominalParameter, ...] = Catalogue("NOMINAL_PARAMETERS", (
    NominalParameter("valve.cv_max", "US gpm/psi^0.5"),
    NominalParameter("valve.leak_fraction", "-"),
    NominalParameter("supply.compliance_m3_per_mpa", "m^3/MPa"),
    NominalParameter("muscle.rubber_stiffness_n_per_mm", "N/mm"),
    NominalParameter("muscle.threshold_pressure_mpa", "MPa"),
    NominalParameter("muscle.braid_angle_deg", "deg"),
    NominalParameter("muscle.radius_mm", "mm"),
    NominalParameter("muscle.damping_n_s_per_mm", "N s/mm"),
    NominalParameter("friction.base_n", "N"),
    NominalParameter("friction.per_mpa_n", "N/MPa"),
    NominalParameter("friction.asymmetry", "-"),
    NominalParameter("friction.presliding_mm", "mm"),
))


def nominal_parameter(key: str) -> NominalParameter:
    """The constant ``key`` (``"group.field"``) as calibration re-estimates it: the entry of
    :data:`NOMINAL_PARAMETERS`, or for any other constant of the rig (``"load.load_n"``,
    ``"supply.supply_pressure_mpa"``) one with its unit and the same 20 % prior.

    Parameters
    ----------
    key : str
        The plant parameter, ``"group.field"``.

    Raises
    ------
    ValueError
        An unknown parameter (the group's fields listed); a parameter of an effect (an effect is a
        candidate, found by the search, not a constant); a sensor's (the diagnosis simulates the model
        without sensor noise and quantisation, so they change nothing) or the solver's (numerical
        settings, not the rig's).
    """
    for known in NOMINAL_PARAMETERS:
        if known.key == key:
            return known
    try:
        unit = PlantParams.unit(key)
    except ValueError as exc:
        raise ValueError(f"calibration: unknown nominal parameter {key!r} ({exc}); the default ones: "
                         f"{', '.join(k.key for k in NOMINAL_PARAMETERS)}") from None
    group = key.partition(".")[0]
    if group in EFFECT_GROUPS:
        raise ValueError(f"calibration: {key!r} is a parameter of an effect ({group}): effects are candidates of "
                         "the search (candidates=), not constants to recalibrate")
    if group in ("sensor", "solver"):
        raise ValueError(f"calibration: {key!r} cannot be recalibrated: "
                         + ("the diagnosis simulates the model without sensor noise and quantisation"
                            if group == "sensor" else "the solver's settings are numerical, not the rig's"))
    return NominalParameter(key, unit or "-")


@dataclass(frozen=True)
class FittedParameter:
    """One coordinate of a least-squares fit: ``theta = center + scale * x``."""

    key: str
    """Plant parameter (``group.field``)."""
    center: float
    """Value at ``x = 0``, in the parameter's unit (for a nominal constant its nominal value, the prior's
    mean)."""
    scale: float
    """Change of the value per unit of ``x``, in the parameter's unit (for a nominal constant the prior's
    sd)."""
    prior: bool
    """Gaussian prior N(center, scale^2) (a nominal constant); False: flat within the bounds (an effect)."""
    lo: float
    """Lower bound of the value, in the parameter's unit."""
    hi: float
    """Upper bound of the value, in the parameter's unit."""


@dataclass
class Fit:
    """Result of :func:`fit_parameters`."""

    values: dict[str, float]
    """The estimate: plant parameter (``group.field``) -> value."""
    x: np.ndarray
    """The estimate in the scaled coordinates."""
    jacobian: np.ndarray
    """Residual Jacobian at the estimate, in the scaled coordinates (rows: training samples) [mm]."""
    residual: np.ndarray
    """Training residual at the estimate [mm]."""
    simulations: int
    """Simulations the fit ran."""


def effective_sigma(r: np.ndarray) -> float:
    """Standard deviation of ``r`` inflated by the AR(1) variance factor of its lag-1 autocorrelation:
    the noise level that makes ``J'J / sigma^2`` honest for a residual that is not white.

    Parameters
    ----------
    r : ndarray
        A residual [mm].
    """
    r = np.asarray(r, float)
    if r.size < 3:
        return float(np.std(r)) or 1e-12
    c = r - r.mean()
    den = sse(c)
    rho = dot(c[:-1], c[1:]) / den if den > 0 else 0.0
    rho = min(max(rho, 0.0), 0.95)
    return max(float(np.sqrt(np.mean(r * r))) * math.sqrt((1 + rho) / (1 - rho)), 1e-12)


def fit_parameters(residual: Callable[[PlantParams], np.ndarray], base: PlantParams,
                   coords: Sequence[FittedParameter], sigma_mm: float, *, max_iterations: int = 40,
                   jacobian0: np.ndarray | None = None, refresh_every: int | None = FRESH_JACOBIAN_EVERY,
                   robust_scale_mm: float | None = None, restarts: int = 0,
                   residual_many: Callable[[list[PlantParams]], list[np.ndarray]] | None = None) -> Fit:
    """Least squares (MAP where a coordinate has a prior) of ``residual(params)`` over ``coords``.

    Parameters
    ----------
    residual : callable
        Plant parameters -> training residual [mm] (one simulation per call). Never called with a
        point the plant refuses (``with_values`` raises ``ValueError``: an input map whose outputs
        cross); such a point gets a large finite residual (:data:`REFUSED_RESIDUAL_SCALE`), and the
        solver steps back.
    base : PlantParams
        The model the coordinates are set on; every other parameter stays as it is.
    coords : sequence of FittedParameter
        What is fitted, scaled; the solver starts from each coordinate's current value in ``base``.
    sigma_mm : float
        Noise level that weighs the prior rows ``sigma * x`` against the residual [mm].
    max_iterations : int
        Solver iterations (each one simulation, plus the Jacobian refreshes).
    jacobian0 : ndarray, optional
        Jacobian columns to start from (e.g. of an earlier fit of the leading coordinates); the
        remaining trailing columns are computed by forward differences.
    refresh_every : int or None
        A fresh forward-difference Jacobian every this many iterations; None: Broyden updates only
        (a warm start, where the first Jacobian stays good).
    robust_scale_mm : float, optional
        Soft-L1 loss with this scale [mm] instead of squares: samples where a localised effect
        (a supply sag) leaves a large residual pull the constants less.
    restarts : int
        When the solver stops on ``max_iterations`` rather than on convergence, start it again (with
        a fresh Jacobian) up to this many times.
    residual_many : callable, optional
        ``residual`` for a list of parameter sets at once (e.g. in parallel processes): used for the
        forward-difference columns, whose simulations are independent. Must return what ``residual``
        would, in order.
    """
    coords = list(coords)
    p = len(coords)
    center = np.array([c.center for c in coords])
    scale = np.array([c.scale for c in coords])
    prior = np.array([c.prior for c in coords], bool)
    lo = np.array([(c.lo - c.center) / c.scale for c in coords])
    hi = np.array([(c.hi - c.center) / c.scale for c in coords])
    # keep strictly inside the bounds so that forward differences stay valid
    span = hi - lo
    lo_in, hi_in = lo + 1e-6 * np.minimum(span, 1.0), hi - 1e-6 * np.minimum(span, 1.0)
    x0 = np.clip(np.array([(base.value(c.key) - c.center) / c.scale for c in coords]), lo_in, hi_in)
    sims = 0

    def params_at(x: np.ndarray) -> PlantParams | None:
        """The parameters at ``x``; None where the model's own checks refuse them (the bounds are per
        coordinate, and an input map's outputs may cross: the map must not decrease)."""
        try:
            return base.with_values(**{c.key: float(v) for c, v in zip(coords, center + scale * x)})
        except ValueError:
            return None

    cache: dict[bytes, np.ndarray] = {}
    refused: list[np.ndarray] = []

    def refused_residual() -> np.ndarray:
        # far worse than any prediction and finite, so that the solver steps back (the start is valid)
        if not refused:
            r0 = data_residual(x0)
            refused.append(np.full(len(r0), REFUSED_RESIDUAL_SCALE * (1.0 + float(np.max(np.abs(r0), initial=0.0)))))
        return refused[0]

    def data_residual(x: np.ndarray) -> np.ndarray:
        nonlocal sims
        key = np.asarray(x, float).tobytes()
        if key not in cache:
            point = params_at(x)
            if point is None:
                return refused_residual()
            sims += 1
            cache[key] = residual(point)
        return cache[key]

    def fun(x: np.ndarray) -> np.ndarray:
        # the solver's steps come out of the BLAS: on the grid, every CPU simulates the same points
        x = snap(x)
        return np.concatenate([data_residual(x), sigma_mm * x[prior]])

    def fd_jacobian(x: np.ndarray, start: int = 0) -> np.ndarray:
        nonlocal sims
        points, steps = [x], []
        for j in range(start, p):
            h = FD_STEP if x[j] + FD_STEP <= hi_in[j] else -FD_STEP
            xj = x.copy()
            xj[j] += h
            points.append(xj)
            steps.append(h)
        if residual_many is not None:  # the uncached points in one batch
            todo = {np.asarray(xi, float).tobytes(): xi for xi in points}
            todo = {k: params_at(xi) for k, xi in todo.items() if k not in cache}
            todo = {k: point for k, point in todo.items() if point is not None}  # refused: not simulated
            if todo:
                for key, r in zip(todo, residual_many(list(todo.values()))):
                    cache[key] = r
                sims += len(todo)
        r0 = data_residual(x)
        cols = [(data_residual(xj) - r0) / h for xj, h in zip(points[1:], steps)]
        return np.column_stack(cols) if cols else np.zeros((len(r0), 0))

    if jacobian0 is not None and jacobian0.shape[1] > p:
        raise ValueError(f"jacobian0 has {jacobian0.shape[1]} columns for {p} coordinates")

    prior_rows = np.eye(p)[prior] * sigma_mm
    state: dict[str, Any] = {"calls": 0, "x": None, "J": None}

    def jac(x: np.ndarray) -> np.ndarray:
        x = snap(x)
        calls = state["calls"]
        state["calls"] += 1
        if state["J"] is None:
            J = fd_jacobian(x, start=0 if jacobian0 is None else jacobian0.shape[1])
            if jacobian0 is not None:
                J = np.hstack([jacobian0, J])
        elif refresh_every and calls % refresh_every == 0:
            J = fd_jacobian(x)
        else:  # Broyden: the secant through the last accepted point
            J = broyden_update(state["J"], x - state["x"], data_residual(x) - data_residual(state["x"]))
        state["x"], state["J"] = x.copy(), J
        return np.vstack([J, prior_rows])

    if p:
        loss = "linear" if robust_scale_mm is None else "soft_l1"
        x = x0
        for attempt in range(restarts + 1):
            sol = optimize.least_squares(fun, x, jac=jac, bounds=(lo, hi), x_scale=1.0, method="trf",
                                         max_nfev=max_iterations, xtol=1e-6, ftol=1e-8, gtol=1e-8, loss=loss,
                                         f_scale=robust_scale_mm or 1.0)
            x = np.clip(snap(sol.x), lo_in, hi_in)
            if sol.status != 0:  # converged (0: stopped on max_nfev)
                break
            state["J"] = None  # a fresh forward-difference Jacobian for the restart
            jacobian0 = None
    else:
        x = x0
    J = state["J"] if state["J"] is not None and np.array_equal(state["x"], x) else fd_jacobian(x)
    values = {c.key: float(v) for c, v in zip(coords, center + scale * x)}
    return Fit(values, x, J, data_residual(x), sims)


@dataclass
class CalibrationRow:
    """One line of the report's ``calibration`` section."""

    parameter: str
    """Plant parameter (``group.field``)."""
    unit: str
    """Its unit."""
    nominal: float
    """Nominal value, in its unit."""
    estimate: float
    """Calibrated value, in its unit."""
    ci95: tuple[float, float]
    """95 % interval, in its unit, clipped to the parameter's bounds."""
    identifiable: bool
    """Whether the recording identifies it."""
    sd_shrink: float
    """Posterior sd / prior sd [-] (<= IDENTIFIABLE_SD_SHRINK: identifiable)."""
    at_bound: bool = False
    """The estimate sits at a bound of the fit (:data:`PRIOR_BOUND_SDS` prior sds from nominal, or the
    parameter's own bound): the data would take it further, so it may stand in for an effect the model
    lacks."""
    wider_than_prior: bool = False
    """An identifiable constant whose interval (before clipping to the bounds) is wider than its
    prior's 95 % interval: identifiable with the other constants held to their priors, but the data
    alone let it trade with them (or with the effects found), so the estimate is one of many that
    fit as well."""

    def identifiable_text(self) -> str:
        """The reports' ``identifiable`` cell."""
        if not self.identifiable:
            return "no (left nominal)"
        if self.at_bound:
            return "yes, at its bound (it may stand in for a left-out effect)"
        if self.wider_than_prior:
            return "yes with the others at their priors; alone it trades with them (interval wider than the prior's)"
        return "yes"

    def to_json(self) -> dict[str, Any]:
        return {"parameter": self.parameter, "unit": self.unit, "nominal": _round(self.nominal),
                "estimate": _round(self.estimate), "ci95": [_round(self.ci95[0]), _round(self.ci95[1])],
                "identifiable": self.identifiable, "sd_shrink": round(self.sd_shrink, 4), "at_bound": self.at_bound,
                "wider_than_prior": self.wider_than_prior}


def _round(v: float) -> float:
    return float(f"{v:.6g}")


@dataclass
class Calibration:
    """The calibrated plant and the report's ``calibration`` section."""

    params: PlantParams
    """The calibrated plant."""
    rows: list[CalibrationRow]
    """One row per constant considered."""
    simulations: int
    """Simulations the calibration ran."""
    jacobian: np.ndarray = field(repr=False)
    """Training-residual Jacobian of the identifiable constants at the estimate (scaled coordinates)."""
    sigma_mm: float = 0.0
    """Effective (autocorrelation-inflated) level of the final training residual [mm]."""
    shrink: tuple[float, ...] = ()
    """Per constant (in ``rows`` order): posterior sd / prior sd at the first fit."""
    kept: tuple[str, ...] = ()
    """Constants kept at their MAP estimate although not identifiable one by one (``combinations``)."""
    consider_jacobian: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    """Training-residual Jacobian of the constants put back to nominal (scaled coordinates, rows as
    ``jacobian``'s): their prior uncertainty enters the intervals (:func:`calibration_rows`)."""
    map_params: PlantParams | None = None
    """The MAP estimate with every constant free, before the ones not identifiable go back to nominal
    (None: the same as ``params``). At a noise level inflated by the nominal model's misfit, few
    constants pass as identifiable, and putting the others back can undo a fit that was right."""

    @property
    def identifiable(self) -> list[str]:
        return [r.parameter for r in self.rows if r.identifiable]

    @property
    def changed(self) -> dict[str, float]:
        """The calibrated constants (identifiable ones, and the ``kept``), ``group.field`` -> value."""
        return {r.parameter: r.estimate for r in self.rows if r.identifiable or r.parameter in self.kept}

    def to_json(self) -> dict[str, Any]:
        return {"method": "MAP least squares on the training blocks (prior: 20 % sd around nominal), "
                          "identifiable when the posterior sd is <= 25 % of the prior sd; the 95 % intervals "
                          "include the prior of the constants left nominal",
                "parameters": [r.to_json() for r in self.rows], "identifiable": self.identifiable,
                "not_identifiable": [r.parameter for r in self.rows if not r.identifiable],
                "simulations": self.simulations}


def nominal_coords(nominal: PlantParams, parameters: Sequence[NominalParameter] = NOMINAL_PARAMETERS,
                   bounds: Callable[[str], tuple[float, float]] = PlantParams.bounds) -> list[FittedParameter]:
    """Scaled coordinates of the nominal constants, centred on ``nominal``'s values (prior), within
    ``bounds(key)`` (default: the plant fields' bounds).

    Parameters
    ----------
    nominal : PlantParams
        The nominal model.
    parameters : sequence of NominalParameter, optional
        The constants; default :data:`NOMINAL_PARAMETERS`.
    bounds : callable, optional
        ``bounds(key) -> (lo, hi)`` of a parameter; default the plant fields' bounds.
    """
    out = []
    for np_ in parameters:
        c = nominal.value(np_.key)
        scale = np_.prior_rel * abs(c) if c != 0 else np_.prior_rel
        lo, hi = bounds(np_.key)
        out.append(FittedParameter(np_.key, c, scale, True, max(lo, c - PRIOR_BOUND_SDS * scale),
                                   min(hi, c + PRIOR_BOUND_SDS * scale)))
    return out


def _posterior(J: np.ndarray, sigma: float, prior: np.ndarray) -> np.ndarray:
    """Posterior covariance in scaled coordinates: ``(J'J / sigma^2 + diag(prior))^-1``."""
    info = J.T @ J / sigma ** 2 + np.diag(prior.astype(float))
    return np.linalg.pinv(info)


def calibrate(residual: Callable[[PlantParams], np.ndarray], nominal: PlantParams, base: PlantParams,
              sigma_mm: float, *, parameters: Sequence[NominalParameter] = NOMINAL_PARAMETERS,
              max_iterations: int = 40, robust: bool = True,
              residual_many: Callable[[list[PlantParams]], list[np.ndarray]] | None = None,
              bounds: Callable[[str], tuple[float, float]] = PlantParams.bounds, combinations: bool = False) -> Calibration:
    """Re-estimate the nominal constants that a recording can identify (module docstring).

    Parameters
    ----------
    residual : callable
        Plant parameters -> training residual [mm] (one simulation per call).
    nominal : PlantParams
        The nominal model: the prior's centre, and what a constant the data cannot pin returns to.
    base : PlantParams
        Where the fit starts (usually ``nominal``).
    sigma_mm : float
        White-noise level of the recording [mm] (weighs the prior; sets identifiability).
    parameters : sequence of NominalParameter
        The constants to re-estimate.
    max_iterations : int
        Solver iterations of the first fit.
    robust : bool
        Soft-L1 loss at 3 sigma (a localised effect, such as a supply sag, then bends the constants
        less); the intervals are those of the plain least-squares problem at the estimate.
    residual_many : callable, optional
        ``residual`` for a list of parameter sets at once (:func:`fit_parameters`).
    bounds : callable
        ``bounds(key) -> (lo, hi)`` of a constant (default: the plant fields' bounds; another model
        family, such as a foreign FMU, gives its own).
    combinations : bool
        Keep every constant at its MAP estimate, identifiable or not: for a model whose constants
        the data pin only in combinations (a DC motor's ``R, K, J, b`` from its speed alone), where
        putting back the ones that are not identifiable one by one would undo the calibration. The
        prior holds the directions the data cannot see; the rows still say which constants are
        identifiable, and their intervals include the prior.

    Returns
    -------
    Calibration
        The calibrated plant (identifiable constants at their estimates, the others nominal) and one
        report row per constant.
    """
    coords = nominal_coords(nominal, parameters, bounds)
    scale = 3.0 * sigma_mm if robust else None
    first = fit_parameters(residual, base, coords, sigma_mm, max_iterations=max_iterations,
                           robust_scale_mm=scale, restarts=2, residual_many=residual_many)
    sims = first.simulations
    # identifiability is a property of the experiment at the recording's noise level (what a correct
    # model could tell from it), not of the remaining misfit, which may still hold a left-out effect
    cov = _posterior(first.jacobian, sigma_mm, np.ones(len(coords), bool))
    # rounded to GRID_BITS bits: the factorisation's last bits (the BLAS's) must not move a constant across
    # the threshold on one CPU and not on another
    shrink = np.array([snap_relative(v) for v in np.sqrt(np.clip(np.diag(cov), 0.0, None))])
    ident = shrink <= IDENTIFIABLE_SD_SHRINK
    fit = first
    params = base.with_values(**first.values)
    if combinations:
        keys = [c.key for c in coords]
        rows = calibration_rows(parameters, nominal, params, [c.key for c, ok in zip(coords, ident) if ok],
                                fit.jacobian, fit.residual, sigma_mm, shrink, bounds, fitted=keys)
        return Calibration(params, rows, sims, fit.jacobian, effective_sigma(fit.residual),
                           tuple(float(v) for v in shrink), kept=tuple(keys))
    if not ident.all():
        # put back what the data cannot pin, and polish the rest without it
        params = params.with_values(**{c.key: c.center for c, ok in zip(coords, ident) if not ok})
        kept = [c for c, ok in zip(coords, ident) if ok]
        fit = fit_parameters(residual, params, kept, sigma_mm, max_iterations=8, refresh_every=None,
                             robust_scale_mm=scale, jacobian0=first.jacobian[:, ident], residual_many=residual_many)
        sims += fit.simulations
        params = params.with_values(**fit.values)
    consider = first.jacobian[:, ~ident]
    rows = calibration_rows(parameters, nominal, params, [c.key for c, ok in zip(coords, ident) if ok],
                            fit.jacobian, fit.residual, sigma_mm, shrink, bounds, consider=consider)
    return Calibration(params, rows, sims, fit.jacobian[:, :int(ident.sum())], effective_sigma(fit.residual),
                       tuple(float(v) for v in shrink), consider_jacobian=consider,
                       map_params=None if ident.all() else base.with_values(**first.values))


def fit_covariance(jacobian: np.ndarray, residual: np.ndarray, sigma_mm: float, prior_columns: int = 0,
                   consider: np.ndarray | None = None) -> np.ndarray:
    """Covariance of a fit's scaled coordinates (module docstring, "Intervals").

    ``(J'J / sigma_eff^2 + P)^-1`` with ``sigma_eff`` the residual's autocorrelation-inflated level
    (at least ``sigma_mm``) and ``P`` the prior's information (one per scaled unit) on the leading
    ``prior_columns`` columns, plus the consider term ``A A'`` of the constants left nominal
    (``consider``: the residual's Jacobian in them, same rows as ``jacobian``, prior sd units).

    Parameters
    ----------
    jacobian : ndarray
        The residual's Jacobian at the estimate, in scaled coordinates [mm].
    residual : ndarray
        The residual at the estimate [mm].
    sigma_mm : float
        The smallest noise level taken [mm].
    prior_columns : int, optional
        Leading columns with a prior (one per scaled unit); default 0.
    consider : ndarray, optional
        The residual's Jacobian in the constants left nominal (same rows, prior sd units).
    """
    sig = max(effective_sigma(residual), sigma_mm)
    info = jacobian.T @ jacobian / sig ** 2
    info = info + np.diag([1.0] * prior_columns + [0.0] * (info.shape[0] - prior_columns))
    cov = np.linalg.pinv(info)
    if consider is not None and consider.size:  # same rows as ``jacobian``: the same training residual
        a = cov @ (jacobian.T @ consider) / sig ** 2
        cov = cov + a @ a.T
    return cov


def fitted_intervals(coords: Sequence[FittedParameter], values: dict[str, float], cov: np.ndarray,
                     bounds: Callable[[str], tuple[float, float]] = PlantParams.bounds) -> dict[str, tuple[float, float]]:
    """95 % intervals ``value +- 1.96 sd`` [the parameters' units] of the fitted ``coords`` (the
    columns of ``cov``, :func:`fit_covariance`, in order), clipped to each parameter's ``bounds``.

    Parameters
    ----------
    coords : sequence of FittedParameter
        The fitted coordinates, in ``cov``'s column order.
    values : dict of str to float
        Their estimates by key.
    cov : ndarray
        Covariance of the scaled coordinates (:func:`fit_covariance`).
    bounds : callable, optional
        ``bounds(key) -> (lo, hi)`` of a parameter; default the plant fields' bounds.
    """
    out = {}
    for j, c in enumerate(coords):
        half = 1.96 * math.sqrt(max(float(cov[j, j]), 0.0)) * c.scale
        lo, hi = bounds(c.key)
        v = values[c.key]
        out[c.key] = (max(lo, v - half), min(hi, v + half))
    return out


def calibration_rows(parameters: Sequence[NominalParameter], nominal: PlantParams, params: PlantParams,
                     identifiable: Sequence[str], jacobian: np.ndarray, residual: np.ndarray, sigma_mm: float,
                     sd_shrink: Sequence[float],
                     bounds: Callable[[str], tuple[float, float]] = PlantParams.bounds,
                     fitted: Sequence[str] | None = None, consider: np.ndarray | None = None) -> list[CalibrationRow]:
    """The report rows of a calibrated plant ``params``.

    ``jacobian``'s leading columns are the ``fitted`` constants (default: the ``identifiable``
    ones) in scaled coordinates (further columns, e.g. jointly fitted effect parameters, enter the
    covariance); the 95 % interval of an identifiable constant is data-only with the
    autocorrelation-inflated residual level, widened by ``consider``, the residual's Jacobian in the
    constants left nominal (same rows, scaled coordinates: one unit is one prior sd), whose prior
    variance the estimate inherits through ``A = (J'J)^-1 J' consider`` (covariance ``A A'``, module
    docstring). A constant left nominal gets its prior's interval. Every interval is clipped to the
    parameter's ``bounds``. When constants that are not
    identifiable are fitted too (``calibrate(combinations=True)``), the intervals of all fitted ones
    include the prior (the data alone leave some directions free).

    Parameters
    ----------
    parameters : sequence of NominalParameter
        The constants considered, in row order.
    nominal : PlantParams
        The nominal model (the priors' centres).
    params : PlantParams
        The calibrated plant.
    identifiable : sequence of str
        The constants the recording identifies.
    jacobian : ndarray
        The training residual's Jacobian at the estimate (scaled coordinates) [mm].
    residual : ndarray
        The training residual at the estimate [mm].
    sigma_mm : float
        The smallest noise level the covariance takes [mm].
    sd_shrink : sequence of float
        Posterior sd / prior sd of each constant of ``parameters`` [-].
    bounds : callable, optional
        ``bounds(key) -> (lo, hi)`` of a parameter; default the plant fields' bounds.
    fitted : sequence of str, optional
        The constants of ``jacobian``'s leading columns; default ``identifiable``.
    consider : ndarray, optional
        The residual's Jacobian in the constants left nominal (same rows, prior sd units).
    """
    coords = {c.key: c for c in nominal_coords(nominal, parameters, bounds)}
    fitted = list(identifiable if fitted is None else fitted)
    k = len(fitted)
    cov = None
    if jacobian.size and k:
        cov = fit_covariance(jacobian, residual, sigma_mm, k if set(fitted) != set(identifiable) else 0,
                             consider)[:k, :k]
    rows = []
    for p_, s in zip(parameters, sd_shrink):
        c = coords[p_.key]
        est = params.value(c.key)
        if c.key in fitted and cov is not None:
            j = fitted.index(c.key)
            half = 1.96 * math.sqrt(max(cov[j, j], 0.0)) * c.scale
        else:
            half = 1.96 * c.scale
        # within the parameter's own bounds: a structured residual's inflated level can widen an
        # interval past values the constant cannot take (a negative flow coefficient)
        lo, hi = bounds(c.key)
        # the solver keeps a point strictly inside the bounds (forward differences), and a joint re-fit
        # may stop just short of one: within a twentieth of a prior sd counts as at it
        at_bound = c.key in identifiable and min(est - c.lo, c.hi - est) <= AT_BOUND_SDS * c.scale
        rows.append(CalibrationRow(c.key, p_.unit, c.center, est, (max(lo, est - half), min(hi, est + half)),
                                   c.key in identifiable, float(s), at_bound,
                                   c.key in identifiable and half > 1.96 * c.scale))
    return rows
