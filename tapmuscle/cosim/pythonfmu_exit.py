"""Exit of a Python host that ran an FMU built with pythonfmu's own binary (Linux).

pythonfmu 0.7.0's Linux binary releases its interpreter holder twice when the process exits: its
global ``shared_ptr`` is destroyed by the C++ exit handlers, and then ``finalizePythonInterpreter``
(in the binary's fini array, run later by the dynamic loader) assigns ``nullptr`` to that destroyed
``shared_ptr``, decrementing a reference count in the block just freed. valgrind shows the invalid
read in every fmpy process that instantiated such an FMU; where the freed block sits in one of
glibc's bins the decrement corrupts the heap's lists and the host aborts after its work is done
("corrupted double-linked list", exit status -6), rarely and at random. (On Windows the binary's
``DllMain`` releases the holder before the C runtime destroys it: no defect.)

The project's own FMUs carry a loader that runs ``finalizePythonInterpreter`` first
(docs/fmu-native-hosts.md). An FMU built elsewhere with plain pythonfmu has the defect; a host
cannot change the FMU, but it can run the same release first: :func:`release_at_exit` registers it
with :mod:`atexit`, which Python runs at interpreter shutdown, before the C++ exit handlers. The
release is the one the binary itself does at exit, only earlier, and a second release finds the
holder empty. Instances still alive keep their own share of the holder.
"""

from __future__ import annotations

import atexit
import ctypes
import os
import sys
import threading
from pathlib import Path

__all__ = ["RELEASE_SYMBOL", "release_at_exit"]

#: The function pythonfmu's binary exports to release its interpreter holder.
RELEASE_SYMBOL = "finalizePythonInterpreter"

_lock = threading.Lock()
#: library path -> its release function (whose ctypes library object keeps the library loaded), or
#: None for a library found without one (not probed again: the master loads the same FMUs many times)
_registered: dict[str, ctypes._CFuncPtr | None] = {}  # type: ignore[name-defined]


def release_at_exit(folder: str | Path, model_identifier: str) -> bool:
    """Release the pythonfmu interpreter holder of an extracted FMU's binary, already loaded by the
    host, when this Python process exits (Linux).

    Parameters
    ----------
    folder : str or Path
        The FMU's extracted folder (fmpy's ``unzipDirectory``).
    model_identifier : str
        The interface's ``modelIdentifier``: the binary is
        ``binaries/<platform>/<model_identifier><extension>`` (fmpy's platform and extension).

    Returns
    -------
    bool
        True if that binary is loaded and exports pythonfmu's :data:`RELEASE_SYMBOL` (its release
        now runs at exit, once per binary however often this is called); False on another platform,
        for a binary not loaded, and for any other binary, which is left as it was (the host can
        still unload it).

    Notes
    -----
    The binary gets one more reference here, never dropped, so that it is still loaded at exit
    whatever the host does with its own (pythonfmu's binary stays loaded once it has instantiated
    anyway).
    """
    if sys.platform != "linux":
        return False
    from fmpy import platform, sharedLibraryExtension  # noqa: PLC0415 - fmpy's import is slow; a host has it

    key = str(Path(folder, "binaries", platform, model_identifier + sharedLibraryExtension).resolve())
    with _lock:
        if key in _registered:
            return _registered[key] is not None
        try:  # a reference to the host's copy only: nothing is loaded here
            library = ctypes.CDLL(key, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)
        except OSError:
            return False
        release = getattr(library, RELEASE_SYMBOL, None)
        if release is None:
            _dlclose(library._handle)
            _registered[key] = None
            return False
        release.argtypes, release.restype = [], None
        _registered[key] = release
        atexit.register(release)
    return True


def _dlclose(handle: int) -> None:
    """Drop one reference to a library opened with ctypes (which never closes its own)."""
    dlclose = ctypes.CDLL(None).dlclose
    dlclose.argtypes, dlclose.restype = [ctypes.c_void_p], ctypes.c_int
    dlclose(handle)
