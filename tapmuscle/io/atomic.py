"""Atomic outputs: a file appears whole or not at all, with the user's umask.

A set of files that belong together (a diagnosis's report, JSON and figures) is written into a
staging folder first (:func:`staged_folder`) and put in place only once every file is written, so
an output folder never holds half of a run or a mix of two runs; a rename that fails on the way (on
Windows, a file that another program holds open cannot be replaced) puts back what had moved.

Every file tapmuscle writes goes through :func:`atomic_path`: the content is written to a temporary
file in the target's folder, which is renamed over the target only once complete (a crash or an
error leaves the old file, or none, and no temporary file). Otherwise the result is what an ordinary
``open(path, "w")`` gives: a new file gets ``0666 & ~umask`` (``tempfile.mkstemp``'s 0600 would
carry over through the rename), an existing file keeps its mode, a symbolic link is followed (its
target is replaced, the link stays), and a file this process may not write is refused.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import signal
import stat
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence

from tapmuscle.interrupts import held_interrupts

__all__ = ["atomic_path", "default_file_mode", "followed", "probe_output_folder", "staged_folder"]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def default_file_mode() -> int:
    """``0o666 & ~umask``: the mode ``open(path, "w")`` gives a new file in this process."""
    return 0o666 & ~_umask()


def followed(path: str | os.PathLike) -> Path:
    """``path`` with its symbolic links resolved (``os.path.realpath``), once no link on the way could
    have been planted: each is this user's or root's, or stands in a folder of its owner's that not
    everyone may write into (a folder of a colleague's, a volume of the host user's mounted in a
    container run as root). A link another user made in a shared folder (``/tmp``, a group's folder)
    would have the output written, or a folder replaced, where they chose: into this user's own
    files (links are followed by the process, so the kernel's ``protected_symlinks``, a rule of this
    kind for sticky folders, does not stop it). Windows: resolved as it is.

    Parameters
    ----------
    path : str or os.PathLike
        The path to resolve.

    Raises
    ------
    PermissionError
        Such a link on the way; named, with its owner.
    """
    if os.name == "nt" or not hasattr(os, "getuid"):
        return Path(os.path.realpath(path))
    trusted = (os.getuid(), 0)
    given = Path(path)
    # the path's own parts, "..", as the kernel takes them: after the link before it, not collapsed first
    pending = list((given if given.is_absolute() else Path(os.getcwd()) / given).parts)
    resolved = Path(pending.pop(0))
    links = 0
    while pending:
        part = pending.pop(0)
        if part == "..":
            resolved = resolved.parent  # resolved holds no link: its parent is the real one
            continue
        nxt = resolved / part
        try:
            st = os.lstat(nxt)
        except OSError:  # missing (made by the write) or not reachable: resolved as the write would
            return Path(os.path.realpath(nxt.joinpath(*pending)))
        if not stat.S_ISLNK(st.st_mode):
            resolved = nxt
            continue
        links += 1
        if links > 40:  # the kernel's limit
            raise OSError(errno.ELOOP, os.strerror(errno.ELOOP), str(path))
        folder = os.stat(resolved)
        # planted: in a folder of someone else's, or one anyone may write into (a group-writable folder
        # of the link's owner's is theirs: under a umask of 002 every folder of a user's is)
        if st.st_uid not in trusted and (folder.st_uid != st.st_uid or folder.st_mode & 0o002):
            raise PermissionError(f"{nxt} is a link that another user (uid {st.st_uid}) made in a folder others may "
                                  f"write into: an output written through it would go where they chose "
                                  f"({os.readlink(nxt)}); not followed. Remove it or write elsewhere")
        target = Path(os.readlink(nxt))
        if target.is_absolute():
            resolved, pending = Path(target.anchor), list(target.parts[1:]) + pending
        else:
            pending = list(target.parts) + pending
    return resolved


def _target(path: Path) -> tuple[Path, int]:
    """The file a write of ``path`` replaces (a symbolic link's target) and the mode it gets, as
    ``open(path, "w")`` would leave them (module docstring).

    Raises
    ------
    IsADirectoryError
        ``path`` is a directory.
    PermissionError
        ``path`` is a file this process may not write.
    """
    real = followed(path)  # every link on the way checked, the file's own too
    target = real if path.is_symlink() else path
    if target.is_dir():
        raise IsADirectoryError(f"{path} is a directory, not a file to write")
    if not target.exists():
        return target, default_file_mode()
    if not os.access(target, os.W_OK):
        raise PermissionError(f"{path} is read-only: not replaced")
    return target, os.stat(target).st_mode & 0o7777


#: A write that fails for want of room names no file (``[Errno 28] No space left on device``).
_NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def _no_room(exc: OSError, written: Path) -> OSError:
    """A full disk's (or quota's) ``exc`` again, naming ``written`` (an ``OSError`` where its own class
    takes other arguments)."""
    try:
        return type(exc)(exc.errno, exc.strerror, str(written))
    except TypeError:
        return OSError(exc.errno, exc.strerror, str(written))


def _named(exc: OSError, written: Path) -> OSError:
    """``exc`` naming ``written`` where it is a full disk's (or quota's) error that names no file."""
    if exc.filename is not None or exc.errno not in _NO_ROOM:
        return exc
    return _no_room(exc, written)


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
        The folder cannot be created or written, ``path`` is a directory or a file this process may
        not write (before the block runs); the temporary file is removed and nothing at ``path``
        changes.
    """
    path = Path(path)
    (path.parent if str(path.parent) else Path(".")).mkdir(parents=True, exist_ok=True)
    target, mode = _target(path)  # before the caller's work: a file that cannot be written is named first
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix, dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        try:
            os.chmod(tmp, mode)
        except PermissionError:  # a file system without modes (vfat): the file as it is
            pass
        try:
            os.replace(tmp, target)
        except PermissionError as exc:  # a file this process may write: held open by another program
            raise _not_replaced(exc, path, path) from exc
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        named = _named(exc, path)
        if named is exc:
            raise
        raise named from exc
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def probe_output_folder(out: str | os.PathLike) -> None:
    """Fail now, naming ``out``, where :func:`staged_folder` would fail once the work is done: ``out``
    a file, or ``out`` or the folder it is in not writable (an immutable or read-only mount; as root,
    permission bits do not stop a write, so the folder is tried, not its mode read).

    Parameters
    ----------
    out : str or os.PathLike
        The output folder (it may not exist yet).

    Raises
    ------
    OSError
        ``NotADirectoryError`` or ``PermissionError`` naming ``out`` and why.
    """
    real = followed(out)  # every link on the way checked, the folder's own too
    out = real if Path(out).is_symlink() else Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out} is a file, not a folder for the outputs")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        os.rmdir(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))  # the staging folder's place
        if out.is_dir():  # the outputs are renamed into it
            fd, name = tempfile.mkstemp(prefix=".probe.", dir=out)
            os.close(fd)
            os.unlink(name)
    except OSError as exc:
        raise PermissionError(f"{out}: the outputs cannot be written there ({exc.strerror or exc}); "
                              "choose another output folder") from None


@contextmanager
def staged_folder(out: str | os.PathLike, *, owned: Sequence[str | re.Pattern[str]] | None = None) -> Iterator[Path]:
    """A temporary folder next to ``out`` to write a run's outputs into, put in place when the block
    ends without error; on error ``out`` is left as it was (or not created) and the temporary folder
    removed.

    Parameters
    ----------
    out : path
        The output folder.
    owned : sequence of str or re.Pattern, optional
        The files a run of this kind writes, relative to ``out``: glob patterns (exact names, mostly),
        or regular expressions that a file's path (``/``-separated) must match whole, where a glob
        cannot say it (``runs/NAME_seed(0|[1-9][0-9]*)\\.csv``: digits only). Given, the staged files
        replace their namesakes in ``out`` (created if missing), and the files of ``out`` that match
        but this run did not write (an earlier run's figures or experiment files) are removed; other
        files in ``out`` are kept. None: ``out`` is replaced as a whole.

    Raises
    ------
    OSError
        ``out`` is a file, or a staged file's place in ``out`` is a directory or a file this process
        may not write (checked before anything in ``out`` changes); or a file in ``out`` could not be
        replaced or moved (on Windows, one that another program holds open), named, after the files
        moved until then were put back.
    """
    out = followed(out) if Path(out).is_symlink() else Path(out)
    probe_output_folder(out)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        try:
            yield tmp
        except OSError as exc:  # a file of the run's written into the staging folder: named in ``out``
            if exc.errno not in _NO_ROOM:
                raise
            if exc.filename is None:
                shown = out
            else:  # a file elsewhere (another disk) keeps its own name
                written, staging = Path(os.path.abspath(exc.filename)), Path(os.path.abspath(tmp))
                if not written.is_relative_to(staging):
                    raise
                shown = out / written.relative_to(staging)
            raise _no_room(exc, shown) from exc
        if owned is None:
            os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp's 0700: the mode mkdir would give the folder
            if not out.exists():
                tmp.rename(out)
                return
            old = out.with_name(f".{out.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            with held_interrupts():  # no Ctrl-C between the two renames: out would be missing
                try:
                    out.rename(old)
                except OSError as exc:
                    raise _not_replaced(exc, out, out) from None
                try:
                    tmp.rename(out)
                except OSError as exc:
                    old.rename(out)
                    raise _not_replaced(exc, out, out) from None
                shutil.rmtree(old, ignore_errors=True)  # before a held Ctrl-C is raised
            return
        new = sorted(p.relative_to(tmp) for p in tmp.rglob("*") if p.is_file())
        # before any rename: one failing half-way would leave two runs mixed
        targets = {rel: _target(out / rel) for rel in new}
        out.mkdir(exist_ok=True)
        globs = [pattern for pattern in owned if isinstance(pattern, str)]
        expressions = [pattern for pattern in owned if not isinstance(pattern, str)]
        matched = {p for pattern in globs for p in out.glob(pattern)}
        if expressions:
            matched |= {p for p in out.rglob("*") if any(e.fullmatch(p.relative_to(out).as_posix()) for e in expressions)}
        stale = sorted(p for p in matched if p.is_file() and p.relative_to(out) not in targets)
        _replace_together(tmp, out, targets, stale)
    finally:
        _remove_uninterrupted(tmp)


def _not_replaced(exc: OSError, path: Path, kept: Path) -> OSError:
    """Why ``path`` could not be replaced or moved, and that ``kept`` (the file, or the output folder
    it is in) holds the earlier outputs whole; ``exc`` itself where it says so already."""
    if getattr(exc, "tapmuscle_named", False):
        return exc
    why = exc.strerror or str(exc)
    held = ("; on Windows a file that another program holds open, a spreadsheet or an image viewer, cannot "
            "be): close it and run again" if isinstance(exc, PermissionError) else ")")
    named = type(exc)(exc.errno, f"{path} could not be replaced ({why}{held}; {kept} is left as it was")
    named.tapmuscle_named = True
    return named


def _replace_together(staged: Path, out: Path, targets: dict[Path, tuple[Path, int]], stale: Sequence[Path]) -> None:
    """Put the ``staged`` files in place of their ``targets`` (relative path -> file replaced and its
    mode) and remove the ``stale`` ones, all or none. Each file replaced or removed is first moved
    aside (a link's target elsewhere copied aside), so that a rename failing half-way (on Windows, a
    file another program holds open cannot be replaced or moved, which ``_target`` cannot see)
    puts back what had moved: ``out`` then holds the earlier run whole, not a mix of two. Ctrl-C is
    held meanwhile (an interrupt between a move and its record would lose the file) and raised after.
    Should putting back fail too, the error names each file left and where its earlier version is."""
    root = Path(os.path.realpath(out))
    aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.replaced.", dir=out.parent))
    moved: list[tuple[Path, Path, bool]] = []  # (file, its copy aside, moved rather than copied)
    placed: list[Path] = []  # new files where none was
    written: set[Path] = set()  # files outside out written in place (a link's target)
    made: list[Path] = []  # folders made for new files
    current = out
    with held_interrupts():
        try:
            # the files replaced (a link's target: the link stays), once each (a link to another
            # file of the run), then the stale ones themselves (a link: the link goes)
            existed = {t for t, _ in targets.values() if t.exists()}
            replaced = {os.path.realpath(t): t for t, _ in targets.values() if t in existed}  # in the run's order
            reals = {os.path.realpath(t) for t, _ in targets.values()}
            for current, inside in [(t, Path(real).is_relative_to(root)) for real, t in replaced.items()] \
                    + [(p, True) for p in stale if os.path.realpath(p) not in reals]:  # not a file the run writes
                keep = aside / str(len(moved))
                moved.append((current, keep, inside))  # first: no file is ever aside unrecorded
                if inside:
                    os.replace(current, keep)
                else:  # a link's target, maybe on another file system: a copy
                    shutil.copyfile(current, keep)
            for rel, (current, mode) in targets.items():
                for parent in reversed(current.parents):
                    if not parent.exists():
                        parent.mkdir()
                        made.append(parent)
                if current == out / rel:
                    os.chmod(staged / rel, mode)
                    os.replace(staged / rel, current)
                else:  # a link's target, maybe on another file system: written beside it, then renamed
                    with atomic_path(current) as t:
                        shutil.copyfile(staged / rel, t)
                    written.add(current)
                if current not in existed:
                    placed.append(current)
        except BaseException as exc:
            left = _put_back(moved, placed, written, made)
            if not any(aside.iterdir()):
                shutil.rmtree(aside, ignore_errors=True)
            if left:
                raise OSError(errno.EIO, f"{current} could not be replaced ({exc}), and putting back the earlier "
                                         f"outputs failed: {'; '.join(left)}") from exc
            shutil.rmtree(aside, ignore_errors=True)
            if isinstance(exc, OSError):
                raise _not_replaced(exc, current, out) from exc
            raise
        shutil.rmtree(aside, ignore_errors=True)  # before a held Ctrl-C is raised


def _put_back(moved: Sequence[tuple[Path, Path, bool]], placed: Sequence[Path], written: set[Path],
              made: Sequence[Path]) -> list[str]:
    """Undo :func:`_replace_together`'s moves as far as it got, every one tried; what could not be
    undone, in words."""
    left = []
    for path in placed:
        try:
            path.unlink(missing_ok=True)
        except OSError as exc:
            left.append(f"{path} is the new run's ({exc.strerror or exc})")
    for path, keep, inside in reversed(moved):
        if not os.path.lexists(keep):
            continue  # the move or copy itself failed: the file never left
        try:
            if inside:
                os.replace(keep, path)
            elif path in written:  # a link's target the run wrote
                with atomic_path(path) as t:
                    shutil.copyfile(keep, t)
            keep.unlink(missing_ok=True)  # a copy, put back or never needed
        except OSError as exc:
            left.append(f"{path} is the new run's or missing ({exc.strerror or exc}); its earlier version is {keep}")
    for folder in reversed(made):
        try:
            folder.rmdir()
        except OSError:
            pass
    return left


def _remove_uninterrupted(folder: Path) -> None:
    """Remove the staging ``folder``, with Ctrl-C ignored meanwhile in the main thread: a Ctrl-C held
    down also lands in this clean-up, and an interrupted removal leaves the hidden folder next to the
    output. An interrupt that stopped the run is raised after it."""
    # a handler not installed from Python (an embedding host's) cannot be put back: left as it is
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        shutil.rmtree(folder, ignore_errors=True)
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        shutil.rmtree(folder, ignore_errors=True)
    finally:
        signal.signal(signal.SIGINT, previous)
