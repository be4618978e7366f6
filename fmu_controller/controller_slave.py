"""``AMPCController``: the paper's displacement controllers as an FMI 2.0 co-simulation slave.

A thin shell around :class:`fmu_controller.displacement_control.DisplacementController`; FMI
behaviour (errors, state) is :class:`fmi_slave.SafeSlave`'s. docs/fmu.md lists every variable.

Sampling and timing
-------------------
The controller samples at ``t_k = t_0 + k Ts``, ``t_0`` the start time of ``fmi2SetupExperiment`` (0
without it). Everything in it counts samples ``k`` from there: the start-up mode, the probing signal
and the built-in sine (phase 0 at ``t_0``), so a run started at ``t_0`` gives the commands of a run
started at 0 for the same measurements, ``t_0`` later. A ``doStep(t, h)`` whose start ``t`` is a
sample time reads the inputs ``l`` (and ``r``) as set for ``t``, computes ``u(k)`` and sets the outputs
to it: the output after that step is the command to hold over ``[t_k, t_k + Ts)``. Stepping the controller
before the plant in each macro step (the master of :mod:`tapmuscle.cosim.master`) therefore applies
``u(k)`` over the same interval as the direct loop, with no extra sample of delay. Steps shorter than
``Ts`` are allowed (the outputs hold between samples); a step longer than ``Ts`` would skip samples
and is refused with fmi2Discard, as are a step that passes a sample time without ending there and one
that starts past a missed sample time.

Reference and preview (``reference_source``)
--------------------------------------------
1. ``builtin_sine`` (default): ``r(t) = sine.offset + sine.amplitude sin(2 pi sine.frequency (t - t_0))``,
   known ahead, so ``r(k..k+Hp)`` is exact as in the paper; the input ``r`` is ignored.
2. ``external_held``: the input ``r`` is ``r(k)``; with no knowledge of the future the controller
   assumes ``r(k+i|k) = r(k)``, which costs tracking lag on a moving reference.
3. ``external_advanced``: the host feeds ``r(t + Hp Ts)`` (the reference ``Hp`` samples ahead; ``Hp``
   of the chosen method, plus the input delay ``input_delay_samples``, and 1 for the default -1, which
   starts with the delayed law: :func:`fmu_controller.reference.advanced_lead`); the controller keeps
   the last ``Hp + 1`` values, which are exactly ``r(k..k+Hp)`` (should -1 decide for a delay of 2 or
   more, the law's samples beyond the last one fed are that one, held). Before ``Hp`` samples have
   arrived the missing past is filled with the first value.

Parallel masters (``input_delay_samples``, default -1: decided from the data)
-----------------------------------------------------------------------------
A master that steps every FMU on the outputs of the previous communication point (libcosim, Ecos,
OMSimulator, SSP runners) hands the plant at ``t_k`` the command the controller output at ``t_k``,
which it computed in the step *before*, from ``l(k-1)``: one macro step of computational delay. With
``input_delay_samples = 1`` the controller expects it: at ``t_k`` it records the command now being
applied, predicts ``l(k+1|k)`` with Eq. (1) plus an online-fitted correction
(:mod:`fmu_controller.delay_predictor`, parameter ``delay_correction``) and evaluates its control law
one sample ahead, so its output is ``u(k+1)``
(:class:`~fmu_controller.displacement_control.ControllerSettings`). On a plant that is the model, the
commands then equal those of the undelayed loop bit for bit; on the rig the one-step prediction error
is what is left (docs/fmu.md has the figures). The default -1 starts with the delayed law (safe in
both kinds of master) and decides the master's kind from the data within about 5 s: it keeps the
delayed law in a parallel master and switches to the undelayed one (as 0) in a sequential one. The
project's own master sets 0. A rig whose valve acts on the command later still (a transport delay,
docs/control.md "Transport delay") takes ``input_delay_samples = 2 .. 25``, the delay over ``Ts``
rounded: the prediction is carried on through the commands in flight; -1 tells those up to 5 apart
as well, and warns when it decides 5, beyond which it cannot see.

The output ``r_k`` is the reference ``r(k)`` at the sample, for evaluation (Eq. 21) in any mode: the
reference itself, also in the start-up mode's first ``startup_s/4``, where the law sees it led in.
"""

from __future__ import annotations

import math
import re

import fmi_slave  # noqa: F401 - first: prepares the embedded interpreter in non-Python hosts
from fmi_slave import SafeSlave
from fmi_slave.base import SlaveInputError, time_tolerance
from pythonfmu import Boolean, DefaultExperiment, Fmi2Variability, Integer
from pythonfmu.enums import Fmi2Status

from fmu_controller.displacement_control import (AUTO_INPUT_DELAY_SAMPLES, DEFAULT_DELAY_MOVE_WEIGHT,
                                                 DEFAULT_MAX_SPEED_MM_PER_S, DEFAULT_PROBING_V, DEFAULT_STARTUP_S,
                                                 GUARD_JUMPS, HELD_READINGS_MAX, L_RANGE_MM, MAX_DELAY_MOVE_WEIGHT,
                                                 MAX_INPUT_DELAY_SAMPLES, MAX_PROBING_V, MAX_STARTUP_S, METHOD_CODES,
                                                 MIN_FORGETTING, P0_TABLE5, VALVE_MAX_V, VALVE_MIN_V, ControllerSettings,
                                                 ControlStep, DisplacementController, held_reading_message, preview_lead,
                                                 real_move_message)
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.identification import PAPER_TS_S
from fmu_controller.loop_watch import LoopWatch
from fmu_controller.loop_watch import samples_in_words as _samples
from fmu_controller.preliminary_model import THETA0_44N, THETA0_LIMIT
from fmu_controller.probing import MLS_LENGTH
from fmu_controller.reference import REFERENCE_SOURCES, SineReference, advanced_lead
from fmu_controller.rls import TABLE2_LOWER, TABLE2_UPPER
from fmu_controller.servo_mpc import ServoMPCSettings
from fmu_controller.servo_settings import DEFAULT_OSQP_ITER, MAX_HORIZON, MAX_OSQP_ITER, MAX_WEIGHT
from fmu_controller.ucp_mpc import UCPSettings

__all__ = ["AMPCController", "METHOD_CODES", "REFERENCE_SOURCES"]


_L_RANGE_MM = L_RANGE_MM
#: Readings held by the glitch guard that the log states one by one (the run summary counts them all).
_HELD_READINGS_LOGGED = 10
#: A sampling period ``Ts`` of this many seconds or more, stepped by a host at a tenth of it or less, is
#: logged at the first step: the muscle's responses take tenths of a second, so it is most likely ``Ts``
#: typed in milliseconds (``Ts = 50``), with which the controller samples once and holds its command for
#: 50 s while the host steps on.
_SLOW_TS_S = 1.0


#: ServoMPCSettings' and UCPSettings' field names as the FMU's parameters: their errors name these
#: (``r`` would read as the reference input).
_SERVO_NAMES = {"hp": "servo.Hp", "hu": "servo.Hu", "qs": "servo.Qs", "q": "servo.Q", "r": "servo.R",
                "max_iter": "servo.max_iter", "u_min_v": "u_min", "u_max_v": "u_max"}
_UCP_NAMES = {"hp": "ucp.Hp", "u_min_v": "u_min", "u_max_v": "u_max"}
#: ControllerSettings' field names as the FMU's parameters (``servo.r`` is ServoMPCSettings' ``r``).
_SETTINGS_NAMES = {"ControllerSettings.ts_s": "Ts", "ControllerSettings.p0": "P0.*",
                   "ControllerSettings.input_delay_samples": "input_delay_samples", "servo.r": "servo.R",
                   **{f"ControllerSettings.{n}": n for n in ("startup_s", "probing_v", "probing_phase", "delay_move_weight")}}
#: Parameters that only some methods use: (names or group prefixes, the methods that use them).
_METHOD_ONLY = (
    (("ucp.",), "the unique-coincidence-point methods 1, 3", lambda s: not s.servo_mechanism),
    (("servo.", "hysteresis_notch", "anti_windup", "delay_move_weight"), "the servo methods 2, 4",
     lambda s: s.servo_mechanism),
    (("P0.", "forgetting", "covariance_ceiling", "box_lower.", "box_upper.", "probing_v", "probing_phase",
      "startup_guard"),
     "the adaptive methods 3, 4", lambda s: s.adaptive),
)


def _fmu_names(message: str, names: dict[str, str]) -> str:
    """``message`` of a settings class with its field names written as the FMU's parameter names."""
    return re.sub(r"\b(" + "|".join(map(re.escape, names)) + r")\b(?=[ (])", lambda m: names[m[1]], message)


class AMPCController(SafeSlave):
    """MPC / AMPC with unique coincidence point or servo mechanism (paper sections 3-4).

    Parameters
    ----------
    **kwargs
        pythonfmu's ``Fmi2Slave`` arguments (``instance_name``, ``resources``, ...), which the
        FMU's host passes on instantiation.
    """

    author = "tapmuscle"
    description = ("Displacement controller of a tap-water McKibben muscle: MPC/AMPC with unique coincidence "
                   "point or servo mechanism, constrained RLS (Algorithm 1), hysteresis cancellation (Eq. 5)")
    #: Tells hosts the communication step (the controller's Ts = 0.1 s) and a run that holds the paper's
    #: Eq. (21) window (10.1-40.1 s; the paper gives no run length) with room to spare; no tolerance: a
    #: sampled controller integrates nothing.
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=60.0, step_size=0.1)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.add_input("r", 35.0, "mm", "reference r [mm] (used unless reference_source = builtin_sine)",
                       lo=_L_RANGE_MM[0], hi=_L_RANGE_MM[1], nominal=35.0)
        self.add_input("l", 0.0, "mm", "measured contraction l(k) [mm] (encoder)",
                       lo=_L_RANGE_MM[0], hi=_L_RANGE_MM[1], nominal=35.0)
        # Outputs change only at samples, from the inputs read at the start of the step: no direct
        # feedthrough at a communication point (depends_on=()), hence no algebraic loop with the plant.
        self.add_output("u", 0.0, "V", "valve command u(k) [V], held over [t_k, t_k + Ts)", lo=0.0, hi=10.0,
                        nominal=5.0)
        self.add_output("uc", 0.0, "V", "servo: QP input u_c(k) before hysteresis cancellation (Eq. 5) [V]; "
                        "UCP: equal to u", nominal=5.0)
        self.add_output("l_pred", 0.0, "mm", "one-step prediction l(k+1|k) [mm]", nominal=35.0)
        self.add_output("pred_error", 0.0, "mm", "prediction error l(k) - l(k|k-1) [mm]", nominal=1.0)
        self.add_output("H", 0.0, "mm", "hysteresis term cancelled by Eq. (5) [mm]: H(k), or with the hysteresis notch its "
                        "5-point mean about k (0 for UCP)", nominal=1.0)
        self.add_output("xs", 0.0, "mm", "servo integrator state x_s(k+1), Eq. (18) [mm] (0 for UCP)", nominal=10.0)
        self.add_output("r_k", 0.0, "mm", "reference r(k) at the last sample, the one Eq. (21) scores (the start-up "
                        "mode's law sees it led in over its first quarter) [mm]", nominal=35.0)
        self.add_output("saturated", False, "", "an input limit (0-10 V or Eq. 19) was active at the last sample",
                        kind=Boolean, variability=Fmi2Variability.discrete)
        # counters and what the run decided: computed at initialisation (0, -1), not start values a host sets
        self.add_output("samples", 0, "", "number of samples taken so far", kind=Integer,
                        variability=Fmi2Variability.discrete, calculated_from=())
        self.add_output("input_delay", -1, "", "the input delay [samples] the law runs for: input_delay_samples, or "
                        "what -1 decided (-1 before the first sample and while it decides)", kind=Integer,
                        variability=Fmi2Variability.discrete, calculated_from=())
        #: output names of theta-hat, in Eq. (1) order; the values are attributes of these names
        self._theta_outputs = tuple(f"theta.{name}" for name in ASYMMETRIC.names)
        for i, name in enumerate(ASYMMETRIC.names):
            self.add_output(self._theta_outputs[i], float(THETA0_44N[i]), "",
                            f"predictor parameter {name} of Eq. (1) in use (AMPC: theta-hat as the law uses it, "
                            "theta0 in the start-up mode's warm-up)", calculated_from=(f"theta0.{name}",))

        self.add_integer_parameter("method", 4, "controller: 1 mpc_ucp, 2 mpc_servo, 3 ampc_ucp, 4 ampc_servo",
                                   lo=1, hi=4)
        self.add_integer_parameter("reference_source", 1, "1 builtin_sine, 2 external_held (r(k+i|k) = r(k)), "
                                   "3 external_advanced (input r is r(t + Hp Ts))", lo=1, hi=3)
        self.add_integer_parameter("input_delay_samples", -1, "samples between computing u and the valve "
                                   "receiving it: -1 (default) decide it from the data (starts with the delayed law, "
                                   "safe in both kinds of master, keeps it when the measurements show the master "
                                   "applies u one step late and switches to 0 within about 5 s when they show it "
                                   "does not); "
                                   "0 when the master steps the controller before the plant (fmpy scenarios, a "
                                   "sequential container); 1 when it steps both on the previous outputs (libcosim, "
                                   "Ecos, OMSimulator: one macro step h = Ts late); with 1 the output after the step "
                                   "at t_k is u(k+1), computed from l(k) and the prediction l(k+1|k); "
                                   f"2 .. {MAX_INPUT_DELAY_SAMPLES} a rig's transport delay as well (the samples "
                                   "from computing u to the valve acting on it, the delay over Ts rounded; -1 also "
                                   f"tells those up to {AUTO_INPUT_DELAY_SAMPLES} apart)",
                                   lo=-1, hi=MAX_INPUT_DELAY_SAMPLES)
        self.add_integer_parameter("delay_correction", 1, "with an input delay (input_delay_samples >= 1, "
                                   "or -1 deciding for one): 1 predict l(k+1|k) with Eq. (1) plus a residual "
                                   "correction fitted online by RLS (halves the delayed loop's error), 0 with "
                                   "Eq. (1) alone", lo=0, hi=1)
        self.add_integer_parameter("hysteresis_notch", -1, "servo methods: -1 by method (on for mpc_servo; for "
                                   "ampc_servo on with the start-up mode, off with startup_s = 0), 1 cancel the centred "
                                   "mean (H(k-2) + 3 H(k-1) + 4 H(k) + 3 H(k+1|k) + H(k+2|k))/12 in Eq. (5) (no valve "
                                   "chatter), 0 cancel H(k) as the paper's Eq. (5)", lo=-1, hi=1)
        self.add_integer_parameter("anti_windup", 1, "servo methods: 1 hold the integrator x_s of Eq. (18) once the "
                                   "command has sat at a valve limit the error pushes it further into for 5 samples "
                                   "in a row (no wind-up when the reference is out of reach), 0 Eq. (18) as the paper "
                                   "writes it", lo=0, hi=1)
        self.add_integer_parameter("probing_phase", 0, "adaptive methods with the start-up mode: the bit of the "
                                   f"probing signal's {MLS_LENGTH}-bit sequence it starts at; controllers started "
                                   "together on one rig probe in phase at the same value: give each its own, chosen "
                                   "by fmu_controller.probing.probing_phases (a pair at the default warm-up: 0 and "
                                   "109, probes uncorrelated over it)", lo=0, hi=MLS_LENGTH - 1)
        self.add_integer_parameter("startup_guard", 1, "adaptive methods with the start-up mode: 1 end its warm-up "
                                   "and blend on theta0 early once the valve command has jumped across 90 % of its "
                                   f"range {GUARD_JUMPS} times (theta0 a poor fixed law on this rig: the law takes the estimate, as "
                                   "with startup_s = 0, and the probing stops), 0 let them run their course", lo=0, hi=1)
        self.add_integer_parameter("covariance_ceiling", 0, "1: keep the RLS covariance P at or below P(0), "
                                   "which stops covariance wind-up under forgetting (set with forgetting = 0.999 "
                                   "for runs of hours); 0: the paper's Eq. (4)", lo=0, hi=1)
        self.add_integer_parameter("servo.Hp", 5, "servo MPC prediction horizon Hp [samples] (Table 5)", lo=1,
                                   hi=MAX_HORIZON)
        self.add_integer_parameter("servo.Hu", 5, "servo MPC control horizon Hu <= Hp [samples] (Table 5)",
                                   lo=1, hi=MAX_HORIZON)
        self.add_integer_parameter("servo.max_iter", DEFAULT_OSQP_ITER, "servo MPC: OSQP iterations per sample at "
                                   "most, which bounds a step's worst-case compute time (a QP with active bounds at "
                                   "Hp = 50 took up to 18 ms at the default, 3.4 ms at 400); on reaching it the last "
                                   "iterate is used where feasible and no worse than the clipped unconstrained plan, "
                                   "else that plan (docs/control.md, In a real-time loop)", lo=1, hi=MAX_OSQP_ITER)
        self.add_integer_parameter("ucp.Hp", 2, "unique coincidence point Hp [samples] (Table 5)", lo=1,
                                   hi=MAX_HORIZON)
        table = [
            ("Ts", 0.1, "s", "sampling period Ts [s] (paper: 0.1)", 1e-4, 60.0),
            ("servo.Q", 5.0, "", "tracking weight Q of Eq. (15) [1/mm^2] (Table 5)", 0.0, MAX_WEIGHT),
            ("servo.Qs", 2.0, "", "integrator weight Qs of Eq. (15) [1/mm^2] (Table 5)", 0.0, MAX_WEIGHT),
            ("servo.R", 15.0, "", "move weight R of Eq. (15) [1/V^2], > 0 (Table 5); servo.R x delay_move_weight "
             f"at most {MAX_WEIGHT:g} too where a delay of 2 or more may be compensated", 0.0, MAX_WEIGHT),
            ("delay_move_weight", DEFAULT_DELAY_MOVE_WEIGHT, "", "servo methods: factor on servo.R while the law compensates a delay of "
             "2 samples or more (input_delay_samples 2 or more, or -1 deciding for one: a rig's transport delay, whose "
             "prediction errors a larger R feeds back less); 1 keeps servo.R; delays 0 and 1 always do "
             "(docs/control.md, Transport delay)", 0.0, MAX_DELAY_MOVE_WEIGHT),
            ("u_min", VALVE_MIN_V, "V", "lowest valve command [V] (Eq. 19)", VALVE_MIN_V, VALVE_MAX_V),
            ("u_max", VALVE_MAX_V, "V", "highest valve command [V] (Eq. 19)", VALVE_MIN_V, VALVE_MAX_V),
            ("forgetting", 1.0, "", "RLS forgetting factor (1 = none, as the paper)", MIN_FORGETTING, 1.0),
            ("startup_s", DEFAULT_STARTUP_S, "s", "start-up mode T [s]: the reference led in from the measured "
             "position over T/4, the adaptive law on theta0 until T/2 and the estimate blended in by T; 0 = the "
             "paper's start (docs/control.md, Start-up)", 0.0, MAX_STARTUP_S),
            ("probing_v", DEFAULT_PROBING_V, "V", "adaptive methods with the start-up mode: amplitude [V] of the "
             "probing signal (a maximum-length sequence, bits of 4 samples) added to the valve command while the "
             "law is on theta0 (t < startup_s/2), so that the estimate is excited; 0 = off (docs/control.md, "
             "Start-up)", 0.0, MAX_PROBING_V),
            ("max_speed", DEFAULT_MAX_SPEED_MM_PER_S, "mm/s", "glitch guard: a reading l further from the last one "
             "used than max_speed x Ts (the muscle cannot move that far in a sample) is taken for a sensor glitch and "
             f"the one-step prediction used instead, at most {HELD_READINGS_MAX} in a row (logged); from 5 s after the "
             "start-up, so is a one-sample spike far beyond the prediction's usual error, and a reading repeated to "
             "the bit while the muscle is predicted to move (a stale sample); 0 = all three off (docs/control.md, "
             "Sensor glitches, Stale readings)", 0.0, None),
            ("sine.offset", 35.0, "mm", "built-in reference offset [mm] (paper: 35); offset +- amplitude within "
             f"{_L_RANGE_MM[0]:g}..{_L_RANGE_MM[1]:g}", *_L_RANGE_MM),
            ("sine.amplitude", 30.0, "mm", "built-in reference amplitude [mm] (paper: 30)", 0.0,
             (_L_RANGE_MM[1] - _L_RANGE_MM[0]) / 2.0),
            ("sine.frequency", 0.1, "Hz", "built-in reference frequency [Hz] (paper: 0.1, 0.2)", 0.0, None),
        ]
        table += [(f"P0.{n}", P0_TABLE5[i], "", f"diagonal of P(0) for {n} (Table 5; Table 8 for 0.2 Hz)",
                   0.0, None) for i, n in enumerate(ASYMMETRIC.names)]
        table += [(f"theta0.{n}", float(THETA0_44N[i]), "", f"initial/fixed Eq. (1) parameter {n} "
                   "(default: preliminary identification at 44 N, fmu_controller.preliminary_model)", -THETA0_LIMIT,
                   THETA0_LIMIT)
                  for i, n in enumerate(ASYMMETRIC.names)]
        table += [(f"box_lower.{n}", TABLE2_LOWER[n], "", f"lower bound of {n} in C (Table 2; -inf: none)"
                   + ("; whatever it is, b1 keeps theta0's sign and a quarter of its size (B1_KEPT_FRACTION)"
                      if n == "b1" else ""), None, None)
                  for n in TABLE2_LOWER]
        table += [(f"box_upper.{n}", TABLE2_UPPER[n], "", f"upper bound of {n} in C (Table 2; inf: none)", None, None)
                  for n in TABLE2_UPPER]
        self.add_real_parameters(table)
        self._watch: LoopWatch | None = None  # the run's supervision, with its controller
        self._controller: DisplacementController | None = None
        self._reference: SineReference | None = None
        self._hp = 0
        self._k = 0
        self._buffer: list[float] = []

    # ------------------------------------------------------------------ numerics
    def _settings(self) -> ControllerSettings:
        """ControllerSettings from the parameters; a bad one raises SlaveInputError naming it."""
        p, ip = self._par, self._int_par
        for name in ("method", "reference_source"):
            codes = METHOD_CODES if name == "method" else REFERENCE_SOURCES
            if ip[name] not in codes:
                raise SlaveInputError(f"parameter {name} = {ip[name]} must be one of "
                                      + ", ".join(f"{k} ({v})" for k, v in codes.items()))
        for name, (lo, hi) in {"Ts": (1e-4, 60.0), "forgetting": (MIN_FORGETTING, 1.0)}.items():
            self.finite(f"parameter {name}", p[name], lo, hi)
        for name, value in p.items():
            # an infinite bound of C on its own side is no bound (an unconstrained identification's)
            if (name.startswith("box_lower.") and value == -math.inf) or (name.startswith("box_upper.") and value == math.inf):
                continue
            if name.startswith(("box_lower.", "box_upper.")) and math.isinf(value):
                side = "-inf (no lower bound)" if name.startswith("box_lower.") else "inf (no upper bound)"
                raise SlaveInputError(f"parameter {name} = {value!r} is not a bound: a finite number, or {side}")
            self.finite(f"parameter {name}", value)
            if name.startswith("P0.") and value <= 0:
                raise SlaveInputError(f"parameter {name} = {value!r} must be > 0")
        if abs(p["theta0.b1"]) < 1e-6:
            raise SlaveInputError(f"parameter theta0.b1 = {p['theta0.b1']!r} must not be ~0 (it divides Eq. 5)")
        try:
            servo = ServoMPCSettings(hp=ip["servo.Hp"], hu=ip["servo.Hu"], q=p["servo.Q"], qs=p["servo.Qs"],
                                     r=p["servo.R"], u_min_v=p["u_min"], u_max_v=p["u_max"],
                                     max_iter=ip["servo.max_iter"])
        except ValueError as exc:
            raise SlaveInputError(f"parameter {_fmu_names(str(exc), _SERVO_NAMES)}") from None
        try:
            ucp = UCPSettings(hp=ip["ucp.Hp"], u_min_v=p["u_min"], u_max_v=p["u_max"])
        except ValueError as exc:
            raise SlaveInputError(f"parameter {_fmu_names(str(exc).removeprefix('UCPSettings.'), _UCP_NAMES)}") from None
        for n in TABLE2_LOWER:
            if not p[f"box_lower.{n}"] <= p[f"box_upper.{n}"]:
                raise SlaveInputError(f"parameter box_lower.{n} = {p[f'box_lower.{n}']!r} exceeds "
                                      f"box_upper.{n} = {p[f'box_upper.{n}']!r}")
        try:
            return self._controller_settings(servo, ucp)
        except ValueError as exc:
            raise SlaveInputError(f"parameter {_fmu_names(str(exc), _SETTINGS_NAMES)}") from None

    def _controller_settings(self, servo: ServoMPCSettings, ucp: UCPSettings) -> ControllerSettings:
        p, ip = self._par, self._int_par
        return ControllerSettings(
            method=METHOD_CODES[ip["method"]], ts_s=p["Ts"], ucp=ucp, servo=servo,
            p0=tuple(p[f"P0.{n}"] for n in ASYMMETRIC.names),
            box_lower={n: p[f"box_lower.{n}"] for n in TABLE2_LOWER},
            box_upper={n: p[f"box_upper.{n}"] for n in TABLE2_UPPER}, forgetting=p["forgetting"],
            covariance_ceiling=ip["covariance_ceiling"] == 1, input_delay_samples=ip["input_delay_samples"],
            delay_correction=ip["delay_correction"] == 1, anti_windup=ip["anti_windup"] == 1,
            startup_guard=ip["startup_guard"] == 1,
            hysteresis_notch=None if ip["hysteresis_notch"] == -1 else ip["hysteresis_notch"] == 1,
            startup_s=p["startup_s"], probing_v=p["probing_v"], probing_phase=ip["probing_phase"],
            delay_move_weight=p["delay_move_weight"],
            max_speed_mm_per_s=p["max_speed"])

    def overflow_hint(self) -> str:
        changed = [n for n in ASYMMETRIC.names if self._par[f"theta0.{n}"] != self._start_values[f"theta0.{n}"]]
        return ("the model's predictions grow past floating point: theta0 is far from a model of a muscle"
                + (f" (set away from its start: {', '.join(f'theta0.{n}' for n in changed)})" if changed else ""))

    def _warn_unused(self, settings: ControllerSettings) -> None:
        """Log a warning naming the parameters set away from their start values that ``settings.method``
        does not use (tuning ``servo.Hp`` for an UCP method changes nothing)."""
        unused = []
        for names, users, uses in _METHOD_ONLY:
            if not uses(settings):
                unused += [f"{name} = {value!r} ({users})" for table in (self._par, self._int_par)
                           for name, value in table.items()
                           if name.startswith(names) and value != self._start_values[name]]
        if unused:
            code = next(c for c, name in METHOD_CODES.items() if name == settings.method)
            self.log(f"parameters not used by method {code} ({settings.method}), which the run has: "
                     f"{', '.join(unused)}", status=Fmi2Status.warning)

    def initialize_numerics(self) -> None:
        settings = self._settings()
        theta0 = [self._par[f"theta0.{n}"] for n in ASYMMETRIC.names]
        if self._int_par["reference_source"] == 1 and self._par["sine.frequency"] > 0.5 / self._par["Ts"]:
            # sampled at Ts, a sine above the Nyquist frequency aliases to a slower one (a constant at 1/Ts)
            raise SlaveInputError(f"bad parameter: sine.frequency = {self._par['sine.frequency']:g} Hz is above the "
                                  f"Nyquist frequency 0.5/Ts = {0.5 / self._par['Ts']:g} Hz")
        offset, amplitude = self._par["sine.offset"], self._par["sine.amplitude"]
        if not _L_RANGE_MM[0] <= offset - amplitude <= offset + amplitude <= _L_RANGE_MM[1]:
            raise SlaveInputError(f"bad parameter: the built-in sine sine.offset +- sine.amplitude = {offset:g} +- "
                                  f"{amplitude:g} mm leaves {_L_RANGE_MM[0]:g}..{_L_RANGE_MM[1]:g} mm")
        try:
            self._controller = DisplacementController(settings, theta0)
            self._reference = SineReference(offset_mm=self._par["sine.offset"],
                                            amplitude_mm=self._par["sine.amplitude"],
                                            frequency_hz=self._par["sine.frequency"], ts_s=settings.ts_s)
        except ValueError as exc:
            raise SlaveInputError(f"bad parameter: {exc}") from None
        self._watch = LoopWatch(self._controller)
        self._hp = settings.preview_samples
        # external_advanced: the last values fed, r(k..k+fed) (the host feeds r(t + fed Ts))
        self._fed = settings.preview_samples - preview_lead(settings.input_delay_samples) \
            + advanced_lead(settings.input_delay_samples)
        self._source = REFERENCE_SOURCES[self._int_par["reference_source"]]
        self._k = 0
        self._buffer = []
        self._set_theta([float(v) for v in theta0])
        self.samples = 0
        self.input_delay = -1
        self._tally = _Tally()
        self._modes_open = True  # the start-up's changes of mode still to come (_say_changes)

    def _warn_paper_defaults_off_period(self, settings: ControllerSettings, theta0: list[float]) -> None:
        """Log a warning when ``Ts`` is not the paper's 0.1 s but ``theta0.*`` are still THETA0_44N, or (for
        an adaptive method) the box C still Table 2's: both hold for Ts = 0.1 s only (at 0.2 s the
        default theta0 gives 2.7 mm of Eq. (21) error and a valve hitting both limits)."""
        if abs(settings.ts_s - PAPER_TS_S) <= 1e-6 * PAPER_TS_S:
            return
        stale = []
        if theta0 == [float(v) for v in THETA0_44N]:
            stale.append("theta0.* are THETA0_44N, identified at Ts = 0.1 s (set them to a model identified at "
                         f"Ts = {settings.ts_s:g} s: tapmuscle identify on random levels, not a sine, whose model "
                         "is a poor fixed law there; docs/identification.md)")
        p = self._par
        if settings.adaptive and all(p[f"box_lower.{n}"] == TABLE2_LOWER[n] and p[f"box_upper.{n}"] == TABLE2_UPPER[n]
                                     for n in TABLE2_LOWER):
            stale.append("box_lower.*/box_upper.* are Table 2's, for Ts = 0.1 s in mm and V (set your model's "
                         "box, or -inf/inf for none)")
        if stale:
            self.log(f"Ts = {settings.ts_s:g} s, not the paper's 0.1 s, but " + "; and ".join(stale),
                     status=Fmi2Status.warning)

    def refresh_calculated(self) -> None:
        self._set_theta([self._par[f"theta0.{n}"] for n in ASYMMETRIC.names])

    def _set_theta(self, theta: list[float]) -> None:
        """The ``theta.*`` outputs from the Python floats ``theta`` (Eq. (1) order)."""
        self.__dict__.update(zip(self._theta_outputs, theta))

    def _preview(self, k: int) -> list[float]:
        """``r(k..k+Hp)`` [mm] for the chosen reference source (module docstring)."""
        source = self._source
        if source == "builtin_sine":
            return self._reference.preview(k, self._hp)
        r = self.finite("r", self.r, *_L_RANGE_MM)
        if source == "external_held":
            return [r] * (self._hp + 1)
        buf = self._buffer or [r] * (self._fed + 1)
        if self._buffer:
            buf = buf[1:] + [r]
        return buf + [buf[-1]] * (self._hp - self._fed)  # -1: r(k+fed) held for the longer delays it may take

    def step_numerics(self, t_s: float, dt_s: float) -> None:
        ts = self._controller.settings.ts_s
        # within a step too short to integrate (MIN_STEP_S, accepted as a no-op) of a sample time is at it:
        # a master's rounding remainder there must not make the next step skip the sample
        tol = time_tolerance(t_s, ts)
        # twelve digits: a step refused for a rounding's worth (h = 0.10000001 s at Ts = 0.1 s) shows why
        if dt_s > ts + tol:
            raise SlaveInputError(f"step size {dt_s:.12g} s exceeds the sampling period Ts = {ts:.12g} s; the "
                                  "controller would skip samples (use a communication step <= Ts)")
        t_next = self._start_s + self._k * ts  # at start time 0: k*Ts, bit for bit
        if t_s < t_next - tol:
            if t_s + dt_s > t_next + tol:  # refused here, where a host can still step to the sample time
                raise SlaveInputError(f"the step from t = {t_s:.12g} s to {t_s + dt_s:.12g} s passes the sample time "
                                      f"{t_next:.12g} s (k = {self._k}) without ending there; end the step at "
                                      f"{t_next:.12g} s (every t0 + k*Ts = {self._start_s:.12g} + k*{ts:.12g} s must be a "
                                      "communication point)")
            return  # between samples: the outputs hold
        if t_s > t_next + tol:
            raise SlaveInputError(f"the step starting at t = {t_s:.12g} s skips the sample time {t_next:.12g} s "
                                  f"(k = {self._k}); step so that every t0 + k*Ts = {self._start_s:.12g} + "
                                  f"k*{ts:.12g} s is a communication point")
        l = self.finite("l", self.l, *_L_RANGE_MM)
        preview = self._preview(self._k)  # validates r first: a refused step changes nothing
        if self._k == 0:
            self._controller.reset(l)
            # at the first step, not at initialisation, where a warning means rejected parameters to a host
            self._warn_paper_defaults_off_period(self._controller.settings, self._controller.theta0.tolist())
            self._warn_unused(self._controller.settings)
            ts_set = self._controller.settings.ts_s
            if ts_set >= _SLOW_TS_S and dt_s <= ts_set / 10.0:
                self.log(f"t = {t_s:.12g} s: Ts = {ts_set:g} s, and the host steps at {dt_s:g} s: the controller samples l "
                         f"once every {ts_set:g} s and holds its command in between ({ts_set / dt_s:.0f} steps a sample); Ts is "
                         f"in seconds (the paper's 0.1 s): is it {ts_set / 1000:g} s typed in milliseconds?",
                         status=Fmi2Status.warning)
        ctrl = self._controller
        # the modes change only until the start-up is over (the delay decided by then): not looked at after
        before = (ctrl.input_delay_decision, ctrl.law_on_theta0) if self._modes_open else None
        step: ControlStep = ctrl.step(l, preview)
        if not all(map(math.isfinite, (step.u_v, step.uc_v, step.predicted_next_mm, step.hysteresis_mm))):
            raise RuntimeError(f"the controller produced a non-finite value at k = {self._k}")
        if self._source == "external_advanced":
            self._buffer = list(preview[:self._fed + 1])
        if before is not None:
            self._say_changes(t_s, before)
            self._modes_open = ctrl.in_startup
        # the run summary's tally, inline: this runs every sample (the first has no prediction to compare with)
        tally = self._tally
        tally.samples += 1
        if step.saturated:
            tally.saturated += 1
        if ctrl.reading_held is not None:
            self._say_held_reading(t_s, *ctrl.reading_held, ctrl.spike_limit_mm)
        if ctrl.held_reading_real is not None:
            tally.real += 1
            if tally.real <= _HELD_READINGS_LOGGED:
                self.log(f"t = {t_s:.12g} s: " + real_move_message(*ctrl.held_reading_real), status=Fmi2Status.warning)
        if ctrl.reading_stuck is not None:
            tally.stuck += 1  # logged by the watch
        if self._k:
            e = step.prediction_error_mm
            tally.errors += 1
            tally.sum_squares_mm2 += e * e
            if abs(e) > tally.largest_mm:
                tally.largest_mm = abs(e)
        for message in self._watch.observe(self._k, t_s, l, float(preview[0]), step, self.u):
            self.log(message, status=Fmi2Status.warning)
        self.u, self.uc, self.l_pred = step.u_v, step.uc_v, step.predicted_next_mm
        self.pred_error, self.H, self.xs = step.prediction_error_mm, step.hysteresis_mm, step.xs_mm
        self.r_k, self.saturated = float(preview[0]), bool(step.saturated)
        self._set_theta(step.theta.tolist())
        self._k += 1
        self.samples = self._k
        self._show_input_delay()

    def _say_held_reading(self, t_s: float, reading: float, used: float, last: float, spike_mm: float | None) -> None:
        """Log a reading the glitch guard held (the first :data:`_HELD_READINGS_LOGGED`; all are counted
        in the run summary)."""
        tally = self._tally
        tally.held += 1
        if tally.held > _HELD_READINGS_LOGGED:
            return
        more = ("; further ones are counted in the run summary, not logged" if tally.held == _HELD_READINGS_LOGGED
                else "")
        self.log(f"t = {t_s:.12g} s: "
                 + held_reading_message(self._controller.settings, reading, used, last, spike_mm) + more,
                 status=Fmi2Status.warning)

    def _say_changes(self, t_s: float, before: tuple[int | None, bool]) -> None:
        """Events (logEvents) of the controller's changes of mode at a sample taken in the start-up:
        -1's decision of the input delay, the end of the start-up mode's law on theta0, the end of the
        start-up. ``before``: the delay decided and whether the law ran on theta0, before the sample."""
        ctrl = self._controller
        decided, on_theta0 = before
        if decided is None and ctrl.input_delay_decision is not None:
            d = ctrl.input_delay_decision
            what = {0: "the undelayed law from now (a sequential master)",
                    1: "the delayed law it started with (a parallel master, or a rig's delay of about a sample)"}
            # any other delay than the delayed law's 1 restarts the estimator with the start-up mode's warm-up
            restart = ("; the adaptive estimate starts again from theta0"
                       + (", with the start-up mode's warm-up" if ctrl.settings.startup_s > 0 else "")
                       if d != 1 and ctrl.settings.adaptive else "")
            if d in what:  # a longer delay is the watch's warning, with what to set (logged once, not twice)
                self.event(f"t = {t_s:.12g} s: input_delay_samples = -1 decided for {_samples(d)}: {what[d]}{restart}")
        if (on_theta0 and not ctrl.law_on_theta0 and ctrl.settings.adaptive and ctrl.startup_guarded_at is None
                and ctrl.settings.startup_s > 0):
            self.event(f"t = {t_s:.12g} s: the start-up mode's law on theta0 is over: the adaptive estimate is "
                       "blended in from the next sample")
        # without a start-up mode or a delay to decide there is no start-up to end
        if not ctrl.in_startup and (ctrl.settings.startup_s > 0 or ctrl.settings.input_delay_samples == -1):
            law = "the adaptive estimate" if ctrl.settings.adaptive else "theta0 (a fixed predictor)"
            self.event(f"t = {t_s:.12g} s: the start-up is over: the law runs on {law}, tracking r itself")

    def setup_summary(self) -> str:
        settings = self._controller.settings
        code = next(c for c, name in METHOD_CODES.items() if name == settings.method)
        horizons = (f"servo.Hp = {settings.servo.hp}, servo.Hu = {settings.servo.hu}" if settings.servo_mechanism
                    else f"ucp.Hp = {settings.ucp.hp}")
        delay = ("decided from the data (input_delay_samples = -1)" if settings.input_delay_samples == -1
                 else _samples(settings.input_delay_samples))
        if self._source == "builtin_sine":
            reference = (f"the built-in sine {self._par['sine.offset']:g} +- {self._par['sine.amplitude']:g} mm at "
                         f"{self._par['sine.frequency']:g} Hz")
        else:
            reference = f"the input r ({self._source})"
        return (f"method {code} {settings.method}, Ts = {settings.ts_s:g} s, {horizons}; input delay {delay}; "
                f"start-up mode {settings.startup_s:g} s; reference {reference}; " + super().setup_summary())

    def run_summary(self) -> str:
        projected, resets, ceilings = self._controller.estimator_counts
        estimator = (f"; Algorithm 1 since the estimator's start: the estimate projected onto the box C in {projected} "
                     f"updates, {resets} covariance resets, {ceilings} covariance ceilings"
                     if self._controller.settings.adaptive else "")
        delay = self._controller.input_delay_decision
        law = ("the delayed law (1 sample), input_delay_samples = -1 still undecided" if delay is None
               else f"the law for an input delay of {_samples(delay)}")
        return f"{super().run_summary()}: {self._tally}; {law}{estimator}"

    def _show_input_delay(self) -> None:
        """The ``input_delay`` output: the delay the law runs for (-1 before a sample, or undecided)."""
        decided = self._controller.input_delay_decision
        self.input_delay = -1 if decided is None or self._k == 0 else decided

    # ------------------------------------------------------------------ state
    def numerics_state(self):
        if self._controller is None:
            return None
        return {"controller": self._controller.get_state(), "k": self._k, "buffer": list(self._buffer),
                "theta": [getattr(self, name) for name in self._theta_outputs],
                # what the log has said: a rewind says it again only where the run does again
                "said": self._watch.get_state(),
                "tally": self._tally.as_list()}

    def restore_numerics_state(self, state) -> None:
        if state is not None:
            self._controller.set_state(state["controller"])
            self._k = int(state["k"])
            self._buffer = [float(v) for v in state["buffer"]]
            self._set_theta([float(v) for v in state["theta"]])
            self._watch.set_state(state.get("said", ()))  # a build's that watched less: watched from here
            # a state of a build without the tally: counted from here, and the summary says so
            self._tally = _Tally(*state["tally"]) if "tally" in state else _Tally(partial=True)
            self._modes_open = self._controller.in_startup  # as after the restored sample
            self._show_input_delay()


class _Tally:
    """What the controller's run summary says: samples, samples at an input limit, prediction errors
    (counted in :meth:`AMPCController.step_numerics`)."""

    __slots__ = ("samples", "saturated", "errors", "sum_squares_mm2", "largest_mm", "partial", "held", "stuck", "real")

    def __init__(self, samples: int = 0, saturated: int = 0, errors: int = 0, sum_squares_mm2: float = 0.0,
                 largest_mm: float = 0.0, partial: bool = False, held: int = 0, stuck: int = 0, real: int = 0) -> None:
        self.samples, self.saturated, self.errors = int(samples), int(saturated), int(errors)
        self.sum_squares_mm2, self.largest_mm = float(sum_squares_mm2), float(largest_mm)
        self.partial = bool(partial)  # counted from a restored state that carried no tally
        self.held = int(held)  # readings the glitch guard held (a state saved without it: none)
        self.stuck = int(stuck)  # stretches of a stuck reading told (reading_stuck; a state saved without it: none)
        self.real = int(real)  # held readings found the muscle's own (held_reading_real; saved without it: none)

    def as_list(self) -> list:
        return [self.samples, self.saturated, self.errors, self.sum_squares_mm2, self.largest_mm, self.partial,
                self.held, self.stuck, self.real]

    def __str__(self) -> str:
        if not self.samples:
            return "no sample"
        rms = math.sqrt(self.sum_squares_mm2 / self.errors) if self.errors else 0.0
        since = " since a restored state" if self.partial else ""
        # no percent sign: hosts that print the message as it arrives (fmpy) would show it doubled
        return (f"{self.samples} samples{since}; an input limit (0-10 V or Eq. 19) active in {self.saturated} of "
                f"them; one-step prediction error l(k) - l(k|k-1): RMS "
                f"{rms:.3g} mm, largest {self.largest_mm:.3g} mm"
                + (f"; {self.held} readings taken for sensor glitches and held (max_speed)" if self.held else "")
                + (f", {self.real} of them found the muscle's own move by the reading after" if self.real else "")
                + (f"; the reading stuck {self.stuck} time{'s' if self.stuck > 1 else ''} (unchanged while the valve "
                   "went end to end)" if self.stuck else ""))
