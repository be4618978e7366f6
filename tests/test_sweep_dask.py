"""Sweeps on a real Dask cluster: a `dask scheduler` and two `dask worker` processes on loopback."""

import csv
import json
import os
import re
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

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
                 "--fmu-dir", fmu_dir]) == 0
    told = capsys.readouterr().err.splitlines()
    assert f"Dask: 2 workers at {address}" in told  # a scheduler started with --no-dashboard: no link
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
    assert ("--scheduler tcp://127.0.0.1:9: tcp://127.0.0.1:9: nothing listens on port 9 of 127.0.0.1"
            in capsys.readouterr().err)


def _server(reply: bytes | None):
    """A listener on loopback that answers each connection with ``reply`` (None: says nothing, as an HTTP
    server waiting for a request does); ``(port, stop)``."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)
    held = []

    def serve():
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            held.append(conn)
            if reply is not None:
                conn.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()

    def stop():
        srv.close()
        for conn in held:
            conn.close()
    return srv.getsockname()[1], stop


@pytest.mark.parametrize("reply, said", [
    (None, "no Dask scheduler answered within 1.5 s"),  # the dashboard's port: distributed would wait for ever
    (b"HTTP/1.1 400 Bad Request\r\n\r\n", "an HTTP server answers there, not a Dask scheduler"),  # a proxy: 3 EiB
])
def test_a_port_that_is_no_schedulers_is_named_within_the_timeout(tmp_path, capsys, reply, said):
    port, stop = _server(reply)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(SWEEP)
    try:
        started = time.monotonic()
        assert main(["sweep", str(sweep), "--scheduler", f"tcp://127.0.0.1:{port}", "--timeout", "1.5", "--out",
                     str(tmp_path / "o"), "--quiet"]) == 2
        assert time.monotonic() - started < 30
    finally:
        stop()
    err = capsys.readouterr().err
    assert f"--scheduler tcp://127.0.0.1:{port}: " in err and said in err, err
    assert not (tmp_path / "o").exists()


def test_workers_that_cannot_run_tapmuscle_are_named_before_any_run():
    """A worker without osqp, with another tapmuscle, or with the same version's other sources (another
    commit, a local edit) would fail each run it took or compute other numbers: each is named, by
    address and by the name its admin gave it, with what it lacks or where its code is, before any run;
    the sweep runs on the others, and a cluster none of whose workers can is refused."""
    import warnings

    from tapmuscle.cosim.distributed_sweep import ClusterError, ClusterWarning, DaskExecutor, _code_here, check_workers

    mine = _code_here()

    class Client:
        def run(self, function, *args, on_error):
            assert on_error == "return"
            if function is exec:
                return {"tcp://a:1": None, "tcp://b:2": ModuleNotFoundError("No module named 'osqp'"),
                        "tcp://c:3": None, "tcp://d:4": None}
            if function is _code_here:
                return {"tcp://a:1": mine, "tcp://b:2": mine, "tcp://c:3": mine,
                        "tcp://d:4": ("0123456789ab", "/scratch/old/tapmuscle")}
            return {w: function(*args) for w in ("tcp://a:1", "tcp://b:2", "tcp://d:4")} | {"tcp://c:3": "0.0.1"}

        def scheduler_info(self):
            return {"workers": {"tcp://a:1": {"name": "tcp://a:1"}, "tcp://b:2": {"name": 0},
                                "tcp://c:3": {"name": "gpu-node"}, "tcp://d:4": {"name": "w-old"}}}

    problems = check_workers(Client())
    assert sorted(problems) == ["tcp://b:2", "tcp://c:3", "tcp://d:4"]  # tcp://a:1 can: the sweep runs there
    with warnings.catch_warnings(record=True) as warned:
        warnings.simplefilter("always", ClusterWarning)
        executor = DaskExecutor(Client(), refused=problems)
    assert executor.refused == problems and len(warned) == 3
    assert all(w.filename == __file__ for w in warned)  # at the caller's line (a notebook cell), not the library's
    assert all(str(w.message).startswith(problems[a]) and "no run is sent to it" in str(w.message)
               for w, a in zip(warned, sorted(problems)))
    said = "; ".join(problems.values())

    class NoneCan(Client):
        def run(self, function, *args, on_error):
            got = super().run(function, *args, on_error=on_error)
            return {w: v for w, v in got.items() if w != "tcp://a:1"}

    with pytest.raises(ClusterError) as err:
        check_workers(NoneCan())
    assert str(err.value).startswith(said) and "every worker needs the client's tapmuscle" in str(err.value)

    class Empty:
        def run(self, *args, **kwargs):
            return {}
    with pytest.raises(ClusterError, match="the cluster has no worker"):
        check_workers(Empty())
    assert "worker tcp://b:2 (0) cannot import tapmuscle's run code: ModuleNotFoundError: No module named 'osqp'" in said
    assert "worker tcp://c:3 (gpu-node) has tapmuscle 0.0.1, the client tapmuscle " in said and "tcp://a:1" not in said
    assert (f"worker tcp://d:4 (w-old) runs other tapmuscle sources (digest 0123456789ab, from /scratch/old/tapmuscle) "
            f"than the client (digest {mine[0]}, from {mine[1]})") in said


def test_the_runs_outlive_the_loss_of_the_only_worker(built_fmus, tmp_path):
    """Its nanny restarts a killed worker; the FMU files, the input of a task the scheduler keeps, are
    sent again, and every run finishes (scattered data would be lost with the worker, and the runs not
    yet done would fail as "already forgotten")."""
    import signal

    from tapmuscle.cosim import load_scenario
    from tapmuscle.cosim.distributed_sweep import DaskExecutor, FmuFiles, dask_client, make_task

    (tmp_path / "case.toml").write_text("duration_s = 300.0\n")  # a few tenths of a second each
    scenario = load_scenario(tmp_path / "case.toml")
    folder = built_fmus["MusclePlant"].parent
    fmus = {name: folder / f"{name}.fmu" for name in ("MusclePlant", "AMPCController")}
    files = FmuFiles.for_scenarios([scenario], fmus)
    tasks = [make_task(str(seed), replace(scenario, seed=seed), fmus, files) for seed in range(6)]
    with dask_client(1) as client:
        results, killed = [], False
        for result in DaskExecutor(client)(tasks, files):
            results.append(result)
            if not killed:
                pid = next(iter(client.run(os.getpid).values()))
                os.kill(pid, signal.SIGKILL)
                killed = True
    assert killed and sorted(r.run_id for r in results) == [str(i) for i in range(6)]
    assert [r.status for r in results] == ["ok"] * 6, [r.error for r in results]
    assert len({r.worker for r in results}) == 2  # runs done after the loss, by the restarted worker


def test_a_result_that_came_back_is_kept_whatever_its_futures_status_became(monkeypatch):
    """A worker that another run's FMU crashes after a run finished there changes that future's status
    from "finished": the run's result, already back, is what counts (not a failed run with the
    RunResult as its error); what came back as an error is a failed run."""
    import distributed

    from tapmuscle.cosim.distributed_sweep import DaskExecutor, FmuFiles, RunResult

    class Future:
        def __init__(self, status):
            self.status = status

        def release(self):
            pass

    ok = RunResult("a", "ok", {"mae_mm": 0.1})
    futures = [Future("lost"), Future("error")]
    back = [(futures[0], ok), (futures[1], ValueError("the FMU crashed"))]

    class Client:
        status = "running"

        def submit(self, *args, **kwargs):
            return Future("finished")

        def map(self, fn, tasks, *args, **kwargs):
            return futures

        def cancel(self, futures):
            pass

        def scheduler_info(self):
            return {"workers": {"w": {}}}

    class AsCompleted:
        def __init__(self, *args, **kwargs):
            self.batches = [back]

        def update(self, futures):
            pass

        def next_batch(self, block=False):
            return self.batches.pop()

    monkeypatch.setattr(distributed, "as_completed", AsCompleted)
    tasks = [SimpleNamespace(run_id="a"), SimpleNamespace(run_id="b")]
    results = list(DaskExecutor(Client())(tasks, FmuFiles({}, {})))
    assert results[0] is ok
    assert results[1].status == "failed" and results[1].error == "ValueError: the FMU crashed"


@pytest.mark.slow
def test_check_on_a_local_cluster(built_fmus, tmp_path, capsys):
    """The default of `tapmuscle sweep`: a LocalCluster of worker processes started by the command."""
    case = tmp_path / "case.toml"
    case.write_text('duration_s = 12.0\nevaluation_samples = [20, 120]\n[expect]\nmae_mm_max = 5.0\n')
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    assert main(["check", str(case), "--workers", "1", "--fmu-dir", fmu_dir]) == 0
    captured = capsys.readouterr()
    assert "Dask: 1 workers at tls://127.0.0.1:" in captured.err and "PASS    case" in captured.out


@pytest.mark.slow
def test_another_client_cannot_use_the_commands_local_cluster():
    """The command's own cluster listens on local ports that every user of the machine reaches; a
    client without its temporary TLS credentials (another user's code, which would run as the
    sweep's user) is refused, with or without TLS of its own."""
    from distributed import Client
    from distributed.security import Security

    from tapmuscle.cosim.distributed_sweep import dask_client

    with dask_client(1) as client:
        address = client.scheduler.address
        assert address.startswith("tls://127.0.0.1:")
        assert client.submit(int, "7").result() == 7  # its own client gets in
        for security in (None, Security.temporary()):  # none, and another cluster's credentials
            with pytest.raises(Exception) as refused:
                Client(address.replace("tls://", "tcp://") if security is None else address, security=security,
                       timeout="3s")
            assert not isinstance(refused.value, AssertionError)


def _wait_for(path: Path, proc: subprocess.Popen, timeout_s: float = 120.0) -> None:
    """Until ``path`` exists; fails with the command's output if it ends or ``timeout_s`` passes first."""
    deadline = time.monotonic() + timeout_s
    while not path.is_file():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.2)


def _sweep_in_a_terminal(sweep, out, built_fmus, *, workers: int) -> subprocess.Popen:
    """``tapmuscle sweep`` on its own local cluster in a process group of its own, with a terminal's
    SIGINT disposition (a test run started in the background ignores SIGINT, and its children
    inherit that), for a test to send Ctrl-C to the whole group."""
    import signal

    return subprocess.Popen([sys.executable, "-m", "tapmuscle", "sweep", str(sweep), "--workers", str(workers),
                             "--out", str(out), "--fmu-dir", str(built_fmus["MusclePlant"].parent), "--quiet",
                             "--no-plots"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def test_ctrl_c_stops_a_local_cluster_sweep_with_one_message(built_fmus, tmp_path):
    """A terminal's Ctrl-C reaches the whole foreground group: the local cluster's worker processes
    ignore it (the command stops them) and print nothing over the command's one line; it exits 130."""
    import signal

    sweep = tmp_path / "long.toml"
    # runs of 1-2 s each, more than the command reaches before the Ctrl-C that follows the first
    sweep.write_text(f'name = "long"\nbase = {{ duration_s = 600.0 }}\ngrid = {{ seed = {list(range(16))} }}\n')
    out = tmp_path / "o"
    proc = _sweep_in_a_terminal(sweep, out, built_fmus, workers=2)
    try:
        _wait_for(out / "results.csv", proc)  # a run finished: the cluster is up and running
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert err.strip() == f"interrupted: finished runs are in {out}/results.csv; rerun the same command to go on"


@pytest.mark.slow
def test_ctrl_c_ends_a_sweep_whose_fmu_hangs_in_a_step(built_fmus, tmp_path):
    """A controller FMU of one's own that never returns from a step, holding the GIL as a C FMU does:
    its worker answers nothing, and closing the local cluster would wait for it for ever; after Ctrl-C
    the command kills the worker it cannot close and exits within seconds, with its one line."""
    import shutil
    import signal

    from own_controller_fmus import EXAMPLES, build_pi_variant

    # a C call that keeps the GIL and never returns, after leaving a file that says the step is in it
    inside = tmp_path / "inside_the_step"
    build_pi_variant(tmp_path, "hanging_pi", do=f"open({str(inside)!r}, 'w').close()\nimport ctypes\n"
                                                 f"ctypes.PyDLL(None).sleep(3600)")
    shutil.copy(EXAMPLES / "own_controller.toml", tmp_path / "base.toml")
    sweep = tmp_path / "hang.toml"
    sweep.write_text('name = "hang"\nbase = "base.toml"\ngrid = { seed = [0, 1] }\n')
    out = tmp_path / "o"
    proc = _sweep_in_a_terminal(sweep, out, built_fmus, workers=1)
    try:
        _wait_for(inside, proc)  # the cluster up and its run inside the step that hangs
        time.sleep(0.5)  # into the C call that follows the file's writing
        os.killpg(proc.pid, signal.SIGINT)
        started = time.monotonic()
        _, err = proc.communicate(timeout=90)
        took = time.monotonic() - started
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "interrupted: no run had finished; rerun the same command to go on" in err
    assert took < 45, took  # the close's 10 s, then the kill and the nanny's own close


def test_a_run_that_kills_its_worker_fails_no_other_run(built_fmus, tmp_path):
    """A controller FMU of one's own that ends its process in a step for one Kp: Dask runs that task on
    other workers until its allowed failures are spent. With one task at a time per single-threaded
    worker no other run sits on a dying worker, so exactly that run fails (KilledWorker) and every other
    passes: a crash fails its own runs only (with Dask's default two per worker, a neighbour failed as
    KilledWorker in 4 of 6 such sweeps)."""
    import shutil

    from own_controller_fmus import EXAMPLES, build_pi_variant

    build_pi_variant(tmp_path, "crashing_pi", from_s=0.5, do="if self.Kp > 1.0:\n    import os\n    os._exit(3)")
    shutil.copy(EXAMPLES / "own_controller.toml", tmp_path / "base.toml")
    gains = [0.1, 5.0, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5]
    sweep = tmp_path / "crash.toml"
    sweep.write_text(f'name = "crash"\nbase = "base.toml"\n[grid]\nduration_s = [35.0]\n'
                     f'"controller.parameters.Kp" = {gains}\n')
    out = tmp_path / "o"
    proc = subprocess.run([sys.executable, "-m", "tapmuscle", "sweep", str(sweep), "--workers", "2", "--out", str(out),
                           "--fmu-dir", str(built_fmus["MusclePlant"].parent), "--quiet", "--no-plots"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 1, proc.stderr[-3000:]  # a failed run
    with open(out / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    status = {float(r["controller.parameters.Kp"]): r["status"] for r in rows}
    assert status == {k: "failed" if k == 5.0 else "ok" for k in gains}, rows
    assert next(r for r in rows if r["status"] == "failed")["error"].startswith("KilledWorker")


def test_the_commands_local_cluster_sends_each_worker_one_run_at_a_time():
    """The setting behind the test above, read off the scheduler (that test catches Dask's default,
    two tasks per single-threaded worker, in about half of its runs, as the crash's timing decides)."""
    from tapmuscle.cosim.distributed_sweep import dask_client

    with dask_client(2) as client:
        assert client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.WORKER_SATURATION) == 1.0


def _count_runs_on_the_cluster(dask_scheduler):
    """On the scheduler: count the sweep's run tasks on workers (processing) at once, keep the most."""
    from distributed.diagnostics.plugin import SchedulerPlugin

    class Count(SchedulerPlugin):
        name = "tapmuscle-test-count"
        now = most = 0

        def transition(self, key, start, finish, *args, **kwargs):
            if str(key).startswith("tapmuscle-run-"):
                self.now += (finish == "processing") - (start == "processing")
                self.most = max(self.most, self.now)

    dask_scheduler.add_plugin(Count())


def _most_runs_on_the_cluster(dask_scheduler):
    return dask_scheduler.plugins["tapmuscle-test-count"].most


def test_the_commands_local_cluster_gets_one_run_per_worker_at_a_time_and_a_clients_own_all(built_fmus, tmp_path,
                                                                                         monkeypatch):
    """On the local cluster of 2 workers, a sweep of 4 runs (Dask holds back none of so few tasks,
    whatever the scheduler's worker-saturation: the executor submits one per worker thread, the next as
    one finishes; a run waiting on a worker whose FMU crashes would fail with it, 2 of 16 such sweeps otherwise)
    and one of 6 (the scheduler's queue holds them back) have at most 2 runs on the workers. On a client
    of one's own every run is submitted at once: an adaptive cluster grows on the backlog."""
    import tapmuscle as tm
    from contextlib import contextmanager

    from tapmuscle.cosim import distributed_sweep

    sweep = tmp_path / "s.toml"
    sweep.write_text(SWEEP)
    folder = built_fmus["MusclePlant"].parent
    fmus = {name: folder / f"{name}.fmu" for name in ("MusclePlant", "AMPCController")}
    real, most = distributed_sweep.dask_client, []

    @contextmanager
    def counted(*args, **kwargs):
        with real(*args, **kwargs) as client:
            client.run_on_scheduler(_count_runs_on_the_cluster)
            yield client
            most.append(client.run_on_scheduler(_most_runs_on_the_cluster))

    monkeypatch.setattr(distributed_sweep, "dask_client", counted)
    local = tm.sweep(sweep, tmp_path / "local", fmus=fmus, workers=2, plots=False)
    larger = tmp_path / "larger.toml"
    larger.write_text(SWEEP.replace('"load.initial_n" = [44.0, 68.0]', '"load.initial_n" = [44.0, 56.0, 68.0]'))
    queued = tm.sweep(larger, tmp_path / "larger", fmus=fmus, workers=2, plots=False)
    with counted(2) as client:
        own = tm.sweep(sweep, tmp_path / "own", fmus=fmus, client=client, plots=False)
    assert [(r.ran, r.failed) for r in (local, queued, own)] == [(4, 0), (6, 0), (4, 0)]
    assert most == [2, 2, 4]


def test_a_notebooks_own_client_runs_the_sweep_and_stays_usable(built_fmus, tmp_path):
    """tm.sweep(client=...): the runs go to the user's cluster (its workers checked first), the same
    numbers as in this process, and the client and its other work are left as they were."""
    import tapmuscle as tm
    from distributed import Client, LocalCluster

    sweep = tmp_path / "s.toml"
    sweep.write_text(SWEEP)
    folder = built_fmus["MusclePlant"].parent
    fmus = {name: folder / f"{name}.fmu" for name in ("MusclePlant", "AMPCController")}
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        mine = client.submit(sum, [1, 2, 3])
        report = tm.sweep(sweep, tmp_path / "dask", fmus=fmus, client=client, plots=False)
        assert client.status == "running" and mine.result() == 6 and client.submit(len, "abc").result() == 3
        worker_pid = next(iter(client.run(os.getpid).values()))
    local = tm.sweep(sweep, tmp_path / "here", fmus=fmus, plots=False)
    assert (report.total, report.ran, report.failed) == (4, 4, 0)
    for row, here in zip(report.rows, local.rows):
        assert row["run_id"] == here["run_id"] and row["mae_mm"] == here["mae_mm"]
        assert int(row["worker"].rsplit(":", 1)[1]) == worker_pid


def test_a_notebooks_cluster_without_workers_is_told_how_to_make_it_again(built_fmus, tmp_path):
    """A LocalCluster whose workers an interrupt killed (it restarts none) is not told to start one with
    `dask worker SCHEDULER_ADDRESS`: the message names the cluster's address and the remedy for a
    cluster made in the notebook, and nothing is written."""
    import tapmuscle as tm
    from distributed import Client, LocalCluster

    sweep = tmp_path / "s.toml"
    sweep.write_text(SWEEP)
    folder = built_fmus["MusclePlant"].parent
    fmus = {name: folder / f"{name}.fmu" for name in ("MusclePlant", "AMPCController")}
    with LocalCluster(n_workers=0, processes=True, dashboard_address=None) as cluster, Client(cluster) as client:
        with pytest.raises(tm.ClusterError, match=rf"the cluster has no worker: start one \(dask worker "
                                                  rf"{cluster.scheduler_address} --nthreads 1\), or, for a LocalCluster "
                                                  "made in this process, close it and make it again"):
            tm.sweep(sweep, tmp_path / "o", fmus=fmus, client=client, plots=False)
    assert not (tmp_path / "o").exists()


def _cluster_processes(tmp, workers=1):
    """A `dask scheduler` and ``workers`` `dask worker` processes without a nanny (a killed worker stays
    dead): ``(address, [scheduler, worker...])``."""
    scheduler_file = tmp / "scheduler.json"
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", str(scheduler_file)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    deadline = time.monotonic() + 60
    while not scheduler_file.is_file() or not scheduler_file.read_text().strip():
        assert time.monotonic() < deadline and procs[0].poll() is None, "the dask scheduler did not start"
        time.sleep(0.1)
    time.sleep(0.2)
    address = json.loads(scheduler_file.read_text())["address"]
    for i in range(workers):
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", "--no-nanny",
                                       "--no-dashboard", "--local-directory", str(tmp / f"w{i}")],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    return address, procs


@pytest.mark.parametrize("lost, command", [("scheduler", "sweep"), ("workers", "sweep"), ("workers", "check")])
def test_a_cluster_lost_mid_sweep_stops_it_in_one_line_keeping_the_finished_runs(built_fmus, tmp_path, lost, command):
    """The scheduler killed mid-sweep must not record every unfinished run as failed, with 40 lines of the
    client's tracebacks, nor every worker killed leave the sweep waiting for ever ("still running"). Both
    end the command with one line and status 3 (CLUSTER_LOST), the runs finished before kept, none
    recorded as failed; a rerun on a cluster again runs only the others. `check`, which keeps no results
    between commands, says that its rerun runs every case again, and its report holds the finished runs."""
    import signal

    from tapmuscle.cli.sweep import CLUSTER_LOST

    sweep = tmp_path / "long.toml"
    sweep.write_text('name = "long"\nbase = { duration_s = 300.0, expect = { mae_mm_max = 100.0 } }\n'
                     'grid = { seed = [0, 1, 2, 3, 4, 5] }\n')
    out = tmp_path / "o"
    address, procs = _cluster_processes(tmp_path)
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    junit = tmp_path / "report.xml"
    options = ["--out", str(out), "--no-plots"] if command == "sweep" else ["--junit", str(junit)]
    try:
        cmd = subprocess.Popen([sys.executable, "-m", "tapmuscle", command, str(sweep), "--scheduler", address,
                                "--timeout", "3", "--fmu-dir", fmu_dir, "--quiet", *options],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 120

        def finished() -> bool:
            if command == "sweep":
                return (out / "results.csv").is_file()
            return junit.is_file() and len(ET.parse(junit).getroot().findall("testsuite/testcase/error")) < 6

        while not finished():  # a run finished
            assert cmd.poll() is None and time.monotonic() < deadline, cmd.communicate()
            time.sleep(0.1)
        (procs[0] if lost == "scheduler" else procs[1]).send_signal(signal.SIGKILL)
        _, err = cmd.communicate(timeout=120)
    finally:
        for proc in procs:
            _stop(proc)
    assert cmd.returncode == CLUSTER_LOST, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"tapmuscle {command}: the cluster was lost: "), err
    assert ("lost the connection to the scheduler" if lost == "scheduler"
            else "no worker has been connected to the scheduler") in lines[0]
    if command == "check":
        cases = list(ET.parse(junit).getroot().iter("testcase"))
        unfinished = sum(c.find("error") is not None and "did not finish" in c.find("error").text for c in cases)
        assert len(cases) == 6 and 0 < unfinished < 6
        assert f"({6 - unfinished} of 6 runs finished): start workers" in lines[0], lines[0]
        assert "rerun the check (it runs every case again)" in lines[0] and "not recorded as failed" not in lines[0]
        assert f"{junit} holds the runs that finished, the others as errors (did not finish)" in lines[0]
        return
    assert "rerun the same command to go on" in lines[0]
    rows = _rows(out / "results.csv")
    assert rows and all(r["status"] == "ok" for r in rows.values()) and len(rows) < 6
    assert re.search(rf"\b{len(rows)} runs? finished here, kept; the {6 - len(rows)} others are not recorded as "
                     "failed", lines[0]), lines[0]


def test_a_script_that_sweeps_on_workers_without_the_main_guard_is_told_so(built_fmus, tmp_path):
    """tm.sweep(workers=2) at a script's top level: each spawned worker imports the script again and
    would start a cluster of its own, which would print about 500 lines of the nannies' tracebacks. Each
    worker ends with one line naming the script and the guard, and the script gets a ClusterError;
    the same script under ``if __name__ == "__main__":`` runs."""
    (tmp_path / "s.toml").write_text('name = "s"\nbase = { duration_s = 5.0, evaluation_samples = [10, 50] }\n'
                                     'grid = { seed = [0, 1] }\n')
    folder = built_fmus["MusclePlant"].parent
    call = (f'tm.sweep("s.toml", "out", workers=2, plots=False, fmus={{"MusclePlant": r"{folder}/MusclePlant.fmu", '
            f'"AMPCController": r"{folder}/AMPCController.fmu"}})')
    for guarded in (False, True):
        script = tmp_path / "run.py"
        body = f"r = {call}\nprint('done', r.total, r.failed)\n"
        script.write_text("import tapmuscle as tm\n" + (body if not guarded else
                                                         "if __name__ == '__main__':\n" + "".join(
                                                             f"    {line}\n" for line in body.splitlines())))
        proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300)
        if guarded:
            assert proc.returncode == 0 and "done 2 0" in proc.stdout, proc.stderr
            continue
        assert proc.returncode == 1 and len(proc.stderr.splitlines()) < 40, proc.stderr
        assert f"tapmuscle: workers=2 starts worker processes, and each imports {script} again" in proc.stderr
        assert 'put it under if __name__ == "__main__":' in proc.stderr
        assert proc.stderr.rstrip().endswith("worker processes did not start (Nanny failed to start.); their message "
                                             "is above"), proc.stderr[-500:]


def test_a_scheduler_without_workers_is_said_in_the_commands_words(built_fmus, tmp_path, capsys):
    """A scheduler that gets no worker within --timeout: Dask's "Only 0/1 workers arrived after 2" is
    said as tm.sweep(client=...) says it, with the command that starts one."""
    address, procs = _cluster_processes(tmp_path, workers=0)
    sweep = tmp_path / "s.toml"
    sweep.write_text(SWEEP)
    try:
        assert main(["sweep", str(sweep), "--scheduler", address, "--timeout", "2", "--out", str(tmp_path / "o"),
                     "--fmu-dir", str(built_fmus["MusclePlant"].parent), "--quiet"]) == 2
    finally:
        for proc in procs:
            _stop(proc)
    err = capsys.readouterr().err
    assert f"the cluster has no worker after 2 s: start one (dask worker {address} --nthreads 1)" in err, err
    assert "Only 0/1" not in err and not (tmp_path / "o").exists()


def test_a_cancelled_run_of_a_windowed_sweep_is_a_failed_run(monkeypatch):
    """One run of four cancelled on the cluster while a small sweep is submitted one run per thread:
    it is a failed run and the others finish (waiting with distributed.wait raised at the cancel)."""
    import threading
    import time as clock

    from distributed import Client, Future, LocalCluster

    from tapmuscle.cosim import distributed_sweep as ds

    def slow(task, files):
        clock.sleep(1.5)
        return ds.RunResult(task.run_id, "ok")

    monkeypatch.setattr(ds, "_worker_run", slow)  # a thread cluster: the workers see the patch
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        def cancel_the_first():
            clock.sleep(0.5)
            client.cancel([Future(k, client) for k in list(client.futures) if str(k).startswith("tapmuscle-run-r0-")])

        threading.Thread(target=cancel_the_first, daemon=True).start()
        tasks = [ds.RunTask(f"r{i}", None, ()) for i in range(4)]
        got = {r.run_id: r for r in ds.DaskExecutor(client, one_run_per_thread=True)(tasks, ds.FmuFiles({}, {}))}
    assert {k: r.status for k, r in got.items()} == {"r0": "failed", "r1": "ok", "r2": "ok", "r3": "ok"}
    assert "Cancelled" in got["r0"].error


def test_the_dashboard_link_is_given_only_where_its_page_answers():
    """A scheduler without bokeh (or started with --no-dashboard) still has a link, to a page that is
    not there: only a link whose page answers is printed."""
    import http.server
    import threading
    from types import SimpleNamespace

    from tapmuscle.cli.sweep import _dashboard

    class Page(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server's name
            self.send_response(200 if self.path == "/status" else 404)
            self.end_headers()

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Page)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        base = f"http://127.0.0.1:{server.server_address[1]}"
        assert _dashboard(SimpleNamespace(dashboard_link=f"{base}/status")) == f"{base}/status"
        assert _dashboard(SimpleNamespace(dashboard_link=f"{base}/nothing")) is None
        assert _dashboard(SimpleNamespace()) is None  # a client without the attribute
    finally:
        server.shutdown()
        server.server_close()


def test_a_sweep_without_a_worker_says_so_for_its_progress_report():
    """What the sweep's heartbeat says while the cluster has no worker (and nothing while it has)."""
    import time as clock

    from tapmuscle.cosim.distributed_sweep import DaskExecutor, _ClusterWatch

    executor = DaskExecutor(object(), no_worker_s=60.0)
    assert executor.waiting() is None  # no sweep running
    executor._watch = _ClusterWatch(object(), 60.0, 4)
    assert executor.waiting() is None  # a worker seen (or not asked yet)
    executor._watch._alone_since = clock.monotonic() - 12.2
    assert executor.waiting() == "no worker connected to the scheduler for 12 s; the sweep stops at 60 s"


def test_a_worker_with_other_sources_runs_none_of_the_runs(built_fmus, tmp_path, capsys):
    """A worker that runs other tapmuscle sources (here: one whose code digest a preload script sets to
    another commit's) would compute other numbers into the same results. One that joins after the
    check refuses each run it is given: the run goes to a worker with the client's sources, no run is
    lost or failed, and the worker is named once. One there at the check (the command's next sweep)
    is named and given no run; the others run the sweep."""
    import warnings

    from distributed import Client, LocalCluster

    from tapmuscle.cosim import load_scenario
    from tapmuscle.cosim.distributed_sweep import ClusterWarning, DaskExecutor, FmuFiles, check_workers, make_task

    (tmp_path / "case.toml").write_text("duration_s = 60.0\n")
    scenario = load_scenario(tmp_path / "case.toml")
    folder = built_fmus["MusclePlant"].parent
    fmus = {name: folder / f"{name}.fmu" for name in ("MusclePlant", "AMPCController")}
    files = FmuFiles.for_scenarios([scenario], fmus)
    tasks = [make_task(str(seed), replace(scenario, seed=seed), fmus, files) for seed in range(8)]
    preload = tmp_path / "other_commit.py"
    preload.write_text("import tapmuscle.cosim.distributed_sweep as ds\n"
                       "ds._CODE_HERE[:] = [('0123456789ab', '/scratch/old/tapmuscle')]\n")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        check_workers(client)  # the worker at the start has the client's sources
        late = subprocess.Popen([sys.executable, "-m", "dask", "worker", cluster.scheduler_address, "--nthreads", "1",
                                 "--no-nanny", "--no-dashboard", "--preload", str(preload), "--name", "w-old",
                                 "--local-directory", str(tmp_path / "late")],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            client.wait_for_workers(2, timeout=60)
            executor = DaskExecutor(client)
            with warnings.catch_warnings(record=True) as said:
                warnings.simplefilter("always", ClusterWarning)
                results = list(executor(tasks, files))
            sweep = tmp_path / "sweep.toml"
            sweep.write_text(SWEEP)
            capsys.readouterr()
            assert main(["sweep", str(sweep), "--scheduler", cluster.scheduler_address, "--out", str(tmp_path / "o"),
                         "--fmu-dir", str(folder), "--no-plots"]) == 0
            told = capsys.readouterr().err
        finally:
            _stop(late)
    rows = _rows(tmp_path / "o" / "results.csv")
    assert len(rows) == 4 and all(r["status"] == "ok" for r in rows.values()), rows
    assert late.pid not in {int(r["worker"].rsplit(":", 1)[1]) for r in rows.values()}
    assert re.search(r"^Dask: 2 workers at tcp://\S+; 1 of them given no run \(below\)$", told, re.M), told
    assert re.search(r"warning: worker tcp://\S+ \(w-old\) runs other tapmuscle sources \(digest 0123456789ab, "
                     r"from /scratch/old/tapmuscle\) than the client .*: no run is sent to it", told), told
    assert sorted(r.run_id for r in results) == sorted(t.run_id for t in tasks)
    assert [r.status for r in results] == ["ok"] * len(tasks), [r.error for r in results]
    assert late.pid not in {int(r.worker.rsplit(":", 1)[1]) for r in results}
    (address, why), = executor.refused.items()
    assert why.startswith(f"worker {address} runs other tapmuscle sources (digest 0123456789ab, from "
                          "/scratch/old/tapmuscle) than the client")
    warned = [str(w.message) for w in said if issubclass(w.category, ClusterWarning)]
    assert len(warned) == 1 and warned[0].startswith(why) and "joined after the sweep's check" in warned[0], warned
