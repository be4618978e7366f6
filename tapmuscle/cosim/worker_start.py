"""Worker processes started by ``spawn`` (``tm.diagnose``'s pool, a sweep's local Dask cluster, whose
nannies spawn theirs): refused before anything starts, naming the remedy, where they cannot start.

A spawned process imports the parent's ``__main__`` again from its file, as ``__mp_main__``. So a
script read from stdin cannot start one, and a script that starts them at its top level, outside
``if __name__ == "__main__":``, starts them again in each of them, which ``multiprocessing`` refuses
there: a sweep's local cluster then printed about 500 lines of its nannies' tracebacks. A notebook or
``python -c`` has no file to import again and is fine.
"""

from __future__ import annotations

import multiprocessing
import os
import sys

from tapmuscle.errors import UsageError

__all__ = ["check_workers_can_start", "spawn_context"]


def check_workers_can_start(what: str) -> None:
    """Refuse ``what`` (the setting that asks for worker processes, e.g. ``"workers=2"``) where its
    spawned processes cannot start (module docstring).

    Parameters
    ----------
    what : str
        The setting that asks for worker processes, as the messages name it (e.g.
        ``"workers=2"``).

    Raises
    ------
    tapmuscle.errors.UsageError
        The main module names a file that does not exist (stdin), or this process is a daemonic
        worker (a ``multiprocessing.Pool``'s), which may not have children.
    SystemExit
        This process is itself a worker importing the main script again (the call is not under the
        ``__main__`` guard): it ends with the message, and the parent's start of its workers fails.
    """
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        # a worker importing the script: said in one line, the worker ending without a traceback of its own
        script = getattr(sys.modules.get("__mp_main__"), "__file__", "the main script")
        raise SystemExit(f"tapmuscle: {what} starts worker processes, and each imports {script} again: the call runs "
                         "at the script's top level, so every worker would start its own; put it under "
                         "if __name__ == \"__main__\": (as for any multiprocessing use)")
    if multiprocessing.current_process().daemon:
        # multiprocessing's own refusal is a bare AssertionError from deep inside the pool
        raise UsageError(f"{what} starts worker processes, and this process is a daemonic one (a multiprocessing.Pool's "
                         "worker, or a Dask worker's), which may not start its own: give 1 worker inside it and let the "
                         "outer pool run the calls side by side (concurrent.futures.ProcessPoolExecutor's workers "
                         "are not daemonic and can)")
    path = getattr(sys.modules.get("__main__"), "__file__", None)
    if path is not None and not os.path.exists(path):
        raise UsageError(f"{what} starts worker processes, which re-import the main script {path!r}, and that is "
                         "not a file; run the script from a file, or with 1 worker")


def spawn_context(what: str) -> multiprocessing.context.SpawnContext:
    """The ``spawn`` multiprocessing context, after :func:`check_workers_can_start` of ``what``.

    Parameters
    ----------
    what : str
        The setting that asks for worker processes, as the messages name it.
    """
    check_workers_can_start(what)
    return multiprocessing.get_context("spawn")
