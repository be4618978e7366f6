"""FMU extraction folders: removed after the process that used them, also when it was killed."""

import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from fmpy_helpers import host_lines

from tapmuscle.cosim import PAPER_SCENARIOS
from tapmuscle.cosim.extraction_folder import LOCK_NAME, claimed_folder, remove_abandoned

pytestmark = pytest.mark.skipif(os.name != "posix", reason="the lock is an fcntl.flock")

CLAIM = textwrap.dedent("""
    import os, signal, sys
    from tapmuscle.cosim.extraction_folder import claimed_folder
    folder = claimed_folder("tm_test_", sys.argv[1])
    open(os.path.join(folder, "payload"), "w").write("x")
    print(folder, flush=True)
    how = sys.argv[2]
    if how == "wait":
        sys.stdin.readline()
    elif how == "_exit":
        os._exit(0)
    elif how == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
""")


def _claim(root, how, **kw):
    return subprocess.Popen([sys.executable, "-c", CLAIM, str(root), how], stdout=subprocess.PIPE,
                            stdin=subprocess.PIPE, text=True, **kw)


def _claimed(proc) -> str:
    """The folder the child process printed (past fmpy's import notice on machines that get one)."""
    while True:
        line = proc.stdout.readline()
        if not line or host_lines(line):
            return line.strip()


def _folders(root, prefix="tm_test_"):
    return sorted(p.name for p in root.iterdir() if p.name.startswith(prefix))


@pytest.mark.parametrize("how", ["_exit", "kill"])
def test_a_killed_process_folder_is_removed_by_the_next_claim(tmp_path, how):
    with _claim(tmp_path, how) as proc:
        folder = _claimed(proc)
        proc.wait(timeout=60)
    assert proc.returncode == (0 if how == "_exit" else -signal.SIGKILL)
    assert _folders(tmp_path) == [os.path.basename(folder)]  # atexit did not run: the folder is left
    mine = claimed_folder("tm_test_", tmp_path)
    assert _folders(tmp_path) == [os.path.basename(mine)]


def test_a_live_process_folder_is_kept_and_removed_at_its_normal_exit(tmp_path):
    with _claim(tmp_path, "wait") as proc:
        try:
            folder = _claimed(proc)
            assert remove_abandoned("tm_test_", tmp_path) == []
            mine = claimed_folder("tm_test_", tmp_path)
            assert _folders(tmp_path) == sorted([os.path.basename(folder), os.path.basename(mine)])
            with open(os.path.join(folder, "payload")) as fh:
                assert fh.read() == "x"
            # this process's own folder is in use too: a sweep from here leaves it
            assert remove_abandoned("tm_test_", tmp_path) == []
        finally:
            proc.communicate("\n", timeout=60)
    assert proc.returncode == 0
    assert _folders(tmp_path) == [os.path.basename(mine)]


def test_folders_without_a_lock_or_of_another_prefix_are_left_alone(tmp_path):
    (tmp_path / "tm_test_foreign").mkdir()
    (tmp_path / "other_x").mkdir()
    (tmp_path / "other_x" / LOCK_NAME).touch()
    assert remove_abandoned("tm_test_", tmp_path) == []
    assert _folders(tmp_path, "") == ["other_x", "tm_test_foreign"]


@pytest.mark.fmu
def test_an_fmu_extracted_by_a_killed_process_is_removed_by_the_next(built_fmus, tmp_path):
    """The master's extraction (``unpack``) in a process that ends without its exit handlers, as a
    restarted notebook kernel or a terminated Dask worker does; TMPDIR keeps the test to its folder."""
    code = textwrap.dedent("""
        import os, sys
        from tapmuscle.cosim.master import unpack
        print(unpack(sys.argv[1]).folder, flush=True)
        if sys.argv[2] == "_exit":
            os._exit(0)
    """)
    # the cache too, where a temporary folder named beyond ASCII sends the extraction (extraction_root)
    env = {**os.environ, "TMPDIR": str(tmp_path), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    plant = str(built_fmus["MusclePlant"])

    def run(how):
        out = subprocess.run([sys.executable, "-c", code, plant, how], env=env, capture_output=True, text=True,
                             timeout=120)
        assert out.returncode == 0, out.stderr
        return host_lines(out.stdout)[-1].strip()

    left = run("_exit")
    root, name = os.path.split(left)
    root = Path(root)
    assert root in (tmp_path, tmp_path / "cache" / "tapmuscle" / "extracted")
    assert _folders(root, "tapmuscle_") == [name]
    assert os.path.isfile(os.path.join(left, "modelDescription.xml"))
    run("exit")  # removes the abandoned folder, and its own at its exit
    assert _folders(root, "tapmuscle_") == []


def test_a_temporary_directory_mounted_noexec_sends_the_folders_to_the_cache(tmp_path, monkeypatch):
    from tapmuscle.cosim import extraction_folder

    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    monkeypatch.setattr(extraction_folder.tempfile, "tempdir", None)  # read TMPDIR again
    (tmp_path / "tmp").mkdir()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert extraction_folder.extraction_root() == str(tmp_path / "tmp")
    noexec = {str(tmp_path / "tmp")}
    monkeypatch.setattr(extraction_folder, "_noexec", lambda folder: str(folder) in noexec)
    assert extraction_folder.extraction_root() == str(tmp_path / "cache" / "tapmuscle" / "extracted")
    assert claimed_folder("tm_test_").startswith(str(tmp_path / "cache" / "tapmuscle" / "extracted" / "tm_test_"))
    noexec.add(str(tmp_path / "cache" / "tapmuscle" / "extracted"))
    with pytest.raises(OSError, match=r"temporary directory .*/tmp is mounted noexec \(no FMU binary can be loaded "
                                      r"from it\), and the cache .*/extracted is mounted noexec .*: set TMPDIR"):
        extraction_folder.extraction_root()


def test_a_temporary_directory_named_in_latin_1_sends_the_folders_to_the_cache(built_fmus, tmp_path, monkeypatch):
    """TMPDIR /tmp/M\xfcller (bytes that are not UTF-8: a Windows zip's or an old home folder's name): the
    FMUs' Python cannot open a path there (pythonfmu's constructor failed with "PyList_Insert: bad
    argument to internal function"), so the folders go to the cache, and a scenario runs."""
    from tapmuscle.cosim import extraction_folder

    latin = os.fsdecode(bytes(tmp_path) + b"/M\xfcller")
    os.mkdir(latin)
    monkeypatch.setenv("TMPDIR", latin)
    monkeypatch.setattr(extraction_folder.tempfile, "tempdir", None)  # read TMPDIR again
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert extraction_folder.extraction_root() == str(tmp_path / "cache" / "tapmuscle" / "extracted")
    monkeypatch.setenv("XDG_CACHE_HOME", os.path.join(latin, "cache"))
    with pytest.raises(OSError, match=r"temporary directory .*/M\\xfcller has a name that is not UTF-8 .*and the "
                                      r"cache .*/M\\xfcller/cache/tapmuscle/extracted has a name that is not UTF-8"):
        extraction_folder.extraction_root()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    scenario = tmp_path / "s.toml"
    scenario.write_text("duration_s = 2.0\n")
    proc = subprocess.run([sys.executable, "-m", "tapmuscle", "run", str(scenario), "--out", str(tmp_path / "out"),
                           "--fmu-dir", str(built_fmus["MusclePlant"].parent), "--quiet"],
                          capture_output=True, text=True, timeout=600, env=os.environ.copy())
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert os.listdir(latin) == ["cache"]  # nothing was extracted there (the cache folder made above)


FOREIGN_RUN = textwrap.dedent("""
    import sys
    from tapmuscle.cosim.master import FmuInstance
    from tapmuscle.diagnosis.foreign_fmus.thermal import build_thermal_fmu

    inst = FmuInstance(build_thermal_fmu(sys.argv[1]), "thermal", role="foreign plant")
    inst.start()
    inst.fmu.setReal([inst.vr("P1")], [50.0])
    inst.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=10.0)
    print(inst.unpacked.folder, inst.fmu.getReal([inst.vr("T1")])[0], flush=True)
    inst.free()
""")


@pytest.mark.utf8_paths
def test_a_temporary_directory_named_beyond_ascii_sends_the_folders_to_an_ascii_cache(tmp_path, monkeypatch):
    """TMPDIR /tmp/.../Zürich (UTF-8): the project's FMUs open it, but an FMU on pythonfmu's own binary
    (the foreign demo ThermalTwoMass, or a user's) decodes only %20 of its resource URI and crashes the
    process in fmi2Instantiate there; the folders go to an ASCII cache, and that FMU runs through the
    master. Where the cache is not ASCII either, cannot take a folder or cannot be had, the temporary
    directory is used."""
    from tapmuscle.cosim import extraction_folder

    if not str(tmp_path).isascii():
        pytest.skip(f"the test's ASCII cache would be in pytest's temporary folder {tmp_path}, named beyond ASCII")
    zurich = tmp_path / "Z\u00fcrich"
    zurich.mkdir()
    monkeypatch.setenv("TMPDIR", str(zurich))
    monkeypatch.setattr(extraction_folder.tempfile, "tempdir", None)  # read TMPDIR again
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    cache = str(tmp_path / "cache" / "tapmuscle" / "extracted")
    assert extraction_folder.extraction_root() == cache
    monkeypatch.setenv("XDG_CACHE_HOME", str(zurich / "cache"))
    assert extraction_folder.extraction_root() == str(zurich)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    # a cache that cannot take a folder (a read-only HOME), or none to be had: the temporary directory
    monkeypatch.setattr(extraction_folder.os, "access", lambda path, mode: path != Path(cache))
    assert extraction_folder.extraction_root() == str(zurich)
    monkeypatch.undo()
    monkeypatch.setenv("TMPDIR", str(zurich))
    monkeypatch.setattr(extraction_folder.tempfile, "tempdir", None)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    (tmp_path / "home").mkdir()
    (tmp_path / "home" / ".cache").write_text("a file where the cache folder would be\n")
    assert extraction_folder.extraction_root() == str(zurich)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, "-c", FOREIGN_RUN, str(tmp_path / "fmu")], capture_output=True, text=True,
                          timeout=300, env=os.environ.copy())
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-3000:])
    folder, t1 = host_lines(proc.stdout)[-1].rsplit(" ", 1)
    assert folder.startswith(cache) and 20.5 < float(t1) < 22.0  # 10 s of 50 W into 500 J/K: about +1 K
    assert not any(name.startswith("tapmuscle_") for name in os.listdir(zurich))


NOEXEC_RUN = textwrap.dedent("""
    mount -t tmpfs -o noexec,size=256m tmpfs "$TMPDIR" || exit 77
    # the mount refuses libraries: what the dynamic loader says for any library there
    cp "$LIBRARY" "$TMPDIR/probe.so"
    "$PYTHON" -c 'import ctypes, sys; ctypes.CDLL(sys.argv[1])' "$TMPDIR/probe.so" 2>&1 | tail -1
    exec "$PYTHON" -m tapmuscle run "$SCENARIO" --out "$OUT" --fmu-dir "$FMUS" --quiet
""")


@pytest.mark.slow
def test_a_scenario_runs_where_the_temporary_directory_is_mounted_noexec(built_fmus, tmp_path):
    """A hardened system's /tmp (noexec) refuses to map the FMUs' libraries; the run extracts them
    into the user's cache instead. A tmpfs mounted noexec in a private mount namespace (unshare)."""
    unshare = shutil.which("unshare")
    if not unshare:
        pytest.skip("unshare (util-linux) not found")
    (tmp_path / "tmp").mkdir()
    env = {**os.environ, "TMPDIR": str(tmp_path / "tmp"), "XDG_CACHE_HOME": str(tmp_path / "cache"),
           "PYTHON": sys.executable, "LIBRARY": str(subprocess.check_output(
               [sys.executable, "-c", "import _ctypes; print(_ctypes.__file__)"], text=True).strip()),
           "SCENARIO": str(PAPER_SCENARIOS / "ampc_servo_44N_0.1Hz.toml"),
           "OUT": str(tmp_path / "out"), "FMUS": str(next(iter(built_fmus.values())).parent)}
    # root: a private mount namespace; anyone else: a user namespace as well, where allowed
    flags = ["--mount"] if os.geteuid() == 0 else ["--user", "--map-root-user", "--mount"]
    proc = subprocess.run([unshare, *flags, "sh", "-c", NOEXEC_RUN], env=env, capture_output=True, text=True,
                          timeout=600)
    if proc.returncode == 77 or any(why in proc.stderr for why in (
            "unshare failed", "Operation not permitted",
            "cannot change root filesystem propagation")):  # a chroot whose / is no mount point
        pytest.skip(f"cannot mount a tmpfs in a private namespace here: {proc.stderr.strip()[-300:]}")
    assert "failed to map segment from shared object" in proc.stdout, proc.stdout + proc.stderr
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Eq. (21) error" in proc.stdout and (tmp_path / "out" / "summary.json").is_file()
    assert (tmp_path / "cache" / "tapmuscle" / "extracted").is_dir()
    assert not list((tmp_path / "cache" / "tapmuscle" / "extracted").iterdir())  # removed at the exit
