"""``MusclePlant``: the simulated rig (fmu_plant.Plant) as an FMI 2.0 co-simulation slave.

Inputs ``u`` [V], ``load_force`` [N], ``supply_pressure`` [MPa(G)]; outputs ``l`` [mm] (encoder) and ``p``
[MPa(G)] (pressure sensor); every physical parameter of docs/plant.md as a fixed parameter named
``group.field`` (e.g. ``friction.rate_gain``), plus ``seed``. A thin shell: the numerics are
:class:`fmu_plant.Plant`; the FMI behaviour (errors, state) is :class:`fmi_slave.SafeSlave`'s.

Bad input (NaN, inf, a command outside -1..11 V, a load outside 0..500 N, a supply pressure outside
0..1 MPa, a step size <= 0) is refused with fmi2Discard and a logged message naming it; the plant and
its outputs are unchanged. A command within -1..11 V saturates in the valve amplifier at 0..10 V as
on the rig.

Time: the plant's clock is the host's. It starts at the start time of ``fmi2SetupExperiment`` (the
plant is at rest there, its sensors read there) and advances with the steps, so every time-based
effect counts in the host's time: a supply sag with ``supply_variation.start_s = 6`` begins at host
time 6 s whatever the start time, and a transport delay's memory starts at the start time. A step
must start at the plant's time (:class:`fmi_slave.SafeSlave`: a gap or a step back is fmi2Error).
"""

from __future__ import annotations

import math
import sys
from dataclasses import fields

from fmi_slave import SafeSlave
from fmi_slave.base import SlaveInputError
from pythonfmu import DefaultExperiment
from pythonfmu.enums import Fmi2Status
from fmu_plant import Plant, PlantParams
from fmu_plant.parameters import dotted_names
from fmu_plant.plant import COMMAND_RANGE_V
from fmu_plant.rosenbrock import COMPILED, COMPILED_FOR_ANOTHER_PYTHON
from fmu_plant.seed import join_seed

__all__ = ["MusclePlant", "SET_BY_INPUT", "parameter_table"]

#: every parameter's default, by the FMU's name
_DEFAULTS = PlantParams().dotted()


#: The parameters whose physics an input of the FMU sets (the parameters stay for plant files, which set
#: every one): the input's name.
SET_BY_INPUT = {"load.load_n": "load_force", "supply.supply_pressure_mpa": "supply_pressure"}


def parameter_table() -> list[tuple[str, float, str, str, float | None, float | None]]:
    """``(name, default, unit, description, min, max)`` of every plant parameter, from the dataclasses;
    the description of one in :data:`SET_BY_INPUT` says how its input and it share the part (a tool's
    parameter dialog shows it beside the others)."""
    rows = []
    defaults = PlantParams()
    for group in fields(defaults):
        sub = getattr(defaults, group.name)
        for f in fields(sub):
            doc = f.metadata.get("doc", "")
            if f"{group.name}.{f.name}" in SET_BY_INPUT:
                inp = SET_BY_INPUT[f"{group.name}.{f.name}"]
                doc = (f"{doc.rstrip('. ')}; in the FMU its input {inp} sets it: this value is used in its place "
                       f"while {inp} is left at its start value (a plant file's)")
            unit = PlantParams.unit(f"{group.name}.{f.name}")
            if f.metadata.get("lo_open"):  # FMI's min cannot be open: the description says the limit is refused
                doc = f"{doc.rstrip('. ')}; must be > {f.metadata['lo']:g} (the declared min itself is refused)"
            rows.append((f"{group.name}.{f.name}", float(getattr(sub, f.name)), unit, doc,
                         f.metadata.get("lo"), f.metadata.get("hi")))
    return rows


class MusclePlant(SafeSlave):
    """Tap-water McKibben muscle rig (paper section 2.4, Table 1).

    Parameters
    ----------
    **kwargs
        pythonfmu's ``Fmi2Slave`` arguments (``instance_name``, ``resources``, ...), which the
        FMU's host passes on instantiation.
    """

    author = "tapmuscle"
    description = "Tap-water-driven McKibben muscle rig: proportional valves, 0.25 MPa supply, 400 mm muscle, load, encoder"
    #: Tells hosts the communication step (the controller's Ts = 0.1 s) and a run that holds the paper's
    #: Eq. (21) window (10.1-40.1 s; the paper gives no run length) with room to spare; no tolerance: the
    #: adaptive sub-steps keep their own (parameters ``solver.*``).
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=60.0, step_size=0.1)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.add_input("u", 0.0, "V", "valve command [V], 0..10 (saturates in the amplifier)", lo=-1.0, hi=11.0,
                       nominal=5.0)
        # not "load": under the structured naming convention that name is the parent of the parameters
        # load.load_n and load.moving_mass_kg, and a tool mapping names to a hierarchy cannot make it both
        self.add_input("load_force", 44.0, "N", "force of the hanging load on the muscle [N]", lo=0.0, hi=500.0, nominal=50.0)
        self.add_input("supply_pressure", 0.25, "MPa", "tap-water supply gauge pressure [MPa]", lo=0.0, hi=1.0,
                       nominal=0.25)
        # l and p are read from the state (encoder, sensor): no direct feedthrough from any input.
        # The declared ranges hold every reading the parameters allow: l has none, since an encoder's
        # drift moves its reading without bound over a long run; p is clipped to the sensor's range
        # (sensor.pressure_range_mpa, at most 100 MPa). At initialisation they are the readings at rest,
        # computed from the parameters (a sensor offset, the noise's seed), not start values a host sets.
        table = parameter_table()
        parameters = tuple(row[0] for row in table) + ("seed", "seed_high")
        self.add_output("l", 0.0, "mm", "encoder reading of the contraction [mm]", nominal=50.0,
                        calculated_from=parameters)
        self.add_output("p", 0.0, "MPa", "pressure-sensor reading [MPa(G)], 0..sensor.pressure_range_mpa", lo=0.0,
                        hi=100.0, nominal=0.25, calculated_from=parameters)
        self.add_real_parameters(table)
        self.add_integer_parameter("seed", 0, "seed of the sensor-noise generator: its low 32 bits (bit pattern; "
                                   "a seed below 2**31 needs this alone)")
        self.add_integer_parameter("seed_high", 0, "high 32 bits of the sensor-noise seed (bit pattern; seeds are "
                                   "unsigned 64-bit)")
        self._plant: Plant | None = None
        self._tally = _Tally()
        self._rest_key: tuple | None = None  # the set-up refresh_calculated computed l and p for

    def _plant_at_rest(self) -> Plant:
        """The rig the parameters describe, at rest at the start time (SlaveInputError naming a bad one)."""
        try:
            params = PlantParams().with_values(**self._par)
        except ValueError as exc:
            raise SlaveInputError(f"bad parameter: {dotted_names(str(exc))}") from None
        try:
            seed = join_seed(self._int_par["seed"], self._int_par["seed_high"])
        except ValueError as exc:
            raise SlaveInputError(str(exc)) from None
        plant = Plant(params, seed=seed)
        if self._start_s != 0.0:
            plant.reset(t_s=self._start_s)
        return plant

    def refresh_calculated(self) -> None:
        key = (tuple(self._par.values()), tuple(self._int_par.values()), self._start_s)
        if key != self._rest_key:  # a host reads the outputs every call: the rig is built once per set-up
            self._rest_key = key
            try:
                rest = self._plant_at_rest().measurement
            except (SlaveInputError, ValueError):
                return
            self.l, self.p = rest.l_mm, rest.p_mpa

    def initialize_numerics(self) -> None:
        self._plant = self._plant_at_rest()
        self._refused_input: str | None = None
        try:
            load = self.finite("load_force", self.load_force, 0.0, 500.0)
            supply = self.finite("supply_pressure", self.supply_pressure, 0.0, 1.0)
        except SlaveInputError as exc:
            # an input, not a parameter: a bad one is refused where it acts, at the steps (fmi2Discard, which
            # a host may retry with it mended); the rig at rest on its stop is the same under any load and
            # supply, so the run is then the one with the mended input from the start
            self.log(f"input {exc} at fmi2ExitInitializationMode: the plant starts at rest, and every fmi2DoStep "
                     "returns fmi2Discard until the input is in range", status=Fmi2Status.warning)
            self._refused_input = str(exc)
        else:
            # the inputs set the load and the supply pressure (they change during a run); the parameters of
            # the same physics are a plant file's, which a user copies into a host's parameter dialog: set
            # while its input is left at its start value, the parameter takes the input's place (the rig the
            # file describes); set against an input set to another value, the input wins and it is said
            inputs = {"load_force": load, "supply_pressure": supply}
            for name, inp in SET_BY_INPUT.items():
                value, par = inputs[inp], self._par[name]
                if par == value or par == _DEFAULTS[name]:
                    continue
                if value == _DEFAULTS[name]:
                    inputs[inp] = par
                    setattr(self, inp, par)
                    self.log(f"parameter {name} = {par!r} sets the input {inp}, left at its start value {value!r}: "
                             "the plant file's rig (an input the host sets later wins)")
                else:
                    self.log(f"parameter {name} = {par!r} is not used: the input {inp} (= {value!r}) sets it in the "
                             "FMU; set the input instead", status=Fmi2Status.warning)
            load, supply = inputs["load_force"], inputs["supply_pressure"]
            self._plant.update(load_n=load, supply_pressure_mpa=supply)
        self.l, self.p = self._plant.measurement.l_mm, self._plant.measurement.p_mpa
        self._tally = _Tally(u_range=(self._plant.params.valve.u_min_v, self._plant.params.valve.u_max_v))
        self._u_lo, self._u_hi = self._tally.u_range
        self._inaccurate_said = False
        self._lock_n, self._light_said = self._plant.params.muscle.braid_lock_force_n, False
        if COMPILED_FOR_ANOTHER_PYTHON:  # said, not warned: the results are the same, only slower
            self.log(f"the plant's compiled integrator sub-step {COMPILED_FOR_ANOTHER_PYTHON} was built for another "
                     f"Python than this host's CPython {sys.version_info.major}.{sys.version_info.minor}: its Python "
                     "sub-step runs instead, with the same results, about 2.5 times slower; build the FMUs with this "
                     "Python (tapmuscle build) for the compiled one")

    def step_numerics(self, t_s: float, dt_s: float) -> None:
        u = self.finite("u", self.u, *COMMAND_RANGE_V)
        load = self.finite("load_force", self.load_force, 0.0, 500.0)
        ps = self.finite("supply_pressure", self.supply_pressure, 0.0, 1.0)
        plant = self._plant
        if load != plant.load_n or ps != plant.supply_pressure_mpa:
            plant.update(load_n=load, supply_pressure_mpa=ps)
        m = plant.step(u, dt_s)
        self.l, self.p = m.l_mm, m.p_mpa
        if load < self._lock_n and not self._light_said:  # once: the unpowered muscle then contracts by itself
            self._light_said = True
            self.log(f"t = {t_s:.12g} s: {plant.light_load_note(load, 'load_force')}", status=Fmi2Status.warning)
        if not self._inaccurate_said and plant.forced_substeps:  # once: outputs that look fine may be far off
            self._inaccurate_said = True
            self.log(f"t = {t_s + dt_s:g} s: {plant.accuracy_note()}", status=Fmi2Status.warning)
        # the run summary's tally, inline: this runs every step
        tally, l, p = self._tally, m.l_mm, m.p_mpa
        tally.steps += 1
        if not self._u_lo <= u <= self._u_hi:
            tally.saturated += 1
        if l < tally.l_lo:
            tally.l_lo = l
        if l > tally.l_hi:
            tally.l_hi = l
        if p < tally.p_lo:
            tally.p_lo = p
        if p > tally.p_hi:
            tally.p_hi = p

    def setup_summary(self) -> str:
        plant = self._plant
        effects = ", ".join(e.name.replace("_", " ") for e in plant.effects) or "none"
        sub_step = "compiled" if COMPILED and not COMPILED_FOR_ANOTHER_PYTHON else "Python"
        inputs = (f"input {self._refused_input} (refused: fmi2Discard from each step until it is in range)"
                  if self._refused_input else
                  f"load {plant.load_n:g} N, supply pressure {plant.supply_pressure_mpa:g} MPa (the inputs)")
        return (f"{inputs}; "
                f"left-out effects switched on: {effects}; integrator sub-step: {sub_step}; "
                + super().setup_summary())

    def run_summary(self) -> str:
        return f"{super().run_summary()}: {self._tally}"

    def numerics_state(self):
        if self._plant is None:
            return None
        return {**self._plant.get_state(), "fmu_tally": self._tally.as_list()}

    def restore_numerics_state(self, state) -> None:
        if state is not None:
            state = dict(state)
            # a state of a build without the tally: counted from here, and the summary says so
            tally = state.pop("fmu_tally", None)
            self._plant.set_state(state)
            u_range = self._tally.u_range
            self._tally = _Tally(*tally, u_range=u_range) if tally else _Tally(partial=tally is None, u_range=u_range)


class _Tally:
    """What the plant's run summary says: steps, ranges of the readings, saturated commands (counted in
    :meth:`MusclePlant.step_numerics`)."""

    __slots__ = ("steps", "l_lo", "l_hi", "p_lo", "p_hi", "saturated", "partial", "u_range")

    def __init__(self, steps: int = 0, l_lo: float = math.inf, l_hi: float = -math.inf, p_lo: float = math.inf,
                 p_hi: float = -math.inf, saturated: int = 0, partial: bool = False, *,
                 u_range: tuple[float, float] = (0.0, 10.0)) -> None:
        self.steps, self.saturated = int(steps), int(saturated)
        self.l_lo, self.l_hi, self.p_lo, self.p_hi = float(l_lo), float(l_hi), float(p_lo), float(p_hi)
        self.partial = bool(partial)  # counted from a restored state that carried no tally
        self.u_range = u_range  # the valve's command range [V] (valve.u_min_v, valve.u_max_v)

    def as_list(self) -> list:
        """Plain data for an FMU state (strict JSON: no infinities before the first step)."""
        return [self.steps, self.l_lo, self.l_hi, self.p_lo, self.p_hi, self.saturated, self.partial] if self.steps \
            else []

    def __str__(self) -> str:
        if not self.steps:
            return "no step"
        since = " since a restored state" if self.partial else ""
        return (f"{self.steps} steps{since}; readings l {self.l_lo:.4g}..{self.l_hi:.4g} mm, p {self.p_lo:.4g}..{self.p_hi:.4g} "
                f"MPa; command outside the amplifier's {self.u_range[0]:g}..{self.u_range[1]:g} V (saturated there) in "
                f"{self.saturated} steps")

