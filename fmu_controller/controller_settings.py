"""Settings of the paper's four displacement controllers (:class:`ControllerSettings`).

One frozen dataclass, validated on construction (each bad value named with its range), hashable and
picklable: the method (``mpc_ucp``, ``mpc_servo``, ``ampc_ucp``, ``ampc_servo``), the sampling period,
the laws' settings (Table 5), the AMPC's ``P(0)`` (Tables 5 and 8) and box C (Table 2), and the
departures from the paper that are on by default (start-up mode, hysteresis notch, conditional
integration, input delay, sensor guards), each documented on its field with what it was measured on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from .argument_checks import real_number, whole_number
from .hysteresis_model import ASYMMETRIC
from .input_delay_scores import AUTO_INPUT_DELAY_SAMPLES
from .methods import METHODS
from .prediction import MAX_INPUT_DELAY_SAMPLES
from .probing import MLS_LENGTH
from .read_only_fields import read_only, settings_hash, settings_reduce
from .reading_guards import DEFAULT_MAX_SPEED_MM_PER_S
from .rls import TABLE2_LOWER, TABLE2_UPPER, RLSSettings
from .servo_mpc import ServoMPCSettings
from .servo_settings import MAX_WEIGHT
from .ucp_mpc import UCPSettings
from .valve_limits import VALVE_MAX_V, VALVE_MIN_V

__all__ = ["MAX_DELAY_MOVE_WEIGHT", "MAX_STARTUP_S", "DEFAULT_STARTUP_S", "DEFAULT_DELAY_MOVE_WEIGHT",
           "DEFAULT_PROBING_V", "MAX_PROBING_V", "MIN_FORGETTING", "P0_TABLE5", "P0_TABLE8", "ControllerSettings",
           "preview_lead"]


#: Largest ``ControllerSettings.delay_move_weight``.
MAX_DELAY_MOVE_WEIGHT = 1000.0

#: Longest start-up mode ``ControllerSettings.startup_s`` [s].
MAX_STARTUP_S = 600.0
#: Default start-up mode ``ControllerSettings.startup_s`` [s] (docs/control.md, "Start-up").
DEFAULT_STARTUP_S = 12.0

#: Default ``ControllerSettings.delay_move_weight``: 16 tracked better than 4 and 32 in most cells of
#: benchmarks/transport_delay.py (every servo cell better than 4; 10 of 16 off-nominal delayed rigs
#: within 2 mm against 8 with 4 and 9 with 32), and 4 left AMPC-servo limit-cycling at 0.35 s.
DEFAULT_DELAY_MOVE_WEIGHT = 16.0

#: Default amplitude [V] of the start-up mode's probing signal (``ControllerSettings.probing_v``).
DEFAULT_PROBING_V = 0.5
#: Largest ``ControllerSettings.probing_v`` [V]: a quarter of the valve's 0-10 V range.
MAX_PROBING_V = 2.5

#: Smallest ``ControllerSettings.forgetting``: below it Algorithm 1 forgets half its information
#: every sample and its estimate follows the measurement noise (0.3: ``u_c`` at thousands of V,
#: 9 mm of Eq. (21) error).
MIN_FORGETTING = 0.5

#: ``P(0)`` of the AMPC for the 0.1 Hz experiments (Table 5).
P0_TABLE5 = (200.0, 200.0, 200.0) + (50.0,) * 8 + (20.0,) * 4
#: ``P(0)`` of the AMPC for the 0.2 Hz experiments (Table 8).
P0_TABLE8 = (1000.0, 1000.0, 1000.0) + (250.0,) * 8 + (150.0,) * 4


@dataclass(frozen=True, kw_only=True)
class ControllerSettings:
    """Settings of a :class:`~fmu_controller.displacement_control.DisplacementController`.

    The constants the fields name live with what they tune: the delay decision's (``DELAY_*``,
    ``AUTO_INPUT_DELAY_SAMPLES``) in :mod:`fmu_controller.input_delay_scores`, the reading guards'
    (``SPIKE_*``, ``REPEAT_MOVE_MM``, ``HELD_READINGS_MAX``) in :mod:`fmu_controller.reading_guards`,
    the valve's (``GUARD_JUMP*``) in :mod:`fmu_controller.valve_limits`, ``HOLD_AFTER_SAMPLES`` in
    :mod:`fmu_controller.displacement_control`, which re-exports them all."""

    method: str = "ampc_servo"
    """One of ``mpc_ucp``, ``mpc_servo``, ``ampc_ucp``, ``ampc_servo``."""
    ts_s: float = 0.1
    """Sampling period [s] (paper: 0.1)."""
    ucp: UCPSettings = field(default_factory=UCPSettings)
    """Unique-coincidence-point settings (Table 5: Hp = 2)."""
    servo: ServoMPCSettings = field(default_factory=ServoMPCSettings)
    """Servo-MPC settings (Table 5: Hp = Hu = 5, Q = 5, Qs = 2, R = 15)."""
    p0: tuple[float, ...] = P0_TABLE5
    """Diagonal of the AMPC's initial covariance ``P(0)`` (Table 5; Table 8 for 0.2 Hz), which
    Algorithm 1 calls ``P(-1)`` (:class:`fmu_controller.rls.RLSSettings`' ``p0``)."""
    box_lower: Mapping[str, float] = field(default_factory=lambda: dict(TABLE2_LOWER))
    """Lower bounds of the constraint region C by parameter name (Table 2)."""
    box_upper: Mapping[str, float] = field(default_factory=lambda: dict(TABLE2_UPPER))
    """Upper bounds of C (Table 2)."""
    forgetting: float = 1.0
    """RLS forgetting factor (1 = off, as the paper)."""
    covariance_ceiling: bool = False
    """Keep the RLS covariance at or below ``P(0)`` (:class:`~fmu_controller.rls.RLSSettings`), which
    stops covariance wind-up under forgetting. Off in the paper; with ``forgetting = 0.999`` it is
    what keeps the adaptive loop as good after 24 h as after 10 min (docs/control.md, "24 hours")."""
    hysteresis_notch: bool | None = None
    """Servo methods: cancel the centred mean ``(H(k-2) + 3 H(k-1) + 4 H(k) + 3 H(k+1|k) + H(k+2|k))/12``
    in Eq. (5) instead of ``H(k)`` (``H(k+i|k)``: Eq. (1)'s hysteresis term on the predictions with the
    last command held). ``H(k)`` responds to the latest measured increments ``l(k) - l(k-1)`` (its
    Bouc-Wen terms), so the cancellation is a feedback path from the measurement to the valve that the
    QP's linear model (Eq. 2) does not know. Where the plant's local gain exceeds the model's (the
    bottom of the cycle, the valve nearly closed; the first cycles of a young adaptive estimate) that
    loop oscillates with a period of two or three samples: the MPC-servo chatter. The mean is the
    product of ``(1, 2, 1)/4`` and ``(1, 1, 1)/3``: a double zero at the Nyquist frequency and a zero
    at a period of three samples, no lag, and a gain of 0.98 at 0.3 Hz, so the cancellation still
    acts on the hysteresis loop of the reference (docs/control.md, "Chatter"). None (default): on for
    ``mpc_servo``; for ``ampc_servo`` on with the start-up mode (``startup_s > 0``), and off with the
    paper's start, whose violent first seconds excite the estimator so that the adapted model
    follows the local gain. False: the paper's Eq. (5)."""
    startup_s: float = DEFAULT_STARTUP_S
    """Length ``T`` [s] of the start-up mode (docs/control.md, "Start-up"); 0: the paper's start, the
    law on the full reference and the raw estimate from the first sample. With ``T > 0``:

    * the reference is led in from the displacement ``l0`` measured at the first sample: over
      ``t < T/4`` the law sees ``l0 + s(4t/T) (r(t) - l0)`` (its preview too), with the smoothstep
      ``s(x) = 3x^2 - 2x^3``;
    * the adaptive controllers run Algorithm 1 from the first sample, but their law uses
      ``theta0`` for ``t < T/2`` (the estimator's warm-up) and ``theta0 + s(2t/T - 1) (theta_hat -
      theta0)`` over ``T/2 <= t < T``: the first estimates, taken while ``l`` is near 0 and the cubic
      terms of Eq. (1) take most of ``P(0)``'s gain, and those of the first full-amplitude cycle, do
      not reach the valve at full weight. The hysteresis state ``v(k)`` of Eq. (1) (section 2.3's
      ``y_hy``) is computed with the law's parameters, and Algorithm 1's regressor takes it from
      there: until ``T`` it is not the raw estimate's, as section 2.3 has it, whose errors would
      enter the regressor that estimates them (docs/control.md, "What the gentle start costs").

    The default 12 s starts every method from rest within 3 mm of the reference's envelope and
    without repeated 0 <-> 10 V reversals, at 44 and 68 N, 0.1 and 0.2 Hz (benchmarks/startup.py);
    it also makes AMPC-UCP beat MPC-UCP at both loads."""
    probing_v: float = DEFAULT_PROBING_V
    """Adaptive methods with the start-up mode: amplitude [V] of the probing signal added to the valve
    command during the estimator's warm-up (``t < startup_s/2``): a 127-bit maximum-length sequence,
    each bit held 4 samples (:mod:`fmu_controller.probing`). The servo law does not see it (its ``u_c``
    and the integrator are its own); the coincidence-point law does, through ``u(k-1)`` of Eq. (14),
    the applied command; the estimator does, through the applied command. Without
    it the gentle start leaves the closed-loop estimate unexcited and ``b1`` drifts to C's lower
    bound, where the servo law ripples at the cycle's turning points (docs/control.md, "Start-up").
    0 turns it off; at most 2.5 V (a quarter of the valve's range)."""
    probing_phase: int = 0
    """The bit of the probing signal's 127-bit sequence it starts at, 0 .. 126. Controllers started
    together on one rig (several muscles in one master, an antagonistic pair) probe in phase at the
    same setting, a common-mode excitation; give each its own from
    :func:`fmu_controller.probing.probing_phases` (a pair at the default warm-up: 0 and 109), shifts of
    one sequence least alike over the warm-up (not any two: 0 and 96 correlate at 0.66 over its 60
    samples). Tracking moves with the phase as with the seed (docs/fmu.md, "Several muscles in one
    master")."""
    startup_guard: bool = True
    """Adaptive methods with the start-up mode: end the warm-up and the blend early once the valve
    command has jumped across :data:`GUARD_JUMP_FRACTION` of its range in one sample
    :data:`GUARD_JUMPS` times since the estimator started. ``theta0`` is then a poor fixed law on this
    rig: typically one identified open loop on another rig, whose hysteresis cancellation (Eq. 5)
    feeds the measured increments back to the valve with a gain above 1, so that the valve slams end
    to end and the cancellation grows to thousands of mm (a 0.3-MPa rig at 30 N: Eq. (21) 6.65 mm
    instead of 0.29). From the next sample the law takes the estimate as the paper's start does, and
    the probing stops. It does not fire on the paper's runs, whose ``theta0`` comes from a closed loop
    (their bits are kept); a large reference step inside the start-up can fire it too (docs/control.md,
    "Start-up"). False: the warm-up runs its course whatever the valve does."""
    input_delay_samples: int = 0
    """Samples between computing a command and the valve receiving it: 0 (the paper: ``u(k)``
    drives the valve from ``t_k``) or 1 (the computational delay of a parallel co-simulation
    master, which applies the controller's output one macro step late, or of a controller whose
    computation takes a whole sample). With 1 the controller computes ``u(k+1)`` at sample ``k``
    from ``l(k)`` and its own Eq. (1) prediction ``l(k+1|k)`` under the command already on its way
    (the classic one-sample delay compensation), so it needs ``r(k..k+1+Hp)``. -1 (the controller
    FMU's default): decide from the data. The controller starts with the delayed law (one sample early
    in a sequential master, which costs tracking; the undelayed law in a parallel master oscillates)
    and compares, at every sample, how well Eq. (1) with ``theta0`` predicts the measured ``l(k)``
    under its output of the last sample (a sequential master) and under the output before it (a
    parallel one); once one explains the data :data:`DELAY_RATIO` times better (mean squares over
    about 5 s, after at least :data:`DELAY_MIN_SAMPLES` samples; the better one after
    :data:`DELAY_DECIDE_BY_SAMPLES`) it is decided for good: parallel keeps the delayed law, sequential
    switches to that of 0 and restarts the adaptive estimator (docs/fmu.md, "Parallel masters").
    2 .. :data:`MAX_INPUT_DELAY_SAMPLES` (25): a rig whose valve acts on the command later still (a
    transport delay, docs/control.md "Transport delay"; in a parallel master one sample more), the delay
    over ``Ts``, rounded: the controller computes ``u(k+d)`` at sample ``k``, carrying Eq. (1)'s
    prediction on to ``l(k+d|k)`` through the commands in flight, and needs ``r(k..k+d+Hp)``. -1
    compares the delays 2 .. :data:`AUTO_INPUT_DELAY_SAMPLES` (5) too and switches to one of them
    (restarting the estimator) once it explains the data :data:`DELAY_RATIO` times better than both 0
    and 1; it takes ``r(k..k+5+Hp)``, for any. A longer delay (0.15 s at Ts = 0.02 s: 8 samples) is
    set, not decided."""
    anti_windup: bool = True
    """Servo methods: hold the integrator of Eq. (18) once the command has sat at a valve limit that
    the error ``r(k) - l(k)`` pushes it further into for :data:`HOLD_AFTER_SAMPLES` samples in a row
    (conditional integration). A reference out of the muscle's reach otherwise winds ``x_s`` up by
    thousands of mm and the loop lags for 6-12 s once the reference is back in reach (docs/control.md,
    "Integrator wind-up"). Shorter stays at a limit are integrated: with the start-up mode on (the
    default) the paper's runs keep their bits; with the paper's start (``startup_s = 0``) the hold
    moves some of them (AMPC-servo, 68 N, 0.1 Hz: 0.124 -> 0.134 mm of Eq. (21)), so the paper's
    controllers exactly need False here too (``tapmuscle paper --paper-start``). False: Eq. (18) as
    the paper writes it."""
    delay_move_weight: float = DEFAULT_DELAY_MOVE_WEIGHT
    """Servo methods: the factor on Eq. (15)'s move weight R (``servo.r``) while the law compensates a
    delay of 2 samples or more (``input_delay_samples`` 2 or more, or -1 once it decided for one: a rig's
    transport delay). The law's prediction through the commands in flight is only as good as Eq. (1),
    and a larger R lowers the gain with which its errors come back to the valve (Eq. (21) with the delay
    set, 16 against Table 5's 15 alone: AMPC-servo 0.65 / 1.56 / 2.60 mm at 0.2 / 0.3 / 0.4 s against
    1.16 / 2.37 / 3.62, MPC-servo 1.20 / 3.87 / 7.26 against 3.9 / 11.2 / 13.6; docs/control.md,
    "Transport delay"). 1 keeps ``servo.r``; delays of 0 and 1 always do (the paper's runs and the
    parallel master keep their bits)."""
    max_speed_mm_per_s: float = DEFAULT_MAX_SPEED_MM_PER_S
    """Glitch guard: a reading ``l(k)`` further from the last one used than the muscle can move in one
    sample (``max_speed_mm_per_s * ts_s``; 40 mm at the default 400 mm/s and 0.1 s) is taken for a
    sensor glitch: the law and the estimator use the one-step prediction ``l(k|k-1)`` instead (the
    estimator then learns nothing from it), and :attr:`DisplacementController.reading_held` says so.
    After :data:`HELD_READINGS_MAX` such readings in a row the next one is used as the new level.
    Without it one reading 50 mm off sent AMPC-servo's valve to 10 V for four samples and the adaptive
    estimate learnt from it (docs/control.md, "Sensor glitches"). From :data:`SPIKE_AFTER_S` after the
    start-up, a one-sample spike within that bound is held too (:data:`SPIKE_MM`,
    :attr:`DisplacementController.spike_limit_mm`), and a reading that repeats the last one to the
    bit where the prediction has the muscle move (a stale sample: :data:`REPEAT_MOVE_MM`). 0: all
    three off (every reading used)."""
    delay_correction: bool = True
    """With an input delay (``input_delay_samples`` 1 or more, or -1 once a delay hypothesis leads): predict
    ``l(k+1|k)`` with Eq. (1) plus a residual correction fitted online
    (:class:`~fmu_controller.delay_predictor.DelayPredictor`), which halves the delayed loop's
    tracking error; False: Eq. (1) alone. No effect on the undelayed law."""

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"ControllerSettings.method must be one of {', '.join(METHODS)}, got {self.method!r}")
        for name in ("ts_s", "startup_s", "probing_v", "forgetting", "max_speed_mm_per_s"):  # numpy numbers as Python floats
            object.__setattr__(self, name, real_number(getattr(self, name), what=f"ControllerSettings.{name}"))
        if not self.ts_s > 0:
            raise ValueError(f"ControllerSettings.ts_s must be a positive finite number, got {self.ts_s!r}")
        if len(self.p0) != ASYMMETRIC.n_params or not all(math.isfinite(p) and p > 0 for p in self.p0):
            raise ValueError(f"ControllerSettings.p0 must be {ASYMMETRIC.n_params} positive finite numbers, "
                             f"got {self.p0!r}")
        object.__setattr__(self, "input_delay_samples",
                           whole_number(self.input_delay_samples, what="ControllerSettings.input_delay_samples"))
        if not -1 <= self.input_delay_samples <= MAX_INPUT_DELAY_SAMPLES:
            raise ValueError(f"ControllerSettings.input_delay_samples must be -1 (detect) or a number of samples "
                             f"0 .. {MAX_INPUT_DELAY_SAMPLES}, got {self.input_delay_samples!r}")
        if not MIN_FORGETTING <= self.forgetting <= 1.0:
            raise ValueError(f"ControllerSettings.forgetting must be within {MIN_FORGETTING:g} .. 1 (1: none, as the "
                             f"paper), got {self.forgetting!r}")
        for part in ("servo", "ucp"):
            bounds = getattr(self, part)
            for name, value in (("u_min_v", bounds.u_min_v), ("u_max_v", bounds.u_max_v)):
                if not VALVE_MIN_V <= value <= VALVE_MAX_V:
                    raise ValueError(f"ControllerSettings.{part}.{name} must be within the valve's range "
                                     f"{VALVE_MIN_V:g} .. {VALVE_MAX_V:g} V, got {value!r}")
        if not 0.0 <= self.startup_s <= MAX_STARTUP_S:
            raise ValueError(f"ControllerSettings.startup_s must be within 0 .. {MAX_STARTUP_S:g} s, got {self.startup_s!r}")
        if not 0.0 <= self.max_speed_mm_per_s < math.inf:
            raise ValueError(f"ControllerSettings.max_speed_mm_per_s must be a finite number >= 0 [mm/s] (0: no glitch "
                             f"guard), got {self.max_speed_mm_per_s!r}")
        if not 0.0 <= self.probing_v <= MAX_PROBING_V:
            raise ValueError(f"ControllerSettings.probing_v must be within 0 .. {MAX_PROBING_V:g} V, got {self.probing_v!r}")
        object.__setattr__(self, "probing_phase", whole_number(self.probing_phase, what="ControllerSettings.probing_phase"))
        if not 0 <= self.probing_phase < MLS_LENGTH:
            raise ValueError(f"ControllerSettings.probing_phase must be a bit of the probe's sequence, 0 .. {MLS_LENGTH - 1}, "
                             f"got {self.probing_phase!r}")
        if not isinstance(self.startup_guard, bool):
            raise ValueError(f"ControllerSettings.startup_guard must be True or False, got {self.startup_guard!r}")
        if not isinstance(self.anti_windup, bool):
            raise ValueError(f"ControllerSettings.anti_windup must be True or False, got {self.anti_windup!r}")
        object.__setattr__(self, "delay_move_weight", real_number(self.delay_move_weight,
                                                                  what="ControllerSettings.delay_move_weight"))
        if not 0.0 < self.delay_move_weight <= MAX_DELAY_MOVE_WEIGHT:
            raise ValueError(f"ControllerSettings.delay_move_weight must be within 0 .. {MAX_DELAY_MOVE_WEIGHT:g} "
                             f"(0 excluded; 1: servo.r as it is), got {self.delay_move_weight!r}")
        if self.servo_mechanism and self.input_delay_samples not in (0, 1):
            # the law may run with R times the factor (servo_for_delay): valid servo settings too
            try:
                self.servo_for_delay(2)
            except ValueError as exc:
                r = max(self.servo.r) if isinstance(self.servo.r, tuple) else self.servo.r
                w = self.delay_move_weight
                # the bound the user sets is servo.r's, not the product's
                most = (f" (with this delay_move_weight, servo.r may be at most {_shown_down(MAX_WEIGHT / w)})"
                        if r * w > MAX_WEIGHT else "")
                raise ValueError(f"servo.r x ControllerSettings.delay_move_weight = {r:g} x {w:g}, "
                                 f"the move weight of the law for a delay of 2 samples or more, is not one: {exc}{most}"
                                 ) from None
        if not isinstance(self.delay_correction, bool):
            raise ValueError(f"ControllerSettings.delay_correction must be True or False, got {self.delay_correction!r}")
        if self.hysteresis_notch is not None and not isinstance(self.hysteresis_notch, bool):
            raise ValueError(f"ControllerSettings.hysteresis_notch must be None, True or False, "
                             f"got {self.hysteresis_notch!r}")
        if not (isinstance(self.box_lower, Mapping) and isinstance(self.box_upper, Mapping)):
            raise ValueError("ControllerSettings.box_lower and box_upper must be mappings of parameter name to bound "
                             f"(e.g. {{'b1': 0.6}}; a name left out is unbounded), got {type(self.box_lower).__name__} "
                             f"and {type(self.box_upper).__name__}")
        try:  # the estimator's own checks: names of Eq. (1), no NaN, lower <= upper
            lower, upper = self.constraint_region()
        except ValueError as exc:
            raise ValueError(f"ControllerSettings: {exc}") from None
        # read-only: a frozen setting's bound cannot be changed in place either
        object.__setattr__(self, "box_lower", read_only({n: float(lower[i]) for i, n in enumerate(ASYMMETRIC.names)
                                                         if n in self.box_lower}))
        object.__setattr__(self, "box_upper", read_only({n: float(upper[i]) for i, n in enumerate(ASYMMETRIC.names)
                                                         if n in self.box_upper}))

    def __hash__(self) -> int:
        return settings_hash(self)

    def __reduce__(self) -> tuple[Any, ...]:
        return settings_reduce(self)

    def constraint_region(self) -> tuple[np.ndarray, np.ndarray]:
        """The box C of Algorithm 1 as lower and upper bounds on Eq. (1)'s parameters, in
        :data:`~fmu_controller.hysteresis_model.ASYMMETRIC`'s order (-inf / +inf: unbounded)."""
        _, _, lower, upper = RLSSettings(p0=self.p0, box_lower=self.box_lower,
                                         box_upper=self.box_upper).resolve(ASYMMETRIC)
        return lower, upper

    def servo_for_delay(self, delay_samples: int) -> ServoMPCSettings:
        """The servo settings the law runs with for a delay of ``delay_samples`` samples: ``servo``, its
        move weight R times :attr:`delay_move_weight` from 2 samples on."""
        f = self.delay_move_weight
        if delay_samples < 2 or f == 1.0:
            return self.servo
        r = self.servo.r
        return replace(self.servo, r=tuple(x * f for x in r) if isinstance(r, tuple) else r * f)

    @property
    def adaptive(self) -> bool:
        return self.method.startswith("ampc")

    @property
    def servo_mechanism(self) -> bool:
        return self.method.endswith("servo")

    @property
    def preview_samples(self) -> int:
        """How many future reference samples the method needs: ``Hp``, plus the input delay
        (:data:`AUTO_INPUT_DELAY_SAMPLES` for -1, which may decide for any up to it)."""
        return (self.servo.hp if self.servo_mechanism else self.ucp.hp) + preview_lead(self.input_delay_samples)


def preview_lead(input_delay_samples: int) -> int:
    """The reference samples beyond ``Hp`` that a controller with ``input_delay_samples`` needs: the
    delay, and :data:`AUTO_INPUT_DELAY_SAMPLES` for -1 (:attr:`ControllerSettings.preview_samples`).

    Parameters
    ----------
    input_delay_samples : int
        The controller's input delay [samples], or -1 (decided from the data).
    """
    return AUTO_INPUT_DELAY_SAMPLES if input_delay_samples == -1 else input_delay_samples


def _shown_down(x: float) -> str:
    """``x`` > 0 to six significant digits, rounded down: a largest allowed value that is itself allowed."""
    scale = 10.0 ** (5 - math.floor(math.log10(x)))
    return f"{math.floor(x * scale) / scale:g}"
