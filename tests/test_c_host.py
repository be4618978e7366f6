"""The FMUs in a non-Python FMI host: tests/c_host/fmi_host.c (gcc, dlopen RTLD_LOCAL, fmpy's FMI
headers), run in a plain environment (no LD_PRELOAD, no PYTHONPATH, the venv's python not on PATH;
Debian's /usr/bin/python3, where present, is on it, which is the case where the FMU could start the wrong
Python). Same numbers as fmpy to 1e-12, several instances, re-instantiation, clean process exit, and
a missing dependency reported through the host's logger. See docs/fmu-native-hosts.md.
"""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import math
import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import time
import zipfile
from pathlib import Path

import fmpy
import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from build_scripts import native_host
from build_scripts.build_fmus import FMUS
from build_scripts.native_host import CONFIG_NAME, NativeHostWarning, prepare_for_native_hosts
from fmpy_helpers import host_lines
from threaded_loops import assert_parallel_loops_as_one_thread

pytestmark = pytest.mark.c_host

HOST_SOURCE = Path(__file__).parent / "c_host" / "fmi_host.c"
ROOT = Path(__file__).resolve().parents[1]
PLAIN_PATH = "/usr/bin:/bin"
TS = 0.1


class Fmu:
    """An extracted FMU and what the host needs to know from its modelDescription.xml."""

    def __init__(self, path: Path, folder: Path) -> None:
        with zipfile.ZipFile(path) as z:
            z.extractall(folder)
        self.dir = folder
        config = json.loads((folder / "resources" / CONFIG_NAME).read_text(encoding="utf-8"))
        if config.get("python_hosts_only"):
            # a C host needs an FMU that starts a Python; test_a_python_without_a_shared_libpython_...
            # checks what such a host gets from this build
            pytest.skip(f"the building Python ({config['python']}) has no shared libpython: its FMUs run in "
                        "Python hosts only")
        self.md = read_model_description(str(folder))
        self.id = self.md.coSimulation.modelIdentifier
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}

    def args(self, key: str, **vrs: str) -> list[str]:
        """``KEY.dir= KEY.id= KEY.guid=`` and ``KEY.<role>=<vr of variable>`` for the host."""
        return ([f"{key}.dir={self.dir}", f"{key}.id={self.id}", f"{key}.guid={self.md.guid}"]
                + [f"{key}.{role}={self.vr[name]}" for role, name in vrs.items()])

    def fmpy_instance(self, name: str, reals=None, ints=None) -> FMU2Slave:
        f = FMU2Slave(guid=self.md.guid, unzipDirectory=str(self.dir), modelIdentifier=self.id,
                      instanceName=name)
        f.instantiate(loggingOn=True)
        f.setupExperiment(startTime=0.0)
        f.enterInitializationMode()
        for key, value in (reals or {}).items():
            f.setReal([self.vr[key]], [value])
        for key, value in (ints or {}).items():
            f.setInteger([self.vr[key]], [value])
        f.exitInitializationMode()
        return f


def _compile(tmp_path_factory, source: str, *, std: str, libs: list[str]) -> Path:
    """tests/c_host/``source`` compiled with gcc (``-std=STD``, linked with ``-ldl`` and ``libs``) and
    fmpy's FMI headers into a temporary folder."""
    gcc = shutil.which("gcc") or shutil.which("cc")
    assert gcc, "gcc is needed to build the FMUs for native hosts and this test's host"
    name = Path(source).stem
    exe = tmp_path_factory.mktemp(name) / name
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run([gcc, f"-std={std}", "-O2", "-Wall", "-Wextra", "-I", str(headers), "-o", str(exe),
                    str(HOST_SOURCE.with_name(source)), "-ldl", *libs], check=True)
    return exe


@pytest.fixture(scope="module")
def host(tmp_path_factory) -> Path:
    """tests/c_host/fmi_host.c compiled."""
    return _compile(tmp_path_factory, "fmi_host.c", std="c99", libs=["-lm"])


@pytest.fixture(scope="module")
def threaded_host(tmp_path_factory) -> Path:
    """tests/c_host/threaded_host.c (a parallel master's threads) compiled."""
    return _compile(tmp_path_factory, "threaded_host.c", std="gnu11", libs=["-pthread"])


@pytest.fixture(scope="module")
def plant(built_fmus, tmp_path_factory) -> Fmu:
    return Fmu(built_fmus["MusclePlant"], tmp_path_factory.mktemp("MusclePlant"))


@pytest.fixture(scope="module")
def controller(built_fmus, tmp_path_factory) -> Fmu:
    return Fmu(built_fmus["AMPCController"], tmp_path_factory.mktemp("AMPCController"))


#: Variables that choose the floating-point kernels (CI's second pass sets them): the host gets the
#: same ones as this process, or its closed loop would not be comparable bit for bit with fmpy's here.
NUMERICS_VARIABLES = ("NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")


def plain_env(tmp: Path, **extra: str | None) -> dict[str, str]:
    """What a user's C host would have: no Python variables, no LD_PRELOAD, no venv on PATH (only the
    floating-point kernel choice of this process, :data:`NUMERICS_VARIABLES`); ``extra`` adds
    variables, or with None removes one (``LANG=None``: the C locale of a container or a service)."""
    numerics = {k: os.environ[k] for k in NUMERICS_VARIABLES if k in os.environ}
    env = {"PATH": PLAIN_PATH, "HOME": str(tmp), "LANG": "C.UTF-8", **numerics, **extra}
    env = {k: v for k, v in env.items() if v is not None}
    venv_bin = os.path.dirname(sys.executable)
    assert venv_bin not in env["PATH"].split(os.pathsep)
    return env


def run_host(host: Path, tmp: Path, *args: str, env_extra: dict[str, str | None] | None = None, check=True):
    proc = subprocess.run([str(host), *args], capture_output=True, text=True, timeout=180,
                          env=plain_env(tmp, **(env_extra or {})))
    if check:
        assert proc.returncode == 0, f"fmi_host exited {proc.returncode}\n{proc.stderr[-4000:]}"
    return proc


def table(stdout: str) -> list[dict[str, float]]:
    return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(io.StringIO(stdout))]


def test_plain_environment_really_is_plain(tmp_path):
    env = plain_env(tmp_path)
    assert not {"PYTHONPATH", "PYTHONHOME", "LD_PRELOAD", "LD_LIBRARY_PATH", "VIRTUAL_ENV"} & set(env)
    found = shutil.which("python3", path=env["PATH"])
    if found is not None and Path(found).resolve() == Path(sys.executable).resolve():
        # a venv of the system's Python (Debian's /usr/bin/python3.11): the C-host tests still run,
        # but cannot tell the loader's choice of interpreter from Python's own search of PATH
        pytest.skip(f"the building Python is the first python3 on the plain PATH ({found})")


def test_open_loop_equals_fmpy(host, plant, tmp_path):
    params = {"load_force": 68.0, "friction.rate_gain": 0.3}
    proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l", p="p"),
                    *(f"P.real={plant.vr[k]}:{v!r}" for k, v in params.items()), f"P.int={plant.vr['seed']}:5",
                    "steps=200", f"dt={TS}", "sine=5,3,0.1")
    rows = table(proc.stdout)
    assert len(rows) == 200
    f = plant.fmpy_instance("fmpy", reals=params, ints={"seed": 5})
    worst = 0.0
    for k, row in enumerate(rows):
        t = k * TS
        assert row["t"] == t
        assert abs(row["u"] - (5 + 3 * math.sin(2 * math.pi * 0.1 * t))) <= 1e-12
        f.setReal([plant.vr["u"]], [row["u"]])
        f.doStep(t, TS)
        l_mm, p_mpa = f.getReal([plant.vr["l"], plant.vr["p"]])
        worst = max(worst, abs(row["l"] - l_mm), abs(row["p"] - p_mpa))
    f.terminate()
    f.freeInstance()
    assert worst <= 1e-12
    ls = [r["l"] for r in rows]
    assert max(ls) - min(ls) > 10.0  # the muscle really moved: the comparison is not of constants


@pytest.mark.parametrize("locale", [{}, {"LANG": None}, {"LANG": None, "LC_ALL": "POSIX"},
                                    {"LANG": "xx_YY.UTF-8"}], ids=["C.UTF-8", "no-LANG", "POSIX", "not-installed"])
@pytest.mark.utf8_paths
def test_a_folder_with_non_ascii_characters_and_spaces(host, built_fmus, tmp_path, locale):
    """The FMU extracted into a user's folder such as "Müller Straße": the C host passes the path as
    it is (file:// and UTF-8 bytes), fmpy percent-encodes it (file:///...M%C3%BCller%20Stra%C3%9Fe);
    both load and step the FMU and read the same displacement. Also where the host's environment has
    no encoding (no LANG: containers, services, CI runners; a locale that is not installed): the
    FMU's Python runs in UTF-8 mode there (else it would fail with "UnicodeEncodeError('ascii', ...)")."""
    plant = Fmu(built_fmus["MusclePlant"], tmp_path / "Müller Straße" / "日本")
    proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l", p="p"), "steps=30", f"dt={TS}",
                    "sine=5,3,0.1", env_extra=locale)
    rows = table(proc.stdout)
    f = plant.fmpy_instance("fmpy")
    for k, row in enumerate(rows):
        f.setReal([plant.vr["u"]], [row["u"]])
        f.doStep(k * TS, TS)
        assert abs(f.getReal([plant.vr["l"]])[0] - row["l"]) <= 1e-12
    f.terminate()
    f.freeInstance()
    assert len(rows) == 30 and rows[-1]["l"] > 10.0  # it moved


def test_a_folder_named_in_latin_1_fails_the_instance_naming_it(host, plant, built_fmus, tmp_path):
    """A folder whose name is not UTF-8 (M\xfcller: Latin-1 bytes from a Windows zip or an old home
    folder) must not segfault the host in fmi2Instantiate (pythonfmu's error path); the instance fails
    with the folder named (its bytes escaped), the host ends at its first step."""
    folder = bytes(tmp_path) + b"/M\xfcller"
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        z.extractall(os.fsdecode(folder))
    args = [b"P.dir=" + folder if a.startswith("P.dir=") else os.fsencode(a) for a in plant.args("P", u="u", l="l")]
    proc = subprocess.run([os.fsencode(host), b"open", *args, b"steps=5", f"dt={TS}".encode()], capture_output=True,
                          timeout=180, env=plain_env(tmp_path))
    stderr = proc.stderr.decode("utf-8", "backslashreplace")
    assert proc.returncode == 2 and "fmi2DoStep" in stderr, (proc.returncode, stderr[-3000:])
    # every byte beyond printable ASCII escaped, those of pytest's temporary folder too (TMPDIR=/tmp/Zürich)
    shown = "".join(chr(b) if 0x20 <= b < 0x7F else f"\\x{b:02X}" for b in bytes(tmp_path))
    assert (f"the FMU's folder {shown}/M\\xFCller/resources has a name that is not UTF-8 (byte 0xFC at "
            f"{len(bytes(tmp_path)) + 2}), which the FMU's Python cannot open: extract the FMU into a folder whose "
            "name is UTF-8") in stderr, stderr[-3000:]


def test_a_pythonhome_without_the_standard_library_fails_the_instance_naming_it(host, plant, tmp_path):
    """PYTHONHOME=/nonexistent (left over from another tool) must not stop Python's start with a fatal error
    that exits the host inside dlopen, before any FMI call; the instance fails naming it."""
    version = "%d.%d" % sys.version_info[:2]
    proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l"), "steps=5", check=False,
                    env_extra={"PYTHONHOME": str(tmp_path / "nonexistent")})
    assert proc.returncode == 2 and "fmi2DoStep" in proc.stderr, (proc.returncode, proc.stderr[-3000:])
    assert (f"PYTHONHOME={tmp_path}/nonexistent has no standard library of CPython {version} (no {tmp_path}/nonexistent"
            f"/lib/python{version}/encodings/__init__.py), so the FMU cannot start its Python: unset PYTHONHOME"
            in proc.stderr), proc.stderr[-3000:]
    assert "Fatal Python error" not in proc.stderr


@pytest.mark.parametrize("what", ["missing", "folder"])
def test_a_tapmuscle_python_that_is_no_executable_fails_the_instance_naming_it(host, plant, tmp_path, what):
    """TAPMUSCLE_PYTHON naming no executable file (a typo, a venv deleted since; a folder) must not be ignored
    without a word, leaving Python to search its own (the first python3 on PATH); the instances fail
    naming it, as on Windows, through the host's logger, and the host ends at its first step."""
    version = "%d.%d" % sys.version_info[:2]
    named = tmp_path / "deleted-venv" / "bin" / "python" if what == "missing" else tmp_path
    proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l"), "steps=5", check=False,
                    env_extra={"TAPMUSCLE_PYTHON": str(named)})
    assert proc.returncode == 2 and "fmi2DoStep" in proc.stderr, (proc.returncode, proc.stderr[-3000:])
    assert (f"[Error] plant logStatusError: [plant] the FMU's pythonfmu library {plant.id}_pythonfmu.so could not be loaded: "
            f"TAPMUSCLE_PYTHON={named} is not an executable file (name the python of a CPython {version} that has "
            "numpy, scipy and osqp: a venv's bin/python, or an installation's bin/python") in proc.stderr, proc.stderr[-3000:]
    assert "Fatal Python error" not in proc.stderr and proc.stdout.splitlines() == ["t,u,l,p"]


@pytest.mark.slow
@pytest.mark.parametrize("method", [3, 4])  # ampc_ucp; ampc_servo (OSQP)
def test_closed_loop_equals_fmpy(host, plant, controller, tmp_path, method):
    steps = 300
    proc = run_host(host, tmp_path, "closed", *plant.args("P", u="u", l="l"), *controller.args("C", l="l", u="u"),
                    f"C.int={controller.vr['method']}:{method}", f"steps={steps}", f"dt={TS}")
    rows = table(proc.stdout)
    assert len(rows) == steps
    p = plant.fmpy_instance("plant")
    c = controller.fmpy_instance("controller", ints={"method": method})
    worst = 0.0
    for k, row in enumerate(rows):  # the host's master algorithm, in fmpy
        t = k * TS
        (l_mm,) = p.getReal([plant.vr["l"]])
        c.setReal([controller.vr["l"]], [l_mm])
        c.doStep(t, TS)
        (u,) = c.getReal([controller.vr["u"]])
        p.setReal([plant.vr["u"]], [u])
        p.doStep(t, TS)
        assert row["t"] == t
        worst = max(worst, abs(row["l"] - l_mm), abs(row["u"] - u))
    for f in (c, p):
        f.terminate()
        f.freeInstance()
    assert worst <= 1e-12
    # and the loop tracks the built-in reference 35 + 30 sin(2 pi 0.1 t) mm once started
    err = [r["l"] - (35 + 30 * math.sin(2 * math.pi * 0.1 * r["t"])) for r in rows[100:]]
    assert math.sqrt(sum(e * e for e in err) / len(err)) < 2.0


@pytest.mark.parametrize("unload", [0, 1])
def test_two_instances_at_once_then_free_and_instantiate_again(host, plant, tmp_path, unload):
    """unload=1: between the frees and the new instance the host also dlclose()s and re-loads the FMU."""
    proc = run_host(host, tmp_path, "instances", *plant.args("P", u="u", l="l", load="load_force"),
                    "load_a=44", "load_b=68", "u_const=6", "steps=100", f"dt={TS}", f"unload={unload}")
    l_mm = {row["name"]: float(row["l"]) for row in csv.DictReader(io.StringIO(proc.stdout))}
    assert set(l_mm) == {"a", "b", "c"}
    assert l_mm["a"] - l_mm["b"] > 3.0  # the heavier load hangs lower: the instances do not share state
    assert l_mm["c"] == l_mm["a"]  # a fresh instance after freeing both repeats a's run exactly


def test_the_host_times_its_own_stepping_loop(host, plant, controller, tmp_path):
    """The host prints the time of its stepping loop alone, which benchmarks/fmu_c_host.py reads: the
    process's start-up varies by more than 2400 steps cost, so process times cannot give it."""
    spec = importlib.util.spec_from_file_location("_fmu_c_host", ROOT / "benchmarks" / "fmu_c_host.py")
    benchmark = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(benchmark)
    started = time.perf_counter()
    proc = run_host(host, tmp_path, "closed", *plant.args("P", u="u", l="l"), *controller.args("C", l="l", u="u"),
                    "steps=30", f"dt={TS}")
    wall = time.perf_counter() - started
    assert len(table(proc.stdout)) == 30
    assert 0.0 < benchmark.stepping_seconds(proc.stderr, 30) < wall, proc.stderr[-2000:]
    proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l"), "steps=7")
    assert 0.0 < benchmark.stepping_seconds(proc.stderr, 7) < wall


@pytest.mark.slow
def test_host_exit_is_clean_repeatedly(host, plant, tmp_path):
    """pythonfmu 0.7.0 frees its interpreter holder twice at exit; unguarded that would abort every run
    of this host ("free(): corrupted unsorted chunks", exit status 134)."""
    for _ in range(3):
        proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l"), "steps=5")
        assert "corrupted" not in proc.stderr and "Aborted" not in proc.stderr



def test_bad_value_reference_is_reported_and_the_host_survives_freeing(host, plant, tmp_path):
    """Unguarded, pythonfmu frees the slave twice after a Python exception (fmi_slave.base): this host
    would segfault within a few instantiate / bad call / free cycles."""
    proc = run_host(host, tmp_path, "badvr", *plant.args("P", u="u", l="l"), "steps=15", "u_const=6")
    rows = list(csv.DictReader(io.StringIO(proc.stdout)))
    assert len(rows) == 15
    assert {r["get"] for r in rows} == {r["set"] for r in rows} == {"Error"}  # the instance is fine: not Fatal
    assert len({r["l"] for r in rows}) == 1 and 0.0 < float(rows[0]["l"]) < 400.0  # each fresh, the same
    assert "is not a variable of type Real" in proc.stderr

@pytest.mark.parametrize("folder", ["empty-venv", pytest.param("Z\u00fcrich venv", marks=pytest.mark.utf8_paths)])
def test_missing_dependency_fails_the_first_step_with_what_to_install(host, plant, tmp_path, folder):
    """A Python without numpy (an empty venv, recorded site-packages switched off): fmi2Instantiate
    returns an instance that refuses to step (some hosts do not check NULL), the host's logger got
    the message, and the host ends at the first fmi2DoStep with fmi2Error. A venv named beyond ASCII
    is named as it is spelled, though the host runs in the "C" locale (not Z\\udcc3\\udcbcrich)."""
    empty = tmp_path / folder
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(empty)], check=True)
    python = str(empty / "bin" / "python")
    proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l"), "steps=5", check=False,
                    env_extra={"TAPMUSCLE_PYTHON": python, "TAPMUSCLE_SITE_PACKAGES": ""})
    assert proc.returncode == 2 and "fmi2DoStep" in proc.stderr, proc.stderr  # fmi_host: an FMI call failed
    # all three named at once: one round of installing
    assert "tapmuscle FMU: cannot import numpy, scipy, osqp; install them into the Python the FMU uses: " in proc.stderr
    # a venv made without pip, as uv makes them: pip's advice would fail ("No module named pip")
    assert (f"this Python has no pip (a uv environment, an embeddable distribution): uv pip install --python {python} "
            f"numpy scipy osqp, or {python} -m ensurepip and then -m pip install numpy scipy osqp") in proc.stderr, \
        proc.stderr
    version = "%d.%d" % sys.version_info[:2]
    assert f"(or set TAPMUSCLE_PYTHON to the python of a CPython {version} environment that has them, or set " \
           "TAPMUSCLE_SITE_PACKAGES to " in proc.stderr  # the way the docs recommend, too
    assert "[Fatal] plant" in proc.stderr  # through the host's logger callback
    assert proc.stdout.splitlines() == ["t,u,l,p"]  # the header, no row
    # the whole message once; each later call (seven messages in all) names it in short
    assert proc.stderr.count("searched: ") == 1, proc.stderr
    refused = [line for line in proc.stderr.splitlines() if "the instance failed at instantiation (" in line]
    assert len(refused) >= 5 and all(len(line) < 400 and "cannot import numpy" in line for line in refused), refused
    assert all(line.endswith("; the whole reason is in the instance's first message)") for line in refused)


@pytest.mark.parametrize("override", [False, True])
def test_packages_come_from_the_recorded_or_named_site_packages(host, plant, tmp_path, override):
    """The interpreter named by TAPMUSCLE_PYTHON has no packages (an empty venv, as on a machine
    where the FMU was moved): numpy comes from the site-packages recorded at build (the building
    venv's), or from those named by TAPMUSCLE_SITE_PACKAGES; same numbers as the default run."""
    empty = tmp_path / "other-python"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(empty)], check=True)
    env = {"TAPMUSCLE_PYTHON": str(empty / "bin" / "python")}
    if override:
        recorded = json.loads((plant.dir / "resources" / "tapmuscle_native.json").read_text())["site_packages"]
        env["TAPMUSCLE_SITE_PACKAGES"] = os.pathsep.join([str(tmp_path / "does-not-exist"), *recorded])
    args = ["open", *plant.args("P", u="u", l="l", p="p"), "steps=50"]
    moved = run_host(host, tmp_path, *args, env_extra=env)
    assert len(table(moved.stdout)) == 50
    assert moved.stdout == run_host(host, tmp_path, *args).stdout


def test_the_packages_of_the_python_tapmuscle_python_names_come_first(host, plant, tmp_path):
    """A venv of its own named by TAPMUSCLE_PYTHON (for other numpy, scipy, osqp versions) on the
    building machine: its packages win over the site-packages recorded at build, which ran the loop on
    the build's numpy. Here the venv's numpy fails at import, and the FMU says so; TAPMUSCLE_SITE_PACKAGES
    naming the recorded ones still puts them first."""
    venv = tmp_path / "own-numpy"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    site_dir = Path(subprocess.run([str(venv / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_path("
                                    "'purelib'))"], check=True, capture_output=True, text=True).stdout.strip())
    (site_dir / "numpy").mkdir(parents=True)
    (site_dir / "numpy" / "__init__.py").write_text("raise ImportError('the named venv numpy, broken on purpose')\n")
    args = ["open", *plant.args("P", u="u", l="l", p="p"), "steps=20"]
    env = {"TAPMUSCLE_PYTHON": str(venv / "bin" / "python")}
    proc = run_host(host, tmp_path, *args, check=False, env_extra=env)
    assert proc.returncode == 2 and "the named venv numpy, broken on purpose" in proc.stderr, proc.stderr[-3000:]
    recorded = json.loads((plant.dir / "resources" / CONFIG_NAME).read_text())["site_packages"]
    forced = run_host(host, tmp_path, *args, env_extra={**env, "TAPMUSCLE_SITE_PACKAGES": os.pathsep.join(recorded)})
    assert forced.stdout == run_host(host, tmp_path, *args).stdout and len(table(forced.stdout)) == 20


def test_tapmuscle_python_of_another_installation_runs_on_its_own_libpython(host, plant, tmp_path):
    """TAPMUSCLE_PYTHON naming a venv of another CPython installation of the same version (the
    system's /usr/bin/python3.11 beside a pyenv build): the loader opens that installation's libpython,
    not the recorded one, whose build does not match the other standard library ("No module named
    '_struct'"); numpy comes from the recorded site-packages, the numbers are the default run's."""
    version = "%d.%d" % sys.version_info[:2]
    other = Path(f"/usr/bin/python{version}")
    if not other.exists() or other.resolve() == Path(sys.executable).resolve() or \
            Path(sys.base_prefix).resolve() == Path("/usr"):
        pytest.skip(f"no other CPython {version} installation at {other} than the building one")
    soname = json.loads((plant.dir / "resources" / CONFIG_NAME).read_text())["libpython_soname"]
    if not any(Path(d, soname).exists() for d in ("/usr/lib", f"/usr/lib/{sysconfig.get_config_var('MULTIARCH')}")):
        pytest.skip(f"{other} has no shared {soname}")
    venv = tmp_path / "system-python-venv"
    subprocess.run([str(other), "-m", "venv", "--without-pip", str(venv)], check=True)
    args = ["open", *plant.args("P", u="u", l="l", p="p"), "steps=20"]
    moved = run_host(host, tmp_path, *args, env_extra={"TAPMUSCLE_PYTHON": str(venv / "bin" / "python")})
    assert moved.stdout == run_host(host, tmp_path, *args).stdout and len(table(moved.stdout)) == 20


def _libpythons_loaded(stderr: str) -> set[str]:
    """The libpython files the dynamic loader opened (``LD_DEBUG=files`` output)."""
    return {line.split("file=")[1].split()[0] for line in stderr.splitlines()
            if "file=" in line and Path(line.split("file=")[1].split()[0]).name.startswith("libpython")}


def test_tapmuscle_python_of_a_copied_venv_or_a_shim_keeps_the_building_libpython(host, plant, tmp_path):
    """Only an interpreter's own libpython replaces the recorded one: a venv made with --copies (its
    pyvenv.cfg names its base) and a shim script (pyenv's shims/python, which `which python` gives)
    keep the building installation's; taken from their folder they would load the system's libpython
    of the same version beside the other build's standard library (or run the system's Python)."""
    config = json.loads((plant.dir / "resources" / CONFIG_NAME).read_text())
    base = config["base_python"]
    venv = tmp_path / "copied"
    subprocess.run([base, "-m", "venv", "--copies", "--without-pip", str(venv)], check=True)
    shim = tmp_path / "shims" / "python"
    shim.parent.mkdir()
    shim.write_text(f'#!/bin/sh\nexec {base} "$@"\n')
    shim.chmod(0o755)
    args = ["open", *plant.args("P", u="u", l="l"), "steps=5"]
    expected = run_host(host, tmp_path, *args).stdout
    for python in (venv / "bin" / "python", shim):
        proc = run_host(host, tmp_path, *args, env_extra={"TAPMUSCLE_PYTHON": str(python), "LD_DEBUG": "files"})
        assert _libpythons_loaded(proc.stderr) == {config["libpython"]}, (python, _libpythons_loaded(proc.stderr))
        assert proc.stdout == expected


def test_a_pythonhome_of_another_build_is_named_when_the_instance_fails(host, plant, tmp_path):
    """PYTHONHOME=/usr beside an FMU built by another CPython installation: the standard library is
    there (the loader's check passes) but of another build, and the import fails ("No module named
    '_struct'"), which says nothing of PYTHONHOME; the failure names it. A prefix:exec_prefix whose
    second part has no compiled modules is refused before Python starts."""
    version = "%d.%d" % sys.version_info[:2]
    config = json.loads((plant.dir / "resources" / CONFIG_NAME).read_text())
    if not Path(f"/usr/lib/python{version}/encodings/__init__.py").exists() or config["libdir"].startswith("/usr/lib"):
        pytest.skip(f"no other CPython {version} standard library in /usr than the building one")
    proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l"), "steps=5", check=False,
                    env_extra={"PYTHONHOME": "/usr"})
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert ("(PYTHONHOME=/usr is set: the FMU's Python took its standard library from there; unset it unless it is "
            f"the CPython {version} installation the FMU's libpython belongs to)") in proc.stderr, proc.stderr[-3000:]
    home = f"{Path(config['libdir']).parent}:{tmp_path / 'nowhere'}"
    proc = run_host(host, tmp_path, "open", *plant.args("P", u="u", l="l"), "steps=5", check=False,
                    env_extra={"PYTHONHOME": home})
    assert (f"PYTHONHOME={home} has no standard library of CPython {version} (no {tmp_path / 'nowhere'}/lib/python"
            f"{version}/lib-dynload)") in proc.stderr, proc.stderr[-3000:]


FMPY_RUN = textwrap.dedent("""
    import sys
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave
    for folder in sys.argv[1:]:
        md = read_model_description(folder)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="x")
        f.instantiate()
        f.setupExperiment(startTime=0.0)
        f.enterInitializationMode()
        f.exitInitializationMode()
        for k in range(20):
            f.setReal([vr["l"]], [30.0]) if "r_k" in vr else f.setReal([vr["u"]], [6.0])
            f.doStep(k * 0.1, 0.1)
        print(md.coSimulation.modelIdentifier, f.getReal([vr["u"] if "r_k" in vr else vr["l"]])[0])
        f.terminate()
        f.freeInstance()
""")


@pytest.mark.slow
def test_fmpy_loads_runs_frees_the_prepared_fmus_and_exits_cleanly(plant, built_fmus, tmp_path):
    folders = [str(plant.dir)]
    if "AMPCController" in FMUS:
        folders.append(str(Fmu(built_fmus["AMPCController"], tmp_path / "ctrl").dir))
    for _ in range(5):
        proc = subprocess.run([sys.executable, "-c", FMPY_RUN, *folders], capture_output=True, text=True,
                              timeout=180)
        assert proc.returncode == 0, proc.stderr[-4000:]
        assert "corrupted" not in proc.stderr
        assert len(host_lines(proc.stdout)) == len(folders)


@pytest.mark.slow
def test_fmpy_missing_dependency_message(controller, tmp_path):
    """In a Python host too: osqp not importable -> instantiation fails with the message."""
    script = textwrap.dedent(f"""
        import sys
        import numpy, scipy, scipy.linalg, scipy.sparse  # what the host itself would have
        from fmpy import read_model_description
        from fmpy.fmi2 import FMU2Slave
        folder = {str(controller.dir)!r}
        md = read_model_description(folder)
        f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="c")
        assert "osqp" not in sys.modules
        sys.path[:] = [p for p in sys.path if "-packages" not in p]  # osqp is no longer findable
        try:  # osqp is imported with the controller's module today; at the latest it is needed here
            f.instantiate(loggingOn=True)
            f.setupExperiment(startTime=0.0)
            f.enterInitializationMode()
            f.exitInitializationMode()
            f.doStep(0.0, 0.1)
        except Exception as exc:
            print("failed:", exc)
        else:
            print("ran")
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "failed: " in proc.stdout
    assert "tapmuscle FMU: cannot import osqp; install it into the Python the FMU uses: " in proc.stdout
    assert "-m pip install osqp" in proc.stdout


def _threaded(threaded_host, plant, controller, tmp, mode, **keys) -> subprocess.CompletedProcess:
    """threaded_host MODE in a fresh plain process (Python started by the FMUs, not yet running)."""
    args = [str(threaded_host), mode, *plant.args("P", u="u", l="l", load="load_force"),
            *controller.args("C", l="l", u="u"), *(f"{k}={v}" for k, v in keys.items())]
    return subprocess.run(args, capture_output=True, text=True, timeout=180, env=plain_env(tmp))


def _key_values(stdout: str) -> dict[str, str]:
    return dict(line.split("=", 1) for line in stdout.splitlines() if "=" in line)


@pytest.mark.slow
def test_a_parallel_master_instantiates_and_steps_both_loops_at_once_as_one_thread_does(
        threaded_host, plant, controller, tmp_path):
    # The process's first fmi2Instantiate of the plant and of the controller in two threads at the same
    # moment (each pythonfmu binary would start Python under a lock of its own: two Py_Initialize at once
    # crashed 19 of 20 such processes), then every fmi2DoStep of a step in its own thread. The same
    # binaries, inputs and environment as the one-thread run: the threads change only who calls, so the
    # trajectories are the same bit for bit (hex floats).
    assert_parallel_loops_as_one_thread(
        lambda threads: _threaded(threaded_host, plant, controller, tmp_path, "loops", threads=threads), repeats=5)


def test_fmu_states_are_updated_freed_and_nulled_as_fmi2_says(threaded_host, plant, controller, tmp_path):
    # 2000 fmi2GetFMUstate and 2000 fmi2DeSerializeFMUstate into the state the host holds (FMI 2.0,
    # 2.1.8: that state is updated, the host owns one): a leak of the replaced states would grow RSS by
    # about 2.9 and 11 kB per call (5.7 and 23 MB); 1 MB bounds the allocator's own noise.
    proc = _threaded(threaded_host, plant, controller, tmp_path, "states", steps=2000)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = _key_values(proc.stdout)
    assert int(out["get_into_held_state_kb"]) < 1000, out
    assert int(out["deserialize_into_held_state_kb"]) < 1000, out
    assert out["pointer_after_free"] == "NULL"  # "returns a null pointer in argument FMUstate"
    assert out["second_free_status"] == "0"  # a null pointer: the call is ignored (fmi2OK)


def test_host_threads_that_exit_leave_no_python_thread_state_behind(threaded_host, plant, controller, tmp_path):
    # 2000 short-lived host threads, one fmi2GetReal each (a master that starts threads per run or per
    # step): each thread's Python thread state (about 4.4 kB) is deleted when the thread exits.
    proc = _threaded(threaded_host, plant, controller, tmp_path, "threads", steps=2000)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert int(_key_values(proc.stdout)["rss_growth_kb"]) < 1000, proc.stdout


def _prepared_as(built_fmus, tree: Path, monkeypatch, **recorded: str) -> Path:
    """The plant prepared again into ``tree`` from the layout pythonfmu makes, the build told that its
    Python's libpython is ``recorded`` (keys ``libpython``, ``libpython_soname``)."""
    import pythonfmu

    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        z.extractall(tree)
    bindir = tree / "binaries" / "linux64"
    (bindir / "MusclePlant_pythonfmu.so").unlink()  # back to the tree pythonfmu makes
    shutil.copy(Path(pythonfmu.__file__).parent / "resources" / "binaries" / "linux64" / "libpythonfmu-export.so",
                bindir / "MusclePlant.so")
    (tree / "resources" / CONFIG_NAME).unlink()
    env = native_host.build_environment()
    monkeypatch.setattr(native_host, "build_environment", lambda: {**env, **recorded})
    prepare_for_native_hosts(tree)
    return tree


def _fmpy_runs_as_built(built_fmus, tree: Path, tmp_path: Path) -> None:
    """FMPY_RUN on ``tree`` gives what it gives on the FMU as built, and exits cleanly, 3 times."""
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        z.extractall(tmp_path / "as-built")
    expected = subprocess.run([sys.executable, "-c", FMPY_RUN, str(tmp_path / "as-built")], capture_output=True,
                              text=True, timeout=180, check=True).stdout
    for _ in range(3):
        proc = subprocess.run([sys.executable, "-c", FMPY_RUN, str(tree)], capture_output=True, text=True,
                              timeout=180)
        assert proc.returncode == 0 and "corrupted" not in proc.stderr, proc.stderr[-4000:]
        assert host_lines(proc.stdout) == host_lines(expected) and len(host_lines(expected)) == 1


def _open_loop(host: Path, tree: Path, tmp_path: Path, **env: str) -> subprocess.CompletedProcess:
    md = read_model_description(str(tree))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    return run_host(host, tmp_path, "open", f"P.dir={tree}", "P.id=MusclePlant", f"P.guid={md.guid}",
                    f"P.u={vr['u']}", f"P.l={vr['l']}", "steps=5", check=False, env_extra=env)


def test_a_python_without_a_shared_libpython_builds_fmus_for_python_hosts_that_tell_other_hosts_why(
        host, built_fmus, tmp_path, monkeypatch):
    """A CPython built without --enable-shared (pyenv's and ./configure's default) has only a static
    libpython. Its FMUs run in Python hosts (fmpy, and libcosim or Ecos imported into Python), which
    are Python processes: the loader takes Python's API from the process. A host that runs no Python
    gets the reason from fmi2Instantiate, and the FMU never crashes it. Measured with such a Python
    (CPython 3.11.2 ./configure && make, .ci/static-python): the FMU suite passes but for the C-host
    tests, which skip (docs/fmu-native-hosts.md). Here the build is told the building Python has no
    shared libpython."""
    with pytest.warns(NativeHostWarning, match=r"FMU prepared for Python hosts only: the building Python .* has no "
                      r"shared libpython .*PYTHON_CONFIGURE_OPTS=--enable-shared"):
        tree = _prepared_as(built_fmus, tmp_path / "python-hosts-only", monkeypatch, libpython="",
                            libpython_soname="")
    assert json.loads((tree / "resources" / CONFIG_NAME).read_text())["python_hosts_only"] is True
    _fmpy_runs_as_built(built_fmus, tree, tmp_path)
    # in a C host: the instance refuses with the reason, the host ends at its first step, no crash
    for _ in range(3):
        proc = _open_loop(host, tree, tmp_path)
        assert proc.returncode == 2 and "fmi2DoStep" in proc.stderr, proc.stderr  # fmi_host: an FMI call failed
        assert ("the FMU's pythonfmu library MusclePlant_pythonfmu.so could not be loaded: the building Python "
                in proc.stderr), proc.stderr
        assert "has no shared libpython" in proc.stderr and "--enable-shared" in proc.stderr
        assert proc.stdout.splitlines() == ["t,u,l,p"]


def test_a_build_in_an_environment_in_uvs_cache_warns_that_it_is_temporary(built_fmus, tmp_path, monkeypatch):
    """`uvx --from tapmuscle tapmuscle build` records uv's cached environment for C hosts; after `uv
    cache clean` they would silently fall back to another Python, so the build says so."""
    monkeypatch.setattr(native_host, "uv_cache_environment", lambda: tmp_path / "uv")
    with pytest.warns(NativeHostWarning, match=r"lies in uv's cache \(.*/uv\): after `uv cache clean` such hosts "
                                               r"fall back to .*build them in an environment of your own"):
        _prepared_as(built_fmus, tmp_path / "tree", monkeypatch)


def test_an_fmu_whose_recorded_libpython_is_gone_runs_in_python_hosts_and_c_hosts_find_it_on_the_library_path(
        host, built_fmus, tmp_path, monkeypatch):
    """The FMU copied to another machine: its building Python's libpython is not at the recorded path.
    A Python host never needs it (were the loader linked to it, fmpy under a Python whose
    executable has Python linked in could not load the FMU: measured with a static CPython 3.11.2 and
    both libpython3.11.so.1.0 of this machine hidden). A C host finds it by its soname on
    LD_LIBRARY_PATH, or is told what to set."""
    libdir = sysconfig.get_config_var("LIBDIR")
    soname = native_host.build_environment()["libpython_soname"]
    if not soname:
        pytest.skip(f"the building Python ({sys.executable}) has no shared libpython")
    moved = _prepared_as(built_fmus, tmp_path / "moved", monkeypatch, libpython=f"/nonexistent/lib/{soname}")
    _fmpy_runs_as_built(built_fmus, moved, tmp_path)
    proc = _open_loop(host, moved, tmp_path, LD_LIBRARY_PATH=libdir)
    assert proc.returncode == 0 and len(table(proc.stdout)) == 5, proc.stderr[-3000:]

    gone = _prepared_as(built_fmus, tmp_path / "gone", monkeypatch, libpython="/nonexistent/lib/libpython-gone.so",
                        libpython_soname="libpython-gone.so.1.0")
    _fmpy_runs_as_built(built_fmus, gone, tmp_path)
    proc = _open_loop(host, gone, tmp_path, LD_LIBRARY_PATH=libdir)
    assert proc.returncode == 2 and "fmi2DoStep" in proc.stderr, proc.stderr
    assert ("this process runs no Python, and the FMU cannot load libpython-gone.so.1.0 "
            "(/nonexistent/lib/libpython-gone.so) to start one" in proc.stderr), proc.stderr
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    assert (f"The FMU was built by CPython {version}: set LD_LIBRARY_PATH to the folder of the libpython-gone.so.1.0 "
            f"of a CPython {version} built with --enable-shared" in proc.stderr), proc.stderr
    assert "or build the FMUs with a Python of yours (tapmuscle build" in proc.stderr


def test_the_value_references_of_the_docs_c_host_example_are_the_builds(built_fmus):
    """docs/fmu-native-hosts.md, "Running the C host by hand", sets the controller's method and delay by
    value reference; a change of the variables' order would leave them naming other variables."""
    import re

    text = (Path(__file__).parents[1] / "docs" / "fmu-native-hosts.md").read_text(encoding="utf-8")
    refs = {}
    for name, path in (("MusclePlant", built_fmus["MusclePlant"]), ("AMPCController", built_fmus["AMPCController"])):
        refs[name] = {v.name: v.valueReference for v in read_model_description(str(path)).modelVariables}
    example = re.search(r"MusclePlant u=(\d+) load_force=(\d+) l=(\d+) p=(\d+); AMPCController l=(\d+) u=(\d+) "
                        r"method=(\d+) input_delay_samples=(\d+)", text)
    assert example is not None
    pu, pload, pl, pp, cl, cu, method, delay = map(int, example.groups())
    assert (refs["MusclePlant"]["u"], refs["MusclePlant"]["l"], refs["MusclePlant"]["p"]) == (pu, pl, pp)
    assert refs["MusclePlant"]["load_force"] == pload and f"P.load={pload} " in text
    assert (refs["AMPCController"]["l"], refs["AMPCController"]["u"]) == (cl, cu)
    assert (refs["AMPCController"]["method"], refs["AMPCController"]["input_delay_samples"]) == (method, delay)
    assert f"C.int={method}:4" in text and f"C.int={delay}:0" in text
