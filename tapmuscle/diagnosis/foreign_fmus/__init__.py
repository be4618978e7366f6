"""Small FMI 2.0 FMUs of other systems, not built by tapmuscle's FMU build, that prove ``tapmuscle diagnose``
on foreign plants: a DC motor with Coulomb friction in C (:func:`build_dc_motor_fmu`) and a thermal
two-mass model with two inputs in pythonfmu (:func:`build_thermal_fmu`)."""

from .dc_motor import build_dc_motor_fmu
from .thermal import build_thermal_fmu

__all__ = ["build_dc_motor_fmu", "build_thermal_fmu"]
