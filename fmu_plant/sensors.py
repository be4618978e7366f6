"""Linear encoder and pressure sensor (Table 1): white noise, then quantisation, then range.

Noise is drawn from the plant's own seeded ``numpy.random.Generator`` so a run is reproducible.
"""

from __future__ import annotations

import numpy as np

from .parameters import SensorParams

__all__ = ["quantise", "read_encoder_mm", "read_pressure_mpa"]


def quantise(value: float, resolution: float) -> float:
    """Round ``value`` to the nearest multiple of ``resolution`` (0 = no quantisation).

    Parameters
    ----------
    value : float
        The value to round.
    resolution : float
        The quantisation step, in the unit of ``value``; <= 0 returns ``value`` unchanged.
    """
    if resolution <= 0.0:
        return value
    return round(value / resolution) * resolution


def read_encoder_mm(sp: SensorParams, l_mm: float, rng: np.random.Generator) -> float:
    """Encoder reading [mm] of the true displacement ``l_mm`` (noise std, then 0.01 mm counts).

    Parameters
    ----------
    sp : SensorParams
        The encoder's noise std and resolution [mm].
    l_mm : float
        True contraction [mm].
    rng : numpy.random.Generator
        Source of the noise (one normal drawn when the noise std is > 0).
    """
    if sp.encoder_noise_std_mm > 0.0:
        l_mm = l_mm + sp.encoder_noise_std_mm * float(rng.standard_normal())
    return quantise(l_mm, sp.encoder_resolution_mm)


def read_pressure_mpa(sp: SensorParams, p_mpa: float, rng: np.random.Generator) -> float:
    """Pressure-sensor reading [MPa(G)], clipped to the 0..range span of the sensor.

    Parameters
    ----------
    sp : SensorParams
        The pressure sensor's noise std, resolution and range [MPa].
    p_mpa : float
        True muscle gauge pressure [MPa].
    rng : numpy.random.Generator
        Source of the noise (one normal drawn when the noise std is > 0).
    """
    if sp.pressure_noise_std_mpa > 0.0:
        p_mpa = p_mpa + sp.pressure_noise_std_mpa * float(rng.standard_normal())
    p_mpa = quantise(p_mpa, sp.pressure_resolution_mpa)
    return min(max(p_mpa, 0.0), sp.pressure_range_mpa)
