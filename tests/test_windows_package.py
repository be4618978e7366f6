"""tapmuscle's own command line in a Windows Python under Wine (the FMUs' win64 binaries:
tests/test_windows_host.py).

The checkout is put on the path of a copy of the Windows interpreter (its ``._pth``), as a Windows
user's installation would have it, without the compiled sub-step (the Python one gives the same
results). What only Windows does to a command is checked here: an output redirected to a pipe is in
cp1252, which cannot show a folder named "Δp"; a file that another program holds open cannot be
replaced or moved; paths are written with backslashes and drive letters.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "windows_host"))
from test_windows_host import _run_windows, _windows_path, windows  # noqa: E402,F401 - the fixture

pytestmark = [pytest.mark.windows, pytest.mark.slow]

ROOT = HERE.parent

#: Holds the file argv[1] open without delete sharing (as a spreadsheet or an image viewer does) until
#: the file argv[2] appears.
HOLDER = """
import ctypes, os, sys, time
from ctypes import wintypes
k = ctypes.WinDLL("kernel32", use_last_error=True)
k.CreateFileW.restype = wintypes.HANDLE
h = k.CreateFileW(sys.argv[1], 0x80000000, 3, None, 3, 0x80, None)  # read; share read and write
print("held" if h not in (None, wintypes.HANDLE(-1).value) else f"not held {ctypes.get_last_error()}", flush=True)
end = time.time() + 300
while not os.path.exists(sys.argv[2]) and time.time() < end:
    time.sleep(0.1)
"""


@pytest.fixture(scope="module")
def python(windows, tmp_path_factory) -> dict:  # noqa: F811 - the fixture imported above
    """A copy of the Windows interpreter whose ``._pth`` adds this checkout; the environment for it."""
    folder = tmp_path_factory.mktemp("windows-python-with-tapmuscle") / "python"
    shutil.copytree(windows["python"].parent, folder)
    for pth in folder.glob("python3*._pth"):
        # its site folder (..\\site) named where it is, and the checkout after it
        lines = [_windows_path(windows["python"].parent.parent / line[3:]) if line.startswith("..\\") else line
                 for line in pth.read_text(encoding="utf-8").splitlines()]
        pth.write_text("\n".join(lines + [_windows_path(ROOT)]) + "\n", encoding="utf-8")
    # no byte code written into the checkout by the other system's interpreter
    env = {**windows["env"], "PYTHONDONTWRITEBYTECODE": "1"}
    return {**windows, "python": folder / "python.exe", "env": env}


def _tapmuscle(python: dict, *args: str) -> subprocess.CompletedProcess:
    """``python -m tapmuscle ARGS`` in the Windows interpreter, its output to pipes (as an IDE, a CI
    log or ``> file`` take it: cp1252)."""
    return _run_windows(python, str(python["python"]), "-m", "tapmuscle", *args, timeout=300)


def test_an_output_folder_named_beyond_cp1252_is_printed_escaped(python, tmp_path):
    out = tmp_path / "Δp 日本" / "rec.csv"
    done = _tapmuscle(python, "record", "--input", "const:value=5", "--duration", "2", "--out", _windows_path(out),
                      "--quiet")
    assert done.returncode == 0, done.stderr
    assert f"wrote {_windows_path(tmp_path)}\\\\u0394p \\u65e5\\u672c\\rec.csv (" in done.stdout, done.stdout
    assert out.is_file()


def test_a_file_held_open_leaves_the_run_folder_as_the_earlier_run_wrote_it(python, tmp_path):
    out = tmp_path / "run"
    scenario = tmp_path / "short.toml"
    scenario.write_text("duration_s = 3.0\nevaluation_samples = [0, 30]\n[controller]\nmethod = 'mpc_servo'\n")
    first = _tapmuscle(python, "run", _windows_path(scenario), "--out", _windows_path(out), "--quiet")
    assert first.returncode == 0, first.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    scenario.write_text(scenario.read_text().replace("mpc_servo", "ampc_servo"))
    holder, release = tmp_path / "hold.py", tmp_path / "release"
    holder.write_text(HOLDER)
    held = subprocess.Popen([python["wine"], str(python["python"]), _windows_path(holder),
                             _windows_path(out / "summary.json"), _windows_path(release)],
                            env=python["env"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:  # (Wine's Python cannot start with a standard stream that is a file: pipes)
        said = held.stdout.readline().strip()
        if said == "held":
            second = _tapmuscle(python, "run", _windows_path(scenario), "--out", _windows_path(out), "--quiet")
    finally:
        release.touch()  # the holder ends: its output can be read to the end
        _, holder_err = held.communicate(timeout=60)
    assert said == "held", said + holder_err
    assert second.returncode == 2
    assert (f"{_windows_path(out)}\\summary.json could not be replaced (" in second.stderr
            and "close it and run again; " in second.stderr), second.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no mix of the two runs
    assert json.loads(before["summary.json"])["method"] == "mpc_servo"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hold.py", "release", "run", "short.toml"]
    # closed, the run goes through
    time.sleep(0.5)
    third = _tapmuscle(python, "run", _windows_path(scenario), "--out", _windows_path(out), "--quiet")
    assert third.returncode == 0, third.stderr
    assert json.loads((out / "summary.json").read_text())["method"] == "ampc_servo"
    assert os.path.getsize(out / "tracking.png") > 10_000
