"""The shell shared by the FMU slaves (`fmu_plant.plant_slave`, `fmu_controller.controller_slave`).

It travels inside both FMUs' resources. It knows FMI (pythonfmu) and nothing of muscles: the slaves
put their numerics behind it.

Importing it first prepares the interpreter for the FMU (:func:`fmi_slave.native_host.setup`: the
recorded site-packages in non-Python hosts, a clear message for a missing numpy/scipy/osqp) before
``base`` imports pythonfmu and before the slave imports its numerics; see docs/fmu-native-hosts.md.
"""

from . import native_host

native_host.setup()

from .base import SafeSlave  # noqa: E402 - after native_host.setup(), on purpose

__all__ = ["SafeSlave"]
