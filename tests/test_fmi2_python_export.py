"""The project's FMI export library (build_scripts/fmi2_python_export.c), which runs the slave behind the
shim where pythonfmu ships no binary for the machine (pythonfmu 0.7's linux64 library is x86-64 only).

On this machine pythonfmu's library is the default; ``TAPMUSCLE_FMI_EXPORT=tapmuscle`` builds with the
project's, as an aarch64 build does by itself, so that its FMI contract is checked here: the FMUs'
closed loop bit for bit, a small slave's every call, an exception's status and text, and freeing after it.
.ci/run runs the FMU and C-host tests once more with it.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

from build_scripts import native_host
from build_scripts.native_host import (CONFIG_NAME, EXPORT_VARIABLE, elf_machine, fmi_export, machine_name,
                                       prepare_for_native_hosts, python_machine)

pytestmark = pytest.mark.c_host

PYTHONFMU_LIBRARY = Path(__import__("pythonfmu").__file__).parent / "resources" / "binaries" / "linux64" / \
    "libpythonfmu-export.so"


def _library_for(tmp_path: Path, machine: int) -> Path:
    """A copy of pythonfmu's linux64 library whose ELF header names ``machine``."""
    data = bytearray(PYTHONFMU_LIBRARY.read_bytes())
    data[18:20] = machine.to_bytes(2, "little")
    path = tmp_path / f"lib-{machine}.so"
    path.write_bytes(bytes(data))
    return path


def test_pythonfmus_library_runs_the_slave_where_it_is_built_for_this_machine(monkeypatch):
    monkeypatch.delenv(EXPORT_VARIABLE, raising=False)
    theirs = elf_machine(PYTHONFMU_LIBRARY.read_bytes()[:20])
    assert machine_name(theirs) == "x86-64"  # pythonfmu 0.7 ships linux64 for x86-64 only
    assert fmi_export(PYTHONFMU_LIBRARY) == ("pythonfmu" if theirs == python_machine() else "tapmuscle")
    assert fmi_export() == fmi_export(PYTHONFMU_LIBRARY)  # the installed pythonfmu's, by default


def test_a_library_for_another_machine_gets_the_projects_export(tmp_path, monkeypatch):
    monkeypatch.delenv(EXPORT_VARIABLE, raising=False)
    other = 183 if python_machine() != 183 else 62  # AArch64, or x86-64 on an AArch64 machine
    assert fmi_export(_library_for(tmp_path, other)) == "tapmuscle"
    assert fmi_export(_library_for(tmp_path, python_machine())) == "pythonfmu"


def test_the_environment_variable_chooses_and_a_wrong_value_is_named(monkeypatch):
    for value in ("tapmuscle", "pythonfmu", " tapmuscle "):
        monkeypatch.setenv(EXPORT_VARIABLE, value)
        assert fmi_export(PYTHONFMU_LIBRARY) == value.strip()
    monkeypatch.setenv(EXPORT_VARIABLE, "cpp")
    with pytest.raises(ValueError, match=r"TAPMUSCLE_FMI_EXPORT='cpp': expected one of pythonfmu, tapmuscle"):
        fmi_export(PYTHONFMU_LIBRARY)


@pytest.fixture(scope="module")
def own_fmus(tmp_path_factory):
    """The two FMUs built with the project's export library."""
    from build_scripts.build_fmus import FMUS, build_fmus

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(EXPORT_VARIABLE, "tapmuscle")
        paths = build_fmus(tmp_path_factory.mktemp("own-export"))
    return dict(zip(FMUS, paths))


@pytest.mark.slow
def test_with_the_projects_export_the_fmus_loop_is_the_direct_loop_bit_for_bit(own_fmus):
    import tapmuscle as tm

    for path in own_fmus.values():
        with zipfile.ZipFile(path) as z:
            assert json.loads(z.read(f"resources/{CONFIG_NAME}"))["fmi_export"] == "tapmuscle"
            names = z.namelist()
        assert not any(n.startswith("binaries/linux64/") and "libpythonfmu" in n for n in names)
    scenario = dataclasses.replace(tm.load_scenario(tm.PAPER_SCENARIOS / "ampc_servo_44N_0.1Hz.toml"),
                                   duration_s=45.0)
    direct = tm.simulate_closed_loop("ampc_servo", None, duration_s=45.0, seed=scenario.seed)
    result = tm.cosimulate(scenario, fmus=own_fmus, plots=False)
    assert len(direct["l_mm"]) == 451
    assert np.array_equal(result["columns"]["l_mm"], direct["l_mm"])  # a contract: one process


SLAVE = '''
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String


class Probe(Fmi2Slave):
    """Echoes its input, names the export library it runs in, and fails on demand."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.x = 0.0
        self.y = 0.0
        self.fail_at = -1.0
        self.export = str(kwargs.get("fmi_export"))
        self.steps = 0
        self.register_variable(Real("x", causality=Fmi2Causality.input))
        self.register_variable(Real("fail_at", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("y", causality=Fmi2Causality.output))
        self.register_variable(String("export", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete))
        self.register_variable(Integer("steps", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete))

    def do_step(self, current_time, step_size):
        if 0.0 <= self.fail_at <= current_time:
            raise RuntimeError(f"probe failed at t = {current_time:g} s, 100% on purpose")
        self.y = 2.0 * self.x
        self.steps += 1
        self.log(f"stepped to {current_time + step_size:g} s")
        return self.x >= 0.0
'''

HOST = r'''
import json, sys
import fmpy
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

folder, cycles = sys.argv[1], int(sys.argv[2])
md = read_model_description(folder + "/modelDescription.xml")
vr = {v.name: v.valueReference for v in md.modelVariables}
log = []
cb = fmi2CallbackFunctions()
cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: log.append([status, cat.decode(), msg.decode()]))
cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)


def status_of(call, *args):
    try:
        call(*args)
        return 0
    except FMICallException as exc:
        return exc.status


out = {}


def cycle():
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="probe")
    f.instantiate(callbacks=cb, loggingOn=True)
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setReal([vr["fail_at"]], [0.15])
    f.exitInitializationMode()
    f.setReal([vr["x"]], [1.5])
    f.doStep(0.0, 0.1)
    out["y"] = f.getReal([vr["y"]])[0]
    out["export"] = f.getString([vr["export"]])[0].decode()
    state = f.getFMUstate()
    f.doStep(0.1, 0.1)
    out["steps_before_restore"] = f.getInteger([vr["steps"]])[0]
    f.setFMUstate(f.deSerializeFMUstate(f.serializeFMUstate(state)))
    out["steps_after_restore"] = f.getInteger([vr["steps"]])[0]
    f.freeFMUstate(state)
    f.setReal([vr["x"]], [-1.0])
    out["negative_input"] = status_of(f.doStep, 0.1, 0.1)  # do_step returned False
    log.clear()
    out["failing_step"] = status_of(f.doStep, 0.2, 0.1)
    out["failing_log"] = list(log)
    out["directional_derivative"] = status_of(f.getDirectionalDerivative, [vr["y"]], [vr["x"]], [1.0])
    f.freeInstance()


try:
    for _ in range(cycles):
        cycle()
except Exception as exc:  # what the host saw, then a failed exit
    print(json.dumps({"error": repr(exc), "log": log}))
    sys.exit(3)
print(json.dumps(out))
'''


@pytest.fixture(scope="module")
def probe_tree(tmp_path_factory):
    """A small pythonfmu FMU, extracted and prepared with the project's export library."""
    from pythonfmu.builder import FmuBuilder

    folder = tmp_path_factory.mktemp("probe")
    script = folder / "probe.py"
    script.write_text(textwrap.dedent(SLAVE), encoding="utf-8")
    fmu = FmuBuilder.build_FMU(script, dest=folder)
    tree = folder / "tree"
    with zipfile.ZipFile(fmu) as z:
        z.extractall(tree)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(EXPORT_VARIABLE, "tapmuscle")
        prepare_for_native_hosts(tree)
    return tree


def test_every_call_of_a_small_slave_goes_through_the_projects_export(probe_tree):
    assert json.loads((probe_tree / "resources" / CONFIG_NAME).read_text())["fmi_export"] == "tapmuscle"
    proc = subprocess.run([sys.executable, "-c", HOST, str(probe_tree), "30"], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]  # 30 instantiate / exception / free cycles, no crash
    out = json.loads(proc.stdout.splitlines()[-1])
    assert out["y"] == 3.0 and out["export"] == "tapmuscle"  # the slave was told which library runs it
    assert (out["steps_before_restore"], out["steps_after_restore"]) == (2, 1)  # a serialised state restores
    assert out["negative_input"] == 2  # do_step returned False: fmi2Discard
    assert out["directional_derivative"] == 3  # not supported: fmi2Error
    # an exception: fmi2Fatal with the exception's type and text, taken literally (the shim hands hosts
    # a format without arguments: '%' doubled)
    assert out["failing_step"] == 4
    fatal = [m for m in out["failing_log"] if m[0] == 4]
    assert fatal == [[4, "logStatusFatal", "[probe] fmi2DoStep: Python RuntimeError: probe failed at t = 0.2 s, 100%% on "
                      "purpose"]]


def test_a_module_without_a_slave_class_is_named(probe_tree, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(probe_tree, broken)
    module = (broken / "resources" / "slavemodule.txt").read_text().strip()
    (broken / "resources" / f"{module}.py").write_text("x = 1\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, "-c", HOST, str(broken), "1"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 3, proc.stderr[-2000:]  # fmpy raised at the first step, nothing crashed
    log = json.loads(proc.stdout.splitlines()[-1])["log"]
    assert [4, "logStatusFatal", f"[probe] fmi2Instantiate: Python TypeError: module {module} has no class derived from "
            "pythonfmu's Fmi2Slave"] in log


def test_the_fmu_check_names_a_binary_built_for_another_machine(built_fmus, tmp_path):
    from tapmuscle.cosim.fmu_file import check_fmu_file
    from tapmuscle.cosim.spec import ScenarioError

    other = 183 if python_machine() != 183 else 62
    moved = tmp_path / "MusclePlant.fmu"
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as src, zipfile.ZipFile(moved, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "binaries/linux64/MusclePlant.so":
                data = data[:18] + other.to_bytes(2, "little") + data[20:]
            dst.writestr(info, data)
    with pytest.raises(ScenarioError, match=rf"MusclePlant.so is built for {machine_name(other)}, and this machine is "
                                            rf"{machine_name(python_machine())} .*build the FMUs on this machine"):
        check_fmu_file(moved)


def test_the_c_sources_ship_with_the_build_scripts():
    """The export library, both loaders and the FMI shim. Installed from a wheel, the files themselves
    are the proof; in a source checkout (an editable install), the package data that puts them into
    the wheel is."""
    for source in (native_host._EXPORT_C, native_host._LINUX_LOADER_C, native_host._WIN64_LOADER_C,
                   native_host._SHIM_C):
        assert source.is_file() and source.parent == Path(native_host.__file__).parent, source
    pyproject = Path(native_host.__file__).parents[1] / "pyproject.toml"
    if pyproject.is_file():
        assert '"build_scripts" = ["*.c"]' in pyproject.read_text()
