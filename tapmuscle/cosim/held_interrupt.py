"""Ctrl-C during a co-simulation, held until the master is between FMI calls.

SIGINT raises ``KeyboardInterrupt`` in whatever Python code is running, and during a co-simulation
that is most often a Python FMU's slave, inside ``fmi2DoStep``. The FMU cannot pass an exception
through FMI: this project's slaves answer fmi2Error ("interrupted"), and a pythonfmu FMU without
their guard answers fmi2Fatal after dropping references it still needs, so that freeing it later
crashes the process (measured: ``tapmuscle paper`` interrupted ended with a segfault, exit 139, in
one of three tries). Within :func:`held_interrupts` the signal only sets a flag; the master reads it
between FMI calls (:data:`HELD`) and raises ``KeyboardInterrupt`` there, so the FMUs are freed
normally and the command ends with its interrupted message (exit status 130).

Only Python's own SIGINT handler is replaced, and only in the main thread (the one that receives
signals): a handler someone else installed (a GUI, a test runner) is left alone.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator

__all__ = ["HELD", "held_interrupts"]


class _Held:
    """Whether a SIGINT arrived while held (``pending``)."""

    __slots__ = ("pending",)

    def __init__(self) -> None:
        self.pending = False

    def raise_if_pending(self) -> None:
        """``KeyboardInterrupt`` if a held SIGINT is waiting (the flag is cleared)."""
        if self.pending:
            self.pending = False
            raise KeyboardInterrupt


#: The one flag: a signal handler is per process.
HELD = _Held()


def _hold(signum: int, frame: object) -> None:
    HELD.pending = True


@contextmanager
def held_interrupts() -> Iterator[_Held]:
    """Hold SIGINT for the block (module docstring); a signal still held at its end is raised there.

    Nested blocks share the outer block's holding. Yields :data:`HELD`, whose
    :meth:`~_Held.raise_if_pending` the block calls where an interrupt may safely end it.
    """
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield HELD  # held already (a nested block), or the signal is someone else's
        return
    HELD.pending = False
    signal.signal(signal.SIGINT, _hold)
    try:
        yield HELD
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    HELD.raise_if_pending()
