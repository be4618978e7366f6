"""Open-loop runs of the plant with a command signal (the data behind a recording).

Sampling convention (used by every recording): row ``k`` holds the time ``t_k = k Ts``, the sensor
readings taken at ``t_k`` and the command ``u_k`` applied (zero-order hold) over ``[t_k, t_{k+1})``.
So ``l(k)`` depends on ``u(k-1)``, as in the paper's Eq. (1).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .plant import COMMAND_RANGE_V, Plant

__all__ = ["run_open_loop", "run_samples"]


def run_samples(duration_s: float, ts_s: float, *, names: tuple[str, str] = ("duration_s =", "ts_s =")) -> int:
    """The samples of a run of ``duration_s`` [s] at period ``ts_s`` [s], its start and end included:
    ``duration_s / ts_s + 1``.

    Parameters
    ----------
    duration_s : float
        Length of the run [s].
    ts_s : float
        Sampling period [s].
    names : tuple of str, optional
        How the error message names ``duration_s`` and ``ts_s`` (a command line's options).

    Raises
    ------
    ValueError
        A duration that is not a whole number of periods (to a relative 1e-9): the run would end on the
        grid before or after it without a word (45.05 s at 0.1 s would run 45.0 s); the nearest two named, the
        two values by ``names`` (a command line's options).
    """
    n = int(round(duration_s / ts_s)) + 1
    if abs((n - 1) * ts_s - duration_s) > 1e-9 * max(duration_s, ts_s):
        below = math.floor(duration_s / ts_s) * ts_s
        raise ValueError(f"{names[0]} {duration_s:g} s is not a whole number of sampling periods {names[1]} {ts_s:g} s "
                         f"({duration_s / ts_s:.6g}); the nearest: {below:.12g} and {below + ts_s:.12g} s")
    return n


def run_open_loop(plant: Plant, signal: Callable[[float], float], *, duration_s: float, ts_s: float,
                  load_n: Callable[[float], float] | float | None = None,
                  progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Run ``plant`` from its current state with ``u = signal(t)`` sampled every ``ts_s``.

    Parameters
    ----------
    plant : Plant
        Advanced in place (call ``plant.reset()`` first for a fresh run).
    signal : callable
        Command [V] as a function of time [s].
    duration_s, ts_s : float
        Length of the run and sampling period [s]; ``round(duration_s / ts_s) + 1`` rows.
    load_n : float or callable, optional
        Hanging load [N], constant or as a function of time (load steps during a run).
    progress : callable, optional
        Called as ``progress(done, total)`` about every 1% of the run.

    Returns
    -------
    dict of ndarray
        ``t_s, u_v, l_mm, p_mpa, load_n`` (one row per sample, see module docstring).

    Raises
    ------
    ValueError
        If the duration or period is not positive and finite, the duration not a whole number of
        periods (:func:`run_samples`), or the signal returns a non-finite
        command or one outside :data:`~fmu_plant.plant.COMMAND_RANGE_V` (the message gives the time).
    """
    for name, value in (("duration_s", duration_s), ("ts_s", ts_s)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    n = run_samples(duration_s, ts_s)
    out = {k: np.empty(n) for k in ("t_s", "u_v", "l_mm", "p_mpa", "load_n")}
    load_fn = load_n if callable(load_n) else None
    if load_n is not None and not callable(load_n):
        plant.update(load_n=load_n)
    t0 = plant.t_s
    l_now, p_now = plant.measurement.l_mm, plant.measurement.p_mpa
    every = max(1, n // 100)
    for k in range(n):
        t = t0 + k * ts_s
        if load_fn is not None:
            plant.update(load_n=load_fn(t))
        value = signal(t)
        if np.ndim(value) != 0:
            raise ValueError(f"input signal u(t = {t:.12g} s) returned an array of shape {np.shape(value)}, not one "
                             f"command [V]")
        try:
            u = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"input signal u(t = {t:.12g} s) = {value!r:.60} is not a number [V]") from None
        if not math.isfinite(u):
            raise ValueError(f"input signal gave a non-finite command {u!r} at t = {t:.12g} s")
        if not COMMAND_RANGE_V[0] <= u <= COMMAND_RANGE_V[1]:  # as the plant FMU's input u
            raise ValueError(f"input signal u(t = {t:.12g} s) = {u:g} V is outside the {COMMAND_RANGE_V[0]:g}.."
                             f"{COMMAND_RANGE_V[1]:g} V the plant takes (the valve's 0..10 V, clipped within a volt "
                             "beyond): a command in mV or %?")
        out["t_s"][k], out["u_v"][k], out["l_mm"][k], out["p_mpa"][k] = t, u, l_now, p_now
        out["load_n"][k] = plant.load_n
        if k + 1 < n:
            meas = plant.step(u, ts_s)
            l_now, p_now = meas.l_mm, meas.p_mpa
        if progress is not None and (k % every == 0 or k + 1 == n):
            progress(k + 1, n)
    plant.warn_run_notes(float(np.min(out["load_n"])))
    return out
