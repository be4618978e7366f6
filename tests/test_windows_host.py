"""The FMUs' win64 binaries in a Windows Python host: a Windows CPython 3.11 with fmpy, under Wine.

``tests/windows_host/fmu_checks.py`` runs in that interpreter and in this one, and the answers are
compared: the plant alone, the closed loop stepped sequentially and in parallel (as libcosim and Ecos
step), the loop in libcosim's Windows build and as an FMU container of fmu-manipulation-toolbox (its
win64 C++ master), the FMU unpacked into a folder whose name is not ASCII (a
Windows user folder "Jürgen"), and the controller in a Python that lacks osqp with logging off. And
``tests/c_host/fmi_host.c``, built for both systems, runs the plant and the loop as a C host (no Python in
the process but the one the FMU starts from ``python3.dll`` on the Windows PATH), and
``tests/c_host/threaded_host.c`` does to the FMUs what a parallel C master's threads do (instantiation of
both FMUs at once, a thread per step, short-lived threads). The Windows interpreter
comes from ``tests/windows_host/prepare_python.py`` (PyPI only); Wine and the MinGW-w64 compiler that
builds the win64 shim from Debian's packages (`.ci/run` installs all three). Without them the tests skip,
unless ``TAPMUSCLE_REQUIRE_WINDOWS=1`` (CI) makes that a failure (``tests/windows_requirement.py``).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from computed_once import computed_once

HERE = Path(__file__).resolve().parent / "windows_host"
sys.path.insert(0, str(HERE))
from prepare_python import DEFAULT_DIR, python_exe  # noqa: E402
from fmu_container import build_parallel_container  # noqa: E402
from threaded_loops import assert_parallel_loops_as_one_thread  # noqa: E402
from windows_requirement import unavailable  # noqa: E402

pytestmark = [pytest.mark.windows, pytest.mark.slow]


def _wine() -> str | None:
    return shutil.which("wine64") or shutil.which("wine") or next(
        (p for p in ("/usr/lib/wine/wine64", "/usr/lib/wine/wine") if os.access(p, os.X_OK)), None)


def _windows_path(path: Path) -> str:
    return "Z:" + str(path).replace("/", "\\")  # Wine maps the root of this machine to Z:


@pytest.fixture(scope="module")
def windows(built_fmus) -> dict:
    """Wine, the Windows Python and its environment; FMUs built with the win64 shim."""
    wine = _wine()
    folder = Path(os.environ.get("TAPMUSCLE_WINDOWS_DIR", DEFAULT_DIR))
    exe = python_exe(folder)
    if not wine:
        unavailable("Wine is not installed (Debian: apt-get install wine64)")
    if not exe.is_file():
        unavailable(f"no Windows Python in {folder} (python tests/windows_host/prepare_python.py {folder})")
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        if "binaries/win64/MusclePlant_pythonfmu.dll" not in z.namelist():
            unavailable("the FMUs were built without the win64 shim (no x86_64-w64-mingw32-gcc)")
    # CI's second pass picks this machine's floating-point path with NPY_*/OPENBLAS_*; they name Linux
    # numpy's and OpenBLAS's kernels, not Windows numpy 1.26's
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NPY_", "OPENBLAS_"))}
    env.update(WINEPREFIX=str(folder / "wineprefix"), WINEDEBUG="-all")
    # A crashing program ends at once with Wine's one-line report: no debugger attached (winedbg hung on
    # a process whose threads had crashed together, until the test's timeout)
    subprocess.run([wine, "reg", "add", r"HKLM\Software\Microsoft\Windows NT\CurrentVersion\AeDebug", "/v",
                    "Debugger", "/t", "REG_SZ", "/d", "", "/f"], env=env, capture_output=True, timeout=300, check=True)
    return {"wine": wine, "python": exe, "env": env}


def _wine_stub_abort(stderr: str) -> bool:
    """Whether Wine ended the program at a call to an import it left unbound (its stub's message)."""
    return "wine: Unimplemented function python3" in stderr or "to unimplemented function python3" in stderr


def _run_windows(windows: dict, *args: str, env_extra: dict | None = None,
                 timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**windows["env"], **(env_extra or {})}
    try:
        for _ in range(2):
            proc = subprocess.run([windows["wine"], *args], env=env, capture_output=True, text=True, timeout=timeout)
            # Wine under load once ended a run at exit code 1 without a word from it or the program (the
            # hosts and scripts here always say why they fail), and once aborted a run at a stub Wine had
            # put in for an import of python3.dll it did not bind ("unimplemented function
            # python3.dll.Py_IsInitialized"; on Windows an import that does not bind fails LoadLibrary,
            # which the shim reports): the emulator's, so once more
            if proc.returncode == 0 or (proc.stdout or proc.stderr) and not _wine_stub_abort(proc.stderr):
                break
        return proc
    except subprocess.TimeoutExpired:
        # the Windows processes run under this prefix's wineserver, not as our children: end them all
        server = Path(windows["wine"]).with_name("wineserver")
        subprocess.run([str(server) if server.exists() else "wineserver", "-k"], env=env, capture_output=True)
        raise


@pytest.fixture(scope="module")
def answers(request, tmp_path_factory) -> dict:
    """What tests/windows_host/fmu_checks.py answered in the Windows Python (three runs) and in this
    Linux Python: computed once per test run (computed_once.py)."""
    return computed_once(tmp_path_factory, "windows-answers",
                         lambda out: _answers(request.getfixturevalue("windows"), request.getfixturevalue("built_fmus"),
                                              out))


def _answers(windows: dict, built_fmus: dict, out: Path) -> dict:
    # both FMUs and the loop as an FMU container (made here, on Linux; it carries its win64 binary too)
    fmu_dir = out / "fmus"
    fmu_dir.mkdir()
    build_parallel_container(built_fmus, fmu_dir)
    script = _windows_path(HERE / "fmu_checks.py")
    result: dict = {}
    for key, extra in (("windows", []), ("windows_folder", ["non-ascii-folder"]), ("windows_missing", ["osqp"])):
        target = out / f"{key}.json"
        proc = _run_windows(windows, str(windows["python"]), script, _windows_path(fmu_dir), _windows_path(target),
                            *extra)
        # a host that died is an answer too (the test of that case fails with its output)
        result[key] = (json.loads(target.read_text(encoding="utf-8")) if proc.returncode == 0 and target.is_file()
                       else {"exit": proc.returncode, "output": (proc.stdout + proc.stderr)[-3000:]})
    target = out / "linux.json"
    subprocess.run([sys.executable, str(HERE / "fmu_checks.py"), str(fmu_dir), str(target)], check=True,
                   timeout=600)
    result["linux"] = json.loads(target.read_text(encoding="utf-8"))
    return result


def _answer(answers: dict, key: str) -> dict:
    assert "exit" not in answers[key], f"the Windows host ended with {answers[key]['exit']}:\n{answers[key]['output']}"
    return answers[key]


def test_the_host_is_windows(answers):
    assert _answer(answers, "windows")["platform"] == "win32" and answers["linux"]["platform"] == "linux"


def test_the_plant_alone_reads_as_in_linux_fmpy(answers):
    # the same Python code on the same inputs: only the C library's exp/pow (and numpy) could differ, in
    # the last bits, and the readings are quantised (encoder 0.01 mm, the pressure sensor's steps): they
    # agree unless such a bit meets a quantisation edge, which 1e-9 would show
    win, lin = _answer(answers, "windows")["plant"], answers["linux"]["plant"]
    assert win["l_mm"] == pytest.approx(lin["l_mm"], abs=1e-9)
    assert win["p_mpa"] == pytest.approx(lin["p_mpa"], abs=1e-9)
    assert 30.0 < win["l_mm"] < 100.0  # the muscle contracted at 5 V


def test_an_fmu_folder_with_non_ascii_characters_runs(answers):
    # pythonfmu's own DLL crashes the host process here; the shim hands it the folder's short name
    odd, plain = _answer(answers, "windows_folder")["plant"], _answer(answers, "windows")["plant"]
    assert "J\u00fcrgen \u65e5\u672c" in odd["folder"]
    assert odd["l_mm"] == plain["l_mm"] and odd["p_mpa"] == plain["p_mpa"]


@pytest.mark.parametrize("master", ["sequential", "parallel", "libcosim", "container"])
def test_the_closed_loop_tracks_as_in_linux(answers, master):
    win, lin = _answer(answers, "windows")[master], answers["linux"][master]
    assert win.get("finite", True) and win.get("stepped", 600) == 600
    assert 0.0 <= win["u_min_v"] <= win["u_max_v"] <= 10.0
    # Windows' numpy (1.26 under Wine) and C library round differently from Linux's in the last bits, and
    # the adaptive loop carries that on: Eq. (21) within the 10 % a master may cost
    assert win["mae_20_60_mm"] == pytest.approx(lin["mae_20_60_mm"], rel=0.10)
    assert win["mae_20_60_mm"] < 0.15  # docs/fmu.md: 0.071 mm sequential, 0.124 mm parallel (libcosim, container too)


def test_a_missing_package_is_named_and_the_instance_refuses_cleanly(answers):
    missing = _answer(answers, "windows_missing")["missing"]
    assert missing["instantiated"]  # an instance that answers, not NULL (pythonfmu's own DLL returns NULL)
    assert "status 3" in missing["step"]  # fmi2Error from fmi2DoStep
    errors = [m for status, _category, m in missing["messages"] if status >= 3]
    assert errors and all("osqp" in m for m in errors)  # logged although logging is off
    assert all(category for _status, category, _m in missing["messages"])


# ---- a Windows C host: tests/c_host/fmi_host.c cross-compiled, no Python in the process but the FMU's ----

C_HOST = Path(__file__).resolve().parent / "c_host" / "fmi_host.c"


def _table(stdout: str) -> list[list[float]]:
    lines = [line for line in stdout.splitlines() if line and line[0].isdigit()]
    return [[float(x) for x in line.split(",")] for line in lines]


def _compile_c_host(source: str, folder: Path, std: str, *, linux_libs: list[str] | None = None) -> dict[str, Path]:
    """tests/c_host/``source`` built for Windows (MinGW-w64, static: no MinGW DLL beside it) and, with
    ``linux_libs``, for Linux (gcc) too, with fmpy's FMI headers."""
    mingw, gcc = shutil.which("x86_64-w64-mingw32-gcc"), shutil.which("gcc") or shutil.which("cc")
    if not mingw or not gcc:
        unavailable("x86_64-w64-mingw32-gcc and gcc are needed to build the C hosts for both systems")
    headers = str(Path(__import__("fmpy").__file__).parent / "c-code")
    flags = [f"-std={std}", "-O2", "-Wall", "-Wextra", "-I", headers]
    stem = Path(source).stem
    built = {"windows": folder / f"{stem}.exe"}
    subprocess.run([mingw, *flags, "-o", str(built["windows"]), str(C_HOST.with_name(source)), "-static",
                    "-lpthread"], check=True)
    if linux_libs is not None:
        built["linux"] = folder / stem
        subprocess.run([gcc, *flags, "-o", str(built["linux"]), str(C_HOST.with_name(source)), *linux_libs],
                       check=True)
    return built


@pytest.fixture(scope="module")
def extracted(built_fmus, tmp_path_factory) -> dict:
    """Both FMUs unzipped: key P (plant) or C (controller) -> folder, model identifier, GUID and value
    references by name."""
    from fmpy import read_model_description

    tmp = tmp_path_factory.mktemp("windows-c-host-fmus")
    fmus = {}
    for key, name in (("P", "MusclePlant"), ("C", "AMPCController")):
        folder = tmp / name
        with zipfile.ZipFile(built_fmus[name]) as z:
            z.extractall(folder)
        md = read_model_description(str(folder))
        fmus[key] = (folder, md.coSimulation.modelIdentifier, md.guid,
                     {v.name: v.valueReference for v in md.modelVariables})
    return fmus


def _host_args(fmus: dict, windows_paths: bool, roles: dict[str, dict[str, str]]) -> list[str]:
    """``KEY.dir= KEY.id= KEY.guid= KEY.<role>=<value reference>`` for the FMUs named in ``roles``
    (key -> role -> variable); Windows paths as Z:/... with forward slashes."""
    out = []
    for key, of_key in roles.items():
        folder, model_id, guid, vr = fmus[key]
        where = _windows_path(folder).replace("\\", "/") if windows_paths else str(folder)
        out += [f"{key}.dir={where}", f"{key}.id={model_id}", f"{key}.guid={guid}"]
        out += [f"{key}.{role}={vr[name]}" for role, name in of_key.items()]
    return out


@pytest.fixture(scope="module")
def c_host_runs(request, tmp_path_factory) -> dict:
    """tests/c_host/fmi_host.c built for Linux (gcc) and for Windows (MinGW-w64), each run on the plant
    alone (`open`) and on the closed loop (`closed`) with the same arguments; the Windows one under Wine
    with the Windows Python's folder on its PATH (python3.dll, which pythonfmu's DLL imports). Computed
    once per test run (computed_once.py)."""
    return computed_once(tmp_path_factory, "windows-c-host-runs",
                         lambda folder: _c_host_runs(request.getfixturevalue("windows"),
                                                     request.getfixturevalue("extracted"), folder))


def _c_host_runs(windows: dict, extracted: dict, folder: Path) -> dict:
    """:func:`c_host_runs`'s runs, with the hosts and the Pythons they need made in ``folder``."""
    (folder / "hosts").mkdir()
    hosts = _compile_c_host("fmi_host.c", folder / "hosts", "c99", linux_libs=["-ldl", "-lm"])

    def args(windows_paths: bool, mode: str) -> list[str]:
        roles = {"P": {"u": "u", "l": "l", "p": "p"}, **({"C": {"l": "l", "u": "u"}} if mode == "closed" else {})}
        return [mode, *_host_args(extracted, windows_paths, roles), "dt=0.1",
                f"steps={100 if mode == 'open' else 600}"]

    runs: dict = {}
    path = {"WINEPATH": _windows_path(windows["python"].parent)}
    for mode in ("open", "closed"):
        lin = subprocess.run([str(hosts["linux"]), *args(False, mode)], capture_output=True, text=True, timeout=600)
        win = _run_windows(windows, str(hosts["windows"]), *args(True, mode), env_extra=path)
        runs[mode] = {"linux": (lin.returncode, _table(lin.stdout), lin.stderr[-3000:]),
                      "windows": (win.returncode, _table(win.stdout), win.stderr[-3000:])}
    # two plant instances at once, both freed, the DLL freed and loaded again, a third instance
    again = _run_windows(windows, str(hosts["windows"]), "instances",
                         *_host_args(extracted, True, {"P": {"u": "u", "l": "l", "load": "load_force"}}),
                         "load_a=44", "load_b=68", "u_const=6", "steps=100", "dt=0.1", "unload=1", env_extra=path)
    runs["instances"] = (again.returncode, again.stdout, again.stderr[-3000:])
    # and as a user's C host may start: no Python on PATH (Wine's PATH has no python3.dll of its own)
    bare = _run_windows(windows, str(hosts["windows"]), *args(True, "open"))
    runs["no_python"] = (bare.returncode, bare.stdout, bare.stderr[-3000:])
    # or a Python without osqp: a copy of the interpreter whose site folder links all but osqp
    lacking = folder / "windows-python-without-osqp"
    shutil.copytree(windows["python"].parent, lacking / "python")
    (lacking / "site").mkdir()
    for entry in (windows["python"].parent.parent / "site").iterdir():
        if not entry.name.lower().startswith("osqp"):
            (lacking / "site" / entry.name).symlink_to(entry)
    no_osqp = _run_windows(windows, str(hosts["windows"]), *args(True, "closed"),
                           env_extra={"WINEPATH": _windows_path(lacking / "python")})
    # the whole stderr: the full reason is logged once, first; the messages after it carry its start
    runs["no_osqp"] = (no_osqp.returncode, _windows_path(lacking / "python" / "python.exe"), no_osqp.stderr)
    # TAPMUSCLE_PYTHON names the Python, ahead of the one on PATH (here the one without osqp)
    named = _run_windows(windows, str(hosts["windows"]), *args(True, "closed"),
                         env_extra={"WINEPATH": _windows_path(lacking / "python"),
                                    "TAPMUSCLE_PYTHON": _windows_path(windows["python"])})
    runs["named"] = (named.returncode, _table(named.stdout), named.stderr[-3000:])
    missing = _windows_path(lacking / "nothing" / "python.exe")
    wrong = _run_windows(windows, str(hosts["windows"]), *args(True, "open"), env_extra={"TAPMUSCLE_PYTHON": missing})
    runs["named_wrong"] = (wrong.returncode, missing, wrong.stderr[-3000:])
    # PYTHONHOME, which a Python without a ._pth file takes (an installation's; the embeddable
    # distribution's ._pth makes it ignore PYTHONHOME): a folder without a standard library, for this
    # Python without its ._pth and with it; and one with a standard library that does not fit
    unpinned = folder / "windows-python-without-pth" / "python"
    shutil.copytree(windows["python"].parent, unpinned, ignore=shutil.ignore_patterns("*._pth"))
    nowhere = _windows_path(lacking / "nothing")
    zip_only = folder / "windows-home-zip-only"
    zip_only.mkdir()
    for archive in windows["python"].parent.glob("python3*.zip"):
        shutil.copy(archive, zip_only)
    for key, python, home in (("bad_home", unpinned, nowhere), ("bad_home_pinned", windows["python"].parent, nowhere),
                              ("other_home", unpinned, _windows_path(unpinned)),
                              ("zip_only_home", unpinned, _windows_path(zip_only))):
        done = _run_windows(windows, str(hosts["windows"]), *args(True, "open"),
                            env_extra={"WINEPATH": _windows_path(python), "PYTHONHOME": home})
        runs[key] = (done.returncode, home, _table(done.stdout) if done.returncode == 0 else [], done.stderr[-3000:])
    return runs


def _mae(rows: list[list[float]]) -> float:
    """Eq. (21) over 20-60 s of the C host's closed loop (t, l, u rows), against the controller's
    built-in reference."""
    err = [abs(35.0 + 30.0 * math.sin(2 * math.pi * 0.1 * t) - l) for t, l, _u in rows if t >= 20.0 - 1e-9]
    return sum(err) / len(err)


def test_tapmuscle_python_names_the_python_of_a_windows_c_host(c_host_runs):
    # As on Linux: TAPMUSCLE_PYTHON names the interpreter the FMU starts, here ahead of a Python on PATH
    # that lacks osqp; the loop runs as with the right Python on PATH. A name that is not a file is
    # refused with the variable and its value.
    (lin_rc, lin, lin_err), (rc, rows, err) = c_host_runs["closed"]["linux"], c_host_runs["named"]
    assert lin_rc == 0, lin_err
    assert rc == 0, err
    assert len(rows) == 600 and _mae(rows) == pytest.approx(_mae(lin), rel=0.10)
    rc, missing, err = c_host_runs["named_wrong"]
    assert rc == 2, err
    assert f"could not be loaded: TAPMUSCLE_PYTHON={missing} is not a file" in err


def test_a_pythonhome_without_a_standard_library_is_named_by_the_windows_host(c_host_runs):
    # Taken by the FMU's Python it fails at a module it cannot find ("No module named '_ctypes'"),
    # naming nothing: checked before, the instances fail naming PYTHONHOME, and the host refuses cleanly; where the Python's
    # ._pth makes it ignore PYTHONHOME (the embeddable distribution), the FMU runs; and the failure of
    # a Python that took a PYTHONHOME with a standard library names it too (here: no numpy there)
    returncode, home, _rows, stderr = c_host_runs["bad_home"]
    assert returncode == 2, stderr
    assert f"PYTHONHOME={home} has no Python standard library (no Lib\\encodings, no python3*.zip)" in stderr, stderr
    assert "fmi2DoStep refused" in stderr
    returncode, _home, rows, stderr = c_host_runs["bad_home_pinned"]
    assert returncode == 0 and len(rows) == 100, stderr
    returncode, home, _rows, stderr = c_host_runs["other_home"]
    assert returncode == 2, stderr
    assert f"PYTHONHOME={home} is set: the FMU's Python t" in stderr.replace("\\\\", "\\"), stderr
    # a standard library without its extension modules: Python fails before any of the FMU's code runs
    returncode, home, _rows, stderr = c_host_runs["zip_only_home"]
    assert returncode == 2, stderr
    assert "No module named" in stderr and f"(PYTHONHOME={home} is set: the FMU's Python took its standard library " \
        "from there; unset it unless it is the home of the Python whose python3.dll the FMU loaded)" in stderr, stderr


def test_a_windows_c_host_frees_reloads_and_instantiates_again(c_host_runs):
    # As tests/test_c_host.py on Linux: between the frees and the new instance the host FreeLibrary()s
    # and loads the FMU's DLL again (the shim stays loaded once it keeps thread states)
    returncode, stdout, stderr = c_host_runs["instances"]
    assert returncode == 0, stderr
    l_mm = {row["name"]: float(row["l"]) for row in csv.DictReader(io.StringIO(stdout))}
    assert set(l_mm) == {"a", "b", "c"}
    assert l_mm["a"] - l_mm["b"] > 3.0  # the heavier load hangs lower: the instances do not share state
    assert l_mm["c"] == l_mm["a"]  # a fresh instance after freeing both repeats a's run exactly


def test_a_windows_c_host_without_python_on_path_is_told_what_to_put_there(c_host_runs):
    # Windows reports a missing python3.dll (pythonfmu's DLL imports it) as "module not found", the
    # same code as a missing FMU library: the message names python3.dll and PATH, and the host goes on
    # to a clean refusal (fmi_host exits 2 at the first fmi2DoStep, no crash)
    returncode, _stdout, stderr = c_host_runs["no_python"]
    assert returncode == 2, stderr
    assert ("could not be loaded: it imports python3.dll, which is not on the DLL search path: put the folder "
            "of a 64-bit Python 3") in stderr
    assert "fmi2DoStep refused" in stderr


def test_a_windows_c_host_whose_python_lacks_osqp_is_told_how_to_install_it_there(c_host_runs):
    # The interpreter the FMU started reports the host's program as sys.executable; the advice names
    # the Python's own python.exe (not the host's fmi_host.exe), and, as this
    # embeddable distribution has no pip, an installer that works without it
    returncode, python, stderr = c_host_runs["no_osqp"]
    assert returncode == 2, stderr
    assert (f"install it into the Python the FMU uses: this Python has no pip (a uv environment, an embeddable "
            f"distribution): uv pip install --python {python} osqp".replace("\\", "\\\\")) in stderr, stderr


def test_the_plant_in_a_windows_c_host_reads_as_in_the_linux_one(c_host_runs):
    (lin_rc, lin, lin_err), (win_rc, win, win_err) = c_host_runs["open"]["linux"], c_host_runs["open"]["windows"]
    assert lin_rc == 0, lin_err
    assert win_rc == 0, win_err
    assert len(win) == len(lin) == 100
    for a, b in zip(win, lin):
        # t, u (the host's sin: the C libraries may differ in the last bit), and l, p quantised as above
        assert a == pytest.approx(b, abs=1e-9)


def test_the_closed_loop_in_a_windows_c_host_tracks_as_in_the_linux_one(c_host_runs):
    (lin_rc, lin, lin_err), (win_rc, win, win_err) = c_host_runs["closed"]["linux"], c_host_runs["closed"]["windows"]
    assert lin_rc == 0, lin_err
    assert win_rc == 0, win_err

    assert len(win) == len(lin) == 600
    assert all(0.0 <= u <= 10.0 and math.isfinite(l) for _t, l, u in win)
    assert _mae(win) == pytest.approx(_mae(lin), rel=0.10) and _mae(win) < 0.15


# ---- a parallel master's threads in a Windows C host: tests/c_host/threaded_host.c cross-compiled ----

@pytest.fixture(scope="module")
def threaded(windows, extracted, tmp_path_factory):
    """Runs threaded_host.exe MODE under Wine on the plant and the controller, in a fresh process each
    time (Python started by the FMUs, not yet running); returns the CompletedProcess."""
    exe = _compile_c_host("threaded_host.c", tmp_path_factory.mktemp("windows-threaded-host"), "gnu11")["windows"]
    roles = {"P": {"u": "u", "l": "l", "load": "load_force"}, "C": {"l": "l", "u": "u"}}
    path = {"WINEPATH": _windows_path(windows["python"].parent)}

    def run(mode: str, **keys) -> subprocess.CompletedProcess:
        return _run_windows(windows, str(exe), mode, *_host_args(extracted, True, roles),
                            *(f"{k}={v}" for k, v in keys.items()), env_extra=path, timeout=180)  # ~8 s a run

    return run


def test_a_parallel_windows_master_instantiates_and_steps_both_loops_at_once_as_one_thread_does(threaded):
    # As tests/test_c_host.py's Linux case: the first fmi2Instantiate of the plant and of the controller
    # in two threads at the same moment (pythonfmu's DLLs each start Python under a lock of their own:
    # without the shim's process-wide mutex 5 of 5 such processes crashed in Py_Initialize under Wine),
    # then every fmi2DoStep of a step in its own thread. The same binaries and inputs as the one-thread
    # run: the threads change only who calls, so the trajectories are the same bit for bit (hex floats).
    assert_parallel_loops_as_one_thread(lambda threads: threaded("loops", threads=threads), repeats=3)


def test_windows_host_threads_that_exit_leave_no_python_thread_state_behind(threaded):
    # 2000 short-lived host threads, one fmi2GetReal each: the thread state the shim keeps for a host
    # thread is deleted when the thread exits (its fiber-local slot's callback). Measured as the
    # process's commit charge: 0 kB with the callback, 8.1 MB without it (about 4 kB a thread).
    proc = threaded("threads", steps=2000)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert int(dict(line.split("=", 1) for line in proc.stdout.splitlines())["rss_growth_kb"]) < 1000, proc.stdout


# ---- tapmuscle itself in a Windows Python (a notebook's or a script's): `tapmuscle run` ----

ROOT = Path(__file__).resolve().parents[1]
#: runs ``python -m tapmuscle ARGS`` with this checkout first on sys.path (the embeddable Python reads
#: no PYTHONPATH)
_TAPMUSCLE = ("import runpy, sys; sys.path.insert(0, sys.argv.pop(1)); "
              "runpy.run_module('tapmuscle', run_name='__main__', alter_sys=True)")


def test_tapmuscle_runs_a_scenario_in_a_windows_python_as_in_linux(windows, tmp_path):
    scenario = ROOT / "scenarios" / "examples" / "load_step.toml"
    proc = _run_windows(windows, str(windows["python"]), "-c", _TAPMUSCLE, _windows_path(ROOT), "run",
                        _windows_path(scenario), "--out", _windows_path(tmp_path / "windows"), "--quiet")
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    subprocess.run([sys.executable, "-m", "tapmuscle", "run", str(scenario), "--out", str(tmp_path / "linux"),
                    "--quiet"], check=True, capture_output=True, timeout=600)
    win, lin = (json.loads((tmp_path / k / "summary.json").read_text(encoding="utf-8")) for k in ("windows", "linux"))
    # the same FMUs' code; Windows' numpy 1.26 and C library move the controller's last bits, which the
    # 45-s adaptive loop carries (1e-9 V in u here): Eq. (21) the same to 1 %
    assert win["mae_mm"] == pytest.approx(lin["mae_mm"], rel=0.01)
    assert win["fmus"]["MusclePlant"]["path"].startswith("C:\\")  # built in the Windows Python's own cache
    assert all((tmp_path / "windows" / f).stat().st_size > 10_000 for f in ("tracking.png", "parameters.png"))
