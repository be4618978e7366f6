"""The diagnosis's simulator (tapmuscle/diagnosis/simulation.py): a run the plant cannot integrate."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fmu_plant import PlantParams
from tapmuscle.diagnosis.fit_problem import SimulationError as FitProblemSimulationError
from tapmuscle.diagnosis.simulation import SimulationError, Simulator, process_pool


def test_parameters_the_plant_cannot_integrate_are_a_failed_simulation_naming_them():
    """A plant integration that breaks down is a failed simulation, which the fits step around (as an
    FMU error), not an exception that ends the diagnosis."""
    sim = Simulator(np.full(50, 5.0), 0.1)
    with pytest.raises(SimulationError, match=r"the plant with muscle\.rest_length_mm=1e-12: .*too many sub-steps"):
        sim.run(PlantParams().with_values(**{"muscle.rest_length_mm": 1e-12}))
    assert FitProblemSimulationError is SimulationError  # the one the fits catch
    assert sim.run(PlantParams())[0].shape == (50,) and sim.runs == 1  # the failed run is not counted


def _sleep_then_mark(folder: str, k: int) -> int:
    """A task of a worker: sleeps, then leaves a file saying it finished."""
    time.sleep(20.0)
    Path(folder, f"done_{k}").write_text("")
    return k


def test_an_interrupt_stops_the_pools_processes_and_its_queued_work(tmp_path):
    """An interrupt of the main process alone (kill -INT, a scheduler): the pool must not first run
    what is queued."""
    with pytest.raises(KeyboardInterrupt):
        with process_pool(2, "jobs=2") as pool:
            futures = [pool.submit(_sleep_then_mark, str(tmp_path), k) for k in range(6)]
            processes = list(pool._processes.values())
            raise KeyboardInterrupt
    assert len(processes) == 2 and not any(p.is_alive() for p in processes)
    assert all(f.cancelled() or f.done() for f in futures)
    assert not list(tmp_path.glob("done_*"))  # no task ran to its end



def test_an_interrupt_while_the_pool_starts_its_feeding_thread_stays_an_interrupt():
    """Ctrl-C can land while the executor starts the thread that feeds its processes (inside
    Thread.start): the clean-up must not try to join that thread, which is not started, and turn the
    interrupt into a RuntimeError (exit 1 and a traceback instead of 130)."""
    import threading

    with pytest.raises(KeyboardInterrupt):
        with process_pool(1, "jobs=1") as pool:
            pool._executor_manager_thread = threading.Thread(target=lambda: None)  # created, not started
            raise KeyboardInterrupt

def test_ctrl_c_on_a_diagnosis_with_workers_ends_it_without_tracebacks_or_output(tmp_path):
    from tapmuscle.diagnosis.demo import DEMO_MODEL, record
    from tapmuscle.io.recording import Recording, write_recording
    from tapmuscle.io.plant_file import plant_file_text

    rig = DEMO_MODEL.with_values(**{"delay.delay_s": 0.3})
    rec = record(rig, "steps", 5, duration_s=120.0)
    write_recording(tmp_path / "rec.csv", Recording({k: rec[k] for k in ("t_s", "u_v", "l_mm")}, {}))
    (tmp_path / "plant.json").write_text(plant_file_text(DEMO_MODEL, "nominal"))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "tapmuscle.cli", "diagnose", "--recording", str(tmp_path / "rec.csv"),
                             "--plant", str(tmp_path / "plant.json"), "--out", str(out), "--workers", "2"],
                            start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    first = proc.stderr.readline()  # the first progress line: the workers are running
    assert first.startswith("diagnose:"), first
    os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C reaches every process of the group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted; nothing is half-written" in err and "Traceback" not in err, err
    assert not out.exists()


def test_a_failed_simulation_names_every_value_that_differs_from_the_defaults():
    """The plant a failed simulation was run with is named by all its values off the defaults: with
    a limit of eight, the ninth, the one of a candidate of one's own that broke it, was 'and 1 more'."""
    from tapmuscle.diagnosis.simulation import _changed

    defaults = PlantParams().dotted()
    keys = [k for k, v in defaults.items() if isinstance(v, float) and v > 0][:9]
    changed = _changed(PlantParams().with_values(**{k: defaults[k] * 0.99 for k in keys}))
    assert all(f"{k}=" in changed for k in keys) and "more" not in changed, changed
    assert _changed(PlantParams()) == "its defaults"
