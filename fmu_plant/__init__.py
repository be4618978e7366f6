"""Physical model of the tap-water McKibben muscle rig (paper section 2.4, Table 1).

Pure numerics: nothing here reads files or knows about FMI. The FMU slave (``fmu_plant.plant_slave``)
and the command line are thin shells around :class:`Plant`.
"""

from .effects import Effect
from .parameters import (FrictionParams, LoadParams, MuscleParams, PlantParams, SensorParams,
                         SolverParams, SupplyParams, ValveParams)
from .plant import LightLoadWarning, Measurement, Plant

__all__ = ["Plant", "Measurement", "LightLoadWarning", "Effect", "PlantParams", "ValveParams", "SupplyParams",
           "MuscleParams", "LoadParams", "FrictionParams", "SensorParams", "SolverParams"]
