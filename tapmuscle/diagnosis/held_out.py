"""The held-out evidence: the displacement's residual, and the pressure's beside it when recorded.

The effects of the vocabulary act at different places of the rig, and the pressure sensor (Table 1)
sees some of them and not others. An amplifier's gain or offset, a valve's no-flow band, a supply
sag and a transport delay change the muscle pressure the model predicts for the recorded command;
a backlash, an encoder drift and a load mismatch act after the pressure (a load mismatch barely
moves the bleed circuit's pressure, which the command sets). On the displacement alone these
trade with each other and with the recalibrated constants (a backlash looks like a short delay, an
amplifier gain like a load and a stiffer bladder); on both channels they do not.

With ``diagnose(..., use_pressure=True)`` (off by default: docs/diagnosis.md has the measured
trade-off) every held-out test of the diagnosis (an effect's significance against the recalibrated
model, two explanations' distinguishability, the ranking of alternatives, the backward step) works
on the stacked residual

.. math::

    \\varepsilon = [\\, (l - \\hat l)_{test},\\; w\\,(p - \\hat p)_{test} \\,], \\qquad w = \\sigma_l / \\sigma_p

in which the pressure residual is rescaled so that its white noise has the displacement's level
``sigma_l`` [mm]: the Gaussian likelihood of both sensors, with the tests' statistics unchanged.
``sigma_p`` is the pressure residual's white-noise level from its first differences (as for the
displacement). The calibration, the joint re-fits and the input map's search fit the same stacked
residual on the training blocks (:meth:`tapmuscle.diagnosis.fit_problem.Problem.sensor_residual`).
Without a usable pressure column (or with a model that predicts none, a foreign FMU) the evidence is
the displacement's alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from tapmuscle.diagnosis.residual_analysis import block_index, white_noise_level_mm

__all__ = ["HeldOut"]


@dataclass(frozen=True)
class HeldOut:
    """The held-out samples of a recording and how its channels are weighed (module docstring).

    Parameters
    ----------
    y_mm : ndarray
        Recorded displacement [mm].
    test : ndarray of bool
        Held-out mask.
    p_mpa : ndarray or None
        Recorded pressure [MPa] (None: the displacement alone).
    noise_mm : float
        ``sigma_l``, the displacement residual's white-noise level [mm].
    pressure_noise_mpa : float or None
        ``sigma_p`` [MPa] (None when the pressure is not used).
    """

    y_mm: np.ndarray
    test: np.ndarray
    noise_mm: float
    p_mpa: np.ndarray | None = None
    pressure_noise_mpa: float | None = None

    @classmethod
    def setup(cls, y_mm: np.ndarray, test: np.ndarray, noise_mm: float, p_mpa: np.ndarray | None,
              p_model_mpa: np.ndarray | None) -> "HeldOut":
        """The evidence of a recording: the pressure is used when the recording has a finite, varying
        pressure column of the right length and the model predicts one (``p_model_mpa``, the nominal
        model's re-simulation, from whose residual ``sigma_p`` is taken)."""
        alone = cls(y_mm, test, noise_mm)
        if p_mpa is None or p_model_mpa is None:
            return alone
        p = np.asarray(p_mpa, float)
        if p.shape != np.shape(y_mm) or not np.all(np.isfinite(p)) or float(np.ptp(p)) == 0.0:
            return alone
        sigma_p = white_noise_level_mm(p - np.asarray(p_model_mpa, float))
        if not (math.isfinite(sigma_p) and sigma_p > 0.0 and noise_mm > 0.0):
            return alone
        return cls(y_mm, test, noise_mm, p, sigma_p)

    @property
    def uses_pressure(self) -> bool:
        return self.p_mpa is not None

    @property
    def weight_mm_per_mpa(self) -> float:
        """``w = sigma_l / sigma_p`` [mm/MPa] (0 when the pressure is not used)."""
        return 0.0 if self.pressure_noise_mpa is None else self.noise_mm / self.pressure_noise_mpa

    def stacked(self, y_hat: np.ndarray, p_hat: np.ndarray | None, mask: np.ndarray) -> np.ndarray:
        """Stacked residual [mm] on the samples of ``mask`` of a prediction from sample 0 (displacement
        [mm] and, when the pressure is used, pressure [MPa]; it may stop before the recording's end)."""
        n = len(y_hat)
        m = mask[:n]
        e = (self.y_mm[:n] - y_hat)[m]
        if self.p_mpa is None:
            return e
        if p_hat is None:
            raise ValueError("the evidence uses the pressure, but this prediction has none")
        return np.concatenate([e, self.weight_mm_per_mpa * (self.p_mpa[:n] - p_hat)[m]])

    def residual(self, y_hat: np.ndarray, p_hat: np.ndarray | None) -> np.ndarray:
        """Stacked held-out residual [mm] of a whole-run prediction (:meth:`stacked` on the held-out
        blocks)."""
        return self.stacked(y_hat, p_hat, self.test)

    def without_blocks_touching(self, stretches_s: Sequence[tuple[float, float]], ts_s: float,
                                block_s: float) -> "HeldOut":
        """The evidence without the held-out blocks that any of ``stretches_s`` touches.

        A stretch is ``(from, to)`` [s] on the recording's time base ``k ts_s``; the blocks are those
        of :func:`~tapmuscle.diagnosis.residual_analysis.block_index` with ``block_s``. The
        evidence is returned unchanged when the blocks left would hold fewer than half its held-out
        samples (the tests' power would go with them).
        """
        if not len(stretches_s):
            return self
        block = block_index(len(self.y_mm), ts_s, block_s)
        touched = [k for a, b in stretches_s for k in range(int(a // block_s), int(b // block_s) + 1)]
        test = self.test & ~np.isin(block, touched)
        if 2 * int(test.sum()) < int(self.test.sum()):
            return self
        return replace(self, test=test)

    def contribution_rms_mm(self, y_a: np.ndarray, p_a: np.ndarray | None, y_b: np.ndarray,
                            p_b: np.ndarray | None) -> float:
        """How much two predictions differ on the held-out blocks [mm]: the larger of the
        displacement's RMS difference and the (rescaled) pressure's, so that an effect that shows in
        one channel only is not diluted by the other."""
        rms = float(np.sqrt(np.mean((y_a - y_b)[self.test] ** 2)))
        if self.p_mpa is None or p_a is None or p_b is None:
            return rms
        return max(rms, self.weight_mm_per_mpa * float(np.sqrt(np.mean((p_a - p_b)[self.test] ** 2))))
