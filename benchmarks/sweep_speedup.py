"""Sweep speed-up on a local Dask cluster: 64 runs on 1 worker process against 2 (issue 7).

The runs: the four controllers x 16 Monte-Carlo operating points (load U(30, 90) N, supply
U(0.20, 0.30) MPa, own noise seed), 45 s of the 0.1 Hz sine each, through the FMUs, as
``tapmuscle sweep`` runs them (:class:`scenarios.distributed_sweep.DaskExecutor`, one task per run).
Timed: from submitting the 64 tasks to the last result (best of ``--repeat``); the cluster's start and
one warm-up run per worker (imports, FMU extraction) are printed apart. Also the same runs in this
process, without Dask. Goal: speed-up 2 workers / 1 worker >= 1.8 on the 2-core development machine.

    python benchmarks/sweep_speedup.py [--repeat 5] [--runs 64]
"""

from __future__ import annotations

import argparse
import time

from build_scripts.build_fmus import cached_fmus
from scenarios.distributed_sweep import DaskExecutor, FmuFiles, dask_client, make_task, run_serial
from scenarios.sweep import parse_sweep


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


def _on_cluster(workers: int, tasks, files, repeat: int) -> float:
    t0 = time.perf_counter()
    with dask_client(workers) as client:  # the local cluster of `tapmuscle sweep --workers N`
        started = time.perf_counter() - t0
        executor = DaskExecutor(client)
        t0 = time.perf_counter()
        list(executor(tasks[:workers * 2], files))  # warm-up: imports and FMU extraction on every worker
        warm = time.perf_counter() - t0
        best, ok = min(_timed(executor, tasks, files) for _ in range(repeat))
    print(f"  {workers} worker{'s' if workers > 1 else ' '}: {best:6.2f} s for {len(tasks)} runs "
          f"({1e3 * best / len(tasks):5.1f} ms/run, {ok} ok)   [cluster start {started:.1f} s, warm-up {warm:.1f} s]")
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="timed repetitions; the best counts (default 5)")
    parser.add_argument("--runs", type=int, default=64, help="runs per repetition (default 64)")
    args = parser.parse_args()
    tasks, files = _tasks(args.runs, cached_fmus())
    print(f"{len(tasks)} runs of 45 s (4 controllers x {len(tasks) // 4} operating points), best of {args.repeat}")
    list(run_serial(tasks[:2], files))  # warm-up
    serial = min(_timed(run_serial, tasks, files)[0] for _ in range(args.repeat))
    print(f"  in-process: {serial:6.2f} s for {len(tasks)} runs ({1e3 * serial / len(tasks):5.1f} ms/run, no Dask)")
    one = _on_cluster(1, tasks, files, args.repeat)
    two = _on_cluster(2, tasks, files, args.repeat)
    print(f"speed-up 2 workers / 1 worker: {one / two:.2f}x (goal >= 1.8); 2 workers / in-process: {serial / two:.2f}x")


if __name__ == "__main__":
    main()
