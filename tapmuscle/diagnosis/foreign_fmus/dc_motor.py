"""DcMotor: an FMI 2.0 FMU of a DC motor with Coulomb friction, written in C (co-simulation,
model exchange, or both).

The model (``dc_motor.c`` next to this module), with the armature current ``i`` [A], the speed
``omega`` [rad/s] and the angle ``theta`` [rad] as states and the armature voltage ``V`` [V] as input::

    L di/dt     = V - R i - K omega
    J domega/dt = K i - b omega - Tc tanh(omega / omega_s)
    dtheta/dt   = omega

======== ======= =========== =====================================================
name     default unit        meaning
======== ======= =========== =====================================================
R        2.0     Ohm         armature resistance
L        0.01    H           armature inductance
K        0.1     N.m/A       torque constant (= back-EMF constant in V.s/rad)
J        0.01    kg.m2       rotor inertia
b        0.002   N.m.s/rad   viscous friction
Tc       0.02    N.m         Coulomb friction torque
omega_s  0.5     rad/s       speed over which the Coulomb term is smoothed by tanh
======== ======= =========== =====================================================

All parameters are ``fixed`` (set them before ``fmi2ExitInitializationMode``, or after ``fmi2Reset``).
The states start at 0. ``fmi2DoStep`` integrates with classic RK4 on ``ceil(h / 0.5 ms)`` equal
substeps, so any communication step ``h > 0`` works. In model exchange the host integrates the
states ``(i, omega, theta)``, whose derivatives are the local variables ``der(i)``, ``der(omega)``,
``der(theta)``; the model has no events. The FMU can get and set its state
(``canGetAndSetFMUstate``) but not serialize it.

:func:`build_dc_motor_fmu` compiles the C source with gcc against fmpy's FMI 2.0 headers (64-bit
Linux: x86-64 or aarch64, into ``binaries/linux64``) and writes ``DcMotor.fmu``, offering the interfaces it is asked for (one binary serves
both).
"""

from __future__ import annotations

import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import NamedTuple, Sequence

import fmpy

__all__ = ["build_dc_motor_fmu", "MODEL_IDENTIFIER", "VARIABLES", "INTERFACES"]

MODEL_IDENTIFIER = "DcMotor"
SOURCE = Path(__file__).with_name("dc_motor.c")

#: The FMI 2.0 interface elements the one binary implements.
INTERFACES = ("CoSimulation", "ModelExchange")


class Variable(NamedTuple):
    """One ScalarVariable of modelDescription.xml (all are Real)."""

    name: str
    value_reference: int
    causality: str
    start: float | None  # None: calculated by the FMU (the outputs)
    unit: str
    description: str
    derivative_of: int | None = None  # a state derivative: the value reference of its state


#: In value-reference order, which must be the order of the enum in dc_motor.c.
VARIABLES = (
    Variable("V", 0, "input", 0.0, "V", "armature voltage"),
    Variable("omega", 1, "output", None, "rad/s", "rotor speed"),
    Variable("i", 2, "output", None, "A", "armature current"),
    Variable("theta", 3, "output", None, "rad", "rotor angle"),
    Variable("R", 4, "parameter", 2.0, "Ohm", "armature resistance"),
    Variable("L", 5, "parameter", 0.01, "H", "armature inductance"),
    Variable("K", 6, "parameter", 0.1, "N.m/A", "torque constant (= back-EMF constant in V.s/rad)"),
    Variable("J", 7, "parameter", 0.01, "kg.m2", "rotor inertia"),
    Variable("b", 8, "parameter", 0.002, "N.m.s/rad", "viscous friction coefficient"),
    Variable("Tc", 9, "parameter", 0.02, "N.m", "Coulomb friction torque"),
    Variable("omega_s", 10, "parameter", 0.5, "rad/s", "smoothing speed of the Coulomb friction: Tc*tanh(omega/omega_s)"),
    # state derivatives, in the order of the state vector of model exchange: (i, omega, theta)
    Variable("der(i)", 11, "local", None, "A/s", "derivative of the armature current", derivative_of=2),
    Variable("der(omega)", 12, "local", None, "rad/s2", "rotor acceleration", derivative_of=1),
    Variable("der(theta)", 13, "local", None, "rad/s", "derivative of the rotor angle", derivative_of=3),
)

#: SI base-unit exponents of every unit the variables use (FMI 2.0 <BaseUnit> attributes).
_UNITS = {
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "A": {"A": 1},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "A/s": {"A": 1, "s": -1},
    "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2},
    "N.m/A": {"kg": 1, "m": 2, "s": -2, "A": -1},
    "kg.m2": {"kg": 1, "m": 2},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "N.m": {"kg": 1, "m": 2, "s": -2},
}

#: The log categories dc_motor.c uses; errors are logged whether or not logging is on.
_LOG_CATEGORIES = {
    "logStatusError": "errors: refused calls and values, a diverging state (always logged)",
    "logStatusWarning": "warnings (none at present)",
    "logAll": "informational messages",
}


def _guid(source: str) -> str:
    """The GUID dc_motor.c checks in fmi2Instantiate: the C source is the one place it is written."""
    match = re.search(r'^#define DC_MOTOR_GUID "(\{[0-9a-f-]+\})"', source, re.MULTILINE)
    if match is None:
        raise RuntimeError(f"{SOURCE}: no '#define DC_MOTOR_GUID \"{{...}}\"' line")
    return match.group(1)


def _scalar_variable(v: Variable) -> str:
    attributes = f'name="{v.name}" valueReference="{v.value_reference}" description="{v.description}" ' \
                 f'causality="{v.causality}"'
    if v.causality == "parameter":
        attributes += ' variability="fixed" initial="exact"'
    else:
        attributes += ' variability="continuous"'  # inputs have no initial; outputs default to calculated
    start = "" if v.start is None else f' start="{v.start!r}"'
    if v.derivative_of is not None:  # FMI 2.0: the 1-based index of the state in ModelVariables
        start += f' derivative="{_index(v.derivative_of)}"'
    return f'    <ScalarVariable {attributes}>\n      <Real unit="{v.unit}"{start}/>\n    </ScalarVariable>'


def _index(value_reference: int) -> int:
    """1-based position in ModelVariables (ModelStructure and ``derivative`` attributes use it)."""
    return next(k for k, v in enumerate(VARIABLES, start=1) if v.value_reference == value_reference)


def model_description(guid: str, interfaces: Sequence[str] = ("CoSimulation",)) -> str:
    """modelDescription.xml of DcMotor.

    Parameters
    ----------
    guid
        The GUID compiled into the binary.
    interfaces
        The interface elements to offer, any of :data:`INTERFACES`.

    Returns
    -------
    str
        The XML text.
    """
    units = "\n".join(
        f'    <Unit name="{name}"><BaseUnit ' + " ".join(f'{k}="{e}"' for k, e in exponents.items()) + "/></Unit>"
        for name, exponents in _UNITS.items())
    categories = "\n".join(f'    <Category name="{name}" description="{text}"/>' for name, text in _LOG_CATEGORIES.items())
    unknown = set(interfaces) - set(INTERFACES)
    if unknown or not interfaces:
        raise ValueError(f"interfaces {tuple(interfaces)!r}: give one or both of {', '.join(INTERFACES)}")
    variables = "\n".join(_scalar_variable(v) for v in VARIABLES)
    # ModelStructure indices are 1-based positions in ModelVariables. The outputs are states, so in
    # co-simulation they depend on no input directly (dependencies=""); model exchange's dependencies
    # also count states, so they are left out there (= may depend on every known). At initialization
    # the states are simply 0.
    dependencies = ' dependencies=""' if "ModelExchange" not in interfaces else ""
    outputs = "\n".join(f'      <Unknown index="{k}"{dependencies}/>'
                        for k, v in enumerate(VARIABLES, start=1) if v.causality == "output")
    derivative_rows = [f'      <Unknown index="{k}"/>'
                       for k, v in enumerate(VARIABLES, start=1) if v.derivative_of is not None]
    derivatives = initial_derivatives = ""
    if "ModelExchange" in interfaces:
        derivatives = "\n    <Derivatives>\n" + "\n".join(derivative_rows) + "\n    </Derivatives>"
        initial_derivatives = "\n" + "\n".join(derivative_rows)
    sources = f"""
    <SourceFiles>
      <File name="{SOURCE.name}"/>
    </SourceFiles>"""
    capabilities = 'canGetAndSetFMUstate="true" canSerializeFMUstate="false" canNotUseMemoryManagementFunctions="true"'
    elements = []
    if "ModelExchange" in interfaces:
        elements.append(f'  <ModelExchange modelIdentifier="{MODEL_IDENTIFIER}" {capabilities}>{sources}\n'
                        '  </ModelExchange>')
    if "CoSimulation" in interfaces:
        elements.append(f'  <CoSimulation modelIdentifier="{MODEL_IDENTIFIER}" '
                        f'canHandleVariableCommunicationStepSize="true"\n    {capabilities}>{sources}\n'
                        '  </CoSimulation>')
    interface_elements = "\n".join(elements)
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{MODEL_IDENTIFIER}" guid="{guid}"
  description="DC motor with smoothed Coulomb friction (hand-written C; co-simulation: RK4 on 0.5 ms substeps)"
  generationTool="tapmuscle.diagnosis.foreign_fmus.dc_motor" variableNamingConvention="flat"
  numberOfEventIndicators="0">
{interface_elements}
  <UnitDefinitions>
{units}
  </UnitDefinitions>
  <LogCategories>
{categories}
  </LogCategories>
  <DefaultExperiment startTime="0" stopTime="10" stepSize="0.05"/>
  <ModelVariables>
{variables}
  </ModelVariables>
  <ModelStructure>
    <Outputs>
{outputs}
    </Outputs>{derivatives}
    <InitialUnknowns>
{outputs}{initial_derivatives}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def _check_platform() -> None:
    # linux64 holds the building machine's binary, x86-64 or aarch64 alike (FMI 2.0 has no folder for
    # aarch64; FMI tools use linux64 for every 64-bit Linux)
    if not (sys.platform.startswith("linux") and sys.maxsize > 2**32):
        raise RuntimeError(f"build_dc_motor_fmu builds binaries/linux64 only (64-bit Linux); this is "
                           f"{sys.platform} {platform.machine()}")


def _compile(library: Path) -> None:
    """gcc dc_motor.c into the shared library ``library``; RuntimeError with gcc's stderr on failure."""
    gcc = shutil.which("gcc")
    if gcc is None:
        raise RuntimeError(f"gcc is needed to compile {SOURCE.name} into the DcMotor FMU, and it is not on PATH")
    headers = Path(fmpy.__file__).parent / "c-code"  # fmpy ships the FMI 2.0 headers
    command = [gcc, "-shared", "-fPIC", "-O2", "-std=c99", f"-I{headers}", "-o", str(library), str(SOURCE), "-lm"]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"gcc failed to compile {SOURCE} (exit status {result.returncode}):\n"
                           f"{' '.join(command)}\n{result.stderr.strip()}")


def _zip_atomically(tree: Path, target: Path) -> None:
    """Zip the folder ``tree`` to ``target`` through a temporary file in the same folder, so that a
    reader sees the old FMU or the new one, never a partly written one."""
    fd, staged = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    os.chmod(staged, 0o644)  # mkstemp's 0600 would make the FMU private to this user
    try:
        with zipfile.ZipFile(staged, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for path in sorted(p for p in tree.rglob("*") if p.is_file()):
                z.write(path, path.relative_to(tree).as_posix())
        os.replace(staged, target)
    except BaseException:
        Path(staged).unlink(missing_ok=True)
        raise


def build_dc_motor_fmu(out_dir: str | Path, *, interfaces: Sequence[str] = ("CoSimulation",)) -> Path:
    """Compile ``dc_motor.c`` and pack ``out_dir/DcMotor.fmu``.

    Parameters
    ----------
    out_dir
        Folder of the FMU; created if missing. An existing ``DcMotor.fmu`` there is replaced atomically.
    interfaces
        The interfaces the model description offers, any of :data:`INTERFACES` (the binary has both).

    Returns
    -------
    Path
        The path of ``DcMotor.fmu``.

    Raises
    ------
    RuntimeError
        Not on 64-bit Linux, gcc missing, or gcc failing (the message carries gcc's stderr).
    ValueError
        ``interfaces`` names none or an unknown one.
    """
    _check_platform()
    description = model_description(_guid(SOURCE.read_text(encoding="utf-8")), interfaces)  # checks interfaces first
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="dc_motor_fmu_") as tmp:
        tree = Path(tmp)
        (tree / "binaries" / "linux64").mkdir(parents=True)
        (tree / "sources").mkdir()
        _compile(tree / "binaries" / "linux64" / f"{MODEL_IDENTIFIER}.so")
        shutil.copyfile(SOURCE, tree / "sources" / SOURCE.name)
        (tree / "modelDescription.xml").write_text(description, encoding="utf-8")
        target = out_dir / f"{MODEL_IDENTIFIER}.fmu"
        _zip_atomically(tree, target)
    return target
