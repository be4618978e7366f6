"""A folder whose contents the process trusts: its own, or the system's, and closed to other users.

An FMU is code: one taken from a folder another user can write into (a shared cache, a folder of a
predictable name in the temporary directory) runs what they put there as this user. The FMU cache
(:func:`build_scripts.build_fmus.cached_fmus`) and the sweep workers' FMU folder
(:mod:`tapmuscle.cosim.distributed_sweep`) are taken through :func:`own_folder`. Windows keeps each
user's cache and temporary folder apart already; there the folder is taken as it is.
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
from pathlib import Path

__all__ = ["own_folder", "remove_foreign", "UntrustedFolderError"]


class UntrustedFolderError(PermissionError):
    """A folder whose FMUs another user could have put there (:func:`own_folder`)."""


def own_folder(folder: Path, *, closed: int, what: str, remedy: str) -> Path:
    """``folder``, made if missing (mode ``0o777 & ~closed``), once it is this user's or root's and
    a link to neither: one of this user's that others may write into (made under a umask of 002,
    say) has the ``closed`` mode bits taken away first.

    Parameters
    ----------
    folder : Path
        The folder.
    closed : int
        The mode bits others must not have: ``0o077`` (this user's alone) or ``0o022`` (not
        writable by others).
    what : str
        What the folder is, for the message (``"the FMU cache"``).
    remedy : str
        What to do instead, for the message (``"set XDG_CACHE_HOME to a folder of your own"``).

    Raises
    ------
    UntrustedFolderError
        ``folder`` is a link, not a folder, another user's, or root's and open to others; named,
        with why an FMU there cannot be trusted and the remedy.
    OSError
        ``folder`` cannot be made.
    """
    try:
        folder.mkdir(mode=0o777 & ~closed, parents=True, exist_ok=True)
    except FileExistsError:  # a file of that name: what a write into it would meet
        raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(folder)) from None
    if os.name == "nt" or not hasattr(os, "getuid"):
        return folder

    def refused(why: str) -> UntrustedFolderError:
        return UntrustedFolderError(f"{what} {folder} {why}: another user could put an FMU there whose code runs as "
                               f"you. {remedy}")

    opened = folder
    if os.path.islink(folder):  # one's own link to a folder elsewhere (a cache on a larger disk): its target
        owner = os.lstat(folder).st_uid
        if owner not in (os.getuid(), 0):
            raise refused(f"is a link another user (uid {owner}) made")
        opened = Path(os.path.realpath(folder))
    try:  # opened, not looked up by name again: what is checked and closed is what the name holds
        fd = os.open(opened, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    except OSError as exc:
        raise refused("is a link" if os.path.islink(opened) else f"is not a folder ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if st.st_uid not in (os.getuid(), 0):
            raise refused(f"belongs to another user (uid {st.st_uid})")
        if st.st_uid != os.getuid():  # root's (a system-wide folder): trusted unless others may write it
            if st.st_mode & 0o022:
                raise refused("is open to other users")
        elif st.st_mode & closed:
            try:
                os.fchmod(fd, st.st_mode & 0o7777 & ~closed)
            except OSError as exc:
                # a read-only mount: no one writes there; a file system without modes (vfat): anyone may
                if not os.fstatvfs(fd).f_flag & os.ST_RDONLY:
                    raise refused(f"cannot be closed to other users ({exc.strerror or exc}: a file system "
                                  "without permissions?)") from None
    finally:
        os.close(fd)
    return folder


def remove_foreign(path: Path) -> bool:
    """Remove what stands at ``path`` in an own folder unless it is a file of this user's or root's:
    a link (to a file of this user's, which a write would go through) or another user's file, left
    while the folder was open to others. True where something was removed (the file is to be written
    anew), False where ``path`` is missing or such a file. Windows: no owners to tell, nothing removed.
    """
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    if os.name == "nt" or not hasattr(os, "getuid"):
        return False
    if stat.S_ISREG(st.st_mode) and st.st_uid in (os.getuid(), 0):
        return False
    shutil.rmtree(path) if stat.S_ISDIR(st.st_mode) else path.unlink()
    return True
