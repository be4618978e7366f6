"""Physical parameters of the tap-water muscle rig (paper section 2.4, Table 1).

Every field carries its unit in its name or docstring. Values marked *datasheet* come from the
components of Table 1, *paper* from the text, and *calibration* were chosen so that the simulated rig
reproduces what the paper measured (the identified poles of Table 3, the ranges of Figs. 3-5,
the load dependence of section 4); see ``docs/plant.md`` for the calibration targets and how they are
checked (``benchmarks/plant_calibration.py``).

All dataclasses are frozen and validated on construction: an invalid value raises ``ValueError``
naming the field and the value.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field, fields, replace
from typing import Any

__all__ = [
    "ValveParams",
    "SupplyParams",
    "MuscleParams",
    "LoadParams",
    "FrictionParams",
    "SensorParams",
    "SolverParams",
    "DeadZoneParams",
    "DelayParams",
    "SupplyVariationParams",
    "LoadMismatchParams",
    "SensorDriftParams",
    "BacklashParams",
    "InputMapParams",
    "EFFECT_GROUPS",
    "PlantParams",
    "GRAVITY_M_S2",
    "CV_TO_SI_WATER",
    "dotted_names",
]

#: Standard gravity [m/s^2], converts the hanging load's weight to its mass.
GRAVITY_M_S2 = 9.80665

#: Flow coefficient conversion for water (specific gravity 1): Q [m^3/s] = Cv * CV_TO_SI_WATER * sqrt(dp [Pa]).
#: (1 US gal/min at 1 psi: 6.309e-5 m^3/s / sqrt(6894.76 Pa)).
CV_TO_SI_WATER = 6.30902e-5 / math.sqrt(6894.757)


def _check(name: str, value: float, *, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False) -> None:
    """Raise ``ValueError`` naming ``name`` when ``value`` is not finite or out of range."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise ValueError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise ValueError(f"{name} must be <= {hi}, got {value!r}")


#: Per class, what :class:`_Validated` checks: (message name, field, lo, hi, lo_open) of each bounded
#: field. Read from the fields once: a diagnosis builds tens of thousands of parameter sets.
_BOUNDED: dict[type, tuple[tuple[str, str, float | None, float | None, bool], ...]] = {}


class _Validated:
    """Mixin: check every numeric field is finite and within the bounds in its metadata."""

    def __post_init__(self) -> None:
        cls = type(self)
        checks = _BOUNDED.get(cls)
        if checks is None:
            checks = _BOUNDED[cls] = tuple(
                (f"{cls.__name__}.{f.name}", f.name, f.metadata.get("lo"), f.metadata.get("hi"),
                 f.metadata.get("lo_open", False))
                for f in fields(self)  # type: ignore[arg-type]
                if "lo" in f.metadata or "hi" in f.metadata)
        for name, attr, lo, hi, lo_open in checks:
            _check(name, getattr(self, attr), lo=lo, hi=hi, lo_open=lo_open)


def _f(default: float, doc: str, lo: float | None = None, hi: float | None = None,
       lo_open: bool = False) -> Any:
    meta: dict[str, Any] = {"doc": doc, "lo_open": lo_open}
    if lo is not None:
        meta["lo"] = lo
    if hi is not None:
        meta["hi"] = hi
    return field(default=default, metadata=meta)


@dataclass(frozen=True, kw_only=True)
class ValveParams(_Validated):
    """Two proportional valves (Koganei KFPV300, Table 1) in a bleed (meter-in/meter-out) circuit.

    The supply valve opens with the command, ``x_in = u/10``; the drain valve is driven with the
    complementary command, ``x_out = 1 - u/10``. At steady state the muscle pressure is set by the
    ratio of the two openings, which gives the finite DC gain the paper identifies (Table 3:
    ``a1 + a2 < 1``). The paper shows "proportional valves" (plural) but not their wiring; this is our
    decision, documented in ``docs/plant.md``.
    """

    cv_max: float = _f(1.5, "Effective flow coefficient of each valve at full command [US gpm/psi^0.5]; calibration (2 % settling of a few seconds, the paper's slow dominant pole, Table 3), bounded by the datasheet rating 1.6 (Table 1).", lo=0.0, lo_open=True, hi=1.6)
    # within the -1..11 V that the plant FMU's input u takes: a valve range beyond it could not be reached
    u_min_v: float = _f(0.0, "Lowest valve command [V]; datasheet (Table 1).", lo=-1.0, hi=11.0)
    u_max_v: float = _f(10.0, "Highest valve command [V]; datasheet (Table 1).", lo=-1.0, hi=11.0)
    spool_time_constant_s: float = _f(0.03, "First-order spool response time constant [s]; calibration (typical of proportional valves).", lo=0.0, lo_open=True, hi=10.0)
    characteristic_exponent: float = _f(0.5, "Flow characteristic: flow coefficient proportional to opening^n (1 linear, 0.5 quick-opening) [-]; calibration: 0.5 makes the bleed circuit's steady pressure proportional to the command.", lo=0.1, hi=3.0)
    leak_fraction: float = _f(0.01, "Opening of a closed valve as a fraction of full opening (spool underlap/leak) [-]; calibration.", lo=0.0, hi=1.0)
    laminar_dp_mpa: float = _f(0.002, "Pressure drop below which orifice flow is regularised to laminar [MPa]; numerical at its default (it keeps the flow's slope finite near equal pressures), physical when raised: at 0.1 MPa the steady displacement moves by up to 12 mm (a low command's leak balance).", lo=0.0, lo_open=True, hi=0.1)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.u_max_v <= self.u_min_v:
            raise ValueError(f"ValveParams.u_max_v ({self.u_max_v}) must exceed u_min_v ({self.u_min_v})")


@dataclass(frozen=True, kw_only=True)
class SupplyParams(_Validated):
    """Tap-water supply and drain (section 2.4, Table 1)."""

    supply_pressure_mpa: float = _f(0.25, "Gauge pressure of the tap-water supply [MPa(G)]; paper (Table 1, average).", lo=0.0, hi=1.0)
    drain_pressure_mpa: float = _f(0.0, "Gauge pressure of the drain (atmosphere) [MPa(G)]; paper.", lo=0.0, hi=1.0)
    compliance_m3_per_mpa: float = _f(1.0e-5, "Hydraulic compliance of hose, fittings and bladder dV/dp [m^3/MPa]; calibration (water itself is nearly incompressible).", lo=0.0, lo_open=True, hi=1e-2)

    def __post_init__(self) -> None:
        super().__post_init__()
        # the drain is where the water leaves to: above the supply, the valve's supply side would drain
        # the muscle and its drain side fill it
        if self.drain_pressure_mpa > self.supply_pressure_mpa:
            raise ValueError(f"{type(self).__name__}.drain_pressure_mpa ({self.drain_pressure_mpa!r}) must not exceed "
                             f"supply_pressure_mpa ({self.supply_pressure_mpa!r}): the drain is the atmosphere the "
                             "muscle empties into")


@dataclass(frozen=True, kw_only=True)
class MuscleParams(_Validated):
    """McKibben muscle, Tondu-Lopez static force model with a rubber bladder.

    Force ``F = p * A0 * (a (1 - eps)^2 - b)``, ``a = 3/tan^2(alpha0)``, ``b = 1/sin^2(alpha0)``,
    ``eps = l / L0`` the contraction ratio. By virtual work the same factor is the volume change per
    unit contraction, ``dV/dl = A0 (a (1 - eps)^2 - b)``.
    """

    rest_length_mm: float = _f(400.0, "Active length L0 at zero contraction [mm]; paper (Table 1).", lo=0.0, lo_open=True, hi=5000.0)
    radius_mm: float = _f(10.0, "Initial bladder radius r0 [mm]; calibration (in-house muscle, not given).", lo=0.0, lo_open=True, hi=200.0)
    braid_angle_deg: float = _f(23.0, "Initial braid angle alpha0 [deg]; calibration (sets the 149 mm maximal contraction).", lo=1.0, hi=54.0)
    rubber_stiffness_n_per_mm: float = _f(1.2, "Axial stiffness of the rubber bladder against contraction [N/mm]; calibration.", lo=0.0, hi=1000.0)
    threshold_pressure_mpa: float = _f(0.04, "Pressure the bladder needs before the braid is loaded [MPa]; calibration.", lo=0.0, hi=1.0)
    threshold_width_mpa: float = _f(0.01, "Width over which the bladder threshold is passed (smooth onset of the braid force) [MPa]; calibration.", lo=0.0, lo_open=True, hi=1.0)
    braid_lock_force_n: float = _f(40.0, "Passive force of the braid near full extension at l = 0, decaying as exp(-l/lock_length) (braid lock), 0 disables it [N]; calibration.", lo=0.0, hi=1e4)
    braid_lock_length_mm: float = _f(20.0, "Decay length of the braid-lock force [mm]; calibration.", lo=0.0, lo_open=True, hi=1000.0)
    damping_n_s_per_mm: float = _f(0.08, "Viscous damping of muscle and load [N s/mm]; calibration.", lo=0.0, hi=100.0)


@dataclass(frozen=True, kw_only=True)
class LoadParams(_Validated):
    """Hanging load (section 4.1: 44 N and 68 N). Its mass is ``load_n / g`` plus the moving parts."""

    load_n: float = _f(44.0, "Weight of the hanging load [N]; paper (section 4.1).", lo=0.0, hi=500.0)
    moving_mass_kg: float = _f(0.3, "Mass of the muscle end plate, cable and encoder slider [kg]; calibration.", lo=0.0, lo_open=True, hi=100.0)


@dataclass(frozen=True, kw_only=True)
class FrictionParams(_Validated):
    """Braid-bladder friction: the source of the muscle's hysteresis.

    A Dahl-type (first-order, rate-independent shape) friction whose level grows with the contact
    pressure (so it is load dependent), differs between contraction and extension (asymmetric), and
    grows with the sliding speed (rate dependent, paper section 4.4 / Fig. 20). Level while moving at
    speed ``|v|`` in direction ``s``::

        F_s = (f0 + mu * p * c(l)) * (1 + s * asym) * (1 + rate * (|v| / v_ref)^rate_exponent)

    with ``c(l) = (r/r0)(L/L0)`` the braid-bladder contact area relative to rest
    (:meth:`~fmu_plant.muscle.MuscleGeometry.contact_factor`).
    """

    base_n: float = _f(8.0, "Pressure-independent friction level f0 [N]; calibration.", lo=0.0, hi=1000.0)
    per_mpa_n: float = _f(30.0, "Growth of friction with muscle pressure mu [N/MPa]; calibration.", lo=0.0, hi=1e4)
    asymmetry: float = _f(0.35, "Contraction friction (1+asym) vs extension friction (1-asym) [-]; calibration.", lo=-0.95, hi=0.95)
    presliding_mm: float = _f(1.5, "Presliding displacement over which friction builds up (Dahl) [mm]; calibration.", lo=0.0, lo_open=True, hi=100.0)
    rate_gain: float = _f(0.8, "Rate dependence of the friction level at v_ref (0 switches it off) [-]; calibration to section 4.4.", lo=0.0, hi=10.0)
    rate_ref_mm_s: float = _f(20.0, "Reference sliding speed v_ref for the rate dependence [mm/s]; calibration.", lo=0.0, lo_open=True, hi=1e4)
    rate_exponent: float = _f(1.0, "Exponent of the rate dependence [-]; calibration.", lo=0.0, lo_open=True, hi=5.0)


@dataclass(frozen=True, kw_only=True)
class SensorParams(_Validated):
    """Linear encoder (MUTOH DX-025, 0.01 mm) and pressure sensor (Yokogawa FP101, 0-1 MPa), Table 1."""

    encoder_resolution_mm: float = _f(0.01, "Encoder quantisation step [mm]; datasheet (Table 1). 0 disables quantisation.", lo=0.0, hi=10.0)
    encoder_noise_std_mm: float = _f(0.01, "Standard deviation of white encoder noise before quantisation [mm]; calibration. 0 disables it.", lo=0.0, hi=10.0)
    pressure_range_mpa: float = _f(1.0, "Full scale of the pressure sensor [MPa]; datasheet (Table 1).", lo=0.0, lo_open=True, hi=100.0)
    pressure_resolution_mpa: float = _f(1.0 / 4096.0, "Pressure quantisation (12-bit ADC over the range) [MPa]. 0 disables it.", lo=0.0, hi=1.0)
    pressure_noise_std_mpa: float = _f(0.001, "Standard deviation of white pressure-sensor noise [MPa]. 0 disables it.", lo=0.0, hi=1.0)


@dataclass(frozen=True, kw_only=True)
class SolverParams(_Validated):
    """Adaptive integration of the continuous-time model (linearly implicit ROS34PW2, docs/plant.md).

    A sub-step is accepted when its estimated local error is within every tolerance below; the step
    size then adapts. Tighter tolerances cost more sub-steps per communication step.
    """

    max_substep_s: float = _f(0.05, "Largest internal integration step [s]; the adaptive sub-steps never exceed it and end exactly on every communication point.", lo=1e-5, hi=1.0)
    min_substep_s: float = _f(1e-5, "Smallest internal integration step [s]; a sub-step this short is accepted whatever its error estimate (guarantees progress).", lo=1e-9, hi=1e-3)
    tol_p_mpa: float = _f(5e-4, "Local error tolerance of the muscle pressure per sub-step [MPa].", lo=0.0, lo_open=True, hi=0.05)
    tol_l_mm: float = _f(5e-3, "Local error tolerance of the contraction per sub-step [mm].", lo=0.0, lo_open=True, hi=0.5)
    tol_v_mm_s: float = _f(0.5, "Local error tolerance of the contraction speed per sub-step [mm/s].", lo=0.0, lo_open=True, hi=50.0)
    tol_z_n: float = _f(0.05, "Local error tolerance of the friction state per sub-step [N].", lo=0.0, lo_open=True, hi=5.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_substep_s > self.max_substep_s:
            raise ValueError(f"SolverParams.min_substep_s ({self.min_substep_s}) must not exceed max_substep_s "
                             f"({self.max_substep_s})")


# ------------------------------------------------------------------------------ left-out effects
# Physics the calibrated core model leaves out, each switched off by default (fmu_plant/effect_library.py
# implements them at the plant's ports; docs/diagnosis.md is the vocabulary). Rate-dependent hysteresis
# needs no group of its own: it is FrictionParams.rate_gain.

@dataclass(frozen=True, kw_only=True)
class DeadZoneParams(_Validated):
    """Valve dead zone: a band of commands in which both valves pass no flow (beyond their leak).

    Within ``center_v +- width_v / 2`` the spool of a worn or overlapped valve does not uncover its
    ports, so the muscle is shut in and its pressure holds. ``width_v = 0`` switches it off.
    """

    center_v: float = _f(5.0, "Command at the middle of the dead band [V].", lo=0.0, hi=10.0)
    width_v: float = _f(0.0, "Width of the dead band [V]; 0 switches the dead zone off.", lo=0.0, hi=5.0)


@dataclass(frozen=True, kw_only=True)
class DelayParams(_Validated):
    """Transport delay between the controller's command and the valve (fieldbus, amplifier, long hose).

    The valve sees ``u(t - delay_s)``, exactly, also for fractions of a sample. 0 switches it off.
    """

    delay_s: float = _f(0.0, "Transport delay of the valve command [s]; 0 switches it off.", lo=0.0, hi=2.0)


@dataclass(frozen=True, kw_only=True)
class SupplyVariationParams(_Validated):
    """The tap-water supply pressure sags for a while and/or fluctuates (other taps in the building).

    The supply valve sees ``ps - sag(t) + ripple_mpa sin(2 pi t / ripple_period_s)``, where ``sag``
    ramps linearly from 0 to ``sag_mpa`` over ``ramp_s`` from ``start_s``, and back to 0 over
    ``recovery_ramp_s`` (by default: ``ramp_s`` too) from ``end_s``. ``sag_mpa = 0`` and
    ``ripple_mpa = 0`` switch it off.
    """

    sag_mpa: float = _f(0.0, "Drop of the supply gauge pressure during the sag [MPa]; 0 switches the sag off.", lo=0.0, hi=0.2)
    start_s: float = _f(0.0, "Time the sag starts [s].", lo=0.0, hi=1.0e6)
    end_s: float = _f(1.0e6, "Time the supply starts to recover [s] (the default, 1e6 s or 11.6 days: never in a run from t = 0; the times are the run's clock, a host's epoch times cannot schedule a sag).", lo=0.0, hi=1.0e6)
    ramp_s: float = _f(1.0, "Duration of the fall, and of the recovery unless recovery_ramp_s is set [s].", lo=0.0, hi=60.0)
    recovery_ramp_s: float = _f(-1.0, "Duration of the recovery [s]; negative (the default): ramp_s, as long as the fall.", lo=-1.0, hi=60.0)
    ripple_mpa: float = _f(0.0, "Amplitude of a periodic fluctuation of the supply pressure [MPa]; 0 switches it off.", lo=0.0, hi=0.1)
    ripple_period_s: float = _f(10.0, "Period of the fluctuation [s].", lo=0.1, hi=1.0e4)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.end_s < self.start_s:
            raise ValueError(f"SupplyVariationParams.end_s ({self.end_s}) must not precede start_s ({self.start_s})")

    @property
    def recovery_s(self) -> float:
        """Duration of the recovery in effect [s]: ``recovery_ramp_s``, or ``ramp_s`` when that is negative."""
        return self.ramp_s if self.recovery_ramp_s < 0.0 else self.recovery_ramp_s


@dataclass(frozen=True, kw_only=True)
class LoadMismatchParams(_Validated):
    """The weight on the muscle differs from the nominal load (hook, pulley friction, a wrong plate).

    The muscle carries ``load + extra_n``. 0 switches it off.
    """

    extra_n: float = _f(0.0, "Weight added to the nominal hanging load [N] (negative: lighter).", lo=-100.0, hi=100.0)


@dataclass(frozen=True, kw_only=True)
class SensorDriftParams(_Validated):
    """The encoder's zero drifts (thermal expansion, a slipping scale): ``l_seen = l + offset + rate t``."""

    offset_mm: float = _f(0.0, "Encoder offset at t = 0 [mm]: an encoder zeroed anywhere within the muscle's stroke.",
                          lo=-100.0, hi=100.0)
    rate_mm_per_min: float = _f(0.0, "Drift of the encoder offset [mm/min].", lo=-10.0, hi=10.0)


@dataclass(frozen=True, kw_only=True)
class BacklashParams(_Validated):
    """Slack in the cable between the muscle and the encoder's slider: a play of ``slack_mm``.

    The slider is dragged along only once the muscle end has taken up the slack (a backlash operator
    on the encoder's input, applied at the sampling instants). 0 switches it off.
    """

    slack_mm: float = _f(0.0, "Total play of the cable link [mm]; 0 switches it off.", lo=0.0, hi=20.0)


@dataclass(frozen=True, kw_only=True)
class InputMapParams(_Validated):
    """Static input map: the valve amplifier turns the command ``u`` into ``map(u)`` instead of ``u``.

    The static characteristic of the amplifier and valve differs from the nominal one: a dead band
    around some command (spool overlap: flow still meters outside the band, but every command inside
    it gives the same opening), a gain or offset error of the amplifier, saturation below full scale.
    ``map`` is monotone (non-decreasing) and piecewise linear through four points, (0 V,
    ``out_at_0_v``), (``knot1_in_v``, ``knot1_out_v``), (``knot2_in_v``, ``knot2_out_v``), (10 V,
    ``out_at_10_v``); commands outside 0..10 V continue the outer segments, and the result is clipped
    to 0..10 V. The knots lie strictly inside 0..10 V and strictly in order, so the map is a
    continuous function of the command (an end knot would make a jump at 0 or 10 V).

    The defaults are the identity (every output equal to its input), which switches the map off; so
    is any other identity (both knots' outputs equal to their inputs, ``out_at_0_v = 0``,
    ``out_at_10_v = 10``), see :meth:`is_identity`. Examples: a dead band of 1.2 V centred at 5 V is
    ``out_at_0_v = 0.6``, knots (4.4, 5.0) and (5.6, 5.0), ``out_at_10_v = 9.4``; a gain of 0.85 with an
    offset of +0.5 V is ``out_at_0_v = 0.5``, knots at ``0.85 u + 0.5``, ``out_at_10_v = 9.0``.
    """

    # The knots at 10/3 and 20/3 V, each input and output the same float, so the identity is exact. Written
    # with 16 significant digits, as the FMU's modelDescription states start values: a host that sets
    # the parameters from there passes these very floats.
    out_at_0_v: float = _f(0.0, "Command the valve receives at a command of 0 V [V].", lo=0.0, hi=10.0)
    knot1_in_v: float = _f(3.333333333333333, "Command at the map's first inner knot [V]; 0 < knot1_in_v < knot2_in_v < 10.", lo=0.0, hi=10.0, lo_open=True)
    knot1_out_v: float = _f(3.333333333333333, "Command the valve receives at knot1_in_v [V].", lo=0.0, hi=10.0)
    knot2_in_v: float = _f(6.666666666666667, "Command at the map's second inner knot [V]; knot1_in_v < knot2_in_v < 10.", lo=0.0, hi=10.0, lo_open=True)
    knot2_out_v: float = _f(6.666666666666667, "Command the valve receives at knot2_in_v [V].", lo=0.0, hi=10.0)
    out_at_10_v: float = _f(10.0, "Command the valve receives at a command of 10 V [V].", lo=0.0, hi=10.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        name = type(self).__name__
        if not self.knot1_in_v < self.knot2_in_v:
            raise ValueError(f"{name}.knot2_in_v ({self.knot2_in_v!r}) must exceed knot1_in_v ({self.knot1_in_v!r})")
        if not self.knot2_in_v < 10.0:
            raise ValueError(f"{name}.knot2_in_v must be < 10.0, got {self.knot2_in_v!r}")
        outs = (("out_at_0_v", self.out_at_0_v), ("knot1_out_v", self.knot1_out_v),
                ("knot2_out_v", self.knot2_out_v), ("out_at_10_v", self.out_at_10_v))
        for (lo_name, lo), (hi_name, hi) in zip(outs, outs[1:]):
            if hi < lo:
                raise ValueError(f"{name}.{hi_name} ({hi!r}) must not be below {lo_name} ({lo!r}): the map "
                                 f"must be monotone (non-decreasing)")

    def is_identity(self) -> bool:
        """True when the map is ``u -> u`` on 0..10 V (then the plant leaves it out)."""
        return (self.out_at_0_v == 0.0 and self.out_at_10_v == 10.0 and self.knot1_out_v == self.knot1_in_v
                and self.knot2_out_v == self.knot2_in_v)


#: The PlantParams groups that hold effects (each off at its defaults).
EFFECT_GROUPS = ("dead_zone", "delay", "supply_variation", "load_mismatch", "sensor_drift", "backlash",
                 "input_map")


@dataclass(frozen=True, kw_only=True)
class PlantParams:
    """All parameters of the simulated rig. Build variants with :func:`dataclasses.replace` or
    :meth:`with_values`."""

    valve: ValveParams = field(default_factory=ValveParams)
    """Proportional valves (section 2.4, Table 1)."""
    supply: SupplyParams = field(default_factory=SupplyParams)
    """Tap-water supply and drain (Table 1: 0.25 MPa)."""
    muscle: MuscleParams = field(default_factory=MuscleParams)
    """McKibben muscle geometry and bladder (Table 1: 400 mm)."""
    load: LoadParams = field(default_factory=LoadParams)
    """Hanging load (section 4.1: 44 N, 68 N)."""
    friction: FrictionParams = field(default_factory=FrictionParams)
    """Braid-bladder friction: the source of the hysteresis (load-, pressure- and rate-dependent)."""
    sensor: SensorParams = field(default_factory=SensorParams)
    """Linear encoder (Table 1: 0.01 mm) and the pressure sensor."""
    solver: SolverParams = field(default_factory=SolverParams)
    """Numerical integration settings."""
    dead_zone: DeadZoneParams = field(default_factory=DeadZoneParams)
    """Effect: a valve no-flow band (off by default; docs/diagnosis.md)."""
    delay: DelayParams = field(default_factory=DelayParams)
    """Effect: a transport delay of the valve command (off by default)."""
    supply_variation: SupplyVariationParams = field(default_factory=SupplyVariationParams)
    """Effect: a supply-pressure sag or ripple (off by default)."""
    load_mismatch: LoadMismatchParams = field(default_factory=LoadMismatchParams)
    """Effect: a load that differs from the nominal one (off by default)."""
    sensor_drift: SensorDriftParams = field(default_factory=SensorDriftParams)
    """Effect: encoder offset and drift (off by default)."""
    backlash: BacklashParams = field(default_factory=BacklashParams)
    """Effect: slack between muscle and encoder (off by default)."""
    input_map: InputMapParams = field(default_factory=InputMapParams)
    """Effect: a static, monotone piecewise-linear valve-command map (off by default)."""

    def with_values(self, **dotted: float) -> "PlantParams":
        """Return a copy with fields replaced by dotted name, e.g. ``with_values(**{"load.load_n": 68})``;
        numpy scalars are taken as the Python numbers they hold.

        Raises ``ValueError`` naming an unknown group or field.
        """
        groups: dict[str, dict[str, float]] = {}
        names = _group_fields()
        for key, value in dotted.items():
            group, _, name = key.partition(".")
            if not name or group not in names:
                raise ValueError(f"unknown plant parameter {key!r} (expected 'group.field', groups: "
                                 f"{', '.join(names)})")
            if name not in names[group]:
                raise ValueError(f"unknown plant parameter {key!r}; {group} has: {', '.join(names[group])}")
            if getattr(value, "ndim", None) == 0 and hasattr(value, "item"):
                value = value.item()  # a numpy scalar (np.int64 from np.arange, np.float32) as Python's number
            groups.setdefault(group, {})[name] = value
        try:
            return replace(self, **{g: replace(getattr(self, g), **kv) for g, kv in groups.items()})
        except ValueError as exc:  # a group's check names its class: said with the dotted name given
            raise ValueError(dotted_names(str(exc))) from None

    def noise_free(self) -> "PlantParams":
        """A copy whose encoder and pressure sensor read the state exactly: their noise and quantisation
        (``sensor.*_noise_std_*``, ``sensor.*_resolution_*``) at 0.

        What a model fitted to a recording is simulated with: the recording's noise is not the model's,
        and the 0.01-mm encoder step makes a cost piecewise constant in every parameter, so a
        finite-difference gradient of it is 0 or a jump (docs/python-api.md, "Estimating the rig's
        constants with an optimiser of your own").
        """
        s = self.sensor
        exact = (s.encoder_noise_std_mm, s.encoder_resolution_mm, s.pressure_noise_std_mpa, s.pressure_resolution_mpa)
        if all(type(v) is float and v == 0.0 and math.copysign(1.0, v) > 0.0 for v in exact):
            return self  # frozen, and equal to the copy it would make (the simulator asks this of every run)
        return self.with_values(**{"sensor.encoder_noise_std_mm": 0.0, "sensor.encoder_resolution_mm": 0.0,
                                   "sensor.pressure_noise_std_mpa": 0.0, "sensor.pressure_resolution_mpa": 0.0})

    @classmethod
    def _field(cls, key: str) -> Any:
        group, _, name = key.partition(".")
        groups = {f.name: f for f in fields(cls)}
        if not name or group not in groups:
            raise ValueError(f"unknown plant parameter {key!r} (expected 'group.field', groups: {', '.join(groups)})")
        # the group's class (its default factory): its fields, without making an instance
        group_fields = fields(groups[group].default_factory)  # type: ignore[arg-type]
        for f in group_fields:
            if f.name == name:
                return f
        raise ValueError(f"unknown plant parameter {key!r}; {group} has: {', '.join(f.name for f in group_fields)}")

    @classmethod
    def bounds(cls, key: str) -> tuple[float, float]:
        """The range ``(lo, hi)`` a parameter may take, by dotted name, as an optimiser's bounds: an open
        lower bound (``valve.cv_max > 0``) is moved just inside it, an unbounded side is ``-inf`` or
        ``inf``. The FMU declares the same range as the parameter's min and max.

        Raises ``ValueError`` naming an unknown parameter.
        """
        f = cls._field(key)
        lo = float(f.metadata.get("lo", -math.inf))
        hi = float(f.metadata.get("hi", math.inf))
        if f.metadata.get("lo_open") and math.isfinite(lo):
            lo = lo + max(1e-12, 1e-9 * abs(lo))
        return lo, hi

    @classmethod
    def unit(cls, key: str) -> str:
        """A parameter's unit by dotted name (``"MPa"``, ``"-"`` for a ratio), as the FMU declares it;
        ``ValueError`` naming an unknown parameter."""
        doc = cls._field(key).metadata.get("doc", "")
        return doc[doc.find("[") + 1:doc.find("]")] if "[" in doc else ""

    def value(self, key: str) -> float:
        """The value of one parameter by dotted name (``"group.field"``); ``AttributeError`` if unknown."""
        group, _, name = key.partition(".")
        return float(getattr(getattr(self, group), name))

    def to_dict(self) -> dict[str, dict[str, float]]:
        """Nested plain dict ``{group: {field: value}}`` (JSON-serialisable)."""
        return {f.name: {g.name: getattr(getattr(self, f.name), g.name) for g in fields(getattr(self, f.name))}
                for f in fields(self)}

    def dotted(self) -> dict[str, float]:
        """Flat ``{"group.field": value}``: the MusclePlant FMU's parameter names (inverse of :meth:`with_values`)."""
        return {f"{group}.{name}": value for group, values in self.to_dict().items() for name, value in values.items()}

    @classmethod
    def from_dict(cls, data: dict[str, dict[str, float]]) -> "PlantParams":
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError`` naming them."""
        if not isinstance(data, dict):
            raise ValueError(f"plant parameters must be a mapping of groups, got {type(data).__name__}")
        if isinstance(data.get("plant"), dict) and "plant" not in {f.name for f in fields(cls)}:
            raise ValueError("a plant parameter file's whole document: its groups are in its 'plant' mapping "
                             "(from_dict(document['plant']))")
        flat = {}
        for group, values in data.items():
            if not isinstance(values, dict):
                raise ValueError(f"plant parameter group {group!r} must be a mapping, got {values!r}")
            for name, value in values.items():
                flat[f"{group}.{name}"] = value
        return cls().with_values(**flat)


@functools.cache
def _group_fields() -> dict[str, tuple[str, ...]]:
    """:class:`PlantParams`' groups, in order, each with its fields' names in order."""
    return {f.name: tuple(g.name for g in fields(f.default_factory))  # type: ignore[arg-type]
            for f in fields(PlantParams)}


def dotted_names(message: str) -> str:
    """``message`` with ``ValveParams.cv_max`` written as the dotted name ``valve.cv_max`` (the plant
    FMU's parameter, a plant file's key).

    Parameters
    ----------
    message : str
        A text naming parameters by their group's class (a validation error's message).
    """
    groups = {type(getattr(PlantParams(), f.name)).__name__: f.name for f in fields(PlantParams)}
    return re.sub(r"\b(\w+Params)\.(\w+)", lambda m: f"{groups.get(m[1], m[1])}.{m[2]}", message)
