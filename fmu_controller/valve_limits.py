"""The valve's command limits (Eq. (19)) and what a command held at one tells.

A command at a limit the error ``r - l`` pushes it further into is the servo integrator's cue to hold
(Eq. (18), conditional integration); a command held at a limit while the error pushes it *away* says
the law's gain has the wrong sign for the rig; a command that jumps end to end in a sample is the
start-up guard's cue (``ControllerSettings.startup_guard``). Floats in volts and millimetres.
"""

from __future__ import annotations

from typing import Any

__all__ = ["VALVE_MIN_V", "VALVE_MAX_V", "GUARD_JUMP_FRACTION", "GUARD_JUMPS", "pushed_at_limit", "pinned_side",
           "HELD_AGAINST_MM", "HELD_WARN_S", "held_against_error", "held_against_cause", "limit_side",
           "full_range_jump"]


#: The proportional valve's command range [V] (Table 1, "Range of input voltage"; Eq. (19)): the servo's and UCP's ``u_min_v`` and
#: ``u_max_v`` lie within it. A bound beyond it is a command the valve clips, and the adaptive
#: estimator, which sees the command, would learn from inputs the valve never received.
VALVE_MIN_V, VALVE_MAX_V = 0.0, 10.0

#: ``ControllerSettings.startup_guard``: the start-up mode leaves ``theta0`` for the estimate once the
#: command has jumped across this fraction of the valve's range in one sample ...
GUARD_JUMP_FRACTION = 0.9
#: ... this many times since the estimator started: a law that slams the valve end to end. (Two
#: happen in a sound start: the delayed law that ``input_delay_samples = -1`` starts with, one sample
#: early in a sequential master, can jump twice before the delay is decided.)
GUARD_JUMPS = 3


def pushed_at_limit(r_mm: float, l_mm: float, u_v: float, u_min_v: float, u_max_v: float) -> bool:
    """Whether the command ``u_v`` [V] sits at a valve limit that the error ``r - l`` [mm] pushes it
    further into (within 1 nV: the QP's bound on u_c leaves u = u_c - H/b1 a rounding error off it).

    Parameters
    ----------
    r_mm : float
        Reference ``r`` [mm].
    l_mm : float
        Measured contraction ``l`` [mm].
    u_v : float
        Valve command [V].
    u_min_v, u_max_v : float
        The valve's command limits [V] (Eq. (19)).
    """
    return pinned_side(r_mm, l_mm, u_v, u_min_v, u_max_v) != 0


def pinned_side(r_mm: float, l_mm: float, u_v: float, u_min_v: float, u_max_v: float) -> int:
    """Which valve limit the command ``u_v`` [V] sits at (within 1 nV) with the error ``r - l`` [mm]
    pushing it further in: 1 the upper (``r > l``), -1 the lower (``r < l``), 0 neither.

    Parameters
    ----------
    r_mm : float
        Reference ``r`` [mm].
    l_mm : float
        Measured contraction ``l`` [mm].
    u_v : float
        Valve command [V].
    u_min_v, u_max_v : float
        The valve's command limits [V] (Eq. (19)).
    """
    if r_mm > l_mm and u_v >= u_max_v - 1e-9:
        return 1
    if r_mm < l_mm and u_v <= u_min_v + 1e-9:
        return -1
    return 0


#: A command held at a valve limit while the error ``r - l`` pushes it away from that limit by at least
#: this much [mm] (the encoder's noise and a resting muscle's sag are hundredths) is held against the
#: error (:func:`held_against_error`).
HELD_AGAINST_MM = 2.0
#: A command held against the error this long [s] in a row is reported (the controller FMU's log, a
#: closed loop's warning).
HELD_WARN_S = 10.0


def held_against_error(r_mm: Any, l_mm: Any, u_v: Any, u_min_v: float, u_max_v: float) -> Any:
    """Whether the command ``u_v`` [V] sits at a valve limit while the error ``r - l`` [mm], by
    :data:`HELD_AGAINST_MM` or more, pushes it away from it: a law that opened (closed) the valve would
    move ``l`` towards ``r``, so the law's gain has the wrong sign for the rig. Floats or arrays
    (element-wise).

    Parameters
    ----------
    r_mm : float or ndarray
        Reference ``r`` [mm].
    l_mm : float or ndarray
        Measured contraction ``l`` [mm].
    u_v : float or ndarray
        Valve command [V].
    u_min_v, u_max_v : float
        The valve's command limits [V] (Eq. (19)).
    """
    return (((r_mm - l_mm >= HELD_AGAINST_MM) & (u_v <= u_min_v + 1e-9))
            | ((l_mm - r_mm >= HELD_AGAINST_MM) & (u_v >= u_max_v - 1e-9)))


def held_against_cause(theta0_b1: float, name: str = "theta0.b1") -> str:
    """Why a command is held against the error (:func:`held_against_error`), in words, for a law on a
    ``theta0`` with this ``b1`` [mm/V] (``name``: how the caller names it).

    Parameters
    ----------
    theta0_b1 : float
        The law's ``b1`` of Eq. (1) [mm/V]; negative inverts the law.
    name : str, optional
        How the message names it; default ``"theta0.b1"``.
    """
    if theta0_b1 < 0:
        return (f"{name} = {theta0_b1:g} < 0 inverts the law: more valve opening contracts the muscle, so b1 > 0 "
                "(a model identified with u or l of the other sign?)")
    return "the law's model (theta0, the box C) has the valve's effect the wrong way round for this rig"


def limit_side(u_v: float, u_min_v: float, u_max_v: float) -> int:
    """The valve limit the command ``u_v`` [V] sits at (within 1 nV): -1 the lower, 1 the upper, 0 neither.

    Parameters
    ----------
    u_v : float
        Valve command [V].
    u_min_v, u_max_v : float
        The valve's command limits [V] (Eq. (19)).
    """
    return -1 if u_v <= u_min_v + 1e-9 else 1 if u_v >= u_max_v - 1e-9 else 0


def full_range_jump(u_v: float, u_prev_v: float, u_min_v: float, u_max_v: float) -> bool:
    """Whether the command moved across :data:`GUARD_JUMP_FRACTION` of the valve's range [V] in one
    sample: the valve slammed end to end.

    Parameters
    ----------
    u_v : float
        Valve command at this sample [V].
    u_prev_v : float
        Valve command at the previous sample [V].
    u_min_v, u_max_v : float
        The valve's command limits [V] (Eq. (19)).
    """
    return abs(u_v - u_prev_v) >= GUARD_JUMP_FRACTION * (u_max_v - u_min_v)
