"""The calibrated constants' linearised step: what an effect leaves once the constants re-fit around it.

A candidate's own search runs on the calibrated constants, which were fitted without the effect and
have taken up part of it. For an effect whose own parameters are not joint coordinates (a valve band's
edges: the cost is piecewise constant in them), the own search then judges each trial value by a
residual that the joint re-fit would change at once: on field case ``079`` (seed 1: a 0.91-V band at
5.62 V under a sine sum) the raw search found a 0.18-V band at 3.25 V, while the true band, with the
constants left where they were, fit worse than none.

:class:`LinearisedConstants` holds, at the model the search starts from, the Jacobian ``A`` of the
residual in the constants' scaled coordinates (one simulation per constant, as far as the searches look),
their prior rows and their bounds. :meth:`LinearisedConstants.left_mm2` is the squared error the
linearised MAP step of the constants leaves on chosen samples,

.. math::

    \\min_{\\delta,\\ \\ell \\le x + \\delta \\le u}
        \\lVert r + A\\delta \\rVert^2 + \\sigma^2 \\lVert x + \\delta \\rVert_{\\text{prior}}^2 ,

with ``x`` the constants' scaled distance from nominal and ``sigma`` the noise level that weighs the
prior (the calibration's own objective, linearised; Gauss-Newton's model of the joint re-fit with the
effect's own parameters held). It is the score test's prediction
(:mod:`tapmuscle.diagnosis.score_test`) for a trial effect whose shape is held, and it respects the
bounds a joint re-fit cannot cross (a constant already at its bound only moves inwards).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear

from fmu_plant import PlantParams
from tapmuscle.diagnosis.reproducible import snap_relative, sse

__all__ = ["LinearisedConstants"]


@dataclass(frozen=True)
class LinearisedConstants:
    """The calibrated constants' linearised MAP step at the model ``at`` (module docstring).

    Parameters
    ----------
    at : PlantParams
        The model the Jacobian was taken at; a search on any other base must not use it.
    jacobian : ndarray, shape (n, k)
        Derivative of the residual ``y - y_hat`` of the recording's first ``n`` samples with respect
        to the ``k`` constants' scaled coordinates [mm per prior sd].
    x : ndarray, shape (k,)
        The constants' scaled distance from their nominal values at ``at`` [prior sds].
    prior : ndarray of bool, shape (k,)
        Which constants have a Gaussian prior (the others are flat within their bounds).
    lower, upper : ndarray, shape (k,)
        The constants' bounds in scaled coordinates [prior sds from nominal].
    sigma_mm : float
        Noise level that weighs the prior [mm].
    """

    at: PlantParams
    jacobian: np.ndarray = field(repr=False)
    x: np.ndarray
    prior: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    sigma_mm: float

    def __post_init__(self) -> None:
        k = self.jacobian.shape[1] if self.jacobian.ndim == 2 else -1
        for name in ("x", "prior", "lower", "upper"):
            if np.shape(getattr(self, name)) != (k,):
                raise ValueError(f"LinearisedConstants.{name} has shape {np.shape(getattr(self, name))}, "
                                 f"expected ({k},) for a Jacobian of shape {np.shape(self.jacobian)}")
        if not (np.isfinite(self.sigma_mm) and self.sigma_mm > 0.0):
            raise ValueError(f"LinearisedConstants.sigma_mm must be finite and > 0, got {self.sigma_mm!r}")

    def left_mm2(self, residual_mm: np.ndarray, rows: np.ndarray) -> float:
        """Squared error [mm^2] left on the samples ``rows`` (indices into the recording) of the
        residual ``residual_mm`` (one value per row) after the constants' bounded linearised MAP step,
        the prior's share included."""
        r = np.asarray(residual_mm, float)
        rows = np.asarray(rows)
        if r.shape != rows.shape:
            raise ValueError(f"{r.size} residual values for {rows.size} rows")
        if rows.size and not 0 <= int(rows.min()) <= int(rows.max()) < len(self.jacobian):
            raise ValueError(f"rows {int(rows.min())}..{int(rows.max())} reach beyond the Jacobian's "
                             f"{len(self.jacobian)} samples")
        p = self.prior.astype(bool)
        eye = np.eye(len(self.x))[p]
        A = np.vstack([self.jacobian[rows], self.sigma_mm * eye])
        b = np.concatenate([r, self.sigma_mm * self.x[p]])
        if A.shape[1] == 0:
            return sse(b)
        # b + A d with d within the bounds: lsq_linear minimises |A z - c|, so z = d and c = -b
        # (a constant at its bound gets a vanishing outward range: the solver needs lower < upper)
        lo = np.minimum(self.lower - self.x, -1e-9)
        hi = np.maximum(self.upper - self.x, 1e-9)
        step = lsq_linear(A, -b, bounds=(lo, hi), method="bvls").x
        # the solver's last bits are the BLAS's: rounded, a search on this ranks the same on every CPU
        return snap_relative(sse(b + A @ step))
