"""The folders FMUs are extracted into, removed after the process that uses them, even a killed one.

An FMU is a zip file; a host extracts it and loads its binary from the folder. A folder removed at
the interpreter's exit (``atexit``) outlives every process that ends without it: a Jupyter kernel
restarted or interrupted for good, a Dask worker its nanny terminates, a forked worker that leaves
through ``os._exit``, a CI job killed at its time limit. Each leaves a copy of the FMU (about 1 MB
per FMU here) in the temporary directory.

So each folder holds a lock file with an exclusive ``flock`` for as long as the process that
extracted it (and any child it forked) is alive; the kernel releases the lock when the process ends,
however it ends. Whoever extracts an FMU next removes the folders of the same prefix whose lock can
be taken: nobody holds them. A folder is created under a name that removal does not look at,
locked, and only then renamed to its final name, so no removal can see it unlocked. Where ``fcntl`` is missing
(Windows), the folders are removed at exit only.

The folders hold libraries to load, and a file system mounted ``noexec`` (a hardened system's
``/tmp``) refuses to map one ("failed to map segment from shared object"); and the FMUs' Python
opens its resources by a UTF-8 path, which a folder named in another encoding (Latin-1 bytes, from
a Windows zip or an old home folder) does not have. So they go to the temporary directory unless it
is either, and then to the user's tapmuscle cache (:func:`extraction_root`). A UTF-8 name with
letters beyond ASCII (``/tmp/Zürich``) the project's FMUs can open (their loader decodes the resource
URI), but an FMU built with pythonfmu's own binary cannot: that binary decodes only ``%20`` in the URI,
gets a folder that does not exist and crashes the process in ``fmi2Instantiate`` (the foreign demo
``ThermalTwoMass``, or a user's own pythonfmu FMU, under ``diagnose``). So an ASCII cache is preferred
to such a temporary directory.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

__all__ = ["LOCK_NAME", "claimed_folder", "extraction_root", "remove_abandoned"]

#: The lock file in each claimed folder.
LOCK_NAME = ".in-use.lock"

_HELD: list[int] = []
"""Lock file descriptors of this process's folders (kept open: closing one releases its lock)."""


def _noexec(folder: str | Path) -> bool:
    """Whether ``folder`` is on a file system mounted ``noexec`` (False where that cannot be told)."""
    try:
        return bool(os.statvfs(folder).f_flag & getattr(os, "ST_NOEXEC", 0))
    except (OSError, AttributeError):  # pragma: no cover - no statvfs (Windows)
        return False


def _ascii(folder: str | Path) -> bool:
    """Whether ``folder``'s name is ASCII (module docstring: what pythonfmu's own binary can open)."""
    return os.fsencode(folder).isascii()


def _unusable(folder: str | Path) -> str | None:
    """Why no FMU can run from ``folder`` (None: it can): a name that is not UTF-8, or ``noexec``."""
    try:
        os.fsencode(folder).decode("utf-8")
    except UnicodeDecodeError:
        return "has a name that is not UTF-8 (the FMUs' Python cannot open it)"
    if _noexec(folder):
        return "is mounted noexec (no FMU binary can be loaded from it)"
    return None


def extraction_root() -> str:
    """Where FMUs are extracted to load their binaries: the temporary directory (``TMPDIR``), unless it
    is on a file system mounted ``noexec``, where no library can be loaded, or has a name that is not
    UTF-8; then ``extracted/`` in the user's tapmuscle cache (``$XDG_CACHE_HOME/tapmuscle``, else
    ``~/.cache/tapmuscle``). A temporary directory named beyond ASCII gives way to a cache named in
    ASCII (module docstring: FMUs built with pythonfmu's own binary), else it is used.

    Raises
    ------
    OSError
        Neither can hold them, or the cache folder cannot be made; the message names them, why, and
        what to set.
    """
    temp = tempfile.gettempdir()
    why = _unusable(temp)
    from build_scripts.build_fmus import user_cache_root

    if why is None:
        if not _ascii(temp):
            try:
                cache = user_cache_root() / "extracted"
                if _ascii(cache):
                    cache.mkdir(parents=True, exist_ok=True)
                    if _unusable(cache) is None and os.access(cache, os.W_OK | os.X_OK):
                        return str(cache)
            except OSError:  # no cache to be had: the temporary directory serves the project's FMUs
                pass
        return temp

    def shown(path: str | Path) -> str:  # a name that is not UTF-8, printable
        return os.fsencode(path).decode("utf-8", "backslashreplace")

    cache = user_cache_root() / "extracted"
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(f"the temporary directory {shown(temp)} {why}, and {cache} cannot be made ({exc.strerror or exc}): "
                      "set TMPDIR to a folder on a file system that allows executing, with a UTF-8 name") from None
    why_cache = _unusable(cache)
    if why_cache is not None:
        raise OSError(f"the temporary directory {shown(temp)} {why}, and the cache {shown(cache)} {why_cache}: set TMPDIR (or "
                      "XDG_CACHE_HOME) to a folder on a file system that allows executing, with a UTF-8 name")
    return str(cache)


def _try_lock(fd: int) -> bool:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def remove_abandoned(prefix: str, root: str | Path | None = None) -> list[Path]:
    """Remove the folders ``root/prefix*`` whose lock nobody holds; the removed folders.

    A folder without a lock file is left alone (not made by :func:`claimed_folder`).

    Parameters
    ----------
    prefix : str
        The folders' name prefix, as given to :func:`claimed_folder`.
    root : str or Path, optional
        Where they are (default: :func:`extraction_root`).
    """
    if fcntl is None:  # pragma: no cover - Windows
        return []
    removed = []
    for folder in sorted(Path(root or extraction_root()).glob(f"{prefix}*")):
        try:
            fd = os.open(folder / LOCK_NAME, os.O_RDWR)
        except OSError:  # no lock file, or not ours to open
            continue
        try:
            if _try_lock(fd):
                shutil.rmtree(folder, ignore_errors=True)
                removed.append(folder)
        finally:
            os.close(fd)
    return removed


def _remove_at_exit(folder: str) -> None:
    owner = os.getpid()

    def remove() -> None:
        if os.getpid() == owner:  # a forked child that exits through sys.exit leaves its parent's folder
            shutil.rmtree(folder, ignore_errors=True)

    atexit.register(remove)


def claimed_folder(prefix: str, root: str | Path | None = None) -> str:
    """A new empty folder ``root/prefix<random>``, locked for this process's life and removed at its exit.

    The abandoned folders of the same prefix (:func:`remove_abandoned`) are removed first.

    Parameters
    ----------
    prefix : str
        The folder's name prefix (e.g. ``tapmuscle_MusclePlant_``).
    root : str or Path, optional
        Where to create it (default: :func:`extraction_root`).

    Returns
    -------
    str
        The folder's path.
    """
    root = str(root or extraction_root())
    remove_abandoned(prefix, root)
    if fcntl is None:  # pragma: no cover - Windows
        folder = tempfile.mkdtemp(prefix=prefix, dir=root)
        _remove_at_exit(folder)
        return folder
    # created under a name no removal matches, locked, then renamed: never visible unlocked
    staging = tempfile.mkdtemp(prefix=f".claiming-{prefix}", dir=root)
    fd = os.open(os.path.join(staging, LOCK_NAME), os.O_CREAT | os.O_RDWR, 0o600)
    folder = os.path.join(root, prefix + os.path.basename(staging)[len(f".claiming-{prefix}"):])
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.rename(staging, folder)
    except OSError:
        os.close(fd)
        shutil.rmtree(staging, ignore_errors=True)
        raise
    _HELD.append(fd)
    _remove_at_exit(folder)
    return folder
