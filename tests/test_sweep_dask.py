"""Sweeps on a real Dask cluster: a `dask scheduler` and two `dask worker` processes on loopback."""

import csv
import json
import os
import subprocess
import sys
import time

import pytest

pytest.importorskip("distributed")

from tapmuscle.cli.main import main  # noqa: E402

# every test here starts a Dask cluster (seconds each)
pytestmark = [pytest.mark.dask, pytest.mark.slow]

SWEEP = """
name = "dask_small"
base = { duration_s = 15.0, evaluation_samples = [20, 150] }
grid = { "controller.method" = ["mpc_servo", "ampc_servo"], "load.initial_n" = [44.0, 68.0] }
"""


def _stop(proc):
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """``(address, worker pids, TMPDIR of the workers)``; the processes are stopped afterwards."""
    tmp = tmp_path_factory.mktemp("dask")
    scheduler_file = tmp / "scheduler.json"
    worker_tmp = tmp / "worker_tmp"
    worker_tmp.mkdir()
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    procs = []
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--dashboard-address", ":0",
             "--scheduler-file", str(scheduler_file)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file() or not scheduler_file.read_text().strip():
            assert time.monotonic() < deadline, "the dask scheduler did not start"
            assert procs[0].poll() is None, "the dask scheduler exited"
            time.sleep(0.1)
        time.sleep(0.2)  # the file is written in one go, but be sure it is complete
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for i in range(2):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                 "--name", f"w{i}", "--dashboard-address", ":0", "--local-directory", str(tmp / f"w{i}"), "--death-timeout", "60"],
                env={**env, "TMPDIR": str(worker_tmp)}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address, {p.pid for p in procs[1:]}, worker_tmp
    finally:
        for proc in reversed(procs):
            _stop(proc)


def _rows(path):
    with open(path, newline="") as fh:
        return {r["run_id"]: r for r in csv.DictReader(fh)}


@pytest.mark.slow
def test_sweep_on_a_dask_cluster_equals_the_serial_run(dask_cluster, built_fmus, tmp_path, capsys):
    address, worker_pids, worker_tmp = dask_cluster
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(SWEEP)
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    assert main(["sweep", str(sweep), "--scheduler", address, "--out", str(tmp_path / "dask"),
                 "--fmu-dir", fmu_dir, "--quiet"]) == 0
    assert main(["sweep", str(sweep), "--workers", "0", "--out", str(tmp_path / "serial"),
                 "--fmu-dir", fmu_dir, "--quiet", "--no-plots"]) == 0
    capsys.readouterr()
    dask_rows, serial_rows = _rows(tmp_path / "dask" / "results.csv"), _rows(tmp_path / "serial" / "results.csv")
    assert dask_rows.keys() == serial_rows.keys() and len(dask_rows) == 4
    for rid, row in dask_rows.items():
        assert row["status"] == "ok", row["error"]
        for metric in ("mae_mm", "rms_error_mm", "max_abs_error_mm", "u_min_v", "u_max_v"):
            assert row[metric] == serial_rows[rid][metric], (rid, metric)  # bit for bit (repr of the float)
        assert int(row["worker"].rsplit(":", 1)[1]) in worker_pids  # ran in a dask worker, not here
        assert int(serial_rows[rid]["worker"].rsplit(":", 1)[1]) == os.getpid()
    # the FMUs were shipped to the workers and written into their own cache, by content digest
    shipped = sorted(p.name for p in worker_tmp.glob("tapmuscle-fmus-*/*/*.fmu"))
    assert shipped == ["AMPCController.fmu", "MusclePlant.fmu"]
    assert (tmp_path / "dask" / "mae_map.png").stat().st_size > 10_000  # load varies: the map is drawn


def test_check_on_the_dask_cluster(dask_cluster, built_fmus, tmp_path, capsys):
    address, _, _ = dask_cluster
    case = tmp_path / "case.toml"
    case.write_text('duration_s = 12.0\nevaluation_samples = [20, 120]\n[expect]\nmae_mm_max = 0.01\n')
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    assert main(["check", str(case), "--scheduler", address, "--fmu-dir", fmu_dir, "--quiet"]) == 1
    assert "FAIL    case" in capsys.readouterr().out


@pytest.mark.slow
def test_unreachable_scheduler_is_a_usage_error(tmp_path, capsys):
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(SWEEP)
    assert main(["sweep", str(sweep), "--scheduler", "tcp://127.0.0.1:9", "--timeout", "2", "--out", str(tmp_path / "o"),
                 "--quiet"]) == 2
    assert "--scheduler tcp://127.0.0.1:9: cannot start or connect" in capsys.readouterr().err


@pytest.mark.slow
def test_check_on_a_local_cluster(built_fmus, tmp_path, capsys):
    """The default of `tapmuscle sweep`: a LocalCluster of worker processes started by the command."""
    case = tmp_path / "case.toml"
    case.write_text('duration_s = 12.0\nevaluation_samples = [20, 120]\n[expect]\nmae_mm_max = 5.0\n')
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    assert main(["check", str(case), "--workers", "1", "--fmu-dir", fmu_dir]) == 0
    captured = capsys.readouterr()
    assert "Dask: 1 workers at tcp://127.0.0.1:" in captured.err and "PASS    case" in captured.out
