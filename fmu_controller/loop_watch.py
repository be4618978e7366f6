"""``LoopWatch``: what a closed loop's supervision tells of a run, sample by sample.

The paper's controllers act on every reading without a word; a loop on a real rig goes wrong in ways
that a user should hear of while it runs: a limit cycle (more delay in the loop than the law
compensates, a servo horizon or move weight the model cannot carry), a valve pinned at a limit (a
reference out of reach, readings in metres), a command held against the error (a law of the wrong
sign), a law slamming the valve end to end, an estimate that diverges, a set input delay that the
measurements contradict, a reading that has stopped changing (a stuck sensor). :class:`LoopWatch` watches one
:class:`~fmu_controller.displacement_control.DisplacementController` and returns each of these as a
message, once a run; the controller FMU logs them as warnings and
:func:`tapmuscle.closed_loop.run_closed_loop` warns of them, so both say the same.

Parameters are named as the FMU names them (``input_delay_samples``, ``servo.R``, ``theta0.b1``),
which are :class:`~fmu_controller.displacement_control.ControllerSettings`' fields with the servo's
and UCP's weights in the paper's capitals (``servo.R`` is ``ServoMPCSettings.r``).
"""

from __future__ import annotations

import math
from typing import Sequence

from fmu_controller.displacement_control import (AUTO_INPUT_DELAY_SAMPLES, FASTEST_MUSCLE_MM_PER_S, GUARD_JUMPS,
                                                 HELD_WARN_S, L_RANGE_MM, MAX_INPUT_DELAY_SAMPLES, settle_samples,
                                                 ControlStep, DisplacementController, full_range_jump, held_against_cause,
                                                 held_against_error, limit_side, pinned_side, stuck_reading_message)
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.identification import PAPER_TS_S
from fmu_controller.prediction import N_INITIAL, RUNAWAY_RANGE_MM, held_command_runaway
from fmu_controller.preliminary_model import REFINE_IN_CLOSED_LOOP, THETA0_44N
from fmu_controller.servo_settings import TABLE5_SERVO, ServoMPCSettings
from fmu_controller.ucp_mpc import UCPSettings

__all__ = ["LoopWatch", "PinnedStretch", "ReachWatch", "samples_in_words", "in_a_row", "pinned_message", "held_message",
           "DIVERGED_MM", "DIVERGED_V", "SLAM_JUMPS", "SLAM_WINDOW_S", "SWINGS",
           "PINNED_S", "HEAVY_MOVE_WEIGHT", "HORIZON_PAST_DELAY_S", "horizon_past_delay", "TABLE5_HORIZON_S",
           "table5_horizon_samples", "RUNAWAY_COMMANDS",
           "RUNAWAY_S", "THETA0_44N_HOLDS_MM", "DELAY_SURE_RATIO", "TRACKING_BLOCK_S",
           "TRACKING_MM", "TRACKING_SHARE", "SMALL_REFERENCE_MM", "REFERENCE_UNIT_S"]

#: A one-step prediction outside ten times the readings' range [mm], or a QP input u_c beyond this [V]
#: (a hundred times the valve's span), means the adaptive estimate diverges.
DIVERGED_MM = (10.0 * L_RANGE_MM[0], 10.0 * L_RANGE_MM[1])
DIVERGED_V = 1000.0
#: This many full-range jumps of the command (90 % of u_min..u_max in one sample) within
#: :data:`SLAM_WINDOW_S` are told once: a law that slams the valve end to end (a sound start makes
#: none; a large reference step a few within a second).
SLAM_JUMPS = 20
SLAM_WINDOW_S = 10.0
#: After the start-up, this many swings of the command from one valve limit to the other within
#: :data:`SLAM_WINDOW_S` (samples between the limits not counted) are told once: a limit cycle, the
#: loop having more delay than the law compensates (a rig's transport delay with
#: ``input_delay_samples`` 0: 8-26 swings in 10 s; a sound loop, with its delay set or decided: 0-2).
SWINGS = 6
#: A reference moving faster than this [mm/s] (about the simulated muscle's fastest) in a sample is a
#: step: the swings of the transient in the :data:`REF_STEP_SETTLE_S` after it (25 mm at 0.1 s: six
#: swings in AMPC-UCP) are not counted; those before and after it are.
REF_STEP_MM_PER_S = FASTEST_MUSCLE_MM_PER_S
#: A servo horizon that looks less than this [s] past the input delay, where it spans less than Table 5's
#: 0.5 s, is told at the start: on the nominal rig at 44 and 68 N, Ts = 0.05 s, with delays of 4 and 5
#: samples set and theta0 made under them, servo.Hp = 10 against 5 tracked better in 7 of 8 cells (mean
#: |r - l| over 40-90 s, MPC-servo 0.68 -> 0.45, 0.72 -> 0.57, 0.83 -> 0.49, 1.72 -> 0.64 mm; AMPC-servo
#: 0.75 -> 0.32, 0.58 -> 0.49, 2.21 -> 0.36, 0.68 -> 0.68), with 2 and 3 samples (0.1 and 0.15 s past
#: the delay) alike or worse (0.17-0.31 against 0.15-0.36); at Ts = 0.1 s, where 5 samples span 0.5 s,
#: 10 did not help with 2-5 samples.
HORIZON_PAST_DELAY_S = 0.1
#: The time Table 5's servo horizon spans at the paper's Ts [s]: 5 samples of 0.1 s.
TABLE5_HORIZON_S = TABLE5_SERVO["hp"] * PAPER_TS_S
#: A servo move weight R above this (Table 5: 15) is named among a limit cycle's causes: with Table 5's
#: horizon and Q, Qs, MPC-servo at 44 N tracked to 0.51 mm at R = 1000, overshot by 26 mm at 3000 (1.4
#: mm of Eq. (21) error) and swung the valve limit to limit at 10^4 (17 mm).
HEAVY_MOVE_WEIGHT = 1000.0
#: A command held at a valve limit that the error pushes it further into for this long [s] is told
#: once: the reference is out of the rig's reach, or ``l`` is in another unit (metres: the valve
#: pinned open while the reading barely moves).
PINNED_S = 10.0
#: The law's model is checked at the first sample for a free run that runs away from rest
#: (:func:`~fmu_controller.prediction.held_command_runaway`) under the command held at these
#: fractions of the valve's range for :data:`RUNAWAY_S`: low, within the range any model is identified
#: on. Beyond it a sound model's cubic g(l) may run away: THETA0_44N does at 8 V, from 70 mm on, and
#: models refined in closed loop over a small rig's 4..44 mm at 4 V and more. At 2 V every model
#: refined in closed loop on 10 simulated rigs (250-600 mm, 0.15-0.4 MPa, 20-100 N; over the paper's
#: range or the rig's own) stays, and every identification whose free run diverged runs away.
RUNAWAY_COMMANDS = (0.2,)
RUNAWAY_S = 30.0
#: The fixed servo loop on THETA0_44N (identified on the paper's 5..65 mm sine) tracks references up to
#: this [mm]: beyond, Eq. (1)'s g(l) feeds the motion back with the other sign (steps to 50-70 mm on the
#: paper's rig: 0.01 mm; to 75-90 mm a limit cycle for good; a 600-mm muscle's 8..88 mm sine: 6.6 mm,
#: 35 mm of overshoot at its start, 5-6 swings in 10 s, too few for the limit-cycle watch). MPC-servo
#: is told once when the reference passes it.
THETA0_44N_HOLDS_MM = 70.0
#: Evidence of another input delay than the one set (``DisplacementController.delay_evidence``) below
#: this ratio may come from ``theta0`` rather than the rig: with THETA0_44N on 24 simulated rigs with
#: 3-6 constants 5-20 % off and no delay, 2 showed 3-4 samples at 1.31-1.62 (setting them: MPC-servo
#: 0.22 -> 0.70 mm), where a recording's ``identify --input-delay-samples auto`` chose 0; real
#: delays of 1-3 samples showed 1.24-5.3 (MPC-servo the lowest).
DELAY_SURE_RATIO = 2.0
#: The loop is told once that it does not track when, over a block of :data:`TRACKING_BLOCK_S` after
#: the start-up and the estimator's first :data:`SLAM_WINDOW_S`, the mean |r - l| exceeds the larger of
#: :data:`TRACKING_MM` and :data:`TRACKING_SHARE` of the reference's range in the block. Not counted:
#: the :data:`REF_STEP_SETTLE_S` after a reference step, and samples with the valve at the limit the
#: error pushes it into (a reference out of reach, told apart). The paper's runs keep under 2 mm (MPC-UCP
#: at 0.2 Hz the most); fixed predictors from another rig leave steady offsets of 5-6 mm and a predictor
#: refined over another range 31 mm, which no other watch names (docs/control.md, "A theta0 for another
#: rig").
TRACKING_BLOCK_S = 20.0
TRACKING_MM = 3.0
TRACKING_SHARE = 0.1
#: A tracking block at its start: samples, samples counted, sum |r - l| [mm], r's least and largest [mm].
#: A reference whose largest |r| over the run's first :data:`REFERENCE_UNIT_S` [s] is above 0 and below
#: this [mm] is told once: a muscle's stroke is tens of mm (the paper's 35 +- 30 mm), and such a
#: reference is one in metres (0.035 for 35 mm), which the loop tracks to the encoder's resolution
#: with an Eq. (21) error far below any real one, and nothing else would say so. r = 0 (the muscle
#: held at rest) is not told.
SMALL_REFERENCE_MM = 1.0
REFERENCE_UNIT_S = 10.0
_NEW_BLOCK = (0, 0, 0.0, math.inf, -math.inf)
#: The reference is told out of the rig's reach at times when, in a tracking block, this share of its
#: samples (1.5 s of 20) has the command at the valve limit the error pushes it into, the reading
#: :data:`TRACKING_MM` or more short of ``r`` and still (moving less than :data:`REACH_STILL_MM_PER_S`;
#: a block whose readings there never change is a stuck sensor's, told apart): the rig at the end of
#: its stroke for part of every cycle. A supply sag with a heavy load (0.21 MPa sagging by 0.08 for 23 s,
#: 68 N plus 11) held the valve at 10 V for about 7 s over two blocks with the reading flat 10-16 mm
#: short, at 0.15-0.49 mm of Eq. (21) when the sag began after the window, without a word (the
#: pinned-valve message needs 10 s in a row). Over the 48 runs of the paper's cells (4 methods, 44/68 N,
#: 0.1/0.2 Hz, seeds 0-2) the share stayed 0, over 512 runs on 32 rigs with 3-6 constants off and 0-2
#: effects (three with a milder sag) at most 1.5 %; 19 of the 32 runs on the two rigs whose sag takes
#: the reference's peak out of reach are told, and that rig at 68 N in 8 of 8 seeds, sequential and
#: parallel (10 % split those 7 s 21 + 18 samples over two blocks and missed one seed in four; a
#: rig owner's study and an FMI user's, 2026-12-06).
REACH_SHARE = 0.075
REACH_STILL_MM_PER_S = 3.0


def in_a_row(count: int, now: bool, long_s: float, ts_s: float) -> tuple[int, float | None]:
    """The samples in a row a condition held, ``count`` before this one, and, once they span ``long_s``
    seconds at the sampling period ``ts_s`` [s], that span [s] (the count then -1: said). The span runs
    from the first sample of the stretch to this one: with a long Ts, a held command is no time sat yet.

    Parameters
    ----------
    count : int
        Samples in a row the condition held before this one, as the last call returned it (-1:
        that stretch was said).
    now : bool
        Whether the condition holds at this sample.
    long_s : float
        The span that is worth saying [s].
    ts_s : float
        Sampling period [s].
    """
    count = count + 1 if now else 0
    span_s = (count - 1) * ts_s
    return (-1, span_s) if span_s >= long_s - 1e-9 else (count, None)


def pinned_message(t_s: float, limit_v: float, sat_s: float, r_mm: float, l_mm: float, moved: bool) -> str:
    """What to tell of a command that has sat at the valve limit ``limit_v`` [V] for ``sat_s`` [s] while
    the error ``r - l`` [mm] pushes it further (:func:`~fmu_controller.displacement_control.pushed_at_limit`);
    ``moved``: whether any reading of that stretch differed from its first.

    Parameters
    ----------
    t_s : float
        Time of the report [s].
    limit_v : float
        The valve limit the command sits at [V].
    sat_s : float
        How long it has sat there [s].
    r_mm : float
        Reference ``r`` [mm].
    l_mm : float
        Reading ``l`` [mm].
    moved : bool
        Whether any reading of that stretch differed from its first.
    """
    # a reading that stayed the same to the bit: at an end stop, or a sensor that froze while the command
    # stayed at one limit, which a stuck-reading check on both limits cannot tell
    stuck = "" if moved else ", or the sensor is stuck (l has not changed at all in that time)"
    return (f"t = {t_s:.12g} s: the command has sat at the valve's {limit_v:g} V for {sat_s:.6g} s while the error "
            f"r - l = {r_mm - l_mm:.4g} mm pushes it further: the reference (r = {r_mm:g} mm) is out of the rig's "
            f"reach, or the readings l (now {l_mm:g} mm) are in another unit than mm (metres?){stuck}")


class PinnedStretch:
    """The command sitting at one valve limit that the error ``r - l`` pushes it further into
    (:func:`~fmu_controller.displacement_control.pinned_side`), counted in a row and told once after
    :data:`PINNED_S`. A command at the other limit starts a stretch anew: a law switching between the
    two is not pinned (a bang-bang law on a reachable reference is not out of the rig's reach).

    Attributes
    ----------
    n : int
        Samples of the stretch so far (-1: told).
    l : float
        The reading the stretch started from [mm].
    moved : bool
        Whether a reading of the stretch differed from its first.
    side : int
        The limit of the stretch: 1 upper, -1 lower, 0 none.
    """

    def __init__(self) -> None:
        self.n, self.l, self.moved, self.side = 0, math.nan, True, 0

    def observe(self, t_s: float, l_mm: float, r_mm: float, u_v: float, u_min_v: float, u_max_v: float,
                ts_s: float) -> str | None:
        """The message to tell after this sample (``t_s`` [s], the reading, reference [mm], command and
        valve range [V], sampling period [s]), or None."""
        if self.n < 0:
            return None
        side = pinned_side(r_mm, l_mm, u_v, u_min_v, u_max_v)
        if side and not self.side and self.n > 0:  # a stretch restored without its limit: this one
            self.side = side
        if side and side != self.side:  # a stretch starts: the reading it starts from
            self.n, self.l, self.moved = 0, l_mm, False
        elif side and l_mm != self.l:
            self.moved = True
        self.side = side
        self.n, sat_s = in_a_row(self.n, bool(side), PINNED_S, ts_s)
        if sat_s is None:
            return None
        return pinned_message(t_s, u_max_v if side > 0 else u_min_v, sat_s, r_mm, l_mm, self.moved)


class ReachWatch:
    """The reference out of the rig's reach for seconds of every cycle, counted over blocks of samples and
    told once (:data:`REACH_SHARE`): the command at the valve limit the error pushes it into (``side``
    of :func:`~fmu_controller.displacement_control.pinned_side`), the reading :data:`TRACKING_MM` or
    more short of ``r`` and still (moving less than :data:`REACH_STILL_MM_PER_S`). A block whose short
    samples all read exactly the last reading is a stuck sensor's (told apart), not the rig's reach.

    Attributes
    ----------
    short : int
        Samples of the block so far short of ``r`` at a still reading.
    moved : bool
        Whether the reading changed at any of them.
    gap_mm : float
        The largest shortfall of the block [mm], where the reading was ``l_at_gap_mm`` for the reference
        ``r_at_gap_mm`` [mm], at the valve limit ``limit_v`` [V], the upper one (``upper``) or the lower.
    l_last_mm : float
        The last reading [mm] (NaN: none).
    told : bool
        Whether it was told.
    """

    def __init__(self) -> None:
        self.short, self.moved, self.gap_mm, self.r_at_gap_mm, self.l_at_gap_mm = 0, False, 0.0, 0.0, 0.0
        self.limit_v, self.upper, self.l_last_mm, self.told = 0.0, True, math.nan, False

    def observe(self, side: int, r_mm: float, l_mm: float, u_min_v: float, u_max_v: float, ts_s: float) -> None:
        """One sample: the limit ``side`` the command sits at pushed (0: none), the reference and reading
        [mm], the valve's range [V], the sampling period [s]."""
        gap = abs(r_mm - l_mm)
        step = abs(l_mm - self.l_last_mm)
        if side and gap >= TRACKING_MM and step < REACH_STILL_MM_PER_S * ts_s:
            self.short += 1
            self.moved = self.moved or step > 0.0
            if gap > self.gap_mm:
                self.gap_mm, self.r_at_gap_mm, self.l_at_gap_mm = gap, r_mm, l_mm
                self.limit_v, self.upper = u_max_v if side > 0 else u_min_v, side > 0
        self.l_last_mm = l_mm

    def end_block(self, t_s: float, samples: int, ts_s: float, *, told_pinned: bool,
                  reference: str = "the controller FMU's sine.offset and sine.amplitude, or the input r") -> str | None:
        """At the end of a block of ``samples``: the message, once, when :data:`REACH_SHARE` of them were
        short (not where the pinned-valve message told it, ``told_pinned``); the counts start anew.
        ``reference`` names where the reference is set, for the remedy."""
        short, moved, gap = self.short, self.moved, self.gap_mm
        self.short, self.moved, self.gap_mm = 0, False, 0.0
        if self.told or told_pinned or not moved or short < REACH_SHARE * samples:
            return None
        self.told = True
        r, l = self.r_at_gap_mm, self.l_at_gap_mm
        if self.upper:
            what = (f"the reading stayed at {l:.4g} mm where r asked {r:.4g} mm: the rig contracts no further there "
                    "(a supply pressure lower than usual or sagging, a heavier load, a stiffer muscle)")
        else:
            what = (f"the reading stayed at {l:.4g} mm where r asked {r:.4g} mm: the rig does not come back that far "
                    "(a load or friction holding it, the muscle's rest)")
        return (f"t = {t_s:.12g} s: the reference is out of the rig's reach at times: over the last {samples * ts_s:g} s "
                f"the command sat at the valve's {self.limit_v:g} V for {short * ts_s:.3g} s with the reading "
                f"still, up to {gap:.3g} mm short: {what}; keep the reference within what the rig reaches "
                f"({reference})")

    def get_state(self) -> list:
        """The counts and whether it was told, as plain data."""
        return [self.short, self.moved, self.gap_mm, self.r_at_gap_mm, self.l_at_gap_mm, self.limit_v, self.upper,
                self.l_last_mm, self.told]

    def set_state(self, state: list | tuple) -> None:
        """Restore :meth:`get_state`'s list."""
        if not (isinstance(state, (list, tuple)) and len(state) == 9):
            raise ValueError(f"watch state's reach = {state!r} must be [samples short, moved, largest shortfall mm, r "
                             "and l there mm, valve limit V, upper limit, last reading mm, told]")
        self.short, self.moved, self.gap_mm = int(state[0]), bool(state[1]), float(state[2])
        self.r_at_gap_mm, self.l_at_gap_mm, self.limit_v = float(state[3]), float(state[4]), float(state[5])
        self.upper, self.l_last_mm, self.told = bool(state[6]), float(state[7]), bool(state[8])


def held_message(t_s: float, limit_v: float, sat_s: float, r_mm: float, l_mm: float, why: str) -> str:
    """What to tell of a command that has sat at the valve limit ``limit_v`` [V] for ``sat_s`` [s]
    against the error ``r - l`` [mm] (:func:`~fmu_controller.displacement_control.held_against_error`),
    with its likely cause ``why``.

    Parameters
    ----------
    t_s : float
        Time of the report [s].
    limit_v : float
        The valve limit the command sits at [V].
    sat_s : float
        How long it has sat there [s].
    r_mm : float
        Reference ``r`` [mm].
    l_mm : float
        Reading ``l`` [mm].
    why : str
        The likely cause, in words
        (:func:`~fmu_controller.displacement_control.held_against_cause`).
    """
    away = "below" if r_mm > l_mm else "above"
    return (f"t = {t_s:.12g} s: the command has sat at the valve's {limit_v:g} V for {sat_s:.6g} s while the reading "
            f"l = {l_mm:g} mm stays {abs(r_mm - l_mm):.4g} mm {away} the reference r = {r_mm:g} mm, where the other "
            f"way would close the gap: {why}")


def samples_in_words(n: int) -> str:
    """``n`` samples, in words a log reads (``1 sample``, ``2 samples``).

    Parameters
    ----------
    n : int
        Number of samples.
    """
    return f"{n} sample" if n == 1 else f"{n} samples"


def horizon_past_delay(hp: int, ts_s: float, d: int) -> str:
    """What to say of a servo horizon of ``hp`` samples at ``ts_s`` [s] that looks less than
    :data:`HORIZON_PAST_DELAY_S` past an input delay of ``d`` samples while it spans less than Table 5's
    0.5 s (a short Ts), else ``""``.

    Parameters
    ----------
    hp : int
        Servo prediction horizon ``Hp`` [samples] (Table 5).
    ts_s : float
        Sampling period [s].
    d : int
        Input delay [samples].
    """
    if d < 1 or hp * ts_s >= TABLE5_HORIZON_S * (1.0 - 1e-9) or (hp - d) * ts_s >= HORIZON_PAST_DELAY_S * (1.0 - 1e-9):
        return ""
    return (f"servo.Hp = {hp} samples spans {hp * ts_s:g} s at Ts = {ts_s:g} s and looks {max(hp - d, 0) * ts_s:g} s "
            f"past the input delay of {samples_in_words(d)}: servo.Hp = {table5_horizon_samples(ts_s)}, Table 5's "
            f"{TABLE5_HORIZON_S:g} s at this Ts, is advised (on delayed rigs at Ts = 0.05 s, 10 samples tracked better "
            "than 5: docs/control.md, \"A short Ts\")")


def table5_horizon_samples(ts_s: float) -> int:
    """The servo horizon [samples] that spans Table 5's :data:`TABLE5_HORIZON_S` at ``ts_s`` [s].

    Parameters
    ----------
    ts_s : float
        Sampling period [s].
    """
    return math.ceil(TABLE5_HORIZON_S / ts_s - 1e-9)


class LoopWatch:
    """The supervision of one controller's closed loop: :meth:`observe` after each
    :meth:`DisplacementController.step <fmu_controller.displacement_control.DisplacementController.step>`
    returns what to tell of the run so far (each kind once a run; a stuck reading once a stretch).

    Parameters
    ----------
    controller : DisplacementController
        The controller watched; its settings and ``theta0`` word the messages.
    """

    def __init__(self, controller: DisplacementController) -> None:
        if not isinstance(controller, DisplacementController):
            raise TypeError(f"LoopWatch watches a DisplacementController, got {type(controller).__name__} "
                            f"{controller!r:.60}")
        self.controller = controller
        # theta0's free run, simulated here rather than at the first sample (30 s of samples: 4-6 ms
        # at Ts = 0.02 s, a real-time loop's whole budget there); told at the first sample
        self._theta0_runaway = self.runaway(controller.theta0)
        self.reset()

    def reset(self) -> None:
        """A new run: nothing said yet."""
        self._diverged = False
        self._pinned = PinnedStretch()  # the command at a valve limit the error pushes into
        self._held_n = 0  # samples in a row at a valve limit the error pushes away from (-1: said)
        self._jump_ks: list[int] | None = []  # samples of the last full-range jumps (None: said)
        self._swing_ks: list[int] | None = []  # samples of the last limit-to-limit swings (None: said)
        self._last_limit = 0  # the valve limit the command sat at last: -1 lower, 1 upper, 0 none yet
        self._r_last = math.nan  # r(k-1) [mm], for the reference steps that restart the swings' watch
        self._swings_from = 0  # the sample swings count from: a window after the last reference step
        self._beyond_said = False  # a reference beyond THETA0_44N_HOLDS_MM told
        # the tracking block: samples, samples counted, sum |r - l| [mm], r's least and largest [mm]
        # (samples -1: said)
        self._block = list(_NEW_BLOCK)
        self._decision_seen: int | None = None  # -1's decision of the input delay, once told
        self._reach = ReachWatch()  # the reference out of reach at times
        self._r_unit = [0, 0.0]  # samples watched and largest |r| [mm] of the run's start (samples -1: done)

    # ------------------------------------------------------------------ the sample
    def observe(self, k: int, t_s: float, l_mm: float, r_mm: float, step: ControlStep, u_prev_v: float) -> list[str]:
        """What to tell after sample ``k`` at ``t_s`` [s]: the reading ``l_mm`` and reference ``r(k)``
        ``r_mm`` [mm] the controller stepped on, the ``step`` it returned and the command of the sample
        before, ``u_prev_v`` [V] (0 before the first). Each message starts with ``t = ... s:``."""
        said: list[str] = []
        u_v = step.u_v
        if k == 0:
            self._check_theta0(said, t_s)
            horizon = self.horizon_past_delay(self.controller.settings.input_delay_samples)
            if horizon:
                said.append(f"t = {t_s:.12g} s: {horizon}")
        self._watch_diverged(said, t_s, l_mm, step.uc_v, step.predicted_next_mm)
        if self.controller.startup_guarded_at == k:
            said.append(f"t = {t_s:.12g} s: the valve command jumped across its range {GUARD_JUMPS} times in the start-up "
                        "mode, whose law runs on theta0: theta0 is a poor fixed law on this rig (an open-loop "
                        "identification's, or another rig's?), or a large reference step came during the start-up. The "
                        "law takes the adaptive estimate from the next sample, as with startup_s = 0 (startup_guard = "
                        "1; docs/control.md, \"Start-up\")")
        if self.controller.reading_stuck is not None:
            said.append(stuck_reading_message(t_s, *self.controller.reading_stuck))
        self._watch_beyond_theta0(said, t_s, r_mm)
        self._watch_reference_unit(said, t_s, r_mm)
        self._watch_pinned(said, t_s, l_mm, r_mm, u_v)
        self._watch_held(said, t_s, l_mm, r_mm, u_v)
        self._watch_slamming(said, k, t_s, u_v, u_prev_v)
        if abs(r_mm - self._r_last) > REF_STEP_MM_PER_S * self.controller.settings.ts_s:
            self._swings_from = k + settle_samples(self.controller.settings.ts_s)
        self._r_last = r_mm
        self._watch_swings(said, k, t_s, u_v, l_mm, r_mm)
        self._watch_tracking(said, k, t_s, l_mm, r_mm, u_v)
        if k == self.controller.delay_check_samples:
            self._check_delay(said, t_s)
        decided = self.controller.input_delay_decision if self.controller.settings.input_delay_samples == -1 else None
        if decided is not None and decided != self._decision_seen:
            self._decision_seen = decided
            if decided >= 2:
                said.append(self.decision_message(t_s, decided))
        return said

    def _law(self) -> ServoMPCSettings | UCPSettings:
        """The settings of the method's own law, whose ``u_min_v``, ``u_max_v`` are the valve limits it
        keeps (the servo's or the coincidence point's)."""
        s = self.controller.settings
        return s.servo if s.servo_mechanism else s.ucp

    def runaway(self, theta: Sequence[float]) -> str | None:
        """Whether Eq. (1) with ``theta`` runs away from rest under a command held within the law's valve
        range (:data:`RUNAWAY_COMMANDS`, :data:`RUNAWAY_S`), in words (None where it does not)."""
        law = self._law()
        span = law.u_max_v - law.u_min_v
        ts = self.controller.settings.ts_s
        held = math.ceil(RUNAWAY_S / ts - 1e-9)  # samples of the held command, after the rest of N_INITIAL
        u = held_command_runaway(theta, ASYMMETRIC, [law.u_min_v + f * span for f in RUNAWAY_COMMANDS],
                                 N_INITIAL + held)
        if u is None:
            return None
        lo, hi = RUNAWAY_RANGE_MM
        return (f"from rest, with the command held at {u:g} V for {held * ts:g} s, its free run of Eq. (1) leaves "
                f"{lo - 10 * (hi - lo):g}..{hi + 10 * (hi - lo):g} mm")

    def _no_box(self) -> str:
        """What to say of an adaptive law without a box C on ``a1``, ``a2``, ``b1``: its estimate wanders
        where ``b1`` is near 0, which Eq. (5) divides by."""
        s = self.controller.settings
        if any(n in s.box_lower or n in s.box_upper for n in ("a1", "a2", "b1")):
            return ""
        if abs(s.ts_s - PAPER_TS_S) <= 1e-3 * PAPER_TS_S:
            return ("; the estimate has no box C to hold it: at Ts = 0.1 s keep Table 2's (AMPC-servo tracked with it on "
                    "rigs of 150-600 mm, 0.15-0.4 MPa, 20-100 N; docs/control.md, \"A theta0 for another rig\")")
        return (f"; the estimate has no box C to hold it: Table 2's holds at Ts = 0.1 s only; at Ts = {s.ts_s:g} s give "
                "one of your rig's spread (docs/identification.md, \"A box at another sampling period\")")

    def _short_horizon(self) -> str:
        """What to say of a servo law whose horizon spans less time than Table 5's 5 samples at Ts = 0.1 s:
        on a rig whose valve lags besides its delay, the paper's seconds tracked where 5 samples swung."""
        s = self.controller.settings
        if not s.servo_mechanism or s.servo.hp * s.ts_s >= TABLE5_HORIZON_S * (1.0 - 1e-9):
            return ""
        return (f"; or the servo horizon is short: servo.Hp = {s.servo.hp} samples spans {s.servo.hp * s.ts_s:g} s "
                f"here, Table 5's spans {TABLE5_HORIZON_S:g} s at Ts = {PAPER_TS_S:g} s (servo.Hp = "
                f"{table5_horizon_samples(s.ts_s)} spans them; docs/control.md, \"A short Ts\")")

    def _check_theta0(self, said: list[str], t_s: float) -> None:
        """Tell at the first sample when ``theta0``'s model runs away (:meth:`runaway`): an identification
        whose free run diverged, which a fixed law predicts with throughout."""
        c = self.controller
        how = self._theta0_runaway
        if how is None:
            return
        s = c.settings
        if s.adaptive:
            uses = ("the start-up mode's law runs on it" + (f" for up to {s.startup_s:g} s" if s.startup_s > 0 else "")
                    + " and the adaptive estimate starts from it" + (", held in the box C" if s.box_lower or s.box_upper
                                                                      else ""))
        else:
            uses = f"the fixed law predicts with it throughout and will hold the valve at a limit or swing it; {REFINE_IN_CLOSED_LOOP}"
        said.append(f"t = {t_s:.12g} s: theta0 runs away: {how} (an unstable model, which can fit one step ahead well: "
                    f"tapmuscle identify notes a free run that diverged on its record); {uses}")

    def _watch_beyond_theta0(self, said: list[str], t_s: float, r: float) -> None:
        """Tell once when MPC-servo on the paper's fixed predictor THETA0_44N is asked for more than
        :data:`THETA0_44N_HOLDS_MM`."""
        c = self.controller
        if self._beyond_said or r <= THETA0_44N_HOLDS_MM or c.settings.method != "mpc_servo":
            return
        self._beyond_said = True
        if list(c.theta0) != list(THETA0_44N):
            return
        said.append(f"t = {t_s:.12g} s: the reference r = {r:.4g} mm is above the {THETA0_44N_HOLDS_MM:g} mm up to which "
                    "the fixed predictor THETA0_44N holds (identified on the paper's 5..65 mm sine): beyond, its "
                    "g(l) feeds the motion back with the other sign, and MPC-servo overshoots or swings (on the "
                    "paper's rig a step to 75-90 mm limit-cycles for good; docs/control.md, \"MPC-servo outside its "
                    "predictor's range\"): identify theta0 over the range the loop runs in, or use an adaptive "
                    "method (ampc_servo)")

    def _watch_reference_unit(self, said: list[str], t_s: float, r: float) -> None:
        """Tell once, after :data:`REFERENCE_UNIT_S`, of a reference that stayed within
        :data:`SMALL_REFERENCE_MM` of 0 (and was not 0 throughout): one in metres."""
        watched = self._r_unit
        if watched[0] < 0:
            return
        watched[0] += 1
        watched[1] = max(watched[1], abs(r))
        if watched[0] < math.ceil(REFERENCE_UNIT_S / self.controller.settings.ts_s - 1e-9):
            return
        watched[0] = -1
        if 0.0 < watched[1] < SMALL_REFERENCE_MM:
            said.append(f"t = {t_s:.12g} s: the reference r has stayed within {watched[1]:.3g} mm of 0 over the first "
                        f"{REFERENCE_UNIT_S:g} s, where a muscle's stroke is tens of mm: is it in metres (35 mm is "
                        "0.035 m)? r is in mm; the loop tracks so small a reference to the encoder's resolution, and "
                        "its Eq. (21) error then says nothing of the law")

    def _watch_tracking(self, said: list[str], k: int, t_s: float, l: float, r: float, u: float) -> None:
        """Tell once when the mean |r - l| over a block of :data:`TRACKING_BLOCK_S` exceeds the larger of
        :data:`TRACKING_MM` and :data:`TRACKING_SHARE` of the reference's range in it."""
        block = self._block
        c = self.controller
        s = c.settings
        # from the estimator's first SLAM_WINDOW_S on, in seconds (a long Ts is few samples)
        if block[0] < 0 or c.in_startup or c.samples_since_start * s.ts_s <= SLAM_WINDOW_S:
            return
        block[0] += 1
        law = self._law()
        side = pinned_side(r, l, u, law.u_min_v, law.u_max_v)
        if k >= self._swings_from and not side:
            block[1] += 1
            block[2] += abs(r - l)
            block[3], block[4] = min(block[3], r), max(block[4], r)
        self._reach.observe(side, r, l, law.u_min_v, law.u_max_v, s.ts_s)
        if block[0] < math.ceil(TRACKING_BLOCK_S / s.ts_s - 1e-9):
            return
        counted, total, r_lo, r_hi = block[1:]
        self._block = list(_NEW_BLOCK)
        message = self._reach.end_block(t_s, block[0], s.ts_s, told_pinned=self._pinned.n < 0)
        if message is not None:
            said.append(message)
        # a block mostly after reference steps or out of reach says little of the law
        if not counted or counted < block[0] // 2:
            return
        mean = total / counted
        limit = max(TRACKING_MM, TRACKING_SHARE * (r_hi - r_lo))
        if mean <= limit:
            return
        self._block[0] = -1
        if s.adaptive:
            why = ("the adaptive estimate is poor here: theta0 or the box C far from this rig (docs/control.md, \"A theta0 "
                   "for another rig\"), or a delay the law does not compensate" + self._no_box() + self._short_horizon())
        else:
            why = ("the fixed predictor theta0 is poor for this rig or for this range of r: refine it in closed loop over "
                   "the range the loop runs in (tapmuscle.paper.preliminary_theta with refine_offset_mm and "
                   "refine_amplitude_mm; docs/control.md, \"A theta0 for another rig\"), or use an adaptive method"
                   + self._short_horizon())
        said.append(f"t = {t_s:.12g} s: the loop does not track: over the last {block[0] * s.ts_s:g} s the reading l was "
                    f"{mean:.3g} mm from the reference on average (r over {r_lo:.4g}..{r_hi:.4g} mm; more than "
                    f"{limit:.3g} mm, the larger of {TRACKING_MM:g} mm and {100 * TRACKING_SHARE:g} % of that range): {why}")

    def _watch_diverged(self, said: list[str], t_s: float, l: float, uc: float, predicted: float) -> None:
        """Tell once when the one-step prediction or the QP's input leaves :data:`DIVERGED_MM` /
        :data:`DIVERGED_V` (a host's log is not flooded every sample)."""
        if self._diverged or (DIVERGED_MM[0] <= predicted <= DIVERGED_MM[1] and abs(uc) <= DIVERGED_V):
            return
        self._diverged = True
        c, s = self.controller, self.controller.settings
        asks = f"predicts l_pred = {predicted:.3g} mm and asks for u_c = {uc:.3g} V, far outside the rig's"
        if s.adaptive and c.law_on_theta0:
            why = (f"the prior model theta0, which the start-up mode's warm-up runs the law on, {asks}: the readings l "
                   f"(now {l:g} mm) are far from what theta0 predicts (their unit? an encoder offset?), or theta0 is a "
                   "poor fixed law on this rig")
        elif s.adaptive and s.forgetting < 1.0:
            why = (f"the adaptive model {asks}: its estimate diverges (forgetting = {s.forgetting:g}, "
                   f"covariance_ceiling = {int(s.covariance_ceiling)}; a forgetting factor below 1 needs "
                   "covariance_ceiling = 1 or a value closer to 1, docs/control.md)")
        elif s.adaptive:
            why = (f"the adaptive model {asks}: its estimate diverges (theta0 or the box C far from this rig, or the "
                   f"readings l, now {l:g} mm, in another unit?)")
        else:  # a fixed model does not diverge: what it is asked to do is out of reach
            why = (f"the fixed model {asks}: the reference is out of the rig's reach from the readings l (now {l:g} mm: "
                   "an encoder offset or drift?), the readings are far from the model's, or theta0 is a poor fixed law "
                   "for this rig")
        said.append(f"t = {t_s:.12g} s: {why}. The command stays within u_min..u_max.")

    def _in_a_row(self, count: int, now: bool, long_s: float) -> tuple[int, float | None]:
        """:func:`in_a_row` on the controller's sampling period."""
        return in_a_row(count, now, long_s, self.controller.settings.ts_s)

    def _watch_pinned(self, said: list[str], t_s: float, l: float, r: float, u: float) -> None:
        """Tell once when the command has sat at a valve limit that the error ``r - l`` pushes it further
        into for :data:`PINNED_S` seconds in a row (:class:`PinnedStretch`)."""
        s = self._law()
        message = self._pinned.observe(t_s, l, r, u, s.u_min_v, s.u_max_v, self.controller.settings.ts_s)
        if message is not None:
            said.append(message)

    def _watch_held(self, said: list[str], t_s: float, l: float, r: float, u: float) -> None:
        """Tell once when the command has sat at a valve limit for ``HELD_WARN_S`` seconds in a row held
        against the error (:func:`~fmu_controller.displacement_control.held_against_error`: a negative
        ``theta0.b1`` holds the valve shut for a whole run, which nothing else would tell)."""
        if self._held_n < 0:
            return
        s = self._law()
        self._held_n, sat_s = self._in_a_row(self._held_n, held_against_error(r, l, u, s.u_min_v, s.u_max_v),
                                             HELD_WARN_S)
        if sat_s is not None:
            limit = s.u_min_v if r > l else s.u_max_v
            c = self.controller
            why = held_against_cause(float(c.theta0[2]))
            if c.theta0[2] >= 0.0:  # of the right sign: the law's model may run away
                model, name = (c.theta, "the adaptive estimate") if c.settings.adaptive else (c.theta0, "theta0")
                how = self.runaway(model)
                if how is not None:
                    why = (f"{name} runs away ({how}), so the law's predictions have the valve's effect the wrong way "
                           "round here" + (self._no_box() if c.settings.adaptive else f"; {REFINE_IN_CLOSED_LOOP}"))
            said.append(held_message(t_s, limit, sat_s, r, l, why))

    def _watch_slamming(self, said: list[str], k: int, t_s: float, u: float, u_prev: float) -> None:
        """Tell once when the command has jumped across the valve's range (``full_range_jump``)
        :data:`SLAM_JUMPS` times within :data:`SLAM_WINDOW_S`."""
        if self._jump_ks is None:
            return
        settings = self.controller.settings
        s = self._law()
        if k > 0 and full_range_jump(u, u_prev, s.u_min_v, s.u_max_v):
            window = int(round(SLAM_WINDOW_S / settings.ts_s))
            self._jump_ks = [j for j in self._jump_ks if j > k - window] + [k]
            if len(self._jump_ks) >= SLAM_JUMPS:
                self._jump_ks = None
                law = ("the fixed predictor theta0 (an open-loop identification's? refine it in closed loop: "
                       "docs/python-api.md, tapmuscle.paper.preliminary_theta)" if not settings.adaptive
                       else "the adaptive law (theta0 or the box C poor for this rig?)")
                said.append(f"t = {t_s:.12g} s: the command has jumped across the valve's range {SLAM_JUMPS} times in "
                            f"{SLAM_WINDOW_S:g} s: {law} slams the valve end to end")

    def _watch_swings(self, said: list[str], k: int, t_s: float, u: float, l: float, r: float) -> None:
        """Tell once when, after the start-up and the first :data:`SLAM_WINDOW_S` of the estimator, the
        command has swung from one valve limit to the other :data:`SWINGS` times within
        :data:`SLAM_WINDOW_S` (a limit cycle). The swings in the :data:`REF_STEP_SETTLE_S` after a
        reference step (``r`` moving further in a sample than the muscle can, :data:`REF_STEP_MM_PER_S`)
        are not counted: its transient is not a limit cycle."""
        if self._swing_ks is None:
            return
        c = self.controller
        s = c.settings
        law = self._law()
        side = limit_side(u, law.u_min_v, law.u_max_v)
        if not side:
            return
        swung, self._last_limit = side == -self._last_limit, side
        if not swung or k < self._swings_from:
            return
        window = int(round(SLAM_WINDOW_S / s.ts_s))
        # not in the law's own start, nor in the first window after it: the paper's start (startup_s = 0)
        # swings the valve 6 times in its first 1-1.5 s, without any delay
        if c.in_startup or c.samples_since_start <= window:
            return
        self._swing_ks = [j for j in self._swing_ks if j > k - window] + [k]
        if len(self._swing_ks) < SWINGS:
            return
        self._swing_ks = None
        decided = c.input_delay_decision
        runs = (f"input_delay_samples = {s.input_delay_samples}" if s.input_delay_samples != -1
                else f"input_delay_samples = -1, decided {decided}")
        if (decided or 0) >= 1:  # a delay set or decided: it may be off, or the law too aggressive for it
            # what makes this law gentler: the servo's move weight (times delay_move_weight from a
            # delay of 2 on), the unique coincidence point's horizon
            gentler = ("ucp.Hp (a later coincidence point)" if not s.servo_mechanism
                       else "delay_move_weight (servo.R times it for a delay of 2 or more)" if decided >= 2
                       else "servo.R")
            more = "" if s.adaptive else ", and make the fixed theta0 under the delay"
            # a servo horizon shorter than the delay (Table 5's 5 samples at a short Ts): AMPC-servo on a
            # 0.15-s delay at Ts = 0.02 s with 8 set, 6.9 mm over 40-120 s with Hp = 5, 0.44 with Hp = 12
            if s.servo_mechanism and s.servo.hp < decided:
                more += f", and raise servo.Hp to the delay or more (now {s.servo.hp} < {decided} samples)"
            # -1 cannot tell a delay beyond the longest it scores: it is set then; a decision of -1's
            # own is final, and a delay between two samples can make it a sample off
            if decided >= AUTO_INPUT_DELAY_SAMPLES:
                check = (f"-1 decides delays up to {samples_in_words(AUTO_INPUT_DELAY_SAMPLES)}: a longer one is set, "
                         f"the rig's delay over Ts rounded, up to {MAX_INPUT_DELAY_SAMPLES}")
            elif s.input_delay_samples == -1:
                check = (f"-1 decided {decided} for good, and a rig's delay between two samples can make it one off: "
                         f"try {decided + 1} or {decided - 1} set, or the rig's delay from a recording, tapmuscle identify "
                         "--input-delay-samples auto")
            else:
                check = "-1 decides it"
            why = ("the loop's delay differs from the one the law compensates, or the law is too aggressive for "
                   f"it: check the delay ({check}), raise {gentler}{more} (docs/control.md, \"Transport delay\")")
        else:
            why = "; ".join(self.limit_cycle_causes(l))
        said.append(f"t = {t_s:.12g} s: the valve command has swung from one limit to the other {SWINGS} times in "
                    f"{SLAM_WINDOW_S:g} s, a limit cycle ({runs}): {why}")

    def horizon_past_delay(self, d: int) -> str:
        """:func:`horizon_past_delay` for this controller's servo horizon and Ts (``""`` for a UCP method)."""
        s = self.controller.settings
        return horizon_past_delay(s.servo.hp, s.ts_s, d) if s.servo_mechanism else ""

    def decision_message(self, t_s: float, d: int) -> str:
        """What to tell when ``input_delay_samples = -1`` has decided for a delay ``d`` of 2 samples or
        more at ``t_s`` [s]: a transport delay, which the law compensates from now on a ``theta0``
        identified without it. On off-nominal rigs with a 0.1-0.27-s delay AMPC-servo tracked to a median
        1.8 mm (Eq. (21)) after such a decision, 0.97 with the delay set and 0.82 with a ``theta0`` made
        under it (docs/control.md, "Transport delay"); on rigs whose constants are off, scores that
        ``theta0`` fits poorly can show a delay the rig does not have (24 of 864 delay-free runs, the
        fixed-predictor methods and AMPC-UCP)."""
        horizon = self.horizon_past_delay(d)
        return self._decision_text(t_s, d) + (f"; {horizon}" if horizon else "")

    def _decision_text(self, t_s: float, d: int) -> str:
        ts = self.controller.settings.ts_s
        head = f"t = {t_s:.12g} s: input_delay_samples = -1 decided for {samples_in_words(d)} ({d * ts:g} s)"
        if d >= AUTO_INPUT_DELAY_SAMPLES:  # the longest -1 scores: the rig's delay may be longer
            return (f"{head}, the longest it decides: the valve may act later still. Set input_delay_samples to the "
                    f"rig's delay over Ts = {ts:g} s, rounded (up to {MAX_INPUT_DELAY_SAMPLES}, "
                    f"{MAX_INPUT_DELAY_SAMPLES * ts:g} s; tapmuscle identify --input-delay-samples auto finds it from a "
                    "recording); where the rig has no delay (a theta0 far from this rig can score one), set 0 in a "
                    "sequential master, 1 in a parallel one (docs/control.md, \"Transport delay\")")
        return (f"{head}: a transport delay, the valve acting on a command that much later (in a parallel master, "
                "libcosim, Ecos or OMSimulator at h = Ts, one of those samples is the master's: the rig's own delay is "
                "then one less). The law compensates it from now on theta0, identified without it, so the start may "
                "overshoot. Where the rig has no delay (a theta0 far from this rig can score one), set "
                "input_delay_samples = 0 in a sequential master, 1 in a parallel one. Where it has, set "
                f"input_delay_samples = {d} and a theta0 identified under the rig's own delay, which tracks better: "
                "tapmuscle identify --input-delay-samples auto on a recording of the rig finds that delay and writes "
                "the theta0.* for the FMU (in Python: tapmuscle.paper.preliminary_theta(params=..., "
                "input_delay_samples=...)); docs/control.md, \"Transport delay\"")

    def _check_delay(self, said: list[str], t_s: float) -> None:
        """Tell when the set ``input_delay_samples`` is not the delay the first samples show
        (:attr:`DisplacementController.delay_evidence`): the commonest mistake of a master's author,
        whose loop then tracks several times worse without a limit cycle to warn of."""
        c = self.controller
        evidence = c.delay_evidence
        if evidence is None:
            return
        d, ratio = evidence
        what = {0: "u reaching the valve within its sample: a sequential master (the controller stepped before "
                   "the plant, as fmpy's scenarios and a sequential container do), or a parallel one sub-stepping "
                   "at a fraction of Ts (Ts/4)",
                1: "u reaching the valve one sample late: a parallel master at h = Ts (libcosim, Ecos, "
                   "OMSimulator, SSP tools: every FMU stepped on the previous outputs)"}.get(
            d, f"a rig's transport delay of about {d} Ts")
        set_ = c.settings.input_delay_samples
        doubt = ratio < DELAY_SURE_RATIO
        if d == c.largest_scored_delay:  # the longest scored: the rig's may be longer
            shown = f"{samples_in_words(d)} or more (the longest scored)"
            finds = "" if doubt else "; tapmuscle identify --input-delay-samples auto finds it from a recording"
            advice = (f"set input_delay_samples to the rig's delay over Ts, rounded ({d} or more, up to "
                      f"{MAX_INPUT_DELAY_SAMPLES}{finds})")
        else:
            shown = samples_in_words(d)
            # -1 first: it decides from the start-up's probe, where a loop run under a wrong delay scores
            # neighbouring delays alike (a 3-sample rig with 0 set: 2 and 3 within 0.3 % of each other)
            advice = (f"set input_delay_samples = -1 to decide it from the start, or {d} (scores from a loop run "
                      f"under a wrong delay can be a sample off)" if d <= AUTO_INPUT_DELAY_SAMPLES
                      else f"set input_delay_samples = {d}")
        if doubt:
            # a theta0 off for the rig shifts the scores too: set on this evidence alone, the delay made
            # loops that tracked worse (a refined theta0 at Ts = 0.2 s told 1 at 1.31-1.74: AMPC-UCP 0.65 -> 8.7 mm)
            what += ", or a theta0 whose dynamics are slower than this rig's, which looks alike at this ratio"
            advice = (f"confirm it on a recording before changing anything (tapmuscle identify --input-delay-samples "
                      f"auto); where that finds it too, {advice}")
        said.append(f"t = {t_s:.12g} s: the measurements show an input delay of {shown}, not the {set_} set "
                    f"(input_delay_samples): theta0's one-step prediction errors are {ratio:.3g} times smaller in "
                    f"mean square under it ({what}); {advice} (docs/control.md, \"Transport delay\")")

    def limit_cycle_causes(self, l_mm: float) -> list[str]:
        """What may make a law that compensates no delay swing the valve limit to limit, each with its
        remedy, as far as the settings tell them apart (``l_mm``: the reading now [mm])."""
        s = self.controller.settings
        causes = []
        if s.input_delay_samples == -1 and not s.adaptive and not s.servo_mechanism:
            # MPC-UCP has no probe: with a sensor noisier than 0.3 mm -1's scores of 0 and 2 samples tie, and
            # it decided 0 on 2-8 of 20 rigs with a 0.15-0.2-s delay
            causes.append("a delay -1 did not see: it decided 0 from the start's scores, which a noisy sensor (0.3 mm "
                          "and more) blurs for this law: set input_delay_samples to the rig's delay in samples "
                          "(tapmuscle identify --input-delay-samples auto finds it from a recording)")
        c = self.controller
        delay = None
        if s.input_delay_samples == 0:  # -1 deciding 0 saw none: no delay to suggest
            # the set delay's check over the first 30 s: where it found no other delay, one is less likely
            # than the model, and set on a guess it makes the loop worse (a rig without a delay, a fixed
            # predictor from an open-loop sine: MPC-servo 10.7 mm, 13.3 with -1)
            none_seen = c.delay_checked and c.delay_evidence is None
            remedy = (f"set input_delay_samples to it in samples (up to {MAX_INPUT_DELAY_SAMPLES}), or -1 to decide it "
                      f"(up to {samples_in_words(AUTO_INPUT_DELAY_SAMPLES)}; docs/control.md, \"Transport delay\")")
            if none_seen:
                remedy = ("confirm it on a recording before changing anything (tapmuscle identify "
                          f"--input-delay-samples auto); where that finds one, {remedy}")
            seen = f", which the first {c.delay_check_samples * s.ts_s:g} s did not show" if none_seen else ""
            delay = ("more delay in the loop than the 0 samples set (a rig's transport delay, or a parallel "
                     f"master?){seen}: {remedy}")
            if not none_seen:
                causes.append(delay)
                delay = None
        if not s.adaptive:
            default = list(c.theta0) == list(THETA0_44N)
            made = ("the default THETA0_44N was identified on the paper's 5..65 mm sine" if default else
                    "if it was identified open loop: such a model is often a poor fixed law, one from a sine "
                    "most of all")
            causes.append(f"the fixed predictor theta0 poor where the loop runs now (l = {l_mm:.4g} mm; {made}): an "
                          f"adaptive method (3, 4), or {REFINE_IN_CLOSED_LOOP if not default else 'theta0 identified over this range'}")
        if delay is not None:
            causes.append(delay)
        if s.servo_mechanism and s.servo.hp > TABLE5_SERVO["hp"] and s.servo.hp * s.ts_s > TABLE5_HORIZON_S * (1.0 + 1e-9):
            # longer than Table 5's in samples and in seconds: at a short Ts its 5 samples span less than the
            # paper's 0.5 s (what the short-horizon note suggests), at a long one Table 5's own is no cause
            causes.append(f"a long prediction horizon servo.Hp = {s.servo.hp} ({s.servo.hp * s.ts_s:g} s) on an "
                          f"imperfect model (Table 5: {TABLE5_SERVO['hp']}, {TABLE5_HORIZON_S:g} s at Ts = {PAPER_TS_S:g} s; "
                          "3 s and more swung the valve in measured runs)")
        r = max(s.servo.r) if isinstance(s.servo.r, tuple) else s.servo.r
        if s.servo_mechanism and r > HEAVY_MOVE_WEIGHT:
            causes.append(f"a heavy move weight servo.R = {r:g} (Table 5: {TABLE5_SERVO['r']:g}): over the short horizon "
                          "the QP moves the valve only once the integrator's cost has grown, and the integrator then "
                          "swings the loop; lower servo.R, or servo.Qs with it, or lengthen servo.Hp (docs/control.md, "
                          "\"Tuning the servo law\")")
        if not causes:
            causes.append("a model poor for this rig (theta0, the box C) or a delay the law does not compensate "
                          "(docs/control.md, \"Transport delay\")")
        return causes

    # ------------------------------------------------------------------ state
    def get_state(self) -> list:
        """What has been said and the counts towards what may be, as plain data."""
        p = self._pinned
        return [self._diverged, p.n, None if self._jump_ks is None else list(self._jump_ks),
                None if self._swing_ks is None else list(self._swing_ks), self._last_limit, self._held_n,
                self._r_last, self._swings_from, p.l, p.moved, self._beyond_said, list(self._block), p.side,
                self._decision_seen, self._reach.get_state(), list(self._r_unit)]

    def set_state(self, said: list | tuple) -> None:
        """Restore :meth:`get_state`'s list; a shorter one of a build that watched less starts the
        missing watches anew (the held command, the reference steps, the pinned stretch's reading, the
        reference beyond THETA0_44N's range, the tracking block) but the reference's unit, which is
        watched at a run's start only."""
        diverged, pinned, jumps, swings, last_limit, held = (*said, 0)[:6] if len(said) >= 5 else \
            (False, 0, [], [], 0, 0)
        self._diverged, self._held_n = bool(diverged), int(held)
        self._pinned.n = int(pinned)
        self._jump_ks = None if jumps is None else [int(k) for k in jumps]
        self._swing_ks = None if swings is None else [int(k) for k in swings]
        self._last_limit = int(last_limit)
        self._r_last, self._swings_from = (float(said[6]), int(said[7])) if len(said) >= 8 else (math.nan, 0)
        # a stretch restored without its reading: not claimed unchanged
        self._pinned.l, self._pinned.moved = (float(said[8]), bool(said[9])) if len(said) >= 10 else (math.nan, True)
        # a stretch restored without its limit goes on at the limit of the next sample
        self._pinned.side = int(said[12]) if len(said) >= 13 else 0
        # a state without the decision told: one the controller already holds is taken as told
        c = self.controller
        seen = said[13] if len(said) >= 14 else c.input_delay_decision if c.settings.input_delay_samples == -1 else None
        self._decision_seen = None if seen is None else int(seen)
        self._reach = ReachWatch()
        if len(said) >= 15:
            self._reach.set_state(said[14])
        self._beyond_said = bool(said[10]) if len(said) >= 11 else False
        # a state without the reference's unit watch: taken as watched (a restored run is past its start)
        unit = said[15] if len(said) >= 16 else [-1, 0.0]
        if not (isinstance(unit, (list, tuple)) and len(unit) == 2 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in unit)):
            raise ValueError(f"watch state's reference unit watch = {unit!r} must be [samples, largest |r| mm]")
        self._r_unit = [int(unit[0]), float(unit[1])]
        block = said[11] if len(said) >= 12 else _NEW_BLOCK
        if not (isinstance(block, (list, tuple)) and len(block) == 5 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in block)):
            raise ValueError(f"watch state's tracking block = {block!r} must be [samples, samples counted, sum |r - l| "
                             "mm, least r, largest r]")
        self._block = [int(block[0]), int(block[1]), float(block[2]), float(block[3]), float(block[4])]
