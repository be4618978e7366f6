"""The fits of the diagnosis's model selection (docs/diagnosis.md, steps 4-5): a candidate effect's own
fit, the joint re-fit of the calibrated constants with the effects' smooth parameters, its further
starts, the profiling of a parameter the own search fits on constants that absorbed part of it, the
score test's linearised gains, and the constants' linearised step for the own searches.

Pure numerics on a :class:`~tapmuscle.diagnosis.fit_problem.Problem` (the recording's training and
held-out blocks and the simulator); :func:`tapmuscle.diagnosis.diagnose.diagnose` decides with them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from fmu_plant import PlantParams

from tapmuscle.diagnosis.calibration import (FD_STEP, FittedParameter, fit_covariance, fit_parameters,
                                             fitted_intervals)
from tapmuscle.diagnosis.candidates import CANDIDATES, Candidate, FitResult, Problem
from tapmuscle.diagnosis.fit_problem import SimulationError
from tapmuscle.diagnosis.linearised_constants import LinearisedConstants
from tapmuscle.diagnosis.model_space import ModelSpace
from tapmuscle.diagnosis.parallel_tasks import on_copies
from tapmuscle.diagnosis.reproducible import sse
from tapmuscle.diagnosis.score_test import score_gain

__all__ = ["SelectedModel", "BUILTIN", "own_fit", "start_fits", "effect_coords", "effect_intervals", "joint_refit",
           "own_parameters", "fd_step", "score_gains", "linearise_constants", "searched_afresh", "profiled_refit",
           "joint_prediction"]


@dataclass
class SelectedModel:
    """A model in the selection: calibrated constants plus effects, and its whole-run prediction."""

    params: PlantParams
    """Its parameters: the calibrated constants and the effects' values."""
    effects: tuple[str, ...]
    """Its effects, by name, in the order accepted."""
    y: np.ndarray
    """Its whole-run displacement prediction [mm]."""
    values: dict[str, dict[str, float]]
    """Per effect, its fitted parameters."""
    q: np.ndarray | None = None
    """Its whole-run pressure prediction [MPa] (None: the model predicts none)."""


BUILTIN = {c.name: c for c in CANDIDATES}


def own_fit(problem: Problem, base: PlantParams, y_base: np.ndarray, cand: Candidate | str) -> FitResult | None:
    """A candidate's own fit on ``base`` (a built-in one by name: candidates hold lambdas, which do not
    pickle).

    Parameters
    ----------
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    base : PlantParams
        The model the candidate is fitted on top of.
    y_base : ndarray
        ``base``'s whole-run prediction [mm].
    cand : Candidate or str
        The candidate, or a built-in one's name.
    """
    if isinstance(cand, str):
        return BUILTIN[cand].fit(problem, base, y_base)
    return cand.fit(problem, base, y_base)


def start_fits(cands: Sequence[Candidate], problem: Problem, base: PlantParams,
               y_base: np.ndarray, each_done: Callable[[], None] | None = None
               ) -> list[Callable[[], tuple[Any, int, float]]]:
    """Each candidate's own fit on ``base`` (whose run left the checkpoints) by :func:`on_copies`,
    one handle per candidate in order: the built-in ones in worker processes (by name), those of one's
    own here meanwhile (they need not pickle).

    Parameters
    ----------
    cands : sequence of Candidate
        The candidate effects.
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    base : PlantParams
        The model the candidate is fitted on top of.
    y_base : ndarray
        ``base``'s whole-run prediction [mm].
    each_done : callable, optional
        Called as each fit's result is had (:func:`~tapmuscle.diagnosis.parallel_tasks.on_copies`).
    """
    own = [i for i, c in enumerate(cands) if BUILTIN.get(c.name) is not c]
    builtin = [i for i in range(len(cands)) if i not in own]
    jobs = dict(zip(builtin, on_copies(problem, own_fit, (base, y_base), [(cands[i].name,) for i in builtin],
                                        each_done=each_done)))
    jobs |= dict(zip(own, on_copies(problem, own_fit, (base, y_base), [(cands[i],) for i in own], parallel=False,
                                     each_done=each_done)))
    return [jobs[i] for i in range(len(cands))]


def effect_coords(space: ModelSpace, effects: Sequence[str]) -> list[FittedParameter]:
    """The coordinates of the ``effects``' parameters re-fitted jointly with the constants (flat
    within their bounds), in the order of the joint re-fit's columns after the constants'.

    Parameters
    ----------
    space : ModelSpace
        The model family's parameters, bounds and effects.
    effects : sequence of str
        The accepted effects, by name.
    """
    return [FittedParameter(key, 0.0, scale, False, *space.bounds(key))
            for e in effects for key, scale in space.joint_parameters.get(e, ())]


def effect_intervals(problem: Problem, space: ModelSpace, params: PlantParams, effects: Sequence[str],
                     sigma: float) -> dict[str, tuple[float, float]]:
    """95 % intervals of the ``effects``' joint parameters at ``params`` with the constants held: a
    forward-difference Jacobian (one simulation of the training blocks per parameter, all at once)
    and :func:`~tapmuscle.diagnosis.calibration.fit_covariance` (for a model without calibrated
    constants; with them, the final joint re-fit's covariance holds both).

    Parameters
    ----------
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    space : ModelSpace
        The model family's parameters, bounds and effects.
    params : PlantParams
        The model's parameters.
    effects : sequence of str
        The accepted effects, by name.
    sigma : float
        The noise level [mm] that weighs the prior.
    """
    extra = effect_coords(space, effects)
    if not extra:
        return {}
    r = problem.sensor_residual(params)
    steps = [fd_step(params, c.key, c.scale, c.hi) for c in extra]
    cols = problem.sensor_residuals([p for _, p in steps])
    jac = np.column_stack([(col - r) / h for (h, _), col in zip(steps, cols)])
    return fitted_intervals(extra, params.dotted(), fit_covariance(jac, r, sigma), space.bounds)


def joint_refit(problem: Problem, space: ModelSpace, coords: Sequence[FittedParameter], sigma: float,
                params: PlantParams, effects: Sequence[str], start_jac: np.ndarray | None = None,
                final: bool = False) -> tuple[PlantParams, Any]:
    """Re-fit the calibrated constants ``coords`` jointly with the effects' smooth parameters (a short
    warm start with secant updates during the search; the final model with fresh Jacobians).

    Parameters
    ----------
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    space : ModelSpace
        The model family's parameters, bounds and effects.
    coords : sequence of FittedParameter
        The calibrated constants (their prior and bounds).
    sigma : float
        The noise level [mm] that weighs the prior.
    params : PlantParams
        The start.
    effects : sequence of str
        The accepted effects, by name.
    start_jac : ndarray, optional
        A Jacobian of the constants to start the secant updates from.
    final : bool, optional
        The final model's re-fit (more iterations, fresh Jacobians).
    """
    joint_coords = list(coords) + effect_coords(space, effects)
    if not joint_coords:
        return params, None
    f = fit_parameters(problem.sensor_residual, params, joint_coords, sigma,
                       max_iterations=30 if final else 12, jacobian0=start_jac,
                       refresh_every=5 if final else None, residual_many=problem.sensor_residuals)
    return params.with_values(**f.values), f


def own_parameters(space: ModelSpace, cand: Candidate) -> set[str]:
    """The candidate's parameters that only its own search fits (not re-fitted jointly).

    Parameters
    ----------
    space : ModelSpace
        The model family's parameters, bounds and effects.
    cand : Candidate
        The candidate.
    """
    return {ps.key for ps in cand.parameters} - {key for key, _ in space.joint_parameters.get(cand.name, ())}


def fd_step(params: PlantParams, key: str, scale: float, hi: float) -> tuple[float, PlantParams]:
    """A forward-difference step of ``key`` (:data:`FD_STEP` in units of ``scale``; backwards where
    the step would cross the upper bound ``hi``): the step and the stepped parameters.

    Parameters
    ----------
    params : PlantParams
        The model's parameters.
    key : str
        The parameter's dotted key (``valve.cv_max``).
    scale : float
        The parameter's scale [its unit].
    hi : float
        Its upper bound.
    """
    v = params.value(key)
    h = FD_STEP if v + FD_STEP * scale <= hi else -FD_STEP
    return h, params.with_values(**{key: v + h * scale})


def score_gains(problem: Problem, space: ModelSpace, coords: Sequence[FittedParameter], sigma: float,
                jac_c: np.ndarray, current: SelectedModel, cands: Sequence[Candidate]) -> dict[str, float]:
    """The score test (:func:`~tapmuscle.diagnosis.score_test.score_gain`) of each candidate whose every
    parameter is a joint one, at the current model: the training error [mm^2] of the fit segment a
    linearised joint step (constants and the effect's parameters) would remove beyond the constants'
    own step. One simulation of the fit segment per parameter, all at once.

    Parameters
    ----------
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    space : ModelSpace
        The model family's parameters, bounds and effects.
    coords : sequence of FittedParameter
        The calibrated constants (their prior and bounds).
    sigma : float
        The noise level [mm] that weighs the prior.
    jac_c : ndarray
        The constants' Jacobian on the fit segment's stacked residual.
    current : SelectedModel
        The current model of the selection.
    cands : sequence of Candidate
        The candidate effects.
    """
    keys = {c.name: space.joint_parameters.get(c.name, ()) for c in cands}
    p = current.params

    def linearisable(c: Candidate) -> bool:
        # its own parameters (if any) at a joint start's values: the joint ones then describe it alone
        own = own_parameters(space, c)
        return not own or any(all(p.value(k) == v for k, v in start.items() if k in own)
                              for start in space.joint_starts.get(c.name, ()))
    smooth = [c for c in cands if keys[c.name] and linearisable(c)]
    if not smooth:
        return {}
    n_fit = problem.n_fit
    r = problem.stacked_residual(current.y[:n_fit], None if current.q is None else current.q[:n_fit])
    if jac_c.shape[0] != len(r):
        raise ValueError(f"the constants' Jacobian has {jac_c.shape[0]} rows for a training residual of {len(r)}")
    prior = np.array([c.prior for c in coords], bool)
    x_c = np.array([(p.value(c.key) - c.center) / c.scale for c in coords])
    A = np.vstack([jac_c, sigma * np.eye(len(coords))[prior]])
    b = np.concatenate([r, sigma * x_c[prior]])
    steps, runs = [], []
    for c in smooth:
        for key, scale in keys[c.name]:
            lo, hi = space.bounds(key)
            v = p.value(key)
            h, stepped = fd_step(p, key, scale, hi)
            steps.append((c.name, h, v <= lo, v >= hi))
            runs.append(stepped)
    cols = problem.sensor_residuals(runs)
    out = {}
    for c in smooth:
        idx = [i for i, s_ in enumerate(steps) if s_[0] == c.name]
        E = np.column_stack([np.concatenate([(cols[i] - r) / steps[i][1], np.zeros(int(prior.sum()))]) for i in idx])
        out[c.name] = score_gain(b, A, E, [steps[i][2] for i in idx], [steps[i][3] for i in idx])
    return out


def linearise_constants(problem: Problem, coords: Sequence[FittedParameter], sigma: float,
                        params: PlantParams, y_hat: np.ndarray, reach: int) -> LinearisedConstants:
    """The constants ``coords``' linearised MAP step at ``params`` (whose whole-run prediction is
    ``y_hat``) on the first ``reach`` samples: one simulation that far per constant, all at once.

    Parameters
    ----------
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    coords : sequence of FittedParameter
        The calibrated constants (their prior and bounds).
    sigma : float
        The noise level [mm] that weighs the prior.
    params : PlantParams
        The model's parameters.
    y_hat : ndarray
        ``params``' whole-run prediction [mm].
    reach : int
        Samples the step covers.
    """
    steps, runs = zip(*(fd_step(params, c.key, c.scale, c.hi) for c in coords))
    ys = problem.sim.run_many(runs, stop=reach)
    jac = np.column_stack([(y_hat[:reach] - y_p) / h for y_p, h in zip(ys, steps)])
    scaled = [((params.value(c.key) - c.center) / c.scale, (c.lo - c.center) / c.scale, (c.hi - c.center) / c.scale)
              for c in coords]
    x, lower, upper = (np.array(col, float) for col in zip(*scaled))
    return LinearisedConstants(params, jac, x, np.array([c.prior for c in coords], bool), lower, upper, sigma)


def searched_afresh(problem: Problem, space: ModelSpace, cand: Candidate, params: PlantParams,
                    values: dict[str, dict[str, float]], checkpoint_every: int) -> PlantParams:
    """``params`` with ``cand``'s own search run again on its constants (the effect switched off
    first); ``values[cand.name]`` is updated. Unchanged when the search finds nothing.

    Parameters
    ----------
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    space : ModelSpace
        The model family's parameters, bounds and effects.
    cand : Candidate
        The accepted effect.
    params : PlantParams
        The model's parameters.
    values : dict
        Per effect, its fitted parameters; ``cand``'s entry is updated.
    checkpoint_every : int
        Samples between the simulator's checkpoints.
    """
    off = params.with_values(**space.off_values(values[cand.name]))
    res = cand.fit(problem, off, problem.sim.run(off, checkpoint_every=checkpoint_every)[0])
    if res is None:
        return params
    values[cand.name] = dict(res.values)
    return off.with_values(**res.values)


def profiled_refit(problem: Problem, space: ModelSpace, coords: Sequence[FittedParameter], current: SelectedModel,
                   by_name: dict[str, Candidate], sigma: float, jac0: np.ndarray | None,
                   checkpoint_every: int) -> tuple[PlantParams, dict[str, dict[str, float]], np.ndarray | None, int] | None:
    """The accepted effects' profiled parameters (:attr:`ModelSpace.profiled`) re-chosen with the
    constants re-fitted jointly at each value.

    The constants were calibrated with the effects left out, and the own search of an effect whose
    cost is piecewise constant (a valve band's edges) then ran on constants that had absorbed part of
    it: a softer bladder and a smaller flow coefficient mimic part of the stall, and the band comes
    out at about half its width. The joint re-fits cannot widen it (its edges are not joint
    coordinates), and a search of the band alone on those constants finds the same narrow optimum. So
    the parameter is profiled: at each multiple of its fitted value the constants and the smooth
    effect parameters are re-fitted jointly (a short warm start), the best value on the training
    blocks is kept, the effect's own search runs again on its constants, and all is re-fitted jointly.
    Returns the parameters, the effects' values, the constants' Jacobian and the simulations used;
    None when no accepted effect has a profiled parameter.

    Parameters
    ----------
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    space : ModelSpace
        The model family's parameters, bounds and effects.
    coords : sequence of FittedParameter
        The calibrated constants (their prior and bounds).
    current : SelectedModel
        The current model of the selection.
    by_name : dict
        The candidates by name.
    sigma : float
        The noise level [mm] that weighs the prior.
    jac0 : ndarray or None
        The constants' Jacobian to start from.
    checkpoint_every : int
        Samples between the simulator's checkpoints.
    """
    todo = [(name, *space.profiled[name]) for name in current.effects if name in space.profiled]
    if not coords or not todo:
        return None
    sim = problem.sim
    runs0 = sim.runs
    values = dict(current.values)
    p, jac = current.params, jac0
    for name, key, factors in todo:
        v0 = p.value(key)
        lo, hi = space.bounds(key)
        best = None
        for k in (1.0, *factors):
            q, f = joint_refit(problem, space, coords, sigma, p.with_values(**{key: min(hi, max(lo, v0 * k))}),
                                current.effects, jac, final=False)
            e = sse(problem.sensor_residual(q))
            if best is None or e < best[0]:
                best = (e, q, f)
        _, p, f = best
        if f is not None:
            jac = f.jacobian[:, :len(coords)]
        p = searched_afresh(problem, space, by_name[name], p, values, checkpoint_every)
    p, f = joint_refit(problem, space, coords, sigma, p, current.effects, jac, final=True)
    return p, values, (jac if f is None else f.jacobian[:, :len(coords)]), sim.runs - runs0


def joint_prediction(problem: Problem, space: ModelSpace, coords: Sequence[FittedParameter], sigma: float,
                     start_jac: np.ndarray | None, start: PlantParams,
                     effects: tuple[str, ...]) -> tuple[PlantParams, np.ndarray, np.ndarray | None]:
    """:func:`joint_refit` from ``start`` and the re-fitted model's whole-recording prediction
    (displacement [mm], pressure [MPa] or None). When the newest effect has joint starts
    (:attr:`ModelSpace.joint_starts`), the re-fit also starts from ``start`` with each of them set
    (and, for an effect of :attr:`ModelSpace.starts_from_nominal`, with the constants ``coords`` at
    their prior's centre as well), and the one that fits the training blocks best is kept (the first
    on a tie).

    Parameters
    ----------
    problem : Problem
        The recording's training and held-out blocks and its simulator.
    space : ModelSpace
        The model family's parameters, bounds and effects.
    coords : sequence of FittedParameter
        The calibrated constants (their prior and bounds).
    sigma : float
        The noise level [mm] that weighs the prior.
    start_jac : ndarray or None
        A Jacobian of the constants to start from.
    start : PlantParams
        The start.
    effects : tuple of str
        The effects, the newest last.
    """
    p1, _ = joint_refit(problem, space, coords, sigma, start, effects, start_jac)
    best = (p1, *problem.sim.run(p1))
    if not coords or not effects:
        return best
    best_sse = sse(problem.stacked_residual(best[1], best[2]))
    further = space.joint_starts.get(effects[-1], ())
    starts = [(start.with_values(**values), start_jac) for values in further]
    if effects[-1] in space.starts_from_nominal:
        # the constants at their prior's centre, with a Jacobian taken there (the calibrated one is
        # another point's): the calibrated constants took the effect up along a valley that a short
        # re-fit from them does not leave
        centre = {c.key: c.center for c in coords}
        starts += [(start.with_values(**centre, **values), None) for values in further]
    for st, jac in starts:
        try:
            p2, _ = joint_refit(problem, space, coords, sigma, st, effects, jac)
            out = (p2, *problem.sim.run(p2))
        except SimulationError:  # a start the model cannot run from: the others still count
            continue
        out_sse = sse(problem.stacked_residual(out[1], out[2]))
        if out_sse < best_sse:
            best, best_sse = out, out_sse
    return best
