"""Left-out physics at an FMU's boundary: what a co-simulation master can add around any plant FMU.

None of these needs anything inside the FMU: the master transforms the recorded inputs before it
sets them, and the FMU's output before it is compared with the measurement. Every function is pure
numpy on one signal, sampled as a recording is (row ``k``: the input held over ``[t_k, t_{k+1})``,
the output measured at ``t_k``).

Applied in this order (:func:`apply_input_effects`): transport delay (the command arrives late),
static input map (the actuator's characteristic), backlash (mechanical play at the actuator's
input). The output: ``gain * y + offset + drift * t``.

Parameter keys are ``"<variable>:<name>"`` (a colon cannot appear in an FMI variable's Modelica
name outside quotes, so they never collide with the FMU's own parameters).
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from fmu_plant.effect_library import backlash_operator

__all__ = ["fractional_delay", "input_map", "map_knots", "identity_map", "dead_band_map", "backlash",
           "window_profile", "apply_input_effects", "apply_output_effects", "MAP_FIELDS", "WINDOW_RAMP_SAMPLES",
           "input_defaults", "secondary_defaults", "output_defaults"]

#: The map's six coordinates (all box-bounded, so any value set is a monotone map): the first knot's
#: input, the gap to the second knot, the output at the low end of the range, and the rises over the
#: three pieces (low end -> knot 1 -> knot 2 -> high end).
MAP_FIELDS = ("map_k1_in", "map_gap", "map_out_lo", "map_rise1", "map_rise2", "map_rise3")

#: A secondary input's window ramps in and out over this many samples (a step would make the fit's
#: cost piecewise constant in the window's edges).
WINDOW_RAMP_SAMPLES = 5


def fractional_delay(u: np.ndarray, delay_s: float, ts_s: float) -> np.ndarray:
    """``u`` delayed by ``delay_s`` [s], any fraction of a sample.

    A held input delayed by ``m + f`` samples is held at ``u[k-m]`` for the first ``1 - f`` of
    the step and at ``u[k-m-1]`` for the rest; a master that sets one value per step gives the
    step's mean, ``(1 - f) u[k-m] + f u[k-m-1]`` (exact for a plant that integrates its input
    linearly over a step). Before the recording starts, the input is ``u[0]``.

    Parameters
    ----------
    u : ndarray
        The input, one value per sample.
    delay_s : float
        The delay [s] (negative counts as 0).
    ts_s : float
        Sampling period [s].
    """
    d = max(0.0, float(delay_s)) / ts_s
    if d == 0.0:
        return np.asarray(u, float).copy()
    m = int(math.floor(d))
    f = d - m
    n = len(u)
    idx = np.arange(n)
    a = np.asarray(u, float)[np.clip(idx - m, 0, n - 1)]
    b = np.asarray(u, float)[np.clip(idx - m - 1, 0, n - 1)]
    return (1.0 - f) * a + f * b


def map_knots(values: Mapping[str, float], lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """The knots ``(inputs, outputs)`` of the map with coordinates ``values`` (``MAP_FIELDS``) on the
    input range ``[lo, hi]``.

    Parameters
    ----------
    values : mapping of str to float
        The map's coordinates by name (``MAP_FIELDS``).
    lo, hi : float
        The input's range, in its unit.
    """
    k1 = min(max(values["map_k1_in"], lo), hi)
    k2 = min(k1 + max(values["map_gap"], 0.0), hi)
    o0 = values["map_out_lo"]
    o1 = o0 + max(values["map_rise1"], 0.0)
    o2 = o1 + max(values["map_rise2"], 0.0)
    o3 = o2 + max(values["map_rise3"], 0.0)
    return np.array([lo, k1, k2, hi]), np.array([o0, o1, o2, o3])


def input_map(u: np.ndarray, values: Mapping[str, float], lo: float, hi: float) -> np.ndarray:
    """The monotone piecewise-linear map of :func:`map_knots` applied to ``u`` (constant beyond the
    range's ends).

    Parameters
    ----------
    u : ndarray
        The input.
    values : mapping of str to float
        The map's coordinates by name (``MAP_FIELDS``).
    lo, hi : float
        The input's range, in its unit.
    """
    xs, ys = map_knots(values, lo, hi)
    return np.interp(u, xs, ys)


def identity_map(lo: float, hi: float) -> dict[str, float]:
    """Map coordinates of the identity on ``[lo, hi]`` (knots at a third and two thirds).

    Parameters
    ----------
    lo, hi : float
        The input's range, in its unit.
    """
    third = (hi - lo) / 3.0
    return {"map_k1_in": lo + third, "map_gap": third, "map_out_lo": lo, "map_rise1": third,
            "map_rise2": third, "map_rise3": third}


def dead_band_map(center: float, width: float, lo: float, hi: float) -> dict[str, float]:
    """Map coordinates of a dead band of ``width`` centred at ``center`` (slope 1 outside it, the
    output pulled towards the centre by half the width: ``u -+ width/2``) on ``[lo, hi]``.

    Parameters
    ----------
    center : float
        Centre of the band, in the input's unit.
    width : float
        Width of the band, in the input's unit.
    lo, hi : float
        The input's range, in its unit.
    """
    a = min(max(center - width / 2.0, lo), hi)
    b = min(max(center + width / 2.0, a), hi)
    return {"map_k1_in": a, "map_gap": b - a, "map_out_lo": lo + (b - a) / 2.0, "map_rise1": a - lo,
            "map_rise2": 0.0, "map_rise3": hi - b}


def backlash(u: np.ndarray, width: float) -> np.ndarray:
    """``u`` through a play of total ``width`` (the output follows once the input has crossed half the
    width beyond it; starts at ``u[0]``).

    Parameters
    ----------
    u : ndarray
        The input.
    width : float
        Total play, in the input's unit; <= 0 returns a copy of ``u``.
    """
    if width <= 0.0:
        return np.asarray(u, float).copy()
    out = np.empty(len(u))
    half = 0.5 * width
    state = float(u[0])
    for k, x in enumerate(np.asarray(u, float).tolist()):
        state = backlash_operator(x, state, half)
        out[k] = state
    return out


def window_profile(t_s: np.ndarray, depth: float, start_s: float, end_s: float, ts_s: float) -> np.ndarray:
    """``depth`` between ``start_s`` and ``end_s`` [s], 0 elsewhere, with linear ramps of
    :data:`WINDOW_RAMP_SAMPLES` samples (a secondary input's temporary change).

    Parameters
    ----------
    t_s : ndarray
        Time [s].
    depth : float
        The change inside the window, in the input's unit.
    start_s, end_s : float
        The window [s]; none when ``end_s <= start_s``.
    ts_s : float
        Sampling period [s] (the ramps' length).
    """
    ramp = WINDOW_RAMP_SAMPLES * ts_s
    up = np.clip((t_s - start_s) / ramp, 0.0, 1.0)
    down = np.clip((end_s - t_s) / ramp, 0.0, 1.0)
    return depth * np.minimum(up, down) * (end_s > start_s)


def input_defaults(var: str, lo: float, hi: float) -> dict[str, float]:
    """The "off" values of a recorded input's boundary effects (no delay, identity map, no play).

    Parameters
    ----------
    var : str
        The FMU input's name.
    lo, hi : float
        The input's range, in its unit.
    """
    return {f"{var}:delay_s": 0.0, f"{var}:backlash": 0.0} | {f"{var}:{k}": v for k, v in identity_map(lo, hi).items()}


def secondary_defaults(var: str) -> dict[str, float]:
    """The "off" values of an unrecorded input's change (none).

    Parameters
    ----------
    var : str
        The FMU input's name.
    """
    return {f"{var}:change": 0.0, f"{var}:start_s": 0.0, f"{var}:end_s": 0.0}


def output_defaults(var: str) -> dict[str, float]:
    """The "off" values of an output's sensor effects (gain 1, no offset, no drift).

    Parameters
    ----------
    var : str
        The output variable's name.
    """
    return {f"{var}:gain": 1.0, f"{var}:offset": 0.0, f"{var}:drift_per_min": 0.0}


def apply_input_effects(u: np.ndarray, var: str, values: Mapping[str, float], ts_s: float, lo: float,
                        hi: float) -> np.ndarray:
    """A recorded input ``u`` of FMU input ``var`` with its boundary effects (delay, map, play) as
    ``values`` state (keys ``"<var>:..."``; missing ones are off).

    Parameters
    ----------
    u : ndarray
        The recorded input.
    var : str
        The FMU input's name.
    values : mapping of str to float
        The parameter set (keys ``"<var>:delay_s"``, ``"<var>:backlash"`` and the map's
        coordinates).
    ts_s : float
        Sampling period [s].
    lo, hi : float
        The input's range, in its unit.
    """
    out = np.asarray(u, float)
    d = values.get(f"{var}:delay_s", 0.0)
    if d > 0.0:
        out = fractional_delay(out, d, ts_s)
    m = {k: values[f"{var}:{k}"] for k in MAP_FIELDS if f"{var}:{k}" in values}
    if len(m) == len(MAP_FIELDS) and m != identity_map(lo, hi):
        out = input_map(out, m, lo, hi)
    w = values.get(f"{var}:backlash", 0.0)
    if w > 0.0:
        out = backlash(out, w)
    return out


def apply_output_effects(y: np.ndarray, var: str, values: Mapping[str, float], t_s: np.ndarray) -> np.ndarray:
    """The FMU's output ``y`` of variable ``var`` as its sensor reads it: ``gain * y + offset + drift * t``.

    Parameters
    ----------
    y : ndarray
        The FMU's output.
    var : str
        The output variable's name.
    values : mapping of str to float
        The parameter set (keys ``"<var>:gain"``, ``"<var>:offset"``, ``"<var>:drift_per_min"``;
        missing ones are off).
    t_s : ndarray
        Time [s] of the samples.
    """
    g = values.get(f"{var}:gain", 1.0)
    c = values.get(f"{var}:offset", 0.0)
    r = values.get(f"{var}:drift_per_min", 0.0)
    if g == 1.0 and c == 0.0 and r == 0.0:
        return y
    return g * y + c + r / 60.0 * (t_s[:len(y)] - t_s[0])
