"""A Python host's exit after an FMU on pythonfmu's own binary (tapmuscle/cosim/pythonfmu_exit.py).

pythonfmu 0.7.0's Linux binary reads freed memory as the process exits; valgrind names the read. The
foreign thermal FMU is such an FMU (plain pythonfmu). CI installs valgrind; elsewhere the valgrind
tests skip unless ``TAPMUSCLE_REQUIRE_VALGRIND=1``.
"""

from __future__ import annotations

import ctypes
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import fmpy
import pytest
from fmpy.fmi2 import FMU2Slave

from tapmuscle.cosim import pythonfmu_exit
from tapmuscle.cosim.pythonfmu_exit import RELEASE_SYMBOL, release_at_exit
from tapmuscle.diagnosis.foreign_fmus.dc_motor import build_dc_motor_fmu
from tapmuscle.diagnosis.foreign_fmus.thermal import FMU_NAME, build_thermal_fmu

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="pythonfmu's exit defect is in its Linux binary")


@pytest.fixture(scope="module")
def thermal(tmp_path_factory) -> Path:
    return build_thermal_fmu(tmp_path_factory.mktemp("thermal"))


def _loaded(path: Path) -> bool:
    """Whether the library ``path`` is mapped into this process."""
    return str(path) in Path("/proc/self/maps").read_text()


def test_registers_pythonfmus_release_once_per_library(thermal, tmp_path, monkeypatch):
    folder = fmpy.extract(str(thermal), unzipdir=str(tmp_path / "x"))
    registered = []
    monkeypatch.setattr(pythonfmu_exit.atexit, "register", registered.append)
    monkeypatch.setattr(pythonfmu_exit, "_registered", {})
    assert not release_at_exit(folder, "ThermalTwoMass")  # not loaded: nothing is loaded here
    binary = Path(folder, "binaries", fmpy.platform, "ThermalTwoMass" + fmpy.sharedLibraryExtension).resolve()
    assert not _loaded(binary)
    md = fmpy.read_model_description(str(thermal))
    FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier="ThermalTwoMass", instanceName="x")  # loads it
    assert release_at_exit(folder, "ThermalTwoMass")
    assert release_at_exit(Path(folder, "binaries", "..", "."), "ThermalTwoMass")  # the same binary, another path
    assert [f.__name__ for f in registered] == [RELEASE_SYMBOL]


def test_other_libraries_are_left_alone(tmp_path, monkeypatch):
    """A C FMU's library without pythonfmu's symbol: nothing registered, and the probe leaves it as it was,
    so the host can unload it (its globals start afresh in the next instance); a missing or broken binary."""
    registered = []
    monkeypatch.setattr(pythonfmu_exit.atexit, "register", registered.append)
    monkeypatch.setattr(pythonfmu_exit, "_registered", {})
    folder = fmpy.extract(str(build_dc_motor_fmu(tmp_path / "dc")), unzipdir=str(tmp_path / "dc" / "x"))
    binary = Path(folder, "binaries", fmpy.platform, "DcMotor" + fmpy.sharedLibraryExtension).resolve()
    host = ctypes.CDLL(str(binary))
    assert _loaded(binary)
    assert not release_at_exit(folder, "DcMotor")
    assert not release_at_exit(folder, "DcMotor")  # the answer kept
    pythonfmu_exit._dlclose(host._handle)
    assert not _loaded(binary)  # the probe's reference is gone with it
    assert not release_at_exit(folder, "NoSuchModel")  # no binary
    (tmp_path / "text" / "binaries" / fmpy.platform).mkdir(parents=True)
    (tmp_path / "text" / "binaries" / fmpy.platform / f"Text{fmpy.sharedLibraryExtension}").write_text("not a library")
    assert not release_at_exit(tmp_path / "text", "Text")
    assert registered == []


HOST = r'''
import sys, fmpy
from fmpy.fmi2 import FMU2Slave
path, mode = sys.argv[1], sys.argv[2]
md = fmpy.read_model_description(path)
folder = fmpy.extract(path)
if mode == "master":
    from tapmuscle.cosim.master import FmuInstance
    for i in range(2):
        inst = FmuInstance(path, "x", role="foreign plant")
        inst.start()
        inst.fmu.doStep(0.0, 1.0)
        inst.free()
else:
    for i in range(2):
        f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="x")
        f.instantiate()
        f.setupExperiment(startTime=0.0); f.enterInitializationMode(); f.exitInitializationMode()
        f.doStep(0.0, 1.0)
        f.terminate(); f.freeInstance()
print("ran")
'''


def _valgrind() -> str:
    tool = shutil.which("valgrind")
    if tool is None:
        if os.environ.get("TAPMUSCLE_REQUIRE_VALGRIND") == "1":
            pytest.fail("TAPMUSCLE_REQUIRE_VALGRIND=1 but valgrind is not on PATH")
        pytest.skip("valgrind is not installed (CI installs it)")
    return tool


def _invalid_accesses(thermal: Path, mode: str, tmp_path: Path) -> list[str]:
    """valgrind's reports of invalid reads, writes and frees in ``HOST`` ``mode`` (``bare``: fmpy
    alone; ``master``: the co-simulation master's instances) whose stack passes
    through the FMU's binary (the dynamic loader's own false reports, in every Python, are not)."""
    script = tmp_path / "host.py"
    script.write_text(HOST)
    env = dict(os.environ, PYTHONMALLOC="malloc")  # valgrind sees Python's objects, not its arenas
    # Addressability alone is asked: without tracking which bytes are defined memcheck runs faster
    done = subprocess.run([_valgrind(), "--num-callers=30", "--undef-value-errors=no",
                           f"--log-file={tmp_path / 'vg.%p'}", sys.executable,
                           str(script), str(thermal), mode], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0 and done.stdout.strip() == "ran", done.stderr[-2000:]
    logs = "".join(p.read_text() for p in tmp_path.glob("vg.*"))
    assert "ERROR SUMMARY" in logs  # valgrind ran the host to its end
    reports = re.split(r"==\d+== \n", logs)
    return [r for r in reports if re.search(r"Invalid (read|write|free)|Mismatched free", r)
            and (FMU_NAME.removesuffix(".fmu") in r or RELEASE_SYMBOL in r)]


@pytest.mark.slow
def test_pythonfmus_binary_reads_freed_memory_at_exit_without_the_release(thermal, tmp_path):
    """The defect the release works around, as valgrind sees it in a plain fmpy host: if this fails,
    pythonfmu no longer has it and the work-around can go."""
    reports = _invalid_accesses(thermal, "bare", tmp_path)
    assert reports and all(RELEASE_SYMBOL in r for r in reports), reports
    assert any("free'd" in r for r in reports)


@pytest.mark.slow
def test_the_master_exits_cleanly_after_a_pythonfmu_fmu(thermal, tmp_path):
    """The co-simulation master's FmuInstance (``tapmuscle run``, ``diagnose --plant``) calls
    :func:`release_at_exit` for every FMU it loads: the FMU's binary touches no freed memory."""
    assert _invalid_accesses(thermal, "master", tmp_path) == []
