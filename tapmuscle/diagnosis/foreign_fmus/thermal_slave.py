"""``ThermalTwoMass``: two lumped thermal masses as an FMI 2.0 co-simulation slave (pythonfmu).

A system unrelated to the project's muscle, for hosts that must work with any FMU. Self-contained:
it imports only the standard library and pythonfmu, so it runs in any Python that has pythonfmu
(no numpy, nothing of this project).

Model (temperatures in degC, powers in W, capacities in J/K, conductances in W/K)::

    C1 dT1/dt = P1 - G12 (T1 - T2) - G1a (T1 - T_amb)
    C2 dT2/dt = P2 + G12 (T1 - T2) - G2a (T2 - T_amb)

Inputs ``P1``, ``P2`` (heater powers, held constant over a communication step); outputs ``T1``,
``T2`` (the states themselves: no direct feedthrough); fixed parameters ``C1``, ``C2``, ``G12``,
``G1a``, ``G2a``, ``T_amb``, ``T1_0``, ``T2_0``.

Integration is exact for inputs held over the step: in the coordinates y = C^(1/2) (T - T_amb) the
system matrix is symmetric, its 2x2 eigen-decomposition (one Jacobi rotation, computed once at
``fmi2ExitInitializationMode``) decouples it into two scalar ODEs z' = lam z + c, solved in closed
form with ``expm1`` (also for lam = 0, i.e. no conductance to ambient). The result is exact up to
rounding for any step size.

Errors of the model never raise into pythonfmu: bad parameters (non-finite, C <= 0, G < 0, a temperature
below -273.15 degC) are logged with status Error at ``fmi2ExitInitializationMode`` and every
``fmi2DoStep`` then returns fmi2Discard with an Error message naming them; a non-finite input or a
step size <= 0 makes that ``fmi2DoStep`` return fmi2Discard with the state unchanged. A parameter set
after ``fmi2ExitInitializationMode`` is ignored with a Warning (the parameters are ``fixed``);
``fmi2Reset`` (which in pythonfmu 0.7 constructs a new instance of this class) makes them settable again.

Errors of the host (a value reference that does not exist or is not a Real, in ``fmi2GetReal`` and
the like) raise, which pythonfmu answers with fmi2Fatal after logging the message. On that path
pythonfmu 0.7's C++ layer releases its references to the slave, its class and its log queue
(``cleanPyObject``) and ``fmi2FreeInstance`` releases them again, which frees live objects: the
host segfaults later (measured: within 40 instantiate / bad getReal / free cycles). Every method
pythonfmu calls therefore adds, before an exception leaves it, the one reference per object that the
C++ layer takes back (:func:`_to_host`), so the instance stays valid and freeing it is safe.
"""

from __future__ import annotations

import functools
import math
from typing import Any, Callable
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real
from pythonfmu.enums import Fmi2Status

__all__ = ["ThermalTwoMass", "UNITS", "PARAMETERS"]

#: Absolute zero [degC]: no temperature parameter may lie below it.
ABSOLUTE_ZERO_DEGC = -273.15

#: FMI 2.0 unit definitions: name -> SI base-unit exponents (and offset, for degC).
UNITS: dict[str, dict[str, str]] = {
    "W": {"kg": "1", "m": "2", "s": "-3"},
    "J/K": {"kg": "1", "m": "2", "s": "-2", "K": "-1"},
    "W/K": {"kg": "1", "m": "2", "s": "-3", "K": "-1"},
    "degC": {"K": "1", "offset": "273.15"},
}

#: ``(name, default, unit, description)`` of every parameter, in value-reference order.
PARAMETERS: tuple[tuple[str, float, str, str], ...] = (
    ("C1", 500.0, "J/K", "heat capacity of mass 1 [J/K], > 0"),
    ("C2", 800.0, "J/K", "heat capacity of mass 2 [J/K], > 0"),
    ("G12", 2.0, "W/K", "thermal conductance between masses 1 and 2 [W/K], >= 0"),
    ("G1a", 1.0, "W/K", "thermal conductance from mass 1 to ambient [W/K], >= 0"),
    ("G2a", 0.5, "W/K", "thermal conductance from mass 2 to ambient [W/K], >= 0"),
    ("T_amb", 20.0, "degC", "ambient temperature [degC]"),
    ("T1_0", 20.0, "degC", "temperature of mass 1 at the end of initialisation [degC]"),
    ("T2_0", 20.0, "degC", "temperature of mass 2 at the end of initialisation [degC]"),
)


class _RealWithUnit(Real):
    """A pythonfmu ``Real`` that also writes the ``unit`` attribute (pythonfmu 0.7's ``Real`` has none)."""

    def __init__(self, name: str, unit: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.unit = unit

    def to_xml(self) -> Element:
        node = super().to_xml()
        node.find("Real").set("unit", self.unit)
        return node


def _python_incref() -> Callable[[Any], None] | None:
    """CPython's ``Py_IncRef`` through ctypes, None where it cannot be reached (then pythonfmu's plain behaviour)."""
    try:
        import ctypes  # noqa: PLC0415 - only for the work-around; a host without ctypes still runs the model

        incref = ctypes.pythonapi.Py_IncRef
    except (ImportError, AttributeError, OSError):
        return None
    incref.argtypes, incref.restype = [ctypes.py_object], None
    return incref


_INCREF = _python_incref()


def _to_host(method: Callable[..., Any]) -> Callable[..., Any]:
    """``method`` that, if it raises, logs the error as fmi2Fatal and adds the references pythonfmu will drop."""
    @functools.wraps(method)
    def call(self: Fmi2Slave, *args: Any) -> Any:
        try:
            return method(self, *args)
        except Exception as exc:
            self.log(f"{method.__name__}{args!r:.200}: {type(exc).__name__}: {exc}", status=Fmi2Status.fatal)
            if _INCREF is not None:
                for obj in (self, type(self), self.log_queue):
                    _INCREF(obj)
            raise
    return call


def _phi1(x: float) -> float:
    """(exp(x) - 1) / x, accurate for every finite x, 1 at x = 0."""
    return 1.0 if x == 0.0 else math.expm1(x) / x


class ThermalTwoMass(Fmi2Slave):
    """Two lumped thermal masses, coupled to each other and to ambient, each with a heater.

    Parameters
    ----------
    **kwargs
        pythonfmu's ``Fmi2Slave`` arguments (``instance_name``, ``resources``, ...), which the
        FMU's host passes on instantiation.
    """

    author = "tapmuscle"
    description = ("Two lumped thermal masses (C1, C2) coupled by G12 and to ambient by G1a, G2a; heater powers "
                   "P1, P2 [W] in, temperatures T1, T2 [degC] out; exact integration over each step")
    #: Ten minutes at 1 s communication steps; the integration is exact, so no tolerance.
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=600.0, step_size=1.0)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._initialised = False
        self._error: str | None = None
        #: set at exit of initialisation: capacities^(1/2), eigenvalues, rotation (c, s)
        self._model: tuple[float, ...] | None = None
        #: (h, exp(lam1 h), exp(lam2 h), h phi1(lam1 h), h phi2(lam2 h)) for the last step size
        self._step_cache: tuple[float, float, float, float, float] | None = None

        self.P1 = 0.0
        self.P2 = 0.0
        for name, default, _unit, _doc in PARAMETERS:
            setattr(self, name, default)
        self.T1 = self.T1_0
        self.T2 = self.T2_0

        cont, inp, out = Fmi2Variability.continuous, Fmi2Causality.input, Fmi2Causality.output
        self.register_variable(_RealWithUnit("P1", "W", causality=inp, variability=cont,
                                             description="heater power on mass 1 [W]"))
        self.register_variable(_RealWithUnit("P2", "W", causality=inp, variability=cont,
                                             description="heater power on mass 2 [W]"))
        self.register_variable(_RealWithUnit("T1", "degC", causality=out, variability=cont,
                                             description="temperature of mass 1 [degC]"))
        self.register_variable(_RealWithUnit("T2", "degC", causality=out, variability=cont,
                                             description="temperature of mass 2 [degC]"))
        for name, _default, unit, doc in PARAMETERS:
            self.register_variable(_RealWithUnit(name, unit, causality=Fmi2Causality.parameter,
                                                 variability=Fmi2Variability.fixed, description=doc,
                                                 setter=self._parameter_setter(name)))

    # ------------------------------------------------------------------ FMI
    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's model description, completed where pythonfmu 0.7 cannot express it.

        Adds ``UnitDefinitions`` (after ``CoSimulation``, as the schema orders), declares that the
        outputs have no direct feedthrough (``dependencies=""``: they are the states) and lists them
        as ``InitialUnknowns``, T1 computed from T1_0 and T2 from T2_0.
        """
        root = super().to_xml(model_options if model_options is not None else {})
        units = Element("UnitDefinitions")
        for name, exponents in UNITS.items():
            unit = Element("Unit", {"name": name})
            unit.append(Element("BaseUnit", exponents))
            units.append(unit)
        root.insert(list(root).index(root.find("CoSimulation")) + 1, units)

        index = {v.name: str(vr + 1) for vr, v in self.vars.items()}  # 1-based ScalarVariable index
        structure = root.find("ModelStructure")
        for unknown in structure.find("Outputs"):
            unknown.set("dependencies", "")
        initial = SubElement(structure, "InitialUnknowns")
        for output, start in (("T1", "T1_0"), ("T2", "T2_0")):
            SubElement(initial, "Unknown", {"index": index[output], "dependencies": index[start]})
        return root

    def _parameter_setter(self, name: str) -> Callable[[float], None]:
        def set_parameter(value: float) -> None:
            if self._initialised:
                self.log(f"{name} = {value!r} ignored: a fixed parameter cannot change after "
                         f"fmi2ExitInitializationMode (it stays {getattr(self, name)!r}); fmi2Reset first",
                         status=Fmi2Status.warning)
                return
            setattr(self, name, value)
            if name in ("T1_0", "T2_0"):  # the outputs are the states: their initial values
                setattr(self, name[:2], value)
        return set_parameter

    def enter_initialization_mode(self) -> None:
        self._initialised = False

    def exit_initialization_mode(self) -> None:
        self._initialised = True
        self._step_cache = None
        self._error = self._check_parameters()
        if self._error is not None:
            self._model = None
            self.log(f"bad parameter: {self._error}; every fmi2DoStep will be refused (fmi2Reset, set valid "
                     "parameters and initialise again)", status=Fmi2Status.error)
            return
        self._model = self._decompose()
        self.T1, self.T2 = float(self.T1_0), float(self.T2_0)

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not self._initialised:
            return self._refuse("fmi2DoStep before fmi2ExitInitializationMode", Fmi2Status.error)
        if self._model is None:
            return self._refuse(f"not initialised: bad parameter: {self._error}", Fmi2Status.error)
        h = step_size
        if not (math.isfinite(h) and h > 0.0):
            return self._refuse(f"t = {current_time:.12g} s: step size {h!r} must be finite and > 0")
        P1, P2 = self.P1, self.P2
        for name, value in (("P1", P1), ("P2", P2)):
            if not math.isfinite(value):
                return self._refuse(f"t = {current_time:.12g} s: input {name} = {value!r} W is not finite; "
                                    "the state is unchanged")
        T1, T2 = self._advance(float(P1), float(P2), float(h))
        if not (math.isfinite(T1) and math.isfinite(T2)):
            return self._refuse(f"t = {current_time:.12g} s: temperatures overflow (P1 = {P1!r} W, P2 = {P2!r} W); "
                                "the state is unchanged")
        self.T1, self.T2 = T1, T2
        return True

    # ------------------------------------------------------------------ numerics
    def _check_parameters(self) -> str | None:
        """A message naming the first bad parameter, None if all are valid."""
        for name in ("C1", "C2", "G12", "G1a", "G2a", "T_amb", "T1_0", "T2_0"):
            value = getattr(self, name)
            if not math.isfinite(value):
                return f"{name} = {value!r} is not finite"
        for name in ("C1", "C2"):
            if not getattr(self, name) > 0.0:
                return f"{name} = {getattr(self, name)!r} J/K must be > 0"
        for name in ("G12", "G1a", "G2a"):
            if getattr(self, name) < 0.0:
                return f"{name} = {getattr(self, name)!r} W/K must be >= 0"
        for name in ("T_amb", "T1_0", "T2_0"):
            if getattr(self, name) < ABSOLUTE_ZERO_DEGC:
                return f"{name} = {getattr(self, name)!r} degC is below absolute zero"
        return None

    def _decompose(self) -> tuple[float, ...]:
        """Eigen-decomposition of S = C^(-1/2) K C^(-1/2), K the (negative semi-definite) conductance matrix.

        Returns ``(sqrt(C1), sqrt(C2), lam1, lam2, c, s)`` with S = R diag(lam1, lam2) R^T and
        R = [[c, s], [-s, c]] (one Jacobi rotation: orthogonal to rounding, also for equal eigenvalues).
        """
        r1, r2 = math.sqrt(self.C1), math.sqrt(self.C2)
        a = -(self.G12 + self.G1a) / self.C1
        d = -(self.G12 + self.G2a) / self.C2
        b = self.G12 / (r1 * r2)
        if b == 0.0:
            return r1, r2, a, d, 1.0, 0.0
        theta = (d - a) / (2.0 * b)
        t = math.copysign(1.0, theta) / (abs(theta) + math.hypot(theta, 1.0))
        c = 1.0 / math.hypot(t, 1.0)
        return r1, r2, a - t * b, d + t * b, c, t * c

    def _advance(self, P1: float, P2: float, h: float) -> tuple[float, float]:
        """(T1, T2) after ``h`` seconds at constant P1, P2, exactly (up to rounding)."""
        r1, r2, lam1, lam2, c, s = self._model
        cache = self._step_cache
        if cache is None or cache[0] != h:
            cache = self._step_cache = (h, math.exp(lam1 * h), math.exp(lam2 * h),
                                        h * _phi1(lam1 * h), h * _phi1(lam2 * h))
        _, e1, e2, f1, f2 = cache
        t_amb = self.T_amb
        # y = C^(1/2) (T - T_amb), u = C^(-1/2) P; modal z = R^T y, w = R^T u; z(h) = e z + f w
        y1, y2 = r1 * (self.T1 - t_amb), r2 * (self.T2 - t_amb)
        u1, u2 = P1 / r1, P2 / r2
        z1 = e1 * (c * y1 - s * y2) + f1 * (c * u1 - s * u2)
        z2 = e2 * (s * y1 + c * y2) + f2 * (s * u1 + c * u2)
        return t_amb + (c * z1 + s * z2) / r1, t_amb + (-s * z1 + c * z2) / r2

    def _refuse(self, message: str, status: Fmi2Status = Fmi2Status.discard) -> bool:
        """Log ``message`` and report the step as not done (pythonfmu returns fmi2Discard)."""
        self.log(message, status=status)
        return False


for _name in ("setup_experiment", "enter_initialization_mode", "exit_initialization_mode", "do_step", "terminate",
              "get_real", "set_real", "get_integer", "set_integer", "get_boolean", "set_boolean", "get_string",
              "set_string", "_get_fmu_state", "_set_fmu_state"):
    setattr(ThermalTwoMass, _name, _to_host(getattr(ThermalTwoMass, _name)))
del _name
