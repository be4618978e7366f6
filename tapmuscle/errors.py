"""The errors tapmuscle raises for a user's bad input, with one common base.

Every error here names the offending value, file, line or variable in its message. The command line
prints the message on one line (``tapmuscle <cmd>: error: ...``) and exits with status 2; a Python
caller can catch :class:`TapmuscleError` for all of them. Each is also a :class:`ValueError`, as it
always was, so ``except ValueError`` keeps working.
"""

from __future__ import annotations

__all__ = ["TapmuscleError", "UsageError"]


class TapmuscleError(Exception):
    """Base of tapmuscle's domain errors: a recording, plant file, scenario or argument that is wrong."""


class UsageError(TapmuscleError, ValueError):
    """A problem with the user's input (an argument, a file it names); reported without a traceback."""
