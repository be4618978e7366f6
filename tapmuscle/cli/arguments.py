"""Checked argument types for the command line: a bad value is reported naming the option."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Callable

__all__ = ["number_within", "integer_at_least", "output_path"]


def number_within(name: str, lo: float, hi: float) -> Callable[[str], float]:
    """Parser of a finite number within ``lo..hi`` for option ``name``."""
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
    (returned as given)."""
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
    that a long run does not end in a path it cannot write)."""
    def parse(text: str) -> str:
        if not text.strip():
            raise argparse.ArgumentTypeError(f"{name} must name a file or folder, got an empty string")
        path = Path(text)
        if kind == "file" and path.is_dir():
            raise argparse.ArgumentTypeError(f"{name} {text}: a folder, not a file to write")
        if kind == "folder" and path.exists() and not path.is_dir():
            raise argparse.ArgumentTypeError(f"{name} {text}: a file, not a folder to write into")
        for parent in path.parents:
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
