"""A broken FMU file is named before anything loads it (tapmuscle/cosim/fmu_file.py): no signal death,
no traceback, no temporary folder left behind."""

from __future__ import annotations

import glob
import os
import re
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import pytest
from fmpy import extract

from tapmuscle.cosim.fmu_file import check_fmu_file
from tapmuscle.cosim.spec import ScenarioError


def _rewrite(src: Path, dst: Path, edit) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            data = edit(info.filename, zin.read(info.filename))
            if data is not None:
                zout.writestr(info, data)
    return dst


def _truncated(src: Path, dst: Path) -> Path:
    return _rewrite(src, dst, lambda name, data: data[:len(data) // 2] if name.endswith("MusclePlant.so") else data)


def _bad_crc(src: Path, dst: Path) -> Path:
    data = bytearray(src.read_bytes())
    with zipfile.ZipFile(src) as z:
        info = z.getinfo("modelDescription.xml")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    data[start + 10] ^= 0xFF  # inside the member's compressed bytes
    dst.write_bytes(bytes(data))
    return dst


def _no_binary(src: Path, dst: Path) -> Path:
    return _rewrite(src, dst, lambda name, data: None if name.startswith("binaries/linux64/") else data)


def _newer_glibc(src: Path, dst: Path) -> Path:
    """The loader as a newer Linux's C library headers build it: it asks for a glibc version this
    machine's has not (the version's name rewritten in place, so the loader's hash check fails)."""
    def edit(name: str, data: bytes) -> bytes:
        return data.replace(b"GLIBC_2.34", b"GLIBC_2.99") if name == "binaries/linux64/MusclePlant.so" else data
    return _rewrite(src, dst, edit)


def _invalid_description(src: Path, dst: Path) -> Path:
    """A variable's unit that the description does not define (a hand-made FMU's mistake)."""
    def edit(name: str, data: bytes) -> bytes:
        return data.replace(b'unit="mm"', b'unit="millimetre"', 1) if name == "modelDescription.xml" else data
    return _rewrite(src, dst, edit)


def _not_a_zip(src: Path, dst: Path) -> Path:
    dst.write_bytes(b"PK\x03\x04 not really a zip")
    return dst


CASES = [(_truncated, r"binaries/linux64/MusclePlant.so is truncated: \d+ bytes, its header says at least \d+"),
         (_bad_crc, r"the archive is damaged \(modelDescription.xml: "),
         (_no_binary, r"it has no binaries/linux64/MusclePlant.so for this platform"),
         (_not_a_zip, r"not a zip archive"),
         # fmpy's reasons are on the lines under its first, "Failed to validate modelDescription.xml:"
         (_invalid_description, r"Failed to validate modelDescription.xml: The unit \"millimetre\" of variable \"l\" "
                                r"\(line \d+\) is not defined\.$"),
         (_newer_glibc, r"binaries/linux64/MusclePlant.so: the dynamic loader refused it: .*version .GLIBC_2\.99. "
                        r"not found.* \(built on a newer Linux: it needs glibc 2\.99, this machine has 2\.\d+; "
                        r"build the FMUs on this machine: tapmuscle build\)")]


@pytest.mark.parametrize("make, pattern", CASES, ids=[c[0].__name__.strip("_") for c in CASES])
def test_a_broken_fmu_is_named_without_loading_it(built_fmus, tmp_path, make, pattern):
    bad = make(built_fmus["MusclePlant"], tmp_path / "MusclePlant.fmu")
    with pytest.raises(ScenarioError, match=r"MusclePlant.fmu: is not a loadable FMU: " + pattern):
        check_fmu_file(bad)


@pytest.mark.parametrize("version", ["3.0", "1.0"])
def test_an_fmu_of_another_fmi_version_is_named_so(built_fmus, tmp_path, version):
    """An FMI 3.0 (or 1.0) FMU must not be "not a loadable FMU: it has no binaries/linux64/... for this platform"
    (3.0 keeps its binaries under another folder name), or fmpy's schema errors."""
    def edit(name: str, data: bytes) -> bytes:
        return data.replace(b'fmiVersion="2.0"', f'fmiVersion="{version}"'.encode(), 1) \
            if name == "modelDescription.xml" else data

    bad = _rewrite(built_fmus["MusclePlant"], tmp_path / "MusclePlant.fmu", edit)
    with pytest.raises(ScenarioError, match=re.escape(f"MusclePlant.fmu: is an FMI {version} FMU (its "
                                                      "modelDescription.xml's fmiVersion): tapmuscle's master runs "
                                                      "FMI 2.0 FMUs; export it as FMI 2.0 co-simulation")):
        check_fmu_file(bad)


def test_a_path_the_file_system_encoding_cannot_carry_is_not_called_a_broken_fmu(built_fmus, tmp_path, monkeypatch):
    """lxml names the model description by the working folder's path: under an ASCII locale with
    PYTHONUTF8=0 a folder "rig ü" must not fail as "is not a loadable FMU: 'utf-8' codec can't encode ..."."""
    import fmpy

    def unreadable(*args, **kwargs):
        raise UnicodeEncodeError("utf-8", "/tmp/rig \udcc3\udcbc", 9, 11, "surrogates not allowed")

    monkeypatch.setattr(fmpy, "read_model_description", unreadable)
    copy = tmp_path / "MusclePlant.fmu"
    copy.write_bytes(built_fmus["MusclePlant"].read_bytes())
    with zipfile.ZipFile(copy, "a") as z:
        z.writestr("documentation/note.txt", "another digest: not one this process has checked")
    with pytest.raises(ScenarioError, match=r"MusclePlant.fmu: its modelDescription.xml cannot be read here: .* "
                                            r"file-system encoding, .*: run in a UTF-8 locale") as err:
        check_fmu_file(copy)
    assert "not a loadable FMU" not in str(err.value)


def test_the_good_fmus_pass(built_fmus):
    for path in built_fmus.values():
        check_fmu_file(path)


def test_the_loader_asks_for_no_glibc_newer_than_2_34(built_fmus):
    """The FMUs built here load on any Linux with glibc 2.34 or newer (Debian 12, Ubuntu 22.04): the
    project's loader library asks for no newer symbol version, whatever C library built it (a
    strtol there would become __isoc23_strtol@GLIBC_2.38 on Debian 13)."""
    import re
    import shutil

    readelf = shutil.which("readelf")
    if readelf is None:
        pytest.skip("readelf (binutils) not found")
    for path in built_fmus.values():
        with zipfile.ZipFile(path) as z, tempfile.TemporaryDirectory() as tmp:
            name = f"binaries/linux64/{path.stem}.so"
            z.extract(name, tmp)
            out = subprocess.run([readelf, "-V", str(Path(tmp) / name)], capture_output=True, text=True,
                                 check=True).stdout
        versions = {tuple(map(int, v.split("."))) for v in re.findall(r"GLIBC_(\d+\.\d+)", out)}
        assert versions and max(versions) <= (2, 34), (path.name, sorted(versions))


@pytest.mark.slow
@pytest.mark.parametrize("command", ["run", "diagnose", "sweep"])
def test_commands_survive_a_truncated_binary_and_leave_nothing(built_fmus, tmp_path, command):
    """The truncated binary must not kill `run`, `diagnose --plant` and `sweep` with SIGBUS and leave tapmuscle_*
    folders in the temporary directory: exit 2, one line, nothing left."""
    fmu_dir = tmp_path / "fmus"
    fmu_dir.mkdir()
    _truncated(built_fmus["MusclePlant"], fmu_dir / "MusclePlant.fmu")
    (fmu_dir / "AMPCController.fmu").write_bytes(built_fmus["AMPCController"].read_bytes())
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    if command == "run":
        scenario = tmp_path / "s.toml"
        scenario.write_text("duration_s = 2.0\nevaluation_samples = [0, 10]\n")
        argv = ["run", str(scenario), "--out", str(tmp_path / "out"), "--fmu-dir", str(fmu_dir), "--quiet"]
    elif command == "sweep":
        sweep = tmp_path / "s.toml"
        sweep.write_text("base = { duration_s = 5.0, evaluation_samples = [0, 40] }\n[grid]\nseed = [0, 1]\n")
        argv = ["sweep", str(sweep), "--out", str(tmp_path / "out"), "--workers", "0", "--fmu-dir", str(fmu_dir),
                "--quiet"]
    else:
        rec = tmp_path / "rec.csv"
        rec.write_text("t_s,u_v,l_mm\n" + "".join(f"{k / 10:g},{5 + (k // 20) % 2},{k % 7}\n" for k in range(1801)))
        argv = ["diagnose", "--recording", str(rec), "--plant", str(fmu_dir / "MusclePlant.fmu"),
                "--out", str(tmp_path / "out"), "--no-calibration", "--no-plots", "--quiet"]
    proc = subprocess.run([sys.executable, "-m", "tapmuscle.cli", *argv], capture_output=True, text=True,
                          env={"TMPDIR": str(scratch), "PATH": "/usr/bin:/bin", **{
                              k: os.environ[k] for k in ("PYTHONPATH", "PYTHONDONTWRITEBYTECODE") if k in os.environ}},
                          timeout=600)
    assert proc.returncode == 2, proc.stderr
    assert "is not a loadable FMU" in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
    assert glob.glob(str(scratch / "tapmuscle_*")) == []
    assert Path(tempfile.gettempdir()).is_dir()


FOREIGN_HOST = r'''
import sys
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
f = FMU2Slave(guid=md.guid, unzipDirectory=sys.argv[2], modelIdentifier=md.coSimulation.modelIdentifier,
              instanceName="x")
f.instantiate(loggingOn=False)  # an Error is logged all the same
try:
    f.setupExperiment(startTime=0.0); f.enterInitializationMode(); f.exitInitializationMode(); f.doStep(0.0, 0.1)
except FMICallException as exc:
    print("refused:", exc)
f.freeInstance()
print("ended")
'''


def test_a_host_that_loads_an_fmu_with_a_truncated_inner_library_is_told_and_survives(built_fmus, tmp_path):
    """A third-party host checks nothing before it loads the FMU's binary: the loader finds its
    pythonfmu library shorter than its ELF header says and fails the instantiation with that reason
    (the dynamic loader mapping it would kill the host with SIGBUS)."""
    folder = Path(extract(str(built_fmus["MusclePlant"]), unzipdir=str(tmp_path / "x")))
    inner = folder / "binaries" / "linux64" / "MusclePlant_pythonfmu.so"
    inner.write_bytes(inner.read_bytes()[:20000])
    script = tmp_path / "host.py"
    script.write_text(FOREIGN_HOST)
    proc = subprocess.run([sys.executable, str(script), str(built_fmus["MusclePlant"]), str(folder)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-2000:])
    out = proc.stdout + proc.stderr
    assert "refused:" in out and "ended" in out, out[-2000:]
    assert "MusclePlant_pythonfmu.so is truncated: 20000 bytes, its ELF header says at least" in out, out[-2000:]


def test_an_fmu_that_would_unpack_outside_its_folder_or_beyond_any_fmus_size_is_named(built_fmus, tmp_path,
                                                                                    monkeypatch):
    """An entry with an absolute path (fmpy refuses it with a bare Exception, which would go out as a
    traceback), and a zip that would unpack to more than any FMU needs (a small "zip bomb"): named,
    and nothing unpacked."""
    import tapmuscle.cosim.master as master

    absolute = tmp_path / "abs" / "MusclePlant.fmu"
    absolute.parent.mkdir()
    _rewrite(built_fmus["MusclePlant"], absolute, lambda name, data: data)
    with zipfile.ZipFile(absolute, "a") as z:
        z.writestr(str(tmp_path / "outside.txt"), "planted")
    with pytest.raises(ScenarioError, match=r"MusclePlant.fmu: not an FMU that can be unpacked: Illegal path .*"
                                            r"outside.txt"):
        master.unpack(absolute)
    assert not (tmp_path / "outside.txt").exists()
    size = sum(m.file_size for m in zipfile.ZipFile(built_fmus["MusclePlant"]).infolist())
    monkeypatch.setattr(master, "MAX_UNPACKED_BYTES", size - 1)
    big = _rewrite(built_fmus["MusclePlant"], tmp_path / "MusclePlant.fmu", lambda name, data: data)
    with pytest.raises(ScenarioError, match=r"MusclePlant.fmu: would unpack to 0.0 GiB in \d+ files, more than .* any "
                                            r"FMU needs: not unpacked"):
        master.unpack(big)
