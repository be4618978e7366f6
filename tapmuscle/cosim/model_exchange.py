"""A model-exchange FMU stepped like a co-simulation one: inputs held over each communication
interval, the states integrated by fmpy's CVode (SUNDIALS, BDF with a dense linear solver).

What :func:`fmpy.simulate_fmu` does for model exchange, cut to the master's loop: the caller sets
the inputs at ``t_k`` and calls :meth:`ModelExchangeStepper.do_step` ``(t_k, h)``, which

1. enters event mode (a held input changes discontinuously at ``t_k``), iterates
   ``fmi2NewDiscreteStates`` to a fixed point and returns to continuous-time mode;
2. restarts CVode at ``t_k`` (its multistep history is not valid across the input's jump);
3. integrates to ``t_k + h``, stopping at the FMU's time events and state events (event
   indicators) and at a ``fmi2CompletedIntegratorStep`` that asks for event mode, handling each
   as in step 1.

A failing FMI call inside the solver's callbacks is kept and raised by :meth:`do_step` (an
exception cannot cross the ctypes callback), so the caller sees the FMU's message, not CVode's.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

__all__ = ["ModelExchangeStepper", "ModelExchangeError", "DEFAULT_RELATIVE_TOLERANCE"]

#: CVode's relative tolerance when the FMU's DefaultExperiment states none: tighter than fmpy's 1e-5,
#: because a diagnosis compares re-simulations whose differences are a fraction of the sensor noise.
DEFAULT_RELATIVE_TOLERANCE = 1e-7


class ModelExchangeError(RuntimeError):
    """An FMI call or the integration failed; the message names the call and the time."""


@functools.cache
def _solver_class() -> type:
    """fmpy's CVodeSolver with a right-hand side that calls the FMU's C functions directly.

    fmpy's own right-hand side goes through its status-checking wrappers and two ``ctypes.cast``
    per vector; CVode calls it about 40 times per sample, which made one re-simulation of a
    10-minute recording 2.5 s. Here a failing call returns CVode's "unrecoverable" code (-1)
    and the reason is kept for :meth:`ModelExchangeStepper.do_step`. Built once per process (it
    binds a SUNDIALS function).
    """
    import ctypes

    from fmpy.sundials import CVodeSolver
    from fmpy.sundials.libraries import sundials_nvecserial
    from fmpy.sundials.sundials_nvector import N_Vector

    try:  # fmpy >= 0.3.28 (SUNDIALS 7): error handlers live on the SUNContext
        from fmpy.sundials.libraries import sundials_core
        from fmpy.sundials.sundials_context import SUNContext, SUNContext_PushErrHandler
    except ImportError:  # older fmpy (SUNDIALS 5): its CVodeSetErrHandlerFn already replaced the printing default
        sundials_core = None

    data = sundials_nvecserial.N_VGetArrayPointer_Serial
    data.argtypes = [N_Vector]
    data.restype = ctypes.POINTER(ctypes.c_double)
    if sundials_core is not None:
        clear_handlers = sundials_core.SUNContext_ClearErrHandlers
        clear_handlers.argtypes = [SUNContext]

    class Solver(CVodeSolver):
        def __init__(self, fmu: Any, stepper: "ModelExchangeStepper", **kwargs: Any) -> None:
            # the raw ctypes functions, argtypes set by fmpy (fmpy 0.3.20-0.3.23 have no _functions: the
            # library's own attributes are those same function objects)
            functions = getattr(fmu, "_functions", None)
            raw = functions.__getitem__ if functions is not None else (lambda name: getattr(fmu.dll, name))
            self._component = fmu.component
            self._set_time_c = raw("fmi2SetTime")
            self._set_x_c = raw("fmi2SetContinuousStates")
            self._get_dx_c = raw("fmi2GetDerivatives")
            self._stepper = stepper
            super().__init__(**kwargs)
            # SUNDIALS' default handler prints every failure to stderr; a rejected candidate's failed
            # integration is expected and reported by do_step, so only fmpy's handler (which keeps
            # the message) stays
            if sundials_core is not None:
                clear_handlers(self.sunctx)
                SUNContext_PushErrHandler(self.sunctx, self.ehfun_, None)

        def f(self, t: float, y: Any, ydot: Any, user_data: Any) -> int:
            c, nx = self._component, self.nx
            if self.discrete:
                dx = data(ydot)
                for j in range(nx):
                    dx[j] = 0.0
                return 0 if self._set_time_c(c, t) <= 1 else self._fail("fmi2SetTime", t)
            if self._set_time_c(c, t) > 1:
                return self._fail("fmi2SetTime", t)
            if self._set_x_c(c, data(y), nx) > 1:
                return self._fail("fmi2SetContinuousStates", t)
            if self._get_dx_c(c, data(ydot), nx) > 1:
                return self._fail("fmi2GetDerivatives", t)
            return 0

        def _fail(self, name: str, t: float) -> int:
            if self._stepper.failure is None:
                self._stepper.failure = f"{name} failed at t = {t:.12g} s"
            return -1

    return Solver


class _NoInput:
    """The solver's input hook: inputs are held over the step, so nothing to apply between events."""

    def apply(self, time: float, continuous: bool = True, discrete: bool = True, after_event: bool = False) -> None:
        return None


class ModelExchangeStepper:
    """Steps one ``fmpy.fmi2.FMU2Model`` instance that has left initialization mode (event mode).

    Parameters
    ----------
    fmu : fmpy.fmi2.FMU2Model
        The instance, right after ``fmi2ExitInitializationMode``.
    model_description : fmpy.model_description.ModelDescription
        Its model description (numbers of states and event indicators).
    start_time : float
        The time at which it was initialised [s].
    relative_tolerance : float, optional
        CVode's relative tolerance (default: the DefaultExperiment's, else
        :data:`DEFAULT_RELATIVE_TOLERANCE`); the absolute one is it times each state's nominal.
    """

    def __init__(self, fmu: Any, model_description: Any, start_time: float = 0.0,
                 relative_tolerance: float | None = None) -> None:
        if relative_tolerance is None:
            de = model_description.defaultExperiment
            relative_tolerance = (float(de.tolerance) if de is not None and de.tolerance is not None
                                  else DEFAULT_RELATIVE_TOLERANCE)
        self.fmu = fmu
        self.time = float(start_time)
        self.failure: str | None = None
        self._needs_step_call = bool(model_description.modelExchange.needsCompletedIntegratorStep)
        self.next_event: float = math.inf
        self._event_iteration()
        self._call("fmi2EnterContinuousTimeMode", fmu.enterContinuousTimeMode)
        nx = model_description.numberOfContinuousStates
        self.solver = _solver_class()(fmu, self, nx=nx, nz=model_description.numberOfEventIndicators,
                                  get_x=self._guarded(fmu.getContinuousStates, "fmi2GetContinuousStates"),
                                  set_x=self._guarded(fmu.setContinuousStates, "fmi2SetContinuousStates"),
                                  get_dx=self._guarded(fmu.getDerivatives, "fmi2GetDerivatives", nan_fill=True),
                                  get_z=self._guarded(fmu.getEventIndicators, "fmi2GetEventIndicators", nan_fill=True),
                                  get_nominals=self._guarded(fmu.getNominalsOfContinuousStates,
                                                             "fmi2GetNominalsOfContinuousStates"),
                                  set_time=self._guarded(fmu.setTime, "fmi2SetTime"),
                                  input=_NoInput(), startTime=self.time, relativeTolerance=relative_tolerance,
                                  maxNumSteps=100_000)
        self._raise_failure()

    # ------------------------------------------------------------------ helpers
    def _call(self, name: str, fn: Any, *args: Any) -> Any:
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - fmpy raises FMICallException
            raise ModelExchangeError(f"{name} at t = {self.time:.12g} s failed: {exc}") from None

    def _guarded(self, fn: Any, name: str, nan_fill: bool = False) -> Any:
        """``fn`` for use inside CVode's callbacks: a failure is kept (and, for an output array,
        answered with NaN, so that CVode stops) instead of raised into ctypes."""
        def call(*args: Any) -> None:
            try:
                return fn(*args)
            except Exception as exc:  # noqa: BLE001 - see the docstring
                if self.failure is None:
                    self.failure = f"{name} failed: {exc}"
                if nan_fill and args[1]:  # (array pointer, length)
                    np.ctypeslib.as_array(args[0], (args[1],))[:] = np.nan
                return None
        return call

    def _raise_failure(self) -> None:
        if self.failure is not None:
            message, self.failure = self.failure, None
            raise ModelExchangeError(f"{message} (near t = {self.time:.12g} s)")

    def _event_iteration(self) -> None:
        """fmi2NewDiscreteStates until the FMU needs no more (event mode on entry and on return)."""
        for _ in range(1000):
            needed, terminate, _nom, _val, defined, next_time = self._call("fmi2NewDiscreteStates",
                                                                          self.fmu.newDiscreteStates)
            if terminate:
                raise ModelExchangeError(f"the FMU asked to terminate at t = {self.time:.12g} s")
            if not needed:
                self.next_event = float(next_time) if defined else math.inf
                return
        raise ModelExchangeError(f"fmi2NewDiscreteStates did not converge in 1000 iterations at t = {self.time:.12g} s")

    def _event(self) -> None:
        """Event mode at the current time, the event iteration, back to continuous time, CVode restarted."""
        self._call("fmi2EnterEventMode", self.fmu.enterEventMode)
        self._event_iteration()
        self._call("fmi2EnterContinuousTimeMode", self.fmu.enterContinuousTimeMode)
        self.solver.reset(self.time)
        self._raise_failure()

    # ------------------------------------------------------------------ stepping
    def do_step(self, t_s: float, h_s: float) -> None:
        """Integrate from ``t_s`` (the current time) to ``t_s + h_s`` with the inputs set now held.

        Raises
        ------
        ModelExchangeError
            An FMI call failed or CVode could not reach the end of the step (with the FMU's or
            CVode's message).
        """
        if not (h_s > 0.0 and math.isfinite(h_s)):
            raise ModelExchangeError(f"communication step {h_s!r} s from t = {t_s:.12g} s: must be finite and > 0")
        self.time = float(t_s)
        self._call("fmi2SetTime", self.fmu.setTime, self.time)
        self._event()
        end = self.time + h_s
        while self.time < end and not math.isclose(self.time, end, rel_tol=0.0, abs_tol=1e-12 * max(1.0, abs(end))):
            target = min(end, self.next_event)
            try:
                state_event, _roots, reached = self.solver.step(self.time, target)
            except RuntimeError as exc:
                self._raise_failure()
                raise ModelExchangeError(f"integration from t = {self.time:.12g} s failed: {exc}") from None
            self._raise_failure()
            self.time = float(reached)
            self._call("fmi2SetTime", self.fmu.setTime, self.time)
            step_event = False
            if self._needs_step_call:
                step_event, terminate = self._call("fmi2CompletedIntegratorStep", self.fmu.completedIntegratorStep)
                if terminate:
                    raise ModelExchangeError(f"the FMU asked to terminate at t = {self.time:.12g} s")
            time_event = math.isclose(self.time, self.next_event, rel_tol=0.0, abs_tol=1e-12 * max(1.0, abs(end)))
            if state_event or step_event or time_event:
                self._event()
        self.time = end
