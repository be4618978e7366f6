"""Ctrl-C: during a co-simulation held until the master is between FMI calls; in the console
script, the first one its last.

SIGINT raises ``KeyboardInterrupt`` in whatever Python code is running, and during a co-simulation
that is most often a Python FMU's slave, inside ``fmi2DoStep``. The FMU cannot pass an exception
through FMI: this project's slaves answer fmi2Error ("interrupted"), and a pythonfmu FMU without
their guard answers fmi2Fatal after dropping references it still needs, so that freeing it later
crashes the process (measured: ``tapmuscle paper`` interrupted ended with a segfault, exit 139, in
one of three tries). Within :func:`held_interrupts` the signal only sets a flag; the master reads it
between FMI calls (:data:`HELD`) and raises ``KeyboardInterrupt`` there, so the FMUs are freed
normally and the command ends with its interrupted message (exit status 130).

Only Python's own SIGINT handler (or :func:`interrupt_once`) is replaced, and only in the main
thread (the one that receives signals): a handler someone else installed (a GUI, a test runner) is
left alone.

A process that ends with its first Ctrl-C (the console script) installs :func:`interrupt_once`: a key
held down sends SIGINT every few milliseconds, and one arriving while the first interrupt unwinds,
even inside the ``except KeyboardInterrupt`` that reports it, would end the process by the signal
(exit -2, with a traceback) instead of exit 130. The handler ignores SIGINT from the moment it raises,
and a held interrupt raised at the end of :func:`held_interrupts` does the same under it, so no
Python line is left between the first interrupt and the ignoring.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator

__all__ = ["HELD", "held_interrupts", "interrupt_once"]


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


def interrupt_once(signum: int, frame: object) -> None:
    """A SIGINT handler: ``KeyboardInterrupt`` as Python's own, with every later SIGINT ignored (set
    before raising, so that no Python line runs between the two); for a process that ends with its
    first interrupt (module docstring).

    Parameters
    ----------
    signum : int
        The signal's number, as :mod:`signal` passes it to a handler.
    frame : frame object
        The interrupted frame (unused).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


@contextmanager
def held_interrupts() -> Iterator[_Held]:
    """Hold SIGINT for the block (module docstring); a signal still held at its end is raised there.

    Nested blocks share the outer block's holding. In the main thread yields :data:`HELD` (in
    another thread a flag no signal sets: the signal interrupts the main thread only), whose
    :meth:`~_Held.raise_if_pending` the block calls where an interrupt may safely end it. A block that
    fails with an exception while a signal is held ends with ``KeyboardInterrupt`` raised from that
    exception: the user asked to stop, and the failure is kept as its cause.
    """
    if threading.current_thread() is not threading.main_thread():
        # Python raises KeyboardInterrupt in the main thread only: a block of another thread (a thread
        # pool's run) has a flag of its own that no signal sets, so that the main thread's Ctrl-C ends
        # the main thread's run, not another's that reads the flag first
        yield _Held()
        return
    previous = signal.getsignal(signal.SIGINT)
    if previous not in (signal.default_int_handler, interrupt_once):
        yield HELD  # held already (a nested block), or the signal is someone else's
        return
    HELD.pending = False
    signal.signal(signal.SIGINT, _hold)
    interrupted = False
    try:
        yield HELD
    except KeyboardInterrupt:
        interrupted = True
        raise
    except Exception as exc:
        if not HELD.pending:
            raise
        HELD.pending, interrupted = False, True
        raise KeyboardInterrupt from exc
    finally:
        if previous is interrupt_once:
            # the interrupt that ends the block leaves SIGINT ignored, as interrupt_once's own does:
            # ignored first, so that no signal falls between reading the flag and the handler's change
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            if not (interrupted or HELD.pending):
                signal.signal(signal.SIGINT, previous)
        else:
            signal.signal(signal.SIGINT, previous)
    HELD.raise_if_pending()
