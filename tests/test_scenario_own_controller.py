"""A controller FMU of one's own in a scenario (``[controller] interface``): the shipped example
PIController.fmu on the project's plant FMU is the same loop as the same PI law driving the plant
in Python, bit for bit; its inputs, output and parameters are checked before a run and named."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from fmu_plant import Plant, PlantParams
from fmu_controller.reference import SineReference
from tapmuscle.cli.main import main
from tapmuscle.closed_loop import eq21_error_mm, run_closed_loop
from tapmuscle.cosim import ScenarioError, co_simulate, load_scenario, parse_scenario
from own_controller_fmus import EXAMPLES, build_pi, build_pi_variant

IFACE = {"measurement": "y", "reference": "r", "command": "u"}

pytestmark = pytest.mark.fmu


@pytest.fixture(scope="module")
def pi_fmu(tmp_path_factory) -> Path:
    """PIController.fmu built from the example script as its docstring says (pythonfmu build)."""
    return build_pi(tmp_path_factory.mktemp("own"))


class PI:
    """The example FMU's law (scenarios/examples/pi_controller.py) as a law of one's own in Python:
    the same arithmetic in the same order."""

    def __init__(self, kp=0.15, ki=0.6, u_bias=5.0, u_min=0.0, u_max=10.0, anti_windup=True, ts_s=0.1):
        self.kp, self.ki, self.u_bias, self.u_min, self.u_max = kp, ki, u_bias, u_min, u_max
        self.anti_windup, self.ts_s, self.integral = anti_windup, ts_s, 0.0

    def step(self, l_mm, preview_mm):
        e = float(preview_mm[0]) - l_mm
        v = self.u_bias + self.kp * e + self.integral
        u = min(max(v, self.u_min), self.u_max)
        pushed = (v > self.u_max and e > 0.0) or (v < self.u_min and e < 0.0)
        if not (self.anti_windup and pushed):
            self.integral += self.ki * self.ts_s * e
        return u


def _scenario(fmu, *, parameters=None, reference=None, load_steps=((20.0, 68.0),), record_seed=4):
    return parse_scenario({
        "duration_s": 30.0, "step_s": 0.1, "seed": record_seed,
        "controller": {"fmu": str(fmu), "interface": IFACE, "parameters": parameters or {}},
        "reference": reference or {"kind": "sine", "frequency_hz": 0.1},
        "load": {"initial_n": 44.0, "steps": [{"t_s": t, "load_n": v} for t, v in load_steps]}}, source="test")


@pytest.mark.parametrize("parameters, law", [
    ({}, {}),
    ({"Kp": 0.3, "Ki": 0.2, "u_max": 8.0, "anti_windup": False}, {"kp": 0.3, "ki": 0.2, "u_max": 8.0,
                                                                   "anti_windup": False}),
])
def test_a_controller_fmu_of_ones_own_is_the_same_loop_as_its_law_in_python(built_fmus, pi_fmu, parameters, law):
    """The master feeds y <- l(k), r <- r(k) before the controller's step and applies u(k) over
    [t_k, t_k+1), as for the project's controller: the plant FMU driven by the PI FMU gives the plant
    driven by the same PI in Python, bit for bit (one process), with the load step at the same sample
    and the FMU's parameters (a Boolean among them) in effect."""
    cols = co_simulate(_scenario(pi_fmu, parameters=parameters), built_fmus)
    plant = Plant(PlantParams(), seed=4)
    plant.update(load_n=44.0)
    direct = run_closed_loop(plant, PI(**law), SineReference(frequency_hz=0.1), duration_s=30.0,
                             load_n=lambda t: 68.0 if t + 1e-9 >= 20.0 else 44.0)
    assert np.array_equal(cols["u_v"], direct["u_v"]) and np.array_equal(cols["l_mm"], direct["l_mm"])
    assert np.array_equal(cols["r_mm"], direct["r_mm"])
    assert cols["load_n"][199] == 44.0 and cols["load_n"][200] == 68.0
    assert set(cols) == {"t_s", "r_mm", "l_mm", "u_v", "p_mpa", "load_n", "wall_time_s"}  # no diagnostics it lacks
    if law.get("u_max"):
        assert cols["u_v"].max() == 8.0  # the parameter reached the FMU: the command is capped there
    # a law that tracks at all: the error over Eq. (21)'s window a few mm, not the 30-mm swing
    assert 0.2 < eq21_error_mm(cols["r_mm"], cols["l_mm"], window=(101, 300)) < 6.0


def test_the_shipped_example_runs_as_documented(built_fmus, pi_fmu, tmp_path, capsys):
    """scenarios/examples/own_controller.toml beside its built FMU: `tapmuscle run` writes the result,
    the summary (the FMU named by its model name, the interface) and the tracking figure (no prediction
    figure: the FMU has no prediction), and `tapmuscle check` passes its [expect]."""
    shutil.copy(EXAMPLES / "own_controller.toml", tmp_path)
    shutil.copy(pi_fmu, tmp_path)
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    assert main(["run", str(tmp_path / "own_controller.toml"), "--out", str(tmp_path / "out"), "--fmu-dir", fmu_dir,
                 "--quiet"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["method"] == "own:PIController"
    assert set(summary["fmus"]) == {"MusclePlant", "PIController"}
    assert summary["controller_interface"] == IFACE
    assert summary["mae_mm"] < 5.0 and 0.0 <= summary["u_min_v"] <= summary["u_max_v"] <= 10.0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["result.csv", "summary.json", "tracking.png"]
    capsys.readouterr()
    assert main(["check", str(tmp_path / "own_controller.toml"), "--fmu-dir", fmu_dir]) == 0
    assert "PASS" in capsys.readouterr().out


def test_a_step_reference_reaches_it_as_r_k(built_fmus, pi_fmu):
    """A step reference is fed as r(k) at sample k (no preview: a controller of one's own has no
    horizon); 'advanced' preview is refused with the reason."""
    ref = {"kind": "steps", "times_s": [0.0, 15.0], "values_mm": [20.0, 50.0]}
    cols = co_simulate(_scenario(pi_fmu, reference=ref, load_steps=()), built_fmus, record="minimal")
    assert cols["r_mm"][149] == 20.0 and cols["r_mm"][150] == 50.0
    assert abs(cols["l_mm"][140] - 20.0) < 2.0 and abs(cols["l_mm"][-1] - 50.0) < 2.0  # settled on each
    with pytest.raises(ScenarioError, match=r"key 'reference.preview': 'advanced' feeds r\(t \+ Hp Ts\) .* a "
                                            r"controller FMU of one's own reads r\(k\) at sample k: 'held'"):
        _scenario(pi_fmu, reference={**ref, "preview": "advanced"})


@pytest.mark.parametrize("controller, key, message", [
    ({"interface": IFACE}, "controller.fmu", "missing: a controller with an interface is an FMU of one's own"),
    ({"fmu": "{fmu}", "interface": IFACE, "method": "ampc_servo"}, "controller.method",
     "chooses the project's AMPCController's law or model; a controller FMU of one's own"),
    ({"fmu": "{fmu}", "interface": {"measurement": "y", "command": "u"}}, "controller.interface.reference",
     "missing"),
    ({"fmu": "{fmu}", "interface": {**IFACE, "gain": "Kp"}}, "controller.interface.gain", "unknown key"),
    ({"fmu": "{fmu}", "interface": {**IFACE, "reference": "y"}}, "controller.interface.reference",
     "names 'y', as measurement does"),
    ({"fmu": "{fmu}", "interface": {**IFACE, "reference": " "}}, "controller.interface.reference",
     "must name a variable"),
    ({"fmu": "{fmu}", "interface": IFACE, "parameters": {"r": 3.0}}, "controller.parameters.r",
     "is the controller's reference (interface), which the master sets every sample"),
])
def test_a_controller_table_of_ones_own_is_checked_when_read(pi_fmu, controller, key, message):
    table = {k: (v.format(fmu=pi_fmu) if isinstance(v, str) else v) for k, v in controller.items()}
    with pytest.raises(ScenarioError, match=re.escape(f"key '{key}': {message}")):
        parse_scenario({"duration_s": 5.0, "controller": table}, source="test")


@pytest.mark.parametrize("interface, parameters, message", [
    ({**IFACE, "measurement": "l"}, {}, "test: key 'controller.interface' does not fit "),
    ({**IFACE, "measurement": "l"}, {}, "PIController.fmu, a PIController FMU: measurement = 'l': no such "
                                        "variable (its Real inputs: r, y; its Real outputs: u)"),
    ({**IFACE, "measurement": "u", "command": "Kp"}, {}, "measurement = 'u': a Real output, not a Real input; "
                                                        "command = 'Kp': a Real parameter, not a Real output"),
    ({**IFACE, "measurement": "Kp"}, {}, "measurement = 'Kp': a Real parameter, not a Real input"),
    (IFACE, {"Kpp": 1.0}, "key 'controller.parameters.Kpp': not a parameter of PIController (did you mean 'Kp'? "),
    (IFACE, {"anti_windup": 1}, "key 'controller.parameters.anti_windup': must be true or false, got 1"),
    (IFACE, {"Kp": True}, "key 'controller.parameters.Kp': must be a number (Real), got True"),
])
def test_what_does_not_fit_the_fmu_is_named_before_a_run(built_fmus, pi_fmu, interface, parameters, message):
    scenario = parse_scenario({"duration_s": 5.0, "controller": {"fmu": str(pi_fmu), "interface": interface,
                                                                 "parameters": parameters}}, source="test")
    with pytest.raises(ScenarioError, match=re.escape(message)):
        co_simulate(scenario, built_fmus)


def test_the_projects_controller_is_refused_with_an_interface(built_fmus, tmp_path):
    """Run through an interface, the scenario would not set its method, Ts and reference source: the
    fed reference would be ignored for the built-in sine."""
    scenario = parse_scenario({"duration_s": 5.0, "controller": {"fmu": str(built_fmus["AMPCController"]),
                                                                 "interface": {"measurement": "l", "reference": "r",
                                                                               "command": "u"}}}, source="test")
    with pytest.raises(ScenarioError, match=r"the project's AMPCController runs without \[controller\] interface"):
        co_simulate(scenario, built_fmus)


def test_what_it_warns_of_from_its_instantiation_on_reaches_the_user(built_fmus, tmp_path, capsys):
    """A controller of one's own that warns as it is set up (at fmi2EnterInitializationMode and
    fmi2ExitInitializationMode) and at every step from 2 s on: every warning is passed on, none taken
    as a rejection of its parameters; the command line says a repeated one once, with its count."""
    fmu = build_pi_variant(tmp_path, "warning_pi", from_s=2.0 - 1e-9,
                           do='self.log("late: a warning", status=Fmi2Status.warning)',
                           methods=("    def enter_initialization_mode(self):\n"
                                    '        self.log("entering: a warning", status=Fmi2Status.warning)\n\n'
                                    "    def exit_initialization_mode(self):\n"
                                    '        self.log("leaving: a warning", status=Fmi2Status.warning)\n'))
    said: list[str] = []
    cols = co_simulate(_scenario(fmu, load_steps=()), built_fmus, fmu_warnings=said, record="minimal")
    assert len(cols["u_v"]) == 301
    assert said == (["controller FMU: entering: a warning", "controller FMU: leaving: a warning"]
                    + ["controller FMU: late: a warning"] * 281)  # t = 2.0 .. 30.0 s
    # tapmuscle run says each once, with how often
    (tmp_path / "s.toml").write_text(f"duration_s = 3.0\n[controller]\nfmu = '{fmu}'\n"
                                     "interface = { measurement = 'y', reference = 'r', command = 'u' }\n")
    assert main(["run", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--fmu-dir",
                 str(built_fmus["MusclePlant"].parent), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "warning: controller FMU: late: a warning (11 times)" in err and err.count("late: a warning") == 1


def test_an_error_it_logs_while_its_step_succeeds_is_passed_on_as_an_error(built_fmus, tmp_path):
    """Its message at error level, with the step's status OK: passed on with the run's warnings, said
    to be an error (it read as a warning)."""
    fmu = build_pi_variant(tmp_path, "logging_pi", from_s=2.0 - 1e-9,
                           do='self.log("sensor out of range", status=Fmi2Status.error)')
    said: list[str] = []
    cols = co_simulate(_scenario(fmu, load_steps=()), built_fmus, fmu_warnings=said, record="minimal")
    assert len(cols["u_v"]) == 301
    assert said == ["controller FMU: sensor out of range (logged as an error; its call did not fail)"] * 281


_RAISING_RUNS = """
import gc, sys
from tapmuscle.cosim import ScenarioError, co_simulate, load_scenario
from tapmuscle.cosim.master import InstancePool
scenario, fmus = load_scenario(sys.argv[1]), {"MusclePlant": sys.argv[2]}
pool = InstancePool()
for _ in range(5):  # each garbage collection after a wrong free crashed the process 2 times in 3
    try:
        co_simulate(scenario, fmus, record="minimal", pool=pool)
    except ScenarioError as exc:
        assert "fatal" in str(exc).lower() and "bug in my law" in str(exc), exc
    else:
        raise AssertionError("the run did not fail")
    gc.collect()
pool.close()
print("survived")
"""


def test_an_exception_in_its_python_law_fails_the_run_and_nothing_else(built_fmus, tmp_path):
    """A pythonfmu controller whose law raises: the export returns fmi2Fatal, having released its
    slave's Python objects, so the master calls nothing on that instance any more (FMI 2.0: no call
    after fmi2Fatal); an fmi2Terminate and fmi2FreeInstance after it released them again, and the
    host's next garbage collection crashed the process (SIGSEGV in 2 of 3 command-line runs)."""
    import subprocess
    import sys

    fmu = build_pi_variant(tmp_path, "raising_pi", from_s=2.0, do='raise RuntimeError("bug in my law")')
    (tmp_path / "s.toml").write_text(f"duration_s = 4.0\n[controller]\nfmu = '{fmu}'\n"
                                     "interface = { measurement = 'y', reference = 'r', command = 'u' }\n")
    for _ in range(2):
        proc = subprocess.run([sys.executable, "-c", _RAISING_RUNS, str(tmp_path / "s.toml"),
                               str(built_fmus["MusclePlant"])], capture_output=True, text=True, timeout=300)
        assert (proc.returncode, proc.stdout.strip()) == (0, "survived"), proc.stderr[-2000:]


def test_a_fatal_status_at_its_initialisation_frees_nothing_either(built_fmus, tmp_path):
    """The calls out of the run loop (setting up the experiment, entering initialisation on a reused
    instance's reset) record their status too: an fmi2Fatal there was followed by fmi2Terminate and
    fmi2FreeInstance, and the process crashed at a later garbage collection."""
    import subprocess
    import sys

    fmu = build_pi_variant(tmp_path, "reinit_pi", methods=(
        "    def enter_initialization_mode(self):\n"
        "        type(self).entered = getattr(type(self), 'entered', 0) + 1\n"
        "        if type(self).entered >= 2:\n"
        "            raise RuntimeError('bug in my law')\n"))
    (tmp_path / "s.toml").write_text(f"duration_s = 2.0\n[controller]\nfmu = '{fmu}'\n"
                                     "interface = { measurement = 'y', reference = 'r', command = 'u' }\n")
    # the first run passes and leaves its instance in the pool; each later one fails at its reset
    script = _RAISING_RUNS.replace("for _ in range(5):", "co_simulate(scenario, fmus, record='minimal', pool=pool)\n"
                                   "for _ in range(5):")
    for _ in range(2):
        proc = subprocess.run([sys.executable, "-c", script, str(tmp_path / "s.toml"), str(built_fmus["MusclePlant"])],
                              capture_output=True, text=True, timeout=300)
        assert (proc.returncode, proc.stdout.strip()) == (0, "survived"), proc.stderr[-2000:]


@pytest.mark.parametrize("status, calls", [(0, ["terminate", "freeInstance"]), (2, ["terminate", "freeInstance"]),
                                           (3, ["freeInstance"]), (4, [])])
def test_an_instance_is_freed_as_its_last_status_allows(status, calls):
    """FMI 2.0 (2.1.3): after fmi2Error only fmi2FreeInstance (and reset, state calls), after fmi2Fatal
    no call at all; a discard ends as a normal run."""
    from tapmuscle.cosim.master import FmuInstance

    made: list[str] = []

    class Recorder:
        def __getattr__(self, name):
            return lambda *args: made.append(name)

    inst = object.__new__(FmuInstance)
    inst.fmu, inst._name, inst.failed_status = Recorder(), "recorder", 0
    inst.failed(status)
    inst.free()
    assert made == calls


def test_the_command_a_controller_of_ones_own_sends_is_what_the_plant_takes(built_fmus, pi_fmu):
    """The plant FMU takes a command within -1..11 V as its valve does (saturated at 0..10 V: 10.5 V
    moves the muscle as 10 V does, and the recorded command is what the controller sent); a command
    beyond, or NaN, stops the run naming the controller FMU, its output, the value and the time."""
    def run(u_bias, u_max=10.0):
        return co_simulate(_scenario(pi_fmu, parameters={"Kp": 0.0, "Ki": 0.0, "u_bias": u_bias, "u_max": u_max},
                                     load_steps=()), built_fmus, record="minimal")

    above, ten = run(10.5, 11.0), run(10.0)
    assert np.all(above["u_v"] == 10.5) and np.all(ten["u_v"] == 10.0)
    assert np.array_equal(above["l_mm"], ten["l_mm"])
    assert ten["l_mm"][-1] > 50.0  # the valve fully open lifts the 44-N load
    with pytest.raises(ScenarioError, match=r"controller FMU \(PIController.fmu\) output u = 12.0 at t = 0 s is not a "
                                            r"command the plant's valve takes \(-1.0..11.0 V, saturated at 0..10 V\)"):
        run(12.0, 20.0)
    # also at the last sample, whose command the plant never receives
    last = parse_scenario({"duration_s": 5.0, "step_s": 0.1, "controller": {
        "fmu": str(pi_fmu), "interface": IFACE, "parameters": {"Kp": 1.0, "Ki": 0.0, "u_max": 20.0, "u_min": -20.0}},
        "reference": {"kind": "steps", "times_s": [0.0, 5.0], "values_mm": [0.0, 400.0]}}, source="test")
    with pytest.raises(ScenarioError, match=r"output u = \d+\.\d+ at t = 5 s is not a command"):
        co_simulate(last, built_fmus, record="minimal")


def test_the_example_scenario_file_reads_without_its_fmu_only_as_a_missing_file(tmp_path):
    """The shipped example's FMU is built by its user: the missing file names the source beside it and
    the command (a user ran the README's command as shipped and met only 'does not exist')."""
    with pytest.raises(ScenarioError, match=r"key 'controller.fmu': file '.*PIController.fmu' does not exist: build "
                                            r"it from pi_controller.py beside it first \(pythonfmu build -f "
                                            r"pi_controller.py, in .*examples\)"):
        load_scenario(EXAMPLES / "own_controller.toml")
    # installed from a wheel, the examples' folder is read-only for a user: built in a copy instead
    # (emulated: root may write anywhere)
    import tapmuscle.cosim.spec as spec

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(spec.os, "access", lambda path, mode: False)
        with pytest.raises(ScenarioError, match=r"build it from pi_controller.py beside it first; .*examples cannot be "
                                                r"written \(an installed package's\?\), so copy the folder and run "
                                                r"there: cp -r .*examples my_copy && cd my_copy && pythonfmu build -f "
                                                r"pi_controller.py, then the scenario file in my_copy"):
            load_scenario(EXAMPLES / "own_controller.toml")
    # a missing FMU without a pythonfmu source beside it is only missing
    (tmp_path / "s.toml").write_text((EXAMPLES / "own_controller.toml").read_text())
    with pytest.raises(ScenarioError, match=r"PIController.fmu' does not exist$"):
        load_scenario(tmp_path / "s.toml")



def test_a_sweep_compares_it_with_the_projects_controller(built_fmus, pi_fmu, tmp_path):
    """A grid over the whole [controller] table: every load with the project's controller and with the
    one of one's own, one method each in results.csv and summary.md (the table itself no axis: the
    method column names it; the FMU the table names found beside the sweep file, where it is written,
    not beside the base); each run the same as it alone."""
    import csv

    from tapmuscle.cosim.distributed_sweep import run_serial
    from tapmuscle.cosim.sweep import load_sweep
    from tapmuscle.cosim.sweep_run import run_sweep

    (tmp_path / "sweeps").mkdir()
    (tmp_path / "bases").mkdir()
    shutil.copy(pi_fmu, tmp_path / "sweeps")  # beside the sweep file, which names it: found from there
    (tmp_path / "bases" / "short.toml").write_text("duration_s = 12.0\nevaluation_samples = [20, 120]\n")
    text = ('name = "pi_vs_ampc"\nbase = "../bases/short.toml"\n[grid]\n'
            'controller = [ { method = "ampc_servo" }, { fmu = "PIController.fmu", interface = { measurement = "y", '
            'reference = "r", command = "u" } } ]\n"load.initial_n" = [44.0, 68.0]\n')
    (tmp_path / "sweeps" / "cmp.toml").write_text(text)
    sweep = load_sweep(tmp_path / "sweeps" / "cmp.toml")
    report = run_sweep(sweep, tmp_path / "out", built_fmus, run_serial)
    assert (report.total, report.failed) == (4, 0)
    with open(tmp_path / "out" / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert sorted((r["method"], r["load_n"]) for r in rows) == [
        ("ampc_servo", "44.0"), ("ampc_servo", "68.0"), ("own:PIController", "44.0"), ("own:PIController", "68.0")]
    alone = co_simulate(parse_scenario(
        {"duration_s": 12.0, "evaluation_samples": [20, 120], "load": {"initial_n": 68.0},
         "controller": {"fmu": str(pi_fmu), "interface": IFACE}}, source="alone"), built_fmus)
    mine = next(r for r in rows if r["method"] == "own:PIController" and r["load_n"] == "68.0")
    assert float(mine["mae_mm"]) == pytest.approx(eq21_error_mm(alone["r_mm"], alone["l_mm"], window=(20, 120)),
                                                  rel=1e-9)
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "| own:PIController | 2 | 0 |" in summary and "| ampc_servo | 2 | 0 |" in summary
    assert "| method | load_n | runs |" in summary  # the controller table is no column of its own


# ------------------------------------------------------------------------ a controller FMU in C
C_FMU = Path(__file__).resolve().parent / "c_fmu" / "pi_controller.c"
C_VARIABLES = (("y", "input", "continuous", "0"), ("r", "input", "continuous", "0"),
               ("u", "output", "continuous", None), ("Kp", "parameter", "fixed", "0.15"),
               ("Ki", "parameter", "fixed", "0.6"), ("u_bias", "parameter", "fixed", "5"),
               ("u_min", "parameter", "fixed", "0"), ("u_max", "parameter", "fixed", "10"))


@pytest.fixture(scope="module")
def c_pi_fmu(tmp_path_factory) -> Path:
    """tests/c_fmu/pi_controller.c built as a C export is: gcc, a hand-written modelDescription.xml."""
    import subprocess
    import zipfile

    import fmpy

    if shutil.which("gcc") is None:
        pytest.skip("no gcc to build the C controller FMU")
    out = tmp_path_factory.mktemp("c_pi")
    library = out / "CPIController.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-ffp-contract=off", "-fno-fast-math",
                    f"-I{Path(fmpy.__file__).parent / 'c-code'}", str(C_FMU), "-o", str(library), "-lm"], check=True)
    variables = "".join(
        f'<ScalarVariable name="{name}" valueReference="{i}" causality="{causality}" variability="{variability}"'
        + (' initial="exact"' if causality == "parameter" else ' initial="calculated"' if start is None else "")
        + f"><Real{f' start={chr(34)}{start}{chr(34)}' if start is not None else ''}/></ScalarVariable>"
        for i, (name, causality, variability, start) in enumerate(C_VARIABLES))
    variables += ('<ScalarVariable name="anti_windup" valueReference="0" causality="parameter" variability="fixed" '
                  'initial="exact"><Boolean start="true"/></ScalarVariable>')
    xml = ('<?xml version="1.0" encoding="UTF-8"?><fmiModelDescription fmiVersion="2.0" modelName="CPIController" '
           'guid="{7c1f0a52-6c1e-4c55-9d7e-0c0ffee00001}" generationTool="hand-written C" '
           'numberOfEventIndicators="0"><CoSimulation modelIdentifier="CPIController"/>'
           '<DefaultExperiment startTime="0" stopTime="30" stepSize="0.05"/>'
           f'<ModelVariables>{variables}</ModelVariables><ModelStructure><Outputs><Unknown index="3"/></Outputs>'
           '<InitialUnknowns><Unknown index="3"/></InitialUnknowns></ModelStructure></fmiModelDescription>')
    fmu = out / "CPIController.fmu"
    with zipfile.ZipFile(fmu, "w") as z:
        z.writestr("modelDescription.xml", xml)
        z.write(library, "binaries/linux64/CPIController.so")
    return fmu


def test_a_controller_fmu_in_c_is_the_same_loop_as_its_law_in_python(built_fmus, c_pi_fmu):
    """Not every controller of one's own is pythonfmu's: the same PI in C (no Python in it) gives
    the plant driven by the PI in Python, bit for bit, Boolean parameter and all; its messages,
    printf formats with arguments as C exports log them, arrive formatted; its DefaultExperiment
    step, which it declares it cannot leave, is said where the scenario's differs."""
    params = {"Kp": 0.3, "Ki": 2.0, "u_max": 8.0, "anti_windup": False}
    said: list[str] = []
    cols = co_simulate(_scenario(c_pi_fmu, parameters=params), built_fmus, fmu_warnings=said)
    plant = Plant(PlantParams(), seed=4)
    plant.update(load_n=44.0)
    direct = run_closed_loop(plant, PI(kp=0.3, ki=2.0, u_max=8.0, anti_windup=False), SineReference(frequency_hz=0.1),
                             duration_s=30.0, load_n=lambda t: 68.0 if t + 1e-9 >= 20.0 else 44.0)
    assert np.array_equal(cols["u_v"], direct["u_v"]) and np.array_equal(cols["l_mm"], direct["l_mm"])
    assert cols["u_v"].max() == 8.0
    from tapmuscle.cosim import master

    # it cannot take another step size than its DefaultExperiment's (FMI's default), which is not step_s
    assert said[0] == "controller FMU: its DefaultExperiment step is 0.05 s; the scenario steps it every step_s = 0.1 s"
    if master._formatting_logger() is not None:  # compiled (CI requires it): the values formatted in
        assert said[1:] == ["controller FMU: Ki = 2 is 200% of a 1 V/(mm s) ceiling"]
    with pytest.raises(ScenarioError, match=r"controller FMU \(CPIController.fmu\) exitInitializationMode failed: "
                                            r"fmi2ExitInitializationMode failed with status 3 \(error\): .*\[ERROR\] "
                                            + (r"Kp = -1 must be >= 0 \(1 of 5 parameters checked\)$"
                                               if master._formatting_logger() is not None else "Kp")):
        co_simulate(_scenario(c_pi_fmu, parameters={"Kp": -1.0}), built_fmus)


def test_a_c_fmu_gets_a_new_instance_every_run_of_a_sweep(built_fmus, c_pi_fmu):
    """An export's fmi2Reset may return OK and keep state (its integral) from the run before, which no
    call can tell: a sweep keeps only pythonfmu's instances (whose reset builds the slave anew), and
    a C FMU's run is the run of a fresh instance."""
    from tapmuscle.cosim.master import InstancePool

    pool = InstancePool()
    try:
        runs = [co_simulate(_scenario(c_pi_fmu, parameters=p), built_fmus, record="minimal", pool=pool)
                for p in ({"Kp": 0.3}, {})]
        assert [inst.role for idle in pool._idle.values() for inst in idle] == ["plant"]
    finally:
        pool.close()
    fresh = co_simulate(_scenario(c_pi_fmu), built_fmus, record="minimal")
    assert np.array_equal(runs[1]["u_v"], fresh["u_v"]) and not np.array_equal(runs[0]["u_v"], fresh["u_v"])
