"""Warnings shown at the user's line, not at the package's.

A warning raised deep in a run (``tm.simulate`` -> ``run_open_loop`` -> here) with a fixed
``stacklevel`` points at a line of the package; a notebook shows that line, and the warnings filter's
"once per location" rule then hides it when the same cell is run again. :func:`warn_at_caller` points
at the first frame outside this project's packages.
"""

from __future__ import annotations

import sys
import warnings
from types import FrameType

__all__ = ["PROJECT_PACKAGES", "in_project", "warn_at_caller"]

#: The top-level packages whose frames a warning skips (this project's).
PROJECT_PACKAGES = ("fmu_plant", "fmu_controller", "fmi_slave", "build_scripts", "tapmuscle")


def in_project(frame: FrameType) -> bool:
    """Whether ``frame`` runs code of :data:`PROJECT_PACKAGES`.

    Parameters
    ----------
    frame : types.FrameType
        A stack frame.
    """
    return frame.f_globals.get("__name__", "").split(".", 1)[0] in PROJECT_PACKAGES


def _stacklevel() -> int:
    """``warnings.warn``'s stacklevel, counted from its caller's caller, of the first frame outside
    :data:`PROJECT_PACKAGES` (the outermost frame if every one is inside)."""
    frame, level = sys._getframe(2), 1
    while frame.f_back is not None and in_project(frame):
        frame, level = frame.f_back, level + 1
    return level


def warn_at_caller(message: str | Warning, category: type[Warning] = UserWarning) -> None:
    """``warnings.warn(message, category)`` located at the first line outside this project's packages
    (the user's script or notebook cell).

    Parameters
    ----------
    message : str or Warning
        The warning, as :func:`warnings.warn` takes it.
    category : type of Warning, optional
        Its category; default ``UserWarning``.
    """
    warnings.warn(message, category, stacklevel=_stacklevel() + 1)
