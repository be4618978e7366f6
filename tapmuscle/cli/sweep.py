"""``tapmuscle sweep`` and ``tapmuscle check``: many scenario runs, locally or on a Dask cluster
(docs/sweeps.md). :func:`register` adds the two subcommands to the ``tapmuscle`` parser."""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from tapmuscle.cli.arguments import integer_at_least, number_within, output_path
from tapmuscle.errors import UsageError
from tapmuscle.plots.figure_formats import FIGURE_FORMATS

__all__ = ["register"]


def _fmus(fmu_dir: str | None) -> dict[str, Path]:
    """The FMUs of ``--fmu-dir``, or those built from the sources (cached)."""
    from build_scripts.build_fmus import FMUS, cached_fmus

    if not fmu_dir:
        return cached_fmus()
    fmus = {name: Path(fmu_dir) / f"{name}.fmu" for name in FMUS}
    missing = [p.name for p in fmus.values() if not p.is_file()]
    if missing:
        raise UsageError(f"--fmu-dir {fmu_dir}: {', '.join(missing)} missing (tapmuscle build --out DIR)")
    return fmus


#: Exit status of ``sweep`` and ``check`` when the cluster was lost mid-way (the scheduler's connection,
#: or every worker for ``--timeout`` seconds): the finished runs kept, a rerun goes on.
CLUSTER_LOST = 3


def _cluster_options(args: argparse.Namespace, default_workers: int) -> None:
    """``--workers``, ``--scheduler`` and ``--timeout`` as one choice of where to run: a local cluster
    (``--workers``, default ``default_workers``) or the cluster of ``--scheduler`` (``--timeout``)."""
    if args.scheduler and args.workers is not None:
        raise UsageError(f"--workers {args.workers} and --scheduler exclude each other: --workers starts a local "
                         "cluster (or, 0, runs in this process), --scheduler runs on the cluster at its address")
    if args.timeout is not None and not args.scheduler:
        raise UsageError(f"--timeout {args.timeout:g} is for --scheduler (the wait for the scheduler and its workers); "
                         "a local cluster is started and waited for without one")
    args.timeout = 60.0 if args.timeout is None else args.timeout
    args.workers = default_workers if args.workers is None else args.workers


def _local_workers(args: argparse.Namespace, n_runs: int) -> None:
    """A local cluster of at most one worker per run: a worker process costs seconds to start and
    memory, and one beyond the runs has nothing to do; beyond the CPUs they share the cores."""
    if args.scheduler or not args.workers:
        return
    cpus = os.cpu_count() or 1
    if args.workers > cpus:
        print(f"--workers {args.workers} on {cpus} CPUs: the workers share the cores (no run finishes sooner)",
              file=sys.stderr)
    args.workers = max(1, min(args.workers, n_runs))


def _dashboard(client: Any) -> str | None:
    """The link to the cluster's dashboard, where the runs can be watched, if it answers within 2 s
    (a scheduler without bokeh, or started with ``--no-dashboard``, has the link but not the page)."""
    import urllib.request

    try:
        link = client.dashboard_link
        with urllib.request.urlopen(link, timeout=2.0) as page:  # noqa: S310 - the scheduler's own http link
            return link if page.status == 200 else None
    except Exception:  # noqa: BLE001 - a fact to print, never a reason to stop
        return None


def _executor(args: argparse.Namespace, stack: ExitStack) -> Any:
    """In this process (``--workers 0`` without ``--scheduler``) or on Dask (a local cluster of
    ``--workers`` processes, or the cluster of ``--scheduler``)."""
    from tapmuscle.cosim.distributed_sweep import ClusterError, DaskExecutor, check_workers, dask_client, run_serial

    if not args.scheduler and args.workers == 0:
        return run_serial
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise UsageError("needs dask.distributed: pip install 'tapmuscle[dist]' (or run in this process with "
                         "--workers 0)") from None
    where = f"--scheduler {args.scheduler}" if args.scheduler else f"local cluster of {args.workers} workers"
    if args.scheduler:
        # a lost connection is said in one line (ClusterError), not as the client's log of tracebacks nor
        # the comms' information, which logs one too ("distributed.batched - INFO - Batched Comm Closed"),
        # also while the client closes (restored after it: the stack unwinds in reverse)
        for name, level in (("distributed.client", logging.CRITICAL), ("distributed", logging.WARNING)):
            log = logging.getLogger(name)
            stack.callback(log.setLevel, log.level)
            log.setLevel(level)
    try:
        client = stack.enter_context(dask_client(args.workers, args.scheduler, wait_s=args.timeout))
        # the workers of a cluster of one's own may run other code; the command's own run this process's
        refused = check_workers(client) if args.scheduler else {}
    except ClusterError as exc:  # what is wrong, said
        raise UsageError(f"{where}: {exc}") from None
    except OSError as exc:  # includes TimeoutError
        raise UsageError(f"{where}: cannot start or connect: {exc}") from None
    if not args.quiet:
        workers = len(client.scheduler_info().get("workers", {}))
        dashboard = _dashboard(client) if args.scheduler else None
        print(f"Dask: {workers} workers at {client.scheduler.address}" + (f", dashboard {dashboard}" if dashboard else "")
              + (f"; {len(refused)} of them given no run (below)" if refused else ""), file=sys.stderr)
    # the command's own cluster: one run per worker thread at a time; a scheduler of one's own gets them
    # all (its adaptive scaling sees the backlog)
    return DaskExecutor(client, no_worker_s=args.timeout, one_run_per_thread=not args.scheduler, refused=refused)


# ------------------------------------------------------------------------------------------ sweep
def _cmd_sweep(args: argparse.Namespace) -> int:
    from tapmuscle.cosim import ScenarioError
    from tapmuscle.cosim.sweep import load_sweep
    from tapmuscle.cosim.distributed_sweep import ClusterError
    from tapmuscle.cosim.sweep_run import ResultsLog, result_columns, run_sweep, summary_markdown

    from tapmuscle.progress import Progress

    try:
        sweep = load_sweep(args.sweep)
    except ScenarioError as exc:
        raise UsageError(str(exc)) from None
    _cluster_options(args, os.cpu_count() or 1)
    _local_workers(args, len(sweep.runs))
    fmus = _fmus(args.fmu_dir)
    out = Path(args.out)
    if not args.quiet:
        print(f"tapmuscle sweep: {sweep.name}, {len(sweep.runs)} runs -> {os.path.join(out, '')}")
    with ExitStack() as stack:
        try:
            ResultsLog(out / "results.csv", result_columns(sweep)).latest()  # another sweep's file: refuse early
            execute = _executor(args, stack)
            progress = Progress("sweep", enabled=not args.quiet)
            progress.why_waiting = getattr(execute, "waiting", None)  # a cluster left without workers
            report = run_sweep(sweep, out, fmus, execute, plots=not args.no_plots, progress=progress,
                               figure_format=args.figure_format)
        except ScenarioError as exc:
            raise UsageError(str(exc)) from None
        except ClusterError as exc:
            print(f"tapmuscle sweep: the cluster was lost: {exc}", file=sys.stderr)
            return CLUSTER_LOST
        except KeyboardInterrupt:
            results = out / "results.csv"
            print(f"\ninterrupted: {f'finished runs are in {results}' if results.is_file() else 'no run had finished'}; "
                  "rerun the same command to go on", file=sys.stderr)
            return 130
    text = summary_markdown(sweep, report.rows)
    start = text.index("## Per method")
    print(text[start:text.find("\n\n", text.index("|", start))].strip())
    print(f"{report.total} runs: {report.skipped} already done, {report.ran} run now; {report.failed} failed, "
          f"{report.violated} missed their expectations")
    if report.other_rows:
        print(f"results.csv also keeps {report.other_rows} rows whose run ids this sweep does not have (an earlier "
              "version of its file, or runs of an earlier tapmuscle, whose ids were made otherwise; after its own, "
              "not summarised)")
    if report.fmu_warnings:
        runs = len({rid for rid, _ in report.fmu_warnings})
        print(f"warning: the FMUs logged {len(report.fmu_warnings)} warnings in {runs} runs (summary.md, "
              f"'FMU warnings'); the first, run {report.fmu_warnings[0][0]}: {report.fmu_warnings[0][1]}",
              file=sys.stderr)
    print(f"wrote {Path(out) / 'results.csv'}, {Path(out) / 'summary.md'}"
          + ("" if args.no_plots else f" and {Path(out) / ('*.' + args.figure_format)}"))
    return 1 if report.failed or report.violated else 0


# ------------------------------------------------------------------------------------------ check
def _cmd_check(args: argparse.Namespace) -> int:
    from tapmuscle.cosim import ScenarioError
    from tapmuscle.cosim.check import CollectionError, collect_cases, evaluate, junit_xml, result_table
    from tapmuscle.cosim.distributed_sweep import ClusterError, FmuFiles, RunResult, make_task, run_serial

    from tapmuscle.progress import Progress
    from tapmuscle.io.recording import atomic_write_text

    _cluster_options(args, 0)
    # As pytest does with a collection error: nothing runs, every bad file is named, and the JUnit
    # report says so too (a CI's test view is where the failure is looked for).
    errors: list[CollectionError] = []
    cases, skipped = collect_cases(args.paths, errors=errors)
    if errors:
        _refuse_files(args, errors, "could not be read")
    if not cases:
        if args.junit:
            atomic_write_text(args.junit, junit_xml([]))
        raise UsageError(f"no scenario with an [expect] table under {', '.join(args.paths)}")
    fmus = _fmus(args.fmu_dir)
    print(f"tapmuscle check: {len(cases)} scenarios with expectations"
          + (f" ({len(skipped)} files without [expect] skipped)" if skipped else ""))
    progress = Progress("check", enabled=not args.quiet)
    with ExitStack() as stack:
        try:
            files = FmuFiles.for_scenarios((c.scenario for c in cases), fmus)
        except ScenarioError as exc:
            if args.junit:
                atomic_write_text(args.junit, junit_xml([], errors=[CollectionError("FMUs", str(exc))]))
            raise UsageError(str(exc)) from None
        # every file's parameters checked against the FMUs before anything runs, each bad one named
        # under its own file (a sweep's runs that share a bad value once)
        tasks, bad = [], {}
        for i, case in enumerate(cases):
            try:
                tasks.append(make_task(str(i), case.scenario, fmus, files))
            except ScenarioError as exc:
                said = bad.setdefault(case.file, [])
                if str(exc) not in said:
                    said.append(str(exc))
        if bad:
            _refuse_files(args, [CollectionError(file, "; ".join(said)) for file, said in bad.items()],
                          "set FMU parameters wrongly")
        _local_workers(args, len(tasks))
        execute = _executor(args, stack)
        progress.why_waiting = getattr(execute, "waiting", None)  # a cluster left without workers
        runs, said = {}, {"pass": 0, "fail": 0, "error": 0}

        serial = execute is run_serial  # the cases one after the other, in their order

        def report_so_far() -> None:
            # the JUnit report as the runs finish: a process that an FMU crashes (in this process,
            # --workers 0) leaves a report that names the case it was running, not none
            if args.junit:
                running = next((i for i in range(len(cases)) if i not in runs), None) if serial else None
                atomic_write_text(args.junit, junit_xml([
                    evaluate(case, runs.get(i) or RunResult(str(i), "failed", error=RUNNING if i == running else
                                                            NOT_STARTED if serial else UNFINISHED))
                    for i, case in enumerate(cases)]))

        try:
            report_so_far()
            for run in execute(tasks, files):
                runs[int(run.run_id)] = run
                said[evaluate(cases[int(run.run_id)], run).status] += 1  # counted as the final table counts
                report_so_far()
                progress(len(runs), len(tasks), f"{said['pass']} passed, {said['fail']} failed, {said['error']} "
                                                f"errors, {len(tasks) - len(runs)} remaining")
        except ClusterError as exc:
            # a check keeps no results between commands: a rerun runs every case again
            said_lost = (f"{exc.cause} ({exc.finished} of {len(tasks)} runs finished): {exc.remedy}, and rerun the "
                         "check (it runs every case again)" if exc.cause else str(exc))
            print(f"tapmuscle check: the cluster was lost: {said_lost}" + (
                  f"; {args.junit} holds the runs that finished, the others as errors (did not finish)"
                  if args.junit else ""), file=sys.stderr)
            return CLUSTER_LOST
        except KeyboardInterrupt:
            print("\ninterrupted" + (f": {args.junit} holds the runs that finished, the others as not finished"
                                     if args.junit else ""), file=sys.stderr)
            return 130
    results = [evaluate(case, runs[i]) for i, case in enumerate(cases)]
    print(result_table(results), end="")
    if args.junit:
        atomic_write_text(args.junit, junit_xml(results))
        print(f"wrote {args.junit}")
    if args.out:
        _keep_what_did_not_pass(results, Path(args.out), fmus)
    return 0 if all(r.status == "pass" for r in results) else 1


#: A check case's error in the JUnit report while it has not finished: what the report says of the
#: cases a check on Dask ended without, of the case a check in its own process (``--workers 0``)
#: was running when it ended (an FMU that crashed the process), and of the cases after that one.
UNFINISHED = ("did not finish: the check ended before this run's result (an FMU that crashed the process, "
              "a kill, a time limit); run it alone with tapmuscle run, or the check with --workers N")
RUNNING = ("did not finish: the check ended while it ran this case, the one running in its process (an FMU "
           "that crashed the process, a kill, a time limit); run it alone with tapmuscle run, or the check "
           "with --workers N, where a crash ends a worker, not the check")
NOT_STARTED = "did not finish: not started, the check ended in an earlier case (the one still running, above)"


def _refuse_files(args: argparse.Namespace, errors: list, what: str) -> None:
    """Stop the check before anything runs, as pytest does on a collection error: every bad file named
    on stderr (the last in the UsageError), and each an error case of its own in the JUnit report."""
    from tapmuscle.cosim.check import junit_xml
    from tapmuscle.io.recording import atomic_write_text

    if args.junit:
        atomic_write_text(args.junit, junit_xml([], errors=errors))
    for error in errors[:-1]:
        print(f"error: {error.message}", file=sys.stderr)
    raise UsageError(errors[-1].message + (f" ({len(errors)} files {what}; nothing was run)" if len(errors) > 1
                                           else " (nothing was run)"))


def _keep_what_did_not_pass(results: list, out: Path, fmus: dict[str, Path]) -> None:
    """``check --out``: each case that did not pass run again here, its files written into
    ``out/<file>/<case>/`` as ``tapmuscle run`` writes them (on one machine the run is the same bit
    for bit, wherever the check ran it)."""
    from tapmuscle.cosim import ScenarioError, run_scenario

    used: set[Path] = set()
    for result in results:
        if result.status == "pass":
            continue
        case = result.case
        stem = Path(case.file).stem  # a file's name is one folder name already, unless it is all dots
        folder = out / (stem if stem.strip(".") else "file") / _component(case.name, "case")
        n = 1
        while folder in used:  # two cases of one name
            n += 1
            folder = folder.with_name(f"{folder.name}-{n}")
        used.add(folder)
        try:
            run_scenario(case.scenario, folder, fmus)
            print(f"wrote {folder} ({result.status}: result.csv, summary.json, the PNGs)")
        except ScenarioError as exc:
            for empty in (folder, folder.parent):  # as said: nothing written, no empty folders either
                if empty != out and empty.is_dir() and not any(empty.iterdir()):
                    empty.rmdir()
            print(f"{folder}: the run failed again, nothing written: {exc}", file=sys.stderr)


def _component(name: str, fallback: str) -> str:
    """``name`` as one folder name under ``--out``: other characters than letters, digits and
    ``._=+-`` as ``_``, and never ``.`` or ``..`` (a case named so, or a file ``...toml``, would put its
    outputs above ``--out``, replacing what is there)."""
    safe = re.sub(r"[^A-Za-z0-9._=+-]+", "_", name).strip("_")
    return fallback if safe.strip(".") == "" else safe


# ------------------------------------------------------------------------------------------ parser
def _common(p: argparse.ArgumentParser, default_workers: str) -> None:
    p.add_argument("--workers", type=integer_at_least("--workers", 0, 4096), default=None,
                   help="worker processes of a local Dask cluster (default: "
                        + ("the number of CPUs" if default_workers == "cpus" else "0")
                        + "); 0 runs everything in this process, without Dask")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run on the Dask cluster of this scheduler instead of a local one (docs/sweeps.md)")
    p.add_argument("--timeout", type=number_within("--timeout", 1e-3, 86400.0), default=None, metavar="S",
                   help="with --scheduler: seconds to wait for the scheduler and its first worker, and for a worker "
                        "when none is left mid-sweep (default 60)")
    p.add_argument("--fmu-dir", help="folder with MusclePlant.fmu and AMPCController.fmu "
                                     "(default: built from the sources, cached)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def register(sub: Any) -> None:
    """Add ``sweep`` and ``check`` to the subparsers ``sub`` of the ``tapmuscle`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subparsers of the ``tapmuscle`` parser.
    """
    sw = sub.add_parser("sweep", help="run a grid / Monte-Carlo sweep of scenarios (locally or on Dask)",
                        description="Run every scenario of a sweep file (a base scenario with a grid and/or "
                                    "Monte-Carlo sample over its fields; tapmuscle/cosim/sweep.py, docs/sweeps.md) "
                                    "through the FMUs on a Dask cluster; write DIR/results.csv as runs finish "
                                    "(a rerun skips finished runs), DIR/summary.md and PNGs. Exit status 1 if "
                                    "a run failed or missed its expectations.")
    sw.add_argument("sweep", help="sweep TOML file (e.g. scenarios/sweeps/robustness_mc.toml)")
    sw.add_argument("--out", type=output_path("--out", "folder"), required=True,
                    help="output folder (rerun into the same folder to resume)")
    _common(sw, "cpus")
    sw.add_argument("--no-plots", action="store_true", help="no figures")
    sw.add_argument("--figure-format", choices=FIGURE_FORMATS, default="png",
                    help="format of the figures: png (default), or pdf or svg for a publication; their data is "
                         "results.csv")
    sw.set_defaults(func=_cmd_sweep)

    ck = sub.add_parser("check", help="run the scenarios that carry [expect] bounds and report pass/fail (CI)",
                        description="Run every scenario file, and every run of a sweep file, with an [expect] "
                                    "table under PATH (files or folders); print a pass/fail table, optionally "
                                    "write JUnit XML; exit status 1 on any missed expectation or failed run.")
    ck.add_argument("paths", nargs="+", metavar="PATH", help="scenario/sweep files or folders (searched for *.toml)")
    ck.add_argument("--junit", type=output_path("--junit", "file"), metavar="FILE", help="write a JUnit XML report (for CI test reports)")
    ck.add_argument("--out", type=output_path("--out", "folder"), metavar="DIR",
                    help="run each case that did not pass again in this process and write its result.csv, "
                         "summary.json and PNGs into DIR/<file>/<case>/ (CI artefacts of a failure)")
    _common(ck, "zero")
    ck.set_defaults(func=_cmd_check)
