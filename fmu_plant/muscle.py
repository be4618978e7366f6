"""McKibben muscle statics: Tondu-Lopez force and volume (400 mm muscle, Table 1).

The braid geometry gives, with contraction ratio ``eps = l / L0`` and initial braid angle ``alpha0``,

.. math::  F = p\\,\\pi r_0^2\\,[a (1-\\varepsilon)^2 - b], \\quad a = 3/\\tan^2\\alpha_0,\\; b = 1/\\sin^2\\alpha_0

(Tondu & Lopez, IEEE Control Systems 2000). By virtual work, ``F = p dV/dl``, so the factor
``pi r0^2 [a (1-eps)^2 - b]`` is also the muscle's volume change per unit contraction [m^2]: the
"piston area" the water flow works against. The muscle cannot push: beyond the maximal contraction
``eps_max = 1 - 1/(sqrt(3) cos alpha0)`` both vanish.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .parameters import MuscleParams

__all__ = ["MuscleGeometry", "effective_pressure_mpa", "muscle_force_n", "LOCK_EXPONENT_MAX"]

#: Largest exponent of the braid lock's ``exp(-l / l_lock)`` evaluated (exp overflows past ~709): at a
#: (trial) state farther beyond the extension stop the force is infinite, and an integrator rejects it.
LOCK_EXPONENT_MAX = 700.0


@dataclass(frozen=True)
class MuscleGeometry:
    """Constants of the Tondu-Lopez model derived once from :class:`MuscleParams` (SI units).

    Parameters
    ----------
    rest_length_m : float
        Active length ``L0`` at zero contraction [m].
    area0_m2 : float
        Bladder cross-section at rest ``A0 = pi r0^2`` [m^2].
    a, b : float
        Tondu-Lopez constants ``a = 3/tan^2(alpha0)``, ``b = 1/sin^2(alpha0)`` [-].
    max_contraction_m : float
        Maximal contraction ``L0 (1 - 1/(sqrt(3) cos(alpha0)))`` [m].
    radius0_m : float
        Bladder radius at rest ``r0`` [m].
    cos_alpha0, sin_alpha0 : float
        Cosine and sine of the initial braid angle ``alpha0`` [-].
    """

    rest_length_m: float
    area0_m2: float
    a: float
    b: float
    max_contraction_m: float
    radius0_m: float
    cos_alpha0: float
    sin_alpha0: float

    @classmethod
    def from_params(cls, p: MuscleParams) -> "MuscleGeometry":
        alpha0 = math.radians(p.braid_angle_deg)
        r0 = p.radius_mm * 1e-3
        length = p.rest_length_mm * 1e-3
        return cls(
            rest_length_m=length,
            area0_m2=math.pi * r0 * r0,
            a=3.0 / math.tan(alpha0) ** 2,
            b=1.0 / math.sin(alpha0) ** 2,
            max_contraction_m=length * (1.0 - 1.0 / (math.sqrt(3.0) * math.cos(alpha0))),
            radius0_m=r0,
            cos_alpha0=math.cos(alpha0),
            sin_alpha0=math.sin(alpha0),
        )

    def piston_area_m2(self, l_m: float) -> float:
        """``dV/dl = F/p`` [m^2] at contraction ``l_m`` [m]; zero beyond the maximal contraction."""
        s = 1.0 - l_m / self.rest_length_m
        g = self.a * s * s - self.b
        return self.area0_m2 * g if g > 0.0 else 0.0

    def contact_factor(self, l_m: float) -> float:
        """Braid-bladder contact area relative to rest, ``(r/r0)(L/L0)`` [-].

        With inextensible braid threads the radius grows as ``r/r0 = sin(alpha)/sin(alpha0)`` and
        ``cos(alpha) = cos(alpha0) (1 - eps)``; friction scales with this area (see friction.py).
        """
        s = 1.0 - l_m / self.rest_length_m
        c = self.cos_alpha0 * s
        return math.sqrt(max(1.0 - c * c, 0.0)) / self.sin_alpha0 * s


def effective_pressure_mpa(p_mpa: float, threshold_mpa: float, width_mpa: float) -> float:
    """Pressure that loads the braid [MPa]: the bladder takes the first ``threshold_mpa``.

    A softplus, ``w ln(1 + exp((p - p_th) / w))``: zero well below the threshold, ``p - p_th`` well
    above, smooth over ``width_mpa`` (a hard kink acts as a dead zone Eq. (1) cannot follow;
    docs/plant.md).

    Parameters
    ----------
    p_mpa : float
        Muscle gauge pressure ``p`` [MPa].
    threshold_mpa : float
        Bladder threshold ``p_th`` [MPa].
    width_mpa : float
        Width ``w`` of the smooth onset [MPa] (> 0).
    """
    arg = (p_mpa - threshold_mpa) / width_mpa
    return width_mpa * (arg + math.log1p(math.exp(-arg)) if arg > 0.0 else math.log1p(math.exp(arg)))


def muscle_force_n(mp: MuscleParams, geo: MuscleGeometry, p_mpa: float, l_mm: float, v_mm_s: float,
                   z_n: float, load_n: float) -> float:
    """Net force on the muscle's free end [N], positive contracting (before the extension stop).

    Tondu-Lopez braid force at the effective pressure, minus the bladder's rubber stiffness, the
    hanging load, viscous damping and the friction state ``z_n`` (friction.py), plus the braid lock
    near full extension, ``F_lock exp(-l / l_lock)``.

    Parameters
    ----------
    mp : MuscleParams
    geo : MuscleGeometry
        ``MuscleGeometry.from_params(mp)``.
    p_mpa, l_mm, v_mm_s, z_n, load_n : float
        Muscle pressure [MPa], contraction [mm], its rate [mm/s], friction state [N], load [N].
    """
    p_eff = effective_pressure_mpa(p_mpa, mp.threshold_pressure_mpa, mp.threshold_width_mpa)
    force = (p_eff * 1e6 * geo.piston_area_m2(l_mm * 1e-3) - mp.rubber_stiffness_n_per_mm * l_mm - load_n
             - mp.damping_n_s_per_mm * v_mm_s - z_n)
    if mp.braid_lock_force_n:
        e_lock = -l_mm / mp.braid_lock_length_mm
        force += mp.braid_lock_force_n * (math.exp(e_lock) if e_lock < LOCK_EXPONENT_MAX else math.inf)
    return force
