"""Independent pieces of the diagnosis's work (candidates' own fits, joint re-fits) in the simulator's
worker processes, each on a copy of the fit problem, or here and now: the results are the same either
way, bit for bit.
"""

from __future__ import annotations

import pickle
import time
from concurrent.futures import Future
from typing import Any, Callable, Sequence

from tapmuscle.diagnosis.fit_problem import Problem, Rejected, SimulationError

__all__ = ["on_copies", "timed"]


def on_copies(problem: Problem, fn: Callable[..., Any], shared: tuple, tasks: Sequence[tuple], *,
              parallel: bool = True, each_done: Callable[[], None] | None = None
              ) -> list[Callable[[], tuple[Any, int, float]]]:
    """``fn(problem, *shared, *task)`` for each of ``tasks``: one handle per task, in order, that
    returns ``(result, simulations, seconds)``.

    The tasks must be independent. With the simulator's worker processes (and ``parallel``) they are
    submitted now, each on a copy of ``(problem, shared)`` taken now (a later baseline run changes the
    checkpoints), so that tasks on two bases can run at once; otherwise they run here and now. The
    results are the same either way (``fn`` must be a module-level function to go to a worker).
    ``each_done`` is called as each task's result is had: here as it ends, from a worker as its
    handle collects it (in both cases once per task, in order).

    Parameters
    ----------
    problem : Problem
        The recording's fit problem (its simulator's ``executor`` is the pool).
    fn : callable
        ``fn(problem, *shared, *task)``, a module-level function.
    shared : tuple
        Arguments common to every task.
    tasks : sequence of tuple
        Each task's own arguments.
    parallel : bool, optional
        False: run here even with a pool (tasks that do not pickle).
    each_done : callable, optional
        Called as each task's result is had.
    """
    pool = problem.sim.executor
    if pool is None or not parallel or len(tasks) < 2:
        done = []
        for task in tasks:
            done.append(timed(fn, problem, shared, task))
            if each_done is not None:
                each_done()
        return [lambda out=out: out for out in done]
    blob = pickle.dumps((problem, shared))
    futures = [pool.submit(_timed_on_copy, fn, blob, task) for task in tasks]

    def collect(fut: Future) -> tuple[Any, int, float]:
        out = fut.result()
        problem.sim.runs += out[1]  # the worker's copy counted them
        if each_done is not None:
            each_done()
        return out
    return [lambda fut=fut: collect(fut) for fut in futures]


def timed(fn: Callable[..., Any], problem: Problem, shared: tuple, task: tuple) -> tuple[Any, int, float]:
    """``fn``'s result (:class:`Rejected` with the reason if a simulation failed), simulations, seconds.

    Parameters
    ----------
    fn : callable
        ``fn(problem, *shared, *task)``.
    problem : Problem
        The recording's fit problem.
    shared, task : tuple
        The common and the task's own arguments.
    """
    runs0, t0 = problem.sim.runs, time.perf_counter()
    try:
        result = fn(problem, *shared, *task)
    except SimulationError as exc:
        result = Rejected(str(exc))
    return result, problem.sim.runs - runs0, time.perf_counter() - t0


def _timed_on_copy(fn: Callable[..., Any], blob: bytes, task: tuple) -> tuple[Any, int, float]:
    """A worker process's share of :func:`on_copies`."""
    problem, shared = pickle.loads(blob)
    return timed(fn, problem, shared, task)
