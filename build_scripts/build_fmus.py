"""Build ``MusclePlant.fmu`` and ``AMPCController.fmu`` with pythonfmu, then finish them.

Each FMU carries the numerics package it wraps (with its slave module) and the shared ``fmi_slave``
shell in ``resources/``: the project's code travels inside the FMU; the host needs a Python with numpy
(and scipy, osqp for the controller) and pythonfmu's runtime, which pythonfmu also packs.

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

import hashlib
import importlib.util
import os
import shutil
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Any

from .model_description import content_guid, finish_model_description

__all__ = ["FMUS", "build_fmus", "cached_fmus", "slave_metadata"]

ROOT = Path(__file__).resolve().parents[1]

#: FMU name (= slave class) -> (slave script, packages shipped in resources)
FMUS: dict[str, tuple[str, tuple[str, ...]]] = {
    "MusclePlant": ("fmu_plant/plant_slave.py", ("fmu_plant", "fmi_slave")),
    "AMPCController": ("fmu_controller/controller_slave.py", ("fmu_controller", "fmi_slave")),
}

_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def entry_script(name: str) -> str:
    """Source of pythonfmu's entry script for FMU ``name``: the slave class imported from its module,
    and one reference added to the entry's own module dict per execution (module docstring)."""
    script = Path(FMUS[name][0])
    module = ".".join(script.with_suffix("").parts)
    return (f'"""pythonfmu\'s entry script of {name}.fmu, written by build_scripts/build_fmus.py: the slave\n'
            f"class {module}.{name}. pythonfmu executes this file at every instantiation and each\n"
            "time releases a reference to its module dict that it never took: give it back.\n"
            '"""\n\n'
            "import ctypes\n\n"
            "import fmi_slave  # noqa: F401 - first: prepares the embedded interpreter in non-Python hosts\n"
            f"from {module} import {name}  # noqa: F401 - the slave class pythonfmu takes\n\n"
            "ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))\n")


def _clean_copy(src: Path, dst: Path) -> None:
    # The FMU carries Python sources only: the plant's compiled sub-step (built for this interpreter,
    # setup.py) is left out, and the FMU runs the Python one, which gives the same bits.
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.pyd", "*.c"))


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


def build_fmus(out: str | Path, names: tuple[str, ...] | None = None) -> list[Path]:
    """Build the FMUs ``names`` (default: all of :data:`FMUS`) into ``out``; returns their paths."""
    from pythonfmu.builder import FmuBuilder

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    unknown = [n for n in names or () if n not in FMUS]
    if unknown:
        raise ValueError(f"unknown FMU {unknown[0]!r}; known: {', '.join(FMUS)}")
    built = []
    for name in names or tuple(FMUS):
        script, packages = FMUS[name]
        meta = slave_metadata(name)
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            for pkg in packages:
                _clean_copy(ROOT / pkg, tmp / "src" / pkg)
            entry = tmp / "entry" / Path(script).name
            entry.parent.mkdir()
            entry.write_text(entry_script(name), encoding="utf-8")
            path = sys.path[:]
            try:
                fmu = FmuBuilder.build_FMU(entry, dest=tmp / "pythonfmu",
                                           project_files=[tmp / "src" / p for p in packages])
            finally:
                sys.path[:] = path  # pythonfmu puts the script's folder first on sys.path
            tree = tmp / "tree"
            with zipfile.ZipFile(fmu) as z:
                z.extractall(tree)
            _prepare_native_hosts(tree)
            md = tree / "modelDescription.xml"
            raw = md.read_text(encoding="utf-8")
            md.write_text(finish_model_description(raw, meta, guid="{pending}"), encoding="utf-8")
            md.write_text(finish_model_description(raw, meta, guid=content_guid(_digest(tree))), encoding="utf-8")
            target = out / f"{name}.fmu"
            staged = out / f".{name}.fmu.partial-{os.getpid()}"
            try:
                _zip(tree, staged)
                os.replace(staged, target)  # atomic: readers see the old or the new FMU, never half
            finally:
                staged.unlink(missing_ok=True)
            built.append(target)
    return built


def _source_digest() -> str:
    h = hashlib.sha256()
    files = {ROOT / script for script, _ in FMUS.values()} | {f for _, pkgs in FMUS.values() for p in pkgs
                                                           for f in (ROOT / p).rglob("*.py")}
    files |= set((ROOT / "build_scripts").glob("*.py"))
    for f in sorted(files):
        h.update(f.relative_to(ROOT).as_posix().encode() + b"\0" + f.read_bytes())
    h.update(sys.executable.encode())  # the native-host preparation records this interpreter
    return h.hexdigest()[:16]


def cached_fmus(cache_root: str | Path | None = None) -> dict[str, Path]:
    """Both FMUs built from this checkout, reused while the sources are unchanged.

    The cache lives in ``cache_root`` (default ``$XDG_CACHE_HOME/tapmuscle`` or ``~/.cache/tapmuscle``)
    under a folder named by a digest of the sources and the interpreter.
    """
    if cache_root is None:
        cache_root = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "tapmuscle"
    folder = Path(cache_root) / f"fmu-{_source_digest()}"
    paths = {name: folder / f"{name}.fmu" for name in FMUS}
    missing = tuple(name for name, p in paths.items() if not p.is_file())
    if missing:
        build_fmus(folder, missing)
    return paths
