"""The simulated tap-water muscle rig: valve, supply, muscle, hanging load, friction, sensors.

State (engineering units, as the rig's instruments show them):

=====  =======  ===============================================================
x      [-]      supply-valve spool opening (the drain valve opens ``1 - x``)
p      [MPa]    muscle gauge pressure
l      [mm]     contraction (the displacement the paper calls ``l``), >= 0
v      [mm/s]   contraction speed
z      [N]      braid-bladder friction force (Dahl state)
=====  =======  ===============================================================

Equations (docs/plant.md derives them and lists every parameter's source)::

    dx/dt = (x*(u) - x) / tau_v
    C dp/dt = Q_in - Q_out - A(l) v                 (water volume balance, hose/bladder compliance C)
    Q_in  = k_in(x)  sign(ps - p) sqrt(|ps - p|)     (supply valve, opening x)
    Q_out = k_out(x) sign(p - pd) sqrt(|p - pd|)     (drain valve, opening 1 - x)
    m dv/dt = F_muscle(p, l) - k_r l - W - c v - z  (hanging load W = m_load g)
    dz/dt = |v|/delta (sign(v) F_s(p, l, |v|) - z)  (friction, friction.py)

``A(l) = dV/dl`` is the Tondu-Lopez piston area (muscle.py) and ``F_muscle = (p - p_th)+ A(l)``.
The fully extended braid is a rigid stop at ``l = 0``. A communication step of length ``dt`` is
integrated with classical Runge-Kutta over equal sub-steps no longer than
``SolverParams.max_substep_s``; the command is held (zero-order hold) over the step, and the
effect ports (effects.py) are sampled at the start of every sub-step.

Lifecycle, as osqp's setup -> update -> solve: ``Plant(params)`` sets up, :meth:`Plant.update` changes
the load or supply pressure between steps (they may change during a run), :meth:`Plant.step` advances
time, :meth:`Plant.reset` starts over. Given the same seed, parameters and inputs, a run is
bit-for-bit reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np

from .effects import Effect
from .friction import friction_level_n
from .muscle import MuscleGeometry
from .parameters import CV_TO_SI_WATER, GRAVITY_M_S2, PlantParams
from .sensors import read_encoder_mm, read_pressure_mpa
from .valve import orifice_flow, valve_opening

__all__ = ["Plant", "Measurement", "STATE_NAMES", "MAX_STEP_S"]

#: Names of the continuous state, in the order of :attr:`Plant.state`.
STATE_NAMES = ("x", "p_mpa", "l_mm", "v_mm_s", "z_n")

#: Longest communication step accepted by :meth:`Plant.step` [s].
MAX_STEP_S = 3600.0


@dataclass(frozen=True)
class Measurement:
    """What the rig's instruments report after a step."""

    t_s: float
    """Time at the end of the step [s]."""
    l_mm: float
    """Encoder reading of the contraction [mm] (noise, 0.01 mm quantisation)."""
    p_mpa: float
    """Pressure-sensor reading [MPa(G)]."""


def _finite(name: str, value: Any) -> float:
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(f):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return f


class Plant:
    """Continuous-time model of the tap-water McKibben muscle rig.

    Parameters
    ----------
    params : PlantParams, optional
        Physical parameters (defaults reproduce the paper's rig at 44 N).
    seed : int, optional
        Seed of the sensor-noise generator.
    effects : sequence of Effect, optional
        Extra physics plugged into the plant's ports (effects.py), applied in order.

    Examples
    --------
    >>> plant = Plant(seed=0)
    >>> m = plant.step(5.0, 0.1)
    >>> 0.0 <= m.l_mm < 150.0
    True
    """

    def __init__(self, params: PlantParams | None = None, *, seed: int = 0,
                 effects: Sequence[Effect] = ()) -> None:
        self.params = params if params is not None else PlantParams()
        if not isinstance(self.params, PlantParams):
            raise ValueError(f"params must be a PlantParams, got {type(self.params).__name__}")
        self.effects: tuple[Effect, ...] = tuple(effects)
        for e in self.effects:
            if not isinstance(e, Effect):
                raise ValueError(f"effects must be Effect instances, got {type(e).__name__}")
        self._geometry = MuscleGeometry.from_params(self.params.muscle)
        vp = self.params.valve
        self._k_valve = vp.cv_max * CV_TO_SI_WATER
        self._laminar_pa = vp.laminar_dp_mpa * 1e6
        self.reset(seed=seed)

    # ------------------------------------------------------------------ lifecycle
    def reset(self, *, seed: int | None = None, load_n: float | None = None,
              supply_pressure_mpa: float | None = None) -> Measurement:
        """Start over at rest: drained muscle, fully extended, time 0.

        Parameters
        ----------
        seed : int, optional
            New noise seed (default: the previous one).
        load_n, supply_pressure_mpa : float, optional
            Initial load [N] and supply pressure [MPa] (default: from the parameters).
        """
        if seed is not None:
            if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
                raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
            self._seed = int(seed)
        self._rng = np.random.default_rng(self._seed)
        self.t_s = 0.0
        self.state = [0.0, 0.0, 0.0, 0.0, 0.0]
        self.u_v = self.params.valve.u_min_v
        self.load_n = self.params.load.load_n
        self.supply_pressure_mpa = self.params.supply.supply_pressure_mpa
        self.update(load_n=load_n, supply_pressure_mpa=supply_pressure_mpa)
        self._last_supply_mpa = self.supply_pressure_mpa
        for e in self.effects:
            e.reset(0.0, self.u_v, 0.0)
        self.measurement = self._measure()
        return self.measurement

    def update(self, *, load_n: float | None = None, supply_pressure_mpa: float | None = None) -> None:
        """Change the hanging load [N] or the supply pressure [MPa(G)] from now on."""
        if load_n is not None:
            load_n = _finite("load_n", load_n)
            if not 0.0 <= load_n <= 500.0:
                raise ValueError(f"load_n must be within 0..500 N, got {load_n!r}")
            self.load_n = load_n
        if supply_pressure_mpa is not None:
            supply_pressure_mpa = _finite("supply_pressure_mpa", supply_pressure_mpa)
            if not 0.0 <= supply_pressure_mpa <= 1.0:
                raise ValueError(f"supply_pressure_mpa must be within 0..1 MPa, got {supply_pressure_mpa!r}")
            self.supply_pressure_mpa = supply_pressure_mpa

    def step(self, u_v: float, dt_s: float) -> Measurement:
        """Hold the valve command ``u_v`` [V] for ``dt_s`` [s] and return the sensor readings.

        Commands outside the valve's 0..10 V range saturate in the valve amplifier.

        Raises
        ------
        ValueError
            If ``u_v`` or ``dt_s`` is not finite, or ``dt_s`` is not within (0, 3600] s. The plant
            state is unchanged then.
        """
        u_v = _finite("u_v", u_v)
        dt_s = _finite("dt_s", dt_s)
        if not 0.0 < dt_s <= MAX_STEP_S:
            raise ValueError(f"dt_s must be within (0, {MAX_STEP_S}] s, got {dt_s!r}")
        self.u_v = u_v
        n = max(1, math.ceil(dt_s / self.params.solver.max_substep_s - 1e-9))
        h = dt_s / n
        t0 = self.t_s
        for i in range(n):
            self._rk4(t0 + i * h, h)
        self.t_s = t0 + dt_s
        self.measurement = self._measure()
        return self.measurement

    # ------------------------------------------------------------------ outputs
    #: The latest sensor readings (from :meth:`reset` or :meth:`step`).
    measurement: Measurement

    @property
    def l_mm(self) -> float:
        """True contraction [mm] (no sensor noise)."""
        return self.state[2]

    @property
    def p_mpa(self) -> float:
        """True muscle gauge pressure [MPa]."""
        return self.state[1]

    def get_state(self) -> dict[str, Any]:
        """Everything needed to continue bit-identically (state, time, RNG, effects), as plain data."""
        return {
            "t_s": self.t_s, "state": list(self.state), "u_v": self.u_v, "load_n": self.load_n,
            "supply_pressure_mpa": self.supply_pressure_mpa, "seed": self._seed,
            "rng": self._rng.bit_generator.state,
            "effects": [e.get_state() for e in self.effects],
            "measurement": (self.measurement.t_s, self.measurement.l_mm, self.measurement.p_mpa),
            "last_supply_mpa": self._last_supply_mpa,
        }

    def set_state(self, s: dict[str, Any]) -> None:
        """Restore what :meth:`get_state` returned."""
        self.t_s = float(s["t_s"])
        self.state = [float(v) for v in s["state"]]
        self.u_v = float(s["u_v"])
        self.load_n = float(s["load_n"])
        self.supply_pressure_mpa = float(s["supply_pressure_mpa"])
        self._seed = int(s["seed"])
        self._rng = np.random.default_rng()
        self._rng.bit_generator.state = s["rng"]
        for e, es in zip(self.effects, s["effects"]):
            e.set_state(es)
        self.measurement = Measurement(*s["measurement"])
        self._last_supply_mpa = float(s["last_supply_mpa"])

    def _measure(self) -> Measurement:
        sp = self.params.sensor
        l_seen = self.state[2]
        for e in self.effects:
            l_seen = e.measurement(self.t_s, l_seen)
        return Measurement(self.t_s, read_encoder_mm(sp, l_seen, self._rng),
                           read_pressure_mpa(sp, self.state[1], self._rng))

    # ------------------------------------------------------------------ dynamics
    def _ports(self, t_s: float) -> tuple[float, float, float]:
        """Valve command [V], supply pressure [MPa], load [N] after the effects, at ``t_s``."""
        u, ps, w = self.u_v, self.supply_pressure_mpa, self.load_n
        for e in self.effects:
            u = e.valve_command(t_s, u)
            ps = e.supply_pressure(t_s, ps)
            w = e.load(t_s, w)
        return u, ps, w

    def _valve_flows(self, x: float, p_mpa: float, ps_mpa: float) -> tuple[float, float]:
        """Flows through the supply and drain valves [m^3/s] at spool opening ``x``."""
        vp = self.params.valve
        xc = 0.0 if x < 0.0 else 1.0 if x > 1.0 else x
        leak = vp.leak_fraction
        n = vp.characteristic_exponent
        k_in = self._k_valve * (leak + (1.0 - leak) * xc ** n)
        k_out = self._k_valve * (leak + (1.0 - leak) * (1.0 - xc) ** n)
        return (orifice_flow(k_in, (ps_mpa - p_mpa) * 1e6, self._laminar_pa),
                orifice_flow(k_out, (p_mpa - self.params.supply.drain_pressure_mpa) * 1e6, self._laminar_pa))

    def flows_l_min(self) -> tuple[float, float]:
        """Flows through the supply and drain valves [L/min] (positive into / out of the muscle), at the
        supply pressure of the last integration sub-step (a query never calls the effect hooks, which
        may have memory)."""
        q_in, q_out = self._valve_flows(self.state[0], self.state[1], self._last_supply_mpa)
        return q_in * 6e4, q_out * 6e4

    def derivatives(self, s: Iterable[float], u_v: float, ps_mpa: float, load_n: float) -> list[float]:
        """Right-hand side ``ds/dt`` of the state equations for fixed port signals.

        Parameters
        ----------
        s : sequence of 5 floats
            State ``(x, p_mpa, l_mm, v_mm_s, z_n)``.
        u_v, ps_mpa, load_n : float
            Valve command [V], supply gauge pressure [MPa], hanging load [N].
        """
        x, p, l, v, z = s
        prm = self.params
        vp, mp, fp = prm.valve, prm.muscle, prm.friction
        geo = self._geometry

        # Valves: spool lag, then the supply and drain orifices.
        dx = (valve_opening(u_v, vp.u_min_v, vp.u_max_v) - x) / vp.spool_time_constant_s
        q_in, q_out = self._valve_flows(x, p, ps_mpa)

        # Muscle: the flow not stored in the hose/bladder compliance moves the braid.
        l_m = l * 1e-3
        area = geo.piston_area_m2(l_m)
        dp = (q_in - q_out - area * v * 1e-3) / prm.supply.compliance_m3_per_mpa
        # Smooth bladder threshold (softplus): no kink where the braid starts to carry load.
        w = mp.threshold_width_mpa
        arg = (p - mp.threshold_pressure_mpa) / w
        p_eff = w * (arg + math.log1p(math.exp(-arg)) if arg > 0.0 else math.log1p(math.exp(arg)))
        f_muscle = p_eff * 1e6 * area
        # Braid lock: the braid stiffens progressively towards full extension and carries the load there.
        f_lock = mp.braid_lock_force_n * math.exp(-l / mp.braid_lock_length_mm) if mp.braid_lock_force_n else 0.0

        # Friction (Dahl) with pressure, contact-area, direction and rate dependence.
        if v != 0.0:
            direction = 1.0 if v > 0.0 else -1.0
            speed = v if v > 0.0 else -v
            level = friction_level_n(fp, p, geo.contact_factor(l_m), speed, direction)
            dz = speed / fp.presliding_mm * (direction * level - z)
        else:
            dz = 0.0

        mass = load_n / GRAVITY_M_S2 + prm.load.moving_mass_kg
        force = f_muscle + f_lock - mp.rubber_stiffness_n_per_mm * l - load_n - mp.damping_n_s_per_mm * v - z
        dv = force / mass * 1e3  # N/kg = m/s^2 -> mm/s^2
        if l <= 0.0 and v <= 0.0 and force <= 0.0:
            # Resting on the braid's full-extension stop: the stop carries the net force.
            return [dx, dp, 0.0, 0.0, 0.0]
        return [dx, dp, v, dv, dz]

    def _rk4(self, t_s: float, h: float) -> None:
        u, ps, w = self._ports(t_s)
        self._last_supply_mpa = ps
        s = self.state
        f = self.derivatives
        k1 = f(s, u, ps, w)
        k2 = f([a + 0.5 * h * b for a, b in zip(s, k1)], u, ps, w)
        k3 = f([a + 0.5 * h * b for a, b in zip(s, k2)], u, ps, w)
        k4 = f([a + h * b for a, b in zip(s, k3)], u, ps, w)
        new = [a + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
               for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4)]
        if new[2] < 0.0:  # the stop is rigid: no penetration, no rebound
            new[2] = 0.0
            if new[3] < 0.0:
                new[3] = 0.0
        self.state = new
