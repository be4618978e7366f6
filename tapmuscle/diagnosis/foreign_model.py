"""Any FMI 2.0 FMU (co-simulation, or model exchange integrated by CVode) as the plant of a
diagnosis: its interface, its parameter sets, and the re-simulation of a recording through it with
boundary effects added by the master.

* :class:`FmuInterface`: the Real inputs, outputs and parameters the model description declares
  (start value, bounds, unit).
* :class:`ModelValues`: one parameter set, immutable: the FMU's Real parameters plus the boundary
  effects' parameters (``"<variable>:<name>"``, :mod:`tapmuscle.diagnosis.boundary_effects`). It
  answers ``value``, ``dotted`` and ``with_values`` as :class:`fmu_plant.PlantParams` does, so the
  calibration and the search work on it unchanged.
* :class:`ForeignSimulator`: runs the recording through the FMU (one instance, reset between runs)
  with a parameter set; what :class:`tapmuscle.diagnosis.simulation.Simulator` is for the
  tapmuscle plant. An FMU that offers co-simulation is stepped by its own solver; one that offers
  only model exchange is integrated between samples by fmpy's CVode
  (:class:`tapmuscle.cosim.model_exchange.ModelExchangeStepper`), with the inputs held.

Sampling as in every recording: row ``k`` holds the output at ``t_k`` and the inputs held over
``[t_k, t_{k+1})``; the FMU is initialised with the first inputs set, and its time 0 is the
recording's first time.
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from tapmuscle.cosim.master import FmuInstance, unpack
from tapmuscle.cosim.model_exchange import ModelExchangeStepper
from tapmuscle.cosim.spec import ScenarioError
from tapmuscle.diagnosis.boundary_effects import apply_input_effects, apply_output_effects, window_profile
from tapmuscle.diagnosis.fit_problem import SimulationError
from tapmuscle.errors import TapmuscleError

__all__ = ["FmuVariable", "FmuInterface", "ModelValues", "ForeignSimulator", "read_interface", "ForeignFmuError"]


class ForeignFmuError(TapmuscleError):
    """An FMU the diagnosis cannot use (unreadable, neither co-simulation nor model exchange, fails to
    instantiate or to run with its own start values); the message names the file and the reason."""


@dataclass(frozen=True)
class FmuVariable:
    """A Real variable of the FMU.

    Parameters
    ----------
    name : str
        The variable's name.
    value_reference : int
        Its value reference.
    start : float or None
        Its start value, if declared.
    unit : str or None
        Its unit (its own or its declared type's), if any.
    lo, hi : float
        Its declared min and max (``-inf``/``inf`` if none).
    variability : str
        Its variability (``"fixed"``, ``"tunable"``, ``"continuous"``, ...).
    """

    name: str
    value_reference: int
    start: float | None
    unit: str | None
    lo: float
    hi: float
    variability: str


@dataclass(frozen=True)
class FmuInterface:
    """What the model description declares: Real inputs, outputs and parameters, and whether the
    FMU is run through model exchange (it offers no co-simulation).

    Parameters
    ----------
    path : Path
        The FMU file.
    model_name : str
        Its model name.
    inputs, outputs : tuple of FmuVariable
        Its Real inputs and outputs.
    parameters : tuple of FmuVariable
        Its fixed or tunable Real parameters.
    default_step_s : float or None
        The default experiment's step size [s], if declared.
    model_exchange : bool, optional
        Run through model exchange (it offers no co-simulation); default False.
    """

    path: Path
    model_name: str
    inputs: tuple[FmuVariable, ...]
    outputs: tuple[FmuVariable, ...]
    parameters: tuple[FmuVariable, ...]
    default_step_s: float | None
    model_exchange: bool = False

    @property
    def kind(self) -> str:
        """``"co-simulation"`` or ``"model exchange"``: how the diagnosis runs the FMU."""
        return "model exchange" if self.model_exchange else "co-simulation"

    def variable(self, name: str) -> FmuVariable:
        for v in self.inputs + self.outputs + self.parameters:
            if v.name == name:
                return v
        raise KeyError(name)


def read_interface(path: str | Path) -> FmuInterface:
    """The :class:`FmuInterface` of the FMU file ``path`` (co-simulation when offered, else model
    exchange); :class:`ForeignFmuError` naming the file if it cannot be read or offers neither.

    Parameters
    ----------
    path : str or Path
        The FMU file.
    """
    path = Path(path)
    if not path.is_file():
        raise ForeignFmuError(f"--plant {path}: no such FMU file")
    try:
        md = unpack(path).model_description
    except ScenarioError as exc:
        raise ForeignFmuError(f"--plant {exc}") from None
    if md.fmiVersion != "2.0":
        raise ForeignFmuError(f"--plant {path}: FMI {md.fmiVersion}; the diagnosis runs FMI 2.0 FMUs")
    if md.coSimulation is None and md.modelExchange is None:
        raise ForeignFmuError(f"--plant {path}: {md.modelName} offers neither co-simulation nor model exchange")

    def real(v: Any) -> FmuVariable:
        dt = v.declaredType
        unit = v.unit or (dt.unit if dt is not None else None)
        lo = v.min if v.min is not None else (dt.min if dt is not None and dt.min is not None else -math.inf)
        hi = v.max if v.max is not None else (dt.max if dt is not None and dt.max is not None else math.inf)
        start = float(v.start) if v.start is not None else None
        return FmuVariable(v.name, int(v.valueReference), start, unit, float(lo), float(hi), v.variability or "")
    reals = [v for v in md.modelVariables if v.type == "Real"]
    de = md.defaultExperiment
    step = float(de.stepSize) if de is not None and de.stepSize is not None else None
    return FmuInterface(path.resolve(), md.modelName,
                        tuple(real(v) for v in reals if v.causality == "input"),
                        tuple(real(v) for v in reals if v.causality == "output"),
                        tuple(real(v) for v in reals if v.causality == "parameter"
                              and v.variability in ("fixed", "tunable")), step,
                        model_exchange=md.coSimulation is None)


@dataclass(frozen=True)
class ModelValues:
    """One parameter set of a foreign plant (module docstring): immutable, every key known.

    Parameters
    ----------
    values : mapping of str to float
        Every value of the set: the FMU's parameters and the boundary effects'
        (``"<variable>:<name>"``).
    """

    values: Mapping[str, float]

    def value(self, key: str) -> float:
        """The value of ``key``; ``KeyError`` if the set has no such parameter."""
        return float(self.values[key])

    def dotted(self) -> dict[str, float]:
        """All values as a plain dict (a copy)."""
        return dict(self.values)

    def with_values(self, **values: float) -> "ModelValues":
        """A copy with ``values`` replaced; ``ValueError`` naming an unknown key or a non-finite value."""
        for key, v in values.items():
            if key not in self.values:
                raise ValueError(f"unknown parameter {key!r} (known: {', '.join(sorted(self.values)[:10])}, ...)")
            if not math.isfinite(v):
                raise ValueError(f"parameter {key!r} = {v!r} is not finite")
        return ModelValues({**self.values, **{k: float(v) for k, v in values.items()}})

    def __iter__(self) -> Iterator[str]:
        return iter(self.values)


@dataclass
class ForeignSimulator:
    """Re-simulates one recording through a foreign FMU (setup once, run many times).

    Parameters
    ----------
    interface : FmuInterface
        The FMU.
    t_s : ndarray
        The recording's times [s] (uniform).
    ts_s : float
        Sampling period [s].
    inputs : dict of str to ndarray
        Recorded values per FMU input (the others are held at their start values, changed only by
        a secondary-input effect).
    output : str
        The FMU output compared with the measurement.
    input_ranges : dict of str to (float, float)
        Each recorded input's range, the domain of its input map.
    fixed : dict of str to float
        Parameters set on every run but not part of the parameter sets (the map's fixed values).
    units : dict of str to str
        The recording's unit of each mapped variable (the signal map's), for the report's words where
        the FMU declares none.
    runs : int, optional
        Simulations run so far (counted on).
    executor : concurrent.futures.Executor, optional
        Worker processes the search submits independent tasks to (None: in this process); not
        pickled.
    """

    interface: FmuInterface
    t_s: np.ndarray
    ts_s: float
    inputs: dict[str, np.ndarray]
    output: str
    input_ranges: dict[str, tuple[float, float]]
    fixed: dict[str, float] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    runs: int = 0
    executor: Any = field(default=None, repr=False, compare=False)
    _instance: FmuInstance | None = field(default=None, repr=False, compare=False)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["executor"] = None
        state["_instance"] = None  # a copy in another process instantiates its own
        return state

    # ------------------------------------------------------------------ the FMU
    def _fresh(self) -> FmuInstance:
        """An instance in initialization mode (reset when one exists; re-created after a failure)."""
        if self._instance is not None:
            try:
                self._instance.reset()
                return self._instance
            except ScenarioError:
                self.close()
        try:
            self._instance = FmuInstance(self.interface.path, "diagnose.foreign", role="foreign plant",
                                         model_exchange=self.interface.model_exchange)
        except ScenarioError as exc:
            raise ForeignFmuError(f"--plant {self.interface.path}: cannot instantiate: {exc}") from None
        return self._instance

    def close(self) -> None:
        """Free the FMU instance (a later run creates a new one)."""
        if self._instance is not None:
            try:
                self._instance.free()
            except Exception:  # noqa: BLE001 - an instance that failed may refuse to be freed; drop it
                pass
            self._instance = None

    def input_signals(self, params: ModelValues) -> dict[str, np.ndarray]:
        """Every FMU input's values per sample with ``params``' boundary effects."""
        values = params.values
        out = {}
        for v in self.interface.inputs:
            if v.name in self.inputs:
                lo, hi = self.input_ranges[v.name]
                out[v.name] = apply_input_effects(self.inputs[v.name], v.name, values, self.ts_s, lo, hi)
            else:
                base = v.start if v.start is not None else 0.0
                change = values.get(f"{v.name}:change", 0.0)
                sig = np.full(len(self.t_s), base)
                if change != 0.0:
                    sig = sig + window_profile(self.t_s, change, values[f"{v.name}:start_s"],
                                               values[f"{v.name}:end_s"], self.ts_s)
                out[v.name] = sig
        return out

    def run(self, params: ModelValues, *, stop: int | None = None, start: int = 0,
            checkpoint_every: int = 0) -> tuple[np.ndarray, None]:
        """The output as the sensor reads it, samples ``0 .. stop - 1`` (``start`` must be 0: a foreign
        FMU has no checkpoints; ``checkpoint_every`` is ignored).

        Raises :class:`~tapmuscle.diagnosis.fit_problem.SimulationError` naming the parameters and the
        FMU's message when a call fails or the output is not finite.
        """
        if start:
            raise ValueError("a foreign FMU is simulated from the start of the recording (start = 0)")
        n = len(self.t_s) if stop is None else stop
        self.runs += 1
        signals = self.input_signals(params)
        names = [v.name for v in self.interface.inputs]
        u = np.column_stack([signals[nm][:n] for nm in names]) if names else np.zeros((n, 0))
        y = self._simulate(params, u, n)
        return apply_output_effects(y, self.output, params.values, self.t_s), None

    def _simulate(self, params: ModelValues, u: np.ndarray, n: int) -> np.ndarray:
        inst = self._fresh()
        fmu = inst.fmu
        own = {v.name for v in self.interface.parameters}
        values = {k: v for k, v in params.values.items() if k in own} | self.fixed
        try:
            inst.set_parameters(values, where=f"{self.interface.path.name}: parameter '")
            vr_in = (ctypes.c_uint * u.shape[1])(*[v.value_reference for v in self.interface.inputs])
            buf = (ctypes.c_double * u.shape[1])()
            vr_out = (ctypes.c_uint * 1)(self.interface.variable(self.output).value_reference)
            got = (ctypes.c_double * 1)()
            comp = fmu.component
            set_real, get_real = fmu.fmi2SetReal, fmu.fmi2GetReal
            nin = u.shape[1]
            if nin:
                buf[:] = u[0].tolist()
                set_real(comp, vr_in, nin, buf)
            inst.start()
            if self.interface.model_exchange:
                step = ModelExchangeStepper(fmu, inst.unpacked.model_description, 0.0).do_step
            else:
                do_step = fmu.fmi2DoStep

                def step(t: float, h: float) -> None:
                    do_step(comp, t, h, 1)
            y = np.empty(n)
            get_real(comp, vr_out, 1, got)
            y[0] = got[0]
            ts = self.ts_s
            rows = u.tolist()
            for k in range(n - 1):
                if nin:
                    buf[:] = rows[k]
                    set_real(comp, vr_in, nin, buf)
                step(k * ts, ts)
                get_real(comp, vr_out, 1, got)
                y[k + 1] = got[0]
        except Exception as exc:  # noqa: BLE001 - FMICallException, ModelExchangeError; the instance is re-made
            logged = [m for m in inst.said(2) if str(exc) not in m]
            inst.failed(getattr(exc, "status", 3))  # freed as its last status allows
            self.close()
            said = f" (the FMU logged: {'; '.join(logged)})" if logged else ""
            raise SimulationError(f"{self.interface.model_name} with {_short(values)}: {exc}{said}") from None
        bad = np.nonzero(~np.isfinite(y))[0]
        if bad.size:
            raise SimulationError(f"{self.interface.model_name} with {_short(values)}: output {self.output} is "
                                  f"{y[bad[0]]!r} at t = {float(self.t_s[bad[0]]):g} s")
        return y

    def run_many(self, params: Sequence[ModelValues], *, stop: int | None = None) -> list[np.ndarray]:
        """``run(p, stop=stop)[0]`` for each of ``params``, in order (here, in this process)."""
        return [self.run(p, stop=stop)[0] for p in params]

    def checkpoints(self) -> list[int]:
        """None: a foreign FMU is always simulated from the start."""
        return []


def _short(values: Mapping[str, float]) -> str:
    return ", ".join(f"{k} = {v:.6g}" for k, v in list(values.items())[:8]) or "its start values"
