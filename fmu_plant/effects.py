"""Plug-in points for physical effects the core model leaves out.

The core equations (valve, supply, muscle, load, friction, sensor) never change when an effect is
added: an :class:`Effect` transforms the signal at one of the plant's ports, each call receiving the
simulation time. The ports are

=====================  =============================================  ===========================
hook                   signal                                          typical effects
=====================  =============================================  ===========================
``valve_command``      valve command [V], every integration sub-step  transport delay, input map
``valve_gate``         opening factor 0..1 of both valves, per sub-step  dead zone
``supply_pressure``    supply gauge pressure [MPa], every sub-step    supply sag or fluctuation
``load``               hanging load [N], every sub-step               load mismatch
``measurement``        true contraction -> encoder input [mm]         sensor drift, backlash
=====================  =============================================  ===========================

An effect whose port signal jumps at known instants (a delayed command change, the start of a supply
sag) reports them from :meth:`Effect.breakpoints`; the plant then ends an integration sub-step exactly
there. An effect whose signals hold still over a stretch of time (between those instants, for a held
command) says so from :meth:`Effect.held`, and its ports are then sampled once per stretch rather than
at every sub-step. The concrete effects are in ``effect_library.py``.

An effect with memory (a delay line, a backlash position) keeps it in its own state, resets it in
:meth:`Effect.reset` and exposes it via :meth:`Effect.get_state` / :meth:`Effect.set_state` so that
the plant's state can be saved and restored bit-identically (FMI get/set FMU state).
"""

from __future__ import annotations

from typing import Any

__all__ = ["Effect"]


class Effect:
    """Base class: every hook is the identity. Subclasses override the ports they act on."""

    #: Short machine name of the effect (e.g. ``"transport_delay"``).
    name: str = "identity"


    def reset(self, t_s: float, u_v: float, l_mm: float) -> None:
        """Forget memory; called by :meth:`Plant.reset` with the initial time, command and contraction."""

    def valve_command(self, t_s: float, u_v: float) -> float:
        """Command the valve amplifier actually receives [V]."""
        return u_v

    def valve_gate(self, t_s: float, u_v: float) -> float:
        """Factor 0..1 on the opening of both valves for the command ``u_v`` [V] (1: unaffected)."""
        return 1.0

    def breakpoints(self, t0_s: float, t1_s: float, u_v: float) -> list[float]:
        """Instants strictly inside ``(t0_s, t1_s)`` [s] where a port signal jumps, for a step that holds
        the command ``u_v`` [V] from ``t0_s``."""
        return []

    def held(self, t0_s: float, t1_s: float) -> bool:
        """True if every port signal of this effect has the same value at every instant of
        ``[t0_s, t1_s]`` [s], a stretch within one step (between two of its breakpoints, the command
        held): the plant then samples the ports once, at ``t0_s``, instead of at every integration
        sub-step, with the same result. The default, False, is always safe; a wrong True changes the
        trajectory."""
        return False

    def supply_pressure(self, t_s: float, p_mpa: float) -> float:
        """Supply gauge pressure seen by the supply valve [MPa]."""
        return p_mpa

    def load(self, t_s: float, load_n: float) -> float:
        """Weight actually hanging on the muscle [N]."""
        return load_n

    def measurement(self, t_s: float, l_mm: float) -> float:
        """Displacement the encoder sees, before its noise and quantisation [mm]."""
        return l_mm

    def get_state(self) -> dict[str, Any]:
        """Plain-data copy of the effect's memory (empty for memoryless effects)."""
        return {}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`get_state` returned."""
