"""Proportional valves and orifice flow (Table 1: Koganei KFPV300, Cv 1.6, 0-10 V).

Pure functions on SI floats; the plant calls them inside its sub-step loop, so they avoid numpy
(scalar numpy calls cost ~1 us each, ten times a float operation).
"""

from __future__ import annotations

import math

__all__ = ["valve_opening", "orifice_flow"]


def valve_opening(u_v: float, u_min_v: float, u_max_v: float) -> float:
    """Normalised opening target ``x* in [0, 1]`` of the supply valve for a command ``u_v`` [V].

    Commands outside the valve's range saturate, as the valve amplifier does.
    """
    x = (u_v - u_min_v) / (u_max_v - u_min_v)
    return 0.0 if x < 0.0 else 1.0 if x > 1.0 else x


def orifice_flow(k_m3_s_pa05: float, dp_pa: float, laminar_dp_pa: float) -> float:
    """Turbulent orifice flow ``Q = k sign(dp) sqrt(|dp|)`` [m^3/s], regularised near ``dp = 0``.

    Below ``laminar_dp_pa`` the flow is made linear in ``dp`` (laminar), which keeps the derivative
    finite so fixed-step integration does not chatter when the two sides equalise.
    """
    adp = abs(dp_pa)
    if adp >= laminar_dp_pa:
        return math.copysign(k_m3_s_pa05 * math.sqrt(adp), dp_pa)
    return k_m3_s_pa05 * dp_pa / math.sqrt(laminar_dp_pa)
