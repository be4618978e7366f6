"""The rig's state equations written with the documented physics modules (the one definition).

``rig_derivatives`` composes :mod:`fmu_plant.valve` (spool target, valve characteristic, orifice
flow), :mod:`fmu_plant.muscle` (Tondu-Lopez area and force, bladder threshold, braid lock, contact
area) and :mod:`fmu_plant.friction` (the Dahl friction state), in SI units, exactly as
docs/plant.md states them:

.. math::

    \\dot x = (x^*(u) - x) / \\tau, \\qquad
    C \\dot p = Q_{in}(x, p_s - p) - Q_{out}(1 - x, p - p_d) - A(l)\\,\\dot l, \\qquad
    m \\ddot l = F(p, l, \\dot l, z) \\;(\\text{0 on the extension stop}), \\qquad
    \\dot z = |\\dot l| / \\delta\\,(s F_s - z)

The simulator integrates a hand-fused copy of the same equations (``rosenbrock.build_model``: plain-float
closures, no function calls in the hot path, plus the Jacobian its Rosenbrock scheme needs).
``tests/test_equations.py`` checks the two against each other at thousands of states and the
Jacobian against finite differences of this definition, so an edit to the physics modules that is
not made in the fast path too fails the tests instead of silently not simulating.
"""

from __future__ import annotations

from .friction import friction_rate_n_s
from .muscle import MuscleGeometry, muscle_force_n
from .parameters import CV_TO_SI_WATER, GRAVITY_M_S2, PlantParams
from .valve import flow_coefficient, orifice_flow, valve_opening

__all__ = ["rig_derivatives"]


def rig_derivatives(params: PlantParams, state: tuple[float, float, float, float, float], u_v: float,
                    supply_mpa: float, load_n: float, *, gate: float = 1.0) -> tuple[float, float, float, float, float]:
    """Right-hand side of the rig's state equations from the physics modules (module docstring).

    Parameters
    ----------
    params : PlantParams
    state : (x, p_mpa, l_mm, v_mm_s, z_n)
        Spool opening [-], muscle gauge pressure [MPa], contraction [mm], its rate [mm/s], friction
        state [N].
    u_v, supply_mpa, load_n : float
        Valve command [V], supply gauge pressure [MPa], hanging load [N].
    gate : float
        Valve gate (1: open; the ``valve_dead_zone`` effect's 0 in its band).

    Returns
    -------
    tuple of 5 floats
        ``(dx/dt [1/s], dp/dt [MPa/s], dl/dt [mm/s], dv/dt [mm/s^2], dz/dt [N/s])``.
    """
    x, p, l, v, z = state
    vp, sup, mp, fp = params.valve, params.supply, params.muscle, params.friction
    geo = MuscleGeometry.from_params(mp)
    dx = (valve_opening(u_v, vp.u_min_v, vp.u_max_v) - x) / vp.spool_time_constant_s
    k_full = vp.cv_max * CV_TO_SI_WATER
    laminar_pa = vp.laminar_dp_mpa * 1e6
    k_in = flow_coefficient(k_full, x, vp.leak_fraction, vp.characteristic_exponent, gate)
    k_out = flow_coefficient(k_full, 1.0 - x, vp.leak_fraction, vp.characteristic_exponent, gate)
    q_m3_s = (orifice_flow(k_in, (supply_mpa - p) * 1e6, laminar_pa)
              - orifice_flow(k_out, (p - sup.drain_pressure_mpa) * 1e6, laminar_pa))
    volume_rate_m3_s = geo.piston_area_m2(l * 1e-3) * v * 1e-3
    dp = (q_m3_s - volume_rate_m3_s) / sup.compliance_m3_per_mpa
    force = muscle_force_n(mp, geo, p, l, v, z, load_n)
    if l <= 0.0 and v <= 0.0 and force <= 0.0:
        return dx, dp, 0.0, 0.0, 0.0  # resting on the braid's full-extension stop
    mass_kg = load_n / GRAVITY_M_S2 + params.load.moving_mass_kg
    dz = friction_rate_n_s(fp, z, v, p, geo.contact_factor(l * 1e-3))
    return dx, dp, v, force / mass_kg * 1e3, dz
