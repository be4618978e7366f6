"""Sweep speed-up on a local Dask cluster: 64 runs on 1 worker process against 2.

The runs: the four controllers x 16 Monte-Carlo operating points (load U(30, 90) N, supply
U(0.20, 0.30) MPa, own noise seed), 45 s of the 0.1 Hz sine each, through the FMUs, as
``tapmuscle sweep`` runs them (:class:`tapmuscle.cosim.distributed_sweep.DaskExecutor`, one task per run).
Timed: from submitting the 64 tasks to the last result (best of ``--repeat``, the three set-ups
interleaved, a new cluster each time); the cluster's start and a warm-up run of each controller method
on every worker (imports, FMU extraction) are not timed. Also the same runs in this process, without Dask. Goal: speed-up
2 workers / 1 worker >= 1.8 on the 2-core development machine.

    python benchmarks/sweep_speedup.py [--repeat 5] [--runs 64]
"""

from __future__ import annotations

import argparse
import time

from build_scripts.build_fmus import cached_fmus
from tapmuscle.cosim.distributed_sweep import DaskExecutor, FmuFiles, _worker_run, dask_client, make_task, run_serial
from tapmuscle.cosim.sweep import parse_sweep


def _tasks(n_runs: int, fmus):
    n = max(1, n_runs // 4)
    sweep = parse_sweep({
        "base": {"duration_s": 45.0, "reference": {"kind": "sine", "frequency_hz": 0.1}},
        "grid": {"controller.method": ["mpc_ucp", "mpc_servo", "ampc_ucp", "ampc_servo"]},
        "monte_carlo": {"n": n, "sample_seed": 1, "load.initial_n": {"uniform": [30.0, 90.0]},
                        "supply.initial_mpa": {"uniform": [0.20, 0.30]}, "seed": {"integers": [0, 9999]}}},
        source="benchmark")
    files = FmuFiles.read(fmus.values())
    return [make_task(r.run_id, r.scenario, fmus, files) for r in sweep.runs], files


def _timed(execute, tasks, files) -> tuple[float, int]:
    t0 = time.perf_counter()
    ok = sum(r.status == "ok" for r in execute(tasks, files))
    return time.perf_counter() - t0, ok


def _warm_up(client, tasks, files) -> None:
    """Every worker runs one task of each controller method, untimed: its imports (the servo methods'
    OSQP and SciPy among them), FMU extraction and pooled instances are then in place, as in the
    process that runs the in-process set-up."""
    shipped = DaskExecutor(client).ship(files, "warm-up")
    first = {}
    for task in tasks:
        first.setdefault(task.scenario.method, task)
    client.gather([client.submit(_worker_run, task, shipped, workers=[worker], allow_other_workers=False, pure=False)
                   for worker in client.scheduler_info()["workers"] for task in first.values()])


def _on_cluster(workers: int, tasks, files) -> tuple[float, int]:
    """One timed sweep on a fresh local cluster of ``workers`` (started and warmed up untimed)."""
    with dask_client(workers) as client:  # the local cluster of `tapmuscle sweep --workers N`
        _warm_up(client, tasks, files)
        return _timed(DaskExecutor(client, one_run_per_thread=True), tasks, files)  # as the command's


def _report(label: str, best: float, n: int, ok: int | None = None) -> None:
    status = f", {ok} ok" if ok is not None else ""
    print(f"  {label:<10} {best:6.2f} s for {n} runs ({1e3 * best / n:5.1f} ms/run{status})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="timed repetitions; the best counts (default 5)")
    parser.add_argument("--runs", type=int, default=64, help="runs per repetition (default 64)")
    args = parser.parse_args()
    tasks, files = _tasks(args.runs, cached_fmus())
    print(f"{len(tasks)} runs of 45 s (4 controllers x {len(tasks) // 4} operating points), best of {args.repeat}")
    list(run_serial(list({task.scenario.method: task for task in tasks}.values()), files))  # warm-up, every method
    # Interleaved rounds (in-process, 1 worker, 2 workers, again ...), each cluster new: the machine
    # is shared and its speed drifts by 10-40 % over minutes, which would otherwise favour whichever
    # set-up ran in a quiet spell.
    rounds = []
    for i in range(args.repeat):
        rounds.append((_timed(run_serial, tasks, files), _on_cluster(1, tasks, files), _on_cluster(2, tasks, files)))
        print(f"  round {i + 1}: in-process {rounds[-1][0][0]:.2f} s, 1 worker {rounds[-1][1][0]:.2f} s, "
              f"2 workers {rounds[-1][2][0]:.2f} s", flush=True)
    serial, one, two = (min(r[i] for r in rounds) for i in range(3))
    _report("in-process", serial[0], len(tasks))
    _report("1 worker", one[0], len(tasks), one[1])
    _report("2 workers", two[0], len(tasks), two[1])
    per_round = ", ".join(f"{r[1][0] / r[2][0]:.2f}" for r in rounds)
    print(f"speed-up 2 workers / 1 worker: {one[0] / two[0]:.2f}x (goal >= 1.8; per round {per_round}); "
          f"2 workers / in-process: {serial[0] / two[0]:.2f}x")


if __name__ == "__main__":
    main()
