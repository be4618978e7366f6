"""Plant parameter files: ``{"note": ..., "plant": {group: {field: value}}}`` (JSON).

``tapmuscle record --params`` and ``tapmuscle diagnose --plant`` read them; ``diagnose`` writes the
calibrated one. Every ``group.field`` is also a parameter of the MusclePlant FMU. The groups are
those of :class:`~fmu_plant.PlantParams`, the effects the diagnosis fits (``delay``, ``dead_zone``,
...) among them; a group or field the file leaves out keeps its default, so ``{"plant": {}}`` is the
nominal plant (``PlantParams()``, the calibrated rig of docs/plant.md, every effect off).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from fmu_plant import PlantParams
from fmu_plant.user_warning import warn_at_caller
from tapmuscle.errors import TapmuscleError
from tapmuscle.io.json_file import read_json
from tapmuscle.io.recording import atomic_write_text

__all__ = ["PlantFileError", "read_plant_file", "write_plant_file", "plant_file_text"]


class PlantFileError(TapmuscleError):
    """A plant file that cannot be read; the message names the option, the file and the line or key."""


def read_plant_file(path: str | os.PathLike, option: str | None = None) -> PlantParams:
    """The plant parameters in a plant parameter file (module docstring), as ``tapmuscle diagnose``
    writes its ``calibrated_plant.json``.

    Parameters
    ----------
    path : path
        The JSON file: its ``"plant"`` mapping of groups, or the whole document if it has none.
    option : str, optional
        The command-line option (``--params``) or scenario key the file was given as, put before the
        file's name in an error.

    Returns
    -------
    PlantParams
        The file's values, the defaults for what it leaves out; the effects it switches on included
        (``Plant(params)`` simulates them).

    Raises
    ------
    PlantFileError
        No such file, not JSON (its line), an unknown group or field or a value out of range (named),
        or a diagnosis report (``diagnosis.json``) given for the plant file beside it.
    """
    where = f"{option} {path}" if option else str(path)
    data = read_json(path, PlantFileError, where=where,
                     missing=f"{option + ': ' if option else ''}no such file {str(path)!r}")
    if isinstance(data, dict) and {"verdict", "findings"} <= set(data) and not isinstance(data.get("plant"), dict):
        # a report's "plant" names the plant it diagnosed
        diagnosed = f"; the plant it diagnosed is {data['plant']}" if isinstance(data.get("plant"), str) else ""
        raise PlantFileError(f"{where}: a diagnosis report, not a plant parameter file (the calibrated plant "
                             f"is {Path(path).with_name('calibrated_plant.json')}{diagnosed})")
    if isinstance(data, dict) and isinstance(data.get("fmu"), str) and isinstance(data.get("parameters"), dict) \
            and not isinstance(data.get("plant"), dict):
        # what diagnose writes for a plant FMU of one's own: that FMU's parameters, not MusclePlant's
        raise PlantFileError(f"{where}: the calibration of a plant FMU of one's own ({data['fmu']}), not a "
                             "MusclePlant parameter file: set its 'parameters' on that FMU where you run it (its "
                             "'note' says how)")
    try:
        params = PlantParams.from_dict(data.get("plant", data) if isinstance(data, dict) else data)
    except ValueError as exc:
        raise PlantFileError(f"{where}: {exc}") from None
    _warn_if_another_unit(params, where)
    return params


#: Sizes no McKibben muscle rig has, which a value in another unit gives: ``(key, lo, hi, guess)``.
#: The parameters' bounds (fmu_plant/parameters.py) refuse values too large by orders of magnitude;
#: these catch the small side, where a value in metres or micrometres still simulates (a 0.4-mm
#: muscle contracting 0.17 mm).
IMPLAUSIBLE = (
    ("muscle.rest_length_mm", 10.0, None, "metres or centimetres?"),
    ("muscle.radius_mm", 1.0, None, "metres or centimetres?"),
    ("sensor.encoder_resolution_mm", None, 1.0, "micrometres?"),
)


def _warn_if_another_unit(params: PlantParams, where: str) -> None:
    """Warn of each :data:`IMPLAUSIBLE` value in ``params``, read from ``where``."""
    for key, lo, hi, guess in IMPLAUSIBLE:
        value = params.value(key)
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            bound = f"under {lo:g}" if lo is not None and value < lo else f"over {hi:g}"
            warn_at_caller(f"{where}: {key} = {value:g} mm is {bound} mm, which no muscle rig has: {guess} "
                           "(the file's lengths are in mm)", UserWarning)


def plant_file_text(params: PlantParams, note: str) -> str:
    """The JSON text of a plant parameter file for ``params``.

    Parameters
    ----------
    params : PlantParams
        The plant's parameters.
    note : str
        The file's ``note``.
    """
    return json.dumps({"note": note, "plant": params.to_dict()}, indent=2) + "\n"


def write_plant_file(path: str | os.PathLike, params: PlantParams, *, note: str = "") -> None:
    """Write a plant parameter file that :func:`read_plant_file`, ``tapmuscle record --params``,
    ``tapmuscle diagnose --plant`` and a scenario's ``plant.parameters_file`` read.

    Parameters
    ----------
    path : path
        The JSON file, written atomically (whole or not at all).
    params : PlantParams
        The parameters; every group and field is written.
    note : str
        Where they come from (the file's ``"note"``).

    Raises
    ------
    TypeError
        ``params`` is not a :class:`~fmu_plant.PlantParams`.
    """
    if not isinstance(params, PlantParams):
        raise TypeError(f"params must be a PlantParams, got {type(params).__name__} {params!r:.60}")
    if not isinstance(note, str):
        raise TypeError(f"note must be a str, got {type(note).__name__}")
    atomic_write_text(path, plant_file_text(params, note))
