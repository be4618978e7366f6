"""The errors tapmuscle raises for a user's bad input, with one common base.

Every error here names the offending value, file, line or variable in its message. The command line
prints the message on one line (``tapmuscle <cmd>: error: ...``) and exits with status 2; a Python
caller can catch :class:`TapmuscleError` for all of them. It is a :class:`ValueError` (bad input, as
the standard library would say), so ``except ValueError`` catches them too.
"""

from __future__ import annotations

__all__ = ["TapmuscleError", "UsageError", "FmuLogWarning"]


class TapmuscleError(ValueError):
    """Base of tapmuscle's domain errors: a recording, plant file, scenario or argument that is wrong."""


class UsageError(TapmuscleError):
    """A problem with the user's input (an argument, a file it names); reported without a traceback."""


class FmuLogWarning(UserWarning):
    """A warning an FMU logged during a co-simulation run (a start-up guard that fired, a command pinned
    at a valve limit, a model far off): the run went on, and its results may not mean what they seem.
    ``tapmuscle run`` prints these and lists them in ``summary.json`` (``fmu_warnings``)."""
