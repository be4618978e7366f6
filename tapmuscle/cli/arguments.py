"""Checked argument types for the command line: a bad value is reported naming the option."""

from __future__ import annotations

import argparse
import errno
import math
import os
from pathlib import Path
from typing import Callable

__all__ = ["number_within", "integer_at_least", "output_path", "Once"]


def number_within(name: str, lo: float, hi: float) -> Callable[[str], float]:
    """Parser of a finite number within ``lo..hi`` for option ``name``.

    Parameters
    ----------
    name : str
        The option, as the error message names it (e.g. ``"--block"``).
    lo, hi : float
        The range a value must lie in, bounds included.
    """
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
        if not math.isfinite(v) or not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{name} must be within {lo:g}..{hi:g}, got {text!r}")
        return v
    return parse


def integer_at_least(name: str, lo: int, hi: int | None = None, *,
                     words: tuple[str, ...] = ()) -> Callable[[str], int | str]:
    """Parser of an integer >= ``lo`` (and <= ``hi`` if given) for option ``name``, or one of ``words``
    (returned as given).

    Parameters
    ----------
    name : str
        The option, as the error message names it.
    lo : int
        The smallest value taken.
    hi : int, optional
        The largest value taken; None (default): no upper bound.
    words : tuple of str, optional
        Words taken besides integers, returned as given.
    """
    def parse(text: str) -> int | str:
        if text in words:
            return text
        try:
            v = int(text)
        except ValueError:
            alternatives = "".join(f" or {w!r}" for w in words)
            raise argparse.ArgumentTypeError(f"{name} must be an integer{alternatives}, got {text!r}") from None
        if hi is not None and not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{name} must be within {lo}..{hi}, got {v}")
        if v < lo:
            raise argparse.ArgumentTypeError(f"{name} must be >= {lo}, got {v}")
        return v
    return parse


def output_path(name: str, kind: str) -> Callable[[str], str]:
    """Parser of an output path for option ``name``, a ``kind`` ``"file"`` or ``"folder"``: not empty (an
    empty path means the current folder, which a command would then try to replace), not a folder
    where a file goes or a file where a folder goes, and under folders (checked before any work, so
    that a long run does not end in a path it cannot write).

    Parameters
    ----------
    name : str
        The option, as the error message names it.
    kind : str
        ``"file"`` or ``"folder"``: what the path is to be.
    """
    def parse(text: str) -> str:
        if not text.strip():
            raise argparse.ArgumentTypeError(f"{name} must name a file or folder, got an empty string")
        try:
            return checked(text)
        except OSError as exc:  # a folder on the way this user may not enter (Python 3.11's Path.exists raises)
            where = os.fsdecode(exc.filename) if exc.filename is not None else text
            hint = "; no permission to enter a folder on the way?" if exc.errno in (errno.EACCES, errno.EPERM) else ""
            raise argparse.ArgumentTypeError(f"{name} {text}: {where} cannot be reached ({exc.strerror or exc}{hint})"
                                             ) from None

    def checked(text: str) -> str:
        path = Path(text)
        if kind == "file" and path.is_dir():
            raise argparse.ArgumentTypeError(f"{name} {text}: a folder, not a file to write")
        if kind == "folder" and path.exists() and not path.is_dir():
            raise argparse.ArgumentTypeError(f"{name} {text}: a file, not a folder to write into")
        # an existing folder to write into is the one that must take files, not its parent
        for parent in ([path] if kind == "folder" and path.is_dir() else []) + list(path.parents):
            if parent.exists():
                if not parent.is_dir():
                    raise argparse.ArgumentTypeError(f"{name} {text}: {parent} is a file, not a folder")
                # the outputs are written beside their place and renamed in: the folder must take files
                if not os.access(parent, os.W_OK | os.X_OK):
                    raise argparse.ArgumentTypeError(f"{name} {text}: the folder {parent} cannot be written "
                                                     "(no permission, or a read-only file system)")
                break
        return text
    return parse


class Once(argparse.Action):
    """Store an option given once; given again it is refused naming both values (argparse would take
    the last in silence: ``--u A --u B`` read B). ``type`` parses each value as written, as argparse's
    own ``type`` does.

    Parameters
    ----------
    option_strings : list of str
        The option's flags, as argparse passes them.
    dest : str
        The attribute of the namespace the value is stored in.
    type : callable, optional
        Parser of the value as written (``type(text)``); None: the text itself.
    **kwargs
        Further ``argparse.Action`` arguments (``help``, ``default``, ``metavar``, ...).
    """

    def __init__(self, option_strings: list[str], dest: str, type: Callable[[str], object] | None = None,
                 **kwargs: object) -> None:
        super().__init__(option_strings, dest, **kwargs)  # no type here: the value arrives as written
        self.parse = type

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object,
                 option_string: str | None = None) -> None:
        given = namespace.__dict__.setdefault("_given_once", {})
        if self.dest in given:
            raise argparse.ArgumentError(self, f"given twice, {given[self.dest]!r} and {values!r}: give it once")
        given[self.dest] = values
        if self.parse is not None:
            try:
                values = self.parse(values)
            except argparse.ArgumentTypeError as exc:
                raise argparse.ArgumentError(self, str(exc)) from None
        setattr(namespace, self.dest, values)
