"""FMU extraction folders: removed after the process that used them, also when it was killed."""

import os
import signal
import subprocess
import sys
import textwrap

import pytest
from fmpy_helpers import host_lines

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
    proc = _claim(tmp_path, how)
    folder = _claimed(proc)
    proc.wait(timeout=60)
    assert proc.returncode == (0 if how == "_exit" else -signal.SIGKILL)
    assert _folders(tmp_path) == [os.path.basename(folder)]  # atexit did not run: the folder is left
    mine = claimed_folder("tm_test_", tmp_path)
    assert _folders(tmp_path) == [os.path.basename(mine)]


def test_a_live_process_folder_is_kept_and_removed_at_its_normal_exit(tmp_path):
    proc = _claim(tmp_path, "wait")
    try:
        folder = _claimed(proc)
        assert remove_abandoned("tm_test_", tmp_path) == []
        mine = claimed_folder("tm_test_", tmp_path)
        assert _folders(tmp_path) == sorted([os.path.basename(folder), os.path.basename(mine)])
        assert open(os.path.join(folder, "payload")).read() == "x"
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
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    plant = str(built_fmus["MusclePlant"])

    def run(how):
        out = subprocess.run([sys.executable, "-c", code, plant, how], env=env, capture_output=True, text=True,
                             timeout=120)
        assert out.returncode == 0, out.stderr
        return os.path.basename(host_lines(out.stdout)[-1].strip())

    left = run("_exit")
    assert _folders(tmp_path, "tapmuscle_") == [left]
    assert (tmp_path / left / "modelDescription.xml").is_file()
    run("exit")  # removes the abandoned folder, and its own at its exit
    assert _folders(tmp_path, "tapmuscle_") == []
