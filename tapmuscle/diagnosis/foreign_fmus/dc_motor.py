"""DcMotor: an FMI 2.0 co-simulation FMU of a DC motor with Coulomb friction, written in C.

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
substeps, so any communication step ``h > 0`` works. The FMU can get and set its state
(``canGetAndSetFMUstate``) but not serialize it.

:func:`build_dc_motor_fmu` compiles the C source with gcc against fmpy's FMI 2.0 headers (Linux
x86_64 only) and writes ``DcMotor.fmu``.
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
from typing import NamedTuple

import fmpy

__all__ = ["build_dc_motor_fmu", "MODEL_IDENTIFIER", "VARIABLES"]

MODEL_IDENTIFIER = "DcMotor"
SOURCE = Path(__file__).with_name("dc_motor.c")


class Variable(NamedTuple):
    """One ScalarVariable of modelDescription.xml (all are Real)."""

    name: str
    value_reference: int
    causality: str
    start: float | None  # None: calculated by the FMU (the outputs)
    unit: str
    description: str


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
)

#: SI base-unit exponents of every unit the variables use (FMI 2.0 <BaseUnit> attributes).
_UNITS = {
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "A": {"A": 1},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
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
    return f'    <ScalarVariable {attributes}>\n      <Real unit="{v.unit}"{start}/>\n    </ScalarVariable>'


def model_description(guid: str) -> str:
    """modelDescription.xml of DcMotor.

    Parameters
    ----------
    guid
        The GUID compiled into the binary.

    Returns
    -------
    str
        The XML text.
    """
    units = "\n".join(
        f'    <Unit name="{name}"><BaseUnit ' + " ".join(f'{k}="{e}"' for k, e in exponents.items()) + "/></Unit>"
        for name, exponents in _UNITS.items())
    categories = "\n".join(f'    <Category name="{name}" description="{text}"/>' for name, text in _LOG_CATEGORIES.items())
    variables = "\n".join(_scalar_variable(v) for v in VARIABLES)
    # ModelStructure indices are 1-based positions in ModelVariables. The outputs are states, so
    # they depend on no input directly (dependencies=""), and at initialization they are simply 0.
    outputs = "\n".join(f'      <Unknown index="{k}" dependencies=""/>'
                        for k, v in enumerate(VARIABLES, start=1) if v.causality == "output")
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{MODEL_IDENTIFIER}" guid="{guid}"
  description="DC motor with smoothed Coulomb friction (hand-written C, RK4 on 0.5 ms substeps)"
  generationTool="tapmuscle.diagnosis.foreign_fmus.dc_motor" variableNamingConvention="flat"
  numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="{MODEL_IDENTIFIER}" canHandleVariableCommunicationStepSize="true"
    canGetAndSetFMUstate="true" canSerializeFMUstate="false" canNotUseMemoryManagementFunctions="true">
    <SourceFiles>
      <File name="{SOURCE.name}"/>
    </SourceFiles>
  </CoSimulation>
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
    </Outputs>
    <InitialUnknowns>
{outputs}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def _check_platform() -> None:
    if not (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")):
        raise RuntimeError(f"build_dc_motor_fmu builds binaries/linux64 only (Linux x86_64); this is "
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


def build_dc_motor_fmu(out_dir: str | Path) -> Path:
    """Compile ``dc_motor.c`` and pack ``out_dir/DcMotor.fmu``.

    Parameters
    ----------
    out_dir
        Folder of the FMU; created if missing. An existing ``DcMotor.fmu`` there is replaced atomically.

    Returns
    -------
    Path
        The path of ``DcMotor.fmu``.

    Raises
    ------
    RuntimeError
        Not on Linux x86_64, gcc missing, or gcc failing (the message carries gcc's stderr).
    """
    _check_platform()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    source = SOURCE.read_text()
    with tempfile.TemporaryDirectory(prefix="dc_motor_fmu_") as tmp:
        tree = Path(tmp)
        (tree / "binaries" / "linux64").mkdir(parents=True)
        (tree / "sources").mkdir()
        _compile(tree / "binaries" / "linux64" / f"{MODEL_IDENTIFIER}.so")
        shutil.copyfile(SOURCE, tree / "sources" / SOURCE.name)
        (tree / "modelDescription.xml").write_text(model_description(_guid(source)), encoding="utf-8")
        target = out_dir / f"{MODEL_IDENTIFIER}.fmu"
        _zip_atomically(tree, target)
    return target
