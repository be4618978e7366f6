"""What ``tests/c_host/threaded_host.c``'s ``loops`` mode must show, in a Linux and in a Windows C host."""

from __future__ import annotations

import subprocess
from typing import Callable


def assert_parallel_loops_as_one_thread(run: Callable[[int], subprocess.CompletedProcess], repeats: int) -> None:
    """``run(threads)`` runs ``threaded_host loops threads=N`` in a fresh process. The one-thread run
    tracks in both loops (44 N and 68 N), and ``repeats`` four-thread runs (both FMUs instantiated at
    once as the process's first calls, every fmi2DoStep of a step in its own thread) give its output
    bit for bit (hex floats): the threads change only who calls."""
    alone = run(1)
    assert alone.returncode == 0, alone.stderr[-3000:]
    rows = alone.stdout.splitlines()
    assert len(rows) == 601
    last = rows[-1].split(",")
    assert all(10.0 < float.fromhex(last[i]) < 80.0 for i in (1, 3))  # both loops track (l in mm)
    assert last[1] != last[3]  # 44 N and 68 N are two different loops
    for k in range(repeats):
        parallel = run(4)
        assert parallel.returncode == 0, f"run {k}: exit {parallel.returncode}\n{parallel.stderr[-3000:]}"
        assert parallel.stdout == alone.stdout, f"run {k}"
