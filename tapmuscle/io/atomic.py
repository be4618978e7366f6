"""Atomic outputs: a file appears whole or not at all, with the user's umask.

Every file tapmuscle writes goes through :func:`atomic_path`: the content is written to a temporary
file in the target's folder, which is renamed over the target only once complete (a crash or an
error leaves the old file, or none, and no temporary file). ``tempfile.mkstemp`` creates its file
with mode 0600; the rename would carry that over, so the file gets the mode an ordinary
``open(path, "w")`` would give, ``0666 & ~umask``, before the rename.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

__all__ = ["atomic_path", "default_file_mode"]


def default_file_mode() -> int:
    """``0o666 & ~umask``: the mode ``open(path, "w")`` gives a new file in this process."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


@contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str = ".tmp") -> Iterator[Path]:
    """A temporary path next to ``path``; renamed to ``path`` when the block ends without error.

    Parameters
    ----------
    path : path
        The file to write; its folder is created if missing.
    suffix : str
        Suffix of the temporary file (``.png`` lets matplotlib infer the format).

    Raises
    ------
    OSError
        The folder cannot be created or written, or ``path`` is a directory; the temporary file is
        removed and nothing at ``path`` changes.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    folder.mkdir(parents=True, exist_ok=True)
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a directory, not a file to write")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=folder)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, default_file_mode())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
