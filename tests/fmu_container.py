"""The closed loop as one FMU made by fmu-manipulation-toolbox's ``fmucontainer`` (a C++ master inside
the FMU that steps the embedded FMUs), for the tests that run it in fmpy on Linux and on Windows."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

TS_S = 0.1


def build_parallel_container(fmus: dict[str, Path], folder: Path, name: str = "TapLoop.fmu") -> Path:
    """Both FMUs (``fmus``: name -> .fmu) copied into ``folder`` and embedded in ``folder/name``, in the
    container's default parallel mode (every embedded FMU stepped on the previous outputs, one thread),
    the parameters exposed (``-auto-parameter``), outputs ``l`` and ``u``."""
    for fmu_name, path in fmus.items():
        if Path(path).resolve() != (folder / f"{fmu_name}.fmu").resolve():
            shutil.copy(path, folder / f"{fmu_name}.fmu")
    (folder / "loop.json").write_text(json.dumps({
        "name": name, "step_size": TS_S, "sequential": False,
        "fmu": ["MusclePlant.fmu", "AMPCController.fmu"],
        "link": [["MusclePlant.fmu", "l", "AMPCController.fmu", "l"], ["AMPCController.fmu", "u", "MusclePlant.fmu", "u"]],
        "output": [["MusclePlant.fmu", "l", "l"], ["AMPCController.fmu", "u", "u"]]}))
    return _fmucontainer(folder, name, "-container", "loop.json", "-auto-parameter")


def build_container_from_ssp(ssp: Path, folder: Path) -> Path:
    """The loop of an SSP archive (``tapmuscle build --ssp``) as one FMU, ``folder/<archive's stem>.fmu``,
    stepped at Ts in the container's default parallel mode. fmucontainer reads the system structure,
    not the parameter bindings."""
    shutil.copy(ssp, folder / ssp.name)
    return _fmucontainer(folder, f"{ssp.stem}.fmu", "-container", f"{ssp.name}:{TS_S}")


def _fmucontainer(folder: Path, name: str, *args: str) -> Path:
    """Run fmu-manipulation-toolbox's ``fmucontainer`` in ``folder`` (its FMU directory); ``folder/name``."""
    cli = [sys.executable, "-c", "from fmu_manipulation_toolbox.cli.fmucontainer import fmucontainer; fmucontainer()"]
    proc = subprocess.run([*cli, *args, "-fmu-directory", str(folder)], cwd=folder, capture_output=True, text=True,
                          timeout=300)
    assert (folder / name).is_file(), proc.stdout[-2000:] + proc.stderr[-2000:]
    return folder / name
