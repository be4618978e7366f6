"""Direct closed loop of the plant and a controller (no FMU); the paper's error measure Eq. (21) with it
(:mod:`tapmuscle.tracking_metrics`).

Timing (one sample ``k``, ``t_k = k Ts``): the encoder reading ``l(k)`` is taken at ``t_k``; the
controller computes ``u(k)`` from ``l(k)`` and the preview ``r(k..k+Hp)``; the valve holds ``u(k)``
(zero-order hold) until ``t_{k+1}``. No extra sample of delay: ``u(k)`` acts on ``l(k+1)``, as in
Eq. (1). Row ``k`` of the result holds ``t_k, r(k), l(k), u(k)``.
"""

from __future__ import annotations

import math
import numbers
from typing import Callable

import numpy as np

from fmu_controller.displacement_control import (REF_STEP_SETTLE_S, REPEAT_MOVE_MM, REPEAT_SPREAD, SPIKE_MM,
                                                 SPIKE_SPREAD, DisplacementController)
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.loop_watch import LoopWatch
from fmu_controller.reference import Reference, as_reference
from fmu_plant import Plant
from fmu_plant.open_loop import run_samples
from fmu_plant.user_warning import warn_at_caller
from tapmuscle.own_law import ControlLaw, ValveWatch, as_law, law_command, law_period, law_preview_samples, reset_law
from tapmuscle.progress import reporter
from tapmuscle.tracking_metrics import EQ21_WINDOW, EQ21_WINDOW_S, command_tv_excess, eq21_error_mm, eq21_window

__all__ = ["run_closed_loop", "eq21_error_mm", "eq21_window", "command_tv_excess", "EQ21_WINDOW", "EQ21_WINDOW_S",
           "ClosedLoopWarning"]


class ClosedLoopWarning(RuntimeWarning):
    """What the watch of a closed loop saw (:class:`fmu_controller.loop_watch.LoopWatch`, or
    :class:`tapmuscle.own_law.ValveWatch` for a law of your own: a limit cycle, a valve pinned or
    slammed, a diverging estimate, a stuck reading) and readings the glitch guard held, warned after
    :func:`run_closed_loop`. Its text carries the run's times and values, so Python's default filter
    shows it for every run: a loop over many runs silences it with
    ``warnings.simplefilter("ignore", tm.ClosedLoopWarning)`` (or ``watch=False``)."""

def _update_load(plant: Plant, load_fn: Callable[[float], float], t_s: float) -> None:
    """The hanging load ``load_fn(t_s)`` [N] on the plant, or an error naming the time."""
    value = load_fn(t_s)
    if isinstance(value, np.ndarray) and value.size == 1:  # np.where(t > 1, 68.0, 44.0) gives a 0-d array
        value = value.reshape(())[()]
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"load_n(t) returned {value!r} at t = {t_s:.12g} s: expected the hanging load [N], a number (a "
                        "function that reaches no return gives None)")
    try:
        plant.update(load_n=value)
    except ValueError as exc:
        exc.add_note(f"load_n(t) at t = {t_s:.12g} s")
        raise


def _found_real(times_s: list[float]) -> str:
    """What the readings after held ones told (``times_s``: the held ones found the muscle's own [s])."""
    if not times_s:
        return ""
    shown = ", ".join(f"{t:.12g}" for t in times_s[:5]) + (", ..." if len(times_s) > 5 else "")
    return (f"; the reading after showed {len(times_s)} of them (t = {shown} s) the muscle's own: it lay nearer the "
            "held one than the prediction (a supply lost or back, a load dropped, a stop reached? or a sensor fault "
            "of two samples or more), and the guards "
            f"held no reading for {REF_STEP_SETTLE_S:g} s after each")


def run_closed_loop(plant: Plant, controller: DisplacementController | ControlLaw,
                    reference: Reference | Callable[[float], float] | np.ndarray | None, *,
                    duration_s: float, load_n: Callable[[float], float] | float | None = None,
                    loop_delay_samples: int = 0,
                    progress: bool | Callable[[int, int], None] | None = None,
                    watch: bool = True, ts_s: float | None = None,
                    preview_samples: int | None = None) -> dict[str, np.ndarray]:
    """Run a new loop for ``duration_s`` from the plant's current physical state.

    The loop runs on the controller's grid ``controller.settings.ts_s``; the controller sees the
    reference's preview ``r(k..k+Hp)`` at every sample. It is a new run: the controller is reset
    (theta0, P(0), its start-up mode), the reference and the returned ``t_s`` start at sample 0,
    whatever the plant's clock says. To continue a run instead, restore both objects' states
    (``get_state``/``set_state``) and step them yourself: ``controller.step(l, reference.preview(k,
    controller.settings.preview_samples))``, then ``plant.step(u, ts)``.

    A law of your own runs the same way (:class:`tapmuscle.own_law.ControlLaw`: an object with
    ``step(l_mm, preview_mm)`` returning the command [V]; ``reset``, ``ts_s`` and
    ``preview_samples`` used when it has them; or a function ``u = f(l_mm, preview_mm)``), so that
    it is timed, loaded, delayed and scored as the paper's methods are.

    Parameters
    ----------
    plant : Plant
        The simulated rig, advanced in place.
    controller : DisplacementController, ControlLaw or callable
        One of the paper's four controllers, reset to the plant's displacement first (its state,
        estimate and start-up mode anew); or a law of your own, whose ``reset(l_mm)`` (or
        ``reset()``), if it has one, is called with the plant's reading first; or a function
        ``u = f(l_mm, preview_mm)`` [V] (its period given as ``ts_s``).
    reference : Reference, callable, array_like or None
        A :class:`fmu_controller.reference.Reference` on the loop's grid (a sine, given samples, a
        function of time); ``r(t)`` [mm] of the time [s]; one value per sample ``r(k)`` [mm]; None:
        the paper's ``35 + 30 sin(2 pi 0.1 t)`` mm (:func:`fmu_controller.reference.as_reference`).
    duration_s : float
        Length of the run [s], finite and > 0; ``round(duration_s / ts) + 1`` samples.
    load_n : float or callable, optional
        Hanging load [N], constant or as a function of time [s].
    loop_delay_samples : {0, 1}
        1 applies each command one sample late (``u`` computed at ``t_k`` drives the valve over
        ``[t_k+1, t_k+2)``, 0 V at first), as a parallel co-simulation master does at a macro step
        of ``Ts``; ``u_v`` then records the command the valve received.
    progress : bool or callable, optional
        ``progress(done, total)`` about every 1 % of the run; True: a report on stderr
        (:class:`tapmuscle.progress.Progress`).
    watch : bool, default True
        Warn (:class:`ClosedLoopWarning`, after the run) of what the controller FMU logs of a loop
        (:class:`fmu_controller.loop_watch.LoopWatch`: a limit cycle, a valve pinned at a limit or
        held against the error, a law slamming the valve, a diverging estimate, a set input delay the
        first 30 s contradict, a stuck reading), each with its time; False: not (a loop run to make
        data). Glitches the guard held and the plant's own notes are warned of either way. A law of
        your own is watched without a model (:class:`tapmuscle.own_law.ValveWatch`: a valve pinned at
        a limit or held against the error, slammed end to end, a limit cycle).
    ts_s : float, optional
        The loop's sampling period [s] for a law of your own (default: its ``ts_s`` attribute; one of
        the two is needed). For the paper's controllers, if given, it must be their
        ``settings.ts_s``.
    preview_samples : int, optional
        A law of your own's preview ``r(k..k+n)``: ``n`` future samples (default: its
        ``preview_samples`` attribute, else :data:`tapmuscle.own_law.LAW_PREVIEW_SAMPLES`, 5). Not
        for the paper's controllers, whose settings decide it.

    Returns
    -------
    dict of ndarray
        ``t_s, r_mm, l_mm`` (the reading the controller had), ``l_true_mm`` (the muscle's displacement
        itself, before the encoder's noise, resolution, drift or backlash: what the reading hides),
        ``u_v, p_mpa, load_n, l_pred_mm`` (the predictor's ``l(k|k-1)``),
        ``pred_error_mm``, ``uc_v``, ``h_mm``, ``xs_mm`` and ``theta_<name>`` for the 15 parameters.
        A law of your own's run has ``t_s, r_mm, l_mm, l_true_mm, u_v, p_mpa, load_n`` (``u_v`` the
        command the valve received: the law's, or with ``loop_delay_samples = 1`` the one of the
        sample before; as given, the valve itself saturating at ``valve.u_min_v..u_max_v``).

    Raises
    ------
    TypeError
        ``controller`` is none of these (no ``step`` method, not callable), or its ``step`` returned
        no number.
    ValueError
        A law's ``step`` returned NaN or an infinite command (with its sample and time), a period or
        preview that is not one (see ``ts_s``, ``preview_samples``), a period longer than the run.
    """
    if not isinstance(plant, Plant):
        raise TypeError(f"plant must be a Plant (tm.Plant(params)), got {type(plant).__name__}")
    own = not isinstance(controller, DisplacementController)
    if own:
        controller = as_law(controller)
        ts = law_period(controller, ts_s)
        hp = law_preview_samples(controller, preview_samples)
    else:
        ts, hp = controller.settings.ts_s, controller.settings.preview_samples
        if preview_samples is not None:
            raise ValueError(f"preview_samples = {preview_samples!r} is for a law of your own: the paper's controllers "
                             f"see the preview their settings need ({hp} samples)")
        if ts_s is not None and not (isinstance(ts_s, numbers.Real) and abs(ts_s - ts) <= 1e-12 * ts):
            raise ValueError(f"ts_s = {ts_s!r} s disagrees with the controller's settings.ts_s = {ts!r} s")
    if loop_delay_samples not in (0, 1) or isinstance(loop_delay_samples, bool):
        raise ValueError(f"loop_delay_samples must be 0 or 1, got {loop_delay_samples!r}")
    if (isinstance(duration_s, bool) or not isinstance(duration_s, numbers.Real) or not math.isfinite(duration_s)
            or duration_s <= 0):
        raise ValueError(f"duration_s must be a finite number > 0 [s], got {duration_s!r}")
    if ts > duration_s:
        # one sample and no loop at all, silently: most likely a period in milliseconds (Ts = 100)
        raise ValueError(f"the loop's sampling period {ts!r} s is longer than the run (duration_s = {duration_s!r} s): "
                         "a period in milliseconds? Give it in seconds")
    progress = reporter(progress, "run_closed_loop")
    reference = as_reference(reference, ts)
    n = run_samples(duration_s, ts)
    in_flight = 0.0
    names = ASYMMETRIC.names
    cols = {k: np.empty(n) for k in ("t_s", "r_mm", "l_mm", "l_true_mm", "u_v", "p_mpa", "load_n") + (
        () if own else ("l_pred_mm", "pred_error_mm", "uc_v", "h_mm", "xs_mm"))}
    theta_hist = np.empty((n, 0 if own else len(names)))
    load_fn = load_n if callable(load_n) else None
    if load_n is not None and load_fn is None:
        plant.update(load_n=load_n)
    meas = plant.measurement
    valve = plant.params.valve
    if own:
        reset_law(controller, meas.l_mm)
        valve_watch = ValveWatch(ts, valve.u_min_v, valve.u_max_v) if watch else None
    else:
        controller.reset(meas.l_mm)
    supervision = LoopWatch(controller) if watch and not own else None
    told: list[str] = []  # what the watch told, as the controller FMU logs it
    u_prev = 0.0
    pred_prev = meas.l_mm
    held_at: list[float] = []  # sample times of the readings the glitch guard held: jumps beyond max_speed ...
    spiked_at: list[float] = []  # ... one-sample spikes from the prediction ...
    repeated_at: list[float] = []  # ... and stale repeats of the last reading
    real: dict[str, list[float]] = {"spike": [], "repeat": []}  # held ones the reading after found the muscle's own
    every = max(1, n // 100)
    try:
        for k in range(n):
            t = k * ts
            if load_fn is not None:
                _update_load(plant, load_fn, t)
            preview = reference.preview(k, hp)
            if own:
                try:
                    result = controller.step(meas.l_mm, preview)
                except Exception as exc:
                    exc.add_note(f"in the law's step at sample k = {k} (t = {t:.12g} s, l = {meas.l_mm:g} mm, "
                                 f"r = {float(preview[0]):g} mm; preview_mm of {len(preview)} samples, "
                                 f"r(k..k+{hp}): preview_samples = {hp})")
                    raise
                u = law_command(result, k, t, meas.l_mm, float(preview[0]))
                if valve_watch is not None:
                    told += valve_watch.observe(k, t, meas.l_mm, float(preview[0]), u, u_prev)
            else:
                step = controller.step(meas.l_mm, preview)
                if supervision is not None:
                    told += supervision.observe(k, t, meas.l_mm, float(preview[0]), step, u_prev)
                u = step.u_v
                cols["l_pred_mm"][k], cols["pred_error_mm"][k] = pred_prev, meas.l_mm - pred_prev
                cols["uc_v"][k], cols["h_mm"][k], cols["xs_mm"][k] = step.uc_v, step.hysteresis_mm, step.xs_mm
                theta_hist[k] = step.theta
                held = controller.reading_held
                if held is not None:
                    (spiked_at if controller.spike_limit_mm is not None else repeated_at if held[0] == held[2]
                     else held_at).append(t)
                if controller.held_reading_real is not None:
                    real[controller.held_reading_real[0]].append(float(cols["t_s"][k - 1]))  # the held one's
                pred_prev = step.predicted_next_mm
            u_prev = u
            if loop_delay_samples:
                u, in_flight = in_flight, u
            cols["t_s"][k], cols["r_mm"][k], cols["l_mm"][k], cols["u_v"][k] = t, reference.at(k), meas.l_mm, u
            cols["p_mpa"][k], cols["load_n"][k], cols["l_true_mm"][k] = meas.p_mpa, plant.load_n, plant.l_mm
            if k + 1 < n:
                meas = plant.step(u, ts)
            if progress is not None and (k % every == 0 or k + 1 == n):
                progress(k + 1, n)
    except Exception:
        for message in told:  # what the watch saw before the run broke off
            warn_at_caller(message, ClosedLoopWarning)
        raise
    for i, name in enumerate(() if own else names):
        cols[f"theta_{name}"] = theta_hist[:, i]
    plant.warn_run_notes(float(np.min(cols["load_n"])))
    for message in told:
        warn_at_caller(message, ClosedLoopWarning)
    if held_at:
        s = controller.settings
        warn_at_caller(f"{len(held_at)} readings (the first at t = {held_at[0]:g} s) were further from the last one used "
                       f"than the muscle moves in a sample (max_speed_mm_per_s x ts_s = {s.max_speed_mm_per_s:g} x "
                       f"{s.ts_s:g} mm) and were taken for sensor glitches: the controller used its prediction instead "
                       "(ControllerSettings.max_speed_mm_per_s; 0 turns this off)", ClosedLoopWarning)
    if spiked_at:
        warn_at_caller(f"{len(spiked_at)} readings (the first at t = {spiked_at[0]:g} s) were further from the one-step "
                       f"prediction than the larger of {SPIKE_MM:g} mm and {SPIKE_SPREAD:g} times its mean error, the two "
                       "readings before within half of that, and were taken for one-sample spikes of the sensor: the "
                       "controller used its prediction instead (ControllerSettings.max_speed_mm_per_s = 0 turns this off)"
                       + _found_real(real["spike"]), ClosedLoopWarning)
    if repeated_at:
        warn_at_caller(f"{len(repeated_at)} readings (the first at t = {repeated_at[0]:.12g} s) repeated the last one to the "
                       f"bit where the one-step prediction had the muscle move more than the larger of {REPEAT_MOVE_MM:g} "
                       f"mm and {REPEAT_SPREAD:g} times its mean error, and were taken for stale samples of the data "
                       "acquisition: the controller used its prediction instead (ControllerSettings.max_speed_mm_per_s "
                       "= 0 turns this off)" + _found_real(real["repeat"]), ClosedLoopWarning)
    return cols
