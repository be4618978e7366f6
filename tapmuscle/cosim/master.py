"""The co-simulation master: MusclePlant and AMPCController (or a controller FMU of one's own)
coupled at a fixed macro step in fmpy.

Master algorithm (Gauss-Seidel, controller first), macro step ``h`` = the controller's ``Ts``;
for ``k = 0 .. N-1``, ``t_k = k h``::

    l(k), p(k)   <- plant outputs                    (the plant is at t_k)
    controller.l <- l(k);  controller.r <- r(.)       (r only for an external reference)
    controller.doStep(t_k, h)                         samples l(k), r(k..k+Hp): u(k)
    u(k), diagnostics <- controller outputs

A controller FMU of one's own (``[controller] interface``, :attr:`~tapmuscle.cosim.spec.FmuSpec.interface`)
takes the same place: its measurement input gets l(k), its reference input r(k) (the sine as the
project's controller makes it, or the steps' value at t_k), and its command output is u(k); it has no
diagnostics.
    plant.u <- u(k);  plant.load_force <- load(t_k);  plant.supply_pressure <- supply(t_k)
    plant.doStep(t_k, h)                              holds u(k) over [t_k, t_k + h): l(k+1)

Timing diagram (one row of the result per ``k``)::

    t_k                         t_{k+1}
    |------ u(k) held ----------|------ u(k+1) held ---...
    ^ l(k) read, u(k) computed  ^ l(k+1) read, u(k+1) computed

``u(k)`` is computed from ``l(k)`` and acts on ``l(k+1)``: exactly the direct loop of
:func:`tapmuscle.closed_loop.run_closed_loop` and Eq. (1), with no hidden extra sample of delay. A
Jacobi master (all FMUs stepped with the outputs of the previous communication point) would add one
sample of delay in the controller's path; docs/fmu.md explains how to avoid it in other tools.

The last row (``k = N-1``) reads the plant and runs the controller but does not step the plant, as the
direct loop. Any FMI call that fails raises :class:`~tapmuscle.cosim.spec.ScenarioError` with the FMU's
logged message. A Ctrl-C is held while FMI calls run and raised between samples
(:mod:`tapmuscle.interrupts`), so the FMUs are freed normally.
"""

from __future__ import annotations

import difflib
import functools
import itertools
import math
import numbers
import os
import re
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
# The installed pythonfmu first: the first FMU's Python code would otherwise import the copy in its
# resources/ (no builder binaries), and a later build in this process would use that copy.
import pythonfmu  # noqa: F401

from fmi_slave.base import BOUND_ROUNDING
from fmu_controller.methods import METHOD_CODES
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.reference import REFERENCE_SOURCES, SineReference, advanced_lead

from fmu_plant.seed import split_seed
from fmu_plant.user_warning import warn_at_caller
from tapmuscle.cosim.extraction_folder import claimed_folder
from tapmuscle.cosim.fmu_file import check_fmu_file
from tapmuscle.cosim.pythonfmu_exit import release_at_exit
from tapmuscle.cosim.spec import Scenario, ScenarioError
from tapmuscle.errors import FmuLogWarning
from tapmuscle.interrupts import held_interrupts

__all__ = ["FmuInstance", "InstancePool", "Unpacked", "unpack", "check_parameters", "co_simulate",
           "formats_fmu_messages"]

#: The controller FMU's Integer codes of its methods and reference sources, by name.
_CODE: dict[str, int] = {name: code for codes in (METHOD_CODES, REFERENCE_SOURCES) for code, name in codes.items()}

_STATUS = ["OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"]


@dataclass(frozen=True)
class Unpacked:
    """An FMU extracted once per process: its model description and folder; ``stamp``, the file's
    modification time [ns], size [bytes] and inode when it was read.

    Parameters
    ----------
    path : Path
        The ``.fmu`` file (resolved).
    model_description : fmpy.model_description.ModelDescription
        Its model description, as fmpy reads it.
    folder : str
        The folder it is extracted into.
    variables : mapping of str to fmpy ScalarVariable
        Its model variables by name.
    stamp : tuple of int, optional
        ``(mtime_ns, size, inode)`` of the file when it was read.
    """

    path: Path
    model_description: Any
    folder: str
    variables: Mapping[str, Any]
    stamp: tuple[int, int, int] = (0, 0, 0)


_UNPACKED: dict[Path, Unpacked] = {}

# One logger for every instance, alive for the whole process, routed by instance name. It is NOT passed
# through fmpy's addLoggerProxy: that proxy keeps the Python logger in one process-wide C variable, so a
# per-instance logger registered there is used by every later FMU, also those created with fmpy's
# default callbacks, and would crash them once its instance is gone. pythonfmu's messages are plain text
# (no printf arguments); another FMU's are formatted by the project's own compiled logger, whose one
# target is this module's router (_callbacks).
_LOG_SINKS: dict[str, list[str]] = {}
_INSTANCE_COUNTER = itertools.count()
_CALLBACKS: dict[bool, Any] = {}


def _log(_env, name, status, _category, message) -> None:
    """The logger of pythonfmu's FMUs, which send their text as a printf format without arguments."""
    text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
    _route(name, status, text.replace("%%", "%"))


def _log_formatted(name: bytes, status: int, _category: bytes, text: bytes) -> None:
    """What ``tapmuscle.cosim._fmi_log`` formatted of another FMU's message and its arguments."""
    _route(name, status, text.decode("utf-8", "replace"))


def _route(name: Any, status: int, text: str) -> None:
    """A message to its instance's sink (:data:`_LOG_SINKS`), else printed."""
    key = name.decode("utf-8", "replace") if isinstance(name, bytes) else str(name)
    label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
    sink = _LOG_SINKS.get(key)
    if sink is None:  # an instance that is not ours: print as fmpy's default logger does
        print(f"[{label}] {text}")
    else:  # ours: the role says which one spoke, not the name the FMU leads its text with
        sink.append(f"[{label}] {text.removeprefix(f'[{key}] ')}")


def _callbacks(formatted: bool = False) -> Any:
    """The process-wide fmi2CallbackFunctions (each kind created once): ``formatted`` for an FMU whose
    messages are printf formats with arguments (any but pythonfmu's), whose logger formats them where
    ``tapmuscle.cosim._fmi_log`` is compiled (else the formats are shown as they come)."""
    formatted = formatted and _formatting_logger() is not None
    if formatted not in _CALLBACKS:
        from fmpy import calloc, free
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                               fmi2CallbackLoggerTYPE)

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(_formatting_logger().address() if formatted else _log)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        _CALLBACKS[formatted] = cb
    return _CALLBACKS[formatted]


@functools.cache
def _formatting_logger() -> Any:
    """The compiled formatting logger with :func:`_log_formatted` as its target (set once), or None."""
    try:
        from tapmuscle.cosim import _fmi_log
    except ImportError:
        return None
    _fmi_log.set_target(_log_formatted)
    return _fmi_log


#: Environment variable: ``plain`` takes every FMU's messages as plain text (for an FMU that sends its
#: text as the format, with a '%' in it, which FMI forbids); unset, only pythonfmu's are.
FMU_LOG_ENV = "TAPMUSCLE_FMU_LOG"


def formats_fmu_messages() -> bool:
    """Whether the compiled logger that formats an FMU's printf messages with their arguments is built
    (``tapmuscle/cosim/_fmi_log.c``; without it they show their formats)."""
    return _formatting_logger() is not None


def _made_by_pythonfmu(unpacked: Unpacked) -> bool:
    """Whether pythonfmu made the FMU (the project's among them): its fmi2Reset builds the slave anew,
    and its messages are plain text."""
    return "PythonFMU" in (unpacked.model_description.generationTool or "")


def _sends_plain_text(unpacked: Unpacked) -> bool:
    """Whether an FMU's messages are plain text (pythonfmu's; every FMU's with ``TAPMUSCLE_FMU_LOG=plain``),
    not printf formats with arguments."""
    return _made_by_pythonfmu(unpacked) or os.environ.get(FMU_LOG_ENV, "").strip().lower() == "plain"


def unpack(path: str | Path) -> Unpacked:
    """Extract ``path`` (cached per process; removed after the process, even a killed one:
    :mod:`tapmuscle.cosim.extraction_folder`).

    Parameters
    ----------
    path : str or Path
        The ``.fmu`` file.
    """
    from fmpy import extract, read_model_description

    path = Path(path).resolve()
    try:
        found = path.stat()
    except OSError:
        found = None
    if found is None or not stat.S_ISREG(found.st_mode):
        raise ScenarioError(f"{path}: FMU file does not exist")
    stamp = (found.st_mtime_ns, found.st_size, found.st_ino)
    # an FMU written anew at the same path (a service that rebuilds its FMUs) is read anew
    if path not in _UNPACKED or _UNPACKED[path].stamp != stamp:
        _check_unpacked_size(path)  # before its members are read
        check_fmu_file(path)  # a broken binary is named here, not by a signal in this process
        try:
            md = read_model_description(str(path))
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad FMU file
            raise ScenarioError(f"{path}: not a readable FMU: {exc}") from None
        try:
            folder = extract(str(path), claimed_folder(f"tapmuscle_{md.modelName}_"))
        except Exception as exc:  # noqa: BLE001 - fmpy refuses an absolute or drive path with a bare Exception
            raise ScenarioError(f"{path}: not an FMU that can be unpacked: {exc}") from None
        _UNPACKED[path] = Unpacked(path, md, folder, {v.name: v for v in md.modelVariables}, stamp)
    return _UNPACKED[path]


#: The most an FMU may unpack to [bytes], and its most files: far beyond any FMU's (the project's
#: unpack to a few MB), short of a small zip that unpacks to fill the disk (a "zip bomb").
MAX_UNPACKED_BYTES = 2 * 1024 ** 3
MAX_UNPACKED_FILES = 100_000


def _check_unpacked_size(path: Path) -> None:
    """Refuse an FMU that would unpack to more than :data:`MAX_UNPACKED_BYTES` or
    :data:`MAX_UNPACKED_FILES`, before anything is unpacked (the zip's own directory says)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            members = z.infolist()
    except (OSError, zipfile.BadZipFile) as exc:
        raise ScenarioError(f"{path}: not a readable FMU: {exc}") from None
    size = sum(m.file_size for m in members)
    if size > MAX_UNPACKED_BYTES or len(members) > MAX_UNPACKED_FILES:
        raise ScenarioError(f"{path}: would unpack to {size / 1024 ** 3:.1f} GiB in {len(members)} files, more than "
                            f"{MAX_UNPACKED_BYTES / 1024 ** 3:g} GiB or {MAX_UNPACKED_FILES} files any FMU needs: not "
                            "unpacked")


#: What sets each input of the closed loop's FMUs every sample, named where a scenario sets one as a parameter.
_SET_EVERY_SAMPLE = {"u": "the controller's command", "load_force": "the scenario's [load]",
                     "supply_pressure": "the scenario's [supply]", "l": "the plant's displacement",
                     "r": "the scenario's [reference]"}


def _driven_inputs(role: str, interface: Mapping[str, str] | None) -> frozenset[str]:
    """The inputs the closed loop's master sets every sample on an FMU in ``role`` (a controller of
    one's own: the measurement and the reference its ``interface`` names); none outside the loop."""
    if interface is not None:
        return frozenset((interface["measurement"], interface["reference"]))
    return frozenset(ROLE_INTERFACE[role][0]) if role in ROLE_INTERFACE else frozenset()


def _settable(unpacked: Unpacked, name: str, where: str, *, driven: frozenset[str] = frozenset()) -> Any:
    """The parameter or input ``name`` of the FMU; ScenarioError (prefixed by ``where``) if it has none,
    with the closest names it has, or if it names one of the inputs ``driven``, which the master sets
    every sample (a value set once would be overwritten at the first step, and the run recorded with a
    setting it never had). Another input (one a controller of one's own leaves outside its interface)
    is set once, as a constant."""
    var = unpacked.variables.get(name)
    model = unpacked.model_description.modelName
    if var is not None and var.causality == "input" and name in driven:
        by = _SET_EVERY_SAMPLE.get(name, "the master") if model in ("MusclePlant", "AMPCController") else "the master"
        there = f" (the value goes in {by})" if by.startswith("the scenario's") else ""
        raise ScenarioError(f"{where}{name}': is an input of {model}, which {by} sets every sample, not a "
                            f"parameter: remove it{there}")
    if var is None or var.causality not in ("parameter", "input"):
        known = sorted(n for n, v in unpacked.variables.items() if v.causality == "parameter")
        close = [n for n in known if n.lower() == name.lower()] or difflib.get_close_matches(name, known, n=3, cutoff=0.6)
        hint = f"did you mean {' or '.join(repr(c) for c in close)}? " if close else ""
        listed = "docs/fmu.md lists all" if model in ("MusclePlant", "AMPCController") else "its modelDescription.xml lists all"
        raise ScenarioError(f"{where}{name}': not a parameter of {model} "
                            f"({hint}known: {', '.join(known[:8])}, ...; {listed})")
    return var


def _declared_value(var: Any, name: str, value: Any, where: str) -> int | float | bool:
    """``value`` as FMI sets the variable ``var`` (an Enumeration's item name as its number); ScenarioError
    (prefixed by ``where``) if it has the wrong type, is not finite, or lies outside the range the model
    description declares, so that a whole sweep is checked before it runs."""
    if var.type == "Enumeration" and isinstance(value, str):
        items = {item.name: item.value for item in var.declaredType.items}
        if value not in items:
            raise ScenarioError(f"{where}{name}': {value!r} is not one of {', '.join(items)}")
        value = items[value]
    if var.type == "Boolean":  # a controller FMU of one's own may have switches
        if not isinstance(value, bool):
            raise ScenarioError(f"{where}{name}': must be true or false, got {value!r}")
        return value
    if isinstance(value, bool):
        raise ScenarioError(f"{where}{name}': must be a number ({var.type}), got {value!r}")
    finite = isinstance(value, numbers.Real) and math.isfinite(value)
    if var.type in ("Enumeration", "Integer"):
        if not finite or int(value) != value:
            raise ScenarioError(f"{where}{name}': must be an integer, got {value!r}")
        number: int | float = int(value)
    elif var.type == "Real":
        # an infinity only where the model description leaves that side open (the controller's
        # box_lower.* = -inf: no bound); the FMU refuses one where it means nothing
        infinite = isinstance(value, numbers.Real) and math.isinf(value)
        if not finite and not (infinite and (var.min if value < 0 else var.max) is None):
            raise ScenarioError(f"{where}{name}': must be a finite number, got {value!r}")
        number = float(value)
    else:
        raise ScenarioError(f"{where}{name}': {var.type} parameters are not supported")
    lo = -math.inf if var.min is None else float(var.min)
    hi = math.inf if var.max is None else float(var.max)
    if not lo <= number <= hi:
        raise ScenarioError(f"{where}{name}': {value!r} is outside its declared range "
                            f"{var.min if var.min is not None else '-inf'}..{var.max if var.max is not None else 'inf'}")
    return number


def check_parameters(scenario: Scenario, fmus: Mapping[str, str | Path]) -> None:
    """Raise ScenarioError (naming file and key) if ``scenario`` sets a parameter its FMUs do not have, or
    a value of the wrong type or outside the range their model descriptions declare, every such
    parameter in one message (a user mends them in one go); makes no instance, to check a whole sweep
    before it runs (opening an FMU checks it, :mod:`tapmuscle.cosim.fmu_file`, which loads its binary
    once in a child process: an FMU's code runs before any of its runs). (Rules between parameters, such as
    ``servo.Hu <= servo.Hp``, are the FMU's, checked when a run starts.)

    Parameters
    ----------
    scenario : Scenario
        The scenario whose ``plant.parameters`` and ``controller.parameters`` are checked.
    fmus : mapping of str to path
        The default FMU files by model name (``"MusclePlant"``, ``"AMPCController"``), for an FMU
        the scenario does not name.
    """
    problems = []
    for name, role, spec in (("MusclePlant", "plant", scenario.plant),
                             ("AMPCController", "controller", scenario.controller)):
        unpacked = unpack(spec.path or fmus[name])
        check_role(unpacked, role, spec.interface, source=scenario.source)
        where = f"{scenario.source}: key '{role}.parameters."
        driven = _driven_inputs(role, spec.interface)
        for key, value in spec.parameters.items():
            try:
                _declared_value(_settable(unpacked, key, where, driven=driven), key, value, where)
            except ScenarioError as exc:
                problems.append(str(exc))
    if problems:
        raise ScenarioError("; ".join(problems))


#: The interface each role of the closed loop needs: (inputs, outputs, parameters) by name, everything
#: :func:`co_simulate` sets or reads (the diagnostics and ``theta.*`` for ``record="all"``).
ROLE_INTERFACE = {
    "plant": ({"u", "load_force", "supply_pressure"}, {"l", "p"}, {"seed", "seed_high"}),
    "controller": ({"l", "r"},
                   {"u", "r_k", "uc", "l_pred", "pred_error", "H", "xs", "input_delay"}
                   | {f"theta.{n}" for n in ASYMMETRIC.names},
                   {"method", "Ts", "reference_source", "sine.offset", "sine.amplitude", "sine.frequency",
                    "servo.Hp", "ucp.Hp", "input_delay_samples"}),
}


def check_role(unpacked: Unpacked, role: str, interface: Mapping[str, str] | None = None, *,
               source: str = "") -> None:
    """ScenarioError unless the FMU has the inputs, outputs and parameters its ``role`` in the loop
    needs (a controller FMU given as the plant is named as such, not by a parameter it lacks; an FMU
    of one's own as the controller without an ``interface`` is told how to give one). A controller
    of one's own needs the Real variables its ``interface`` names (:attr:`FmuSpec.interface`). A role
    outside the closed loop (:data:`ROLE_INTERFACE`), such as a foreign plant FMU, has no fixed
    interface. ``source`` (the scenario file) leads an interface's messages."""
    if interface is not None:
        if unpacked.model_description.modelName == "AMPCController":
            # its method, Ts and reference source are set by the scenario only without an interface
            lacking = sorted(ROLE_INTERFACE["controller"][1] - {n for n, v in unpacked.variables.items()
                                                                if v.causality == "output"})
            earlier = (f"; this one lacks output {', '.join(lacking)}, as an earlier tapmuscle built it: build the FMUs "
                       "again (tapmuscle build)" if lacking else "")
            raise ScenarioError(f"{unpacked.path}: the project's AMPCController runs without [controller] interface "
                                f"(the scenario sets its method, Ts and reference source then): remove the interface"
                                f"{earlier}")
        _check_interface(unpacked, interface, source)
        return
    if role not in ROLE_INTERFACE:
        return
    need_in, need_out, need_par = ROLE_INTERFACE[role]
    variables = unpacked.variables
    has = {kind: {n for n, v in variables.items() if v.causality == kind} for kind in ("input", "output", "parameter")}
    missing = ([f"input {n}" for n in sorted(need_in - has["input"])]
               + [f"output {n}" for n in sorted(need_out - has["output"])]
               + [f"parameter {n}" for n in sorted(need_par - has["parameter"])])
    if missing:
        ours = unpacked.model_description.modelName == {"plant": "MusclePlant", "controller": "AMPCController"}.get(role)
        renamed = ("; its input load is the plant's load_force as an earlier tapmuscle named it: build the FMU "
                   "again (tapmuscle build)" if role == "plant" and "load" in has["input"]
                   and "load_force" not in has["input"] else
                   "; it is the project's FMU as an earlier tapmuscle built it: build the FMUs again (tapmuscle "
                   "build, or leave the scenario's FMUs to be built from this version)" if ours else "")
        own = ("; a scenario runs the project's MusclePlant interface, which it sets and reads: run a plant FMU "
               "of your own in fmpy or a master of your own (docs/fmu.md)" if role == "plant" else
               "; a controller FMU of one's own runs with [controller] interface = { measurement = ..., "
               "reference = ..., command = ... } naming its variables (docs/fmu.md)") if not renamed else ""
        shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
        raise ScenarioError(f"{unpacked.path}: this {unpacked.model_description.modelName} FMU cannot be the {role}: "
                            f"it lacks {shown}{renamed}{own}")


def _check_interface(unpacked: Unpacked, interface: Mapping[str, str], source: str = "") -> None:
    """ScenarioError unless each variable ``interface`` names exists as a Real of the causality its
    role needs (``measurement``, ``reference``: input; ``command``: output), naming every one that
    does not, with the FMU's Real inputs and outputs."""
    variables, problems = unpacked.variables, []
    for role, name in interface.items():
        causality = "output" if role == "command" else "input"
        var = variables.get(name)
        if var is None:
            problems.append(f"{role} = {name!r}: no such variable")
        elif var.causality != causality or var.type != "Real":
            problems.append(f"{role} = {name!r}: a {var.type} {var.causality}, not a Real {causality}")
    if problems:
        have = {c: sorted(n for n, v in variables.items() if v.causality == c and v.type == "Real")
                for c in ("input", "output")}
        raise ScenarioError(f"{source + ': ' if source else ''}key 'controller.interface' does not fit "
                            f"{unpacked.path}, a {unpacked.model_description.modelName} FMU: {'; '.join(problems)} "
                            f"(its Real inputs: {', '.join(have['input']) or 'none'}; its Real outputs: "
                            f"{', '.join(have['output']) or 'none'})")


def _reason(message: str) -> str:
    """An FMU's initialisation log line without its level tag and its advice to FMI hosts."""
    text = re.sub(r"^\[[A-Z]+\] (initialisation failed: )?", "", message)
    return text.split("; every fmi2DoStep will return fmi2Error")[0]


class FmuInstance:
    """An fmpy ``FMU2Slave`` (or, with ``model_exchange=True``, an ``FMU2Model``) with a logger that
    keeps the FMU's messages (to name them in errors).

    Lifecycle as FMI's: construct (instantiate, setup experiment, enter initialization), set
    parameters and initial inputs, :meth:`start` (exit initialization), then ``set``/``do_step``/
    ``get``; :meth:`free` at the end. A model-exchange instance is in event mode after :meth:`start`;
    :class:`tapmuscle.cosim.model_exchange.ModelExchangeStepper` steps it.

    Parameters
    ----------
    path : str or Path
        The ``.fmu`` file.
    instance_name : str
        The instance's name (made unique with a counter: messages are routed by it).
    role : str
        Its role in the loop (``"plant"``, ``"controller"``, or one outside the closed loop such
        as ``"foreign plant"``), whose inputs, outputs and parameters are checked
        (:func:`check_role`).
    model_exchange : bool, optional
        Instantiate the model-exchange interface (``FMU2Model``) instead of co-simulation;
        default False.
    interface : mapping of str to str, optional
        A controller of one's own's variable names (:attr:`FmuSpec.interface`); None: the
        project's.
    source : str, optional
        The scenario file, which leads an interface's messages.
    """

    def __init__(self, path: str | Path, instance_name: str, *, role: str, model_exchange: bool = False,
                 interface: Mapping[str, str] | None = None, source: str = "") -> None:
        from fmpy.fmi2 import FMU2Model, FMU2Slave

        self.unpacked = unpack(path)
        self.role = role
        self.messages: list[str] = []
        md = self.unpacked.model_description
        self.interface = interface
        check_role(self.unpacked, role, interface, source=source)
        instance_name = f"{instance_name}#{next(_INSTANCE_COUNTER)}"  # unique: messages are routed by name
        _LOG_SINKS[instance_name] = self.messages
        self._name = instance_name
        kind, interface = (FMU2Model, md.modelExchange) if model_exchange else (FMU2Slave, md.coSimulation)
        if interface is None:
            raise ScenarioError(f"{self.unpacked.path}: {md.modelName} has no "
                                f"{'model-exchange' if model_exchange else 'co-simulation'} interface"
                                + ("" if model_exchange else " (a model-exchange FMU): scenarios, sweeps and check "
                                   "step co-simulation FMUs, so export it for co-simulation (tapmuscle diagnose "
                                   "--plant takes a model-exchange plant)"))
        self.fmu = kind(guid=md.guid, unzipDirectory=self.unpacked.folder,
                        modelIdentifier=interface.modelIdentifier, instanceName=instance_name)
        self.failed_status = 0  # the worst fmi2Status a failed call returned (3: fmi2Error, 4: fmi2Fatal)
        # an FMU on pythonfmu's own binary would otherwise corrupt this process's heap as it exits
        release_at_exit(self.unpacked.folder, interface.modelIdentifier)
        callbacks = _callbacks(formatted=not _sends_plain_text(self.unpacked))
        self._call("instantiate", lambda: self.fmu.instantiate(callbacks=callbacks, loggingOn=True))
        try:
            self._call("fmi2SetupExperiment", lambda: self.fmu.setupExperiment(startTime=0.0))
            self._call("fmi2EnterInitializationMode", self.fmu.enterInitializationMode)
        except BaseException:
            try:
                self.free()  # as its last status allows
            except Exception:  # noqa: BLE001 - the failure that stopped it is the one to report
                pass
            raise

    # ------------------------------------------------------------------ helpers
    def vr(self, name: str) -> int:
        return self.unpacked.variables[name].valueReference

    def error(self, what: str, detail: Any, t_s: float | None = None) -> ScenarioError:
        """A ScenarioError for a failed FMI call, with the FMU's last logged messages."""
        at = "" if t_s is None else f" at t = {t_s:.12g} s"
        log = "; ".join(self.said(3)) or "no message logged"
        detail = str(detail).rstrip(".")  # fmpy's "... with status 3 (error)." leads the FMU's own text
        return ScenarioError(f"{self.role} FMU ({self.unpacked.path.name}) {what}{at} failed: {detail}: {log}")

    def said(self, n: int) -> list[str]:
        """The FMU's last ``n`` messages with a status other than OK (its events, status OK, left out)."""
        return [m for m in self.messages if not m.startswith("[OK]")][-n:]

    def _call(self, what: str, fn: Callable[[], Any], t_s: float | None = None) -> Any:
        try:
            return fn()
        except Exception as exc:  # noqa: BLE001 - fmpy raises FMICallException (and others on NULL)
            self.failed(getattr(exc, "status", 3))
            raise self.error(what, exc, t_s) from None

    def failed(self, status: int) -> None:
        """Note that a call returned ``status`` (fmi2Error or worse): what :meth:`free` may still call."""
        if isinstance(status, int) and status > self.failed_status:
            self.failed_status = status

    def set_parameters(self, values: Mapping[str, Any], *, where: str, inputs: bool = False) -> None:
        """Set parameters by FMU variable name, and inputs the master does not drive (with ``inputs``,
        those too: the master's own start values); ``where`` (e.g. ``file: key 'plant.parameters.'``)
        prefixes the name in errors."""
        driven = frozenset() if inputs else _driven_inputs(self.role, self.interface)
        for name, value in values.items():
            var = _settable(self.unpacked, name, where, driven=driven)
            number = _declared_value(var, name, value, where)
            if var.type == "Real":
                self._call(f"setting {name}", lambda: self.fmu.setReal([var.valueReference], [number]))
            elif var.type == "Boolean":
                self._call(f"setting {name}", lambda: self.fmu.setBoolean([var.valueReference], [number]))
            else:
                self._call(f"setting {name}", lambda: self.fmu.setInteger([var.valueReference], [number]))

    def start(self) -> None:
        self._call("exitInitializationMode", self.fmu.exitInitializationMode)
        # the project's FMUs log a rejected parameter as a warning at this call; an FMU of one's own
        # may warn of anything here, and its warnings reach the caller with the run's
        bad = ("[ERROR]", "[FATAL]") if self.interface is not None else ("[WARNING]", "[ERROR]", "[FATAL]")
        if any(m.startswith(bad) for m in self.messages):
            # the reason only: the log's level and its advice to FMI hosts mean nothing to a scenario's user
            reasons = [_reason(m) for m in self.messages if m.startswith(bad)]
            raise ScenarioError(f"{self.role} FMU ({self.unpacked.path.name}) rejected its parameters: "
                                + "; ".join(reasons))

    def reset(self) -> None:
        """Back to the state right after construction (fmi2Terminate, fmi2Reset, setup, enter
        initialization): every parameter at its start value, for the next run."""
        self._call("fmi2Terminate", self.fmu.terminate)
        self._call("fmi2Reset", self.fmu.reset)
        self.messages.clear()
        self._call("fmi2SetupExperiment", lambda: self.fmu.setupExperiment(startTime=0.0))
        self._call("fmi2EnterInitializationMode", self.fmu.enterInitializationMode)

    def get_integer(self, name: str) -> int:
        """The Integer variable ``name`` (its status recorded as every call's is)."""
        return int(self._call(f"getting {name}", lambda: self.fmu.getInteger([self.vr(name)]))[0])

    def free(self) -> None:
        """End the instance as FMI 2.0 (2.1.3, 4.2.4) allows after its last status: fmi2Terminate and
        fmi2FreeInstance; after an fmi2Error only fmi2FreeInstance; after an fmi2Fatal nothing at all,
        the instance (a few kB) is kept unfreed for the process's life. A pythonfmu export has
        released its slave's Python objects when it returns fmi2Fatal for an exception in the slave;
        a later fmi2Terminate or fmi2FreeInstance releases them again, and the host's next garbage
        collection crashes the process."""
        if self.failed_status >= 4:
            _ABANDONED.append(self)
            return
        try:
            if self.failed_status < 3:
                self.fmu.terminate()
        finally:
            self.fmu.freeInstance()
            _LOG_SINKS.pop(self._name, None)


#: Instances that returned fmi2Fatal: no FMI call may reach them again, and their library stays loaded.
_ABANDONED: list[FmuInstance] = []


def _interface_key(interface: Mapping[str, str] | None) -> tuple[tuple[str, str], ...] | None:
    """A controller of one's own's interface as a hashable key (instances checked for one are kept apart)."""
    return None if interface is None else tuple(sorted(interface.items()))


class InstancePool:
    """Idle FMU instances of one process, reused by :func:`co_simulate` (``pool=``) across runs.

    A run takes an idle instance of the same FMU file and role, resets it (:meth:`FmuInstance.reset`:
    fmi2Reset, after which pythonfmu creates the slave object anew, so every parameter and all state
    are back at their start values) instead of instantiating (about 12 ms per FMU against 0.5 ms).
    Only pythonfmu's FMUs are kept; another FMU gets a new instance every run.
    Results are the same bit for bit (tests/test_sweep.py). An instance whose run raised is freed,
    not reused. Thread-safe; :meth:`close` frees the idle instances.
    """

    def __init__(self) -> None:
        self._idle: dict[tuple[Path, tuple[int, int, int], str, tuple[tuple[str, str], ...] | None],
                         list[FmuInstance]] = {}
        self._fresh_only: set[tuple[Path, tuple[int, int, int], str, tuple[tuple[str, str], ...] | None]] = set()
        self._lock = threading.Lock()

    def acquire(self, path: str | Path, instance_name: str, *, role: str,
                interface: Mapping[str, str] | None = None, source: str = "") -> FmuInstance:
        """An instance of ``path`` in initialization mode: a reset idle one, or a new one."""
        unpacked = unpack(path)
        key = (unpacked.path, unpacked.stamp, role, _interface_key(interface))
        with self._lock:
            idle = self._idle.get(key)
            inst = idle.pop() if idle else None
        if inst is None:
            return FmuInstance(path, instance_name, role=role, interface=interface, source=source)
        try:
            inst.reset()
        except ScenarioError:
            # an FMU whose fmi2Reset fails (an export that does not implement it): a new instance
            # instead, and this FMU's instances are not kept for another run
            with self._lock:
                self._fresh_only.add(key)
            try:
                inst.free()
            except Exception:  # noqa: BLE001 - freeing what failed to reset: the new instance matters
                pass
            return FmuInstance(path, instance_name, role=role, interface=interface, source=source)
        except BaseException:
            inst.free()
            raise
        return inst

    def release(self, inst: FmuInstance) -> None:
        """Keep ``inst`` (after a run that ended normally) for a later :meth:`acquire`: a pythonfmu FMU's,
        whose fmi2Reset builds the slave anew; another FMU's is freed (an export's fmi2Reset may keep
        state from the run before, which no call can tell)."""
        with self._lock:
            key = (inst.unpacked.path, inst.unpacked.stamp, inst.role, _interface_key(inst.interface))
            if key not in self._fresh_only and _made_by_pythonfmu(inst.unpacked):
                self._idle.setdefault(key, []).append(inst)
                return
        inst.free()

    def close(self) -> None:
        """Free every idle instance."""
        with self._lock:
            idle, self._idle = [i for lst in self._idle.values() for i in lst], {}
        for inst in idle:
            inst.free()


def sample_columns(cols: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The per-sample columns of :func:`co_simulate`'s result (without its 0-d ``wall_time_s`` and
    ``input_delay``): what a recording holds."""
    return {k: v for k, v in cols.items() if np.ndim(v) == 1}


def co_simulate(scenario: Scenario, fmus: Mapping[str, str | Path], *, record: str = "all",
                controller_parameters: Mapping[str, Any] | None = None,
                progress: Callable[[int, int], None] | None = None,
                pool: InstancePool | None = None, fmu_warnings: list[str] | None = None) -> dict[str, np.ndarray]:
    """Run ``scenario`` with the master algorithm of the module docstring.

    Parameters
    ----------
    scenario : Scenario
    fmus : mapping
        ``{"MusclePlant": path, "AMPCController": path}``; the scenario's own ``fmu`` keys win.
    record : {"all", "minimal"}
        ``all``: the columns of :func:`tapmuscle.closed_loop.run_closed_loop` (diagnostics and theta-hat
        each step); ``minimal``: ``t_s, r_mm, l_mm, u_v`` only (fewer FMI calls, for timing).
    controller_parameters : mapping, optional
        Extra controller parameters (e.g. ``theta0.*``), applied after the scenario's.
    progress : callable, optional
        Called with ``(done, total)`` samples.
    pool : InstancePool, optional
        Take the FMU instances from (and give them back to) this pool instead of instantiating and
        freeing them; same results.
    fmu_warnings : list, optional
        Where to append what the FMUs warned of during the run (``"controller FMU: ..."``). Without
        it each is issued as a :class:`~tapmuscle.errors.FmuLogWarning` (Python's warnings, which are
        process-wide: a worker running runs in threads passes a list).

    Returns
    -------
    dict of ndarray
        One row per sample ``k`` (module docstring), plus ``wall_time_s`` (a 0-d array) and the
        controller's ``input_delay`` at the end (a 0-d array: the delay its law ran for, what
        ``input_delay_samples = -1`` decided).
    """
    if record not in ("all", "minimal"):
        raise ValueError(f"record must be 'all' or 'minimal', got {record!r}")
    src = scenario.source
    new = pool.acquire if pool is not None else FmuInstance
    with held_interrupts() as held:  # Ctrl-C ends the run between FMI calls, not inside an FMU
        plant = new(scenario.plant.path or fmus["MusclePlant"], f"{scenario.name}.plant", role="plant")
        ctrl, done = None, False
        own = scenario.controller.interface
        try:
            ctrl = new(scenario.controller.path or fmus["AMPCController"], f"{scenario.name}.controller",
                       role="controller", interface=own, source=src)
            plant.set_parameters(scenario.plant.parameters, where=f"{src}: key 'plant.parameters.")
            low, high = split_seed(scenario.seed)  # FMI Integers are 32-bit: the seed travels as two
            plant.set_parameters({"seed": low, "seed_high": high}, where=f"{src}: key '")
            plant.set_parameters({"load_force": scenario.load.at(0.0), "supply_pressure": scenario.supply.at(0.0)},
                                 where=f"{src}: key '[load]/[supply] ", inputs=True)
            if own is not None:  # its own law and parameters; the master feeds it r(k), no preview
                ctrl_params: dict[str, Any] = {**scenario.controller.parameters, **(controller_parameters or {})}
                ctrl.set_parameters(ctrl_params, where=f"{src}: key 'controller.parameters.")
                hp = 0
                step = _default_step(ctrl)
                variable = getattr(ctrl.unpacked.model_description.coSimulation,
                                   "canHandleVariableCommunicationStepSize", False)
                if step is not None and not variable and abs(step - scenario.step_s) > 1e-9 * scenario.step_s:
                    # an export that cannot take another step size computes its law for its own: say so
                    ctrl.messages.append(f"[WARNING] its DefaultExperiment step is {step:g} s; the scenario "
                                         f"steps it every step_s = {scenario.step_s:g} s")
            else:
                hp = _set_up_project_controller(ctrl, scenario, controller_parameters)
            # an own controller's warnings from its instantiation on (the project's FMUs say nothing
            # there that a run should pass on; a rejected parameter of theirs stops the run at start)
            logged = [len(plant.messages), 0 if own is not None else len(ctrl.messages)]
            plant.start()
            ctrl.start()
            cols = _loop(scenario, plant, ctrl, hp, record, progress, held)
            if "input_delay" in ctrl.unpacked.variables and own is None:  # an FMU built before the output existed has none
                cols["input_delay"] = np.asarray(ctrl.get_integer("input_delay"))
            # what the FMUs warned of during the run reaches the caller (a failed run's error names it)
            for inst, n0 in zip((plant, ctrl), logged):
                for m in inst.messages[n0:]:
                    if m.startswith(("[WARNING]", "[ERROR]")):
                        # an error the FMU logged while its call still returned OK or Warning: said as one
                        level = " (logged as an error; its call did not fail)" if m.startswith("[ERROR]") else ""
                        text = f"{inst.role} FMU: {_reason(m)}{level}"
                        if fmu_warnings is None:
                            warn_at_caller(FmuLogWarning(text), FmuLogWarning)
                        else:
                            fmu_warnings.append(text)
            done = True
            return cols
        finally:
            for inst in (ctrl, plant):
                if inst is not None:
                    try:
                        if done and pool is not None:
                            pool.release(inst)
                        else:
                            inst.free()
                    except Exception:  # noqa: BLE001 - after a failed run, its failure is the one reported
                        if done:       # and the other instance is freed still
                            raise


def _default_step(inst: FmuInstance) -> float | None:
    """The ``stepSize`` [s] of the FMU's DefaultExperiment, None without one."""
    experiment = inst.unpacked.model_description.defaultExperiment
    step = getattr(experiment, "stepSize", None) if experiment is not None else None
    try:
        return float(step) if step is not None else None
    except (TypeError, ValueError):
        return None


def _set_up_project_controller(ctrl: FmuInstance, scenario: Scenario,
                               controller_parameters: Mapping[str, Any] | None) -> int:
    """Set the project's AMPCController up for ``scenario`` (its method, ``Ts``, reference source and
    the scenario's parameters) and return the samples ``Hp`` of preview it reads (plus the lead of a
    delayed law), which the master's advanced reference feeds ahead."""
    src, h, ref = scenario.source, scenario.step_s, scenario.reference
    ctrl_params: dict[str, Any] = {"method": _CODE[scenario.method], "Ts": h}
    if ref.kind == "sine":
        ctrl_params.update({"reference_source": _CODE["builtin_sine"], "sine.offset": ref.offset_mm,
                            "sine.amplitude": ref.amplitude_mm, "sine.frequency": ref.frequency_hz})
    else:
        ctrl_params["reference_source"] = _CODE["external_advanced" if ref.preview == "advanced"
                                                else "external_held"]
    if "input_delay_samples" in ctrl.unpacked.variables:
        # this master steps the controller before the plant: no delay to detect (the FMU's
        # default -1 would start with the delayed law); a scenario may still set -1 or 1
        ctrl_params["input_delay_samples"] = 0
    ctrl_params.update(scenario.controller.parameters)
    ctrl_params.update(controller_parameters or {})
    ctrl.set_parameters(ctrl_params, where=f"{src}: key 'controller.parameters.")
    hp_name = "servo.Hp" if scenario.method.endswith("servo") else "ucp.Hp"
    hp = ctrl.get_integer(hp_name)
    if "input_delay_samples" in ctrl.unpacked.variables:  # an FMU built before the parameter existed has none
        hp += advanced_lead(ctrl.get_integer("input_delay_samples"))
    return hp


def _holding_gil(fmu: Any, names: tuple[str, ...]) -> list[Any]:
    """fmpy's ctypes functions ``names`` of ``fmu``, called without releasing the GIL and without
    argument conversion.

    ctypes releases the GIL around every foreign call, and a pythonfmu FMU takes it back at once to
    run its Python slave. In a Dask worker the worker's event-loop thread is waiting for the GIL
    then, so every FMI call becomes a thread hand-over (a run was 15-25 % slower in a worker than in
    a plain process, benchmarks/sweep_speedup.py). Holding the GIL through the call is safe: the
    slave's ``PyGILState_Ensure`` nests. The same library handle as fmpy's; no ``argtypes``: the
    callers (:class:`_RealPort`) pass ready-made ctypes objects of the C types, which saves the
    per-argument conversion (about 0.5 us of a 2 us call).
    """
    from ctypes import PyDLL, c_int

    lib = PyDLL(fmu.dll._name, handle=fmu.dll._handle)
    functions = []
    for name in names:
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = None, c_int  # fmi2Status
        functions.append(fn)
    return functions


class _RealPort:
    """The hot FMI calls of one FMU (fmi2GetReal of its outputs, fmi2SetReal of its inputs, fmi2DoStep)
    with preallocated ctypes arguments.

    fmpy's ``getReal``/``setReal`` build new arrays and lists on every call; in a loop of ~40 us per
    sample that overhead matters (benchmarks/fmu_cosim.py). Same FMI calls, same status checks.
    Each call is a ``(function, arguments)`` pair, called by :func:`_loop` as ``fn(*args)``, which
    returns the fmi2Status; :meth:`check` raises for a status worse than fmi2Warning. Write the inputs
    into :attr:`inputs` and the step's start into ``t.value`` before the calls; read :attr:`outputs`.
    """

    def __init__(self, inst: FmuInstance, out_vrs: list[int], in_vrs: list[int], h_s: float) -> None:
        from ctypes import c_double, c_size_t, c_uint, c_void_p

        self.inst = inst
        get, set_, step = _holding_gil(inst.fmu, ("fmi2GetReal", "fmi2SetReal", "fmi2DoStep"))
        component = c_void_p(inst.fmu.component)
        outputs, inputs = (c_double * len(out_vrs))(), (c_double * len(in_vrs))()
        self.outputs = np.frombuffer(outputs, dtype=np.float64)
        self.inputs = np.frombuffer(inputs, dtype=np.float64)
        self.t = c_double()
        self.get = (get, (component, (c_uint * len(out_vrs))(*out_vrs), c_size_t(len(out_vrs)), outputs))
        self.set = (set_, (component, (c_uint * len(in_vrs))(*in_vrs), c_size_t(len(in_vrs)), inputs))
        self.step = (step, (component, self.t, c_double(h_s), 1))  # noSetFMUStatePriorToCurrentPoint

    def check(self, status: int, what: str, t_s: float) -> None:
        """Raise ScenarioError if ``status`` (of the call ``what`` at ``t_s``) is worse than fmi2Warning."""
        if status > 1:
            self.inst.failed(status)
            raise self.inst.error(what, f"status {_STATUS[status] if status < len(_STATUS) else status}", t_s)


def _loop(scenario: Scenario, plant: FmuInstance, ctrl: FmuInstance, hp: int, record: str,
          progress: Callable[[int, int], None] | None, held: Any) -> dict[str, np.ndarray]:
    n, h, ref = scenario.n_samples, scenario.step_s, scenario.reference
    own = ctrl.interface
    # a controller of one's own reads r(k) from the master and writes its command only; the project's
    # reads r (an external reference) or makes it (the sine), and gives r(k) back with its diagnostics
    external = own is not None or ref.kind != "sine"
    advance = hp * h if external and ref.preview == "advanced" else 0.0
    full = record == "all"
    diag = ["u", "r_k", "uc", "l_pred", "pred_error", "H", "xs"] + [f"theta.{n_}" for n_ in ASYMMETRIC.names]
    if own is not None:
        # the command the plant's valve takes (its input u's declared range): one outside is the
        # controller's, named as such, also at the last sample, which the plant never receives
        u_var = plant.unpacked.variables["u"]
        u_lo = -math.inf if u_var.min is None else float(u_var.min)
        u_hi = math.inf if u_var.max is None else float(u_var.max)
        # as the plant takes an ulp beyond its bound (a host's rounding) as the bound
        u_lo, u_hi = u_lo - BOUND_ROUNDING * max(1.0, abs(u_lo)), u_hi + BOUND_ROUNDING * max(1.0, abs(u_hi))
        ctrl_out = [ctrl.vr(own["command"])]
        ctrl_in = [ctrl.vr(own["measurement"]), ctrl.vr(own["reference"])]
        # r(k) as the project's controller makes its built-in sine, so both kinds of run see one r
        sine = (SineReference(offset_mm=ref.offset_mm, amplitude_mm=ref.amplitude_mm, frequency_hz=ref.frequency_hz,
                              ts_s=h) if ref.kind == "sine" else None)
        r_fed = np.array([sine.at(k) if sine is not None else ref.at(k * h) for k in range(n)])
    else:
        ctrl_out = [ctrl.vr(v) for v in (diag if full else ["u", "r_k"])]
        ctrl_in = [ctrl.vr("l"), ctrl.vr("r")] if external else [ctrl.vr("l")]
    plant_out = [plant.vr("l"), plant.vr("p")] if full else [plant.vr("l")]
    plant_in = [plant.vr("u"), plant.vr("load_force"), plant.vr("supply_pressure")]
    rows_p = np.empty((n, len(plant_out)))
    rows_c = np.empty((n, len(ctrl_out)))
    plant_io, ctrl_io = _RealPort(plant, plant_out, plant_in, h), _RealPort(ctrl, ctrl_out, ctrl_in, h)
    p_in, c_in, p_out, c_out = plant_io.inputs, ctrl_io.inputs, plant_io.outputs, ctrl_io.outputs
    (p_get, p_get_args), (p_set, p_set_args), (p_step, p_step_args) = plant_io.get, plant_io.set, plant_io.step
    (c_get, c_get_args), (c_set, c_set_args), (c_step, c_step_args) = ctrl_io.get, ctrl_io.set, ctrl_io.step
    p_t, c_t = plant_io.t, ctrl_io.t
    every = max(1, n // 100)
    load_k = [scenario.load.at(k * h) for k in range(n)]
    supply_k = [scenario.supply.at(k * h) for k in range(n)]
    start = time.perf_counter()
    for k in range(n):  # the master algorithm of the module docstring; a status > 0 is checked
        t = k * h
        if status := p_get(*p_get_args):
            plant_io.check(status, "fmi2GetReal", t)
        c_in[0] = p_out[0]
        if own is not None:
            c_in[1] = r_fed[k]
        elif external:
            c_in[1] = ref.at(t + advance)
        if status := c_set(*c_set_args):
            ctrl_io.check(status, "fmi2SetReal", t)
        c_t.value = t
        if status := c_step(*c_step_args):
            ctrl_io.check(status, "fmi2DoStep", t)
        if status := c_get(*c_get_args):
            ctrl_io.check(status, "fmi2GetReal", t)
        if own is not None and not u_lo <= c_out[0] <= u_hi:  # also NaN
            raise ScenarioError(f"controller FMU ({ctrl.unpacked.path.name}) output {own['command']} = {float(c_out[0])!r} "
                                f"at t = {t:.12g} s is not a command the plant's valve takes ({u_var.min}..{u_var.max} V, "
                                "saturated at 0..10 V)")
        if k + 1 < n:
            p_in[0], p_in[1], p_in[2] = c_out[0], load_k[k], supply_k[k]
            if status := p_set(*p_set_args):
                plant_io.check(status, "fmi2SetReal", t)
            p_t.value = t
            if status := p_step(*p_step_args):
                plant_io.check(status, "fmi2DoStep", t)
        rows_p[k], rows_c[k] = p_out, c_out
        if held.pending:
            held.raise_if_pending()
        if progress is not None and (k % every == 0 or k + 1 == n):
            progress(k + 1, n)
    wall = time.perf_counter() - start
    cols = {"t_s": np.arange(n) * h, "r_mm": rows_c[:, 1].copy() if own is None else r_fed,
            "l_mm": rows_p[:, 0].copy(), "u_v": rows_c[:, 0].copy()}
    if full and own is not None:
        cols.update({"p_mpa": rows_p[:, 1].copy(), "load_n": np.array(load_k)})
    elif full:
        pred_next = rows_c[:, 3]
        cols.update({"p_mpa": rows_p[:, 1].copy(), "load_n": np.array(load_k),
                     "l_pred_mm": np.concatenate(([rows_p[0, 0]], pred_next[:-1])),
                     "pred_error_mm": rows_c[:, 4].copy(), "uc_v": rows_c[:, 2].copy(), "h_mm": rows_c[:, 5].copy(),
                     "xs_mm": rows_c[:, 6].copy()})
        for i, name in enumerate(ASYMMETRIC.names):
            cols[f"theta_{name}"] = rows_c[:, 7 + i].copy()
    cols["wall_time_s"] = np.asarray(wall)
    return cols
