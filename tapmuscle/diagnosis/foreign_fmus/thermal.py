"""Build ``ThermalTwoMass.fmu``: a thermal two-mass model with two inputs, a "foreign" FMU for the diagnosis.

The FMU (FMI 2.0 co-simulation, pythonfmu; slave class in :mod:`.thermal_slave`, self-contained)
models two lumped masses, each with a heater, coupled to each other and to ambient::

    C1 dT1/dt = P1 - G12 (T1 - T2) - G1a (T1 - T_amb)
    C2 dT2/dt = P2 + G12 (T1 - T2) - G2a (T2 - T_amb)

=========  ==========  =========  ==========================================  =======
name       causality   unit       meaning                                     default
=========  ==========  =========  ==========================================  =======
``P1``     input       W          heater power on mass 1                      0
``P2``     input       W          heater power on mass 2                      0
``T1``     output      degC       temperature of mass 1
``T2``     output      degC       temperature of mass 2
``C1``     parameter   J/K        heat capacity of mass 1 (> 0)               500
``C2``     parameter   J/K        heat capacity of mass 2 (> 0)               800
``G12``    parameter   W/K        conductance between the masses (>= 0)       2.0
``G1a``    parameter   W/K        conductance mass 1 to ambient (>= 0)        1.0
``G2a``    parameter   W/K        conductance mass 2 to ambient (>= 0)        0.5
``T_amb``  parameter   degC       ambient temperature                         20
``T1_0``   parameter   degC       initial temperature of mass 1               20
``T2_0``   parameter   degC       initial temperature of mass 2               20
=========  ==========  =========  ==========================================  =======

Value references follow that order (0 .. 11). Parameters are ``fixed``: set them after
``fmi2Instantiate`` or ``fmi2Reset`` and before ``fmi2ExitInitializationMode``. The inputs are held
constant over each communication step and the step is integrated exactly (closed-form matrix
exponential), so results do not depend on the step size beyond the input sampling. The model
description has a ``DefaultExperiment`` (0 .. 600 s, step 1 s).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from pythonfmu.builder import FmuBuilder

__all__ = ["build_thermal_fmu", "FMU_NAME", "SLAVE_SCRIPT"]

#: File name of the built FMU (pythonfmu names it after the slave class, its model identifier).
FMU_NAME = "ThermalTwoMass.fmu"
#: The pythonfmu slave script packed into the FMU.
SLAVE_SCRIPT = Path(__file__).with_name("thermal_slave.py")


def build_thermal_fmu(out_dir: str | Path) -> Path:
    """Build ``ThermalTwoMass.fmu`` into ``out_dir`` (created if missing) and return its path.

    The FMU is built in a temporary folder inside ``out_dir`` and moved into place with
    :func:`os.replace`, so a reader never sees a half-written file and an existing FMU of the same
    name is replaced atomically.

    Parameters
    ----------
    out_dir : str or Path
        Folder to write ``ThermalTwoMass.fmu`` into.

    Returns
    -------
    Path
        Path of the built FMU.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / FMU_NAME
    # pythonfmu's builder puts the script's folder at the front of sys.path and imports the script
    # as the top-level module ``thermal_slave``; undo both, so this process later loads the FMU's
    # own copy of the script and the folder of this package does not shadow other modules.
    saved_path = list(sys.path)
    had_module = "thermal_slave" in sys.modules
    with tempfile.TemporaryDirectory(prefix=".thermal-build-", dir=out_dir) as tmp:
        try:
            built = FmuBuilder.build_FMU(SLAVE_SCRIPT, dest=Path(tmp) / FMU_NAME)
        finally:
            sys.path[:] = saved_path
            if not had_module:
                sys.modules.pop("thermal_slave", None)
        os.replace(built, target)
    return target
