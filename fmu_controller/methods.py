"""The paper's four displacement controllers by name, and the controller FMU's codes for them.

Section 3's MPC with a unique coincidence point and MPC with the servo mechanism (Eq. 15-20), each
with fixed (MPC) or adaptive (AMPC, Algorithm 1) parameters. A module of its own, without the
controllers' numerics (osqp, scipy), so that what only names a method (a scenario file's check, the
co-simulation master's reading of the FMU's ``method`` parameter) loads none of them.
"""

from __future__ import annotations

__all__ = ["METHODS", "METHOD_CODES"]

#: The methods, as :class:`~fmu_controller.displacement_control.ControllerSettings` ``method`` names them.
METHODS = ("mpc_ucp", "mpc_servo", "ampc_ucp", "ampc_servo")
#: The controller FMU's ``method`` parameter (an Integer) -> method name.
METHOD_CODES: dict[int, str] = {i + 1: m for i, m in enumerate(METHODS)}
