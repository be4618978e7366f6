"""Open-loop re-simulation of a recording with a plant model: the recorded command in, the displacement
the model predicts out.

Sampling as in every recording (``fmu_plant.open_loop``): row ``k`` holds ``l(k)`` measured at
``t_k = k Ts`` and the command ``u(k)`` held over ``[t_k, t_{k+1})``. The model is run without sensor
noise and quantisation (they are the recording's, not the model's), from rest (drained, fully
extended: how every tapmuscle recording starts; documented in docs/diagnosis.md), with the recorded
load when the recording has a ``load_n`` column.
"""

from __future__ import annotations

import signal
import sys
from concurrent.futures import Executor, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator, Sequence

import numpy as np

from fmu_plant import Plant, PlantParams

from tapmuscle.cosim.worker_start import spawn_context
from tapmuscle.errors import UsageError

__all__ = ["Simulator", "SimulationError", "checkpoint_interval", "worker_pool", "process_pool"]

#: Recording time between the checkpoints a baseline run keeps [s]: a window fit continues from the
#: last one before its window, so it simulates at most this much more than the window.
CHECKPOINT_S = 10.0


def checkpoint_interval(ts_s: float) -> int:
    """Samples between checkpoints (:data:`CHECKPOINT_S`) at sampling period ``ts_s`` [s].

    Parameters
    ----------
    ts_s : float
        Sampling period [s].
    """
    return max(1, int(round(CHECKPOINT_S / ts_s)))


class SimulationError(RuntimeError):
    """A model that cannot be simulated with some parameters (an FMU error, non-finite outputs, the
    plant's integration breaking down); the message says which parameters and why."""


@dataclass
class Simulator:
    """Re-simulates one recording's command with plant parameters (setup once, run many times).

    Parameters
    ----------
    u_v : ndarray
        Recorded command [V], one per sample.
    ts_s : float
        Sampling period [s].
    load_n : ndarray, optional
        Recorded load [N] per sample (default: the parameters' ``load.load_n`` throughout).
    """

    u_v: np.ndarray
    ts_s: float
    load_n: np.ndarray | None = None
    runs: int = 0
    """How many simulations were run (for the report)."""
    _checkpoints: dict[int, dict[str, Any]] = field(default_factory=dict)
    executor: Executor | None = field(default=None, repr=False, compare=False)
    """Worker processes (:func:`worker_pool`) that :meth:`run_many` spreads its runs over, and that
    other independent work on this recording may use (None: everything in this process)."""

    def run(self, params: PlantParams, *, stop: int | None = None, start: int = 0,
            checkpoint_every: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free displacement [mm] and pressure [MPa] for samples ``start .. stop - 1``.

        Parameters
        ----------
        params : PlantParams
            The model (its sensor noise is switched off here).
        stop : int, optional
            First sample not simulated (default: all).
        start : int
            First sample; > 0 continues from the baseline checkpoint at ``start`` (see
            ``checkpoint_every``), which is valid for effects that do not act before ``t_start``.
        checkpoint_every : int
            Keep the plant's state every this many samples (0: none), for later runs with ``start``.
        """
        n = len(self.u_v) if stop is None else stop
        plant = Plant(params.noise_free(), seed=0)
        if start:
            plant.set_state(self._checkpoints[start])
        u = np.asarray(self.u_v, dtype=float)[start:n - 1]  # the commands held over the steps
        load = None if self.load_n is None else np.asarray(self.load_n, dtype=float)[start:n - 1]
        l = [np.array([plant.measurement.l_mm])]
        p = [np.array([plant.measurement.p_mpa])]
        if load is not None and len(load):
            plant.update(load_n=float(load[0]))
        # the plant's own loop between checkpoints (the samples that are multiples of checkpoint_every)
        every = checkpoint_every
        edges = sorted({0, len(u), *(range(-start % every, len(u), every) if every else ())})
        try:
            for a, b in zip(edges, edges[1:]):
                if every and (start + a) % every == 0:
                    self._checkpoints[start + a] = plant.get_state()
                l_ab, p_ab = plant.step_many(u[a:b], self.ts_s, load_n=None if load is None else load[a:b])
                l.append(l_ab)
                p.append(p_ab)
        except FloatingPointError as exc:  # parameters the plant cannot be integrated with: a failed run
            raise SimulationError(f"the plant with {_changed(params)}: {exc}") from None
        self.runs += 1
        return np.concatenate(l), np.concatenate(p)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["executor"] = None  # a copy sent to a worker process runs there, serially
        return state

    def run_many(self, params: Sequence[PlantParams], *, stop: int | None = None,
                 pressure: bool = False) -> list[Any]:
        """Noise-free displacements [mm] of ``run(p, stop=stop)`` for each of ``params``, in order
        (``pressure``: ``(displacement, pressure)`` pairs instead).

        With an :attr:`executor` the runs are spread over its processes; the results are the same,
        bit for bit (each run is a deterministic function of its parameters).
        """
        params = list(params)
        if self.executor is None or len(params) < 2:
            return [self.run(p, stop=stop) if pressure else self.run(p, stop=stop)[0] for p in params]
        light = Simulator(self.u_v, self.ts_s, self.load_n)  # what a run needs, without the checkpoints
        n = len(params)
        out = list(self.executor.map(_run_copy, [light] * n, params, [stop] * n, [pressure] * n))
        self.runs += len(params)
        return out

    def checkpoints(self) -> list[int]:
        """Samples at which :meth:`run` may start (from a baseline run with ``checkpoint_every``)."""
        return sorted(self._checkpoints)


@contextmanager
def worker_pool(workers: int) -> Iterator[Executor | None]:
    """``workers`` fresh processes for independent simulations (None for 1: run in this process).

    The processes are spawned (safe under threads, notebooks and Dask workers); as with any
    ``multiprocessing`` use, a script that starts them needs an ``if __name__ == "__main__":`` guard.

    Parameters
    ----------
    workers : int
        Number of processes (>= 1).
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if workers == 1:
        yield None
        return
    with process_pool(workers, f"workers={workers}") as pool:
        yield pool


@contextmanager
def process_pool(workers: int, what: str) -> Iterator[ProcessPoolExecutor]:
    """``workers`` spawned processes (:func:`~tapmuscle.cosim.worker_start.spawn_context`) that leave an interrupt to this one.

    On an interrupt or any other exception in the ``with`` block, the work not started is cancelled
    and the processes are stopped at once. A terminal's Ctrl-C and Jupyter's interrupt reach every
    process of the group, and a plain ``ProcessPoolExecutor``'s workers would each print their own
    ``KeyboardInterrupt`` traceback; an interrupt sent to this process alone (``kill -INT``, a job
    scheduler) would make it first finish every queued task (a field run's remaining cases: minutes).

    Parameters
    ----------
    workers : int
        Number of processes.
    what : str
        The setting that asked for them, named if they cannot start (``"jobs=2"``).
    """
    pool = ProcessPoolExecutor(workers, mp_context=spawn_context(what), initializer=_leave_interrupts_to_parent)
    try:
        yield pool
    except BaseException as exc:
        # the executor has no public way to stop a task that has started; its shutdown forgets the
        # processes and the thread that feeds them, so both are taken first
        processes = list((getattr(pool, "_processes", None) or {}).values())
        manager = getattr(pool, "_executor_manager_thread", None)
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        for process in processes:
            process.join()
        if manager is not None and manager.ident is not None:  # an interrupt can come while it starts
            manager.join()
        if isinstance(exc, BrokenProcessPool):
            # the usual cause prints its own line in each worker; the pool's traceback (40 lines through
            # concurrent.futures) says only that a process ended
            script = getattr(sys.modules.get("__main__"), "__file__", None)
            raise UsageError(f"{what}: a worker process ended abruptly. If each printed that it imports "
                             f"{script or 'the main script'} again, put the call under if __name__ == \"__main__\": "
                             "(as for any multiprocessing use); otherwise a worker was killed (out of memory?): "
                             "use fewer workers, or 1") from None
        raise
    pool.shutdown(wait=True)


def _leave_interrupts_to_parent() -> None:
    """A worker ignores SIGINT: the parent stops it (:func:`process_pool`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run_copy(sim: Simulator, params: PlantParams, stop: int | None, pressure: bool = False) -> Any:
    """One run of :meth:`Simulator.run_many` in a worker process."""
    out = sim.run(params, stop=stop)
    return out if pressure else out[0]


def _changed(params: PlantParams) -> str:
    """``params``' values that differ from the defaults, ``group.field=value``, for a message."""
    nominal = PlantParams().dotted()
    diff = [f"{k}={v:.6g}" for k, v in params.dotted().items() if v != nominal.get(k)]
    return ", ".join(diff) if diff else "its defaults"  # all: the one that broke it may be any
