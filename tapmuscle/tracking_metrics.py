"""The paper's figures of merit for a run: Eq. (21)'s tracking error and how far the valve command's
travel exceeds a smooth one's (chatter).

Eq. (21) is the mean of ``|r(k) - l(k)|`` [mm] over the samples ``k = 101..401`` at the paper's
Ts = 0.1 s, 10.1 s to 40.1 s; at another sampling period the same seconds (:func:`eq21_window`).
A module of its own, without the controllers and the plant, so that what only scores or checks a
run (a scenario file's window, a sweep's metrics) loads neither.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping

import numpy as np

from fmu_controller.argument_checks import sampling_period, whole_number

__all__ = ["eq21_error_mm", "eq21_window", "command_tv_excess", "EQ21_WINDOW", "EQ21_WINDOW_S"]

#: Samples of Eq. (21): k = 101..401, with the sample k at t = k Ts as in Eq. (1), so 10.1-40.1 s at
#: Ts = 0.1 s. The paper's text says "from 10 to 40 s", the same 301 samples counted from 1 (MATLAB's
#: indices); the equation's indices are kept (the samples 100..400 change the paper's cells by at most
#: 0.003 mm).
EQ21_WINDOW = (101, 401)
#: Eq. (21)'s window in seconds, 10.1 s to 40.1 s: the samples 101..401 at the paper's Ts = 0.1 s.
EQ21_WINDOW_S = (10.1, 40.1)


def eq21_window(ts_s: float) -> tuple[int, int]:
    """The samples ``(k0, k1)`` (inclusive) of Eq. (21)'s 10.1..40.1 s at a sampling period ``ts_s``
    [s]: ``(101, 401)`` at the paper's 0.1 s, ``(202, 802)`` at 0.05 s; where those times fall between
    two samples, the nearest (Python's ``round``, half to even: ``(50, 200)`` at 0.2 s, 10.0..40.0 s).

    Parameters
    ----------
    ts_s : float
        Sampling period [s].
    """
    ts_s = sampling_period(ts_s)  # 100 (ms meant) would put the whole window on sample 0
    k0, k1 = (int(round(t / ts_s)) for t in EQ21_WINDOW_S)
    return k0, k1


def eq21_error_mm(r_mm: np.ndarray | Mapping[str, np.ndarray], l_mm: np.ndarray | None = None,
                  window: tuple[int, int] | None = None, *, ts_s: float | None = None) -> float:
    """Eq. (21): ``(1/301) sum_{k=101}^{401} |r(k) - l(k)|`` [mm] at Ts = 0.1 s, the mean of
    ``|r(k) - l(k)|`` over the inclusive window ``k0..k1`` in general.

    Parameters
    ----------
    r_mm : ndarray or mapping
        Reference [mm], one value per sample ``k``; or a whole run (what
        :func:`run_closed_loop` and ``tm.simulate_closed_loop`` return: ``t_s``, ``r_mm``, ``l_mm``),
        whose sampling period then places the default window (``l_mm`` not given).
    l_mm : ndarray
        Displacement [mm], one value per sample ``k`` (with the reference as an array).
    window : (int, int), optional
        First and last sample of the mean, inclusive. Default: the paper's 10 s to 40 s, the samples
        101..401 at Ts = 0.1 s, or :func:`eq21_window` of ``ts_s`` when that is given.
    ts_s : float, optional
        The run's sampling period [s], which puts the default window at 10.1..40.1 s whatever the
        period (at 0.05 s the samples 101..401 are 5.05..20.05 s, the start-up included).

    Raises
    ------
    ValueError
        ``r_mm`` and ``l_mm`` not one-dimensional or of different lengths (a column vector against a
        row broadcast to a matrix and gave a wrong number), a window that is not ``0 <= k0 <= k1``,
        both ``window`` and ``ts_s``, or a run that ends before ``k1``.
    """
    if isinstance(r_mm, Mapping):
        run = r_mm
        missing = [k for k in ("t_s", "r_mm", "l_mm") if k not in run]
        if l_mm is not None or missing:
            raise ValueError("give Eq. (21) a run (a mapping with t_s, r_mm and l_mm) alone, or the arrays r_mm and "
                             "l_mm" + (f"; the run has no {', '.join(missing)}" if missing else ""))
        r_mm, l_mm = run["r_mm"], run["l_mm"]
        t = np.asarray(run["t_s"], dtype=float)
        if window is None and ts_s is None and t.size > 1:
            step = float(t[-1] - t[0]) / (t.size - 1)
            try:
                ts_s = sampling_period(step, what="the run's sampling period (from its t_s)")
            except ValueError as exc:
                raise ValueError(f"{exc} (t_s in seconds from the start, or give ts_s)") from None
    elif l_mm is None:
        raise ValueError("Eq. (21) needs the displacement l_mm beside the reference r_mm (or a whole run)")
    r, l = np.asarray(r_mm, dtype=float), np.asarray(l_mm, dtype=float)
    if r.ndim != 1 or l.ndim != 1 or r.shape != l.shape:
        raise ValueError(f"r_mm and l_mm must be 1-D arrays of the same length (one value per sample k), got "
                         f"shapes {r.shape} and {l.shape}")
    k0, k1 = _window(window, ts_s)
    if not 0 <= k0 <= k1:
        raise ValueError(f"window must be (k0, k1) with 0 <= k0 <= k1, got {tuple(window)}")
    if len(r) <= k1:
        shorter = (f"; or the window this run has, window=({k0}, {len(r) - 1}) (what a scenario's default "
                   "window is cut to)" if k0 < len(r) - 1 else "")
        raise ValueError(f"Eq. (21) needs samples k = 0..{k1} ({k1 + 1} samples), the run has {len(r)}"
                         + ("; a run at another period than 0.1 s: give ts_s, or the run itself "
                            "(eq21_error_mm(run))" if window is None and ts_s is None else "") + shorter)
    for name, x in (("r_mm", r), ("l_mm", l)):
        bad = np.flatnonzero(~np.isfinite(x[k0:k1 + 1]))
        if bad.size:
            raise ValueError(f"{name}[{k0 + int(bad[0])}] = {float(x[k0 + bad[0]])!r} is not finite: Eq. (21)'s mean "
                             f"over samples {k0}..{k1} would be NaN")
    return float(np.mean(np.abs(r[k0:k1 + 1] - l[k0:k1 + 1])))


def _window(window: tuple[int, int] | None, ts_s: float | None) -> tuple[int, int]:
    """The window of :func:`eq21_error_mm` / :func:`command_tv_excess` (one of the two, or the paper's)."""
    if window is not None and ts_s is not None:
        raise ValueError(f"give the window in samples (window = {tuple(window)}) or the sampling period ts_s = "
                         f"{ts_s!r} for Eq. (21)'s 10.1..40.1 s, not both")
    if window is not None:
        if isinstance(window, numbers.Real):  # eq21_error_mm(r, l, 0.1): the period where the window goes
            raise ValueError(f"window must be the samples (k0, k1), got the number {window!r}; for Eq. (21)'s "
                             f"10.1..40.1 s at a sampling period give it by name: ts_s={window!r}")
        k0, k1 = window
        # sample numbers: 101.0 is sample 101; 100.5 would be cut to sample 100 without a word
        return tuple(int(k) if isinstance(k, numbers.Real) and not isinstance(k, bool) and float(k).is_integer()
                     else whole_number(k, what=f"window {tuple(window)}: a sample number") for k in (k0, k1))
    return EQ21_WINDOW if ts_s is None else eq21_window(ts_s)


def command_tv_excess(u_v: np.ndarray, frequency_hz: float, *, ts_s: float = 0.1,
                      window: tuple[int, int] | None = None) -> float:
    """How far the command's total variation in the Eq. (21) window exceeds a smooth command's [-].

    A command that follows a sine reference of ``frequency_hz`` without ripple travels its range twice
    per cycle, so the figure is ``sum |u(k+1) - u(k)| / (2 (max u - min u) f (k1 - k0) Ts) - 1`` over
    ``k = k0..k1``: 0 for a smooth command, 0.1 for one that travels 10 % more (valve chatter).

    Parameters
    ----------
    u_v : ndarray
        Valve command [V], one value per sample ``k``.
    frequency_hz : float
        Frequency of the reference [Hz].
    ts_s : float
        Sampling period [s].
    window : (int, int), optional
        First and last sample, inclusive (default: Eq. (21)'s 10.1..40.1 s at ``ts_s``,
        :func:`eq21_window`; 101..401 at 0.1 s).
    """
    k0, k1 = window if window is not None else eq21_window(ts_s)
    if len(u_v) <= k1:
        raise ValueError(f"the Eq. (21) window needs samples up to k = {k1}, the run has {len(u_v)}")
    u = np.asarray(u_v, dtype=float)[k0:k1 + 1]
    return float(np.sum(np.abs(np.diff(u))) / (2.0 * np.ptp(u) * frequency_hz * (k1 - k0) * ts_s) - 1.0)


