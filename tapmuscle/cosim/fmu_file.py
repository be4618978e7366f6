"""Check an FMU file before anything loads it: a broken one is named, the process survives.

The dynamic loader maps a shared library into the process; a truncated binary then kills the
process with SIGBUS before Python can say anything (and leaves its extraction folders behind). So
:func:`check_fmu_file`, before the first extraction of a file,

1. tests the zip archive (reads every member: its CRC and its compressed stream);
2. checks that ``modelDescription.xml`` is there and the binary for this platform (co-simulation's,
   else model exchange's)
   exists, is an ELF file of the right class and for this machine (an FMU built on x86-64 Linux
   carries x86-64 binaries in ``linux64``, which an aarch64 host cannot load), and is not shorter
   than its own header says (its section-header table ends within the file);
3. loads the binary once in a *child* process (``ctypes.CDLL``), with a time limit.

A failure raises :class:`~tapmuscle.cosim.spec.ScenarioError` ("... is not a loadable FMU: ...")
naming the file and the member. A file that passed is remembered by its SHA-256 digest for the
rest of the process, so a sweep of many runs checks each FMU once.
"""

from __future__ import annotations

import hashlib
import os
import platform
import re
import signal
import struct
import subprocess
import sys
import tempfile
import zipfile
import zlib
from pathlib import Path

from build_scripts.native_host import elf_machine, machine_name, python_machine
from tapmuscle.cosim.extraction_folder import extraction_root
from tapmuscle.cosim.spec import ScenarioError

__all__ = ["check_fmu_file", "LOAD_TIMEOUT_S"]

#: Longest a child process may take to load a binary [s] (pythonfmu's start Python; ~0.1 s here).
LOAD_TIMEOUT_S = 60.0

_CHECKED: set[str] = set()
"""Digests of the FMU files that passed in this process."""


def _platform_folder() -> str:
    if sys.platform.startswith("linux"):
        return "linux64"
    if sys.platform == "darwin":
        return "darwin64"
    return "win64"


def _elf_problem(data: bytes) -> str | None:
    """Why ``data`` is not a complete 64-bit little-endian ELF file, or None."""
    if len(data) < 64 or data[:4] != b"\x7fELF":
        return f"not an ELF shared library ({len(data)} bytes, starts {data[:4]!r})"
    if data[4] != 2 or data[5] != 1:
        return "not a 64-bit little-endian ELF file"
    ours, theirs = python_machine(), elf_machine(data)
    if ours is not None and theirs != ours:
        return (f"built for {machine_name(theirs)}, and this machine is {machine_name(ours)} "
                f"({platform.machine()}): build the FMUs on this machine (tapmuscle build), which compiles "
                "their binary for it")
    shoff, = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
    end = shoff + shentsize * shnum
    if end > len(data):
        return f"truncated: {len(data)} bytes, its header says at least {end}"
    return None


def _load_in_child(binaries: dict[str, bytes], main: str) -> str | None:
    """Write the platform's binaries into a scratch folder and load ``main`` with ``ctypes`` in a child
    process (its sibling libraries resolve next to it); why it failed, or None."""
    with tempfile.TemporaryDirectory(prefix="tapmuscle_fmucheck_", dir=extraction_root()) as folder:
        for name, data in binaries.items():
            (Path(folder) / name).write_bytes(data)
        try:
            proc = subprocess.run([sys.executable, "-c", "import ctypes, sys; ctypes.CDLL(sys.argv[1])",
                                   str(Path(folder) / main)], capture_output=True, text=True, timeout=LOAD_TIMEOUT_S,
                                  cwd=folder)
        except subprocess.TimeoutExpired:
            return f"loading it took longer than {LOAD_TIMEOUT_S:g} s"
    if proc.returncode == 0:
        return None
    if proc.returncode < 0:
        return f"the dynamic loader died of {signal.Signals(-proc.returncode).name} loading it"
    last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
    return f"the dynamic loader refused it: {last[:200]}" + _remedy(last)


def _reader_failure(exc: Exception, shown: int = 3) -> str:
    """fmpy's reason for refusing a modelDescription.xml, on one line: its first line, then the first
    ``shown`` problems it lists under it (a ValidationError's first line alone says only that there
    are some)."""
    lines = [line.strip().removeprefix("- ") for line in str(exc).splitlines() if line.strip()] or [type(exc).__name__]
    head, problems = lines[0][:200], [p[:300] for p in lines[1:]]
    more = f"; and {len(problems) - shown} more" if len(problems) > shown else ""
    return f"{head} {'; '.join(problems[:shown])}{more}".strip()


def _remedy(loader_message: str) -> str:
    """What to do about a dynamic loader's refusal, where its message tells (else "")."""
    newer = re.search(r"version .?GLIBC_(\d+\.\d+).? not found", loader_message)
    if newer:
        here = platform.libc_ver()[1]
        return (f" (built on a newer Linux: it needs glibc {newer.group(1)}, this machine has "
                f"{here or 'an older one'}; build the FMUs on this machine: tapmuscle build)")
    return ""


def check_fmu_file(path: str | Path) -> None:
    """Raise ScenarioError unless ``path`` is an FMU whose binary loads: its co-simulation binary, or
    its model-exchange one when it offers only that (module docstring).

    Parameters
    ----------
    path : path
        The ``.fmu`` file.
    """
    path = Path(path)
    raw = path.read_bytes()
    digest = hashlib.sha256(raw).hexdigest()
    if digest in _CHECKED:
        return
    where = f"{path}: is not a loadable FMU:"
    try:
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():  # every member's CRC (what ZipFile.testzip does, naming the member)
                try:
                    with z.open(info) as fh:
                        while fh.read(1 << 20):
                            pass
                except (zipfile.BadZipFile, zlib.error, EOFError) as exc:
                    raise ScenarioError(f"{where} the archive is damaged ({info.filename}: "
                                        f"{str(exc).splitlines()[0][:100]})") from None
            names = set(z.namelist())
            if "modelDescription.xml" not in names:
                raise ScenarioError(f"{where} it has no modelDescription.xml")
            version = re.search(rb'fmiVersion\s*=\s*["\']([^"\']*)["\']', z.read("modelDescription.xml"))
            if version is not None and not version.group(1).startswith(b"2."):
                shown = version.group(1).decode("utf-8", "replace")[:20]
                raise ScenarioError(f"{path}: is an FMI {shown} FMU (its modelDescription.xml's fmiVersion): "
                                    "tapmuscle's master runs FMI 2.0 FMUs; export it as FMI 2.0 co-simulation")
            from fmpy import read_model_description

            try:
                md = read_model_description(str(path))
            except UnicodeEncodeError as exc:  # lxml names the member by the working folder's path
                raise ScenarioError(
                    f"{path}: its modelDescription.xml cannot be read here: {exc} (a path, the working folder "
                    f"{os.getcwd()!r} or the file's, is not valid in this process's file-system encoding, "
                    f"{sys.getfilesystemencoding()}): run in a UTF-8 locale (LC_ALL=C.UTF-8, or without "
                    "PYTHONUTF8=0), or from a folder with an ASCII name") from None
            except Exception as exc:  # noqa: BLE001 - any other reader failure is a bad FMU
                raise ScenarioError(f"{where} {_reader_failure(exc)}") from None
            interface = md.coSimulation or md.modelExchange
            if interface is None:
                raise ScenarioError(f"{where} it offers neither co-simulation nor model exchange")
            ext = {"linux64": ".so", "darwin64": ".dylib", "win64": ".dll"}[_platform_folder()]
            folder = f"binaries/{_platform_folder()}/"
            member = f"{folder}{interface.modelIdentifier}{ext}"
            if member not in names:
                raise ScenarioError(f"{where} it has no {member} for this platform")
            binaries = {n[len(folder):]: z.read(n) for n in names
                        if n.startswith(folder) and "/" not in n[len(folder):] and n != folder}
    except zipfile.BadZipFile as exc:
        raise ScenarioError(f"{where} not a zip archive ({exc})") from None
    if ext == ".so":
        for name, data in sorted(binaries.items()):
            if ".so" in name:
                problem = _elf_problem(data)
                if problem is not None:
                    raise ScenarioError(f"{where} {folder}{name} is {problem}")
    problem = _load_in_child(binaries, Path(member).name)
    if problem is not None:
        raise ScenarioError(f"{where} {member}: {problem}")
    _CHECKED.add(digest)
