"""``PIController``: a PI displacement controller as an FMI 2.0 co-simulation FMU of one's own.

An example of a controller FMU that is not the project's, for ``[controller] interface`` in a
scenario file (``own_controller.toml`` beside this file; docs/fmu.md, "A controller FMU of your
own"). Build it with pythonfmu, from this folder::

    pythonfmu build -f pi_controller.py

and run the scenario with ``tapmuscle run own_controller.toml --out out/own``. It imports only the
standard library and pythonfmu, so it runs in any Python that has pythonfmu.

Law, at each communication point ``t_k`` with the step ``h`` [s]::

    e(k) = r(k) - y(k)                              [mm]
    v(k) = u_bias + Kp e(k) + I(k)                  [V]
    u(k) = min(max(v(k), u_min), u_max)             the valve's range
    I(k+1) = I(k) + Ki h e(k)                       unless anti_windup and u(k) is at a limit that
                                                    e(k) pushes further into

Variables: inputs ``y`` (the measured displacement, mm) and ``r`` (the reference, mm); output ``u``
(the valve command, V); parameters ``Kp`` [V/mm], ``Ki`` [V/(mm s)], ``u_bias``, ``u_min``,
``u_max`` [V] and the Boolean ``anti_windup``. A non-finite input is answered with fmi2Discard and
the command held, so a host never receives NaN.
"""

from __future__ import annotations

import math

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real
from pythonfmu.enums import Fmi2Status


class PIController(Fmi2Slave):
    """PI with conditional integration at the valve's limits (module docstring)."""

    author = "tapmuscle example"
    description = "PI displacement controller with conditional integration (an FMU of one's own)"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.y = 0.0
        self.r = 0.0
        self.u = 5.0
        self.Kp = 0.15
        self.Ki = 0.6
        self.u_bias = 5.0
        self.u_min = 0.0
        self.u_max = 10.0
        self.anti_windup = True
        self.integral = 0.0
        self.register_variable(Real("y", causality=Fmi2Causality.input, description="measured displacement [mm]"))
        self.register_variable(Real("r", causality=Fmi2Causality.input, description="reference displacement [mm]"))
        self.register_variable(Real("u", causality=Fmi2Causality.output, description="valve command [V]"))
        for name, text in (("Kp", "proportional gain [V/mm]"), ("Ki", "integral gain [V/(mm s)]"),
                           ("u_bias", "command at zero error and integral [V]"),
                           ("u_min", "lowest command [V]"), ("u_max", "highest command [V]")):
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable, description=text))
        self.register_variable(Boolean("anti_windup", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.tunable,
                                       description="hold the integral while the command sits at a limit the error "
                                                   "pushes further into"))

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not (math.isfinite(self.y) and math.isfinite(self.r)):
            self.log(f"input y = {self.y!r} or r = {self.r!r} is not finite at t = {current_time:g} s; "
                     "the command is held", status=Fmi2Status.error)  # the step is discarded
            return False
        e = self.r - self.y
        v = self.u_bias + self.Kp * e + self.integral
        u = min(max(v, self.u_min), self.u_max)
        pushed = (v > self.u_max and e > 0.0) or (v < self.u_min and e < 0.0)
        if not (self.anti_windup and pushed):
            self.integral += self.Ki * step_size * e
        self.u = u
        return True
