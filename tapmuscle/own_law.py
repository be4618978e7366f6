"""A control law of your own in the project's closed loop: what it must offer, and a watch of its valve.

:func:`tapmuscle.closed_loop.run_closed_loop` and ``tm.simulate_closed_loop`` run the paper's four
controllers; they run any object with a ``step(l_mm, preview_mm)`` method the same way (the
:class:`ControlLaw` protocol), so that a law of one's own is timed, loaded, delayed, recorded and
scored (Eq. (21)) exactly as the paper's methods are, and plotted beside them.

The paper's controllers are watched by :class:`fmu_controller.loop_watch.LoopWatch`, whose messages
name their settings. A law of one's own is watched by :class:`ValveWatch` for what needs no model: a
valve pinned at a limit the error pushes it into, a command held against the error, a valve slammed
end to end, a limit cycle. A PID tuned on the rig without delay limit-cycles under a 0.1-s transport
delay and sits at a valve limit most of the time (docs/control.md, "A PID baseline"); the watch tells it.
"""

from __future__ import annotations

import inspect
import math
import numbers
from typing import Any, Protocol, runtime_checkable

import numpy as np

from fmu_controller.argument_checks import in_sampling_range
from fmu_controller.displacement_control import (HELD_WARN_S, full_range_jump, held_against_error, limit_side,
                                                 pinned_side, settle_samples)
from fmu_controller.loop_watch import (REF_STEP_MM_PER_S, SLAM_JUMPS, SLAM_WINDOW_S, SWINGS, TRACKING_BLOCK_S,
                                       PinnedStretch, ReachWatch, held_message, in_a_row)
from fmu_controller.servo_settings import TABLE5_SERVO
from tapmuscle.io.sampling import TS_RANGE_S

__all__ = ["ControlLaw", "ValveWatch", "LAW_PREVIEW_SAMPLES", "MAX_LAW_PREVIEW_SAMPLES", "as_law", "law_period", "law_preview_samples",
           "law_command", "reset_law"]

#: Future reference samples a law of one's own sees by default, ``[r(k), ..., r(k+5)]``: Table 5's
#: servo horizon ``Hp``, what the paper's default law looks ahead.
LAW_PREVIEW_SAMPLES = int(TABLE5_SERVO["hp"])
#: The longest preview a law of one's own may ask for [samples]: 1000 s at the paper's Ts = 0.1 s,
#: far beyond any receding horizon. The reference builds the preview anew every sample, so a typo
#: (10**9) would fill the memory instead of running.
MAX_LAW_PREVIEW_SAMPLES = 10_000


@runtime_checkable
class ControlLaw(Protocol):
    """What the closed loop needs of a control law: a valve command for each reading.

    ``step(l_mm, preview_mm)`` gets the encoder reading ``l(k)`` [mm] and the reference's preview
    ``[r(k), ..., r(k+n)]`` [mm] (a new array each sample) and returns the command ``u(k)`` [V], held
    until ``t_{k+1}``; a float, or an object with a ``u_v`` attribute (the paper's controllers'
    :class:`~fmu_controller.displacement_control.ControlStep`).

    Optional attributes the loop uses when present: ``reset(l_mm)`` (or ``reset()``), called once
    before the first sample with the plant's reading [mm]; ``ts_s``, the law's sampling period [s];
    ``preview_samples``, the ``n`` of its preview (default :data:`LAW_PREVIEW_SAMPLES`).
    """

    def step(self, l_mm: float, preview_mm: np.ndarray) -> Any:
        """The command ``u(k)`` [V] for this sample.

        Parameters
        ----------
        l_mm : float
            The encoder reading ``l(k)`` [mm].
        preview_mm : ndarray
            The reference ``[r(k), ..., r(k+n)]`` [mm].

        Returns
        -------
        float or object with ``u_v``
            The valve command [V].
        """


class _FunctionLaw:
    """A function ``u = f(l_mm, preview_mm)`` as a :class:`ControlLaw`; the function's own ``ts_s``,
    ``preview_samples`` and ``reset`` attributes, if it has them, are the law's."""

    def __init__(self, function: Any) -> None:
        self.function = function

    def step(self, l_mm: float, preview_mm: np.ndarray) -> Any:
        return self.function(l_mm, preview_mm)

    def __getattr__(self, name: str) -> Any:
        if name in ("ts_s", "preview_samples", "reset"):
            return getattr(self.function, name)
        raise AttributeError(name)


def law_name(law: Any) -> str:
    """How messages name a law: its class's name, or the wrapped function's (``<lambda>``)."""
    if isinstance(law, _FunctionLaw):
        return getattr(law.function, "__name__", type(law.function).__name__)
    return type(law).__name__


def as_law(law: Any) -> ControlLaw:
    """``law`` as a :class:`ControlLaw`: an object with a ``step`` method as it is, a function
    ``u = f(l_mm, preview_mm)`` wrapped (its period then given as ``ts_s``).

    Parameters
    ----------
    law : object
        A control law: an object with a ``step`` method, or a function ``u = f(l_mm,
        preview_mm)``.

    Raises
    ------
    TypeError
        Neither: no ``step`` method and not callable.
    """
    if isinstance(law, type):
        raise TypeError(f"got the class {law.__name__} itself: give the law, an instance ({law.__name__}(...))")
    if callable(getattr(law, "step", None)):
        return law
    if callable(law):
        return _FunctionLaw(law)
    raise TypeError(f"controller must be a DisplacementController (tm.DisplacementController(settings, theta0)) or "
                    f"a law of your own: an object with a step(l_mm, preview_mm) method returning the valve command "
                    f"[V] (tapmuscle.own_law.ControlLaw), or a function u = f(l_mm, preview_mm); got "
                    f"{type(law).__name__}")


def _attribute(law: Any, name: str, given: Any) -> Any:
    """``given`` when not None, else the law's attribute ``name`` (None when it has none)."""
    return given if given is not None else getattr(law, name, None)


def law_period(law: Any, ts_s: float | None) -> float:
    """The loop's sampling period [s] for ``law``: ``ts_s`` when given, else the law's ``ts_s``.

    Parameters
    ----------
    law : object
        The control law; its ``ts_s`` attribute [s], if any, is compared with ``ts_s``.
    ts_s : float or None
        The loop's sampling period as given [s]; None: the law's.

    Raises
    ------
    ValueError
        Neither gives one, or the one given is not a finite number > 0, or both give different ones.
    """
    own = getattr(law, "ts_s", None)
    name = law_name(law)
    if ts_s is None and own is None:
        raise ValueError(f"the law {name} has no ts_s attribute: give the loop's sampling period, ts_s=... [s]")
    lo, hi = TS_RANGE_S
    for what, value in (("ts_s", ts_s), (f"{name}.ts_s", own)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)
                                  or not math.isfinite(value) or in_sampling_range(value) != 0):
            raise ValueError(f"{what} must be a finite number within {lo:g} .. {hi:g} s (the muscle's sampling "
                             f"periods), got {value!r}")
    # a period given in single precision (np.float32(0.1)) is the same period
    if ts_s is not None and own is not None and abs(float(own) - float(ts_s)) > 1e-6 * float(ts_s):
        raise ValueError(f"ts_s = {ts_s!r} s disagrees with the law's own {name}.ts_s = {own!r} s")
    return float(_attribute(law, "ts_s", ts_s))


def law_preview_samples(law: Any, preview_samples: int | None) -> int:
    """The ``n`` of the preview ``r(k..k+n)`` the law gets: ``preview_samples`` when given, else the
    law's ``preview_samples``, else :data:`LAW_PREVIEW_SAMPLES`; an integer in 0 ..
    :data:`MAX_LAW_PREVIEW_SAMPLES` or a ValueError.

    Parameters
    ----------
    law : object
        The control law; its ``preview_samples`` attribute, if any, is used when
        ``preview_samples`` is None.
    preview_samples : int or None
        The preview as given [samples]; None: the law's.
    """
    n = _attribute(law, "preview_samples", preview_samples)
    if n is None:
        return LAW_PREVIEW_SAMPLES
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or not 0 <= n <= MAX_LAW_PREVIEW_SAMPLES:
        raise ValueError(f"preview_samples must be an integer in 0..{MAX_LAW_PREVIEW_SAMPLES} (the future reference "
                         f"samples the law sees), got {n!r}")
    return int(n)


def reset_law(law: Any, l_mm: float) -> None:
    """Call the law's ``reset`` before a run, with the plant's reading [mm] if it takes an argument.

    Parameters
    ----------
    law : object
        The control law; nothing happens when it has no ``reset``.
    l_mm : float
        The plant's reading before the run [mm], passed if ``reset`` takes an argument.
    """
    reset = getattr(law, "reset", None)
    if reset is None:
        return
    if not callable(reset):
        raise TypeError(f"the law's reset is {reset!r}, not a method: define reset(self, l_mm) or reset(self), "
                        "or leave it out")
    try:
        takes_reading = any(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.VAR_POSITIONAL)
                            for p in inspect.signature(reset).parameters.values())
    except (TypeError, ValueError):  # a builtin without a signature: given the reading
        takes_reading = True
    try:
        if takes_reading:
            reset(l_mm)
        else:
            reset()
    except Exception as exc:
        given = f"the reading {l_mm:g} mm" if takes_reading else "nothing"
        exc.add_note(f"in the law's reset before the run (given {given})")
        raise


def law_command(result: Any, k: int, t_s: float, l_mm: float = math.nan, r_mm: float = math.nan) -> float:
    """The command [V] a law's ``step`` returned at sample ``k`` (``t_s`` [s], on the reading ``l_mm``
    and the reference ``r_mm`` [mm], named in the errors): a finite real number, or an object whose
    ``u_v`` is one.

    Parameters
    ----------
    result : object
        What the law's ``step`` returned: a number, or an object with ``u_v``.
    k : int
        Sample index, for the error message.
    t_s : float
        Time of the sample [s], for the error message.
    l_mm : float, optional
        The reading the law was given [mm], for the error message.
    r_mm : float, optional
        The reference at the sample [mm], for the error message.

    Raises
    ------
    TypeError
        Not a number (a string, None, an array of more than one value ...).
    ValueError
        NaN or infinite: the loop stops there, the plant is not driven with it.
    """
    u = getattr(result, "u_v", result)
    if isinstance(u, np.ndarray) and u.size == 1:
        u = u.reshape(())[()]
    where = f"at sample k = {k} (t = {t_s:.12g} s, l = {l_mm:g} mm, r = {r_mm:g} mm)"
    if isinstance(u, bool) or not isinstance(u, numbers.Real):
        what = f"u_v = {u!r}" if u is not result else repr(result)
        hint = " (a list or tuple of one: return its element)" if isinstance(u, (list, tuple)) and len(u) == 1 else ""
        raise TypeError(f"the law's step returned {what} {where}: expected the valve command u [V], a float (or an "
                        f"object with a u_v attribute){hint}")
    u = float(u)
    if not math.isfinite(u):
        raise ValueError(f"the law's step returned u = {u!r} V {where}: a valve command must be finite; the loop "
                         "stops before driving the plant with it")
    return u


class ValveWatch:
    """What a run of a law of one's own tells without a model, sample by sample (each once a run).

    :meth:`observe` after each sample returns its messages, each starting with ``t = ... s:``: the
    command pinned at a valve limit that the error pushes it further into for
    :data:`~fmu_controller.loop_watch.PINNED_S`; held at a limit against an error of 2 mm or more for
    :data:`~fmu_controller.displacement_control.HELD_WARN_S` (a law of the wrong sign); jumping across
    the valve's range :data:`~fmu_controller.loop_watch.SLAM_JUMPS` times within
    :data:`~fmu_controller.loop_watch.SLAM_WINDOW_S`; swinging from one limit to the other
    :data:`~fmu_controller.loop_watch.SWINGS` times within it (a limit cycle; not in the first window
    of the run, nor in the settling time after a reference step); the reference out of the rig's reach
    for seconds of every cycle (:class:`~fmu_controller.loop_watch.ReachWatch`, over 20-s blocks). The thresholds are those of the
    paper's controllers' :class:`~fmu_controller.loop_watch.LoopWatch`.

    Parameters
    ----------
    ts_s : float
        The loop's sampling period [s].
    u_min_v, u_max_v : float
        The valve's command range [V] (the plant's ``valve.u_min_v``, ``valve.u_max_v``).
    """

    def __init__(self, ts_s: float, u_min_v: float, u_max_v: float) -> None:
        self.ts_s, self.u_min_v, self.u_max_v = float(ts_s), float(u_min_v), float(u_max_v)
        if not (math.isfinite(self.ts_s) and self.ts_s > 0):
            raise ValueError(f"ts_s must be a finite number > 0 [s], got {ts_s!r}")
        if not (math.isfinite(self.u_min_v) and math.isfinite(self.u_max_v) and self.u_min_v < self.u_max_v):
            raise ValueError(f"the valve's range u_min_v .. u_max_v must be finite and increasing [V], got "
                             f"{u_min_v!r} .. {u_max_v!r}")
        self._window = int(round(SLAM_WINDOW_S / self.ts_s))
        self.reset()

    def reset(self) -> None:
        """A new run: nothing said yet."""
        self._pinned = PinnedStretch()
        self._reach = ReachWatch()
        self._block_n = 0  # samples of the reach watch's block (after the run's first window)
        self._held_n = 0
        self._jump_ks: list[int] | None = []
        self._swing_ks: list[int] | None = []
        self._last_limit = 0
        self._r_last = math.nan
        self._swings_from = self._window  # not in the run's first window: any law's start-up transient

    def observe(self, k: int, t_s: float, l_mm: float, r_mm: float, u_v: float, u_prev_v: float) -> list[str]:
        """What to tell after sample ``k`` at ``t_s`` [s]: the reading ``l(k)`` and reference ``r(k)``
        [mm] the law stepped on, its command ``u(k)`` and the one before ``u(k-1)`` [V], each as the
        valve takes it (clipped to its range: a law asking 15 V and 45 V in turn holds it at 10 V)."""
        said: list[str] = []
        lo, hi = self.u_min_v, self.u_max_v
        u_v, u_prev_v = min(max(u_v, lo), hi), min(max(u_prev_v, lo), hi)
        message = self._pinned.observe(t_s, l_mm, r_mm, u_v, lo, hi, self.ts_s)
        if message is not None:
            said.append(message)
        if k > self._window:  # in blocks after the run's first window, as the paper controllers' watch
            self._reach.observe(pinned_side(r_mm, l_mm, u_v, lo, hi), r_mm, l_mm, lo, hi, self.ts_s)
            self._block_n += 1
            if self._block_n >= math.ceil(TRACKING_BLOCK_S / self.ts_s - 1e-9):
                message = self._reach.end_block(t_s, self._block_n, self.ts_s, told_pinned=self._pinned.n < 0,
                                                reference="the reference the loop is given")
                self._block_n = 0
                if message is not None:
                    said.append(message)
        if self._held_n >= 0:
            self._held_n, sat_s = in_a_row(self._held_n, bool(held_against_error(r_mm, l_mm, u_v, lo, hi)),
                                           HELD_WARN_S, self.ts_s)
            if sat_s is not None:
                said.append(held_message(t_s, lo if r_mm > l_mm else hi, sat_s, r_mm, l_mm,
                                         "the law acts with the wrong sign, or not on the error at all (on this "
                                         "rig more command contracts the muscle further: l grows with u)"))
        if self._jump_ks is not None and k > 0 and full_range_jump(u_v, u_prev_v, lo, hi):
            self._jump_ks = [j for j in self._jump_ks if j > k - self._window] + [k]
            if len(self._jump_ks) >= SLAM_JUMPS:
                self._jump_ks = None
                said.append(f"t = {t_s:.12g} s: the command has jumped across the valve's range {SLAM_JUMPS} times in "
                            f"{SLAM_WINDOW_S:g} s: the law slams the valve end to end (a gain too high for the rig?)")
        if abs(r_mm - self._r_last) > REF_STEP_MM_PER_S * self.ts_s:
            self._swings_from = max(self._swings_from, k + settle_samples(self.ts_s))
        self._r_last = r_mm
        self._watch_swings(said, k, t_s, u_v)
        return said

    def _watch_swings(self, said: list[str], k: int, t_s: float, u_v: float) -> None:
        """Count the command's swings from one valve limit to the other; tell the :data:`SWINGS`-th
        within :data:`SLAM_WINDOW_S`."""
        if self._swing_ks is None:
            return
        side = limit_side(u_v, self.u_min_v, self.u_max_v)
        if not side:
            return
        swung, self._last_limit = side == -self._last_limit, side
        if not swung or k < self._swings_from:
            return
        self._swing_ks = [j for j in self._swing_ks if j > k - self._window] + [k]
        if len(self._swing_ks) >= SWINGS:
            self._swing_ks = None
            said.append(f"t = {t_s:.12g} s: the valve command has swung from one limit to the other {SWINGS} times in "
                        f"{SLAM_WINDOW_S:g} s, a limit cycle: the loop has more delay than the law tolerates (a "
                        "transport delay on the rig, or loop_delay_samples = 1, a parallel master's sample), or its "
                        "gain is too high for the rig (docs/control.md, \"A PID baseline\"); or the reference moves "
                        "faster than the muscle can follow, and the valve swings with it")
