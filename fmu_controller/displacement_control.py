"""The paper's four displacement controllers (sections 3-4, Figs. 6-7, Tables 5 and 8).

=============  ==========================  ==========================================================
method         predictor                   control law
=============  ==========================  ==========================================================
``mpc_ucp``    Eq. (1), fixed theta        unique coincidence point, Eq. (11)-(14) (ucp_mpc.py)
``mpc_servo``  Eq. (2), fixed theta        servo QP, Eq. (15)-(20), with hysteresis cancellation Eq. (5)
``ampc_ucp``   Eq. (1), constrained RLS    as ``mpc_ucp``, theta from Algorithm 1 every step (Fig. 7)
``ampc_servo`` Eq. (2), constrained RLS    as ``mpc_servo``, a1, a2, b1 and H(k) from Algorithm 1 (Fig. 6)
=============  ==========================  ==========================================================

The fixed predictors use ``theta0``, the paper's preliminary identification at 44 N (section 4.2).
The adaptive ones start from ``theta0`` with ``P(0)`` from Table 5 (Table 8 for 0.2 Hz) and keep
``(a1, a2, b1)`` in the Table 2 box from the first step.

Per sample ``k`` (:meth:`DisplacementController.step`)::

    phi(k-1) from the history                              (u(k-1) is what the valve received)
    AMPC: theta(k) = constrained RLS update with l(k)        Eq. (4), Algorithm 1
    v(k) = l(k) - [a1 l(k-1) + a2 l(k-2) + b1 u(k-1)]        section 2.3
    UCP:   u(k) = u(k-1) + (r(k+Hp) - l_f) / S(Hp)          Eq. (13)-(14), clipped to 0-10 V
    servo: H(k) = theta_h^T phi_h(k)                         "y_hy(k) + y_hy(k-1)" of Eq. (5)
           u_c(k) = QP(l(k), l(k-1), u_c(k-1), x_s(k), r(k..k+Hp), H/b1)   Eq. (15)-(20)
           u(k) = u_c(k) - H(k)/b1                           Eq. (5)
           x_s(k+1) = x_s(k) + r(k) - l(k)                   Eq. (18)

Three departures from the paper are on by default, each documented on its setting and measured in
docs/control.md: the start-up mode (``ControllerSettings.startup_s``: reference lead-in, estimator
warm-up and blend), the hysteresis notch (``ControllerSettings.hysteresis_notch``: the servo
methods cancel a centred 5-point mean of ``H`` instead of ``H(k)``) and conditional integration
(``ControllerSettings.anti_windup``: the servo integrator of Eq. (18) holds while the command sits
at a valve limit the error pushes it into). ``startup_s=0``, ``hysteresis_notch=False`` and
``anti_windup=False`` (with ``input_delay_samples=0``, this class's default) is the paper's
controller. Its sensor guards (``max_speed_mm_per_s``) stay on: they act only on a reading the muscle
cannot make (a glitch, a one-sample spike), never on the paper's runs (the 16 runs of 4 methods, 44
and 68 N, 0.1 and 0.2 Hz give the same commands bit for bit with ``max_speed_mm_per_s=0``).

Lifecycle as osqp's: construct (setup), :meth:`reset` with the first measurement, :meth:`step` every
sample; :meth:`get_state`/:meth:`set_state` for exact rewind (FMU state).

Its parts in their own modules: the settings (:mod:`fmu_controller.controller_settings`), the guards on
the reading (:mod:`fmu_controller.reading_guards`), the input-delay hypotheses' scores
(:mod:`fmu_controller.input_delay_scores`), the valve-limit tests (:mod:`fmu_controller.valve_limits`);
their names import from here too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from .controller_settings import (DEFAULT_DELAY_MOVE_WEIGHT, DEFAULT_PROBING_V, DEFAULT_STARTUP_S,
                                  MAX_DELAY_MOVE_WEIGHT, MAX_PROBING_V, MAX_STARTUP_S, MIN_FORGETTING, P0_TABLE5,
                                  P0_TABLE8, ControllerSettings, preview_lead)
from .delay_predictor import DelayPredictor
from .hysteresis_model import ASYMMETRIC, ModelState
from .identification import PAPER_TS_S
from .input_delay_scores import (AUTO_INPUT_DELAY_SAMPLES, DELAY_CHECK_SAMPLES, DELAY_CLEAR_RATIO,
                                 DELAY_DECIDE_BY_SAMPLES, DELAY_FORGET, DELAY_LEAD_SAMPLES, DELAY_MIN_SAMPLES,
                                 DELAY_RATIO, DELAY_SCORES_TS_S, DELAY_TIE_RATIO, DelayScores)
from .methods import METHOD_CODES, METHODS
from .prediction import MAX_INPUT_DELAY_SAMPLES, guard_bounds
from .probing import probe_v
from .reading_guards import (DEFAULT_MAX_SPEED_MM_PER_S, FASTEST_MUSCLE_MM_PER_S, HELD_READINGS_MAX, L_RANGE_MM,
                             REF_STEP_SETTLE_S, REPEAT_MOVE_MM, REPEAT_SPREAD, SPIKE_AFTER_S, SPIKE_FORGET,
                             SPIKE_MEAN_CAP, SPIKE_MM, SPIKE_SPREAD, STUCK_AT_LIMIT_S, ReadingGuard, held_reading_message,
                             real_move_message, settle_samples, stuck_reading_message)
from .rls import TABLE2_LOWER, TABLE2_UPPER, ConstrainedRLS, RLSSettings
from .servo_mpc import ServoMPC, integrator_step
from .ucp_mpc import held_input_run, ucp_move
from .valve_limits import (GUARD_JUMP_FRACTION, GUARD_JUMPS, HELD_AGAINST_MM, HELD_WARN_S, VALVE_MAX_V,
                           VALVE_MIN_V, full_range_jump, held_against_cause, held_against_error, limit_side,
                           pinned_side, pushed_at_limit)

__all__ = ["METHODS", "METHOD_CODES", "MAX_STARTUP_S", "MAX_DELAY_MOVE_WEIGHT", "MAX_INPUT_DELAY_SAMPLES",
           "AUTO_INPUT_DELAY_SAMPLES", "DELAY_FORGET", "DELAY_RATIO", "DELAY_MIN_SAMPLES", "DELAY_TIE_RATIO",
           "HOLD_AFTER_SAMPLES", "B1_KEPT_FRACTION", "GUARD_JUMP_FRACTION", "GUARD_JUMPS", "pushed_at_limit", "pinned_side", "limit_side",
           "full_range_jump", "preview_lead", "VALVE_MIN_V", "VALVE_MAX_V", "MIN_FORGETTING", "HELD_AGAINST_MM",
           "SPIKE_MM", "SPIKE_SPREAD", "SPIKE_MEAN_CAP", "SPIKE_FORGET", "SPIKE_AFTER_S", "REPEAT_MOVE_MM", "REPEAT_SPREAD",
           "REF_STEP_SETTLE_S", "settle_samples",
           "L_RANGE_MM", "FASTEST_MUSCLE_MM_PER_S", "DEFAULT_MAX_SPEED_MM_PER_S", "HELD_READINGS_MAX",
           "STUCK_AT_LIMIT_S", "stuck_reading_message", "DEFAULT_DELAY_MOVE_WEIGHT",
           "HELD_WARN_S", "held_against_error", "held_against_cause", "held_reading_message", "real_move_message",
           "P0_TABLE5", "P0_TABLE8", "ControllerSettings", "ControlStep",
           "DisplacementController", "DEFAULT_STARTUP_S", "DEFAULT_PROBING_V", "MAX_PROBING_V", "DELAY_CLEAR_RATIO",
           "DELAY_DECIDE_BY_SAMPLES", "DELAY_CHECK_SAMPLES", "DELAY_LEAD_SAMPLES", "DELAY_SCORES_TS_S"]


#: ``ControllerSettings.anti_windup``: the integrator of Eq. (18) is held once the command has sat at
#: a valve limit that the error pushes it into for this many samples in a row (0.5 s at Ts = 0.1 s).
HOLD_AFTER_SAMPLES = 5

#: The adaptive estimate of ``b1`` keeps theta0's sign and at least this fraction of its size, whatever
#: the box C: more valve opening contracts the muscle more, and an estimate that crosses zero inverts
#: the law, which then holds the valve at the wrong limit for good (a loop run under a wrong
#: transport delay at Ts = 0.05 s, where C is unbounded by default: 39 mm of Eq. (21) error, the
#: valve at 10 V from 2.5 s on). Table 2's lower bound is 0.75 of THETA0_44N's b1, so under the
#: paper's C this bound never acts.
B1_KEPT_FRACTION = 0.25

#: ``hysteresis_notch``: the predicted H(k+1|k), H(k+2|k) stay within one and two times
#: ``NOTCH_RATE_FACTOR x`` (the larger of H's last two changes) ``+ NOTCH_FLOOR_MM`` of H(k) [mm].
#: In tracking (the paper's sines, both loads) the predictions move under 0.5 mm per sample and the
#: bound never acts; after a large reference step, unbounded on the adaptive estimate's jump, they
#: reach hundreds to thousands of mm, the QP input u_c thousands of volts, and the valve slams shut
#: for a sample.
NOTCH_RATE_FACTOR = 2.0
NOTCH_FLOOR_MM = 1.0


def _keep_gain_sign(settings: ControllerSettings, b1: float) -> tuple[dict[str, float], dict[str, float]]:
    """The box C that Algorithm 1 projects on: ``settings``' box, with ``b1`` kept on the side of
    :data:`B1_KEPT_FRACTION` times theta0's ``b1`` [mm/V] away from zero (its sign kept)."""
    lower, upper = dict(settings.box_lower), dict(settings.box_upper)
    kept = B1_KEPT_FRACTION * b1
    if b1 > 0.0:
        lower["b1"] = max(lower.get("b1", -math.inf), kept)
    else:
        upper["b1"] = min(upper.get("b1", math.inf), kept)
    return lower, upper


def _smoothstep(x: float) -> float:
    """``3x^2 - 2x^3`` on [0, 1] (0 below, 1 above): 0 -> 1 with zero slope at both ends."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class ControlStep:
    """What the controller did at one sample (diagnostics for plots and the FMU)."""

    u_v: float
    """Valve command ``u(k)`` [V], within 0-10 V."""
    predicted_next_mm: float
    """The predictor's one-step prediction ``l(k+1|k)`` [mm] (servo: linear model Eq. (2) with
    ``u_c``; UCP: Eq. (1) with ``u``). Under an input delay (``input_delay_samples`` >= 1, or -1 once
    it decided for one) Eq. (1) under the commands in flight, plus the residual correction with
    ``delay_correction`` (:class:`~fmu_controller.delay_predictor.DelayPredictor`)."""
    prediction_error_mm: float
    """``l(k) - l(k|k-1)`` [mm] (0 at the first step)."""
    uc_v: float
    """Servo: ``u_c(k)`` [V]; UCP: equal to ``u(k)``."""
    hysteresis_mm: float
    """The hysteresis term [mm] that Eq. (5) cancels: ``H(k)``, or with the hysteresis notch
    (:attr:`ControllerSettings.hysteresis_notch`) its 5-point mean about ``k``; 0 for UCP."""
    xs_mm: float
    """Integrator state ``x_s(k+1)`` [mm]: the sum of the errors ``r - l``, one per sample (Eq. 18; 0 for UCP)."""
    theta: np.ndarray
    """Predictor parameters used at this step."""
    saturated: bool
    """An input limit was active."""


def _read_only(a: np.ndarray) -> np.ndarray:
    """``a``, made read-only (it is handed out with every :class:`ControlStep`)."""
    a.flags.writeable = False
    return a

_new_object = object.__new__
_set_attribute = object.__setattr__


def _control_step(u_v, predicted_next_mm, prediction_error_mm, uc_v, hysteresis_mm, xs_mm, theta,
                  saturated) -> ControlStep:
    """``ControlStep(...)`` at half the cost of the frozen dataclass's ``__init__`` (same object)."""
    step = _new_object(ControlStep)
    _set_attribute(step, "__dict__", {
        "u_v": u_v, "predicted_next_mm": predicted_next_mm, "prediction_error_mm": prediction_error_mm,
        "uc_v": uc_v, "hysteresis_mm": hysteresis_mm, "xs_mm": xs_mm, "theta": theta, "saturated": saturated})
    return step


def _restored_controller(cls: type[DisplacementController], settings: ControllerSettings, theta0: Sequence[float],
                         state: Mapping[str, Any]) -> DisplacementController:
    """A :class:`DisplacementController` (of class ``cls``, a subclass taking the same arguments) built
    from ``settings`` and ``theta0``, at ``state`` (copying, unpickling)."""
    controller = cls(settings, theta0)
    controller.set_state(state)
    return controller


class DisplacementController:
    """One of the paper's four controllers (see module docstring).

    Parameters
    ----------
    settings : ControllerSettings
    theta0 : sequence of 15 float or mapping
        Eq. (1) parameters from the preliminary identification: in the asymmetric model's order (as
        ``IdentificationReport.theta``) or all 15 by name (as its ``theta_dict``).
    """

    def __init__(self, settings: ControllerSettings, theta0: Sequence[float] | Mapping[str, float]) -> None:
        if not isinstance(settings, ControllerSettings):
            raise ValueError(f"settings must be ControllerSettings, got {type(settings).__name__}")
        theta0 = ASYMMETRIC.as_theta(theta0, what="theta0")
        if abs(theta0[2]) < 1e-6:
            raise ValueError(f"theta0's b1 must not be ~0 (it divides the hysteresis cancellation, Eq. 5), got {float(theta0[2])!r}")
        if settings.adaptive:
            # Algorithm 1 keeps the estimate in C; a start outside it would be in the law, outside C,
            # for the start-up mode's 12 s
            for name, lo, hi in zip(ASYMMETRIC.names, *settings.constraint_region()):
                v, lo, hi = float(theta0[ASYMMETRIC.index(name)]), float(lo), float(hi)
                if not lo - 1e-9 * max(1.0, abs(lo)) <= v <= hi + 1e-9 * max(1.0, abs(hi)):
                    # Table 2's box holds at Ts = 0.1 s: a theta0 of another period falls outside it
                    table2 = dict(settings.box_lower) == TABLE2_LOWER and dict(settings.box_upper) == TABLE2_UPPER
                    if not table2:
                        period = ""
                    elif abs(settings.ts_s - PAPER_TS_S) > 1e-3 * PAPER_TS_S:
                        # the box, not theta0, is of another period: Table 2's defaults stay at any Ts
                        period = (f"; the box is Table 2's, which holds at Ts = {PAPER_TS_S:g} s, and this controller "
                                  f"samples at Ts = {settings.ts_s:.6g} s: give your identification's box "
                                  "(box_lower/box_upper, empty for none, in the controller FMU box_lower.*/box_upper.* "
                                  "= -inf/inf; an identification file carries its Ts and box: give the file, not its "
                                  "theta alone)")
                    else:
                        period = (f"; or theta0 was identified at another sampling period than this controller's Ts = "
                                  f"{settings.ts_s:g} s (an identification file carries its Ts and box: give the file, "
                                  "not its theta alone)")
                    raise ValueError(f"theta0's {name} = {v!r} lies outside the constraint region C, {lo!r}..{hi!r} "
                                     "(Table 2 unless box_lower/box_upper say otherwise): start the adaptive "
                                     f"controller inside it, or widen the box{period}")
        self.settings = settings
        self.theta0 = _read_only(theta0.copy())
        self._rls: ConstrainedRLS | None = None
        if settings.adaptive:
            lower, upper = _keep_gain_sign(settings, float(theta0[2]))
            self._rls = ConstrainedRLS(ASYMMETRIC, RLSSettings(
                p0=settings.p0, theta0=tuple(theta0), forgetting=settings.forgetting,
                covariance_ceiling=settings.covariance_ceiling, box_lower=lower, box_upper=upper,
                # the box from the first step (the identification's waits 120 s): the estimate starts
                # inside it, and Eq. (5) divides by b1 from the first sample
                constraint_start_s=0.0, ts_s=settings.ts_s))
        self._servo = ServoMPC(settings.servo_for_delay(settings.input_delay_samples), a1=theta0[0], a2=theta0[1],
                               b1=theta0[2]) if settings.servo_mechanism else None
        # per-step constants (the settings are frozen)
        self._need = settings.preview_samples + 1
        self._law_n = self._need - preview_lead(settings.input_delay_samples)  # r(k..k+Hp) the law takes
        self._ucp_hp = settings.ucp.hp
        self._u_min, self._u_max = settings.servo.u_min_v, settings.servo.u_max_v  # the servo law's, Eq. (19)
        law = settings.servo if settings.servo_mechanism else settings.ucp
        self._law_bounds = (law.u_min_v, law.u_max_v)  # the valve limits the method's own law keeps
        self._anti_windup = settings.anti_windup
        self._auto = settings.input_delay_samples == -1
        # the largest delay scored (-1's hypotheses, a set delay's check): a set delay beyond -1's reach
        # is scored too, so that delay_evidence can weigh it against the others
        self._scores = DelayScores(self.theta0, AUTO_INPUT_DELAY_SAMPLES if self._auto else
                                   max(AUTO_INPUT_DELAY_SAMPLES, settings.input_delay_samples), settings.ts_s)
        notch = settings.hysteresis_notch
        if notch is None:
            notch = not settings.adaptive or settings.startup_s > 0
        self._notch = settings.servo_mechanism and notch
        # start-up mode: reference lead-in over T/4, theta0 in the law until T/2, blend until T
        self._ramp_n = int(round(0.25 * settings.startup_s / settings.ts_s))
        self._warm_n = int(round(0.5 * settings.startup_s / settings.ts_s))
        self._blend_n = int(round(settings.startup_s / settings.ts_s))
        self._probing_v = settings.probing_v if settings.adaptive and self._warm_n > 0 else 0.0
        self._probing_phase = settings.probing_phase
        self._guard = settings.startup_guard and settings.adaptive and self._blend_n > 0
        self._readings = ReadingGuard(settings.max_speed_mm_per_s * settings.ts_s, settings.ts_s, self._need,
                                      *self._law_bounds)
        self._delay_predictor = DelayPredictor() if settings.delay_correction and settings.input_delay_samples else None
        self.reset(0.0)

    def __reduce__(self) -> tuple[Any, ...]:
        # The QP solver (osqp) and the estimator's read-only box cannot be pickled, and a copy sharing
        # them would step both controllers at once: a copy or an unpickled controller is built anew
        # from its settings and theta0 and continues from get_state, bit for bit (copy.copy as well).
        return (_restored_controller, (type(self), self.settings, self.theta0.tolist(), self.get_state()))

    # ------------------------------------------------------------------ lifecycle
    def reset(self, l0_mm: float) -> None:
        """Start over with the muscle at ``l0_mm`` [mm] and the valve at 0 V."""
        l0 = float(l0_mm)
        if not math.isfinite(l0):
            raise ValueError(f"l0_mm must be finite, got {l0_mm!r}")
        self.theta = _read_only(self.theta0.copy())
        self._theta_list = self.theta.tolist()
        if self._rls is not None:
            self._rls.setup(ASYMMETRIC, self._rls.settings)
        if self._servo is not None:
            self._servo.update_model(*self.theta[:3])
        self._state = ModelState(ASYMMETRIC, l_init=(l0, l0, l0), u_init=0.0)
        self._k = 0
        self._est_from = 0  # the sample the estimator (re)started at: the start-up mode's clock
        self._jumps = 0  # full-range jumps of the command in the start-up mode (startup_guard)
        self._guarded_at: int | None = None  # the sample the guard ended the start-up mode's law at
        self._l_start = l0
        self._u_prev = 0.0
        self._uc_prev = 0.0
        self._xs = 0.0
        self._limit_run = 0  # samples in a row at a valve limit the error pushes into (_integrate)
        self._h_prev = self._h_prev2 = math.nan  # H(k-1), H(k-2) for hysteresis_notch (NaN: none yet)
        self._predicted = math.nan
        self._readings.reset()
        # -1 starts with the delayed law: it is safe in both kinds of master while undecided (one
        # sample early in a sequential one), the undelayed law is not (it oscillates in a parallel one)
        self._lag = 1 if self._auto else self.settings.input_delay_samples  # the delay the law runs for
        self._fit_servo_to_lag()
        self._decided = not self._auto
        # an input delay: the commands (u, u_c) computed but not at the valve yet, the one it gets next
        # first (_u_next, _uc_next), then those of later samples (a delay of 2 or more)
        self._u_next = 0.0
        self._uc_next = 0.0
        self._later = [(0.0, 0.0)] * max(self._lag - 1, 0)
        # the outputs (u, u_c) of the last samples, newest first: y(k-1), y(k-2), ...
        self._outs = [(0.0, 0.0)] * (self._scores.largest + 1)
        self._scores.reset(l0)
        if self._delay_predictor is not None:
            self._delay_predictor.reset(l0, 0.0)

    @property
    def reading_held(self) -> tuple[float, float, float] | None:
        """The last step's reading taken for a glitch, a spike or a stale repeat (then equal to the last
        one used), the value used instead and the last one used before [mm]; None where the reading
        was used (:class:`~fmu_controller.reading_guards.ReadingGuard`)."""
        return self._readings.reading_held

    @property
    def spike_limit_mm(self) -> float | None:
        """Where :attr:`reading_held` is a one-sample spike (further from the prediction than
        :data:`SPIKE_MM` and :data:`SPIKE_SPREAD` times the usual error), the distance it exceeded [mm];
        None where it is a jump beyond ``max_speed_mm_per_s`` or no reading was held."""
        return self._readings.spike_limit_mm

    @property
    def held_reading_real(self) -> tuple[str, float, float, float] | None:
        """On the step after a reading was held as a one-sample spike or a stale repeat, where this
        reading lies nearer the held one than its own one-step prediction, so that the held one was the
        muscle's own (a supply lost or back, a load dropped, a stop reached): what it was held as
        (``"spike"``, ``"repeat"``), the held reading, this reading and the prediction [mm]; None
        otherwise. The spike and repeat guards then hold no reading for :data:`REF_STEP_SETTLE_S`."""
        return self._readings.held_reading_real

    @property
    def reading_stuck(self) -> tuple[float, float] | None:
        """On the step that tells it, once a stretch: the reading [mm] that has not changed at all
        while the command sat at each of the valve's limits for :data:`STUCK_AT_LIMIT_S` or more, and
        how long it has not changed [s] (a stuck or disconnected sensor, a DAQ holding its last value,
        or the supply shut with the muscle at rest); None otherwise. The law goes on with the reading."""
        return self._readings.reading_stuck

    def _guarded(self) -> bool:
        """Whether the spike and repeat guards act at this sample: a prediction to use, past the
        start-up and :data:`SPIKE_AFTER_S` after it (an estimate still learning predicts badly)."""
        # past the start-up: -1 decided, and more than the blend's samples since the estimator's start
        return (self._decided and self._k - self._est_from > self._readings.after_samples + self._blend_n
                and math.isfinite(self._predicted))

    def step(self, l_mm: float, r_preview_mm: Sequence[float]) -> ControlStep:
        """One control sample: measured ``l(k)`` [mm] and the preview ``r(k), ..., r(k+n)`` [mm] ->
        ``u(k)``, with ``n = settings.preview_samples`` (``Hp`` plus the input delay: 5 for -1,
        :data:`AUTO_INPUT_DELAY_SAMPLES`).

        Raises
        ------
        TypeError
            ``l_mm`` not one number (an array, None). The controller's state is unchanged then.
        ValueError
            ``l_mm`` non-finite or outside :data:`L_RANGE_MM`, a non-finite reference, or a preview shorter than ``preview_samples + 1``
            samples. The controller's state is unchanged then.
        """
        # Per-sample hot path (docs/control.md, "Compute time per step"): python floats for
        # the scalars, each numpy call on the small arrays only where it does the arithmetic.
        try:
            l = float(l_mm)
        except (TypeError, ValueError):  # an array l[k:k+1], None, a string: named, not numpy's words
            raise TypeError(f"measured l_mm must be one number [mm], got {type(l_mm).__name__} {l_mm!r:.60}") from None
        if not L_RANGE_MM[0] <= l <= L_RANGE_MM[1]:  # NaN fails it too
            raise ValueError(f"measured l_mm must be a finite reading within {L_RANGE_MM[0]:g}..{L_RANGE_MM[1]:g} mm "
                             f"(every contraction the plant allows; a reading in micrometres?), got {l_mm!r}")
        r = r_preview_mm if isinstance(r_preview_mm, np.ndarray) else np.asarray(r_preview_mm, dtype=float)
        need = self._need
        if r.ndim != 1 or len(r) < need:
            s = self.settings
            hp = s.servo.hp if s.servo_mechanism else s.ucp.hp
            d = s.input_delay_samples
            delay = (f" + the {AUTO_INPUT_DELAY_SAMPLES} samples input_delay_samples = -1 may decide" if d == -1
                     else f" + input_delay_samples = {d}" if d else "")
            got = (f"a single value {float(r):g}" if r.ndim == 0 else f"{len(r)} samples" if r.ndim == 1
                   else f"an array of shape {r.shape}")
            raise ValueError(f"reference preview must hold r(k)..r(k+{need - 1}), {need} samples ({'servo' if s.servo_mechanism else 'ucp'}"
                             f".hp = {hp}{delay}, + 1), got {got}")
        rl = (r if len(r) == need else r[:need]).tolist()
        if r.dtype.char != "d":  # not float64
            rl = [float(x) for x in rl]
        # a finite sum implies finite terms; the elementwise test only if it is not (1e308s overflow)
        if not math.isfinite(sum(rl)) and not all(map(math.isfinite, rl)):
            raise ValueError(f"reference preview must be finite, got {r[:need]}")
        state = self._state
        k = self._k
        # a glitch, a one-sample spike or a stale repeat is replaced by the one-step prediction (ReadingGuard)
        l = self._readings.check(l, k, self._predicted, state.last_l, state.l_prev_mm, rl[-1], self._outs[0][0],
                                 self._guarded())
        error = 0.0 if math.isnan(self._predicted) else l - self._predicted
        if k < self._ramp_n:
            rl = self._lead_in(rl, l)

        # -1 scores the delays until it decides; a set delay over DELAY_CHECK_SAMPLES (delay_evidence)
        if (not self._decided) if self._auto else not self._scores.checked:
            if k == 0:  # the hypotheses' models start from the first measurement
                self._scores.start(l)
            elif self._auto:
                self._detect_delay(l)
            else:  # a delay set: scored over the first samples as -1 would, to tell a wrong one (delay_evidence)
                self._scores.score(l, self._outs)

        if self._rls is not None and k > 0:
            phi = state.phi_list()
            if not math.isfinite(sum(phi)) and not all(map(math.isfinite, phi)):
                raise ValueError(f"phi must be finite, got {phi}")
            theta_hat = self._rls.update_unchecked(np.array(phi), l)
            j = k - self._est_from
            if j < self._blend_n and self._guarded_at is None:
                w = _smoothstep((j - self._warm_n) / (self._blend_n - self._warm_n)) if j >= self._warm_n else 0.0
                theta_hat = self.theta0 + w * (theta_hat - self.theta0)
            self.theta = _read_only(theta_hat.copy())
            t = self.theta.tolist()
            if self._servo is not None:
                self._servo.update_model_unchecked(t[0], t[1], t[2])
        else:
            t = self._theta_list
        theta = self.theta
        # v(k) with the law's parameters: the estimator's next regressor takes it too (during the
        # start-up the blend's, not the raw young estimate's; docs/control.md, "What the gentle start costs")
        state.observe_unchecked(l, t[0], t[1], t[2])
        if self._lag:
            return self._step_ahead(l, rl, t, theta, error)
        if self._auto:  # decided for a sequential master: the preview holds more than the law takes
            rl = rl[:self._law_n]

        u, uc, h, xs_next, predicted, saturated, pushed = self._decide(l, rl, t, theta, self._xs, self._u_prev,
                                                                       self._uc_prev, self._h_prev2, self._h_prev)
        if self._servo is not None:
            self._xs = xs_next
            self._limit_run = self._limit_run + 1 if pushed else 0
            self._uc_prev = uc
            if self._notch:
                self._h_prev2, self._h_prev = self._h_prev, state.hysteresis_unchecked(t)
        state.apply(u)
        self._u_prev = u
        self._watch_jump(u)
        self._outs = [(u, uc)] + self._outs[:-1]
        self._predicted = predicted
        self._k += 1
        # theta is read-only and replaced, never modified in place: the step can share it, and a
        # caller writing into it gets an error instead of changing the law.
        return _control_step(u, predicted, error, uc, h, xs_next, theta, saturated)

    def _detect_delay(self, l: float) -> None:
        """``input_delay_samples = -1``: score ``l(k)`` [mm] under each delay ``d = 0 ..
        AUTO_INPUT_DELAY_SAMPLES`` and act on the scores' verdict (:meth:`DelayScores.verdict
        <fmu_controller.input_delay_scores.DelayScores.verdict>`). The controller starts with the
        delayed law (``d = 1``): a verdict of 1 keeps it, any other switches the law to that delay
        (:meth:`_decide_delay`), for good."""
        self._scores.score(l, self._outs)
        d = self._scores.verdict(self.settings.servo_mechanism)
        if d == 1:
            self._decided = True
        elif d is not None:
            self._decide_delay(d)

    @property
    def delay_evidence(self) -> tuple[int, float] | None:
        """With ``input_delay_samples`` set: once the first :data:`DELAY_CHECK_SAMPLES` samples are
        scored as -1 scores them (:meth:`_detect_delay`, the delays 0 .. :attr:`largest_scored_delay`),
        ``(d, ratio)`` when another delay ``d`` explains the measurements :data:`DELAY_RATIO` times better
        or more (``ratio``: the set delay's mean squared one-step error over ``d``'s), else None (also
        before, and with -1)."""
        return self._scores.evidence(self._lag) if self.delay_checked else None

    @property
    def delay_checked(self) -> bool:
        """With ``input_delay_samples`` set: whether the first :attr:`delay_check_samples` samples have
        been scored, so that :attr:`delay_evidence` None means that no other delay explained them
        better (False before, and with -1)."""
        return not self._auto and self._scores.checked

    def _decide_delay(self, d: int) -> None:
        """``input_delay_samples = -1`` decided for the delay ``d`` other than the delayed law's 1 it ran
        with: the model's input over ``[t_k-1, t_k)`` becomes ``y(k-1-d)``, the outputs since are the
        commands in flight, and the adaptive estimator, whose regressors all held a command off by
        ``d - 1`` samples, starts again from ``theta0`` and ``P(0)`` with the start-up mode's warm-up and
        blend (and the guard, whose jumps may have come from the wrong hypothesis)."""
        outs = self._outs
        self._decided = True
        self._lag = d
        self._fit_servo_to_lag()
        self._state.apply(outs[d][0])
        self._u_prev, self._uc_prev = outs[d]
        if d:
            (self._u_next, self._uc_next), self._later = outs[d - 1], outs[d - 2::-1] if d > 1 else []
            if self._delay_predictor is not None:  # fitted to the residuals under the wrong commands
                self._delay_predictor.reset(self._state.history[2], outs[d][0])
        if self._rls is not None:
            self._rls.setup(ASYMMETRIC, self._rls.settings)
            self._est_from = self._k
            self._jumps, self._guarded_at = 0, None

    def _fit_servo_to_lag(self) -> None:
        """The servo QP with the move weight for the delay the law runs for
        (:meth:`ControllerSettings.servo_for_delay`), set up again from its model if that changed it."""
        if self._servo is None:
            return
        wanted = self.settings.servo_for_delay(self._lag)
        if self._servo.settings != wanted:
            a1, a2, b1 = self._servo.model
            self._servo = ServoMPC(wanted, a1=a1, a2=a2, b1=b1)

    @property
    def delay_check_samples(self) -> int:
        """How many samples a set delay is scored over before :attr:`delay_evidence` speaks:
        :data:`DELAY_CHECK_SAMPLES` at Ts = :data:`DELAY_SCORES_TS_S`, the same seconds at another Ts."""
        return self._scores.check_n

    @property
    def largest_scored_delay(self) -> int:
        """The largest delay [samples] the controller scores: :data:`AUTO_INPUT_DELAY_SAMPLES` for -1
        (the longest it may decide), else the larger of that and the delay set. Evidence for it may mean a
        longer delay still."""
        return self._scores.largest

    @property
    def input_delay_decision(self) -> int | None:
        """The delay [samples] the controller runs its law for; None while ``input_delay_samples = -1``
        is still undecided (the delayed law, a delay of 1, runs then)."""
        if not self._decided:
            return None
        return self._lag

    @property
    def input_delay_detected(self) -> bool:
        """Whether the law runs for an input delay: ``input_delay_samples`` 1 or more set, or -1 decided for
        a delay of 1 or more (a parallel master, a rig's transport delay); False for 0, while -1 is
        undecided, and after it decided for a sequential master."""
        return self._lag != 0 and self._decided

    def _future_hysteresis(self, t: list[float], theta: np.ndarray, u_prev: float,
                           bounds: tuple[float, float] | None) -> tuple[float, float]:
        """``(H(k+1|k), H(k+2|k))`` [mm]: the Eq. (1) hysteresis term one and two samples ahead, on the
        predictions ``l(k+1|k), l(k+2|k)`` with the last command held (for ``hysteresis_notch``;
        clamped into ``bounds``, if given, as :func:`held_input_run` does); the state is left as it was but
        for its input, which the caller sets next."""
        state = self._state
        l1, l2 = held_input_run(state, theta, t[:3], u_prev, 2, bounds)
        saved = state.history
        state.apply(u_prev)
        state.observe_unchecked(l1, t[0], t[1], t[2])
        h1 = state.hysteresis_unchecked(t)
        state.apply(u_prev)
        state.observe_unchecked(l2, t[0], t[1], t[2])
        h2 = state.hysteresis_unchecked(t)
        state.restore_history(saved)
        return h1, h2

    def _lead_in(self, rl: list[float], l: float) -> list[float]:
        """The preview ``r(k..k+Hp)`` as the start-up mode leads it in from the first measured ``l0``
        (``ControllerSettings.startup_s``); entries at or after the lead-in's end unchanged."""
        k, n = self._k, self._ramp_n
        if k == 0:
            self._l_start = l
        l0 = self._l_start
        return [x if k + i >= n else l0 + _smoothstep((k + i) / n) * (x - l0) for i, x in enumerate(rl)]

    def _decide(self, l: float, rl: list[float], t: list[float], theta: np.ndarray, xs: float, u_prev: float,
                uc_prev: float, h_prev2: float, h_prev: float, bounds: tuple[float, float] | None = None
                ) -> tuple[float, float, float, float, float, bool, bool]:
        """The control law at a sample whose ``l`` the state has observed: ``(u, u_c, H, x_s(k+1),
        l(k+1|k), saturated, pushed)`` for the preview ``rl = r(k..k+Hp)`` (``pushed``: the command at
        a valve limit the error pushes it into, :meth:`_integrate`; ``bounds``: those of the
        predictions through the commands in flight, for the notch's); changes no state (but the QP's
        warm start)."""
        if self._servo is None:
            res = ucp_move(self.settings.ucp, self._state, theta, u_prev_v=u_prev, r_target_mm=rl[self._ucp_hp])
            u = self._probed(res.u_v)
            return u, u, 0.0, 0.0, float(res.predicted_mm[0]), res.saturated, False
        h = self._state.hysteresis_unchecked(t)
        if self._notch and h_prev == h_prev:  # not NaN: a previous H exists
            h_next, h_next2 = self._future_hysteresis(t, theta, u_prev, bounds)
            if h_prev2 != h_prev2:  # the second sample: H(k-2) does not exist yet
                h_prev2 = h_prev
            # the predictions move H(k) ahead no faster than NOTCH_RATE_FACTOR times its last two changes,
            # plus NOTCH_FLOOR_MM per sample (unbounded, an estimate's jump takes them to thousands of mm)
            d = NOTCH_RATE_FACTOR * max(abs(h - h_prev), abs(h_prev - h_prev2)) + NOTCH_FLOOR_MM
            h_next = min(max(h_next, h - d), h + d)
            h_next2 = min(max(h_next2, h - 2.0 * d), h + 2.0 * d)
            # the centred 5-point mean (1, 3, 4, 3, 1)/12 of H(k-2) .. H(k+2|k)
            h = (h_prev2 + h_next2) / 12.0 + (h_prev + h_next) / 4.0 + h / 3.0
        offset = h / t[2]
        uc, predicted, constrained = self._servo.solve_unchecked(l, self._state.l_prev_mm, uc_prev, xs, rl, offset)
        u_raw = uc - offset  # Eq. (5)
        u = u_raw  # = min(max(u_raw, u_min), u_max)
        if self._u_min > u:
            u = self._u_min
        elif self._u_max < u:
            u = self._u_max
        saturated = constrained or u != u_raw
        xs_next, pushed = self._integrate(xs, rl[0], l, u, self._limit_run)
        return self._probed(u), uc, h, xs_next, predicted, saturated, pushed

    def _integrate(self, xs: float, r_mm: float, l_mm: float, u: float, limit_run: int) -> tuple[float, bool]:
        """Eq. (18), ``x_s(k+1) = x_s(k) + r(k) - l(k)``, and whether the command ``u`` [V] sits at a
        valve limit that the error pushes it further into. Once it has for :data:`HOLD_AFTER_SAMPLES`
        samples in a row, ``x_s`` is held (conditional integration): a reference out of the muscle's
        reach would otherwise wind it up by the thousands and the loop would lag for seconds once the
        reference is back in reach. A shorter stay at a limit (the valve closed for a few samples at the
        bottom of a fast cycle) is integrated as Eq. (18) says: holding there costs tracking."""
        pushed = pushed_at_limit(r_mm, l_mm, u, self._u_min, self._u_max)
        if pushed and self._anti_windup and limit_run + 1 >= HOLD_AFTER_SAMPLES:
            return xs, True
        return integrator_step(xs, r_mm, l_mm), pushed

    def _watch_jump(self, u: float) -> None:
        """``ControllerSettings.startup_guard``: count the output ``u`` [V] if it jumps across
        :data:`GUARD_JUMP_FRACTION` of the valve's range from the last one while the start-up mode's
        law still holds ``theta0``; at :data:`GUARD_JUMPS` the law leaves it for the estimate."""
        if (self._guard and self._guarded_at is None and full_range_jump(u, self._outs[0][0], *self._law_bounds)
                and self._k - self._est_from < self._blend_n):
            self._jumps += 1
            if self._jumps >= GUARD_JUMPS:
                self._guarded_at = self._k

    @property
    def startup_guarded_at(self) -> int | None:
        """The sample ``k`` at which ``ControllerSettings.startup_guard`` ended the start-up mode's law
        on ``theta0`` (from ``k + 1`` the law takes the estimate); None while it has not."""
        return self._guarded_at

    @property
    def samples_since_start(self) -> int:
        """Samples since the estimator's (re)start: the first sample, or -1's decision for a delay other
        than the delayed law's 1 it starts with."""
        return self._k - self._est_from

    @property
    def in_startup(self) -> bool:
        """Whether the last step came before the law's own start was over: ``input_delay_samples = -1``
        still deciding, or within ``startup_s`` of the estimator's (re)start (the start-up mode's
        lead-in, warm-up and blend)."""
        return not self._decided or self.samples_since_start - 1 < self._blend_n

    @property
    def law_on_theta0(self) -> bool:
        """Whether the last step's law ran on ``theta0`` alone: always for the fixed-predictor MPCs; for
        the adaptive ones in the start-up mode's warm-up (until the guard, ``startup_guard``, ends it)."""
        if self._rls is None:
            return True
        # the guard fires at a step whose command still came from theta0
        return (self._guarded_at is None or self._guarded_at == self._k - 1) and self._k - 1 - self._est_from < self._warm_n

    def _probed(self, u: float) -> float:
        """``u`` [V] plus the start-up mode's probing signal during the estimator's warm-up
        (``ControllerSettings.probing_v``), within the valve's range."""
        j = self._k - self._est_from
        if self._probing_v and 0 < j < self._warm_n and self._guarded_at is None:
            u += probe_v(j, self._probing_v, self._probing_phase)
            u_min, u_max = self._law_bounds  # the method's own limits (the coincidence point's may be narrower)
            return min(max(u, u_min), u_max)
        return u

    def _step_ahead(self, l: float, rl: list[float], t: list[float], theta: np.ndarray,
                    error: float) -> ControlStep:
        """One sample with an input delay of ``d >= 1`` samples (``ControllerSettings.input_delay_samples``
        set, or decided by -1, which runs ``d = 1`` until it decides).

        The valve receives over ``[t_k, t_k+1)`` the command computed at ``k - d``. It is recorded
        as ``u(k)`` (with the true ``l(k)`` the state has observed, and ``x_s`` integrating the true
        error); the Eq. (1) model predicts ``l(k+1|k)`` under it; the control law is then evaluated
        ``d`` samples ahead (:meth:`_decide_ahead`: on to ``l(k+d|k)`` through the commands in flight,
        with ``r(k+d..k+d+Hp)``) on a scratch copy of the history, and its command is returned (it
        reaches the valve at ``t_k+d``). With ``delay_correction`` the prediction is
        :class:`~fmu_controller.delay_predictor.DelayPredictor`'s.
        """
        state = self._state
        u_now, uc_now = self._u_next, self._uc_next
        l_next = held_input_run(state, theta, t[:3], u_now, 1)[0]  # l(k+1|k), Eq. (1)
        if self._delay_predictor is not None:
            corrected = self._delay_predictor.predict(l, u_now, l_next)
            if self._decided or self._scores.parallel_leads():
                # while -1 is undecided, only where the parallel hypothesis leads: in a sequential
                # master the command in flight is not the one the valve has, and a correction fitted
                # to that wrong record destabilises the loop (an overshoot of 19 mm on an off-nominal
                # rig); it keeps learning meanwhile
                l_next = corrected
        state.apply(u_now)
        # Eq. (18) with the true l(k), held at a limit the valve has now (_integrate)
        xs, pushed = self._integrate(self._xs, rl[0], l, u_now, self._limit_run) if self._servo is not None else (0.0, False)
        saved = state.history
        h_now = state.hysteresis_unchecked(t) if self._notch else math.nan  # H(k), before the scratch step
        state.observe_unchecked(l_next, t[0], t[1], t[2])
        u, uc, h, saturated = self._decide_ahead(l_next, rl, t, theta, xs, u_now, uc_now, h_now,
                                                 self._limit_run + 1 if pushed else 0)
        state.restore_history(saved)
        state.apply(u_now)
        self._xs, self._u_prev, self._uc_prev = xs, u_now, uc_now
        self._limit_run = self._limit_run + 1 if pushed else 0
        # the commands in flight move up one sample; this one joins them last
        (self._u_next, self._uc_next), *self._later = *self._later, (u, uc)
        self._watch_jump(u)
        self._outs = [(u, uc)] + self._outs[:-1]
        self._h_prev2, self._h_prev = self._h_prev, h_now
        self._predicted = l_next
        self._k += 1
        return _control_step(u, l_next, error, uc, h, xs, theta, saturated)

    def _decide_ahead(self, l_next: float, rl: list[float], t: list[float], theta: np.ndarray, xs: float,
                      u_now: float, uc_now: float, h_now: float, limit_run: int) -> tuple[float, float, float, bool]:
        """The control law ``d = input delay`` samples ahead, on the scratch history that has observed
        ``l(k+1|k)``: for ``d >= 2`` Eq. (1) carries the prediction on to ``l(k+d|k)`` under the commands still
        in flight, Eq. (18) integrates the predicted errors ``r(k+i) - l(k+i|k)`` (with its hold, counting
        on from ``limit_run`` samples at a limit up to ``k``), and the law is evaluated there with
        ``r(k+d..k+d+Hp)``. Returns ``(u, u_c, H, saturated)`` of the command that reaches the valve at
        ``t_k+d``."""
        state = self._state
        l_ahead, u_prev, uc_prev = l_next, u_now, uc_now
        h_prev2, h_prev = self._h_prev, h_now
        # an estimate made under another delay than the rig's can predict without bound through the
        # commands in flight (to a float's overflow within a sample); clamped as the free run of
        # Eq. (1) is, around l(k-1), l(k), l(k+1|k) and the reference the loop drives to (from rest
        # the displacements alone span ~0 mm)
        bounds = guard_bounds(None, (*state.history[:3], min(rl), max(rl)), widen=True) if self._later else None
        for i, (u_i, uc_i) in enumerate(self._later, start=1):
            if self._servo is not None:  # Eq. (18) with its hold, as the loop will integrate at k + i
                xs, pushed = self._integrate(xs, rl[i], l_ahead, u_i, limit_run)
                limit_run = limit_run + 1 if pushed else 0
            if self._notch:
                h_prev2, h_prev = h_prev, state.hysteresis_unchecked(t)
            l_ahead = held_input_run(state, theta, t[:3], u_i, 1, bounds)[0]
            state.apply(u_i)
            state.observe_unchecked(l_ahead, t[0], t[1], t[2])
            u_prev, uc_prev = u_i, uc_i
        d = len(self._later) + 1
        u, uc, h, _, _, saturated, _ = self._decide(l_ahead, rl[d:d + self._law_n], t, theta, xs, u_prev, uc_prev,
                                                    h_prev2, h_prev, bounds)
        return u, uc, h, saturated

    # ------------------------------------------------------------------ estimator
    @property
    def covariance(self) -> np.ndarray | None:
        """The AMPC's RLS covariance after the last update, ``P(k-1)`` of Eq. (4) (a copy, 15 x 15;
        :attr:`fmu_controller.rls.ConstrainedRLS.P`); None for the fixed-predictor MPCs."""
        return None if self._rls is None else self._rls.P

    @property
    def covariance_resets(self) -> int:
        """How often Algorithm 1's covariance lost positive definiteness and restarted from ``P(0)``
        (the estimator's documented rule; 0 for the fixed-predictor MPCs)."""
        return 0 if self._rls is None else self._rls.n_resets

    @property
    def estimator_counts(self) -> tuple[int, int, int]:
        """Algorithm 1 since the estimator's (re)start: updates whose estimate it projected onto the box C,
        covariance resets (:attr:`covariance_resets`) and updates whose covariance ``covariance_ceiling``
        clipped; zeros for the fixed-predictor MPCs."""
        rls = self._rls
        return (0, 0, 0) if rls is None else (rls.n_projections, rls.n_resets, rls.n_ceilings)

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        """Everything needed to continue bit-identically, as plain data (JSON-serialisable:
        python floats, ints, lists and ``None``; ``predicted`` is NaN before the first step)."""
        rls = None
        if self._rls is not None:
            rls = self._rls.get_state()
            rls["theta"], rls["P"] = rls["theta"].tolist(), rls["P"].tolist()
        return {
            "theta": self.theta.tolist(), "model": self._state.get_state(), "k": self._k,
            "u_prev": self._u_prev, "uc_prev": self._uc_prev, "xs": self._xs, "limit_run": self._limit_run,
            "predicted": self._predicted, **self._readings.get_state(),
            "u_next": self._u_next, "uc_next": self._uc_next, "h_prev": self._h_prev,
            "h_prev2": self._h_prev2, "l_start": self._l_start,
            "delayed": self._lag != 0, "decided": self._decided, "lag": self._lag,
            "in_flight": [list(pair) for pair in self._later],
            "u_out": [u for u, _ in self._outs], "uc_out": [uc for _, uc in self._outs],
            **self._scores.get_state(), "est_from": self._est_from,
            "guard": [self._jumps, self._guarded_at],
            "delay_predictor": None if self._delay_predictor is None else self._delay_predictor.get_state(),
            "rls": rls,
            "servo": None if self._servo is None else self._servo.get_state(),
        }

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore what :meth:`get_state` returned.

        Raises
        ------
        ValueError
            A field that no controller could have saved (non-finite, wrong length, negative count),
            named. The RLS and QP parts validate their own fields.
        """
        theta = np.array(state["theta"], dtype=float)  # a copy: the caller's array stays writeable
        if theta.shape != (ASYMMETRIC.n_params,) or not np.all(np.isfinite(theta)) or abs(theta[2]) < 1e-6:
            raise ValueError(f"state field theta must be {ASYMMETRIC.n_params} finite numbers with b1 not ~0, "
                             f"got {state['theta']!r}")
        for name in ("u_prev", "uc_prev", "xs", "u_next", "uc_next", "l_start"):
            if name in state and not math.isfinite(float(state[name])):
                raise ValueError(f"state field {name} = {state[name]!r} must be finite")
        if not (math.isfinite(float(state["predicted"])) or math.isnan(float(state["predicted"]))):
            raise ValueError(f"state field predicted = {state['predicted']!r} must be finite (or NaN before a step)")
        if int(state["k"]) < 0:
            raise ValueError(f"state field k = {state['k']!r} must be >= 0")
        self.theta = _read_only(theta)
        self._theta_list = self.theta.tolist()
        self._state.set_state(state["model"])
        self._k = int(state["k"])
        self._u_prev, self._uc_prev, self._xs = float(state["u_prev"]), float(state["uc_prev"]), float(state["xs"])
        self._limit_run = int(state.get("limit_run", 0))
        self._predicted = float(state["predicted"])
        self._readings.set_state(state)  # a state saved without a guard's fields: that guard anew
        self._u_next, self._uc_next = float(state.get("u_next", 0.0)), float(state.get("uc_next", 0.0))
        for name in ("h_prev", "h_prev2"):
            if math.isinf(float(state.get(name, math.nan))):
                raise ValueError(f"state field {name} = {state[name]!r} must be finite (or NaN before a step)")
        self._h_prev, self._h_prev2 = float(state.get("h_prev", math.nan)), float(state.get("h_prev2", math.nan))
        self._l_start = float(state.get("l_start", self._state.history[2]))
        if "delayed" in state:
            d = self.settings.input_delay_samples
            if state["delayed"] not in (True, False) or (state["delayed"] is False and d >= 1) \
                    or (state["delayed"] is True and d == 0):
                raise ValueError(f"state field delayed = {state['delayed']!r} contradicts input_delay_samples = {d}")
            lag = state.get("lag", 1 if state["delayed"] else 0)
            if (isinstance(lag, bool) or int(lag) != lag or not 0 <= lag <= self._scores.largest
                    or (lag != 0) != state["delayed"] or (d != -1 and lag != d)):
                raise ValueError(f"state field lag = {lag!r} contradicts input_delay_samples = {d} with delayed = "
                                 f"{state['delayed']!r}")
            lag = int(lag)
            n = self._scores.largest + 1
            try:
                outs = [(float(u), float(uc)) for u, uc in zip(state["u_out"], state["uc_out"], strict=True)]
                later = [(float(u), float(uc)) for u, uc in state.get("in_flight", [])]
                scores = [float(x) for x in state["delay_scores"]]
            except (KeyError, TypeError, ValueError):
                outs, later, scores = [], [], []
            values = [x for pair in outs + later for x in pair] + scores
            if (len(outs) != n or len(scores) != n or len(later) != max(lag - 1, 0) or not all(map(math.isfinite, values))
                    or min(scores, default=0.0) < 0 or int(state["compared"]) < 0):
                raise ValueError(f"state fields u_out, uc_out ({n} finite numbers each), in_flight ({max(lag - 1, 0)} "
                                 f"finite pairs), delay_scores ({n}, >= 0) and compared (>= 0) do not fit, got "
                                 f"{state.get('u_out')!r}, {state.get('uc_out')!r}, {state.get('in_flight')!r}, "
                                 f"{state.get('delay_scores')!r}, {state.get('compared')!r}")
            decided = state.get("decided", True)  # a state without it (an older FMU's): decided
            if decided not in (True, False) or (not decided and not self._auto) or (not decided and lag != 1):
                raise ValueError(f"state field decided = {decided!r} contradicts input_delay_samples = "
                                 f"{d} with lag = {lag!r}")
            self._lag = lag
            self._fit_servo_to_lag()
            self._decided = bool(decided)
            self._outs, self._later = outs, later
            self._est_from = int(state.get("est_from", 0))
            if not 0 <= self._est_from <= self._k:
                raise ValueError(f"state field est_from = {state['est_from']!r} must be within 0 .. k = {self._k}")
            self._scores.set_state(scores, state["compared"], state.get("delay_models"))
        jumps, guarded_at = state.get("guard", (0, None))  # a state without it (an older FMU's): not fired
        if (isinstance(jumps, bool) or int(jumps) != jumps or jumps < 0
                or (guarded_at is not None and not (int(guarded_at) == guarded_at and 0 <= guarded_at <= self._k))):
            raise ValueError(f"state field guard = {state.get('guard')!r} must be [jumps >= 0, None or a sample "
                             f"within 0 .. k = {self._k}]")
        self._jumps, self._guarded_at = int(jumps), None if guarded_at is None else int(guarded_at)
        predictor = state.get("delay_predictor")
        if "delay_predictor" in state and (predictor is None) != (self._delay_predictor is None):
            raise ValueError(f"state field delay_predictor = {'None' if predictor is None else 'a predictor'} "
                             f"contradicts delay_correction = {self.settings.delay_correction} with "
                             f"input_delay_samples = {self.settings.input_delay_samples}")
        if predictor is not None:
            self._delay_predictor.set_state(predictor)
        if self._rls is not None:
            self._rls.set_state(state["rls"])
        if self._servo is not None:
            self._servo.set_state(state["servo"])
