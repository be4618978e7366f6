"""A fixture's result computed once per test run, shared by the run's xdist workers.

A module-scoped fixture is computed again in every worker that runs one of its tests, and again in
the same worker when work stealing hands it the module's tests after another module's: the paper's
whole grid (13 s) can be computed three times in one run, the Windows C hosts' runs (50 s) twice. What
such a fixture computes depends on nothing but the checkout, so the first worker to need it computes
it under a lock in the run's shared base directory and the others read what it wrote.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any, Callable

try:
    import fcntl
except ImportError:  # Windows: no advisory locks of this kind; each process computes its own
    fcntl = None  # type: ignore[assignment]

__all__ = ["computed_once"]


def computed_once(tmp_path_factory: Any, name: str, make: Callable[[Path], Any]) -> Any:
    """``make(folder)``'s result, computed by the first process of this test run that asks for ``name``.

    Parameters
    ----------
    tmp_path_factory : pytest.TempPathFactory
        The asking test's factory: its base directory, or under xdist the parent of the workers' base
        directories, holds the result.
    name : str
        The result's name in that directory (one per fixture).
    make : callable
        Computes the result into an empty ``folder`` it may fill (files the tests read, not change)
        and returns something JSON can hold exactly (numbers, strings, lists, dicts with string keys;
        tuples come back as lists).

    Returns
    -------
    object
        What ``make`` returned, as JSON read it back (the same in every process of the run; where the
        system has no ``fcntl`` locks, Windows, each process computes its own).
    """
    if fcntl is None:
        return json.loads(json.dumps(make(tmp_path_factory.mktemp(name))))
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the workers' base directories are popen-gw0, popen-gw1, ... of the run's
    done = root / f"once-{name}.json"
    with open(root / f"once-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also when `make` raises
        if not done.is_file():
            folder = root / f"once-{name}"
            shutil.rmtree(folder, ignore_errors=True)  # what a process that failed in `make` left
            folder.mkdir()
            text = json.dumps(make(folder))
            partial = done.with_suffix(".partial")
            partial.write_text(text, encoding="utf-8")
            partial.replace(done)
        return json.loads(done.read_text(encoding="utf-8"))
