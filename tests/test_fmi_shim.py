"""The FMI shim of the FMUs' loader library (build_scripts/native_host.py): what a foreign host sees.

* A failed instantiation (here: the slave's Python code imports a package the interpreter lacks, as
  when numpy is missing from a tool's Python) gives an instance, not NULL: hosts that do not check
  NULL (libcosim) would dereference it. The instance logs the reason on every call, answers the calls
  before the first step with fmi2Warning and fmi2DoStep with fmi2Error; freeing it is safe.
* Messages reach the host with a category (pythonfmu passes NULL on its exception path), and
  Discard/Error messages reach it even with ``loggingOn = false``.

The failure cases run in a fresh interpreter each: Python caches a slave module by name, so a broken
copy must not meet a working one in one process.
"""

import json
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from fmpy_helpers import host_lines

pytestmark = pytest.mark.c_host

#: A host script's start: the FMU of argv[1] extracted, and callbacks whose logger keeps every message in
#: ``log`` as ``[status, category, text]``.
HOST_START = r'''
import json, sys
import fmpy
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

path = sys.argv[1]
md = read_model_description(path)
folder = extract(path)
log = []
cb = fmi2CallbackFunctions()
cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: log.append(
    [status, None if cat is None else cat.decode(), msg.decode()]))
cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
'''

HOST = HOST_START + r'''
reps, logging_on = int(sys.argv[2]), sys.argv[3] == "1"
out = []
for _ in range(reps):
    log.clear()
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="c")
    f.instantiate(callbacks=cb, loggingOn=logging_on)
    calls = {"setupExperiment": f.setupExperiment(startTime=0.0), "enterInitializationMode": f.enterInitializationMode(),
             "exitInitializationMode": f.exitInitializationMode()}
    if len(sys.argv) > 4:  # an input to set before the step: [name, value]
        name, value = json.loads(sys.argv[4])
        f.setReal([next(v.valueReference for v in md.modelVariables if v.name == name)], [value])
    try:
        status = f.doStep(0.0, 0.1)
        calls["doStep"] = 0 if status is None else status
    except FMICallException as exc:
        calls["doStep"] = exc.status
    f.freeInstance()
    out.append({"calls": calls, "log": list(log)})
print(json.dumps(out))
'''


def _run_host(fmu: Path, reps: int, logging_on: bool, set_input=None) -> list[dict]:
    args = [sys.executable, "-c", HOST, str(fmu), str(reps), "1" if logging_on else "0"]
    if set_input:
        args.append(json.dumps(set_input))
    proc = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def broken_controller(built_fmus, tmp_path_factory) -> Path:
    """The controller FMU whose slave module imports a package that does not exist."""
    src = Path(built_fmus["AMPCController"])
    out = tmp_path_factory.mktemp("broken") / "AMPCController.fmu"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
        entry = f"resources/{zin.read('resources/slavemodule.txt').decode().strip()}.py"
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == entry:
                data += b"\nimport tapmuscle_missing_package_xyz\n"
            zout.writestr(item, data)
    return out


@pytest.mark.slow
def test_a_failed_instantiation_is_an_instance_that_refuses_to_step(broken_controller):
    """20 times in one process with logging off: the reason names the missing module, every message has
    a category, the calls before the step are warnings, the step an error, the process exits cleanly."""
    runs = _run_host(broken_controller, 20, logging_on=False)
    assert len(runs) == 20
    for run in runs:
        assert run["calls"] == {"setupExperiment": 1, "enterInitializationMode": 1, "exitInitializationMode": 1,
                                "doStep": 3}
        assert all(cat for _, cat, _ in run["log"]), run["log"]
        assert any("tapmuscle_missing_package_xyz" in msg and status >= 3 for status, _, msg in run["log"])
        step_msgs = [msg for status, _, msg in run["log"] if status == 3 and msg.startswith("[c] fmi2DoStep refused")]
        assert step_msgs and "tapmuscle_missing_package_xyz" in step_msgs[0]


@pytest.mark.slow
def test_libcosim_stops_cleanly_on_a_failed_instantiation(broken_controller, built_fmus):
    """libcosim dereferences a NULL instance; with the shim its step returns False and the process
    exits normally, 20 executions in a row."""
    pytest.importorskip("libcosimpy")
    code = r'''
import sys
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimSlave import CosimLocalSlave
for _ in range(20):
    ex = CosimExecution.from_step_size(step_size=100_000_000)
    ex.add_local_slave(CosimLocalSlave(fmu_path=sys.argv[1], instance_name="plant"))
    ex.add_local_slave(CosimLocalSlave(fmu_path=sys.argv[2], instance_name="ctrl"))
    assert ex.step(1) is False
print("clean")
'''
    proc = subprocess.run([sys.executable, "-c", code, str(built_fmus["MusclePlant"]), str(broken_controller)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "clean" in proc.stdout.splitlines(), proc.stderr[-2000:]
    assert "tapmuscle_missing_package_xyz" in proc.stdout + proc.stderr


@pytest.mark.slow
def test_ecos_stops_cleanly_on_a_failed_instantiation(broken_controller, built_fmus):
    """Ecos (in-process) with the broken controller, 20 executions in a row: no segfault, no abort, the
    reason reaches Ecos's log (at its debug level), and the process exits normally."""
    code = r'''
import ctypes, sys
from importlib import metadata
lib = next(f for f in metadata.files("tbb") if f.name == "libtbb.so.12")
ctypes.CDLL(str(lib.locate()), mode=ctypes.RTLD_GLOBAL)
from ecospy import EcosSimulation, EcosSimulationStructure
from ecospy.lib import EcosLib
EcosLib.set_log_level("debug")
outcomes = []
for _ in range(20):
    ss = EcosSimulationStructure()
    ss.add_model("plant", sys.argv[1])
    ss.add_model("ctrl", sys.argv[2])
    ss.make_real_connection("plant::l", "ctrl::l")
    ss.make_real_connection("ctrl::u", "plant::u")
    try:
        sim = EcosSimulation(structure=ss, step_size=0.1)
        sim.init()
        sim.step()
        outcomes.append(f"stepped, u = {sim.get_real('ctrl::u')}")
    except Exception as exc:
        outcomes.append(type(exc).__name__)
print("outcomes", sorted(set(outcomes)))
print("clean")
'''
    proc = subprocess.run([sys.executable, "-c", code, str(built_fmus["MusclePlant"]), str(broken_controller)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "clean" in proc.stdout.splitlines(), (proc.returncode, proc.stderr[-2000:])
    assert "tapmuscle_missing_package_xyz" in proc.stdout + proc.stderr
    # Ecos ignores the refused step (it reports OK; notes/third-party-masters.md): the valve then gets
    # the broken instance's safe output, 0 V, never NaN
    assert "outcomes ['stepped, u = 0.0']" in proc.stdout.splitlines(), proc.stdout[-500:]


@pytest.mark.slow
def test_discard_messages_reach_a_host_that_turned_logging_off(built_fmus):
    """A bad input (l = NaN) with loggingOn = false: fmi2Discard, and its message with status Discard
    and category logStatusDiscard (as the Reference FMUs do)."""
    runs = _run_host(Path(built_fmus["AMPCController"]), 1, logging_on=False, set_input=["l", float("nan")])
    run = runs[0]
    assert run["calls"]["exitInitializationMode"] == 0 and run["calls"]["doStep"] == 2
    assert [s for s, _, _ in run["log"]] == [2]
    status, cat, msg = run["log"][0]
    assert cat == "logStatusDiscard" and "l = nan is not finite" in msg


@pytest.mark.slow
def test_quiet_when_all_is_well_and_logging_is_off(built_fmus):
    run = _run_host(Path(built_fmus["AMPCController"]), 1, logging_on=False, set_input=["l", 10.0])[0]
    assert run["calls"] == {"setupExperiment": 0, "enterInitializationMode": 0, "exitInitializationMode": 0,
                            "doStep": 0}
    assert run["log"] == []


def test_a_wrong_guid_is_refused_with_both_guids(built_fmus, tmp_path, capfd):
    """FMI 2.0: the host passes the GUID it read; an FMU that does not match must not run. The
    instance logs both GUIDs and refuses to step, like any failed instantiation; the right GUID works
    from a folder whose path needs percent-encoding in the resource URI."""
    from fmpy import extract, read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    path = built_fmus["MusclePlant"]
    md = read_model_description(str(path))
    folder = extract(str(path), unzipdir=str(tmp_path / "dir with space"))
    wrong = "{00000000-0000-0000-0000-000000000000}"
    f = FMU2Slave(guid=wrong, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="g")
    f.instantiate(loggingOn=False)
    assert f.setupExperiment(startTime=0.0) == 1  # fmi2Warning: the calls before the first step
    with pytest.raises(FMICallException, match="error"):
        f.doStep(0.0, 0.1)
    f.freeInstance()
    out = capfd.readouterr().out
    assert f"the host passed GUID {wrong}, this FMU's is {md.guid}" in out, out
    good = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                     instanceName="ok")
    good.instantiate()
    good.setupExperiment(startTime=0.0)
    good.enterInitializationMode()
    assert good.exitInitializationMode() == 0
    good.doStep(0.0, 0.1)
    good.terminate()
    good.freeInstance()


def test_repeated_instantiation_keeps_one_resources_entry_in_sys_path(built_fmus):
    """pythonfmu puts the FMU's resources folder in front of sys.path at every instantiation; the slave
    keeps one copy, so a host that instantiates the FMU a thousand times does not carry a thousand."""
    code = r"""
import sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
folder = extract(sys.argv[1])
before = len(sys.path)
for _ in range(20):
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="p")
    f.instantiate()
    f.freeInstance()
print(len(sys.path) - before, sum("resources" in p for p in sys.path))
"""
    proc = subprocess.run([sys.executable, "-c", code, str(built_fmus["MusclePlant"])], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert " ".join(host_lines(proc.stdout)).split() == ["1", "1"], proc.stdout


RESOURCE_LOCATIONS = r"""
import sys
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
folder, location = sys.argv[1], sys.argv[2].encode()
md = read_model_description(folder)
log = []
f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="r",
              fmiCallLogger=None)
f.instantiate(loggingOn=False, callbacks=None)  # fmpy's own URI first: a working instance to free
f.freeInstance()
f.component = f.fmi2Instantiate(b"r", 1, md.guid.encode(), None if location == b"NULL" else location, f.callbacks,
                                0, 0)
print("instance", bool(f.component))
try:
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    f.doStep(0.0, 0.1)
    print("stepped")
except FMICallException as exc:
    print("refused", exc.status)
f.freeInstance()
"""


@pytest.mark.parametrize("location, reason", [
    ("http://example.org/resources", "is not a file URI of a local folder"),
    ("file://otherhost/tmp/resources", "is not a file URI of a local folder"),
    ("relative/resources", "is not a file URI of a local folder"),
    ("NULL", "fmuResourceLocation (NULL) is not a file URI"),
    ("file:///nonexistent/resources", "no readable slavemodule.txt in it"),
])
def test_a_resource_location_pythonfmu_cannot_use_fails_cleanly(built_fmus, tmp_path, location, reason):
    """pythonfmu only strips "file://" and decodes %20; a location it cannot use makes its failure path call
    a NULL class (a segfault in fmi2Instantiate). The shim refuses such a location with the reason, and
    the instance refuses to step."""
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        z.extractall(tmp_path / "fmu")
    proc = subprocess.run([sys.executable, "-c", RESOURCE_LOCATIONS, str(tmp_path / "fmu"), location],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()  # fmpy prints the FMU's messages among them
    assert "instance True" in lines and "refused 3" in lines, proc.stdout
    assert reason in proc.stdout + proc.stderr


@pytest.mark.parametrize("folder, works", [pytest.param("Müller dir", True, marks=pytest.mark.utf8_paths), ("a%41b", True),
                                           ("x%20y", False)])
def test_percent_encoded_folder_names_reach_pythonfmu_decoded(built_fmus, tmp_path, folder, works):
    """fmpy percent-encodes the resource URI (Müller -> M%C3%BCller, % -> %25); the shim decodes it. A
    literal "%20" in a folder's name, which pythonfmu would read as a space, is refused with that reason."""
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        z.extractall(tmp_path / folder)
    location = (tmp_path / folder / "resources").as_uri()
    proc = subprocess.run([sys.executable, "-c", RESOURCE_LOCATIONS, str(tmp_path / folder), location],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    if works:
        assert {"instance True", "stepped"} <= set(proc.stdout.splitlines()), proc.stdout + proc.stderr
    else:
        # '%%': without fmpy's logging helper (aarch64) the host prints the shim's format unformatted
        assert "refused 3" in proc.stdout and re.search(r'holds "%%?20" in a name', proc.stdout + proc.stderr)


#: A host script's start: the FMU of argv[1] extracted, callbacks whose messages go to ``log``.
PRELUDE = r'''
import gc, sys
from ctypes import byref
from pathlib import Path
import fmpy
from fmpy import extract, read_model_description
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2FMUstate)
path = sys.argv[1]
md = read_model_description(path)
folder = extract(path)
log = []
cb = fmi2CallbackFunctions()
cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: log.append(msg.decode()))
cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
'''

STATES = PRELUDE + r'''
def make(name):
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    f.instantiate(callbacks=cb, loggingOn=False)
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    f.doStep(0.0, 0.1)
    return f
a, b = make("a"), make("b")
kept = a.getFMUstate()
state = a.getFMUstate()
freed = fmi2FMUstate(state.value)  # a host's copy of the pointer: freeing clears only the one passed
a.freeFMUstate(state)
statuses = []
for call in (lambda: a.setFMUstate(fmi2FMUstate()), lambda: a.setFMUstate(freed),
             lambda: b.setFMUstate(kept), lambda: a.serializeFMUstate(fmi2FMUstate()),
             lambda: a.serializeFMUstate(freed)):
    try:
        call()
        statuses.append("ok")
    except Exception as exc:
        statuses.append(type(exc).__name__)
junk = [[i] for i in range(200000)]
gc.collect()
a.setFMUstate(kept)  # the state the instance holds still restores
a.doStep(0.1, 0.1)
a.freeFMUstate(kept)
for f in (a, b):
    f.terminate()
    f.freeInstance()
gc.collect()
print(statuses)
print(sum("the FMU state is NULL" in m for m in log), sum("not one this instance gave out" in m for m in log))
'''


@pytest.mark.parametrize("name", ["MusclePlant", "AMPCController"])
def test_a_null_freed_or_other_instances_state_is_refused_and_the_host_lives_on(built_fmus, tmp_path, name):
    """pythonfmu builds a Python object from whatever state pointer it gets: a NULL, freed or other
    instance's state would crash the host a few calls later (segfault in the garbage collector). The shim
    refuses each with fmi2Error and a message; the states the instance holds keep working."""
    script = tmp_path / "states.py"
    script.write_text(STATES)
    run = subprocess.run([sys.executable, str(script), str(built_fmus[name])], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    statuses, counts = run.stdout.strip().splitlines()[-2:]
    assert statuses == str(["FMICallException"] * 5)
    assert counts == "2 3"


NAMELESS = PRELUDE + r'''
f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier)
uri = (Path(folder) / "resources").as_uri().encode()
for name, kind in ((None, 1), (b"", 1), (b"me", 0)):
    c = f.fmi2Instantiate(name, kind, md.guid.encode(), uri, byref(cb), 0, 0)
    try:
        status = f.fmi2DoStep(c, 0.0, 0.1, 1)
    except Exception as exc:
        status = exc.status
    print(bool(c), status)
    f.fmi2FreeInstance(c)
print(log[0]); print(log[-2])
'''


def test_an_instance_without_a_name_or_for_model_exchange_is_refused(built_fmus, tmp_path):
    """A NULL instanceName must not abort the host (C++ std::string from NULL), nor a model-exchange request get a
    working co-simulation instance. Both get the shim's refusing instance, with the reason."""
    script = tmp_path / "nameless.py"
    script.write_text(NAMELESS)
    run = subprocess.run([sys.executable, str(script), str(built_fmus["MusclePlant"])], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.strip().splitlines()
    assert lines[:3] == ["True 3"] * 3  # an instance, refusing to step with fmi2Error
    assert "instanceName is NULL or empty" in lines[3]
    assert "fmuType 0: this FMU is for co-simulation only" in lines[4]


DEBUG_HOST = HOST_START + r'''
configs = json.loads(sys.argv[2])
vr = {v.name: v.valueReference for v in md.modelVariables}
out = []
for logging_on, categories in configs:
    log.clear()
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="d")
    f.instantiate(callbacks=cb, loggingOn=logging_on)
    status = None
    if categories is not None:  # fmpy's wrapper returns nothing: the status is the C function's
        from ctypes import c_char_p
        names = (c_char_p * max(len(categories), 1))(*[c.encode() for c in categories])
        status = f.fmi2SetDebugLogging(f.component, logging_on, len(categories), names)
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    for k in range(3):
        f.setReal([vr["u"]], [12.0 if k == 1 else 5.0])  # 12 V: a Discard at the second step
        try:
            f.doStep(k * 0.1 if k < 2 else 0.1, 0.1)
        except FMICallException:
            pass
    f.terminate()
    f.freeInstance()
    out.append({"status": status, "log": list(log)})
print(json.dumps(out))
'''


def test_logging_on_passes_the_events_and_fmi2SetDebugLogging_picks_the_categories(built_fmus):
    """With logging on the plant's events (category logEvents, status OK: its set-up and a summary at
    fmi2Terminate) reach the host; fmi2SetDebugLogging's categories pick the OK messages passed on (FMI
    2.0: none listed, or logAll, is every one), while a Discard's message always arrives with its
    reason; a category the FMU does not declare is a warning naming it."""
    configs = [[False, None], [True, None], [True, []], [True, ["logEvents"]], [True, ["logStatusDiscard"]],
               [True, ["logAll", "logStatusError"]], [True, ["logFoo"]], [True, ["logFoo", "logEvents"]],
               [False, ["logEvents"]]]
    proc = subprocess.run([sys.executable, "-c", DEBUG_HOST, str(built_fmus["MusclePlant"]), json.dumps(configs)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    md = {}
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        md = z.read("modelDescription.xml").decode()
    assert '<Category name="logEvents"' in md  # declared, as FMI 2.0 asks of a category the FMU logs

    def kinds(run):
        return [(status, cat) for status, cat, msg in run["log"] if "logFoo" not in msg]

    discard = (2, "logStatusDiscard")
    events = [(0, "logEvents"), discard, (0, "logEvents")]
    expected = [[discard], events, events, events, [discard], events, [discard], events, [discard]]
    assert [kinds(run) for run in runs] == expected
    assert [run["status"] for run in runs] == [None, None, 0, 0, 0, 0, 1, 1, 0]
    for run in (runs[6], runs[7]):
        assert run["log"][0][:2] == [1, "logStatusWarning"] and "category logFoo is not one of this FMU's" in \
            run["log"][0][2]
    # each text led by the instance's name: fmpy's default logger, libcosim and Ecos print the text alone
    assert all(msg.startswith("[d] ") for run in runs for _, _, msg in run["log"])
    setup, summary = (runs[1]["log"][i][2].removeprefix("[d] ") for i in (0, 2))
    assert setup.startswith("initialised at t = 0 s: load 44 N, supply pressure 0.25 MPa")
    assert "u = 12.0 is outside" in runs[1]["log"][1][2]  # the Discard names its input
    # the refused step is not counted: two steps of 0.1 s
    assert summary.startswith("fmi2Terminate at t = 0.2 s: 0.2 s from t = 0 s: 2 steps; readings l ")


def test_the_loaders_known_categories_are_the_ones_the_fmus_declare(built_fmus):
    """The shim checks fmi2SetDebugLogging's categories against its own list: the model descriptions'."""
    import re

    source = (Path(__file__).parents[1] / "build_scripts" / "fmi_shim.c").read_text(encoding="utf-8")
    known = re.findall(r'"(\w+)"', re.search(r"KNOWN_CATEGORIES\[\] = \{(.*?)\};", source, re.S).group(1))
    for path in built_fmus.values():
        with zipfile.ZipFile(path) as z:
            declared = re.findall(r'<Category name="(\w+)"', z.read("modelDescription.xml").decode())
        assert sorted(known) == sorted(declared)


TWO_PLANTS = r'''
import sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

path = sys.argv[1]
md = read_model_description(path)
folder = extract(path)
vr = {v.name: v.valueReference for v in md.modelVariables}
plants = {}
names = sys.argv[2:] or ["left", "right"]
for name, load in zip(names, (600.0, 44.0)):
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    f.instantiate()  # fmpy's default logger: it prints the status and the text, not the instance's name
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setReal([vr["load_force"]], [load])
    f.exitInitializationMode()
    plants[name] = f
for f in plants.values():
    f.setReal([vr["u"]], [5.0])
    try:
        f.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.1)
    except Exception:  # left's fmi2Discard
        pass
for f in plants.values():
    f.terminate()
    f.freeInstance()
print("done", flush=True)
'''


def test_each_message_names_the_instance_that_spoke_where_the_host_prints_the_text_alone(built_fmus):
    """Two plant instances of one FMU in fmpy with its default logger, which prints a message's status and
    text and drops the instance name the FMI logger gets apart: the text leads with ``[name]``, so the
    message of the instance whose load is out of range is told from the other's (a rig of several
    muscles in libcosim or Ecos prints alike)."""
    proc = subprocess.run([sys.executable, "-c", TWO_PLANTS, str(built_fmus["MusclePlant"])], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0 and host_lines(proc.stdout)[-1] == "done", proc.stderr[-2000:]
    said = [line for line in host_lines(proc.stdout) if "load_force = 600" in line]
    assert said and all(line.startswith(("[WARNING] [left] ", "[DISCARD] [left] ")) for line in said), said
    assert not [line for line in host_lines(proc.stdout) if "[right]" in line]  # the other had nothing to say


def test_instances_named_by_their_fmus_path_are_numbered_in_the_messages(built_fmus):
    """Ecos names every instance by its FMU's path, so two controllers' messages led with the same name: a
    name that is a path is numbered in the order the instances were made ("[/rig/MusclePlant.fmu #1]")."""
    path = "/rig/MusclePlant.fmu"
    proc = subprocess.run([sys.executable, "-c", TWO_PLANTS, str(built_fmus["MusclePlant"]), path, path],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and host_lines(proc.stdout)[-1] == "done", proc.stderr[-2000:]
    said = [line for line in host_lines(proc.stdout) if "load_force = 600" in line]
    assert said and all(f"] [{path} #1] " in line for line in said), said
