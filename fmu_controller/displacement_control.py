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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from .argument_checks import real_number, whole_number
from .delay_predictor import DelayPredictor
from .hysteresis_model import ASYMMETRIC, ModelState
from .identification import PAPER_TS_S
from .methods import METHOD_CODES, METHODS
from .prediction import MAX_INPUT_DELAY_SAMPLES, guard_bounds
from .probing import MLS_LENGTH, probe_v
from .read_only_fields import read_only, settings_hash, settings_reduce
from .rls import TABLE2_LOWER, TABLE2_UPPER, ConstrainedRLS, RLSSettings
from .servo_mpc import ServoMPC, ServoMPCSettings, integrator_step
from .servo_settings import MAX_WEIGHT
from .ucp_mpc import UCPSettings, held_input_run, ucp_move

__all__ = ["METHODS", "METHOD_CODES", "MAX_STARTUP_S", "MAX_DELAY_MOVE_WEIGHT", "MAX_INPUT_DELAY_SAMPLES",
           "AUTO_INPUT_DELAY_SAMPLES", "DELAY_FORGET", "DELAY_RATIO", "DELAY_MIN_SAMPLES", "DELAY_TIE_RATIO",
           "HOLD_AFTER_SAMPLES", "B1_KEPT_FRACTION", "GUARD_JUMP_FRACTION", "GUARD_JUMPS", "pushed_at_limit", "pinned_side", "limit_side",
           "full_range_jump", "preview_lead", "VALVE_MIN_V", "VALVE_MAX_V", "MIN_FORGETTING", "HELD_AGAINST_MM",
           "SPIKE_MM", "SPIKE_SPREAD", "SPIKE_FORGET", "SPIKE_AFTER_S", "REPEAT_MOVE_MM", "REPEAT_SPREAD",
           "REF_STEP_SETTLE_S", "settle_samples",
           "L_RANGE_MM", "FASTEST_MUSCLE_MM_PER_S", "DEFAULT_MAX_SPEED_MM_PER_S", "HELD_READINGS_MAX",
           "STUCK_AT_LIMIT_S", "stuck_reading_message", "DEFAULT_DELAY_MOVE_WEIGHT",
           "HELD_WARN_S", "held_against_error", "held_against_cause", "held_reading_message",
           "P0_TABLE5", "P0_TABLE8", "ControllerSettings", "ControlStep",
           "DisplacementController"]


#: ``input_delay_samples = -1``: the largest delay [samples] it scores and may decide, and the
#: reference samples beyond ``Hp`` it takes (:func:`preview_lead`): 0.5 s at the paper's Ts = 0.1 s. At a
#: shorter Ts a longer delay is set (up to :data:`MAX_INPUT_DELAY_SAMPLES`): -1's decision rule below was
#: measured over these six hypotheses, and each costs a model state and a prediction a sample until it
#: decides.
AUTO_INPUT_DELAY_SAMPLES = 5

#: ``input_delay_samples = -1``: weight of the newest squared one-step error in the running means
#: (a memory of about 50 samples, 5 s at Ts = 0.1 s: over one second the two hypotheses' errors
#: overlap, the sequential/parallel ratio reaching 1.53 in a sequential loop and only 2.15 in a
#: parallel one; over five seconds at most 1.03 and at least 1.43, measured over every method,
#: 44/68 N, 0.1/0.2 Hz, two seeds) ...
DELAY_FORGET = 0.02
#: ... one hypothesis must explain the data this many times better (in mean square) to be decided,
#: between those two figures (measured with the undelayed law running; with the delayed law the
#: decision came at the minimum in every case of tests/test_displacement_control.py) ...
DELAY_RATIO = 1.25
#: ... after at least this many samples compared.
DELAY_MIN_SAMPLES = 50
#: Servo methods: a delay of 1 or more decided, and the next longer one within this factor of its mean
#: square: the rig's delay lies between the two samples (0.15 s at Ts = 0.1 s scored 1 and 2 within
#: 0.4-4 %, where a whole number of samples leaves the next one 1.09-1.96 times worse), and the longer
#: one is decided: the servo law tracked better so (mean |r - l| over 40-90 s, 0.15 s: AMPC-servo 0.36
#: against 0.68 mm, MPC-servo 0.53 against 2.3-2.5, swinging; 0.35 s: AMPC-servo 0.98 against 3.55;
#: MPC-servo's fixed predictor is poor either way there, 9.2 against 4.3-5.9). The coincidence point
#: tracked a little worse with the longer one and keeps the better scored (AMPC-UCP at 0.15 s: 2, 0.64-0.70
#: mm; 1 set, 0.63).
DELAY_TIE_RATIO = 1.05
#: A delay of 2 samples or more that the scores do not fall towards from 0 (outside
#: ``DisplacementController._valley_beyond_one``) is still decided where it explains the data this many
#: times better than both 0 and 1: a rig's 0.4-s delay under MPC-UCP at 68 N, 0.2 Hz scored 5.31, 3.67,
#: 4.77, 2.86, 1, 3.0 times the best for 0..5 (a bump at 2), where 1 tracked to 11 mm and 4 to 3.8; a
#: loop chattering with a period of a few samples, which scores that period like 0, reached 1.68
#: (h = Ts/4 in a parallel master) and 1.31 (a fixed predictor on an off-nominal rig).
DELAY_CLEAR_RATIO = 2.0
#: ``input_delay_samples = -1``: if neither hypothesis has won by :data:`DELAY_RATIO` after this many
#: samples (a delay of a fraction of a sample: a rig's transport delay), the one that predicts better
#: is taken.
DELAY_DECIDE_BY_SAMPLES = 300
#: ``input_delay_samples`` set: the first this many samples are scored as -1 scores them (the delays
#: 0 .. max(:data:`AUTO_INPUT_DELAY_SAMPLES`, the delay set)), to tell a set delay the measurements
#: contradict (:attr:`DisplacementController.delay_evidence`): as long as -1 may take to decide,
#: since the start-up mode hides a wrong delay for its first seconds (100 samples do not tell
#: AMPC-servo's 0 in a parallel master); the scores cost about 20 us a sample (the direct loop of
#: benchmarks/fmu_cosim.py: 77 and 93 us a sample over 40 s without and with).
DELAY_CHECK_SAMPLES = DELAY_DECIDE_BY_SAMPLES

#: ``input_delay_samples = -1``, undecided: the delayed law uses the corrected one-step prediction
#: (:class:`~fmu_controller.delay_predictor.DelayPredictor`) once this many samples are compared and
#: the parallel hypothesis leads.
DELAY_LEAD_SAMPLES = 20
#: The sampling period [s] at which the delay scores' memory and sample counts above were measured:
#: at another ``Ts`` they span the same seconds (:meth:`DisplacementController.delay_check_samples`).
DELAY_SCORES_TS_S = 0.1

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

#: Largest ``ControllerSettings.delay_move_weight``.
MAX_DELAY_MOVE_WEIGHT = 1000.0

#: Longest start-up mode ``ControllerSettings.startup_s`` [s].
MAX_STARTUP_S = 600.0
#: Default start-up mode ``ControllerSettings.startup_s`` [s] (docs/control.md, "Start-up").
DEFAULT_STARTUP_S = 12.0

#: Every contraction [mm] the plant FMU's parameter ranges allow (rest lengths up to 5000 mm, an
#: encoder offset of +-100 mm, stretch under the load): a reading ``l`` outside is refused (by the
#: controller FMU and :meth:`DisplacementController.step` alike), and its ``r`` inputs and built-in
#: sine stay within it.
L_RANGE_MM = (-1000.0, 5000.0)

#: The simulated rig's fastest move [mm/s]: from rest to 10 V and back at 0.25 MPa and 10-100 N.
FASTEST_MUSCLE_MM_PER_S = 200.0
#: Fastest the muscle moves [mm/s] as far as the glitch guard is concerned
#: (``ControllerSettings.max_speed_mm_per_s``): twice the simulated rig's fastest, room for a faster rig.
DEFAULT_MAX_SPEED_MM_PER_S = 2.0 * FASTEST_MUSCLE_MM_PER_S
#: Readings held in a row, at most, before one that stays as far from the last used is taken as the new
#: level (an encoder re-zeroed, a real step): a glitch lasts a sample or two.
HELD_READINGS_MAX = 3
#: From :data:`SPIKE_AFTER_S` after the start-up on, a reading further from the one-step prediction
#: than the larger of :data:`SPIKE_MM` and :data:`SPIKE_SPREAD` times the running mean |prediction
#: error| (weight :data:`SPIKE_FORGET` a sample: about 50 samples, 5 s at Ts = 0.1 s) is taken for a
#: one-sample spike of the sensor (a potentiometer's wiper lifting, an ADC's bad conversion) where the
#: two readings before came within half that (a loop whose errors swing already is not told from a
#: spike): the prediction is used instead, once. Without it a spike
#: under the max_speed bound (40 mm) is used as a reading, and one 30 mm low moves the muscle by 36-40
#: mm. The guard waits :data:`REF_STEP_SETTLE_S` after the preview moves by more than
#: :data:`SPIKE_MM` in a sample (a step: the fixed predictors miss by 7.5 mm in its transient, which
#: starts as the step enters the preview), and as long after a reading as far off follows a held one
#: (a model that predicts badly just then). On 68 runs without spikes (the paper's cells, load steps,
#: staircases, delayed rigs, 0.5-mm sensor noise, rigs with constants off) it holds none.
SPIKE_MM = 5.0
SPIKE_SPREAD = 10.0
SPIKE_FORGET = 0.02
SPIKE_AFTER_S = 5.0
#: A reading equal to the last one, to the bit, where the one-step prediction has the muscle move by
#: more than the larger of :data:`REPEAT_MOVE_MM` and :data:`REPEAT_SPREAD` times the running mean
#: |prediction error| (the spike guard's), is taken for a stale sample (a data acquisition that
#: delivered the last value again): the prediction is used instead, for the first repeat only (a
#: muscle that stopped, at an end stop or on a shut supply, reads the same again, and that reading is
#: used). An encoder read with noise never repeats to the bit while the muscle moves a millimetre in a
#: sample; without the guard one repeat at the fastest point of the paper's sine (1.9 mm a sample)
#: made the law push the valve for a move that had happened (docs/control.md, "Stale readings"). The
#: same gates as the spike guard's (from :data:`SPIKE_AFTER_S` after the start-up). The threshold sits
#: between the misses measured at a stale repeat (4.3-5.4 times the fixed predictors' mean error) and
#: those of a muscle that really stopped short (backlash, a swinging loop, a poor predictor: 3.4-3.9
#: times).
REPEAT_MOVE_MM = 1.0
REPEAT_SPREAD = 4.0
#: The first seconds after a reference step are its transient: the spike guard waits them out, and the
#: loop's watch does not count their swings.
REF_STEP_SETTLE_S = 3.0


#: The spike guard's state at the start: the running mean |one-step prediction error| [mm], the last
#: reading's |error| [mm] (NaN: none yet), the sample the guard acts from (after a reference step's
#: transient), the preview's last sample at the last step [mm], the |error| of the reading before the
#: last [mm].
_NEW_SPIKE_GUARD = (math.nan, math.nan, 0, math.nan, math.nan)


def settle_samples(ts_s: float) -> int:
    """:data:`REF_STEP_SETTLE_S` in samples of ``ts_s`` [s].

    Parameters
    ----------
    ts_s : float
        Sampling period [s].
    """
    return int(round(REF_STEP_SETTLE_S / ts_s))


#: Seconds the command sits at each of the valve's limits, within one stretch of readings that have not
#: changed at all, that tell a stuck sensor: the valve held open, then shut (or the other way round),
#: moves a working muscle by millimetres within a second, whatever its transport delay (at most 0.5 s
#: here) or end stop; the encoder resolves 0.01 mm (:attr:`DisplacementController.reading_stuck`).
STUCK_AT_LIMIT_S = 2.0

#: Default ``ControllerSettings.delay_move_weight``: 16 tracked better than 4 and 32 in most cells of
#: benchmarks/transport_delay.py (every servo cell better than 4; 10 of 16 off-nominal delayed rigs
#: within 2 mm against 8 with 4 and 9 with 32), and 4 left AMPC-servo limit-cycling at 0.35 s.
DEFAULT_DELAY_MOVE_WEIGHT = 16.0

#: Default amplitude [V] of the start-up mode's probing signal (``ControllerSettings.probing_v``).
DEFAULT_PROBING_V = 0.5
#: Largest ``ControllerSettings.probing_v`` [V]: a quarter of the valve's 0-10 V range.
MAX_PROBING_V = 2.5

#: The proportional valve's command range [V] (Table 1, "Range of input voltage"; Eq. (19)): the servo's and UCP's ``u_min_v`` and
#: ``u_max_v`` lie within it. A bound beyond it is a command the valve clips, and the adaptive
#: estimator, which sees the command, would learn from inputs the valve never received.
VALVE_MIN_V, VALVE_MAX_V = 0.0, 10.0

#: Smallest ``ControllerSettings.forgetting``: below it Algorithm 1 forgets half its information
#: every sample and its estimate follows the measurement noise (0.3: ``u_c`` at thousands of V,
#: 9 mm of Eq. (21) error).
MIN_FORGETTING = 0.5

#: ``ControllerSettings.startup_guard``: the start-up mode leaves ``theta0`` for the estimate once the
#: command has jumped across this fraction of the valve's range in one sample ...
GUARD_JUMP_FRACTION = 0.9
#: ... this many times since the estimator started: a law that slams the valve end to end. (Two
#: happen in a sound start: the delayed law that ``input_delay_samples = -1`` starts with, one sample
#: early in a sequential master, can jump twice before the delay is decided.)
GUARD_JUMPS = 3

#: ``P(0)`` of the AMPC for the 0.1 Hz experiments (Table 5).
P0_TABLE5 = (200.0, 200.0, 200.0) + (50.0,) * 8 + (20.0,) * 4
#: ``P(0)`` of the AMPC for the 0.2 Hz experiments (Table 8).
P0_TABLE8 = (1000.0, 1000.0, 1000.0) + (250.0,) * 8 + (150.0,) * 4


#: ``hysteresis_notch``: the predicted H(k+1|k), H(k+2|k) stay within one and two times
#: ``NOTCH_RATE_FACTOR x`` (the larger of H's last two changes) ``+ NOTCH_FLOOR_MM`` of H(k) [mm].
#: In tracking (the paper's sines, both loads) the predictions move under 0.5 mm per sample and the
#: bound never acts; after a large reference step, unbounded on the adaptive estimate's jump, they
#: reach hundreds to thousands of mm, the QP input u_c thousands of volts, and the valve slams shut
#: for a sample.
NOTCH_RATE_FACTOR = 2.0
NOTCH_FLOOR_MM = 1.0


@dataclass(frozen=True, kw_only=True)
class ControllerSettings:
    """Settings of a :class:`DisplacementController`."""

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


def _shown_down(x: float) -> str:
    """``x`` > 0 to six significant digits, rounded down: a largest allowed value that is itself allowed."""
    scale = 10.0 ** (5 - math.floor(math.log10(x)))
    return f"{math.floor(x * scale) / scale:g}"


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


def held_reading_message(settings: ControllerSettings, reading_mm: float, used_mm: float, last_mm: float,
                         spike_mm: float | None) -> str:
    """What to tell of a reading :attr:`DisplacementController.reading_held` reports (without the time):
    the ``reading_mm`` [mm], the prediction ``used_mm`` instead, the last reading used ``last_mm``, and
    ``spike_mm``, its :attr:`~DisplacementController.spike_limit_mm` (None: a jump beyond ``max_speed``,
    or, where the reading is ``last_mm`` itself, a stale repeat: :data:`REPEAT_MOVE_MM`).

    Parameters
    ----------
    settings : ControllerSettings
        The controller's settings (``max_speed_mm_per_s`` [mm/s] and ``ts_s`` [s] for a jump's
        message).
    reading_mm : float
        The reading held [mm].
    used_mm : float
        The one-step prediction used instead [mm].
    last_mm : float
        The last reading used [mm].
    spike_mm : float or None
        The spike limit [mm] for a one-sample spike, or None for a jump beyond ``max_speed`` or a
        stale repeat.
    """
    if spike_mm is None and reading_mm == last_mm:
        return (f"the reading l = {reading_mm:g} mm repeats the last one to the bit while the one-step prediction has "
                f"the muscle move {abs(used_mm - last_mm):.3g} mm (more than {REPEAT_MOVE_MM:g} mm and "
                f"{REPEAT_SPREAD:g} times the mean error): taken for a stale sample of the data acquisition, the law "
                f"and the estimator used the prediction {used_mm:.4g} mm instead (a second repeat is used, as a "
                "muscle that stopped; max_speed = 0 turns this off)")
    if spike_mm is not None:
        return (f"the reading l = {reading_mm:g} mm is {abs(reading_mm - used_mm):.3g} mm from the one-step prediction "
                f"{used_mm:.4g} mm, more than the {spike_mm:.3g} mm it has lately come within (the larger of "
                f"{SPIKE_MM:g} mm and {SPIKE_SPREAD:g} times the mean error): taken for a one-sample spike of the sensor, "
                "the law and the estimator used the prediction instead (the next reading is not held as a spike; "
                "max_speed = 0 turns this off)")
    s = settings
    return (f"the reading l = {reading_mm:g} mm is {abs(reading_mm - last_mm):.3g} mm from the last one used, more than "
            f"the muscle moves in a sample (max_speed x Ts = {s.max_speed_mm_per_s:g} x {s.ts_s:g} = "
            f"{s.max_speed_mm_per_s * s.ts_s:g} mm): taken for a sensor glitch, the law and the estimator used the "
            f"prediction {used_mm:.4g} mm instead (after {HELD_READINGS_MAX} in a row the reading is taken as the new "
            "level; max_speed = 0 turns this off)")


def stuck_reading_message(t_s: float, reading_mm: float, unchanged_s: float) -> str:
    """What to tell of a reading :attr:`DisplacementController.reading_stuck` reported at ``t_s`` [s]:
    ``reading_mm`` [mm], unchanged for ``unchanged_s`` [s].

    Parameters
    ----------
    t_s : float
        Time of the report [s].
    reading_mm : float
        The stuck reading [mm].
    unchanged_s : float
        How long it has not changed [s].
    """
    return (f"t = {t_s:.12g} s: the reading l = {reading_mm:g} mm has not changed at all for {unchanged_s:.4g} s while "
            f"the command sat at each of the valve's limits for {STUCK_AT_LIMIT_S:g} s or more, which moves a working "
            "muscle by millimetres: the sensor is stuck or disconnected (a DAQ holding its last value?), or the supply "
            "is shut with the muscle at rest. The controller goes on with the reading")


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


def _valid_spike_guard(spike: Any) -> bool:
    """Whether ``spike`` is a spike guard's state (``_NEW_SPIKE_GUARD``'s fields) a controller could save."""
    if not isinstance(spike, (list, tuple)) or len(spike) != 5:
        return False
    try:
        mean, last, acts_from, r, earlier = (float(spike[0]), float(spike[1]), spike[2], float(spike[3]),
                                             float(spike[4]))
    except (TypeError, ValueError):
        return False
    errors_ok = all(x != x or 0.0 <= x < math.inf for x in (mean, last, earlier))
    whole = not isinstance(acts_from, bool) and isinstance(acts_from, (int, float)) and int(acts_from) == acts_from >= 0
    return errors_ok and whole and (r != r or math.isfinite(r))


def _valid_still(still: Any) -> bool:
    """Whether ``still`` is a stretch of identical readings that :meth:`DisplacementController.get_state`
    could have saved: ``[reading or NaN, samples, samples after the lower limit, after the upper, said]``."""
    try:
        if not isinstance(still, (list, tuple)) or len(still) != 5 or still[4] not in (True, False):
            return False
        reading, counts = float(still[0]), still[1:4]
        if any(isinstance(n, bool) or int(n) != n or int(n) < 0 for n in counts):
            return False
        return ((math.isnan(reading) or L_RANGE_MM[0] <= reading <= L_RANGE_MM[1])
                and int(counts[1]) + int(counts[2]) <= int(counts[0]))
    except (TypeError, ValueError, OverflowError):
        return False


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
        self._scored = AUTO_INPUT_DELAY_SAMPLES if self._auto else max(AUTO_INPUT_DELAY_SAMPLES,
                                                                        settings.input_delay_samples)
        # the scores' memory and windows span the seconds they were measured over at DELAY_SCORES_TS_S:
        # at Ts = 0.02 s 300 samples are 6 s, inside the start-up mode, where a set delay that was right
        # was scored wrong (exactly the constants at 0.1 s: the scale is 1.0)
        scale = settings.ts_s / DELAY_SCORES_TS_S
        self._forget = DELAY_FORGET * scale if scale < 1.0 / DELAY_FORGET else 1.0
        self._min_n, self._decide_n, self._check_n, self._lead_n = (
            max(1, round(n / scale)) for n in (DELAY_MIN_SAMPLES, DELAY_DECIDE_BY_SAMPLES, DELAY_CHECK_SAMPLES,
                                               DELAY_LEAD_SAMPLES))
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
        self._max_jump = settings.max_speed_mm_per_s * settings.ts_s  # 0: no glitch guard
        self._stuck_n = max(1, int(math.ceil(STUCK_AT_LIMIT_S / settings.ts_s - 1e-9)))
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
        self._held_in_a_row = 0  # readings the glitch guard held in a row
        self.reading_held: tuple[float, float, float] | None = None
        """The last step's reading taken for a glitch, a spike or a stale repeat (then equal to the last
        one used), the value used instead and the last one used before [mm]; None where the reading
        was used."""
        self.spike_limit_mm: float | None = None
        """Where :attr:`reading_held` is a one-sample spike (further from the prediction than
        :data:`SPIKE_MM` and :data:`SPIKE_SPREAD` times the usual error), the distance it exceeded [mm];
        None where it is a jump beyond ``max_speed_mm_per_s`` or no reading was held."""
        self._spike = list(_NEW_SPIKE_GUARD)
        # the stretch of identical readings: its reading (NaN before the first), its samples, the
        # samples of it that followed a command at the lower and at the upper valve limit, and whether
        # reading_stuck has said it
        self._still = [math.nan, 0, 0, 0, False]
        self.reading_stuck: tuple[float, float] | None = None
        """On the step that tells it, once a stretch: the reading [mm] that has not changed at all
        while the command sat at each of the valve's limits for :data:`STUCK_AT_LIMIT_S` or more, and
        how long it has not changed [s] (a stuck or disconnected sensor, a DAQ holding its last value,
        or the supply shut with the muscle at rest); None otherwise. The law goes on with the reading."""
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
        self._outs = [(0.0, 0.0)] * (self._scored + 1)
        # the mean squared one-step errors of Eq. (1) under each delay 0 .. _scored (0: a sequential
        # master, 1: a parallel one, more: a transport delay too), each with its own model state;
        # samples compared so far
        self._ms = [0.0] * (self._scored + 1)
        self._compared = 0
        self._lin0 = self.theta0[:3].tolist()
        self._shadows = [ModelState(ASYMMETRIC, l_init=(l0, l0, l0), u_init=0.0)
                         for _ in range(self._scored + 1)]
        if self._delay_predictor is not None:
            self._delay_predictor.reset(l0, 0.0)

    def _spike_limit(self) -> float:
        """How far [mm] a reading may lie from its one-step prediction before it is a spike: the larger of
        :data:`SPIKE_MM` and :data:`SPIKE_SPREAD` times the running mean error (inf before one)."""
        mean = self._spike[0]
        return max(SPIKE_MM, SPIKE_SPREAD * mean) if mean == mean else math.inf

    def _guarded(self) -> bool:
        """Whether the spike and repeat guards act at this sample: a prediction to use, past the
        start-up and :data:`SPIKE_AFTER_S` after it (an estimate still learning predicts badly)."""
        return (math.isfinite(self._predicted) and not self.in_startup
                and self.samples_since_start > int(round(SPIKE_AFTER_S / self.settings.ts_s)) + self._blend_n)

    def _stale(self, l: float) -> bool:
        """Whether ``l`` [mm], a reading equal to the last one used, is a stale sample: the prediction
        has the muscle move further than :data:`REPEAT_MOVE_MM` and :data:`REPEAT_SPREAD` times the
        running mean prediction error."""
        mean = self._spike[0]
        # not in a reference step's transient either, where a muscle held by its friction stops short of
        # a prediction that misses by a millimetre (the spike guard's wait, spike[2])
        return (self._guarded() and mean == mean and self._k >= self._spike[2]
                and abs(self._predicted - l) > max(REPEAT_MOVE_MM, REPEAT_SPREAD * mean))

    def _spike_guard(self, l: float, r: float) -> float:
        """The reading ``l`` [mm] to use: the one-step prediction where ``l`` is a one-sample spike
        (:data:`SPIKE_MM`; ``r``: the preview's last sample [mm], whose steps pause the guard from when
        the law first sees them), else ``l``, the running mean of the prediction errors updated with it."""
        spike = self._spike
        ts = self.settings.ts_s
        if abs(r - spike[3]) > SPIKE_MM:  # a step at the preview's end: the law acts on it now
            spike[2] = self._k + self._need + settle_samples(ts)
        spike[3] = r
        predicted = self._predicted
        if not math.isfinite(predicted):
            return l
        error = abs(l - predicted)
        limit = self._spike_limit()
        before = spike[1]
        # a reading after two ordinary ones (within half the limit); not in the start-up, whose estimate is
        # still learning (an open-loop theta0 at 0.3 MPa missed by 60 mm there), nor in the seconds after
        # it; and the prediction used instead must itself be a reading the muscle could give
        if (error > limit and before <= 0.5 * limit and spike[4] <= 0.5 * limit and self._k >= spike[2] and self._guarded()
                and abs(predicted - self._state.last_l) <= self._max_jump):
            spike[1], spike[4] = error, before
            self.spike_limit_mm = limit
            self.reading_held = (l, predicted, self._state.last_l)
            return predicted
        if before > limit and error > limit:
            # a reading as far off after a held (or far-off) one: no spike but a model that predicts this
            # badly now; the guard waits a transient out and takes the error in whole
            spike[2] = self._k + settle_samples(ts)
            limit = error
        spike[1], spike[4] = error, before
        # an error beyond the limit counts as the limit: a transient does not blunt the guard
        spike[0] = error if spike[0] != spike[0] else spike[0] + SPIKE_FORGET * (min(error, limit) - spike[0])
        return l

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
        self.reading_held = None
        self.reading_stuck = None
        still = self._still
        if l == still[0]:
            self._watch_still(still)
        else:
            still[:] = [l, 0, 0, 0, False]
        self.spike_limit_mm = None
        if self._max_jump and k > 0:
            last = state.last_l
            if abs(l - last) <= self._max_jump:
                self._held_in_a_row = 0
                if still[1] == 1 and l == last and self._stale(l):
                    self.reading_held = (l, self._predicted, last)
                    l = self._predicted
                else:
                    l = self._spike_guard(l, rl[-1])
            elif self._held_in_a_row >= HELD_READINGS_MAX or (
                    not self._held_in_a_row and abs(l - state.l_prev_mm) <= self._max_jump
                    and self._spike[1] > self._spike_limit()):
                # the new level; or, after a used reading that was far from its prediction, within reach of
                # the reading before it: that one was a spike under the bound, and the readings after it
                # are the muscle's. The model's state has jumped: its predictions are no guide for a while
                self._held_in_a_row = 0
                spike = self._spike
                spike[1], spike[4] = abs(l - self._predicted) if math.isfinite(self._predicted) else math.nan, spike[1]
                spike[2], spike[3] = k + settle_samples(self.settings.ts_s), rl[-1]
            else:  # further than the muscle moves in a sample: a glitch, the prediction used instead
                self._held_in_a_row += 1
                used = self._predicted if math.isfinite(self._predicted) else last
                self.reading_held = (l, used, last)
                l = used
        error = 0.0 if math.isnan(self._predicted) else l - self._predicted
        if k < self._ramp_n:
            rl = self._lead_in(rl, l)

        # -1 scores the delays until it decides; a set delay over DELAY_CHECK_SAMPLES (delay_evidence)
        if (not self._decided) if self._auto else self._compared < self._check_n:
            if k == 0:  # the shadow models start from the first measurement
                for shadow in self._shadows:
                    shadow.observe_unchecked(l, self._lin0[0], self._lin0[1], self._lin0[2])
            elif self._auto:
                self._detect_delay(l)
            else:  # a delay set: scored over the first samples as -1 would, to tell a wrong one (delay_evidence)
                self._score_delays(l)

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
        """``input_delay_samples = -1``: score the fixed prior model ``theta0``'s prediction of ``l(k)``
        (Eq. (1)) under each delay ``d = 0 .. AUTO_INPUT_DELAY_SAMPLES``: the valve had the output
        ``y(k-1-d)`` over ``[t_k-1, t_k)`` (0: a sequential master, 1: a parallel one, more: a rig's
        transport delay as well), each hypothesis with its own model state. The controller starts with
        the delayed law (``d = 1``). Once the best delay of 2 or more that the scores fall towards from 1
        (:meth:`_valley_beyond_one`) is :data:`DELAY_RATIO` times better than both 0 and 1, the law switches
        to it; else once the parallel hypothesis is that much
        better than the sequential one it keeps the delayed law (or switches to a longer delay that
        scores better still), once the sequential one is, it switches to the undelayed law; after
        :data:`DELAY_DECIDE_BY_SAMPLES` samples the best is taken. A servo method takes the longer of
        two neighbouring delays that score within :data:`DELAY_TIE_RATIO` (a rig's delay between
        them). A switch corrects the model's input over ``[t_k-1, t_k)`` to the command the valve had
        under the delay decided. (The prior, not the adaptive estimate: in the first seconds the
        estimate can be far off.)"""
        self._score_delays(l)
        ms = self._ms
        if self._compared < self._min_n:
            return
        ms_seq, ms_par = ms[0], ms[1]
        late = self._compared >= self._decide_n
        # the valley's delays, and any other that explains the data DELAY_CLEAR_RATIO times better than 0 and 1
        clear = [d for d in range(2, len(ms)) if DELAY_CLEAR_RATIO * ms[d] < min(ms_seq, ms_par)]
        far = min((*self._valley_beyond_one(), *clear), key=ms.__getitem__, default=None)
        if far is not None and (DELAY_RATIO * ms[far] < min(ms_seq, ms_par) or (late and ms[far] < min(ms_seq, ms_par))):
            self._decide_delay(self._longer_if_tied(far))  # a rig's transport delay: each command far samples on
        elif DELAY_RATIO * ms_par < ms_seq or (late and ms_par <= ms_seq):
            # a parallel master (or a rig's delay of about a sample): the delayed law stays, unless a longer
            # delay scores better still (a rig's delay between 1 and 2 samples)
            d = self._longer_if_tied(far if far is not None and ms[far] < ms_par else 1)
            if d == 1:
                self._decided = True
            else:
                self._decide_delay(d)
        elif DELAY_RATIO * ms_seq < ms_par or late:
            # a sequential master: the valve had the last output over [t_k-1, t_k), not the one
            # before; the law runs undelayed from now on
            self._decide_delay(0)

    def _valley_beyond_one(self) -> range:
        """The delays of 2 samples or more that a rig's transport delay can be on the scores: those reached
        from 0, through 1, while each next one scores no worse than :data:`DELAY_TIE_RATIO` times the one
        before. A transport delay's scores fall towards it from the shorter delays. A loop that chatters
        with a period of a few samples (the delayed law on a rig whose command acts within a fraction of a
        sample: a parallel master sub-stepping at Ts/4; the delayed law of a fixed predictor on a rig whose
        constants are off) repeats its command every period, so the delay of one period scores as well as
        0 whatever lies between (0.025 s at 68 N, 0.2 Hz: 1.68, 3.68, 6.98, 1 times the best for 0 .. 3
        samples; deciding 3 tracks MPC-servo to 2.0 mm, 0 to 0.42; MPC-UCP on an off-nominal rig without a
        delay: 1.31, 1.86, 1.0, deciding 2 tracked to 1.60 mm, 0 to 1.18)."""
        ms, d = self._ms, 0
        while d + 1 < len(ms) and ms[d + 1] <= DELAY_TIE_RATIO * ms[d]:
            d += 1
        return range(2, d + 1)

    def _longer_if_tied(self, d: int) -> int:
        """``d``, or for a servo method ``d + 1`` where that one scores within :data:`DELAY_TIE_RATIO` of
        it (a delay between the two samples: the longer one is compensated)."""
        ms = self._ms
        longer = self.settings.servo_mechanism and d + 1 < len(ms) and ms[d + 1] <= DELAY_TIE_RATIO * ms[d]
        return d + 1 if longer else d

    def _score_delays(self, l: float) -> None:
        """One sample of :meth:`_detect_delay`'s scores: ``theta0``'s one-step prediction error of ``l(k)``
        [mm] under each delay, into the running mean squares."""
        th0, lin0, outs, ms, forget = self.theta0, self._lin0, self._outs, self._ms, self._forget
        for d, shadow in enumerate(self._shadows):
            u = outs[d][0]
            shadow.apply(u)
            e = l - held_input_run(shadow, th0, lin0, u, 1)[0]
            shadow.observe_unchecked(l, lin0[0], lin0[1], lin0[2])
            ms[d] += forget * (e * e - ms[d])
        self._compared += 1

    @property
    def delay_evidence(self) -> tuple[int, float] | None:
        """With ``input_delay_samples`` set: once the first :data:`DELAY_CHECK_SAMPLES` samples are
        scored as -1 scores them (:meth:`_detect_delay`, the delays 0 .. :attr:`largest_scored_delay`),
        ``(d, ratio)`` when another delay ``d`` explains the measurements :data:`DELAY_RATIO` times better
        or more (``ratio``: the set delay's mean squared one-step error over ``d``'s), else None (also
        before, and with -1)."""
        if not self.delay_checked:
            return None
        ms, lag = self._ms, self._lag
        best = min(range(len(ms)), key=ms.__getitem__)
        if best != lag and DELAY_RATIO * ms[best] < ms[lag]:
            return best, ms[lag] / ms[best] if ms[best] > 0.0 else math.inf
        return None

    @property
    def delay_checked(self) -> bool:
        """With ``input_delay_samples`` set: whether the first :attr:`delay_check_samples` samples have
        been scored, so that :attr:`delay_evidence` None means that no other delay explained them
        better (False before, and with -1)."""
        return not self._auto and self._compared >= self._check_n

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
        return self._check_n

    @property
    def largest_scored_delay(self) -> int:
        """The largest delay [samples] the controller scores: :data:`AUTO_INPUT_DELAY_SAMPLES` for -1
        (the longest it may decide), else the larger of that and the delay set. Evidence for it may mean a
        longer delay still."""
        return self._scored

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
            if self._decided or (self._compared >= self._lead_n and self._ms[1] < self._ms[0]):
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

    def _watch_still(self, still: list) -> None:
        """Count a reading equal to the last one: after a command at a valve limit, towards that
        limit's time; set :attr:`reading_stuck` when both reach :data:`STUCK_AT_LIMIT_S`."""
        still[1] += 1
        u = self._outs[0][0]  # the command that followed the last reading
        u_min, u_max = self._law_bounds
        if u <= u_min + 1e-9:
            still[2] += 1
        elif u >= u_max - 1e-9:
            still[3] += 1
        if not still[4] and still[2] >= self._stuck_n and still[3] >= self._stuck_n:
            still[4] = True
            self.reading_stuck = (still[0], still[1] * self.settings.ts_s)

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
            "predicted": self._predicted, "held_in_a_row": self._held_in_a_row, "still": list(self._still),
            "spike": list(self._spike),
            "u_next": self._u_next, "uc_next": self._uc_next, "h_prev": self._h_prev,
            "h_prev2": self._h_prev2, "l_start": self._l_start,
            "delayed": self._lag != 0, "decided": self._decided, "lag": self._lag,
            "in_flight": [list(pair) for pair in self._later],
            "u_out": [u for u, _ in self._outs], "uc_out": [uc for _, uc in self._outs],
            "delay_scores": list(self._ms),
            "compared": self._compared, "est_from": self._est_from,
            "guard": [self._jumps, self._guarded_at],
            "delay_models": [shadow.get_state() for shadow in self._shadows],
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
        held = state.get("held_in_a_row", 0)  # a state saved without the guard: none held
        if isinstance(held, bool) or int(held) != held or not 0 <= held <= HELD_READINGS_MAX:
            raise ValueError(f"state field held_in_a_row = {held!r} must be a count 0 .. {HELD_READINGS_MAX}")
        self._held_in_a_row = int(held)
        still = state.get("still", [math.nan, 0, 0, 0, False])  # a state saved without the watch: a new stretch
        if not _valid_still(still):
            raise ValueError(f"state field still = {still!r} must be [reading within {L_RANGE_MM[0]:g}..{L_RANGE_MM[1]:g} "
                             "mm or NaN, samples >= 0, samples after the lower limit and after the upper one (together "
                             "at most the samples), said true/false]")
        self._still = [float(still[0]), int(still[1]), int(still[2]), int(still[3]), bool(still[4])]
        spike = state.get("spike", _NEW_SPIKE_GUARD)  # saved without the spike guard: a new one
        if not _valid_spike_guard(spike):
            raise ValueError(f"state field spike = {spike!r} must be [mean |prediction error| >= 0 mm or NaN, the last "
                             "reading's |error| >= 0 mm or NaN, the sample the guard acts from >= 0, the preview's last "
                             "sample (finite) or NaN, the |error| before >= 0 mm or NaN]")
        self._spike = [float(spike[0]), float(spike[1]), int(spike[2]), float(spike[3]), float(spike[4])]
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
            if (isinstance(lag, bool) or int(lag) != lag or not 0 <= lag <= self._scored
                    or (lag != 0) != state["delayed"] or (d != -1 and lag != d)):
                raise ValueError(f"state field lag = {lag!r} contradicts input_delay_samples = {d} with delayed = "
                                 f"{state['delayed']!r}")
            lag = int(lag)
            n = self._scored + 1
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
            self._outs, self._later, self._ms = outs, later, scores
            self._compared = int(state["compared"])
            self._est_from = int(state.get("est_from", 0))
            if not 0 <= self._est_from <= self._k:
                raise ValueError(f"state field est_from = {state['est_from']!r} must be within 0 .. k = {self._k}")
            models = state.get("delay_models")
            if models is not None:
                if len(models) != n:
                    raise ValueError(f"state field delay_models must hold {n} model states, got {len(models)}")
                for shadow, model in zip(self._shadows, models):
                    shadow.set_state(model)
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
