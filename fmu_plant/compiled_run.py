"""Plant.step_many's loop compiled (``_ros34pw2.c``, ``Model.run``) for the effects of the library.

The compiled loop is :meth:`~fmu_plant.Plant.step_many`'s Python loop (``_integrate``, ``_advance``,
``_ports``, ``_readings``) with the arithmetic of the effects in ``effect_library.py`` inlined,
operation for operation, so it gives the same bits (``tests/test_compiled_run.py`` checks them). It
runs only what it inlines: a plant whose effects are exactly the library's classes (no subclass, no hook
replaced on the instance, none of the class's functions replaced), each at most once and in the order
:func:`effects_from_params` gives them, and whose sensors draw no noise; :meth:`Plant.step_many` keeps
its Python loop otherwise. This module packs such an effect list into the run's arguments and writes
back the memory the run changed (the delay's command history, the backlash's slider).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from .effect_library import (Backlash, InputMap, LoadMismatch, SensorDrift, SupplyPressureVariation,
                             TransportDelay, ValveDeadZone)
from .effects import Effect
from .parameters import SensorParams

__all__ = ["LIBRARY_ORDER", "runnable", "run_spec", "write_back"]

#: The library's effects in the order the compiled loop applies them (that of effects_from_params).
LIBRARY_ORDER = (TransportDelay, InputMap, ValveDeadZone, SupplyPressureVariation, LoadMismatch, Backlash,
                 SensorDrift)

#: Every method of Effect: one replaced on an instance is code the compiled loop does not have.
_EFFECT_METHODS = tuple(name for name, v in vars(Effect).items() if callable(v) and not name.startswith("__"))

#: The library classes' own functions as imported: one changed on the class (a patch in a notebook)
#: is code the compiled loop does not have either.
_AS_IMPORTED = {cls: {name: v for name, v in vars(cls).items() if callable(v)} for cls in LIBRARY_ORDER}


def _as_imported(cls: type) -> bool:
    """Whether the library class ``cls`` has the functions it was imported with, and no others."""
    now = {name: v for name, v in vars(cls).items() if callable(v)}
    return now.keys() == _AS_IMPORTED[cls].keys() and all(now[n] is v for n, v in _AS_IMPORTED[cls].items())


def runnable(effects: Sequence[Effect], sensor: SensorParams) -> bool:
    """Whether the compiled loop gives the Python loop's bits for a plant with ``effects`` and ``sensor``.

    Parameters
    ----------
    effects : sequence of Effect
        The plant's effects, in the order it applies them; only classes of :data:`LIBRARY_ORDER`,
        each once and in that order, with none of their methods overridden on the instance, can
        run compiled.
    sensor : SensorParams
        The plant's sensors: any encoder or pressure noise (std > 0) rules the compiled loop out.
    """
    if sensor.encoder_noise_std_mm > 0.0 or sensor.pressure_noise_std_mpa > 0.0:
        return False
    last = -1
    for e in effects:
        if type(e) not in LIBRARY_ORDER or any(m in vars(e) for m in _EFFECT_METHODS) or not _as_imported(type(e)):
            return False
        slot = LIBRARY_ORDER.index(type(e))
        if slot <= last:
            return False
        last = slot
    return True


def run_spec(effects: Sequence[Effect]) -> tuple[tuple[Any, ...], list[float] | None, list[float] | None]:
    """The ``spec`` (one entry per class of :data:`LIBRARY_ORDER`: its numbers, or None if absent) and the
    delay's history ``(times, values)`` that ``Model.run`` takes, read from ``effects`` now.

    Parameters
    ----------
    effects : sequence of Effect
        The plant's effects (library classes, as :func:`runnable` accepts them).
    """
    spec: list[tuple[float, ...] | None] = [None] * len(LIBRARY_ORDER)
    times = values = None
    for e in effects:
        if isinstance(e, TransportDelay):
            spec[0] = (e.delay_s,)
            times, values = e._times, e._values
        elif isinstance(e, InputMap):
            p = e.p
            spec[1] = (p.out_at_0_v, p.knot1_in_v, p.knot1_out_v, p.knot2_in_v, p.knot2_out_v, p.out_at_10_v)
        elif isinstance(e, ValveDeadZone):
            spec[2] = (e.lo_v, e.hi_v)
        elif isinstance(e, SupplyPressureVariation):
            corners = e._corners or (math.nan,) * 4  # NaN: no instant lies between two others
            spec[3] = (e._sag, e._start, e._end, e._ramp, e._back, e.p.ripple_mpa, e.p.ripple_period_s, *corners)
        elif isinstance(e, LoadMismatch):
            spec[4] = (e.extra_n,)
        elif isinstance(e, Backlash):
            spec[5] = (e.half_mm, e.y_mm)
        elif isinstance(e, SensorDrift):
            spec[6] = (e.offset_mm, e.rate_mm_s)
    return tuple(spec), times, values


def write_back(effects: Sequence[Effect], times: list[float] | None, values: list[float] | None,
               slider_mm: float) -> None:
    """Give ``effects`` the memory a run left: the delay's command history, the backlash's slider [mm].

    Parameters
    ----------
    effects : sequence of Effect
        The plant's effects, given back their memory in place.
    times, values : list of float or None
        The transport delay's command history after the run: instants the command changed [s] and
        the command from then on [V] (as :func:`run_spec` returned them, updated by the run).
    slider_mm : float
        The backlash slider's position after the run [mm].
    """
    for e in effects:
        if isinstance(e, TransportDelay):
            e._times, e._values = times, values
        elif isinstance(e, Backlash):
            e.y_mm = slider_mm
