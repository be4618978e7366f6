"""The ``--plant`` of ``tapmuscle diagnose``: a plant parameter file or a MusclePlant FMU.

* a plant parameter file (``tapmuscle/io/plant_file.py``), as ``tapmuscle record --params`` reads and
  ``diagnose`` writes;
* a ``MusclePlant`` FMU: its parameters' start values (``group.field``) are the model. The FMU is also
  run once with the recording's command (:func:`simulate_plant_fmu`) to check that the in-process
  re-simulations the fits use are the FMU's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from fmu_plant import PlantParams
from tapmuscle.io.plant_file import PlantFileError, read_plant_file

__all__ = ["PlantSourceError", "load_plant", "simulate_plant_fmu"]


class PlantSourceError(PlantFileError):
    """A ``--plant`` that cannot be read; the message names the file (and key or line)."""


def load_plant(path: str | Path) -> tuple[PlantParams, str]:
    """``(parameters, kind)`` of a plant file (``kind`` is ``"fmu"`` or ``"json"``).

    Parameters
    ----------
    path : str or Path
        A MusclePlant ``.fmu`` or a plant parameter ``.json``.
    """
    path = Path(path)
    if path.is_dir():
        raise PlantSourceError(f"--plant {path}: a folder, not a MusclePlant .fmu or a plant .json")
    if not path.is_file():
        raise PlantSourceError(f"--plant {path}: no such file (a MusclePlant .fmu or a plant .json)")
    if path.suffix.lower() == ".fmu":
        from fmpy import read_model_description

        from tapmuscle.cosim.fmu_file import check_fmu_file
        from tapmuscle.cosim.spec import ScenarioError

        try:  # before the diagnosis: its FMU check would load the binary at the end
            check_fmu_file(path)
        except ScenarioError as exc:
            raise PlantSourceError(f"--plant {exc}") from None

        try:
            md = read_model_description(str(path))
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad FMU
            raise PlantSourceError(f"--plant {path}: not a readable FMU: {exc}") from None
        if md.modelName != "MusclePlant":
            raise PlantSourceError(f"--plant {path}: a {md.modelName} FMU, expected MusclePlant")
        group_names = set(PlantParams().to_dict())
        values = {v.name: float(v.start) for v in md.modelVariables
                  if v.causality == "parameter" and v.name.partition(".")[0] in group_names}
        try:
            return PlantParams().with_values(**values), "fmu"
        except ValueError as exc:
            raise PlantSourceError(f"--plant {path}: {exc}") from None
    return read_plant_file(path, "--plant"), "json"


def simulate_plant_fmu(path: str | Path, values: Mapping[str, float], u_v: np.ndarray, ts_s: float,
                       load_n: np.ndarray | None = None) -> np.ndarray:
    """Run a MusclePlant FMU with parameters ``values`` and the command ``u_v`` held over each ``ts_s``;
    the encoder output per sample [mm] (row ``k`` before the step that applies ``u(k)``).

    Parameters
    ----------
    path : str or Path
        The MusclePlant FMU.
    values : mapping of str to float
        Its parameters (``group.field`` -> value); ``supply.supply_pressure_mpa`` also sets its
        input ``supply_pressure``, and ``load.load_n`` its input ``load_force`` when ``load_n``
        is not given.
    u_v : ndarray
        The command [V], one value per sample.
    ts_s : float
        Sampling period [s].
    load_n : ndarray, optional
        The load [N] per sample, set as the FMU's input ``load_force`` before each step.
    """
    from tapmuscle.cosim.master import FmuInstance
    from tapmuscle.interrupts import held_interrupts

    with held_interrupts() as held:  # Ctrl-C between FMI calls, not inside the FMU's step
        inst = FmuInstance(path, "diagnose.plant", role="plant")
        try:
            inst.set_parameters(dict(values), where=f"{path}: parameter '")
            # the FMU's inputs set the load and the supply pressure (its parameters of the same names are unused)
            inputs = {"load_force": float(load_n[0]) if load_n is not None else values.get("load.load_n"),
                      "supply_pressure": values.get("supply.supply_pressure_mpa")}
            inst.set_parameters({k: float(v) for k, v in inputs.items() if v is not None}, where=f"{path}: input '",
                               inputs=True)
            inst.start()
            fmu = inst.fmu
            vr_u, vr_l, vr_w = inst.vr("u"), inst.vr("l"), inst.vr("load_force")
            n = len(u_v)
            out = np.empty(n)
            out[0] = fmu.getReal([vr_l])[0]
            for k in range(n - 1):
                if load_n is not None:
                    fmu.setReal([vr_w], [float(load_n[k])])
                fmu.setReal([vr_u], [float(u_v[k])])
                inst._call("doStep", lambda: fmu.doStep(k * ts_s, ts_s), k * ts_s)
                out[k + 1] = fmu.getReal([vr_l])[0]
                if held.pending:
                    held.raise_if_pending()
            return out
        except BaseException as exc:
            inst.failed(getattr(exc, "status", 0))  # an FMI call's failure: freed as its status allows
            raise
        finally:
            inst.free()
