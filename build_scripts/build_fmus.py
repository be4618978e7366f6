"""Build ``MusclePlant.fmu`` and ``AMPCController.fmu`` with pythonfmu, then finish them.

Each FMU carries the numerics package it wraps (with its slave module) and the shared ``fmi_slave``
shell in ``resources/``: the project's code travels inside the FMU; the host needs a Python with numpy
(and scipy, osqp for the controller) and pythonfmu's runtime, which pythonfmu also packs. All of it
lives in a package of the FMU's own build (:func:`private_package`), so that the FMU runs its own code
in a process that has imported the project's packages, or another build of them.

pythonfmu's entry script is not the slave module itself but an import of its class
(:func:`entry_script`). pythonfmu 0.7 finds the slave class at every ``fmi2Instantiate`` by executing
the entry script again (globals: the entry module's dict; locals: a fresh dict), takes the class it
finds there by name from the module, keeps a list of the class's MRO it never frees, and releases a
reference to the module's dict that ``PyModule_GetDict`` never gave it. With the whole slave class in
the entry script, every instantiation left a new copy of the class behind, about 40 kB for the
controller (its methods hold the dict, which is what kept the dict alive). An import defines no new
class, and the entry gives the dict back the reference pythonfmu takes, once per execution.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import os
import shutil
import stat
import sys
import tempfile
import time
import tomllib
import warnings
import zipfile
from contextlib import contextmanager
from importlib import metadata
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path
from typing import Any, Iterator, Sequence

from .model_description import content_guid, finish_model_description
from .native_host import EXPORT_VARIABLE, NativeHostWarning, building_python
from .own_folder import UntrustedFolderError, own_folder, remove_foreign

__all__ = ["FMUS", "build_fmus", "cached_fmus", "entry_script", "private_package", "project_version",
           "slave_metadata", "user_cache_root"]

ROOT = Path(__file__).resolve().parents[1]

#: FMU name (= slave class) -> (slave script, packages shipped in resources)
FMUS: dict[str, tuple[str, tuple[str, ...]]] = {
    "MusclePlant": ("fmu_plant/plant_slave.py", ("fmu_plant", "fmi_slave")),
    "AMPCController": ("fmu_controller/controller_slave.py", ("fmu_controller", "fmi_slave")),
}

_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def entry_script(name: str, private: str) -> str:
    """Source of pythonfmu's entry script for FMU ``name`` whose code lives in the package ``private``
    (:func:`private_package`): the slave class imported from its module, and one reference added to
    the entry's own module dict per execution (module docstring)."""
    script = Path(FMUS[name][0])
    module = ".".join(script.with_suffix("").parts)
    return (f'"""pythonfmu\'s entry script of {name}.fmu, written by build_scripts/build_fmus.py: the slave\n'
            f"class {module}.{name}, of this FMU's own copy {private}. pythonfmu executes this file at every\n"
            "instantiation and each time releases a reference to its module dict that it never took: give it back.\n"
            '"""\n\n'
            "import ctypes\n\n"
            f"from {private} import fmi_slave  # noqa: F401 - first: prepares the embedded interpreter in non-Python hosts\n"
            f"from {private}.{module} import {name}  # noqa: F401 - the slave class pythonfmu takes\n\n"
            "ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))\n")


def private_package(name: str, sources: Path) -> str:
    """The name of FMU ``name``'s own package of its code, from a digest of ``sources`` (the copied
    packages): ``_tapmuscle_<name>_<12 hex digits>``.

    Python caches modules by name, process-wide. Under their own names (``fmu_plant``, ``pythonfmu``)
    the packages an FMU carries would meet those of its host: an FMU loaded in a process that has
    imported ``fmu_plant`` (tapmuscle's own master, a notebook) would run the host's copy instead of
    its own (another version's code, silently), and one loaded first would leave its copy, in a
    temporary folder its host deletes, as the host's ``fmu_plant``. A name per build keeps each FMU's code its
    own, and two builds of one FMU apart in one process.
    """
    return f"_tapmuscle_{name.lower()}_{_digest(sources).hex()[:12]}"


#: Packages whose absolute imports an FMU's own copy redirects into its private package.
_PRIVATE = ("fmu_plant", "fmu_controller", "fmi_slave", "pythonfmu")


def _redirect_imports(root: Path, private: str) -> None:
    """Rewrite, in every ``.py`` file under ``root``, the absolute imports of :data:`_PRIVATE`
    packages to ``private``: ``from fmu_plant.x import y`` -> ``from P.fmu_plant.x import y``,
    ``import fmi_slave`` -> ``from P import fmi_slave``. The statements are found by ``ast`` (not in
    strings or docstrings); a form that cannot be redirected (``import fmu_plant.x``) is refused."""
    for path in sorted(root.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        lines = text.splitlines(keepends=True)
        for node in ast.walk(ast.parse(text, filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module.split(".")[0] in _PRIVATE:
                line = lines[node.lineno - 1]
                head = line[:node.col_offset] + "from " + node.module
                assert line.startswith(head), f"{path}:{node.lineno}: unexpected import layout"
                lines[node.lineno - 1] = line[:node.col_offset] + f"from {private}.{node.module}" + line[len(head):]
            elif isinstance(node, ast.Import) and any(a.name.split(".")[0] in _PRIVATE for a in node.names):
                line = lines[node.lineno - 1]
                alias = node.names[0]
                head = line[:node.col_offset] + "import " + alias.name
                if len(node.names) != 1 or "." in alias.name or not line.startswith(head):
                    raise ValueError(f"{path}:{node.lineno}: write this import as 'from {alias.name.split('.')[0]} "
                                     f"import ...' so that the FMU can carry it under its own name")
                lines[node.lineno - 1] = line[:node.col_offset] + f"from {private} import {alias.name}" + line[len(head):]
        path.write_text("".join(lines), encoding="utf-8")


def _shipped(folder: str, names: list[str]) -> set[str]:
    """``shutil.copytree``'s ``ignore``: what an FMU does not carry. It carries the Python sources,
    and the plant's compiled sub-step (setup.py) built for this interpreter's exact ABI, the one the
    FMU's binary links (a CPython 3.11 on x86_64 Linux): the same bits as the Python sub-step, which
    the FMU runs wherever the compiled one does not load (another platform, an older C library)."""
    compiled = "_ros34pw2" + EXTENSION_SUFFIXES[0]
    return {n for n in names if n == "__pycache__" or (n.endswith((".pyc", ".c", ".so", ".pyd")) and n != compiled)}


@contextmanager
def _build_folder() -> Iterator[Path]:
    """A temporary folder for one FMU's build, removed whole even when Ctrl-C lands in its removal
    (``TemporaryDirectory``'s left 2 MB behind then, in one of five interrupts of a build): the
    removal finishes and the interrupt is raised after it."""
    folder = Path(tempfile.mkdtemp(prefix="tapmuscle-build-"))
    try:
        yield folder
    finally:
        interrupted = False
        while folder.exists():
            try:
                shutil.rmtree(folder, ignore_errors=True)
                break
            except KeyboardInterrupt:
                interrupted = True
        if interrupted:
            raise KeyboardInterrupt


def _clean_copy(src: Path, dst: Path) -> None:
    """``src`` copied to ``dst`` without what an FMU does not carry (:func:`_shipped`), every copy
    writable by its owner: the build rewrites the copies' imports, and a read-only checkout or install
    (a Nix store, a read-only CI workspace, ``chmod a-w``) would lend them its modes."""
    shutil.copytree(src, dst, ignore=_shipped, copy_function=shutil.copyfile)
    for path in (dst, *dst.rglob("*")):
        path.chmod(path.stat().st_mode | stat.S_IWUSR)


def slave_metadata(name: str) -> dict[str, dict[str, Any]]:
    """``variable_meta`` of FMU ``name``'s slave class (instantiated once, outside any FMU)."""
    script = ROOT / FMUS[name][0]
    spec = importlib.util.spec_from_file_location(f"_tapmuscle_build_{script.stem}", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return getattr(module, name)(instance_name="build").variable_meta


def _files(tree: Path) -> list[Path]:
    return sorted((f for f in tree.rglob("*") if f.is_file() and "__pycache__" not in f.parts),
                  key=lambda f: f.relative_to(tree).as_posix())


def _digest(tree: Path) -> bytes:
    h = hashlib.sha256()
    for f in _files(tree):
        h.update(f.relative_to(tree).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.digest()


def _zip(tree: Path, target: Path) -> None:
    with zipfile.ZipFile(target, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for f in _files(tree):
            info = zipfile.ZipInfo(f.relative_to(tree).as_posix(), date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o755 if f.suffix in (".so", ".dll") else 0o644) << 16
            z.writestr(info, f.read_bytes())


def _prepare_native_hosts(tree: Path) -> None:
    try:
        from .native_host import prepare_for_native_hosts
    except ImportError:  # pragma: no cover - the module is part of the project; kept optional for bisecting
        return
    prepare_for_native_hosts(tree)


def _pythonfmu_build(entry: Path, package: Path, dest: Path) -> Path:
    """pythonfmu's build of ``entry`` with the FMU's own ``package``. pythonfmu imports the entry and
    instantiates its slave class (for the model description) in this process, and takes only a
    subclass of its own ``Fmi2Slave``: for that while, the package's ``pythonfmu`` is this process's.
    Everything imported is forgotten afterwards."""
    import pythonfmu
    import pythonfmu.enums
    from pythonfmu.builder import FmuBuilder

    private = package.name
    # an FMU of this build loaded in this process earlier has its own modules under the same names
    loaded = {m: sys.modules.pop(m) for m in list(sys.modules) if m.startswith(private)}
    path = sys.path[:]
    sys.path.insert(0, str(package.parent))
    sys.modules[f"{private}.pythonfmu"] = pythonfmu
    sys.modules[f"{private}.pythonfmu.enums"] = pythonfmu.enums
    try:
        return FmuBuilder.build_FMU(entry, dest=dest, project_files=[package])
    finally:
        sys.path[:] = path  # pythonfmu puts the script's folder first on sys.path too
        for module in [m for m in sys.modules if m.startswith(private)]:
            del sys.modules[module]
        sys.modules.update(loaded)


def build_fmus(out: str | Path, names: str | Sequence[str] | None = None) -> list[Path]:
    """Build the FMUs ``names`` (default: all of :data:`FMUS`; one name alone counts as one) into
    ``out``; returns their paths."""
    if isinstance(names, str):
        names = (names,)
    unknown = [n for n in names or () if n not in FMUS]
    if unknown:
        raise ValueError(f"unknown FMU {unknown[0]!r}; known: {', '.join(FMUS)}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out} is a file, not a folder for the FMUs")
    out.mkdir(parents=True, exist_ok=True)
    built, version = [], project_version()
    for name in names or tuple(FMUS):
        script, packages = FMUS[name]
        meta = slave_metadata(name)
        with _build_folder() as tmp:
            for pkg in packages:
                _clean_copy(ROOT / pkg, tmp / "copy" / pkg)
            private = private_package(name, tmp / "copy")
            (tmp / "copy").rename(tmp / private)
            (tmp / private / "__init__.py").write_text(f'"""{name}.fmu\'s own copy of its code (build_scripts/'
                                                       f'build_fmus.py, private_package)."""\n', encoding="utf-8")
            _redirect_imports(tmp / private, private)
            entry = tmp / "entry" / f"{private}_slave.py"
            entry.parent.mkdir()
            entry.write_text(entry_script(name, private), encoding="utf-8")
            fmu = _pythonfmu_build(entry, tmp / private, tmp / "pythonfmu")
            tree = tmp / "tree"
            with zipfile.ZipFile(fmu) as z:
                z.extractall(tree)
            # pythonfmu's runtime, packed beside, joins the FMU's own package too
            shutil.move(tree / "resources" / "pythonfmu", tree / "resources" / private / "pythonfmu")
            _redirect_imports(tree / "resources" / private / "pythonfmu", private)
            _prepare_native_hosts(tree)
            md = tree / "modelDescription.xml"
            raw = md.read_text(encoding="utf-8")
            sources = private.rsplit("_", 1)[1]
            md.write_text(finish_model_description(raw, meta, guid="{pending}", version=version, sources=sources),
                          encoding="utf-8")
            md.write_text(finish_model_description(raw, meta, guid=content_guid(_digest(tree)), version=version,
                                                   sources=sources), encoding="utf-8")
            target = out / f"{name}.fmu"
            # a new file of a name no one can foresee: in a folder others may write, a foreseen name
            # could be a link they made to a file of this user's, which the zip would overwrite
            fd, partial = tempfile.mkstemp(prefix=f".{name}.fmu.partial-", dir=out)
            os.close(fd)
            staged = Path(partial)
            try:
                _zip(tree, staged)
                mask = os.umask(0o022)
                os.umask(mask)
                try:
                    os.chmod(staged, 0o666 & ~mask)  # the mode a new file gets, not mkstemp's 0600
                except PermissionError:  # a file system without modes (vfat)
                    pass
                os.replace(staged, target)  # atomic: readers see the old or the new FMU, never half
            finally:
                staged.unlink(missing_ok=True)
            built.append(target)
    return built


def project_version() -> str:
    """tapmuscle's version for the FMUs' model descriptions: the checkout's ``pyproject.toml`` (the
    sources being packed), else the installed distribution's."""
    pyproject = ROOT / "pyproject.toml"
    if pyproject.is_file():
        return tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["version"]
    return metadata.version("tapmuscle")


def _source_digest() -> str:
    h = hashlib.sha256()
    h.update(project_version().encode() + b"\0")  # the model descriptions carry it
    files = {ROOT / script for script, _ in FMUS.values()} | {f for _, pkgs in FMUS.values() for p in pkgs
                                                           for f in (ROOT / p).rglob("*")
                                                           if f.suffix == ".py" or f.name == "_ros34pw2" + EXTENSION_SUFFIXES[0]}
    files |= set((ROOT / "build_scripts").glob("*.py")) | set((ROOT / "build_scripts").glob("*.c"))
    for f in sorted(files):
        h.update(f.relative_to(ROOT).as_posix().encode() + b"\0" + f.read_bytes())
    h.update(building_python().encode())  # the native-host preparation records this interpreter
    h.update(b"\0" + os.environ.get(EXPORT_VARIABLE, "").strip().encode())  # and which library runs the slave
    return h.hexdigest()[:16]


def user_cache_root() -> Path:
    """``$XDG_CACHE_HOME/tapmuscle``, else (on Windows) ``%LOCALAPPDATA%\\tapmuscle``, else
    ``~/.cache/tapmuscle``: this user's tapmuscle cache.

    Raises
    ------
    OSError
        None is set nor can be found (HOME unset and a user id without a passwd entry: a container
        run as an arbitrary user); the message says what to set.
    """
    cache = os.environ.get("XDG_CACHE_HOME")
    if not cache and sys.platform == "win32":  # where Windows programs keep a user's caches
        cache = os.environ.get("LOCALAPPDATA")
    if not cache:
        try:
            cache = Path.home() / ".cache"
        except RuntimeError:  # pathlib's "Could not determine home directory."
            raise OSError(f"no home folder for the FMU cache (HOME is unset and user id {os.getuid()} has no "
                          "passwd entry): set XDG_CACHE_HOME (or HOME) to a writable folder, or give run, sweep "
                          "and check --fmu-dir DIR with the FMUs of tapmuscle build --out DIR") from None
    return Path(cache) / "tapmuscle"


def cached_fmus(cache_root: str | Path | None = None) -> dict[str, Path]:
    """Both FMUs built from this checkout, reused while the sources are unchanged.

    The cache lives in ``cache_root`` (default :func:`user_cache_root`)
    under a folder named by a digest of the sources and the interpreter. ``OSError`` naming the
    folder and the remedies when it cannot be written (a read-only home in a container).

    These are the FMUs the project's own commands run in fmpy, a Python host: a tool missing for
    other hosts' binaries (MinGW-w64, a shared libpython) is not warned of here, where it changes
    nothing, and where warnings made errors (``PYTHONWARNINGS=error``) it stopped ``tapmuscle
    paper`` on most Linux machines. ``tapmuscle build``, which writes FMUs to take elsewhere, warns.
    """
    if cache_root is None:
        cache_root = user_cache_root()
    folder = Path(cache_root) / f"fmu-{_source_digest()}"
    paths = {name: folder / f"{name}.fmu" for name in FMUS}

    def unwritable(exc: OSError, where: Path = folder) -> OSError:
        return OSError(f"cannot write the FMU cache {where} ({exc.strerror or exc}): set XDG_CACHE_HOME to a "
                       f"writable folder (or give run, sweep and check --fmu-dir DIR with the FMUs of "
                       f"tapmuscle build --out DIR)")

    # The FMUs are code run as this user: taken only from folders of this user's (or root's) that no
    # one else may write into, and only files of this user's (or root's); another's is built anew
    remedy = ("Set XDG_CACHE_HOME to a folder of your own (or give run, sweep and check --fmu-dir DIR with the FMUs "
              "of tapmuscle build --out DIR)")
    for level in (Path(cache_root), folder):
        try:
            own_folder(level, closed=0o022, what="the FMU cache", remedy=remedy)
        except UntrustedFolderError:
            raise
        except OSError as exc:
            raise unwritable(exc, level) from None
    for p in paths.values():
        try:
            remove_foreign(p)
        except OSError as exc:
            raise unwritable(exc) from None
    missing = tuple(name for name, p in paths.items() if not p.is_file())
    if missing:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NativeHostWarning)
            try:
                build_fmus(folder, missing)
            except PermissionError as exc:  # a cache folder another user made (a shared XDG_CACHE_HOME)
                raise unwritable(exc) from None
        _prune_cache(Path(cache_root), folder)
    else:
        try:
            os.utime(folder)  # last used: what the pruning keeps
        except OSError:
            pass  # a read-only cache still serves
    return paths


#: The FMU cache keeps the builds of this many source states, the most recently used, and any used
#: in the last :data:`CACHE_IN_USE_S` (another process may be running it).
CACHE_KEEP = 8
CACHE_IN_USE_S = 3600.0


def _prune_cache(cache_root: Path, keep: Path) -> None:
    """Remove the cached builds beyond :data:`CACHE_KEEP` (each source state of a checkout gets one,
    and a developer's cache held 51, 35 MB); never ``keep`` nor one used within :data:`CACHE_IN_USE_S`."""
    builds = []
    for d in cache_root.glob("fmu-*"):
        try:
            builds.append((d.stat().st_mtime, d))
        except OSError:
            continue
    builds.sort(reverse=True)
    now = time.time()
    for mtime, d in builds[CACHE_KEEP:]:
        if d != keep and now - mtime > CACHE_IN_USE_S:
            shutil.rmtree(d, ignore_errors=True)
