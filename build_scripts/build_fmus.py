"""Build ``MusclePlant.fmu`` (and, when present, ``AMPCController.fmu``) with pythonfmu.

Each FMU carries its slave script, the numerics package it wraps and the shared ``fmi_slave`` shell
in ``resources/``: the project's code travels inside the FMU; the host needs a Python with numpy
(and scipy, osqp for the controller) and pythonfmu's runtime, which pythonfmu also packs.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

__all__ = ["FMUS", "build_fmus"]

ROOT = Path(__file__).resolve().parents[1]

#: FMU name -> (slave script, packages shipped in resources)
FMUS: dict[str, tuple[str, tuple[str, ...]]] = {
    "MusclePlant": ("fmu_plant/plant_slave.py", ("fmu_plant", "fmi_slave")),
}


def _clean_copy(src: Path, dst: Path) -> None:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


def build_fmus(out: str | Path, names: tuple[str, ...] | None = None) -> list[Path]:
    """Build the FMUs into ``out``; returns their paths. Each FMU is built in a temporary folder and
    moved into place whole, so a failed build leaves no partial file."""
    from pythonfmu.builder import FmuBuilder

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    built = []
    for name in names or tuple(FMUS):
        script, packages = FMUS[name]
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            for pkg in packages:
                _clean_copy(ROOT / pkg, tmp / "src" / pkg)
            fmu = FmuBuilder.build_FMU(ROOT / script, dest=tmp, project_files=[tmp / "src" / p for p in packages])
            target = out / f"{name}.fmu"
            shutil.move(str(fmu), str(target))
            built.append(target)
    return built
