"""Identify Eq. (1) on a whole record and score it like the paper's Table 4.

This is the pipeline behind ``tapmuscle identify``: validate the data, normalise units, run the
(constrained) RLS of Eq. (4) / Algorithm 1 (:func:`fmu_controller.prediction.run_rls`), convert the
estimate back to the record's units, and compute the 1-, 3-, 5-step-ahead and free-run fits.

Units and scaling
-----------------
The paper's settings (``P(-1) = 1e3 I``, Table 2's box on ``b1`` in mm/V) are tied to its units, and
the cubic term ``l^3`` of ``g(l)`` spans fifteen orders of magnitude if ``l`` is in micrometres.
So the record is normalised by powers of ten, ``l / l_scale`` and ``u / u_scale``, chosen so that
the normalised data have the paper's magnitudes (displacement of tens, command of units):
millimetres and volts are left alone (scale 1, exactly the paper's algorithm), micrometres are
divided by 1000, metres multiplied by 1000. ``P(-1)`` applies in the normalised units, so the result
does not depend on the unit the rig reports in; ``theta`` is converted back with
:func:`fmu_controller.prediction.rescale_theta`.

Constraint region
-----------------
``box="auto"`` uses Table 2 (``a1, a2, b1``) when the record is in the paper's units and sampling
period (scales 1, ``Ts = 0.1 s``): the box is an identification result of the paper's rig at that
period, meaningless at another. Otherwise no constraint, and :attr:`IdentificationReport.notes`
says so. An explicit box is given in the record's units.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from .argument_checks import sampling_period
from .box_projection import box_from_pairs
from .hysteresis_model import (ASYMMETRIC, STANDARD, ModelStructure, identifiable_combinations, regressor,
                               virtual_hysteresis_sequence)
from .prediction import (IdentificationResult, delayed_input, fit_percent, predict_ahead, rescale_theta, run_rls,
                         simulate, theta_scale_factors)
from .preliminary_model import REFINE_IN_CLOSED_LOOP
from .rls import TABLE2_LOWER, TABLE2_UPPER, RLSSettings

__all__ = ["MODELS", "FitReport", "IdentificationReport", "identify_record", "check_record", "score_model",
           "decade_scale", "units_note", "cancellation_swing", "PAPER_TS_S", "MIN_SAMPLES", "SHORT_TS_S", "CANCELLATION_SWING_V"]

#: Model variants by name (Eq. (1) with and without ``g(l)``).
MODELS: dict[str, ModelStructure] = {"asymmetric": ASYMMETRIC, "standard": STANDARD}

#: Sampling period of the paper's identification [s] (section 2.4).
PAPER_TS_S = 0.1

#: Fewest samples accepted: ten per parameter of the asymmetric model.
MIN_SAMPLES = 150

HORIZONS = (1, 3, 5)


def decade_scale(x: np.ndarray, typical: float) -> float:
    """Power of ten that brings ``max |x|`` closest to ``typical`` on a log scale (1 when ``max |x|``
    lies within a factor ``sqrt(10) = 3.16`` of ``typical``).

    Parameters
    ----------
    x : ndarray
        The data.
    typical : float
        The magnitude ``max |x|`` should come close to, in the unit of ``x``.
    """
    peak = float(np.max(np.abs(x)))
    if peak == 0.0:
        return 1.0
    return 10.0 ** round(math.log10(peak / typical))


#: Sampling periods [s] below this are short for Eq. (1) (:func:`identify_record` notes it): a 1-kHz
#: record of the simulated rig gave a free-run fit of 69.9 % where the same record merged to 0.1 s gave
#: 81.9 %, and at 0.01 s the free run diverged (b1 = 0.005); 0.02 s is the shortest the controllers
#: were run at (docs/control.md, "A short Ts").
SHORT_TS_S = 0.02

#: The hysteresis cancellation of Eq. (5), ``H(k)/b1``, swinging by more than this over the record
#: (its standard deviation [V], in a record in V) marks a model whose hysteresis terms have taken up the
#: linear dynamics (docs/identification.md, "A model that is a poor fixed law"): half the valve's 0..10 V.
#: Open-loop identifications of the simulated rig at Ts = 0.05, 0.1 (no box) and 0.2 s under sines,
#: chirps, random levels and steps: 7.0-33 V wherever fixed MPC-servo on the model swung the valve
#: limit to limit for good (10-37 mm of Eq. (21) error), 0.6-3.05 V elsewhere.
CANCELLATION_SWING_V = 5.0


@dataclass(frozen=True)
class FitReport:
    """Fit percentages of Table 4 on one record (MATLAB ``compare``: NRMSE fit).

    ``fit = 100 (1 - ||y - yhat|| / ||y - mean(y)||)`` over the samples where the prediction exists
    (the first 4 samples are initial conditions; an h-step prediction starts at sample 3 + h). The
    free run starts from the first 4 measured samples and uses only its own outputs after that.
    """

    percent: dict[str, float]
    """Keys ``"1"``, ``"3"``, ``"5"`` (steps ahead) and ``"sim"`` (free run) [%]."""
    free_run_diverged: bool
    """The free run left ten times the data's span and was clamped (fit then meaningless)."""
    simulated_mm: np.ndarray = field(repr=False)
    """The free-run output (record units)."""


def score_model(theta: Sequence[float] | Mapping[str, float], structure: ModelStructure | str, u: np.ndarray,
                l: np.ndarray, *, input_delay_samples: int = 0) -> FitReport:
    """1-, 3-, 5-step-ahead and free-run fits of ``theta`` on ``(u, l)`` (Table 4).

    Parameters
    ----------
    theta : sequence of float or mapping
        Eq. (1)'s parameters (record units): in the order of ``structure`` (as
        ``IdentificationReport.theta``) or by name (as its ``theta_dict``).
    structure : ModelStructure or str
        :data:`~fmu_controller.hysteresis_model.ASYMMETRIC` or ``STANDARD``, or its name as
        :func:`identify_record`'s ``model`` takes it (``"asymmetric"``, ``"standard"``).
    u, l : ndarray
        Command [V] and displacement [mm] of a record, one sample per period.
    input_delay_samples : int
        The rig's transport delay ``d`` [samples] that ``theta`` was identified under: Eq. (1)'s
        input is ``u(k - d)`` (:func:`~fmu_controller.prediction.delayed_input`).

    Returns
    -------
    FitReport
        NRMSE fits [%] (MATLAB ``compare``) and the free run.
    """
    if isinstance(structure, str):
        if structure not in MODELS:
            raise ValueError(f"unknown model structure {structure!r}; expected one of {', '.join(MODELS)}")
        structure = MODELS[structure]
    elif not isinstance(structure, ModelStructure):
        raise TypeError(f"structure must be a ModelStructure (ASYMMETRIC or STANDARD) or its name, got "
                        f"{type(structure).__name__} {structure!r:.60}")
    theta = structure.as_theta(theta, what="theta")
    u, l = delayed_input(u, input_delay_samples), np.asarray(l, dtype=float)
    rng = (float(l.min()), float(l.max()))
    percent: dict[str, float] = {}
    for h in HORIZONS:
        pred = predict_ahead(theta, structure, u, l, h, output_range=rng)
        percent[str(h)] = float(fit_percent(l, pred.l_hat, start=pred.start))
    sim = simulate(theta, structure, u, l[:4], output_range=rng)
    percent["sim"] = float(fit_percent(l, sim.l_hat, start=sim.start))
    return FitReport(percent, bool(sim.diverged), sim.l_hat)


@dataclass(frozen=True)
class IdentificationReport:
    """Result of :func:`identify_record` (``tm.identify``; all in the record's units); :meth:`to_dict` for JSON."""

    model: str
    """``"asymmetric"`` or ``"standard"`` (Eq. (1) with or without ``g(l)``)."""
    structure: ModelStructure
    """The regressor layout of Eq. (1): parameter names and their order in ``theta``."""
    ts_s: float
    """Sampling period [s]."""
    n_samples: int
    """Samples in the record."""
    theta: np.ndarray
    """Final estimate, record units (``theta[structure.index(name)]``)."""
    theta_history: np.ndarray = field(repr=False)
    """Estimate at every sample, shape ``(n_samples, n_params)``, record units."""
    fit: FitReport
    """Fits on the identification record itself."""
    l_scale: float
    """Power of ten the displacement was divided by for the RLS (1 for mm; module docstring)."""
    u_scale: float
    """Power of ten the command was divided by for the RLS (1 for V)."""
    box_lower: dict[str, float]
    """Algorithm 1's constraint region C, lower bounds by parameter name (record units; empty: none)."""
    box_upper: dict[str, float]
    """Upper bounds of C."""
    constraint_start_s: float
    """Time from which the projection was applied [s] (paper: 120)."""
    n_projections: int
    """Samples at which the estimate was projected onto C."""
    n_resets: int
    """Times the covariance was reset (kept positive definite)."""
    notes: tuple[str, ...]
    """What the user should know (e.g. why no box was applied)."""
    input_delay_samples: int = 0
    """The transport delay [samples] Eq. (1) was identified under: its input is ``u(k - d)``."""

    @property
    def theta_dict(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.structure.names, self.theta)}

    @property
    def identifiable(self) -> dict[str, float]:
        """The identifiable combinations (``a1+A1``, ``a2-A1`` and the rest), see hysteresis_model."""
        return {k: float(v) for k, v in identifiable_combinations(self.theta, self.structure).items()}

    def to_dict(self) -> dict[str, Any]:
        """The report as plain data (JSON-ready; ``tapmuscle identify --json`` writes it).

        Returns
        -------
        dict
            ``model``, ``ts_s`` [s], ``n_samples``, ``theta`` (name -> value, record units),
            ``fit_percent`` (``"1"``, ``"3"``, ``"5"``, ``"sim"``: Table 4's fits [%]),
            ``free_run_diverged``, ``identifiable_combinations``, ``constraint`` (Algorithm 1's box
            ``lower``/``upper``, its finite bounds only, ``start_s`` [s], ``n_projections``), ``scaling`` (``l_scale``,
            ``u_scale``), ``input_delay_samples`` and ``notes``. The histories (``theta_history``,
            the free run) are left out.
        """
        return {
            "model": self.model, "ts_s": self.ts_s, "n_samples": self.n_samples,
            "theta": self.theta_dict, "fit_percent": dict(self.fit.percent),
            "free_run_diverged": self.fit.free_run_diverged,
            "identifiable_combinations": self.identifiable,
            # an infinite bound is no bound, which the file leaves out (its readers take a missing one so)
            "constraint": {"lower": {k: v for k, v in self.box_lower.items() if math.isfinite(v)},
                           "upper": {k: v for k, v in self.box_upper.items() if math.isfinite(v)},
                           "start_s": self.constraint_start_s, "n_projections": self.n_projections},
            "scaling": {"l_scale": self.l_scale, "u_scale": self.u_scale},
            "input_delay_samples": self.input_delay_samples,
            "notes": list(self.notes),
        }


def _diverged_note(structure: ModelStructure, u_scaled: np.ndarray, l_scaled: np.ndarray, settings: RLSSettings,
                   l_scale: float, u_scale: float, u: np.ndarray, l: np.ndarray, boxed: bool) -> str:
    """What to say of an identification whose free run diverged: the model is unstable, what a fixed
    law on it does, and (where a box held the estimate) the free run of the estimate without the box.
    ``u_scaled``, ``l_scaled`` and ``settings``: the normalised record and the RLS run it was fitted with;
    ``u``, ``l`` the record."""
    said = ("the free run diverged: Eq. (1) with these parameters fits one step ahead but runs away on its own "
            "outputs")
    if boxed:
        free = run_rls(structure, u_scaled, l_scaled, replace(settings, box_lower={}, box_upper={}))
        theta = rescale_theta(free.theta, structure, l_scale, u_scale)
        fit = score_model(theta, structure, u, l)
        said += (", held in a box C that does not hold this rig (without it, --box none or box=None, the free run "
                 + ("diverges as well" if fit.free_run_diverged else f"fits {fit.percent['sim']:.1f} %")
                 + f", with b1 = {theta[structure.names.index('b1')]:.3g} mm/V, which Eq. (5) divides by)")
    return said + (". A fixed MPC on it as theta0 holds the valve at a limit (the controllers warn of a theta0 that "
                   f"runs away): {REFINE_IN_CLOSED_LOOP}; an adaptive controller's estimate starts from it")


def check_record(u: np.ndarray, l: np.ndarray, ts_s: float) -> None:
    """Refuse a record :func:`identify_record` cannot identify Eq. (1) on, naming what is wrong: ``u``
    and ``l`` [V, mm] not 1-D of one length, a period outside the muscle's (milliseconds meant), a
    value that is not finite, too few samples, or a constant command or displacement.

    Parameters
    ----------
    u : ndarray
        Command of the record [V].
    l : ndarray
        Displacement of the record [mm].
    ts_s : float
        Sampling period [s].
    """
    if u.shape != l.shape or u.ndim != 1:
        raise ValueError(f"u and l must be 1-D arrays of equal length, got shapes {u.shape} and {l.shape}")
    sampling_period(ts_s)
    for name, x in (("u_v", u), ("l_mm", l)):
        bad = np.nonzero(~np.isfinite(x))[0]
        if bad.size:
            # samples counted from 0, as the diagnosis names them
            raise ValueError(f"column {name}, sample {int(bad[0])}: {float(x[bad[0]])!r} is not finite; data must be finite")
    if len(l) < MIN_SAMPLES:
        raise ValueError(f"too short to identify Eq. (1): {len(l)} samples, need at least {MIN_SAMPLES} (ten per "
                         "parameter of the larger model, the asymmetric one's 15)")
    if np.ptp(u) <= 1e-9 * max(1.0, float(np.max(np.abs(u)))):
        raise ValueError(f"the input u_v is constant ({float(u[0]):g}) over the whole record: it cannot excite "
                         "the model (b1 and the hysteresis terms are not identifiable)")
    if np.ptp(l) <= 1e-9 * max(1.0, float(np.max(np.abs(l)))):
        raise ValueError(f"the output l_mm is constant ({float(l[0]):g}): the record shows no motion to identify")


def cancellation_swing(theta: np.ndarray, structure: ModelStructure, u: np.ndarray, l: np.ndarray) -> float:
    """The standard deviation over a record of the hysteresis cancellation ``H(k)/b1`` of Eq. (5) that a
    controller on ``theta`` would add to its command (in the record's units of ``u``): ``H(k)`` is
    Eq. (1)'s hysteresis term (:func:`~fmu_controller.hysteresis_model.hysteresis_term`) on the
    recorded ``l`` and the command ``u`` the model was identified on (``u(k - d)`` under an input
    delay ``d``), ``v`` the linear part's residual with ``theta``. Infinite where ``b1`` is 0 and the
    term is not (no command cancels it).

    Parameters
    ----------
    theta : ndarray
        Parameters of Eq. (1), in ``structure``'s order.
    structure : ModelStructure
        Model variant of ``theta``.
    u : ndarray
        The command the model was identified on (``u(k - d)`` under an input delay ``d``), in the
        record's unit.
    l : ndarray
        Recorded displacement, in the record's unit.
    """
    theta = np.asarray(theta, dtype=float)
    v = virtual_hysteresis_sequence(theta, l, u)
    k = np.arange(2, len(l))
    phi = regressor(l[k], l[k - 1], l[k - 2], u[k], v[k - 1], v[k - 2], structure)
    h = phi[:, 3:] @ theta[3:]
    b1 = theta[structure.index("b1")]
    spread = float(np.std(h))
    return spread / abs(b1) if b1 != 0.0 else (math.inf if spread > 0.0 else 0.0)


def _beyond(key: str, scale: float) -> str | None:
    """What a scale beyond the mm and V of the controllers says, else None: a displacement's of 100 or
    more is one over 60 x 10^1.5 = 1897 mm; the valve takes 0..10 V, so a command's of 10 (a largest
    command of 6 x 10^0.5 = 18.97 or more) is not in volts."""
    if scale <= 0.01:
        return (f"under about 1.9 (scaling.{key} = {scale:g}: metres?)" if key == "l_scale" else
                f"under about 0.19 (scaling.{key} = {scale:g}: a normalised 0..1 command?)")
    if key == "l_scale" and scale >= 100.0:
        return f"over about 1900 (scaling.{key} = {scale:g}: micrometres?)"
    if key == "u_scale" and scale >= 100.0:
        return f"about 190 or more (scaling.{key} = {scale:g}: millivolts?)"
    if key == "u_scale" and scale >= 10.0:
        return (f"about 19 or more (scaling.{key} = {scale:g}: % of the valve's opening, or volts x 10? The valve "
                "takes 0..10 V)")
    return None


def units_note(scaling: object) -> str | None:
    """``"a recording whose largest ... ; the controllers need ..."`` where an identification's
    ``scaling`` (``{"l_scale": ..., "u_scale": ...}``) is beyond the mm and V of the controllers
    (:func:`_beyond`), else None.

    Parameters
    ----------
    scaling : object
        An identification's ``scaling``: a dict ``{"l_scale": ..., "u_scale": ...}``; anything
        else gives None.
    """
    if not isinstance(scaling, dict):
        return None
    odd = []
    for key, what in (("l_scale", "displacement"), ("u_scale", "command")):
        scale = scaling.get(key)
        if isinstance(scale, (int, float)) and not isinstance(scale, bool):
            said = _beyond(key, float(scale))
            if said is not None:
                odd.append(f"largest {what} is {said}")
    if not odd:
        return None
    return (f"a recording whose {' and whose '.join(odd)}; the controllers need Eq. (1) in mm and V, as their "
            "readings l and command u are: identify on the recording in mm and V")


def identify_record(u_v: np.ndarray, l_mm: np.ndarray, *, ts_s: float, model: str = "asymmetric",
                    box: str | Mapping[str, tuple[float, float]] | None = "auto",
                    constraint_start_s: float = 120.0, p0: float = 1e3, forgetting: float = 1.0,
                    theta0: Mapping[str, float] | Sequence[float] | None = None,
                    input_delay_samples: int = 0) -> IdentificationReport:
    """Identify Eq. (1) on a record by (constrained) RLS and score it (section 2.3, Table 4).

    Parameters
    ----------
    u_v, l_mm : ndarray
        Command and displacement, one sample per period (any units, see module docstring).
    ts_s : float
        Sampling period [s].
    model : {"asymmetric", "standard"}
        Eq. (1) with the polynomial ``g(l)`` (15 parameters) or without it (11).
    box : "auto", None, or mapping name -> (lower, upper)
        Constraint region C of Algorithm 1, in the record's units (module docstring).
    constraint_start_s : float
        Time from which the projection is applied (paper: 120 s).
    p0 : float
        ``P(-1) = p0 I`` in normalised units (paper: 1e3).
    forgetting : float
        Forgetting factor (1 = off, the paper's Eq. (4)).
    theta0 : mapping or sequence of float, optional
        Initial estimate, record units: by name (names left out start at 0, as
        ``report.theta_dict``) or every parameter in ``structure.names`` order (as ``report.theta``).
        Default zeros (section 2.4).
    input_delay_samples : int
        A rig's transport delay ``d`` [samples], 0 .. 25 (``MAX_INPUT_DELAY_SAMPLES``): Eq. (1) is
        identified on the command the valve had, ``u(k - d)``
        (:func:`~fmu_controller.prediction.delayed_input`), the model that the controller's
        ``input_delay_samples = d`` predicts with (docs/control.md, "Transport delay"). Open loop,
        a random or step input's 1-step fit is highest at the rig's delay; a sine's rises past it (its
        phase lag takes up a delay, too).

    Raises
    ------
    ValueError
        Unknown model; data that cannot support identification (constant input or output, fewer
        than ``MIN_SAMPLES`` samples, non-finite values); a bad box or delay.
    """
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; expected one of {', '.join(MODELS)}")
    structure = MODELS[model]
    if isinstance(ts_s, bool) or not isinstance(ts_s, numbers.Real):
        raise TypeError(f"ts_s must be a number of seconds, got {type(ts_s).__name__} {ts_s!r}")
    ts_s = float(ts_s)
    u = np.asarray(u_v, dtype=float)
    l = np.asarray(l_mm, dtype=float)
    check_record(u, l, ts_s)
    u = delayed_input(u, input_delay_samples)
    l_scale, u_scale = decade_scale(l, 60.0), decade_scale(u, 6.0)
    f = theta_scale_factors(structure, l_scale, u_scale)
    notes: list[str] = []
    table2 = False  # box="auto" took Table 2's

    if isinstance(box, str):
        if box != "auto":
            raise ValueError(f"box must be 'auto', None or a mapping name -> (lower, upper), got {box!r}")
        # Ts as exact as a recording's period can be told (tapmuscle.io.recording: 0.1 %)
        if l_scale == 1.0 and u_scale == 1.0 and abs(ts_s - PAPER_TS_S) <= 1e-3 * PAPER_TS_S:
            lower, upper = dict(TABLE2_LOWER), dict(TABLE2_UPPER)
            table2 = True
        else:
            lower, upper = {}, {}
            paper_ts = abs(ts_s - PAPER_TS_S) <= 1e-3 * PAPER_TS_S
            # the scales are chosen by magnitude: a stroke of a few mm is scaled like one in cm
            hint = ("if it is in mm and V (a small stroke or command), pass Table 2 itself: --box "
                    + ",".join(f"{n}={TABLE2_LOWER[n]:g}:{TABLE2_UPPER[n]:g}" for n in TABLE2_LOWER)
                    if paper_ts else "the estimate is unconstrained, and so is an adaptive controller started from this file "
                    "unless you pass a box of your rig's (--box; docs/identification.md, 'A box at another sampling "
                    "period': none is derived for you)")
            notes.append(f"no constraint region: Table 2's box is for mm, V and Ts = 0.1 s, this record has "
                         f"Ts = {ts_s:.6g} s and magnitudes normalised by l/{l_scale:g}, u/{u_scale:g}; {hint}")
    elif box is None:
        lower, upper = {}, {}
    else:
        lower, upper = box_from_pairs(box, names=structure.names, what=f"box ({model} model)")
    # Box and initial estimate into normalised units: theta_scaled = theta_physical / f.
    idx = {n: i for i, n in enumerate(structure.names)}
    s_lower = {n: v / f[idx[n]] for n, v in lower.items()}
    s_upper = {n: v / f[idx[n]] for n, v in upper.items()}
    th0 = None if theta0 is None else structure.as_theta(theta0, what="theta0", default=0.0) / f
    settings = RLSSettings(p0=p0, theta0=None if th0 is None else tuple(th0), forgetting=forgetting,
                           box_lower=s_lower, box_upper=s_upper,
                           constraint_start_s=constraint_start_s, ts_s=float(ts_s))
    result: IdentificationResult = run_rls(structure, u / u_scale, l / l_scale, settings)
    theta = rescale_theta(result.theta, structure, l_scale, u_scale)
    outside = [f"{n} = {theta[idx[n]]:.4g} not in [{lower.get(n, -math.inf):g}, {upper.get(n, math.inf):g}]"
               for n in structure.names if not lower.get(n, -math.inf) <= theta[idx[n]] <= upper.get(n, math.inf)]
    duration = (len(l) - 1) * float(ts_s)
    if outside:
        # the controllers refuse a theta0 outside its region C: said here, where it can be mended
        why = (f"the record ({duration:g} s) ends before the constraint starts ({constraint_start_s:g} s): give "
               f"--constraint-start (constraint_start_s) below {duration:g} s"
               if duration < constraint_start_s else "the projection of Algorithm 1 did not bring it inside")
        notes.append(f"the final estimate lies outside the constraint region ({'; '.join(outside)}): {why}; a "
                     "controller refuses it as theta0 with this box")
    elif (lower or upper) and duration < constraint_start_s:
        # the file records the box, which an adaptive controller then applies from its start
        notes.append(f"the constraint region was never applied: the record ({duration:g} s) ends before the constraint "
                     f"starts ({constraint_start_s:g} s); the final estimate lies inside it unprojected (give "
                     f"--constraint-start (constraint_start_s) below {duration:g} s for Algorithm 1 to act)")
    elif table2:
        # the paper's rig's box, taken for any record in mm and V at 0.1 s: said, with what it held
        # at a bound: within a thousandth of the box's span, or 2e-4 (an update after the last projection
        # moves the estimate off it by ulps to 1e-4: the simulated rig's identification ends with
        # b1 = 0.60709 on Table 2's 0.607)
        near = {n: max(1e-3 * (upper[n] - lower[n]), 2e-4) for n in lower}
        held = [f"{n} = {theta[idx[n]]:.5g} at its {'lower' if theta[idx[n]] <= lower[n] + near[n] else 'upper'} bound"
                for n in lower if theta[idx[n]] <= lower[n] + near[n] or theta[idx[n]] >= upper[n] - near[n]]
        notes.append("constraint region: Table 2's box on " + ", ".join(lower) + " (the paper's rig at Ts = 0.1 s; "
                     f"Algorithm 1 projected at {result.n_projections} samples)" + (f"; the final estimate has {', '.join(held)}"
                                                                     if held else "")
                     + "; on another rig a diverged free run says that the box does not hold it")
    history = result.theta_history * f
    fit = score_model(theta, structure, u, l)
    if fit.free_run_diverged:
        notes.append(_diverged_note(structure, u / u_scale, l / l_scale, settings, l_scale, u_scale, u, l,
                                    bool(lower or upper)))
    swing = cancellation_swing(theta, structure, u, l)
    if not swing <= CANCELLATION_SWING_V * u_scale:  # a NaN too
        b1 = theta[structure.index("b1")]
        size = f"{swing:.3g} V" if u_scale == 1.0 else f"{swing:.3g} (the record's units of u)"
        notes.append(f"the hysteresis cancellation of Eq. (5) on this model, H(k)/b1, swings by {size} (standard "
                     f"deviation over this record; b1 = {b1:.3g}), more than half the valve's range: the hysteresis "
                     "terms have taken up the linear dynamics (docs/identification.md, \"A model that is a poor "
                     "fixed law\"), and a "
                     "fixed law on it (MPC-UCP, MPC-servo) slams the valve; the adaptive methods recover from it. "
                     "Identify on random levels held 0.5-3 s (random:lo=2,hi=8,hold_min=0.5,hold_max=3) rather than a "
                     f"sine or a chirp, or {REFINE_IN_CLOSED_LOOP}")
    unit = units_note({"l_scale": l_scale, "u_scale": u_scale})
    if unit is not None:
        notes.append(f"identified on {unit}")
    if ts_s < SHORT_TS_S:
        # the muscle moves a few hundredths of a mm a sample: any model predicts the next sample from
        # the last, and the dynamics Eq. (1) is meant to hold are in its last digits
        free = "diverged" if fit.free_run_diverged else f"{fit.percent['sim']:.1f} %"
        notes.append(f"Ts = {ts_s:g} s is short for Eq. (1): the muscle moves little from one sample to the next, so "
                     f"the 1-step fit ({fit.percent['1']:.2f} %) says little and the free run ({free}) is the figure "
                     f"to judge; compare it with the record merged to {SHORT_TS_S:g}-{PAPER_TS_S:g} s (tapmuscle "
                     "import --decimate N, tm.decimated; docs/identification.md, \"Fast data acquisition\")")
    return IdentificationReport(
        model=model, structure=structure, ts_s=float(ts_s), n_samples=len(l), theta=theta,
        theta_history=history, fit=fit, l_scale=l_scale, u_scale=u_scale,
        box_lower=lower, box_upper=upper, constraint_start_s=float(constraint_start_s),
        n_projections=result.n_projections, n_resets=result.n_resets, notes=tuple(notes),
        input_delay_samples=int(input_delay_samples))
