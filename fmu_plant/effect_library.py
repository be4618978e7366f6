"""The effects library: physics a calibrated core model may leave out, as plug-ins at the plant's ports.

Each effect is parameterised by one group of :class:`~fmu_plant.parameters.PlantParams` (so the plant
FMU exposes it as ordinary parameters, e.g. ``delay.delay_s``) and is off at that group's defaults.
:func:`effects_from_params` builds the switched-on ones; :class:`~fmu_plant.Plant` does so itself.
The vocabulary, with each effect's physics, parameters and how the diagnosis fits it, is in
``docs/diagnosis.md``; rate-dependent hysteresis is the friction model's ``friction.rate_gain`` and
needs no plug-in.

==========================  ====================  ==========================================
effect                      port                  parameters
==========================  ====================  ==========================================
``transport_delay``         valve command         ``delay.delay_s``
``input_map``               valve command         ``input_map.*`` (the knots of a monotone map)
``valve_dead_zone``         valve gate            ``dead_zone.center_v``, ``dead_zone.width_v``
``supply_pressure_variation``  supply pressure    ``supply_variation.*``
``load_mismatch``           load                  ``load_mismatch.extra_n``
``backlash``                measurement           ``backlash.slack_mm``
``sensor_drift``            measurement           ``sensor_drift.offset_mm``, ``.rate_mm_per_min``
==========================  ====================  ==========================================
"""

from __future__ import annotations

import bisect
import math
from typing import Any

from .effects import Effect
from .parameters import (BacklashParams, DeadZoneParams, DelayParams, InputMapParams, LoadMismatchParams,
                         PlantParams, SensorDriftParams, SupplyVariationParams)

__all__ = ["TransportDelay", "InputMap", "ValveDeadZone", "SupplyPressureVariation", "LoadMismatch", "Backlash",
           "SensorDrift", "effects_from_params", "input_map_v"]


#: Instants closer than this [s] are one (rounding of a time's last bits), far below the plant's
#: shortest sub-step (1e-9 s).
_SAME_INSTANT_S = 1e-12


class TransportDelay(Effect):
    """The valve receives the command ``delay_s`` late: ``u_valve(t) = u(t - delay_s)``.

    The command is piecewise constant (zero-order hold), so the delayed command changes exactly at
    ``t_change + delay_s``; these instants are reported as :meth:`breakpoints` and the plant ends a
    sub-step on each, so a delay of a fraction of a sample is exact.

    Parameters
    ----------
    p : DelayParams
        The delay; ``p.delay_s`` [s] is read once, at construction.
    """

    name = "transport_delay"

    def __init__(self, p: DelayParams) -> None:
        self.delay_s = p.delay_s
        self._times: list[float] = [0.0]   # instants the command changed [s]
        self._values: list[float] = [0.0]  # the command from then on [V]

    def reset(self, t_s: float, u_v: float, l_mm: float) -> None:
        self._times, self._values = [t_s], [u_v]

    def _record_change(self, t_s: float, u_v: float) -> None:
        """Record a command ``u_v`` that differs from the last one recorded, from ``t_s`` on."""
        if t_s >= self._times[-1]:
            self._times.append(t_s)
            self._values.append(u_v)
            # forget what can no longer be seen (keep the value in force at t - delay)
            cut = bisect.bisect_right(self._times, t_s - self.delay_s) - 1
            if cut > 8:
                del self._times[:cut], self._values[:cut]

    def breakpoints(self, t0_s: float, t1_s: float, u_v: float) -> list[float]:
        if u_v != self._values[-1]:  # tested here: the ports call this at every stretch
            self._record_change(t0_s, u_v)
        d = self.delay_s
        # from the newest change back: the times are in order, so the first change seen at or before
        # t0_s ends the search (the step is called for every sample). Within the 1e-12-s guard of
        # valve_command an instant is the step's start or the next step's: t_change + delay computed
        # as 0.30000000000000004 against a master's 0.3 would otherwise split off a sub-step of 4e-17 s,
        # and a run's last bits would follow how its master adds up time
        out = []
        for t in reversed(self._times):
            seen_s = t + d
            if seen_s <= t0_s + _SAME_INSTANT_S:
                break
            if seen_s < t1_s - _SAME_INSTANT_S:
                out.append(seen_s)
        out.reverse()
        return out

    def held(self, t0_s: float, t1_s: float) -> bool:
        # between breakpoints the delayed command is one value (the 1e-12-s guard below is far shorter
        # than the plant's shortest sub-step, 1e-9 s, so no sub-step starts within it)
        return True

    def valve_command(self, t_s: float, u_v: float) -> float:
        if u_v != self._values[-1]:
            self._record_change(t_s, u_v)
        # the guard: a sub-step starting at t_change + delay sees the new value despite rounding
        i = bisect.bisect_right(self._times, t_s - self.delay_s + _SAME_INSTANT_S) - 1
        return self._values[i if i >= 0 else 0]

    def get_state(self) -> dict[str, Any]:
        return {"times": list(self._times), "values": list(self._values)}

    def set_state(self, state: dict[str, Any]) -> None:
        self._times = [float(t) for t in state["times"]]
        self._values = [float(v) for v in state["values"]]


def input_map_v(u_v: float, p: InputMapParams) -> float:
    """The command the valve receives through the input map ``p``.

    Piecewise linear through (0 V, ``out_at_0_v``), the two knots and (10 V, ``out_at_10_v``); a
    command outside 0..10 V continues the outer segment.

    Parameters
    ----------
    u_v : float
        Command [V].
    p : InputMapParams
        The map.

    Returns
    -------
    float
        Mapped command [V], clipped to 0..10 V.
    """
    if u_v < p.knot1_in_v:
        x0, y0, x1, y1 = 0.0, p.out_at_0_v, p.knot1_in_v, p.knot1_out_v
    elif u_v < p.knot2_in_v:
        x0, y0, x1, y1 = p.knot1_in_v, p.knot1_out_v, p.knot2_in_v, p.knot2_out_v
    else:
        x0, y0, x1, y1 = p.knot2_in_v, p.knot2_out_v, 10.0, p.out_at_10_v
    y = y0 + (y1 - y0) * (u_v - x0) / (x1 - x0)
    return 0.0 if y < 0.0 else 10.0 if y > 10.0 else y


class InputMap(Effect):
    """The valve receives ``map(u)``: a static, monotone, piecewise-linear input map (parameters' docstring).

    The physical picture: the amplifier and valve's static characteristic differs from the nominal
    one. A dead band around some command (spool overlap: outside the band the flow still meters as
    usual, but every command inside it gives the same opening), a gain or offset error of the
    amplifier, a saturation below full scale. Unlike the valve dead zone, which shuts both valves,
    the valve here keeps metering, at a shifted command. Memoryless: the held command maps to a held
    command, so it adds no breakpoints (after a transport delay it maps the delayed command).

    Parameters
    ----------
    p : InputMapParams
        The map's end points and knots [V].
    """

    name = "input_map"

    def __init__(self, p: InputMapParams) -> None:
        self.p = p

    def valve_command(self, t_s: float, u_v: float) -> float:
        return input_map_v(u_v, self.p)

    def held(self, t0_s: float, t1_s: float) -> bool:
        return True  # a function of the held command alone


class ValveDeadZone(Effect):
    """Commands within ``center_v +- width_v / 2`` leave both valves shut (only their leak flows).

    The physical picture: an overlapped or worn spool that must travel through a band before it
    uncovers its ports, so the muscle is shut in and holds its pressure while the command crosses the
    band. Acts through the valve-gate port (the opening of both valves is multiplied by the gate).

    Parameters
    ----------
    p : DeadZoneParams
        The band's center and width [V].
    """

    name = "valve_dead_zone"

    def __init__(self, p: DeadZoneParams) -> None:
        self.lo_v = p.center_v - 0.5 * p.width_v
        self.hi_v = p.center_v + 0.5 * p.width_v

    def valve_gate(self, t_s: float, u_v: float) -> float:
        return 0.0 if self.lo_v < u_v < self.hi_v else 1.0

    def held(self, t0_s: float, t1_s: float) -> bool:
        return True  # a function of the held command alone


class SupplyPressureVariation(Effect):
    """The tap-water supply sags between ``start_s`` and ``end_s`` and/or ripples (parameters' docstring).

    Parameters
    ----------
    p : SupplyVariationParams
        The sag's depth [MPa] and timing [s], and the ripple's amplitude [MPa] and period [s].
    """

    name = "supply_pressure_variation"

    def __init__(self, p: SupplyVariationParams) -> None:
        self.p = p
        # read once: the port is sampled at every integration sub-step
        self._sag, self._start, self._end = p.sag_mpa, p.start_s, p.end_s
        self._ramp, self._back = p.ramp_s, p.recovery_s
        self._corners = () if p.sag_mpa == 0.0 else (p.start_s, p.start_s + p.ramp_s, p.end_s, p.end_s + p.recovery_s)

    def sag_mpa(self, t_s: float) -> float:
        """Drop of the supply pressure at ``t_s`` [MPa] (trapezoid in time)."""
        if self._sag == 0.0 or t_s <= self._start:
            return 0.0
        ramp, back = self._ramp, self._back
        up = 1.0 if ramp == 0.0 else min(1.0, (t_s - self._start) / ramp)
        end = self._end
        down = 1.0 if t_s <= end else 0.0 if back == 0.0 else max(0.0, 1.0 - (t_s - end) / back)
        return self._sag * min(up, down)

    def breakpoints(self, t0_s: float, t1_s: float, u_v: float) -> list[float]:
        return [t for t in self._corners if t0_s < t < t1_s]

    def held(self, t0_s: float, t1_s: float) -> bool:
        """Constant before the sag, on its plateau and after its recovery (no ripple). Each test is
        one that, true at ``t0_s`` or ``t1_s``, holds at every instant between, float for float:
        ``sag_mpa``'s subtractions and divisions are monotone in ``t_s``."""
        if self.p.ripple_mpa:
            return False
        if self._sag == 0.0 or t1_s <= self._start:
            return True  # sag_mpa is 0.0 up to start_s
        if t0_s <= self._start:
            return False
        ramp, back = self._ramp, self._back
        if t1_s <= self._end:  # the fall's fraction is 1.0 from t0_s on: the plateau
            return ramp == 0.0 or (t0_s - self._start) / ramp >= 1.0
        # the recovery's fraction is 0.0 from t0_s on: recovered
        return t0_s > self._end and (back == 0.0 or 1.0 - (t0_s - self._end) / back <= 0.0)

    def supply_pressure(self, t_s: float, p_mpa: float) -> float:
        ps = p_mpa - self.sag_mpa(t_s)
        if self.p.ripple_mpa:
            ps += self.p.ripple_mpa * math.sin(2.0 * math.pi * t_s / self.p.ripple_period_s)
        return ps if ps > 0.0 else 0.0


class LoadMismatch(Effect):
    """The muscle carries ``extra_n`` more than the nominal load.

    Parameters
    ----------
    p : LoadMismatchParams
        The extra weight ``extra_n`` [N] (negative: a lighter load; the total is clipped at 0).
    """

    name = "load_mismatch"

    def __init__(self, p: LoadMismatchParams) -> None:
        self.extra_n = p.extra_n

    def load(self, t_s: float, load_n: float) -> float:
        w = load_n + self.extra_n
        return w if w > 0.0 else 0.0

    def held(self, t0_s: float, t1_s: float) -> bool:
        return True


class Backlash(Effect):
    """A play of ``slack_mm`` between the muscle end and the encoder slider (backlash operator).

    The slider stays put until the muscle end has moved half the play past it, then is dragged along
    at that distance. Applied to the positions at the sampling instants (the encoder's input).

    Parameters
    ----------
    p : BacklashParams
        The play ``slack_mm`` [mm]; the slider follows within half of it either side.
    """

    name = "backlash"

    def __init__(self, p: BacklashParams) -> None:
        self.half_mm = 0.5 * p.slack_mm
        self.y_mm = 0.0

    def reset(self, t_s: float, u_v: float, l_mm: float) -> None:
        self.y_mm = l_mm

    def measurement(self, t_s: float, l_mm: float) -> float:
        self.y_mm = backlash_operator(l_mm, self.y_mm, self.half_mm)
        return self.y_mm

    def get_state(self) -> dict[str, Any]:
        return {"y_mm": self.y_mm}

    def set_state(self, state: dict[str, Any]) -> None:
        self.y_mm = float(state["y_mm"])


def backlash_operator(x: float, y: float, half_play: float) -> float:
    """One update of the backlash (play) operator: output ``y`` follows ``x`` within ``+- half_play``."""
    if x - y > half_play:
        return x - half_play
    if y - x > half_play:
        return x + half_play
    return y


class SensorDrift(Effect):
    """The encoder's zero drifts: ``l_seen = l + offset_mm + rate_mm_per_min t / 60``.

    Parameters
    ----------
    p : SensorDriftParams
        The zero's offset [mm] and drift rate [mm/min].
    """

    name = "sensor_drift"

    def __init__(self, p: SensorDriftParams) -> None:
        self.offset_mm = p.offset_mm
        self.rate_mm_s = p.rate_mm_per_min / 60.0

    def measurement(self, t_s: float, l_mm: float) -> float:
        return l_mm + self.offset_mm + self.rate_mm_s * t_s


def effects_from_params(params: PlantParams) -> list[Effect]:
    """The switched-on effects of ``params``, in the order the plant applies them.

    Input side first (the delayed command passes through the input map, and the mapped command is the
    one the dead zone sees), then the supply and the load, then the measurement chain (the slider's
    backlash, then the encoder's drifting zero). An identity input map is left out, so the default
    plant has no effects at all.

    Parameters
    ----------
    params : PlantParams
        The plant's parameters; an effect is switched on by its group (``delay``, ``input_map``,
        ``dead_zone``, ``supply_variation``, ``load_mismatch``, ``backlash``, ``sensor_drift``).
    """
    out: list[Effect] = []
    if params.delay.delay_s > 0.0:
        out.append(TransportDelay(params.delay))
    if not params.input_map.is_identity():
        out.append(InputMap(params.input_map))
    if params.dead_zone.width_v > 0.0:
        out.append(ValveDeadZone(params.dead_zone))
    sv = params.supply_variation
    if sv.sag_mpa > 0.0 or sv.ripple_mpa > 0.0:
        out.append(SupplyPressureVariation(sv))
    if params.load_mismatch.extra_n != 0.0:
        out.append(LoadMismatch(params.load_mismatch))
    if params.backlash.slack_mm > 0.0:
        out.append(Backlash(params.backlash))
    sd = params.sensor_drift
    if sd.offset_mm != 0.0 or sd.rate_mm_per_min != 0.0:
        out.append(SensorDrift(sd))
    return out
