"""A pythonfmu slave that never crashes its host and never emits NaN.

pythonfmu turns an exception escaping ``do_step`` into fmi2Fatal; a host may then abandon the whole
simulation. :class:`SafeSlave` runs the slave's step inside a guard: any problem (bad input, bad step
size, bad parameter, a numerical failure) is logged at error level with a message naming the
offending variable and value, the outputs keep their last valid values, and ``do_step`` returns
False, which pythonfmu reports as fmi2Discard. The host can fix the input and step again.

Parameters are kept in one table (``self._par``) registered from a list of
``(name, start, unit, description)``; full dynamic state is saved and restored through
:meth:`SafeSlave.numerics_state` / :meth:`SafeSlave.restore_numerics_state`, so FMI
get/set/serialize FMU state restores everything, not just the registered variables.
"""

from __future__ import annotations

import math
import traceback
from typing import Any, Iterable

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

__all__ = ["SafeSlave", "SlaveInputError"]


class SlaveInputError(ValueError):
    """A bad input, parameter or step size; the message names it."""


class SafeSlave(Fmi2Slave):
    """Base of the project's FMU slaves (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._par: dict[str, float] = {}
        self._int_par: dict[str, int] = {}
        self._failed = False

    # ------------------------------------------------------------------ registration
    def add_real_parameters(self, table: Iterable[tuple[str, float, str, str]]) -> None:
        """Register fixed Real parameters ``(name, start, unit, description)``."""
        for name, start, _unit, description in table:
            self._par[name] = float(start)
            self.register_variable(Real(
                name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                description=description,
                getter=lambda n=name: self._par[n],
                setter=lambda v, n=name: self._par.__setitem__(n, float(v))), nested=False)

    def add_integer_parameter(self, name: str, start: int, description: str) -> None:
        self._int_par[name] = int(start)
        self.register_variable(Integer(
            name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed, description=description,
            getter=lambda: self._int_par[name],
            setter=lambda v: self._int_par.__setitem__(name, int(v))), nested=False)

    # ------------------------------------------------------------------ guards
    @staticmethod
    def finite(name: str, value: float, lo: float = -math.inf, hi: float = math.inf) -> float:
        """``value`` as float, or :class:`SlaveInputError` naming ``name`` if not finite or outside lo..hi."""
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise SlaveInputError(f"{name} = {value!r} is not a number") from None
        if not math.isfinite(v):
            raise SlaveInputError(f"{name} = {v!r} is not finite")
        if not lo <= v <= hi:
            raise SlaveInputError(f"{name} = {v!r} is outside {lo:g}..{hi:g}")
        return v

    def fail(self, message: str) -> bool:
        """Log ``message`` at error level and report the step as discarded."""
        self.log(message, status=Fmi2Status.error)
        return False

    def exit_initialization_mode(self) -> None:
        try:
            self.initialize_numerics()
            self._failed = False
        except Exception as exc:  # noqa: BLE001 - reported to the host, never raised into it
            self._failed = True
            self.log(f"initialisation failed: {exc}", status=Fmi2Status.error)

    def do_step(self, current_time: float, step_size: float) -> bool:
        try:
            if self._failed:
                return self.fail("the FMU was not initialised (see the previous error); fix the parameters and "
                                 "instantiate again")
            self.finite("step size", step_size, 1e-9, 3600.0)
            self.step_numerics(float(current_time), float(step_size))
            return True
        except SlaveInputError as exc:
            return self.fail(f"t = {current_time:g} s: {exc}; outputs keep their last values")
        except Exception as exc:  # noqa: BLE001
            return self.fail(f"t = {current_time:g} s: internal error {type(exc).__name__}: {exc}\n"
                             f"{traceback.format_exc(limit=3)}")

    # ------------------------------------------------------------------ state
    def _get_fmu_state(self) -> dict[str, Any]:
        return {"variables": super()._get_fmu_state(), "numerics": self.numerics_state(),
                "failed": self._failed}

    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        super()._set_fmu_state(state["variables"])
        self.restore_numerics_state(state["numerics"])
        self._failed = bool(state["failed"])

    # ------------------------------------------------------------------ to implement
    def initialize_numerics(self) -> None:
        """Build the numerics from the parameters (raise SlaveInputError naming a bad one)."""
        raise NotImplementedError  # abstract: each slave implements it

    def step_numerics(self, t_s: float, dt_s: float) -> None:
        """Validate inputs (raise SlaveInputError naming a bad one), advance, set outputs."""
        raise NotImplementedError  # abstract

    def numerics_state(self) -> Any:
        """JSON-serialisable snapshot of everything dynamic."""
        raise NotImplementedError  # abstract

    def restore_numerics_state(self, state: Any) -> None:
        raise NotImplementedError  # abstract
