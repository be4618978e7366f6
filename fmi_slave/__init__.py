"""The shell shared by the FMU slaves (`fmu_plant.plant_slave`, `fmu_controller.controller_slave`).

It travels inside both FMUs' resources. It knows FMI (pythonfmu) and nothing of muscles: the slaves
put their numerics behind it.
"""

from .base import SafeSlave

__all__ = ["SafeSlave"]
