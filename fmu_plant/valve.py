"""Proportional valves and orifice flow (Table 1: Koganei KFPV300, Cv 1.6, 0-10 V).

Pure functions on SI floats; the plant calls them inside its sub-step loop, so they avoid numpy
(scalar numpy calls cost ~1 us each, ten times a float operation).
"""

from __future__ import annotations

import math

__all__ = ["valve_opening", "flow_coefficient", "orifice_flow"]


def valve_opening(u_v: float, u_min_v: float, u_max_v: float) -> float:
    """Normalised opening target ``x* in [0, 1]`` of the supply valve for a command ``u_v`` [V].

    Commands outside the valve's range saturate, as the valve amplifier does.

    Parameters
    ----------
    u_v : float
        Valve command [V].
    u_min_v, u_max_v : float
        The valve's command range [V] (``ValveParams.u_min_v``, ``u_max_v``).
    """
    x = (u_v - u_min_v) / (u_max_v - u_min_v)
    return 0.0 if x < 0.0 else 1.0 if x > 1.0 else x


def flow_coefficient(k_full: float, opening: float, leak_fraction: float, exponent: float,
                     gate: float = 1.0) -> float:
    """Orifice coefficient of a valve at spool ``opening`` (0..1, clipped) [units of ``k_full``].

    ``k = k_full (e + (1 - e) g x^n)``: the leak ``e`` of a closed spool, a quick-opening
    characteristic ``x^n`` (n = 0.5 makes the bleed circuit's steady pressure proportional to the
    command, docs/plant.md), and a gate ``g`` (1; 0 in a no-flow band, the ``valve_dead_zone``
    effect). The supply valve opens with ``x``, the drain valve with ``1 - x``.

    Parameters
    ----------
    k_full : float
        Coefficient of the fully open valve ``k_full``, in the unit the result takes.
    opening : float
        Spool opening ``x`` [-], clipped to 0..1.
    leak_fraction : float
        Leak ``e`` of the closed spool, as a fraction of full opening [-].
    exponent : float
        Characteristic exponent ``n`` [-].
    gate : float, optional
        Gate ``g`` [-] on the opening beyond the leak; default 1.
    """
    x = 0.0 if opening < 0.0 else 1.0 if opening > 1.0 else opening
    return k_full * (leak_fraction + (1.0 - leak_fraction) * gate * x ** exponent)


def orifice_flow(k_m3_s_pa05: float, dp_pa: float, laminar_dp_pa: float) -> float:
    """Turbulent orifice flow ``Q = k sign(dp) sqrt(|dp|)`` [m^3/s], regularised near ``dp = 0``.

    Below ``laminar_dp_pa`` the flow is made linear in ``dp`` (laminar), which keeps the derivative
    finite (the Rosenbrock sub-steps' Jacobian) where the two sides equalise.

    Parameters
    ----------
    k_m3_s_pa05 : float
        Orifice coefficient ``k`` [m^3/(s Pa^0.5)].
    dp_pa : float
        Pressure drop across the orifice ``dp`` [Pa]; its sign gives the flow's direction.
    laminar_dp_pa : float
        Drop below which the flow is linear in ``dp`` [Pa] (> 0).
    """
    adp = abs(dp_pa)
    if adp >= laminar_dp_pa:
        return math.copysign(k_m3_s_pa05 * math.sqrt(adp), dp_pa)
    return k_m3_s_pa05 * dp_pa / math.sqrt(laminar_dp_pa)
