"""Inside the FMU, before anything else: find the packages, and say clearly when one is missing.

``fmi_slave/__init__.py`` calls :func:`setup` first, so it runs before pythonfmu, numpy or the
numerics are imported (the slave scripts import ``fmi_slave`` first). It uses only the standard
library's pure-Python modules.

* In a non-Python FMI host the interpreter was started by the FMU (the loader library made by
  ``build_scripts/native_host.py`` already made libpython's symbols global and chose the building
  environment's interpreter, a venv's ``bin/python``, whose site-packages Python then adds itself).
  The site-packages recorded at build time in ``resources/tapmuscle_native.json`` are added too, with
  ``site.addsitedir`` (those that exist and are not on sys.path yet; ``.pth`` files are honoured):
  ahead of the interpreter's own when the FMU chose the interpreter (the building venv, or its base
  interpreter when the venv is gone), after them when ``TAPMUSCLE_PYTHON`` names one: a user naming
  a venv gets that venv's numpy, scipy, osqp, and the recorded ones only for a package it lacks.
* ``TAPMUSCLE_SITE_PACKAGES`` (directories separated by ``os.pathsep``) replaces the recorded list, in
  any host; set but empty, it adds none.
* In a Python host (fmpy) without the override nothing is added: the host's own environment rules;
  nor in a host on another operating system than the build's (a Windows C host: its Python's own).
* In every host, a finder of last resort on ``sys.meta_path`` turns "No module named 'numpy'" (or
  scipy, osqp) into a message saying what to install (every one of the three that is missing, located
  without importing them) and where it looked; the exception makes
  pythonfmu's ``fmi2Instantiate`` log it through the host's logger and return NULL.

Outside an FMU (no ``tapmuscle_native.json`` beside the ``fmi_slave`` package) nothing happens.
"""

from __future__ import annotations

import json
import os
import site
import sys

__all__ = ["CONFIG_NAME", "DEPENDENCIES", "PYTHON_ENV", "SITE_ENV", "MissingDependencyFinder", "is_embedded", "python_command",
           "setup"]

CONFIG_NAME = "tapmuscle_native.json"
SITE_ENV = "TAPMUSCLE_SITE_PACKAGES"
#: The interpreter a C host's FMU starts, where the user names it (read by the loader library).
PYTHON_ENV = "TAPMUSCLE_PYTHON"
#: Third-party packages the FMUs' numerics import (module name = pip name).
DEPENDENCIES = ("numpy", "scipy", "osqp")

_done = False


def _resources() -> str:
    """The FMU's resources folder: this package's parent, or (inside a built FMU, where the code is
    the FMU's own package under resources/) the one above it, whichever holds :data:`CONFIG_NAME`."""
    parent = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    above = os.path.dirname(parent)
    return above if os.path.isfile(os.path.join(above, CONFIG_NAME)) else parent


def is_embedded() -> bool:
    """True when the interpreter was started by an FMU (``Py_Initialize`` in a C host), not by a
    ``python`` command: such an interpreter has an empty ``sys.orig_argv``."""
    return not getattr(sys, "orig_argv", ["python"])


def _site_dirs(config: dict) -> list[str] | None:
    """Directories to add: the override, or (embedded only) the recorded ones; None: add nothing."""
    override = os.environ.get(SITE_ENV)
    if override is not None:
        return [d for d in override.split(os.pathsep) if d]
    # the recorded directories are the building machine's: another operating system (a Windows host of
    # an FMU built on Linux) has its own, and may even reach those paths (Wine's Z: drive)
    if is_embedded() and config.get("platform", "linux") == sys.platform:
        return list(config.get("site_packages", []))
    return None


def python_command() -> str:
    """The interpreter the FMU runs in, as a command for ``-m pip install`` advice.

    ``sys.executable``, unless it is not a Python: an interpreter started by the FMU in a Windows C
    host reports the host's program there (``fmi_host.exe``, a simulation tool's executable). Its own
    executable then lies in its prefix (``python.exe`` on Windows, ``bin/python3`` elsewhere).
    """
    executable = sys.executable or ""
    if os.path.basename(executable).lower().startswith("python"):
        return executable
    names = ("python.exe",) if sys.platform == "win32" else ("bin/python3", "bin/python")
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        for name in names:
            candidate = os.path.join(prefix, name)
            if os.path.isfile(candidate):
                return candidate
    return executable or "python3"


def _venv_version(python: str) -> str | None:
    """The ``major.minor`` of the virtual environment ``python`` belongs to (its ``pyvenv.cfg``), or None."""
    try:
        with open(os.path.join(os.path.dirname(os.path.dirname(python)), "pyvenv.cfg"), encoding="utf-8") as f:
            for line in f:
                key, _, value = line.partition("=")
                if key.strip() in ("version", "version_info"):
                    return ".".join(value.strip().split(".")[:2])
    except OSError:
        pass
    return None


def _install_advice(python: str, name: str) -> str:
    """How to install ``name`` into ``python``: pip, or where the interpreter has no pip (a uv
    environment) uv's, or where it is the system's (PEP 668 refuses pip there) a venv of its own."""
    import sysconfig

    if sys.prefix == sys.base_prefix and os.path.isfile(os.path.join(sysconfig.get_path("stdlib"),
                                                                      "EXTERNALLY-MANAGED")):
        return (f"this Python is the system's, which refuses pip (externally managed, PEP 668): make an "
                f"environment of your own, python{sys.version_info[0]}.{sys.version_info[1]} -m venv DIR && DIR/bin/pip "
                f"install {' '.join(DEPENDENCIES)}, and set TAPMUSCLE_PYTHON=DIR/bin/python")
    if not any(os.path.isdir(os.path.join(d, "pip")) for d in site.getsitepackages()):
        return (f"this Python has no pip (a uv environment, an embeddable distribution): uv pip install --python "
                f"{python} {name}, or {python} -m ensurepip and then -m pip install {name}")
    return f"{python} -m pip install {name}"


def _context(config: dict) -> str:
    """Why a package may be missing in an interpreter the FMU started (a C host): the environment that
    built the FMU is gone or is now another Python version, or PYTHONHOME points elsewhere."""
    if not config or not is_embedded():
        return ""
    version = "%d.%d" % sys.version_info[:2]
    built, notes = config.get("python", ""), []
    fix = (f"set TAPMUSCLE_PYTHON to a CPython {version} python with {', '.join(DEPENDENCIES)}, or build the FMUs "
           "again in your environment (tapmuscle build)")
    now = _venv_version(built) if built else None
    if built and not os.path.exists(built):
        notes.append(f"The Python that built this FMU, {built}, is gone (an environment moved or deleted, or a "
                     f"cache cleaned); this host started {python_command()} instead: {fix}.")
    elif now not in (None, version):
        notes.append(f"The environment that built this FMU, {os.path.dirname(os.path.dirname(built))}, is now "
                     f"CPython {now}, and the FMU runs CPython {version}, whose packages it does not have: {fix}.")
    if os.environ.get("PYTHONHOME"):
        notes.append(f"PYTHONHOME={os.environ['PYTHONHOME']} is set: the FMU's Python takes its standard library "
                     "and packages from there.")
    return " " + " ".join(notes) if notes else ""


class MissingDependencyFinder:
    """Last entry of ``sys.meta_path``: asked only when no other finder has the module. For the
    top-level packages in ``names`` it raises ModuleNotFoundError with what to install, and, in an
    interpreter the FMU started, why it may be missing (``config``: the FMU's recorded build)."""

    #: Marks every copy of this class: each FMU carries its own package (fmu.md, "One Python per
    #: process"), so two FMUs in one process add finders of two classes, which must not ask each other.
    tapmuscle_last_resort = True

    def __init__(self, names: tuple[str, ...] = DEPENDENCIES, config: dict | None = None) -> None:
        self.names = tuple(names)
        self.config = dict(config or {})

    def find_spec(self, fullname, path=None, target=None):
        if path is not None or fullname not in self.names:
            return None
        # every package missing now, not only the first imported: one round of installing, not three
        missing = [fullname, *(n for n in self.names if n != fullname and not self._findable(n))]
        names, them = ", ".join(missing), "it" if len(missing) == 1 else "them"
        python = python_command()
        advice, context = _install_advice(python, " ".join(missing)), _context(self.config)
        named = ""
        if is_embedded() and PYTHON_ENV not in advice + context:
            # the interpreter a C host starts can be chosen; in a Python host it is the host's own
            named = (f"set {PYTHON_ENV} to the python of a CPython {sys.version_info[0]}.{sys.version_info[1]} "
                     f"environment that has {them}, or ")
        raise ModuleNotFoundError(
            f"tapmuscle FMU: cannot import {names}; install {them} into the Python the FMU uses: {advice} (or "
            f"{named}set {SITE_ENV} to site-packages directories that have {them}, separated by '{os.pathsep}'; "
            f"searched: {os.pathsep.join(p for p in sys.path if p)}){context}",
            name=fullname)

    def _findable(self, name: str) -> bool:
        """Whether a finder ahead of this one locates top-level ``name`` (without importing it)."""
        if name in sys.modules:
            return True
        for finder in sys.meta_path:
            if getattr(finder, "tapmuscle_last_resort", False) or not hasattr(finder, "find_spec"):
                continue
            try:
                if finder.find_spec(name, None) is not None:
                    return True
            except Exception:  # noqa: BLE001 - another finder's failure must not replace the install advice
                continue
        return False

    def invalidate_caches(self) -> None:
        pass


def _recorded_first() -> bool:
    """Whether the directories :func:`_site_dirs` gives go ahead of the interpreter's own: the
    override always (it names what to use); the recorded ones unless the user named the interpreter
    (``TAPMUSCLE_PYTHON``), whose own packages are what the user asked for."""
    return os.environ.get(SITE_ENV) is not None or not os.environ.get(PYTHON_ENV)


def _add_site_dirs(dirs, ahead: bool = True) -> None:
    """``site.addsitedir`` each existing directory (``.pth`` files honoured), then, if ``ahead``, move
    what was added ahead of the interpreter's own site-packages (else they stay after them)."""
    before = set(sys.path)
    for d in dirs:
        if os.path.isdir(d) and d not in sys.path:
            site.addsitedir(d)
    added = [p for p in sys.path if p not in before]
    if not added or not ahead:
        return
    rest = [p for p in sys.path if p in before]
    own = set(site.getsitepackages())
    if site.ENABLE_USER_SITE:
        own.add(site.getusersitepackages())
    i = next((k for k, p in enumerate(rest) if p in own), len(rest))
    sys.path[:] = rest[:i] + added + rest[i:]


def setup() -> None:
    """Prepare this interpreter for the FMU's code (see the module docstring); runs once."""
    global _done
    if _done:
        return
    _done = True
    config_path = os.path.join(_resources(), CONFIG_NAME)
    if not os.path.isfile(config_path):
        return  # not inside a prepared FMU
    with open(config_path, encoding="utf-8") as f:
        config = json.load(f)
    _add_site_dirs(_site_dirs(config) or (), ahead=_recorded_first())
    if not any(isinstance(f, MissingDependencyFinder) for f in sys.meta_path):
        sys.meta_path.append(MissingDependencyFinder(config=config))
