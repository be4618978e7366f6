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
    m dv/dt = F_muscle(p, l) + F_lock(l) - k_r l - W - c v - z  (hanging load W = m_load g)
    dz/dt = |v|/delta (sign(v) F_s(p, l, |v|) - z)  (friction, friction.py)

``A(l) = dV/dl`` is the Tondu-Lopez piston area (muscle.py), ``F_muscle = softplus_w(p - p_th) A(l)``
(the bladder takes the first ``p_th``) and ``F_lock = F_lock0 exp(-l / l_lock)`` the braid lock near
full extension; ``k_in(x) = K (e + (1 - e) g x^n)`` (valve.py).
The fully extended braid is a rigid stop at ``l = 0``.

Integration: the command is held over a communication step (zero-order hold), so the spool follows
its exact exponential solution. The other four states are stiff (the hose/bladder compliance makes the
pressure and the load a ~40-45 Hz hydraulic spring-mass pair, and the valve conductance near a
saturated command relaxes the pressure at ~900 1/s), so they are integrated with the linearly
implicit Rosenbrock-W method ROS34PW2 (3rd order, L-stable) over adaptive sub-steps: each sub-step
solves four 4x4 linear systems with the analytic Jacobian of the stiff couplings, its embedded
2nd-order solution estimates the local error, and the step size follows the tolerances in
``SolverParams`` (``docs/plant.md``, "Integration"). Sub-steps end exactly on every communication
point, so the trajectory does not depend on the communication step beyond those tolerances. The
effect ports (effects.py) are sampled at the start of every sub-step (once per stretch between
breakpoints for effects that hold their signals there).

Lifecycle, as osqp's setup -> update -> solve: ``Plant(params)`` sets up, :meth:`Plant.update` changes
the load or supply pressure between steps (they may change during a run), :meth:`Plant.step` advances
time, :meth:`Plant.reset` starts over. Given the same seed, parameters and inputs, a run is
bit-for-bit reproducible.
"""

from __future__ import annotations

import copy
import math
import os
from typing import Any, Callable, Iterable, NamedTuple, Sequence

import numpy as np

from . import compiled_run as _compiled
from .effect_library import effects_from_params
from .effects import Effect
from .muscle import MuscleGeometry
from .parameters import CV_TO_SI_WATER, GRAVITY_M_S2, PlantParams
from .rosenbrock import KINK_SCALE_INITIAL, build_model, compiled_step_loop, forced_substeps
from .seed import check_seed
from .sensors import quantise
from .user_warning import warn_at_caller
from .valve import flow_coefficient, orifice_flow, valve_opening

__all__ = ["Plant", "Measurement", "LightLoadWarning", "STATE_NAMES", "MAX_STEP_S", "COMMAND_RANGE_V"]


class LightLoadWarning(RuntimeWarning):
    """A run whose hanging load was below the braid lock (``muscle.braid_lock_force_n``), where the
    model's unpowered muscle contracts by itself. Its message names the load, so a loop over loads
    shows one per load; ``warnings.simplefilter("ignore", tm.LightLoadWarning)`` silences it where
    light loads are meant (a parameter estimation, a sweep)."""

#: Names of the continuous state, in the order of :attr:`Plant.state`.
STATE_NAMES = ("x", "p_mpa", "l_mm", "v_mm_s", "z_n")

#: Longest communication step accepted by :meth:`Plant.step` [s].
MAX_STEP_S = 3600.0

#: Commands [V] the plant takes, as the MusclePlant FMU's input ``u`` declares: the valve's 0..10 V and
#: 1 V either side, which saturates in the amplifier (an offset amplifier, a read-back's noise);
#: outside: another unit (mV, %).
COMMAND_RANGE_V = (-1.0, 11.0)

#: Sensor noise is drawn from the plant's generator in blocks of this many normals.
_NOISE_BLOCK = 64


class Measurement(NamedTuple):
    """What the rig's instruments report after a step: ``t_s, l_mm, p_mpa = plant.step(u_v, dt_s)``.

    A named tuple (immutable), as cheap to make as the plant's step needs: a diagnosis steps the
    plant millions of times.

    Attributes
    ----------
    t_s : float
        Time at the end of the step [s].
    l_mm : float
        Encoder reading of the contraction [mm] (noise, 0.01 mm quantisation).
    p_mpa : float
        Pressure-sensor reading [MPa(G)].
    """

    t_s: float
    l_mm: float
    p_mpa: float


def _effect_states(saved: Any, effects: Sequence[Effect]) -> list[dict[str, Any] | None]:
    """The saved state of each of ``effects``, paired by name (and order among equal names), or None.

    A plant with an extra effect may start from the state of the plant without it (the diagnosis's
    checkpoints): that effect keeps its own state, wherever it sits in the order. A saved effect this
    plant does not have is an error (the state of another plant).
    """
    try:
        pairs = [(str(name), dict(state)) for name, state in saved]
    except (TypeError, ValueError):
        raise ValueError(f"state field effects must be [name, state] pairs, got {saved!r}") from None
    out: list[dict[str, Any] | None] = [None] * len(effects)
    taken = [False] * len(effects)
    for name, state in pairs:
        i = next((i for i, e in enumerate(effects) if not taken[i] and e.name == name), None)
        if i is None:
            raise ValueError(f"state field effects holds the state of effect {name!r}, which this plant "
                             f"does not have (it has {[e.name for e in effects]})")
        taken[i] = True
        out[i] = state
    return out


def _hooks(effects: Sequence[Effect], hook: str) -> tuple[Callable[..., Any], ...]:
    """The ``hook`` callables of those ``effects`` that replace the base class's (in the subclass or
    on the instance), in order."""
    base = getattr(Effect, hook)
    bound = [getattr(e, hook) for e in effects]
    return tuple(f for f in bound if getattr(f, "__func__", None) is not base)


#: The hooks of the ports sampled during the integration (the measurement hook is not one).
_PORT_HOOKS = ("valve_command", "valve_gate", "supply_pressure", "load")


def _hold_checks(effects: Sequence[Effect]) -> tuple[Callable[[float, float], bool], ...] | None:
    """The :meth:`Effect.held` methods of the ``effects`` that act on a port, or None if one of them
    has a port hook replaced on the instance (which its class's ``held`` knows nothing of)."""
    checks = []
    for e in effects:
        replaced = [h for h in _PORT_HOOKS if _hooks([e], h)]
        if replaced:
            if any(h in vars(e) for h in replaced):
                return None
            checks.append(e.held)
    return tuple(checks)


def _breakdown(failed_at_s: float, state: Sequence[float], params: PlantParams) -> FloatingPointError:
    """The error of an integration whose numbers broke down at ``failed_at_s`` from ``state``, naming
    the parameters off their defaults (one of them drove it there)."""
    defaults = PlantParams().dotted()
    off = [f"{k}={v:.6g}" for k, v in params.dotted().items() if v != defaults.get(k)]
    return FloatingPointError(f"plant integration failed at t = {failed_at_s:.6g} s: the state "
                              f"({', '.join(f'{v:.6g}' for v in state)}) went non-finite at "
                              f"the shortest sub-step (extreme parameters? off their defaults: "
                              f"{', '.join(off) or 'none'})")


def _finite(name: str, value: Any) -> float:
    # a number only: float() also takes "68", b"68" and a bool (True is 1 N); the common scalars are
    # told by their type (this runs every step), anything else by its array's kind
    scalar = type(value) is float or (isinstance(value, (float, int, np.floating, np.integer))
                                      and not isinstance(value, bool))
    if not scalar and (isinstance(value, (str, bytes, bytearray, memoryview, bool, np.bool_))
                       or np.asarray(value).dtype.kind not in "iuf"):
        raise ValueError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(f):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return f


def _step_length(dt_s: Any) -> float:
    dt_s = _finite("dt_s", dt_s)
    if not 0.0 < dt_s <= MAX_STEP_S:
        raise ValueError(f"dt_s must be within (0, {MAX_STEP_S}] s, got {dt_s!r}")
    return dt_s


def _finite_array(name: str, values: Any, takes: str = "a sequence of numbers") -> np.ndarray:
    """``values`` as a 1-D float array, every entry finite (else a ValueError naming the first bad one,
    or what ``name`` ``takes``)."""
    try:
        a = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {takes}, got {values!r}") from None
    if a.ndim != 1:
        raise ValueError(f"{name} must be {takes} (one-dimensional), got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] must be finite, got {float(a[bad[0]])!r}")
    return a


def _restored_plant(cls: type[Plant], params: PlantParams, seed: int, effects: Sequence[Effect],
                    state: dict[str, Any]) -> Plant:
    """A :class:`Plant` (of class ``cls``, a subclass taking the same arguments) built from its
    parameters, seed and own effects, at ``state`` (copying, unpickling)."""
    plant = cls(params, seed=seed, effects=effects)
    plant.set_state(state)
    return plant


class Plant:
    """Continuous-time model of the tap-water McKibben muscle rig.

    Parameters
    ----------
    params : PlantParams, optional
        Physical parameters (defaults reproduce the paper's rig at 44 N).
    seed : int, optional
        Seed of the sensor-noise generator.
    effects : Effect or sequence of Effect, optional
        Extra physics plugged into the plant's ports (effects.py), applied in order after the effects
        ``params`` switch on. They act in this process only: a plant FMU carries the parameters'
        effects alone (docs/plant.md, "Effects of your own").

    Examples
    --------
    >>> plant = Plant(seed=0)
    >>> m = plant.step(5.0, 0.1)
    >>> 0.0 <= m.l_mm < 150.0
    True
    """

    def __init__(self, params: PlantParams | None = None, *, seed: int = 0,
                 effects: Sequence[Effect] | Effect = ()) -> None:
        self.params = params if params is not None else PlantParams()
        if not isinstance(self.params, PlantParams):
            # a file is read by its reader (tapmuscle.read_plant_file); the plant takes the parameters
            hint = (": a plant parameter file is read by tm.read_plant_file(path)"
                    if isinstance(self.params, (str, os.PathLike)) else "")
            raise TypeError(f"params must be a PlantParams, got {type(self.params).__name__}{hint}")
        # the effects switched on in the parameters (effect_library.py), then the caller's own (one
        # counts as one)
        if isinstance(effects, Effect):
            effects = (effects,)
        elif not isinstance(effects, Iterable):
            raise TypeError(f"effects must be a sequence of Effect instances, got {type(effects).__name__}")
        self._own_effects = tuple(effects)
        self.effects: tuple[Effect, ...] = tuple(effects_from_params(self.params)) + self._own_effects
        for e in self.effects:
            if not isinstance(e, Effect):
                raise TypeError(f"effects must be Effect instances (subclasses of fmu_plant.Effect), got "
                                f"{type(e).__name__}")
        # Each port calls only the effects that act on it: a base hook is the identity (and a gate of
        # 1.0 multiplies exactly), so leaving it out changes no bit, and a sub-step of a plant whose
        # effects act on no port is integrated as the effect-free plant's.
        self._command_hooks = _hooks(self.effects, "valve_command")
        self._gate_hooks = _hooks(self.effects, "valve_gate")
        self._supply_hooks = _hooks(self.effects, "supply_pressure")
        self._load_hooks = _hooks(self.effects, "load")
        self._measurement_hooks = _hooks(self.effects, "measurement")
        self._breakpoint_hooks = _hooks(self.effects, "breakpoints")
        self._acts_on_ports = bool(self._command_hooks or self._gate_hooks or self._supply_hooks or self._load_hooks)
        # Ports that hold still over a stretch between breakpoints are sampled once for it (Effect.held):
        # the sub-steps would sample the same values, and a sub-step's Python call costs more than
        # its arithmetic.
        self._hold_checks = _hold_checks(self.effects)
        self._geometry = MuscleGeometry.from_params(self.params.muscle)
        vp = self.params.valve
        self._k_valve = vp.cv_max * CV_TO_SI_WATER
        self._laminar_pa = vp.laminar_dp_mpa * 1e6
        self._rhs, _, _, self._set_gate, self._advance_substeps = build_model(self.params)
        # step_many's loop compiled where it inlines every effect (compiled_run.py), the same bits; it
        # stands in for this sub-step loop only: one replaced on the instance (a counting benchmark) runs
        self._run = (compiled_step_loop(self._advance_substeps)
                     if _compiled.runnable(self.effects, self.params.sensor) else None)
        self._run_replaces = self._advance_substeps
        self.reset(seed=check_seed(seed))  # None is no seed here: there is no previous one to keep

    def __reduce__(self) -> tuple[Any, ...]:
        # The sub-step's closures (build_model) hold the valve gate and cannot be shared or pickled: a
        # copy or an unpickled plant is built anew and continues from get_state, bit for bit.
        return (_restored_plant, (type(self), self.params, self._seed, self._own_effects, self.get_state()))

    def __copy__(self) -> Plant:
        # a copy sharing the state would step both plants at once: copy.copy is copy.deepcopy
        return copy.deepcopy(self)

    # ------------------------------------------------------------------ lifecycle
    def reset(self, *, seed: int | None = None, load_n: float | None = None,
              supply_pressure_mpa: float | None = None, t_s: float = 0.0) -> Measurement:
        """Start over at rest: drained muscle, fully extended, at time ``t_s``.

        Parameters
        ----------
        seed : int, optional
            New noise seed (default: the previous one).
        load_n, supply_pressure_mpa : float, optional
            Initial load [N] and supply pressure [MPa] (default: from the parameters).
        t_s : float
            The clock's start [s] (an FMU's start time): every time-based effect counts in it.
        """
        t_s = _finite("t_s", t_s)
        if seed is not None:
            self._seed = check_seed(seed)  # unsigned 64-bit, as the FMU carries it (seed.py)
        self._rng = np.random.default_rng(self._seed)
        self._noise_start = None  # generator state before the current block of normals (None: no block)
        self._noise: list[float] = []
        self._noise_i = 0
        self.t_s = t_s
        self.state = [0.0, 0.0, 0.0, 0.0, 0.0]
        self._kink_scale = KINK_SCALE_INITIAL
        self._xs_last = 0.0
        self._gate = 1.0
        self._set_gate(1.0)
        self.u_v = self.params.valve.u_min_v
        self.load_n = self.params.load.load_n
        self.supply_pressure_mpa = self.params.supply.supply_pressure_mpa
        self.update(load_n=load_n, supply_pressure_mpa=supply_pressure_mpa)
        self._last_supply_mpa = self.supply_pressure_mpa
        for e in self.effects:
            e.reset(t_s, self.u_v, 0.0)
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
        FloatingPointError
            If the integration breaks down (a non-finite error estimate at the shortest sub-step, or
            too many sub-steps of ``solver.min_substep_s`` over their tolerances; only with extreme
            parameters). The state is that of the start of the step.
        """
        u_v = _finite("u_v", u_v)
        dt_s = _step_length(dt_s)
        self._integrate(u_v, dt_s)
        self.measurement = self._measure()
        return self.measurement

    def step_many(self, u_v: Sequence[float] | np.ndarray, dt_s: float, *,
                  load_n: float | Sequence[float] | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Hold each command of ``u_v`` [V] for ``dt_s`` [s] in turn; the readings after each step.

        The same, bit for bit, as calling :meth:`step` once per command (and :meth:`update` before a
        step whose load differs), without the per-step checks and records: a diagnosis re-simulates a
        recording's commands thousands of times. With the compiled sub-step installed, noise-free
        sensors and only the library's effects (the diagnosis's re-simulations), the whole loop runs
        in C (``compiled_run.py``): the same bits, 2-5 times faster.

        Parameters
        ----------
        u_v : sequence of float
            Valve commands [V], one per step.
        dt_s : float
            Length of every step [s], within (0, 3600].
        load_n : float or sequence of float, optional
            Hanging load [N], within 0..500: one value held throughout (the plant's load from the first
            step on, as :meth:`update` sets it), or one value per step (default: the current load
            throughout).

        Returns
        -------
        l_mm, p_mpa : ndarray
            Encoder and pressure-sensor readings [mm], [MPa(G)] at the end of each step, as
            :attr:`measurement` (which holds the last of them afterwards).

        Raises
        ------
        ValueError
            A command or load that is not finite or out of range (its index named), or a bad ``dt_s``;
            the plant is unchanged then.
        FloatingPointError
            As :meth:`step`; the plant is at the start of the step that failed.
        """
        u = _finite_array("u_v", u_v)
        dt_s = _step_length(dt_s)
        loads = None
        if load_n is not None:
            takes = "a number, or one number per command"
            if np.ndim(load_n) == 0:  # one load throughout
                if isinstance(load_n, (str, bytes, bool, np.bool_)):
                    raise ValueError(f"load_n must be {takes}, got {load_n!r}")
                w0 = float(load_n)
                if not (math.isfinite(w0) and 0.0 <= w0 <= 500.0):
                    raise ValueError(f"load_n must be within 0..500 N, got {w0!r}")
                w = np.full(len(u), w0)
            else:
                w = _finite_array("load_n", load_n, takes)
            if len(w) != len(u):
                raise ValueError(f"load_n has {len(w)} values for {len(u)} commands in u_v")
            out = np.flatnonzero((w < 0.0) | (w > 500.0))
            if out.size:
                raise ValueError(f"load_n[{out[0]}] must be within 0..500 N, got {float(w[out[0]])!r}")
            loads = w.tolist()
        if self._run is not None and self._advance_substeps is self._run_replaces:
            return self._step_many_compiled(u, dt_s, w if loads is not None else None)
        l_mm: list[float] = []
        p_mpa: list[float] = []
        integrate, readings = self._integrate, self._readings
        try:
            for i, u_i in enumerate(u.tolist()):
                if loads is not None and loads[i] != self.load_n:
                    self.load_n = loads[i]
                integrate(u_i, dt_s)
                l_i, p_i = readings()
                l_mm.append(l_i)
                p_mpa.append(p_i)
        finally:
            if l_mm:
                self.measurement = Measurement(self.t_s, l_mm[-1], p_mpa[-1])
        return np.array(l_mm, dtype=float), np.array(p_mpa, dtype=float)

    def _step_many_compiled(self, u: np.ndarray, dt_s: float, loads: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`step_many`'s loop in C (``compiled_run.py``), for checked commands and loads."""
        n = len(u)
        l_mm, p_mpa = np.empty(n), np.empty(n)
        if n == 0:
            return l_mm, p_mpa
        sp = self.params.sensor
        spec, times, values = _compiled.run_spec(self.effects)
        done, plant, gate, times, values, slider, failure = self._run(
            np.ascontiguousarray(u), None if loads is None else np.ascontiguousarray(loads), l_mm, p_mpa, dt_s,
            (self.t_s, *self.state, self._xs_last, self._kink_scale, self._last_supply_mpa, self._gate, self.u_v,
             self.load_n, self.supply_pressure_mpa),
            (sp.encoder_resolution_mm, sp.pressure_resolution_mpa, sp.pressure_range_mpa), spec, times, values)
        self.t_s, *state, self._xs_last, self._kink_scale, self._last_supply_mpa, self.u_v, self.load_n = plant
        self.state = state
        self._gate = gate
        self._set_gate(gate)  # the Python equations' gate too (derivatives, flows)
        _compiled.write_back(self.effects, times, values, slider)
        if done:
            self.measurement = Measurement(self.t_s, float(l_mm[done - 1]), float(p_mpa[done - 1]))
        if failure is not None:
            raise failure[1] if failure[0] == "raised" else _breakdown(failure[1], failure[2], self.params)
        return l_mm, p_mpa

    def _integrate(self, u_v: float, dt_s: float) -> None:
        """Advance the state by one step of a checked command and length (:meth:`step`).

        A breakdown (FloatingPointError) or an interrupt (KeyboardInterrupt, checked in the compiled
        sub-steps too) leaves the state of the step's start; an interrupt also the command before it.
        """
        u_before, self.u_v = self.u_v, u_v
        t0 = self.t_s
        t1 = t0 + dt_s
        cuts = [t for f in self._breakpoint_hooks for t in f(t0, t1, u_v)] if self._breakpoint_hooks else ()
        if len(cuts) > 1:
            cuts = sorted(set(cuts))
        try:
            if cuts:  # end sub-steps exactly where an effect's port signal jumps
                saved = (list(self.state), self._xs_last, self._kink_scale, self._last_supply_mpa, self._gate)
                try:
                    ta = t0
                    for tb in (*cuts, t1):
                        self._advance(ta, tb - ta)
                        ta = tb
                except (FloatingPointError, KeyboardInterrupt):
                    self.state, self._xs_last, self._kink_scale, self._last_supply_mpa, self._gate = saved
                    self._set_gate(self._gate)
                    raise
            else:
                self._advance(t0, dt_s)
        except KeyboardInterrupt:
            self.u_v = u_before
            raise
        self.t_s = t1

    # ------------------------------------------------------------------ accuracy
    @property
    def forced_substeps(self) -> int:
        """Sub-steps of ``solver.min_substep_s`` accepted over their error tolerances since the plant was
        built (every step, :meth:`step_many` too; a reset does not clear it): with any, the trajectory is
        not integrated to the solver's tolerances (stiff parameters, docs/plant.md "Integration")."""
        return forced_substeps(self._advance_substeps)

    def accuracy_note(self) -> str | None:
        """What :attr:`forced_substeps` means for the run, in one sentence (None when it is 0)."""
        n = self.forced_substeps
        if not n:
            return None
        return (f"the plant's integration accepted {n} sub-step{'s' if n > 1 else ''} of solver.min_substep_s = "
                f"{self.params.solver.min_substep_s:g} s over their error tolerances, so its trajectory may be far "
                "off (stiff parameters: a friction.presliding_mm far below 1 um, say); a smaller "
                "solver.min_substep_s integrates it accurately (docs/plant.md, Integration)")

    def light_load_note(self, load_n: float, name: str = "load_n") -> str | None:
        """What a hanging load of ``load_n`` [N] below the braid lock (``muscle.braid_lock_force_n``)
        means for the model, in one sentence naming the load ``name`` (None at or above the lock)."""
        lock = self.params.muscle.braid_lock_force_n
        if not load_n < lock:
            return None
        # a mass in kilograms whose weight would be a load the rig takes is the likely slip
        mass = (f"; if {load_n:g} is a mass in kg, its weight is {9.80665 * load_n:.3g} N: the load is a force in N"
                if lock <= 9.80665 * load_n and load_n < 10.0 else "")
        return (f"{name} = {load_n:g} N is below the braid lock's {lock:g} N (muscle.braid_lock_force_n){mass}: the "
                "model's muscle contracts without pressure then (9.6 mm at 0 N, 2.1 mm at 20 N, from rest at 0 V), as "
                "no rig at rest does; the lock was calibrated for the paper's 44 and 68 N: for a lighter load set "
                "muscle.braid_lock_force_n below it (docs/plant.md)")

    def warn_run_notes(self, lightest_load_n: float) -> None:
        """After a run whose lightest load was ``lightest_load_n`` [N]: :meth:`accuracy_note` and
        :meth:`light_load_note` as ``RuntimeWarning`` (:class:`LightLoadWarning`), at the user's line."""
        for note, category in ((self.accuracy_note(), RuntimeWarning),
                               (self.light_load_note(lightest_load_n), LightLoadWarning)):
            if note:
                warn_at_caller(note, category)

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
            "rng": self._rng.bit_generator.state if self._noise_start is None else self._noise_start,
            "noise_index": None if self._noise_start is None else self._noise_i,
            "effects": [[e.name, e.get_state()] for e in self.effects],
            "measurement": (self.measurement.t_s, self.measurement.l_mm, self.measurement.p_mpa),
            "last_supply_mpa": self._last_supply_mpa, "kink_scale_s": self._kink_scale,
            "xs_last": self._xs_last, "gate": self._gate,
        }

    def set_state(self, s: dict[str, Any]) -> None:
        """Restore what :meth:`get_state` returned.

        Raises
        ------
        ValueError
            A field that no plant could have saved (non-finite, out of its range, wrong length), named;
            a restored plant must step as the saved one did (a zero step scale would never return).
        """
        def field(name: str, lo: float = -math.inf, hi: float = math.inf, *, open_lo: bool = False) -> float:
            v = float(s[name])
            if not (math.isfinite(v) and (lo < v if open_lo else lo <= v) and v <= hi):
                raise ValueError(f"state field {name} = {v!r} must be a finite number in "
                                 f"{'(' if open_lo else '['}{lo:g}, {hi:g}]")
            return v

        field("t_s")  # any start time
        field("u_v")
        field("load_n", 0.0)
        field("supply_pressure_mpa", 0.0)
        field("last_supply_mpa", 0.0)
        if "kink_scale_s" in s:
            field("kink_scale_s", 0.0, 1.0, open_lo=True)
        if "gate" in s:
            field("gate", 0.0, 1.0)
        if len(s["state"]) != len(self.state) or not all(math.isfinite(float(v)) for v in s["state"]):
            raise ValueError(f"state field state must be {len(self.state)} finite numbers, got {s['state']!r}")
        if not all(math.isfinite(float(v)) for v in s["measurement"]) or len(s["measurement"]) != 3:
            raise ValueError(f"state field measurement must be 3 finite numbers, got {s['measurement']!r}")
        if int(s["seed"]) < 0:
            raise ValueError(f"state field seed = {s['seed']!r} must be >= 0")
        effect_states = _effect_states(s["effects"], self.effects)
        self.t_s = float(s["t_s"])
        self.state = [float(v) for v in s["state"]]
        self.u_v = float(s["u_v"])
        self.load_n = float(s["load_n"])
        self.supply_pressure_mpa = float(s["supply_pressure_mpa"])
        self._seed = int(s["seed"])
        self._rng = np.random.default_rng()
        self._rng.bit_generator.state = s["rng"]
        self._noise_start, self._noise, self._noise_i = None, [], 0
        if s.get("noise_index") is not None:  # redraw the block the saved plant was reading from
            self._noise_start = s["rng"]
            self._noise = self._rng.standard_normal(_NOISE_BLOCK).tolist()
            self._noise_i = int(s["noise_index"])
        for e, es in zip(self.effects, effect_states):
            if es is not None:
                e.set_state(es)
        self.measurement = Measurement(*s["measurement"])
        self._last_supply_mpa = float(s["last_supply_mpa"])
        self._kink_scale = float(s.get("kink_scale_s", KINK_SCALE_INITIAL))
        self._xs_last = float(s.get("xs_last", self.state[0]))
        self._gate = float(s.get("gate", 1.0))
        self._set_gate(self._gate)

    def _normal(self) -> float:
        """The generator's next standard normal, drawn in blocks (the same sequence, 20x cheaper)."""
        if self._noise_i == len(self._noise):
            self._noise_start = self._rng.bit_generator.state
            self._noise = self._rng.standard_normal(_NOISE_BLOCK).tolist()
            self._noise_i = 0
        self._noise_i += 1
        return self._noise[self._noise_i - 1]

    def _measure(self) -> Measurement:
        """Sensor readings of the current state, timed."""
        return Measurement(self.t_s, *self._readings())

    def _readings(self) -> tuple[float, float]:
        """Encoder [mm] and pressure [MPa(G)] readings of the current state (sensors.py: noise, then
        quantisation, then range); draws the noise and updates the measurement effects."""
        sp = self.params.sensor
        l_seen = self.state[2]
        for f in self._measurement_hooks:
            l_seen = f(self.t_s, l_seen)
        if sp.encoder_noise_std_mm > 0.0:
            l_seen = l_seen + sp.encoder_noise_std_mm * self._normal()
        p_seen = self.state[1]
        if sp.pressure_noise_std_mpa > 0.0:
            p_seen = p_seen + sp.pressure_noise_std_mpa * self._normal()
        p_seen = quantise(p_seen, sp.pressure_resolution_mpa)
        return quantise(l_seen, sp.encoder_resolution_mm), min(max(p_seen, 0.0), sp.pressure_range_mpa)

    # ------------------------------------------------------------------ dynamics
    def _ports(self, t_s: float) -> tuple[float, float, float]:
        """Valve command [V], supply pressure [MPa], load [N] after the effects, at ``t_s``; sets the
        valve gate."""
        u, ps, w = self.u_v, self.supply_pressure_mpa, self.load_n
        for f in self._command_hooks:
            u = f(t_s, u)
        gate = 1.0
        for f in self._gate_hooks:
            gate *= f(t_s, u)
        for f in self._supply_hooks:
            ps = f(t_s, ps)
        for f in self._load_hooks:
            w = f(t_s, w)
        if gate != self._gate:
            self._gate = gate
            self._set_gate(gate)
        return u, ps, w

    def _valve_flows(self, x: float, p_mpa: float, ps_mpa: float) -> tuple[float, float]:
        """Flows through the supply and drain valves [m^3/s] at spool opening ``x``."""
        vp = self.params.valve
        k_in = flow_coefficient(self._k_valve, x, vp.leak_fraction, vp.characteristic_exponent, self._gate)
        k_out = flow_coefficient(self._k_valve, 1.0 - x, vp.leak_fraction, vp.characteristic_exponent, self._gate)
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

        Returns
        -------
        list of 5 floats
            ``(dx/dt [1/s], dp/dt [MPa/s], dl/dt [mm/s], dv/dt [mm/s^2], dz/dt [N/s])``.
        """
        x, p, l, v, z = s
        vp = self.params.valve
        dx = (valve_opening(u_v, vp.u_min_v, vp.u_max_v) - x) / vp.spool_time_constant_s
        inv_mass = 1e3 / (load_n / GRAVITY_M_S2 + self.params.load.moving_mass_kg)
        return [dx, *self._rhs(x, p, l, v, z, ps_mpa, load_n, inv_mass)]

    def _held(self, t0: float, t1: float) -> bool:
        """Whether every port effect holds its signals over ``[t0, t1]`` (Effect.held)."""
        if self._hold_checks is None:
            return False
        for held in self._hold_checks:  # a loop, not all(...) over a generator: it runs for every stretch
            if not held(t0, t1):
                return False
        return True

    def _advance(self, t0: float, dt: float) -> None:
        """Integrate the state over ``[t0, t0 + dt]`` with adaptive ROS34PW2 sub-steps (module docstring)."""
        # the ports are sampled at every sub-step where an effect acts on them, or once for the stretch
        # where every such effect holds its signals; a gate left from a restored state is reset by
        # their first sampling
        ports = self._ports if self._acts_on_ports or self._gate != 1.0 else None
        u, ps, w = self.u_v, self.supply_pressure_mpa, self.load_n
        if ports is not None and self._held(t0, t0 + dt):
            u, ps, w = ports(t0)
            ports = None
        x, p, l, v, z = self.state
        x, p, l, v, z, xs, self._kink_scale, self._last_supply_mpa, failed_at = self._advance_substeps(
            x, p, l, v, z, self._xs_last, self._kink_scale, self._last_supply_mpa, u, ps, w, t0, dt, ports)
        if failed_at == failed_at:  # not NaN: the numbers broke down at the shortest sub-step
            raise _breakdown(failed_at, self.state, self.params)
        self.state = [x, p, l, v, z]
        self._xs_last = xs

