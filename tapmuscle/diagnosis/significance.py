"""The residual tests and held-out tests the diagnosis's decisions rest on (docs/diagnosis.md, steps 2,
4 and 6): is a residual structured, does an effect improve the held-out blocks more than noise could,
can the held-out data tell two explanations apart.

Every sum goes through :mod:`tapmuscle.diagnosis.reproducible`: the same recording gives the same
decisions on any CPU or BLAS kernel.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import stats

from tapmuscle.diagnosis.calibration import effective_sigma
from tapmuscle.diagnosis.reproducible import dot, norm, sse
from tapmuscle.diagnosis.residual_analysis import (Correlation, autocorrelation_test, cross_correlation_test,
                                                   is_structured)

__all__ = ["residual_tests", "significance_test", "distinguishable"]


def residual_tests(u: np.ndarray, e: np.ndarray, sensor_mm: float) -> tuple[dict[str, Any], Correlation, Correlation]:
    """The residual ``e``'s tests (:func:`~tapmuscle.diagnosis.residual_analysis.is_structured`, its
    whiteness and its cross-correlation with the input ``u``): their numbers as the report keeps them,
    and the two correlation tests.

    Parameters
    ----------
    u : ndarray
        The recording's input (the command [V]).
    e : ndarray
        The residual, measured minus simulated [mm].
    sensor_mm : float
        The sensor noise the model states [mm].
    """
    structured, numbers = is_structured(e, sensor_noise_mm=sensor_mm)
    ac = autocorrelation_test(e)
    xc = cross_correlation_test(u, e)
    numbers.update({"structured": structured, "whiteness_p": ac.p_value, "autocorrelation_lags_outside": ac.outside,
                    "cross_correlation_p": xc.p_value, "cross_correlation_lags_outside": xc.outside,
                    "band_99": ac.band})
    return numbers, ac, xc


def significance_test(e0: np.ndarray, e1: np.ndarray, noise_mm: float, alpha: float) -> dict[str, float]:
    """Is the held-out improvement ``e0 -> e1`` more than noise could give?

    With the effect's contribution ``d = e0 - e1`` (fitted on other samples), ``e0 . d / (sigma |d|)``
    is the residual's projection on the contribution in units of the white-noise level ``sigma``: a
    standard normal if the held-out residual were only noise. One-sided p-value.

    Parameters
    ----------
    e0, e1 : ndarray
        Held-out residuals [mm] without and with the effect.
    noise_mm : float
        White-noise level [mm].
    alpha : float
        The test's level, reported with it.
    """
    sse0, sse1 = sse(e0), sse(e1)
    d = e0 - e1
    nd = norm(d)
    z = dot(e0, d) / (noise_mm * nd) if nd > 0 and noise_mm > 0 else (math.inf if nd > 0 else 0.0)
    return {"sse_before_mm2": sse0, "sse_after_mm2": sse1, "reduction": 1.0 - sse1 / sse0 if sse0 > 0 else 0.0,
            "z": z, "p_value": float(stats.norm.sf(z)), "significant_at": alpha}


def distinguishable(e_best: np.ndarray, e_other: np.ndarray, noise_mm: float, *, alpha: float = 1e-3,
                    min_ratio: float = 1.1, residual_mm: np.ndarray | None = None) -> tuple[bool, dict[str, float]]:
    """Can the held-out data tell the best explanation from another one?

    Both must hold: the other's held-out squared error exceeds the best's by at least
    ``min_ratio``, and the difference is more than noise could give. The statistic is
    ``z = (SSE_other - SSE_best) / (2 sigma |y_best - y_other|)``, the SSE difference in units of its
    sampling spread when the best leaves noise of level ``sigma``; ``sigma`` is the white-noise level,
    or the best's own residual level inflated for its autocorrelation where that is larger (a
    residual that is not white spreads an SSE difference more). One-sided, level ``alpha``.

    Parameters
    ----------
    e_best, e_other : ndarray
        Held-out residuals [mm] of the best explanation and the other one.
    noise_mm : float
        White-noise level [mm].
    alpha : float, optional
        Level of the one-sided test; default 1e-3.
    min_ratio : float, optional
        Smallest ratio of the other's held-out SSE to the best's; default 1.1.
    residual_mm : ndarray, optional
        The residual whose level stands for what no explanation accounts for (default ``e_best``).
        The diagnosis passes the final model's held-out residual: the best's residual at the round
        the alternatives were fitted still holds the effects that later rounds explained, and those
        are not noise.
    """
    s_best, s_other = sse(e_best), sse(e_other)
    delta = norm(e_best - e_other)
    sigma = max(noise_mm, effective_sigma(e_best if residual_mm is None else residual_mm))
    z = (s_other - s_best) / (2.0 * sigma * delta) if delta > 0 and sigma > 0 else 0.0
    ratio = s_other / s_best if s_best > 0 else math.inf
    p = float(stats.norm.sf(z))
    return ratio >= min_ratio and p < alpha, {"sse_ratio": ratio, "z": z, "p_value": p, "sigma_mm": sigma}
