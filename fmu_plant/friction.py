"""Braid-bladder friction: the hysteresis of the muscle (paper section 1 and 2.1).

A Dahl-type friction state ``z`` [N] relaxes towards the sliding level over the presliding
displacement ``delta``:

.. math::  \\dot z = \\frac{|v|}{\\delta} (s F_s(p, l, |v|) - z), \\quad s = \\mathrm{sign}(v)

With a constant level this is rate independent (the loop depends on the path, not on time), like
the Bouc-Wen model. Three physical dependences make it like the real muscle:

* load/pressure: the normal force between braid and bladder grows with pressure and with the
  contact area, so at a higher pressure for the same contraction the level is higher; in the rig
  the valve sets the pressure at a command whatever the load, so a heavier load mostly shifts the
  loop and widens it by a few % (docs/plant.md, "Hysteresis");
* asymmetry: the level differs between contraction (``s = +1``) and extension (``s = -1``);
* rate: the level grows with sliding speed (lubricated contact), so faster motion widens the loop;
  the paper's section 4.4 finds this frequency dependence at 0.2 Hz. ``rate_gain = 0`` removes it.
"""

from __future__ import annotations

from .parameters import FrictionParams

__all__ = ["friction_level_n", "friction_rate_n_s"]


def friction_level_n(fp: FrictionParams, p_mpa: float, contact: float, speed_mm_s: float,
                     direction: float) -> float:
    """Sliding friction level ``F_s`` [N] (always >= 0) for motion in ``direction`` (+1 contraction).

    Parameters
    ----------
    fp : FrictionParams
    p_mpa : float
        Muscle gauge pressure [MPa] (negative values count as zero).
    contact : float
        Braid-bladder contact area relative to rest [-] (``MuscleGeometry.contact_factor``).
    speed_mm_s : float
        Sliding speed ``|v|`` [mm/s].
    direction : float
        +1 while contracting, -1 while extending.
    """
    level = (fp.base_n + fp.per_mpa_n * (p_mpa if p_mpa > 0.0 else 0.0) * contact)
    level *= 1.0 + direction * fp.asymmetry
    if fp.rate_gain > 0.0:
        level *= 1.0 + fp.rate_gain * (speed_mm_s / fp.rate_ref_mm_s) ** fp.rate_exponent
    return level


def friction_rate_n_s(fp: FrictionParams, z_n: float, v_mm_s: float, p_mpa: float,
                      contact: float) -> float:
    """Time derivative of the friction state ``dz/dt`` [N/s] (Dahl model, see module docstring).

    Parameters
    ----------
    fp : FrictionParams
    z_n : float
        Friction state ``z`` [N].
    v_mm_s : float
        Contraction speed [mm/s] (> 0 contracting); at 0 the state does not change.
    p_mpa : float
        Muscle gauge pressure [MPa].
    contact : float
        Braid-bladder contact area relative to rest [-] (``MuscleGeometry.contact_factor``).
    """
    if v_mm_s == 0.0:
        return 0.0
    direction = 1.0 if v_mm_s > 0.0 else -1.0
    speed = abs(v_mm_s)
    target = direction * friction_level_n(fp, p_mpa, contact, speed, direction)
    return speed / fp.presliding_mm * (target - z_n)
