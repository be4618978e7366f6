"""Plant parameter files: ``{"note": ..., "plant": {group: {field: value}}}`` (JSON).

``tapmuscle record --params`` and ``tapmuscle diagnose --plant`` read them; ``diagnose`` writes the
calibrated one. Every ``group.field`` is also a parameter of the MusclePlant FMU.
"""

from __future__ import annotations

import json
from pathlib import Path

from fmu_plant import PlantParams
from tapmuscle.errors import TapmuscleError
from tapmuscle.io.json_file import read_json

__all__ = ["PlantFileError", "read_plant_file", "plant_file_text"]


class PlantFileError(TapmuscleError):
    """A plant file that cannot be read; the message names the option, the file and the line or key."""


def read_plant_file(path: str | Path, option: str) -> PlantParams:
    """The parameters in ``path`` (the ``"plant"`` mapping, or the whole document if it has none).

    Raises :class:`PlantFileError` prefixed by ``option`` (e.g. ``--params``).
    """
    data = read_json(path, PlantFileError, where=f"{option} {path}", missing=f"{option}: no such file {str(path)!r}")
    if isinstance(data, dict) and "plant" not in data and {"verdict", "findings"} <= set(data):
        raise PlantFileError(f"{option} {path}: a diagnosis report, not a plant parameter file (the calibrated plant "
                             f"is {Path(path).with_name('calibrated_plant.json')})")
    try:
        return PlantParams.from_dict(data.get("plant", data) if isinstance(data, dict) else data)
    except ValueError as exc:
        raise PlantFileError(f"{option} {path}: {exc}") from None


def plant_file_text(params: PlantParams, note: str) -> str:
    """The JSON text of a plant parameter file for ``params``."""
    return json.dumps({"note": note, "plant": params.to_dict()}, indent=2) + "\n"
