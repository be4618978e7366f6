"""Atomic outputs: a file appears whole or not at all, with the user's umask.

A set of files that belong together (a diagnosis's report, JSON and figures) is written into a
staging folder first (:func:`staged_folder`) and put in place only once every file is written, so
an output folder never holds half of a run or a mix of two runs.

Every file tapmuscle writes goes through :func:`atomic_path`: the content is written to a temporary
file in the target's folder, which is renamed over the target only once complete (a crash or an
error leaves the old file, or none, and no temporary file). ``tempfile.mkstemp`` creates its file
with mode 0600; the rename would carry that over, so the file gets the mode an ordinary
``open(path, "w")`` would give, ``0666 & ~umask``, before the rename.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence

__all__ = ["atomic_path", "default_file_mode", "staged_folder"]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def default_file_mode() -> int:
    """``0o666 & ~umask``: the mode ``open(path, "w")`` gives a new file in this process."""
    return 0o666 & ~_umask()


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


@contextmanager
def staged_folder(out: str | os.PathLike, *, owned: Sequence[str] | None = None) -> Iterator[Path]:
    """A temporary folder next to ``out`` to write a run's outputs into, put in place when the block
    ends without error; on error ``out`` is left as it was (or not created) and the temporary folder
    removed.

    Parameters
    ----------
    out : path
        The output folder.
    owned : sequence of str, optional
        Glob patterns (relative to ``out``) of the files a run of this kind writes. Given, the staged
        files replace their namesakes in ``out`` (created if missing), and the files of ``out`` that
        match a pattern but this run did not write (an earlier run's figures or experiment files)
        are removed; other files in ``out`` are kept. None: ``out`` is replaced as a whole.

    Raises
    ------
    OSError
        ``out`` is a file, or a staged file's place in ``out`` is a directory (checked before anything
        in ``out`` changes).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out} is a file, not a folder for the outputs")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        yield tmp
        if owned is None:
            os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp's 0700: the mode mkdir would give the folder
            if out.exists():
                old = out.with_name(f".{out.name}.old")
                shutil.rmtree(old, ignore_errors=True)
                out.rename(old)
                tmp.rename(out)
                shutil.rmtree(old, ignore_errors=True)
            else:
                tmp.rename(out)
            return
        new = sorted(p.relative_to(tmp) for p in tmp.rglob("*") if p.is_file())
        for rel in new:  # before any rename: one failing half-way would leave two runs mixed
            if (out / rel).is_dir():
                raise IsADirectoryError(f"{out / rel} is a directory, not a file to write")
        out.mkdir(exist_ok=True)
        for rel in new:
            (out / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp / rel, out / rel)
        for pattern in owned:
            for p in out.glob(pattern):
                if p.is_file() and p.relative_to(out) not in new:
                    p.unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
