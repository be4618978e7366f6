"""Ctrl-C during a co-simulation: held until the master is between FMI calls; in a slave, fmi2Error.

Without both, SIGINT landed in a Python FMU's step most of the time: ``tapmuscle paper`` ended with a
segfault (exit 139) or a fatal FMU error (exit 2) in two of three tries, and a sweep recorded the
interrupted run as failed and went on.
"""

import argparse
import importlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tapmuscle.cosim import PAPER_SCENARIOS
from tapmuscle.interrupts import HELD, held_interrupts, interrupt_once

# about Python's own SIGINT handler, which a test run started with SIGINT ignored has not; children start
# with the default disposition (_default_sigint)
pytestmark = [pytest.mark.skipif(os.name != "posix", reason="SIGINT sent to a child process (POSIX)"),
              pytest.mark.usefixtures("python_sigint_handler")]


def _default_sigint() -> None:
    """SIGINT's default disposition, in a child process (Python then installs its own handler)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_a_sigint_in_the_block_is_held_then_raised_where_asked_and_the_handler_restored():
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with held_interrupts() as held:
            signal.raise_signal(signal.SIGINT)
            reached.append("after the signal")  # the block goes on: the signal is only noted
            assert held.pending
            held.raise_if_pending()
            reached.append("never")
    assert reached == ["after the signal"] and not HELD.pending
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_signal_still_held_at_the_end_of_the_block_is_raised_there():
    done = []
    with pytest.raises(KeyboardInterrupt):
        with held_interrupts():
            signal.raise_signal(signal.SIGINT)
            done.append(True)
    assert done == [True] and signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_held_interrupt_left_by_a_block_that_ended_interrupted_otherwise_does_not_end_the_next():
    """A block that a held SIGINT had reached, ending by a KeyboardInterrupt of its own (a nested
    call's), leaves the flag up; the next block starts afresh and runs to its end."""
    with pytest.raises(KeyboardInterrupt):
        with held_interrupts():
            signal.raise_signal(signal.SIGINT)
            raise KeyboardInterrupt
    done = []
    with held_interrupts():
        done.append(True)
    assert done == [True] and not HELD.pending


def test_nested_blocks_hold_once_and_other_threads_and_handlers_are_left_alone():
    with held_interrupts():
        ours = signal.getsignal(signal.SIGINT)
        with held_interrupts():
            assert signal.getsignal(signal.SIGINT) is ours
        assert signal.getsignal(signal.SIGINT) is ours  # the inner block did not restore the default
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler

    # a thread pool's run beside the main thread's: the main thread's Ctrl-C ends the main thread's
    # run, whichever reads its flag first
    seen = []
    signalled, in_thread = threading.Event(), threading.Event()

    def run_in_thread():
        with held_interrupts() as held:
            assert held is not HELD and signal.getsignal(signal.SIGINT) is ours
            in_thread.set()
            signalled.wait(10)
            held.raise_if_pending()  # not this run's signal
            seen.append("thread ran on")

    with pytest.raises(KeyboardInterrupt):
        with held_interrupts() as held:
            ours = signal.getsignal(signal.SIGINT)
            thread = threading.Thread(target=run_in_thread)
            thread.start()
            in_thread.wait(10)
            signal.raise_signal(signal.SIGINT)
            signalled.set()
            thread.join()
            seen.append("main ran on")
            held.raise_if_pending()
    assert seen == ["thread ran on", "main ran on"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    seen.clear()

    def own(signum, frame):
        seen.append("own handler")

    previous = signal.signal(signal.SIGINT, own)
    try:
        with held_interrupts():
            assert signal.getsignal(signal.SIGINT) is own
            signal.raise_signal(signal.SIGINT)
        assert seen[-1] == "own handler"
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.fixture
def interrupting_once():
    """The console script's handler (``interrupt_once``) installed for the test, the default put back."""
    signal.signal(signal.SIGINT, interrupt_once)
    yield
    signal.signal(signal.SIGINT, signal.default_int_handler)


def test_interrupt_once_raises_and_ignores_every_later_sigint(interrupting_once):
    with pytest.raises(KeyboardInterrupt):
        signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    signal.raise_signal(signal.SIGINT)  # a key still held: nothing raised, in an except clause or anywhere


def test_under_interrupt_once_a_held_interrupt_that_ends_the_block_leaves_sigint_ignored(interrupting_once):
    """Whether raised in the block (the master's ``raise_if_pending``) or still held at its end, the
    interrupt that ends the block ignores the later ones as ``interrupt_once``'s own does; a block that
    ends without one puts ``interrupt_once`` back."""
    with held_interrupts():
        assert signal.getsignal(signal.SIGINT) is not interrupt_once  # held
    assert signal.getsignal(signal.SIGINT) is interrupt_once

    with pytest.raises(KeyboardInterrupt):
        with held_interrupts() as held:
            signal.raise_signal(signal.SIGINT)
            held.raise_if_pending()
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN

    signal.signal(signal.SIGINT, interrupt_once)
    with pytest.raises(KeyboardInterrupt):
        with held_interrupts():
            signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN and not HELD.pending


@pytest.mark.parametrize("once", [False, True])
def test_a_block_that_fails_with_a_signal_held_ends_interrupted_with_the_failure_as_its_cause(once):
    """A Ctrl-C held while the block fails otherwise (an FMU's error in a run being stopped): the stop
    wins, ``KeyboardInterrupt`` from the failure, nothing left pending; under ``interrupt_once`` SIGINT
    stays ignored, as after any interrupt that ends the process, else Python's handler is back."""
    if once:
        signal.signal(signal.SIGINT, interrupt_once)
    try:
        with pytest.raises(KeyboardInterrupt) as stopped:
            with held_interrupts():
                signal.raise_signal(signal.SIGINT)
                raise RuntimeError("the FMU failed")
        assert isinstance(stopped.value.__cause__, RuntimeError) and not HELD.pending
        assert signal.getsignal(signal.SIGINT) is (signal.SIG_IGN if once else signal.default_int_handler)
        if once:
            signal.signal(signal.SIGINT, interrupt_once)
        with pytest.raises(RuntimeError):  # without a signal held, the failure is the failure
            with held_interrupts():
                raise RuntimeError("the FMU failed")
        assert signal.getsignal(signal.SIGINT) is (interrupt_once if once else signal.default_int_handler)
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def test_the_console_script_interrupts_once_and_puts_the_callers_handler_back(monkeypatch, tmp_path):
    """``main()`` as the console script calls it (no argv) runs its command under ``interrupt_once``
    and, not interrupted, ends with the handler it found; ``main(argv)`` (an in-process caller) keeps
    Python's own throughout."""
    cli = importlib.import_module("tapmuscle.cli.main")

    seen = []

    def command(args):
        seen.append(signal.getsignal(signal.SIGINT))
        return 0

    real = cli.build_parser

    def parser_with_probe():
        parser = real()
        commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        commands.choices["build"].set_defaults(func=command)  # the command replaced: nothing is built
        return parser

    monkeypatch.setattr(cli, "build_parser", parser_with_probe)
    monkeypatch.setattr(sys, "argv", ["tapmuscle", "build", "--out", str(tmp_path)])
    assert cli.main() == 0
    assert cli.main(["build", "--out", str(tmp_path)]) == 0
    assert seen == [interrupt_once, signal.default_int_handler]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


_INTERRUPTED_STEP = r"""
import signal, sys
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

path, cycles = sys.argv[1], int(sys.argv[2])
md = read_model_description(path)
folder = extract(path)
vr = {v.name: v.valueReference for v in md.modelVariables}
for i in range(cycles):
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=f"i{i}")
    f.instantiate(loggingOn=True)
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    slave = next(m for name, m in sys.modules.items() if name.endswith(".fmu_plant.plant_slave")).MusclePlant
    original = slave.step_numerics
    def interrupted(self, t, h):
        original(self, t, h)
        signal.raise_signal(signal.SIGINT)  # Ctrl-C: Python's handler raises KeyboardInterrupt in the slave
        for _ in range(3):
            pass
    slave.step_numerics = interrupted
    f.setReal([vr["u"]], [6.0])
    try:
        f.doStep(0.0, 0.1)
        status = 0
    except FMICallException as exc:
        status = exc.status
    slave.step_numerics = original
    print("status", status, flush=True)
    f.terminate()
    f.freeInstance()
print("done", flush=True)
"""


@pytest.mark.fmu
def test_an_interrupt_inside_a_slaves_step_is_an_error_not_a_crash(built_fmus):
    """Python's own SIGINT handler inside the plant slave's step, 20 instantiate / interrupted step /
    free cycles in one fmpy process: fmi2Error every time, and the process ends normally (a
    KeyboardInterrupt reaching pythonfmu's C++ layer was fmi2Fatal, and freeing the instance then
    crashed the host)."""
    proc = subprocess.run([sys.executable, "-c", _INTERRUPTED_STEP, str(built_fmus["MusclePlant"]), "20"],
                          capture_output=True, text=True, timeout=300, preexec_fn=_default_sigint)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    lines = [line for line in proc.stdout.splitlines() if line.startswith(("status", "done"))]
    assert lines == ["status 3"] * 20 + ["done"], proc.stdout[-2000:]


def test_tapmuscle_run_interrupted_mid_run_exits_130_and_frees_the_fmus(built_fmus, tmp_path):
    """SIGINT to ``tapmuscle run`` once its loop is under way (its first progress line): the
    interrupted message, exit status 130, no output file, and no FMU error on the way."""
    fmu_dir = Path(built_fmus["MusclePlant"]).parent
    paper = (PAPER_SCENARIOS / "ampc_servo_44N_0.1Hz.toml").read_text(encoding="utf-8")
    assert "duration_s = 45.0" in paper
    scenario = tmp_path / "long.toml"  # two hours of rig time: about 7 s here
    scenario.write_text(paper.replace("duration_s = 45.0", "duration_s = 7200.0"), encoding="utf-8")
    for attempt in range(3):
        out = tmp_path / f"out{attempt}"
        proc = subprocess.Popen([sys.executable, "-m", "tapmuscle", "run", str(scenario), "--out", str(out),
                                 "--fmu-dir", str(fmu_dir)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                preexec_fn=_default_sigint)
        with proc:
            deadline = time.monotonic() + 120
            for line in proc.stderr:  # progress goes to stderr
                if "%" in line or time.monotonic() > deadline:
                    break
            time.sleep(0.2 * attempt)
            proc.send_signal(signal.SIGINT)
            stdout, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 130, (proc.returncode, stdout[-1000:], stderr[-2000:])
        assert "interrupted; nothing is half-written" in stderr and "FATAL" not in stderr and "ERROR" not in stderr
        assert not (out / "result.csv").exists()


@pytest.mark.slow
def test_ctrl_c_held_down_still_exits_130_without_a_traceback(built_fmus, tmp_path):
    """SIGINT every 2 ms once ``tapmuscle run`` is under way (a key held, hammered): the first ends the
    run; the others, arriving in its clean-up and in the exit's (the FMUs' extraction folders removed
    at exit), are ignored. They made the process die by the signal (-2), not exit 130, with
    "Exception ignored in atexit callback ... KeyboardInterrupt", in 3 of 3 tries."""
    fmu_dir = Path(built_fmus["MusclePlant"]).parent
    paper = (PAPER_SCENARIOS / "ampc_servo_44N_0.1Hz.toml").read_text(encoding="utf-8")
    scenario = tmp_path / "long.toml"
    scenario.write_text(paper.replace("duration_s = 45.0", "duration_s = 7200.0"), encoding="utf-8")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "tapmuscle", "run", str(scenario), "--out", str(out),
                             "--fmu-dir", str(fmu_dir)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)
    with proc:
        deadline = time.monotonic() + 120
        for line in proc.stderr:
            if "%" in line or time.monotonic() > deadline:
                break
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                proc.send_signal(signal.SIGINT)
            except ProcessLookupError:
                break
            time.sleep(0.002)
        stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, (proc.returncode, stderr[-2000:])
    assert "Traceback" not in stderr and "Exception ignored" not in stderr, stderr[-2000:]
    assert "interrupted; nothing is half-written" in stderr and not (out / "result.csv").exists()
