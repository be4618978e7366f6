"""Candidates of one's own: checked before the search, and held to their contract during it.

A researcher gives :func:`~tapmuscle.diagnosis.diagnose.diagnose` a
:class:`~tapmuscle.diagnosis.candidates.Candidate` of her own beside the built-in ones
(docs/diagnosis.md, "A candidate of your own"). The search re-simulates every model it weighs
through the plant's parameters, so such a candidate must set plant parameters, within the plant's
bounds, that no other candidate sets, under a name the joint re-fits and the report do not already
know (:func:`check_own_candidates`). Its fit and refine are the user's code: :func:`held_to_contract`
wraps them so that what they return is checked (values among its parameters and within its bounds,
a finite prediction of the recording's length) and what they raise names the candidate
(:class:`~tapmuscle.diagnosis.candidates.CandidateError`, with the original as its cause).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any, Sequence

import numpy as np

from fmu_plant import PlantParams

from tapmuscle.diagnosis.candidates import CANDIDATES, Candidate, CandidateError, FitResult, Problem
from tapmuscle.diagnosis.fit_problem import SimulationError

__all__ = ["RESERVED_NAMES", "check_own_candidates", "held_to_contract", "own_joint"]

#: Names a candidate of one's own may not take: the report's finding for what no effect explains.
RESERVED_NAMES = ("unexplained",)

_WHERE = "(docs/diagnosis.md, \"A candidate of your own\")"


def check_own_candidates(candidates: Sequence[Candidate], model: PlantParams) -> None:
    """Refuse candidates the search could not carry (module docstring).

    Parameters
    ----------
    candidates : sequence of Candidate
        The diagnosis's candidates, built-in (the objects of
        :data:`~tapmuscle.diagnosis.candidates.CANDIDATES`) and one's own.
    model : PlantParams
        The nominal model: a candidate's keys must be its parameters.

    Raises
    ------
    CandidateError
        Naming the candidate and what it lacks.
    """
    builtin = {c.name: c for c in CANDIDATES}
    keys = model.dotted()
    seen: set[str] = set()
    set_by: dict[str, str] = {}
    for c in candidates:
        own = builtin.get(c.name) is not c
        if own and c.name in builtin:
            raise CandidateError(f"candidates: a candidate of your own is named {c.name!r}, a built-in candidate's name, "
                                 "by which the joint re-fits and the report would take it for the built-in: name it "
                                 "otherwise")
        if own and c.name in RESERVED_NAMES:
            raise CandidateError(f"candidates: a candidate of your own is named {c.name!r}, the report's name for "
                                 "what no effect explains: name it otherwise")
        if c.name in seen:
            raise CandidateError(f"candidates: {c.name!r} is given twice")
        seen.add(c.name)
        for spec in c.parameters:
            if spec.key in set_by:
                raise CandidateError(f"candidates: {c.name!r} and {set_by[spec.key]!r} both set {spec.key!r}: the "
                                     "search could not tell which of them a fitted value belongs to; give one of them")
            set_by[spec.key] = c.name
        if own:
            _check_parameters(c, keys)


def _real(x: Any) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


def _check_parameters(c: Candidate, keys: dict[str, float]) -> None:
    """A candidate of one's own's parameters and joint ones (:func:`check_own_candidates`)."""
    if not c.parameters:
        raise CandidateError(f"candidates: {c.name!r} sets no plant parameter: the diagnosis re-simulates an accepted "
                             "effect through the plant parameters its fit sets, so an effect the plant does not have "
                             f"is dropped from every model it is in {_WHERE}")
    for spec in c.parameters:
        if spec.key not in keys:
            raise CandidateError(f"candidates: {c.name!r} sets {spec.key!r}, which is not a plant parameter "
                                 "('group.field' of PlantParams; the plant's own effects are in "
                                 f"fmu_plant/effect_library.py) {_WHERE}")
        lo, hi = spec.lo, spec.hi
        if not (_real(lo) and _real(hi)):
            raise CandidateError(f"candidates: {c.name!r}: its bounds of {spec.key} are {lo!r} .. {hi!r}: give two "
                                 "finite numbers (ParameterSpec(key, unit, lo, hi))")
        if not lo < hi:
            raise CandidateError(f"candidates: {c.name!r}: its bounds of {spec.key} are {lo!r} .. {hi!r}: give the "
                                 "lower bound first, below the upper one (ParameterSpec(key, unit, lo, hi))")
        plant_lo, plant_hi = PlantParams.bounds(spec.key)
        if lo < plant_lo or hi > plant_hi:
            raise CandidateError(f"candidates: {c.name!r}: its bounds of {spec.key} are {lo:g} .. {hi:g}, beyond the "
                                 f"plant's {plant_lo:g} .. {plant_hi:g}: the plant refuses a value outside them")
    specs = {spec.key for spec in c.parameters}
    if not isinstance(c.joint, (tuple, list)):
        raise CandidateError(f"candidates: {c.name!r}: its joint must be a tuple of (key, scale) pairs, got "
                             f"{type(c.joint).__name__}")
    for pair in c.joint:
        if not (isinstance(pair, (tuple, list)) and len(pair) == 2):
            raise CandidateError(f"candidates: {c.name!r}: its joint holds {pair!r:.60}, not a (key, scale) pair")
        key, scale = pair
        if key not in specs:
            raise CandidateError(f"candidates: {c.name!r}: its joint names {key!r}, not one of its parameters "
                                 f"({', '.join(sorted(specs))})")
        if not (_real(scale) and scale > 0):
            raise CandidateError(f"candidates: {c.name!r}: its joint scale of {key} is {scale!r}: give a typical change "
                                 "of the value (a positive number, in its unit)")


def own_joint(candidates: Sequence[Candidate]) -> dict[str, tuple[tuple[str, float], ...]]:
    """The joint parameters of those of ``candidates`` (one's own) that name some
    (:attr:`~tapmuscle.diagnosis.candidates.Candidate.joint`), for
    :class:`~tapmuscle.diagnosis.model_space.MuscleSpace`'s ``own_joint``.

    Parameters
    ----------
    candidates : sequence of Candidate
        Candidates of one's own.
    """
    return {c.name: tuple((str(k), float(v)) for k, v in c.joint) for c in candidates if c.joint}


def held_to_contract(cand: Candidate) -> Candidate:
    """``cand`` (one's own, checked by :func:`check_own_candidates`) with its fit and refine checked
    as they run (module docstring); the search runs these in the calling process.

    Parameters
    ----------
    cand : Candidate
        A candidate of one's own.
    """
    contract = _Contract(cand)
    return dataclasses.replace(cand, fit=contract.fit, refine=None if cand.refine is None else contract.refine)


class _Contract:
    """A candidate of one's own's fit and refine, and the checks of what they return and raise."""

    def __init__(self, cand: Candidate) -> None:
        self.cand = cand
        self.specs = {spec.key: spec for spec in cand.parameters}

    def fit(self, problem: Problem, base: PlantParams, y_base: np.ndarray) -> FitResult | None:
        """The candidate's fit: None, or a :class:`FitResult` of its parameters with a finite
        prediction of the recording's length. A failed simulation is the search's to report."""
        result = self._call("fit", self.cand.fit, problem, base, y_base)
        if result is None:
            return None
        if not isinstance(result, FitResult):
            raise CandidateError(f"candidate {self.cand.name!r}: its fit returned {type(result).__name__} "
                                 f"{result!r:.60}, not a FitResult or None")
        self._check_values("fit", result.values)
        self._check_prediction(result.y_hat, np.shape(y_base))
        return result

    def refine(self, problem: Problem, params: PlantParams) -> dict[str, float] | None:
        """The candidate's refine: None (not moved), or values of its parameters within its bounds. A
        simulation that fails in it leaves the values where they are."""
        try:
            moved = self._call("refine", self.cand.refine, problem, params)
        except SimulationError:
            return None
        if moved is None:
            return None
        if not isinstance(moved, dict):
            raise CandidateError(f"candidate {self.cand.name!r}: its refine returned {type(moved).__name__} "
                                 f"{moved!r:.60}, not a dict of its parameters' values or None")
        self._check_values("refine", moved)
        return moved

    def _call(self, what: str, fn: Any, *args: Any) -> Any:
        try:
            return fn(*args)
        except (SimulationError, CandidateError):
            raise
        except Exception as exc:  # the user's code: say whose (the traceback is the cause's)
            raise CandidateError(f"candidate {self.cand.name!r}: its {what} raised {type(exc).__name__}: {exc}") from exc

    def _check_values(self, what: str, values: Any) -> None:
        """The values re-simulated: among the candidate's parameters and within its bounds."""
        name = self.cand.name
        if not isinstance(values, dict):
            raise CandidateError(f"candidate {name!r}: its {what} set values of type {type(values).__name__}, not a "
                                 "dict of its parameters' values")
        for key, value in values.items():
            spec = self.specs.get(key)
            if spec is None:
                raise CandidateError(f"candidate {name!r}: its {what} set {key!r}, not one of its parameters "
                                     f"({', '.join(self.specs)})")
            if not (_real(value) and spec.lo <= value <= spec.hi):
                raise CandidateError(f"candidate {name!r}: its {what} set {key} = {value!r}, outside its bounds "
                                     f"{spec.lo:g} .. {spec.hi:g}")

    def _check_prediction(self, y_hat: Any, shape: tuple[int, ...]) -> None:
        """The prediction scored on the held-out blocks: the recording's length, finite."""
        name = self.cand.name
        y = np.asarray(y_hat, dtype=float)
        if y.shape != shape:
            raise CandidateError(f"candidate {name!r}: its fit's prediction y_hat has shape {y.shape}, not the "
                                 f"recording's {shape} (full_prediction(problem, base, values) gives it)")
        bad = np.flatnonzero(~np.isfinite(y))
        if bad.size:
            raise CandidateError(f"candidate {name!r}: its fit's prediction y_hat is {float(y[bad[0]])!r} at sample "
                                 f"{bad[0]} ({bad.size} samples not finite): return None where the fit fails")
