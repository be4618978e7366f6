"""The fitting problem every candidate effect works on: the recording, its split, the simulator.

:class:`Problem` is one recording to explain (measured data, interleaved training and held-out
blocks, the simulator with its checkpoints); :class:`FitResult` is a fitted candidate;
:func:`full_prediction` simulates the whole recording with a candidate's values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmu_plant import PlantParams
from tapmuscle.diagnosis.held_out import HeldOut
from tapmuscle.diagnosis.linearised_constants import LinearisedConstants
from tapmuscle.diagnosis.simulation import SimulationError, Simulator, checkpoint_interval

__all__ = ["Problem", "FitResult", "Rejected", "SimulationError", "full_prediction"]


@dataclass(frozen=True)
class Rejected:
    """A candidate whose fit had to stop: a simulation failed (``reason``); the search goes on.

    Parameters
    ----------
    reason : str
        Why the fit stopped (the simulation's error).
    """

    reason: str


#: The residual of a failed simulation, in multiples of the recording's largest magnitude: far worse than
#: any real prediction, and finite, so that a solver steps back from the point instead of failing.
FAILED_RESIDUAL_SCALE = 1e3


@dataclass
class Problem:
    """One recording to explain: measured data, the train/held-out split, the simulator."""

    y_mm: np.ndarray
    """Measured displacement [mm]."""
    t_s: np.ndarray
    """Time [s]."""
    u_v: np.ndarray
    """Command [V]."""
    ts_s: float
    """Sampling period [s]."""
    train: np.ndarray
    """Mask of the training samples (fits see only these)."""
    test: np.ndarray
    """Mask of the held-out samples (scores only)."""
    sim: Simulator
    """Re-simulates the recording's command with a parameter set."""
    noise_mm: float
    """White-noise level of the residual [mm]."""
    fit_segment_s: float = 120.0
    """Stationary effects are fitted on the first this many seconds (whole-run simulations are the cost)."""
    block_s: float = 10.0
    """Length of the interleaved training and held-out blocks [s]."""
    evidence: HeldOut | None = None
    """How the recording's channels are weighed; with the pressure in it, :meth:`sensor_residual`
    stacks it beside the displacement (None: the displacement alone)."""
    constants: LinearisedConstants | None = None
    """The calibrated constants' linearised step at the model the own searches about to run start
    from (None without a calibration): a search whose base is that model may judge trial values by
    what the constants' re-fit would leave."""

    @property
    def uses_pressure(self) -> bool:
        return self.evidence is not None and self.evidence.uses_pressure

    @property
    def n(self) -> int:
        return len(self.y_mm)

    @property
    def checkpoint_every(self) -> int:
        """Samples between the checkpoints a baseline run keeps (:func:`checkpoint_interval`)."""
        return checkpoint_interval(self.ts_s)

    @property
    def n_fit(self) -> int:
        return min(self.n, int(round(self.fit_segment_s / self.ts_s)) + 1)

    def plateau(self, best_mm2: float) -> float:
        """The highest training cost [mm^2] that still counts as ``best_mm2``'s: 0.1 % above it, or
        ten samples' noise variance. A parameter the training blocks cannot place (an edge whose
        evidence lies in a held-out block) leaves the cost flat within this."""
        return best_mm2 + max(1e-3 * best_mm2, 10.0 * self.noise_mm ** 2)

    def as_good(self, best_mm2: float, n_samples: int) -> float:
        """:meth:`plateau`, or ten samples' worth of the residual left (``best_mm2`` over the
        ``n_samples`` training samples it sums) where that is higher [mm^2].

        A residual that is model error, not noise, is not white: a parameter moved where the
        training blocks hold no evidence of it changes their cost through the muscle's memory by
        more than ten samples' noise variance."""
        return max(self.plateau(best_mm2), best_mm2 + 10.0 * best_mm2 / max(1, n_samples))

    def fit_residual(self, params: PlantParams) -> np.ndarray:
        """Training residual [mm] of ``params`` over the fit segment (one simulation); for parameters
        the model cannot be simulated with, a large finite residual (:data:`FAILED_RESIDUAL_SCALE`)."""
        try:
            return self.train_residual(self.sim.run(params, stop=self.n_fit)[0])
        except SimulationError:
            return self._failed_residual()

    def fit_residuals(self, params: list[PlantParams]) -> list[np.ndarray]:
        """:meth:`fit_residual` of each of ``params`` (spread over the simulator's executor, if any)."""
        try:
            return [self.train_residual(l) for l in self.sim.run_many(params, stop=self.n_fit)]
        except SimulationError:  # find out which, one by one
            return [self.fit_residual(p) for p in params]

    def sensor_residual(self, params: PlantParams) -> np.ndarray:
        """Training residual of every sensor the fits weigh [mm]: :meth:`fit_residual`'s, with the
        rescaled pressure residual appended when :attr:`evidence` uses the pressure (the calibration
        and the joint re-fits use it; the candidates' own searches stay on the displacement)."""
        if not self.uses_pressure:
            return self.fit_residual(params)
        try:
            return self.stacked_residual(*self.sim.run(params, stop=self.n_fit))
        except SimulationError:
            return self._failed_residual(2)

    def sensor_residuals(self, params: list[PlantParams]) -> list[np.ndarray]:
        """:meth:`sensor_residual` of each of ``params`` (spread over the simulator's executor, if any)."""
        if not self.uses_pressure:
            return self.fit_residuals(params)
        try:
            return [self.stacked_residual(l, p) for l, p in self.sim.run_many(params, stop=self.n_fit, pressure=True)]
        except SimulationError:
            return [self.sensor_residual(p) for p in params]

    def stacked_residual(self, l_hat: np.ndarray, p_hat: np.ndarray | None) -> np.ndarray:
        """Training residual [mm] of a prediction from sample 0 (displacement [mm], pressure [MPa]):
        the displacement's, with the rescaled pressure's appended when :attr:`evidence` uses it."""
        if not self.uses_pressure:
            return self.train_residual(l_hat)
        return self.evidence.stacked(l_hat, p_hat, self.train)

    def _failed_residual(self, channels: int = 1) -> np.ndarray:
        size = channels * int(np.count_nonzero(self.train[:self.n_fit]))
        return np.full(size, FAILED_RESIDUAL_SCALE * (1.0 + float(np.max(np.abs(self.y_mm)))))

    def train_residual(self, y_hat: np.ndarray, start: int = 0) -> np.ndarray:
        """``y - y_hat`` on the training samples from ``start`` over ``len(y_hat)`` samples."""
        stop = start + len(y_hat)
        m = self.train[start:stop]
        return (self.y_mm[start:stop] - y_hat)[m]


@dataclass
class FitResult:
    """A fitted candidate: its parameter values and its prediction of the whole recording."""

    values: dict[str, float]
    """Plant parameters to set (``group.field`` -> value), on top of the base model."""
    y_hat: np.ndarray
    """Noise-free prediction of the whole recording with those values [mm]."""
    located: list[tuple[float, float]] | None = None
    """Where the effect acts, when the fit itself says (a sag's window); otherwise None."""
    joint_gain_mm2: float | None = None
    """Training error of the fit segment [mm^2] that the constants' linearised step with the effect
    as fitted removes beyond their step without it (:class:`LinearisedConstants`), when the search
    judged its trial values that way; otherwise None."""


def full_prediction(problem: Problem, base: PlantParams, values: dict[str, float]) -> np.ndarray:
    """Noise-free prediction of the whole recording [mm] by ``base`` with ``values`` set.

    Parameters
    ----------
    problem : Problem
        The recording (its simulator).
    base : PlantParams
        The model.
    values : dict of str to float
        Plant parameters to set (``group.field`` -> value).
    """
    return problem.sim.run(base.with_values(**values))[0]
