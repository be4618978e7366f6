"""A pythonfmu slave that never crashes its host and never emits NaN.

pythonfmu turns an exception escaping ``do_step`` into fmi2Fatal; a host may then abandon the whole
simulation. :class:`SafeSlave` runs the slave's step inside a guard: any problem (bad input, bad step
size, bad parameter, a numerical failure) is logged with a message naming the offending variable and
value, the outputs keep their last valid values, and ``do_step`` returns False, which pythonfmu reports
as fmi2Discard: a bad input or step size is logged as a discard (the host can fix it and step again),
a failure no retry can fix (parameters rejected at initialisation, an internal error) as an error,
which the FMU's loader library (build_scripts.native_host) returns instead of pythonfmu's status.

Parameters are kept in one table (``self._par``) registered from a list of
``(name, start, unit, description[, min, max])``. Units, ranges and nominal values of every variable
are collected in :attr:`SafeSlave.variable_meta`; the build (``build_scripts``) writes them into
modelDescription.xml, which pythonfmu cannot do itself. Full dynamic state is saved and restored through
:meth:`SafeSlave.numerics_state` / :meth:`SafeSlave.restore_numerics_state`, so FMI
get/set/serialize FMU state restores everything, not just the registered variables.

Time: the FMU's clock starts at the start time of ``fmi2SetupExperiment`` (``tStart``; 0 without
that call) and advances with every completed step. A step whose ``currentCommunicationPoint`` is not
the FMU's time (a gap, or a step back, beyond :func:`time_tolerance`) is refused with fmi2Error and a
message naming both times: a slave's numerics (the plant's clock, the controller's sampling grid)
would silently run on another time than the host's. Going back is what FMU states are for: the time
is part of the state, so after ``fmi2SetFMUstate`` the FMU's time is the restored one. A step a master
computed as the difference of two times is integrated as the step it meant (:func:`intended_step`).

Exceptions that must reach the host (a value reference of the wrong type in ``fmi2GetReal`` and the
like, a foreign FMU state) go through :meth:`SafeSlave._keep_references`. pythonfmu 0.7's C++ layer answers
an exception with fmi2Fatal, and on the way releases its references to the slave, its class and its
log queue (``cleanPyObject`` in ``handle_py_exception``) without forgetting them; ``fmi2FreeInstance``
releases them a second time, which frees live objects and crashes the host later, in the garbage
collector (measured: a segfault within 30 instantiate / bad call / free cycles, and in the test suite).
``_keep_references`` adds the one reference per object that the C++ layer will take back, so freeing the
instance after an fmi2Fatal is safe and nothing leaks (tests/test_plant_fmu.py).
"""

from __future__ import annotations

import ctypes
import functools
import sys
import json
import math
import os
import traceback
from operator import itemgetter
from typing import Any, Callable, Iterable

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Status

__all__ = ["SafeSlave", "SlaveInputError", "VariableMeta"]

_BAD_STATE = "tapmuscle: bad FMU state"

#: The keys of an FMU state (:meth:`SafeSlave._snapshot`), and those of the mode it was saved in and its
#: run's start time, which a state of an FMU built before they were kept lacks (its numerics tell
#: whether it was initialised; the restoring instance's start time stands in).
_STATE_KEYS = frozenset({"variables", "numerics", "failed", "time"})
_STATE_MODE_KEYS = frozenset({"initialised", "terminated", "start"})


def _saved_initialised(state: dict[str, Any]) -> bool:
    """Whether the FMU state ``state`` was saved after fmi2ExitInitializationMode."""
    return bool(state.get("initialised", state["numerics"] is not None or state["failed"]))

#: A Ctrl-C in a Python host lands in whatever Python code runs, most often a slave's step. It cannot
#: pass through FMI as an exception, and reaching pythonfmu's C++ layer it would become fmi2Fatal, after
#: which freeing the instance crashes the host: the slave answers fmi2Error with this instead.
_INTERRUPTED = ("interrupted {where} (KeyboardInterrupt: Ctrl-C in the host process); the state may be "
                "half updated: restore an FMU state saved before, or instantiate again")

#: Shortest communication step that is integrated [s]. A master whose accumulated time leaves a
#: rounding remainder asks for a last step of 1e-14 .. 2e-12 s: such a step is accepted with fmi2OK
#: and changes nothing (the outputs hold), since no physics happens in it.
MIN_STEP_S = 1e-9

#: An input this far beyond a bound of its range (relative, absolute below 1) is taken as the bound: a
#: host that interpolates a signal held at the bound computes it with a rounding error (fmpy's
#: ``simulate_fmu`` gave 500.00000000000006 for a load held at 500 N, and ended the run early at the
#: fmi2Discard). Far above a double's rounding, far below any physical difference.
BOUND_ROUNDING = 1e-9

#: A step's ``currentCommunicationPoint`` may differ from the FMU's time (the start time, or the end of
#: the last step) by :func:`time_tolerance`: a master that computes its time as ``tStart + n h`` rather
#: than by summing the steps differs by a few units in the last place, and an interval shorter than a
#: step that integrates nothing is no gap. The same tolerance as the controller's sampling grid.
TIME_TOLERANCE = 1e-9

#: The most :func:`time_tolerance` allows, as a fraction of the step (or the sampling period): at a
#: start time of 1e9 s (a Unix time) ``TIME_TOLERANCE * |time|`` alone would be a whole second, and a
#: gap of several samples, or a half step taken for a sample time, would pass.
TIME_TOLERANCE_OF_STEP = 0.25


def time_tolerance(time_s: float, step_s: float) -> float:
    """How far [s] a master's time may be from the FMU's before it is a gap or a step back.

    ``TIME_TOLERANCE * max(step_s, |time_s|)``, at most ``TIME_TOLERANCE_OF_STEP * step_s``, at least
    :data:`MIN_STEP_S` and 16 units in the last place of ``time_s`` (the rounding of a time as large).

    Parameters
    ----------
    time_s : float
        The FMU's time [s].
    step_s : float
        The communication step, or the controller's sampling period [s], > 0.
    """
    relative = min(TIME_TOLERANCE * max(step_s, abs(time_s)), TIME_TOLERANCE_OF_STEP * step_s)
    return max(MIN_STEP_S, 16.0 * math.ulp(time_s), relative)


def intended_step(t_s: float, h_s: float) -> float:
    """The communication step ``h_s`` [s] a master meant, as the slave's numerics integrate it.

    A master that computes its times as ``tStart + n h`` and each step as the difference of two of them
    (fmpy's ``simulate_fmu``) asks for 0.1 s as 0.10000000000000003 s at t = 0.2 s: a step a few units
    in the last place of ``t_s`` off a whole number of nanoseconds. Taken as it comes, the plant's
    adaptive sub-steps then differ in their last bits from a run with the steps themselves and drift
    apart at the solver's tolerance (6e-4 mm of l with noise-free sensors). Such a step is integrated as
    that whole number of nanoseconds, so a run gives the same bits in any master that means the same
    step; any other step (Ts/3, a rounding remainder) is integrated as given. The FMU's clock keeps the
    master's ``t + h`` either way.

    Parameters
    ----------
    t_s : float
        The step's start, ``currentCommunicationPoint`` [s].
    h_s : float
        ``communicationStepSize`` [s], > 0.

    Returns
    -------
    float
        ``round(h_s * 1e9) / 1e9`` where that lies within four units in the last place of ``t_s + h_s``
        of ``h_s`` (and those are below a quarter of a nanosecond, so the nearest is unambiguous), else
        ``h_s``.
    """
    ns = round(h_s * 1e9)
    meant = ns / 1e9
    slack = 4.0 * math.ulp(abs(t_s) + h_s)
    if ns > 0 and slack < 0.25e-9 and abs(h_s - meant) <= slack:
        return meant
    return h_s


#: Per variable: ``unit`` (a key of fmi_slave.units.UNITS or ""), ``min``, ``max``, ``nominal`` (None =
#: not declared), ``depends_on`` (outputs only: names of inputs with direct feedthrough; () = none).
VariableMeta = dict[str, Any]


def _plain(obj: Any) -> Any:
    """``obj`` with numpy arrays/scalars replaced by lists/Python numbers, recursively."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    tolist = getattr(obj, "tolist", None)  # numpy array or scalar, without importing numpy here
    return tolist() if callable(tolist) else obj


class SlaveInputError(ValueError):
    """A bad input, parameter or step size; the message names it."""


_incref = ctypes.pythonapi.Py_IncRef
_incref.argtypes, _incref.restype = [ctypes.py_object], None


def _to_host(method: Callable) -> Callable:
    """``method`` (called by pythonfmu's C++ layer) with :meth:`SafeSlave._keep_references` on any exception."""
    @functools.wraps(method)
    def call(self, *args):
        try:
            return method(self, *args)
        except BaseException:
            self._keep_references()
            raise
    return call


def _drop_repeated_path(resources: str | None) -> None:
    """pythonfmu inserts the FMU's resources folder at the front of ``sys.path`` at every
    instantiation, so a host that instantiates the FMU N times carries N copies (a long sweep in one
    process: thousands). Keep the first only; the module is imported already."""
    if not resources:
        return
    seen = [i for i, p in enumerate(sys.path) if p == resources]
    for i in reversed(seen[1:]):
        del sys.path[i]


#: The project's packages an FMU built by a tapmuscle of 2 December 2026 or earlier ships at the top of
#: its resources folder and imports by these plain names (later builds keep them in a private package).
PLAIN_PACKAGES = ("fmi_slave", "fmu_plant", "fmu_controller")


def check_own_code(resources: str | None) -> None:
    """Refuse to run an FMU on code other than its own.

    An FMU built before its code was kept in a private package imports ``fmi_slave``, ``fmu_plant``
    and ``fmu_controller`` by those names, and in a process that imported another tapmuscle (or
    another such FMU) first it runs that one's modules: its parameters then land on other variables
    (wrong numbers without a word), or it fails on a call the other code does not know.

    Raises
    ------
    ValueError
        A package the FMU ships in ``resources`` that this process loaded from elsewhere, naming both.
    """
    if not resources:
        return
    for name in PLAIN_PACKAGES:
        own = os.path.join(resources, name, "__init__.py")
        loaded = getattr(sys.modules.get(name), "__file__", None)
        if loaded and os.path.isfile(own) and os.path.realpath(loaded) != os.path.realpath(own):
            raise ValueError(f"this FMU's own {name} ({os.path.dirname(own)}) is not the one this process runs "
                             f"({os.path.dirname(loaded)}, imported before the FMU): an FMU built by an earlier "
                             "tapmuscle would run another version's code, whose variables differ from its "
                             "modelDescription's; build it again with this tapmuscle (tapmuscle build), or run it in "
                             "a process that has imported no other tapmuscle")


class SafeSlave(Fmi2Slave):
    """Base of the project's FMU slaves (see module docstring)."""

    #: FMI 2.0's status categories (pythonfmu's) and ``logEvents``: the run's set-up, a slave's changes of
    #: mode and a summary at fmi2Terminate, logged with status OK, so a host sees them with logging on
    #: (its fmi2SetDebugLogging may list the categories it wants; the FMU's loader library filters).
    log_categories = {**Fmi2Slave.log_categories,
                      "logEvents": "What the run is set up with (the parameters set away from their start values), "
                                   "the FMU's changes of mode during it, and a summary at fmi2Terminate"}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        _drop_repeated_path(kwargs.get("resources"))
        check_own_code(kwargs.get("resources"))
        #: pythonfmu's C++ layer drops references when an exception reaches it (:meth:`_keep_references`);
        #: the project's own export library (build_scripts/fmi2_python_export.c) keeps them
        self._export_keeps_references = kwargs.get("fmi_export") == "tapmuscle"
        self._par: dict[str, float] = {}
        self._int_par: dict[str, int] = {}
        #: every parameter's start value, by name (what the set-up event compares with)
        self._start_values: dict[str, float | int] = {}
        self._failed = False
        #: the start time of fmi2SetupExperiment [s] and the FMU's time: the start time, then the end of
        #: the last completed step (module docstring)
        self._start_s = 0.0
        self._time_s = 0.0
        #: FMI 2.0's co-simulation states: before initialisation (neither flag), step mode (initialised)
        #: and terminated. Fixed parameters are settable until fmi2ExitInitializationMode, steps until
        #: fmi2Terminate; each fmi2Reset makes a new slave object (pythonfmu), not initialised.
        self._initialised = False
        self._terminated = False
        #: a step-mode FMU state restored before initialisation: the initialisation calls a host may still
        #: make before its first step (FMI 2.0's state machine asks for them) keep the restored run
        self._restored_before_init = False
        #: between fmi2EnterInitializationMode and fmi2ExitInitializationMode: the outputs computed at
        #: initialisation (``initial = calculated``) are computed from the parameters when read
        self._in_init_mode = False
        self.variable_meta: dict[str, VariableMeta] = {}
        #: Real variables whose value is the instance attribute of the same name (inputs, outputs without
        #: a getter): read and written through ``self.__dict__`` by :meth:`get_real` / :meth:`set_real`.
        self._attribute_reals: set[str] = set()
        #: ``tuple(vrs) -> reader(self.__dict__)`` / ``-> names`` for vr lists of attribute Reals only
        self._readers: dict[tuple[int, ...], Callable[[dict], list[float]]] = {}
        self._writers: dict[tuple[int, ...], tuple[str, ...]] = {}
        #: value references of the outputs (any type): settable only before initialisation, and then only
        #: those with an exact start value
        self._outputs: set[int] = set()
        #: value references of the outputs computed at initialisation (``initial = calculated``)
        self._calculated: set[int] = set()

    # ------------------------------------------------------------------ registration
    def _meta(self, name: str, unit: str = "", lo: float | None = None, hi: float | None = None,
              nominal: float | None = None, **extra: Any) -> None:
        self.variable_meta[name] = {"unit": unit, "min": lo, "max": hi, "nominal": nominal, **extra}

    def add_real_parameters(self, table: Iterable[tuple]) -> None:
        """Register fixed Real parameters ``(name, start, unit, description[, min, max])``."""
        for name, start, unit, description, *bounds in table:
            lo, hi = (bounds + [None, None])[:2]
            self._par[name] = self._start_values[name] = float(start)
            self.register_variable(Real(
                name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                description=description,
                getter=lambda n=name: self._par[n],
                setter=lambda v, n=name: self._set_parameter(self._par, n, float(v))), nested=False)
            self._meta(name, unit, lo, hi)

    def add_integer_parameter(self, name: str, start: int, description: str, *, lo: int | None = None,
                              hi: int | None = None) -> None:
        """Register a fixed Integer parameter (a choice is an Integer whose description lists the codes:
        libcosim cannot set FMI Enumerations)."""
        self._int_par[name] = self._start_values[name] = int(start)
        self.register_variable(Integer(
            name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed, description=description,
            getter=lambda: self._int_par[name],
            setter=lambda v: self._set_parameter(self._int_par, name, int(v))), nested=False)
        self._meta(name, "", lo, hi)

    def _set_parameter(self, table: dict, name: str, value: float | int) -> None:
        """A fixed parameter's setter: after fmi2ExitInitializationMode the dynamics would ignore a new
        value, so it is refused (logged as an error, which the loader returns as fmi2Error)."""
        if self._initialised:
            self.log(f"parameter {name} is fixed: set it before fmi2ExitInitializationMode (the value "
                     f"{value!r} is ignored, {table[name]!r} stays)", status=Fmi2Status.error)
            return
        table[name] = value

    def _check_parameter_ranges(self) -> None:
        """Every parameter within its declared min..max (modelDescription.xml), or SlaveInputError."""
        for table in (self._par, self._int_par):
            for name, value in table.items():
                meta = self.variable_meta.get(name, {})
                lo, hi = meta.get("min"), meta.get("max")
                if value != value:  # NaN passes every comparison below
                    raise SlaveInputError(f"parameter {name} = {value!r} is not finite")
                if (lo is not None and value < lo) or (hi is not None and value > hi):
                    span = f"{'-inf' if lo is None else f'{lo:g}'}..{'inf' if hi is None else f'{hi:g}'}"
                    var = next((v for v in self.vars.values() if v.name == name), None)
                    desc = var.description if var is not None and var.description else ""
                    # one host log line: the description shortened (the name is what identifies it)
                    about = f" ({desc[:100]}{'...' if len(desc) > 100 else ''})" if desc else ""
                    raise SlaveInputError(f"parameter {name} = {value!r} is outside its declared range {span}{about}")

    def _attribute_accessors(self, name: str, start: Any, kind: type = Real) -> dict[str, Callable]:
        """Getter and setter of the instance attribute ``name`` (set to ``start``). pythonfmu's defaults
        would use the part of a dotted name after the last dot (``theta.a1`` -> ``a1``)."""
        setattr(self, name, start)
        if kind is Real:
            self._attribute_reals.add(name)
        return {"getter": lambda: getattr(self, name), "setter": lambda v: setattr(self, name, v)}

    def add_input(self, name: str, start: float, unit: str, description: str, *, lo: float, hi: float,
                  nominal: float | None = None) -> None:
        """Register a continuous Real input (attribute ``name``, checked against ``lo..hi`` by
        :meth:`finite` in the step)."""
        self.register_variable(Real(name, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                                    start=float(start), description=description,
                                    **self._attribute_accessors(name, float(start))), nested=False)
        self._meta(name, unit, lo, hi, nominal)

    def add_output(self, name: str, start: float | bool | int, unit: str, description: str, *,
                   lo: float | None = None, hi: float | None = None, nominal: float | None = None,
                   depends_on: tuple[str, ...] = (), kind: type = Real,
                   variability: Fmi2Variability = Fmi2Variability.continuous, getter=None,
                   calculated_from: tuple[str, ...] | None = None) -> None:
        """Register an output (attribute ``name`` unless a ``getter`` is given), defined before the first
        step (which also gives hosts a correct InitialUnknowns list, PythonFMU#193). ``depends_on``
        lists the inputs the output depends on directly at a communication point (none for ours, so
        hosts see no algebraic loop, PythonFMU#258).

        With ``calculated_from`` (the parameters its value at initialisation is computed from) the
        output is ``initial = calculated``: no start value in modelDescription.xml (``start`` is only
        the value before initialisation), an InitialUnknowns entry with those dependencies, and a
        host may not set it. Without, its ``start`` is exact: the value it has until the first step
        computes it, which a host may set before initialisation (FMI 2.0)."""
        accessors = {"getter": getter} if getter is not None else self._attribute_accessors(name, start, kind)
        calculated = calculated_from is not None
        self.register_variable(kind(name, causality=Fmi2Causality.output, variability=variability,
                                    initial=Fmi2Initial.calculated if calculated else Fmi2Initial.exact,
                                    start=None if calculated else start, description=description, **accessors),
                               nested=False)
        self._meta(name, unit, lo, hi, nominal, depends_on=tuple(depends_on),
                   **({"initial_depends_on": tuple(calculated_from)} if calculated else {}))

    # ------------------------------------------------------------------ Real I/O (hot path)
    #: ``({vr: getter}, {vr: setter}, {vr: attribute name})`` of the Real variables; None: rebuild.
    #: At most this many value-reference lists are compiled (a host that asks for ever new lists gets
    #: the table path, not a growing cache).
    _MAX_COMPILED = 64
    _real_io: tuple[dict[int, Any], dict[int, Any], dict[int, str]] | None = None

    def register_variable(self, var: Any, nested: bool = True) -> None:
        super().register_variable(var, nested)
        self._real_io = None
        self._readers, self._writers = {}, {}
        if var.causality == Fmi2Causality.output:
            self._outputs.add(var.value_reference)
            if var.initial == Fmi2Initial.calculated:
                self._calculated.add(var.value_reference)

    def _real_tables(self) -> tuple[dict[int, Any], dict[int, Any], dict[int, str]]:
        reals = [(vr, var) for vr, var in self.vars.items() if isinstance(var, Real)]
        self._real_io = ({vr: var.getter for vr, var in reals}, {vr: var.setter for vr, var in reals},
                         {vr: var.name for vr, var in reals if var.name in self._attribute_reals})
        return self._real_io

    def get_real(self, vrs: list[int]) -> list[float]:
        """pythonfmu's ``get_real``: the same values and TypeError, faster.

        A master asks for the same value references every step (benchmarks/fmu_cosim.py). The first call
        with a list of attribute-backed Reals (inputs, outputs without a getter) compiles it into one
        ``itemgetter`` on ``self.__dict__``; later calls with that list cost one dictionary lookup.
        Other lists go through a value-reference table (no ABC ``isinstance`` per value as pythonfmu's).
        """
        try:  # inline rather than @_to_host: one Python frame less on the hot path
            if self._in_init_mode:
                self.refresh_calculated()
            reader = self._readers.get(tuple(vrs))
            if reader is not None:
                return reader(self.__dict__)
            return self._read_reals(vrs)
        except BaseException as exc:
            getters = (self._real_io or self._real_tables())[0]
            missing = [vr for vr in vrs if vr not in getters]
            if isinstance(exc, KeyError) and missing:  # not a KeyError from inside a getter
                return self._wrong_reference(missing[0], Real, vrs, 0.0)
            self._keep_references()
            raise

    def _read_reals(self, vrs: list[int]) -> list[float]:
        getters, _, attributes = self._real_io or self._real_tables()
        values = [float(getters[vr]()) for vr in vrs]  # KeyError: not a Real (get_real says so)
        if vrs and len(self._readers) < self._MAX_COMPILED and all(vr in attributes for vr in vrs):
            if len(vrs) == 1:
                get_one = itemgetter(attributes[vrs[0]])
                self._readers[tuple(vrs)] = lambda d: [float(get_one(d))]
            else:
                get_all = itemgetter(*(attributes[vr] for vr in vrs))
                self._readers[tuple(vrs)] = lambda d: list(map(float, get_all(d)))
        return values

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        """pythonfmu's ``set_real`` (see :meth:`get_real`): attribute-backed Reals are written into
        ``self.__dict__`` in one update, as pythonfmu's default setter (``setattr``) would. Refused
        (logged error, nothing written) after fmi2Terminate, and for an output after initialisation."""
        try:
            names = self._writers.get(tuple(vrs))
            if names is not None and not self._terminated:
                self.__dict__.update(zip(names, values))
                return
            _, setters, attributes = self._real_io or self._real_tables()
            missing = [vr for vr in vrs if vr not in setters]
            if missing:
                self._wrong_reference(missing[0], Real, vrs, None)
                return
            if self._refused_set("fmi2SetReal", vrs) or self._refused_output_start(vrs, values):
                return
            for vr, value in zip(vrs, values):
                setters[vr](value)
            # outputs are never compiled: the compiled path does not check the mode
            if (vrs and len(self._writers) < self._MAX_COMPILED and all(vr in attributes for vr in vrs)
                    and not any(vr in self._outputs for vr in vrs)):
                self._writers[tuple(vrs)] = tuple(attributes[vr] for vr in vrs)
        except BaseException:
            self._keep_references()
            raise

    def _refused_set(self, call: str, vrs: list[int]) -> bool:
        """True (and logged as an error) if setting ``vrs`` now is not allowed: after fmi2Terminate, an
        output after fmi2ExitInitializationMode (FMI 2.0: then only inputs and tunable parameters), or
        an output computed at initialisation (``initial = calculated``) before it."""
        if self._terminated:
            self._after_terminate(call)
            return True
        if self._initialised:
            out = [vr for vr in vrs if vr in self._outputs]
            if out:
                self.log(f"{call}: {self.vars[out[0]].name} is an output: after initialisation only inputs can be "
                         "set; nothing was written", status=Fmi2Status.error)
                return True
        calculated = [vr for vr in vrs if vr in self._calculated]
        if calculated:
            self.log(f"{call}: output {self.vars[calculated[0]].name} is computed at initialisation (initial = "
                     "calculated): before it, a host may set only inputs, parameters and the outputs' exact start "
                     "values; nothing was written", status=Fmi2Status.error)
            return True
        return False

    def _refused_output_start(self, vrs: list[int], values: list[float]) -> bool:
        """True (and logged as an error, nothing written) if an output's value set before
        initialisation (FMI 2.0 allows it for ``initial = exact``: its start value) is not finite or
        outside its declared range: an output is never NaN, and never outside what it declares."""
        for vr, value in zip(vrs, values):
            if vr not in self._outputs:
                continue
            name = self.vars[vr].name
            meta = self.variable_meta.get(name, {})
            lo = -math.inf if meta.get("min") is None else meta["min"]
            hi = math.inf if meta.get("max") is None else meta["max"]
            if not (math.isfinite(value) and lo <= value <= hi):
                bounds = f"within {lo:g}..{hi:g}" if (lo, hi) != (-math.inf, math.inf) else "finite"
                self.log(f"fmi2SetReal: output {name} = {value!r} as its start value: it must be {bounds}; nothing was "
                         "written", status=Fmi2Status.error)
                return True
        return False

    def _wrong_reference(self, vr: int, kind: type, vrs: list[int], zero: Any) -> list | None:
        """A value reference that is not a ``kind`` variable of this FMU: an error, logged (the loader
        returns fmi2Error; the instance is fine, so not pythonfmu's fmi2Fatal); nothing is written,
        a getter returns ``zero`` for every value."""
        self.log(f"value reference {vr} is not a variable of type {kind.__name__} of this FMU; nothing was "
                 f"{'read' if zero is not None else 'written'}", status=Fmi2Status.error)
        return None if zero is None else [zero] * len(vrs)

    def _typed_access(kind: type, getter: bool, zero: Any) -> Callable:  # noqa: N805 - a class-body helper
        method = getattr(Fmi2Slave, f"{'get' if getter else 'set'}_{kind.__name__.lower()}")
        guarded = _to_host(method)

        def call(self, vrs, *values):
            bad = [vr for vr in vrs if not isinstance(self.vars.get(vr), kind)]
            if bad:
                return self._wrong_reference(bad[0], kind, vrs, zero if getter else None)
            if not getter and self._refused_set(f"fmi2Set{kind.__name__}", vrs):
                return None
            return guarded(self, vrs, *values)
        return call

    get_integer = _typed_access(Integer, True, 0)
    set_integer = _typed_access(Integer, False, 0)
    get_boolean = _typed_access(Boolean, True, False)
    set_boolean = _typed_access(Boolean, False, False)
    get_string = _typed_access(String, True, "")
    set_string = _typed_access(String, False, "")
    del _typed_access

    @_to_host
    def setup_experiment(self, start_time: float, stop_time: float | None, tolerance: float | None) -> None:
        """Keep the start time: the FMU's clock starts there at fmi2ExitInitializationMode (the stop time
        and tolerance do not apply to fixed-step numerics; after fmi2Reset the next initialisation takes
        the new one). A non-finite start time is an error, logged; the start time stays."""
        if self._terminated:
            self._after_terminate("fmi2SetupExperiment")
            return
        if self._restored_before_init:
            return  # the restored state's start time stands
        if self._initialised:
            self._after_initialisation("fmi2SetupExperiment")
            return
        try:
            t0 = float(start_time)
        except (TypeError, ValueError):
            t0 = math.nan
        if not math.isfinite(t0):
            self.log(f"fmi2SetupExperiment: startTime = {start_time!r} is not finite; the start time stays "
                     f"{self._start_s!r} s", status=Fmi2Status.error)
            return
        self._start_s = t0

    @_to_host
    def enter_initialization_mode(self) -> None:
        # fmi2Reset makes a new slave object (pythonfmu), so a terminated one is only ever reused by
        # mistake: its outputs would start from the last run's values
        if self._terminated:
            self._after_terminate("fmi2EnterInitializationMode")
            return
        if self._restored_before_init:
            return
        if self._initialised:
            self._after_initialisation("fmi2EnterInitializationMode")
            return
        self._in_init_mode = True
        Fmi2Slave.enter_initialization_mode(self)

    def _after_terminate(self, call: str) -> None:
        """Log the refusal of ``call`` on a terminated instance (FMI 2.0 allows only the getters,
        fmi2Reset and fmi2FreeInstance there); the loader returns fmi2Error."""
        self.log(f"{call} after fmi2Terminate: call fmi2Reset first (after fmi2Terminate FMI 2.0 allows only "
                 "the getters, fmi2Reset and fmi2FreeInstance); nothing was done", status=Fmi2Status.error)

    def _after_initialisation(self, call: str) -> None:
        """Log the refusal of ``call``, which FMI 2.0 allows only before fmi2ExitInitializationMode, on an
        initialised instance (initialising it again would start the next run from this one's outputs);
        the loader returns fmi2Error."""
        self.log(f"{call} after fmi2ExitInitializationMode: the instance is initialised (step mode); to run "
                 "again from the start call fmi2Reset first (or restore an FMU state saved at the start); "
                 "nothing was done", status=Fmi2Status.error)

    @_to_host
    def terminate(self) -> None:
        if not self._initialised and not self._terminated:
            # FMI 2.0 allows fmi2Terminate only once the slave steps; hosts call it in their clean-up of an
            # instance they only inspected (fmpy raises on an error there), so a warning, and the
            # instance, which never ran, is not marked terminated: it can still be initialised
            self.log("fmi2Terminate before fmi2ExitInitializationMode: the instance has not been initialised; "
                     "nothing was done (fmi2FreeInstance ends it)", status=Fmi2Status.warning)
            return
        if self._initialised and not self._failed and not self._terminated:
            self._summary_event(f"fmi2Terminate at t = {self._time_s:.12g} s", self.run_summary)
        self._terminated = True
        Fmi2Slave.terminate(self)

    # ------------------------------------------------------------------ events (category logEvents)
    def event(self, message: str) -> None:
        """Log ``message`` in the category ``logEvents`` with status OK (passed on to a host with logging on)."""
        self.log(message, status=Fmi2Status.ok, category="logEvents")

    def _summary_event(self, prefix: str, summary: Callable[[], str]) -> None:
        """The event ``prefix: summary()``; a summary that fails says so (it is not worth failing the call)."""
        try:
            text = summary()
        except Exception as exc:  # noqa: BLE001 - never raised into the host
            text = f"(no summary: {type(exc).__name__}: {exc})"
        self.event(f"{prefix}: {text}")

    def changed_parameters(self) -> str:
        """``name = value, ...`` of the parameters set away from their start values ("none" if none is)."""
        changed = [f"{name} = {value!r}" for table in (self._par, self._int_par) for name, value in table.items()
                   if value != self._start_values[name]]
        return ", ".join(changed) or "none"

    def setup_summary(self) -> str:
        """What the run is set up with, logged as an event once the numerics are built."""
        return f"parameters away from their start values: {self.changed_parameters()}"

    def run_summary(self) -> str:
        """What the run did, logged as an event at fmi2Terminate (after an initialisation that succeeded)."""
        return f"{self._time_s - self._start_s:.12g} s from t = {self._start_s:.12g} s"

    def _keep_references(self) -> None:
        """Add the references pythonfmu's C++ layer drops once too often when an exception reaches it
        (module docstring): the instance, its class and its log queue. Not under the project's own
        export library, which keeps them."""
        if self._export_keeps_references:
            return
        for obj in (self, type(self), self.log_queue):
            _incref(obj)

    # ------------------------------------------------------------------ guards
    @staticmethod
    def finite(name: str, value: float, lo: float = -math.inf, hi: float = math.inf) -> float:
        """``value`` as float, or :class:`SlaveInputError` naming ``name`` if not finite or outside lo..hi
        (within :data:`BOUND_ROUNDING` of a bound, relative, or absolute below 1: that bound)."""
        # fast path (every input, every step): NaN fails the comparison, +-inf fails v - v == 0
        if value.__class__ is float and lo <= value <= hi and value - value == 0.0:
            return value
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise SlaveInputError(f"{name} = {value!r} is not a number") from None
        if not math.isfinite(v):
            raise SlaveInputError(f"{name} = {v!r} is not finite")
        if not lo <= v <= hi:
            # a host's interpolation of a signal held at a bound lands an ulp or so beyond it
            # (fmpy: 500.00000000000006 for 500): taken as the bound, not refused mid-run
            if lo - BOUND_ROUNDING * max(1.0, abs(lo)) <= v < lo:
                return lo
            if hi < v <= hi + BOUND_ROUNDING * max(1.0, abs(hi)):
                return hi
            raise SlaveInputError(f"{name} = {v!r} is outside {lo:g}..{hi:g}")
        return v

    def fail(self, message: str, status: Fmi2Status = Fmi2Status.discard) -> bool:
        """Log ``message`` with ``status`` and report the step as not done (pythonfmu: fmi2Discard).

        The FMU's loader library returns the worst status logged during a call (docs/fmu.md), so a
        host sees fmi2Discard for a step it may retry with other inputs and fmi2Error (``status``)
        for one that no retry can fix."""
        self.log(message, status=status)
        return False

    def exit_initialization_mode(self) -> None:
        in_init_mode, self._in_init_mode = self._in_init_mode, False
        if self._terminated:
            self._after_terminate("fmi2ExitInitializationMode")
            return
        if self._restored_before_init:
            self._restored_before_init = False  # the model is the restored one: nothing to build
            return
        if self._initialised:
            self._after_initialisation("fmi2ExitInitializationMode")
            return
        if not in_init_mode:
            # FMI 2.0's order: the parameters a host sets between the two calls are the run's
            self.log("fmi2ExitInitializationMode before fmi2EnterInitializationMode: call fmi2SetupExperiment and "
                     "fmi2EnterInitializationMode first; nothing was done", status=Fmi2Status.error)
            return
        self._initialised = True
        self._time_s = self._start_s
        try:
            self._check_parameter_ranges()
            self.initialize_numerics()
            self._failed = False
        except Exception as exc:  # noqa: BLE001 - reported to the host, never raised into it
            # A warning here and fmi2Error from every fmi2DoStep: libcosim terminates the process on an
            # error during its initialisation phase, but stops cleanly on an error from a step.
            self._failed = True
            self.log(f"initialisation failed: {exc}; every fmi2DoStep will return fmi2Error (fmi2Reset or "
                     "instantiate again, and set valid parameters)", status=Fmi2Status.warning)
        except KeyboardInterrupt:
            self._failed = True
            self.log(_INTERRUPTED.format(where="during initialisation"), status=Fmi2Status.error)
        else:
            self._summary_event(f"initialised at t = {self._start_s:.12g} s", self.setup_summary)

    def do_step(self, current_time: float, step_size: float) -> bool:
        try:
            if self._failed:
                return self.fail("the FMU was not initialised (see the initialisation's message); fmi2Reset or "
                                 "instantiate again, and set valid parameters", Fmi2Status.error)
            self._restored_before_init = False
            if self._terminated or not self._initialised:
                return self.fail(f"fmi2DoStep {'after fmi2Terminate' if self._terminated else 'before fmi2ExitInitializationMode'}"
                                 "; instantiate (or fmi2Reset) and initialise again", Fmi2Status.error)
            h = self.finite("step size", step_size, 0.0, 3600.0)
            if h == 0.0:
                raise SlaveInputError(f"step size = {step_size!r} must be > 0")
            t = float(current_time)
            if not abs(t - self._time_s) <= time_tolerance(self._time_s, h):
                return self.fail(self._time_mismatch(t), Fmi2Status.error)
            if h >= MIN_STEP_S:
                self.step_numerics(t, intended_step(t, h))
            self._time_s = t + h
            return True
        except SlaveInputError as exc:
            return self.fail(f"t = {current_time:.12g} s: {exc}; outputs keep their last values")
        except FloatingPointError as exc:  # a documented breakdown of the numerics (extreme parameters): no bug
            return self.fail(f"t = {current_time:.12g} s: {exc}; the state and outputs are those of the step's start",
                             Fmi2Status.error)
        except OverflowError as exc:  # Python float arithmetic past 1.8e308: parameters far out, not a bug
            return self.fail(f"t = {current_time:.12g} s: numerical overflow ({exc}): {self.overflow_hint()}; the "
                             "outputs keep their last values; restore an FMU state or reset", Fmi2Status.error)
        except Exception as exc:  # noqa: BLE001
            return self.fail(f"t = {current_time:.12g} s: internal error {type(exc).__name__}: {exc}\n"
                             f"{traceback.format_exc(limit=3)}", Fmi2Status.error)
        except KeyboardInterrupt:
            return self.fail(_INTERRUPTED.format(where=f"in the step from t = {current_time:.12g} s"), Fmi2Status.error)

    def _time_mismatch(self, t: float) -> str:
        """The message for a step at ``t`` that does not start at the FMU's time."""
        now = self._time_s
        what = f"a gap of {t - now:.6g} s" if t > now else f"{now - t:.6g} s back" if t < now else "not a time"
        return (f"fmi2DoStep at currentCommunicationPoint = {t:.12g} s, but the FMU's time is {now:.12g} s ("
                f"{'the start time' if now == self._start_s else 'the end of the last step'}): {what}; a step must "
                "start where the previous one ended (to go back, restore an FMU state with fmi2SetFMUstate); "
                "nothing was done")

    # ------------------------------------------------------------------ state
    def _snapshot(self) -> dict[str, Any]:
        # pythonfmu serialises the state as JSON: numpy arrays and scalars become lists and floats
        # (exact: JSON keeps the shortest repr, which round-trips every double).
        return {"variables": super()._get_fmu_state(), "numerics": _plain(self.numerics_state()),
                "failed": self._failed, "time": self._time_s, "initialised": self._initialised,
                "terminated": self._terminated, "start": self._start_s}

    _get_fmu_state = _to_host(_snapshot)

    @_to_host
    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        # A foreign or corrupted state leaves the instance as it was and usable: an error, logged (the
        # loader returns fmi2Error), not an exception (pythonfmu would answer fmi2Fatal).
        if not isinstance(state, dict) or not _STATE_KEYS <= set(state) <= _STATE_KEYS | _STATE_MODE_KEYS:
            reason = state.get(_BAD_STATE) if isinstance(state, dict) else None
            why = reason or "unexpected content: another FMU, or another build of this one"
            self.log(f"not an FMU state of this FMU ({why}); nothing was changed", status=Fmi2Status.error)
            return
        before = self._snapshot()
        if isinstance(state["variables"], dict) and set(state["variables"]) != set(before["variables"]):
            theirs, ours = set(state["variables"]), set(before["variables"])
            self.log(f"not an FMU state of this FMU: a state of another FMU or another build of this one (it has "
                     f"{', '.join(sorted(theirs - ours)[:3]) or 'none of its own'}; lacks "
                     f"{', '.join(sorted(ours - theirs)[:3]) or 'none'}); nothing was changed", status=Fmi2Status.error)
            return
        # a state from before fmi2ExitInitializationMode holds no model: a host in step mode would step none
        if not _saved_initialised(state) and self._initialised:
            self.log("fmi2SetFMUstate: this FMU state was saved before fmi2ExitInitializationMode (it holds "
                     "parameters, no model yet) and this instance is initialised; restore it into an instance "
                     "that is not, or save a state after fmi2ExitInitializationMode; nothing was changed",
                     status=Fmi2Status.error)
            return
        try:
            self._restore(state, before["variables"])
        except Exception as exc:  # noqa: BLE001 - a malformed state: put everything back as it was
            self._restore(before)
            self.log(f"not an FMU state of this FMU ({type(exc).__name__}: {exc}); nothing was changed",
                     status=Fmi2Status.error)

    def _restore(self, state: dict[str, Any], current: dict[str, Any] | None = None) -> None:
        """Restore ``state``; ``current``: this instance's variables now, if already read."""
        time_s, start_s = float(state["time"]), float(state.get("start", self._start_s))
        if not math.isfinite(time_s) or not math.isfinite(start_s):
            raise ValueError(f"time = {time_s!r} and start = {start_s!r} must be finite")
        if current is None:
            current = super()._get_fmu_state()
        # a state of an instance with other parameters (a rig of another length, another method), or one
        # restored before initialisation (fmpy's simulate_fmu(fmu_state=...) does): the numerics are
        # built from the state's parameters, or they would step this instance's, or none
        rebuild = state["numerics"] is not None and (self.numerics_state() is None or any(
            state["variables"].get(v.name) != current[v.name]
            for v in self.vars.values() if v.causality == Fmi2Causality.parameter))
        self._start_s = start_s  # the sample times count from the saving run's start (also in a rebuild)
        initialised, self._initialised = self._initialised, False  # a state sets the fixed parameters too
        try:
            super()._set_fmu_state(state["variables"])
            if rebuild:
                self.initialize_numerics()
                super()._set_fmu_state(state["variables"])  # the outputs as saved, not as just built
        finally:
            self._initialised = initialised
        self.restore_numerics_state(state["numerics"])
        self._failed = bool(state["failed"])
        self._time_s = time_s
        # the state's mode: a state from step mode steps on (also in a terminated instance or one not yet
        # initialised, which either steps at once, as fmpy's simulate_fmu(fmu_state=...) does, or is taken
        # through the initialisation calls first), a terminated one stays terminated
        self._restored_before_init = (_saved_initialised(state) and not self._terminated
                                      and (not initialised or self._restored_before_init))
        if _saved_initialised(state):
            self._initialised = True
        self._terminated = bool(state.get("terminated", False))
        # a state saved before fmi2ExitInitializationMode restores that mode: the host leaves it next
        self._in_init_mode = not self._initialised and not self._terminated

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> dict[str, Any]:
        # A static method has no instance to balance the C++ layer's references with (module
        # docstring), so a bad byte string is reported by _set_fmu_state instead.
        try:
            return json.loads(state.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            return {_BAD_STATE: f"the serialised state is not this FMU's JSON: {exc}"}

    # ------------------------------------------------------------------ to implement
    def initialize_numerics(self) -> None:
        """Build the numerics from the parameters (raise SlaveInputError naming a bad one)."""
        raise NotImplementedError  # abstract: each slave implements it

    def step_numerics(self, t_s: float, dt_s: float) -> None:
        """Validate inputs (raise SlaveInputError naming a bad one), advance, set outputs."""
        raise NotImplementedError  # abstract

    def overflow_hint(self) -> str:
        """What drives the numerics past floating point, for the message of a step that overflowed."""
        return "the parameters drive the model beyond floating point"

    def refresh_calculated(self) -> None:
        """Set the outputs computed at initialisation (``add_output(calculated_from=...)``) from the
        parameters as they are now, in Initialization Mode, where FMI 2.0 lets a host read them
        before fmi2ExitInitializationMode computes them for the run; parameters that cannot make a
        run leave them as they are (fmi2ExitInitializationMode names the problem)."""

    def numerics_state(self) -> Any:
        """JSON-serialisable snapshot of everything dynamic."""
        raise NotImplementedError  # abstract

    def restore_numerics_state(self, state: Any) -> None:
        raise NotImplementedError  # abstract
