"""Figures that check the simulated rig against the paper (the rig's calibration targets: the ranges and
response times the paper's rig shows).

Every function takes plain arrays from a recording (``t_s``, ``u_v``, ``l_mm``), so the same
measurements apply to a simulated recording and to one from a real rig.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LoopBranches", "loop_branches", "LoopFigures", "loop_figures", "settling_time_s",
           "TARGET_RECORDINGS", "TargetCheck", "check_targets"]


@dataclass(frozen=True)
class LoopBranches:
    """Rising and falling branches of a hysteresis loop, averaged over cycles, on a command grid."""

    u_v: np.ndarray
    """Command grid [V]."""
    rising_mm: np.ndarray
    """Mean displacement on the rising-command branch at each grid point [mm] (NaN if not covered)."""
    falling_mm: np.ndarray
    """Mean displacement on the falling-command branch [mm] (NaN if not covered)."""
    monotonic: bool
    """Each branch is monotonic (non-decreasing in ``u``) over the grid, within the tolerance."""
    worst_reversal_mm: float
    """Largest decrease of displacement with increasing command found on either branch [mm]."""


def _segments(u: np.ndarray) -> list[tuple[int, int, int]]:
    """Runs of strictly rising (+1) or falling (-1) command: (start, stop, direction)."""
    du = np.sign(np.diff(u))
    out, start = [], 0
    for k in range(1, len(du) + 1):
        if k == len(du) or du[k] != du[start]:
            if du[start] != 0 and k - start >= 3:
                out.append((start, k + 1, int(du[start])))
            start = k
    return out


def loop_branches(t_s: np.ndarray, u_v: np.ndarray, l_mm: np.ndarray, *, settle_s: float = 30.0,
                  grid_v: np.ndarray | None = None, trim_fraction: float = 0.1,
                  bin_v: float = 0.05, tol_mm: float = 0.05) -> LoopBranches:
    """Split a periodic-input recording into rising/falling branches and average each.

    Parameters
    ----------
    t_s, u_v, l_mm : ndarray
        Time [s], command [V], displacement [mm].
    settle_s : float
        Samples before this time are left out (start-up transient).
    grid_v : ndarray, optional
        Command grid; default 0.05 V steps over the inner ``1 - 2 trim_fraction`` of the input range.
    trim_fraction : float
        Fraction of the input range left out at each end, where the branches reverse.
    bin_v, tol_mm : float
        Monotonicity is judged on bin means of width ``bin_v``; a drop larger than ``tol_mm``
        (noise and quantisation are ~0.01 mm) counts as non-monotonic.
    """
    t_s, u_v, l_mm = (np.asarray(a, dtype=float) for a in (t_s, u_v, l_mm))
    keep = t_s >= settle_s
    u, l = u_v[keep], l_mm[keep]
    lo, hi = float(u.min()), float(u.max())
    span = hi - lo
    if grid_v is None:
        grid_v = np.arange(lo + trim_fraction * span, hi - trim_fraction * span + 1e-9, bin_v)
    curves: dict[int, list[np.ndarray]] = {1: [], -1: []}
    worst = 0.0
    for a, b, d in _segments(u):
        us, ls = u[a:b][::d], l[a:b][::d]  # ascending command
        # The displacement at a command is read where the command passes it (the row's command
        # acts on the next samples, so pair u(k) with l(k+1)).
        if b < len(l):
            ls = l[a + 1:b + 1][::d]
        curves[d].append(np.interp(grid_v, us, ls, left=np.nan, right=np.nan))
        inner = (us >= lo + trim_fraction * span) & (us <= hi - trim_fraction * span)
        if inner.sum() > 4:
            edges = np.arange(us[inner].min(), us[inner].max() + bin_v, bin_v)
            idx = np.digitize(us[inner], edges)
            means = np.array([ls[inner][idx == i].mean() for i in np.unique(idx)])
            if len(means) > 1:
                worst = max(worst, float(np.max(-np.diff(means), initial=0.0)))
    rising = np.nanmean(np.array(curves[1]), axis=0) if curves[1] else np.full_like(grid_v, np.nan)
    falling = np.nanmean(np.array(curves[-1]), axis=0) if curves[-1] else np.full_like(grid_v, np.nan)
    return LoopBranches(grid_v, rising, falling, worst <= tol_mm, worst)


@dataclass(frozen=True)
class LoopFigures:
    """The quasi-static loop figures of the calibration targets (docs/plant.md)."""

    swing_mm: float
    """Peak-to-peak displacement after settling [mm]."""
    min_mm: float
    """Smallest displacement after settling [mm]."""
    max_mm: float
    """Largest displacement after settling [mm]."""
    max_width_mm: float
    """Widest |rising - falling| at equal command [mm]."""
    width_at_mm: dict[float, float]
    """Width at selected commands [mm]."""
    mean_at_mm: dict[float, float]
    """Mean of both branches at selected commands [mm]."""
    monotonic: bool
    """Each branch is monotonic in the command (:attr:`LoopBranches.monotonic`)."""
    worst_reversal_mm: float
    """Largest decrease of displacement with increasing command on either branch [mm]."""


def loop_figures(t_s: np.ndarray, u_v: np.ndarray, l_mm: np.ndarray, *, settle_s: float = 30.0,
                 at_v: tuple[float, ...] = (3.5, 5.0, 6.5)) -> LoopFigures:
    """Swing, widths and branch means of a hysteresis-loop recording (see :func:`loop_branches`).

    Parameters
    ----------
    t_s, u_v, l_mm : ndarray
        Time [s], command [V], displacement [mm].
    settle_s : float, optional
        Samples before this time are left out [s]; default 30.
    at_v : tuple of float, optional
        The commands at which widths and branch means are taken [V].
    """
    br = loop_branches(t_s, u_v, l_mm, settle_s=settle_s)
    keep = np.asarray(t_s) >= settle_s
    l = np.asarray(l_mm)[keep]
    width = np.abs(br.rising_mm - br.falling_mm)
    width_at = {a: float(np.interp(a, br.u_v, width)) for a in at_v}
    mean_at = {a: float(np.interp(a, br.u_v, 0.5 * (br.rising_mm + br.falling_mm))) for a in at_v}
    return LoopFigures(float(l.max() - l.min()), float(l.min()), float(l.max()),
                       float(np.nanmax(width)), width_at, mean_at, br.monotonic, br.worst_reversal_mm)


def settling_time_s(t_s: np.ndarray, l_mm: np.ndarray, *, t_step_s: float, band: float = 0.02,
                    final_window_s: float = 10.0) -> float:
    """Time after ``t_step_s`` until the response stays within ``band`` of the step size [s].

    The final value is the mean over the last ``final_window_s`` seconds of the record, the
    initial value the mean over the second before the step.

    Parameters
    ----------
    t_s : ndarray
        Time [s].
    l_mm : ndarray
        Displacement [mm].
    t_step_s : float
        Time of the step [s].
    band : float, optional
        The band as a fraction of the step size [-]; default 0.02.
    final_window_s : float, optional
        The last seconds of the record that give the final value [s]; default 10.
    """
    t_s, l_mm = np.asarray(t_s, dtype=float), np.asarray(l_mm, dtype=float)
    before = l_mm[(t_s >= t_step_s - 1.0) & (t_s < t_step_s)]
    final = float(l_mm[t_s >= t_s[-1] - final_window_s].mean())
    initial = float(before.mean()) if before.size else float(l_mm[0])
    tol = band * abs(final - initial)
    after = t_s >= t_step_s
    outside = np.nonzero(after & (np.abs(l_mm - final) > tol))[0]
    if outside.size == 0:
        return 0.0
    last = int(outside[-1])
    return float(t_s[min(last + 1, len(t_s) - 1)] - t_step_s)


#: The recordings the calibration targets are measured on: name -> (load [N], input spec, duration [s]).
#: All at Ts = 0.1 s, seed 0, noise on.
TARGET_RECORDINGS: dict[str, tuple[float, str, float]] = {
    "ident_44": (44.0, "sine:bias=5,amp=3,freq=0.1", 240.0),
    "quasi_static_44": (44.0, "sine:bias=5,amp=3,freq=0.01", 240.0),
    "quasi_static_68": (68.0, "sine:bias=5,amp=3,freq=0.01", 240.0),
    "full_range_44": (44.0, "sine:bias=5,amp=5,freq=0.01", 240.0),
    "full_range_68": (68.0, "sine:bias=5,amp=5,freq=0.01", 240.0),
    "step_44": (44.0, "step:initial=4,final=6,at=60", 120.0),
    "max_command_44": (44.0, "const:value=10", 60.0),
    "min_command_68": (68.0, "const:value=0", 60.0),
}


@dataclass(frozen=True)
class TargetCheck:
    """One calibration target: its measured value against its bound.

    Parameters
    ----------
    name : str
        The target, with its unit.
    value : float
        The measured value.
    bound : str
        The bound, in words (``">= 60"``, ``"reported"``).
    ok : bool
        Whether the value meets it.
    """

    name: str
    value: float
    bound: str
    ok: bool


def check_targets(recordings: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
                  settle_s: float = 30.0) -> list[TargetCheck]:
    """Measure the calibration targets on ``{name: (t_s, u_v, l_mm)}`` for
    :data:`TARGET_RECORDINGS` and compare them with their bounds.

    Parameters
    ----------
    recordings : dict of str to (ndarray, ndarray, ndarray)
        ``{name: (t_s, u_v, l_mm)}`` [s, V, mm] for each of :data:`TARGET_RECORDINGS`.
    settle_s : float, optional
        Samples before this time are left out [s]; default 30.
    """
    out: list[TargetCheck] = []

    def add(name: str, value: float, bound: str, ok: bool) -> None:
        out.append(TargetCheck(name, float(value), bound, bool(ok)))

    t, u, l = recordings["ident_44"]
    keep = t >= settle_s
    # A bottom of <= 5 mm here was a target too. On this rig that conflicts with identifying Eq. (1) at
    # 68 N (docs/plant.md, "Range"): we require the 60 mm swing and report the bottom without a bound.
    add("0.1 Hz, 44 N: swing [mm]", np.ptp(l[keep]), ">= 60", np.ptp(l[keep]) >= 60.0)
    add("0.1 Hz, 44 N: max l [mm]", l[keep].max(), ">= 65", l[keep].max() >= 65.0)
    add("0.1 Hz, 44 N: min l [mm] (deviation: target was <= 5)", l[keep].min(), "reported", True)
    for load in (44, 68):
        t, u, l = recordings[f"full_range_{load}"]
        keep = t >= settle_s
        add(f"0..10 V, {load} N: min l [mm]", l[keep].min(), "<= 5", l[keep].min() <= 5.0)
        add(f"0..10 V, {load} N: max l [mm]", l[keep].max(), ">= 65", l[keep].max() >= 65.0)
    extremes = [recordings[k][2] for k in ("max_command_44", "min_command_68", "full_range_44", "full_range_68", "ident_44")]
    lo, hi = min(e.min() for e in extremes), max(e.max() for e in extremes)
    # The encoder's noise (0.01 mm std) may read a few hundredths below the stop at l = 0.
    add("any command: min l [mm]", lo, ">= -0.06 (0 within 6 sigma of encoder noise)", lo >= -0.06)
    add("any command: max l [mm]", hi, "<= 150", hi <= 150.0)
    f44 = loop_figures(*recordings["quasi_static_44"], settle_s=settle_s)
    f68 = loop_figures(*recordings["quasi_static_68"], settle_s=settle_s)
    add("quasi-static 44 N: widest width / swing [%]", 100 * f44.max_width_mm / f44.swing_mm, ">= 5",
        f44.max_width_mm >= 0.05 * f44.swing_mm)
    w35, w65 = f44.width_at_mm[3.5], f44.width_at_mm[6.5]
    asym = abs(w35 - w65) / max(w35, w65)
    add("quasi-static 44 N: |w(3.5 V) - w(6.5 V)| / max [%]", 100 * asym, ">= 30", asym >= 0.30)
    shift = f44.mean_at_mm[5.0] - f68.mean_at_mm[5.0]
    add("quasi-static: mean l(5 V) at 44 N - at 68 N [mm]", shift, ">= 5", shift >= 5.0)
    add("quasi-static 44 N: worst branch reversal [mm]", f44.worst_reversal_mm, "<= 0.05 (monotonic)", f44.monotonic)
    add("quasi-static 68 N: worst branch reversal [mm]", f68.worst_reversal_mm, "<= 0.05 (monotonic)", f68.monotonic)
    t, u, l = recordings["step_44"]
    ts = settling_time_s(t, l, t_step_s=60.0)
    add("step 4 -> 6 V, 44 N: 2% settling time [s]", ts, "1..10", 1.0 <= ts <= 10.0)
    return out
