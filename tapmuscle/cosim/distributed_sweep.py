"""Running sweep runs: in this process, or as tasks on a dask.distributed cluster.

A run is a :class:`RunTask` (the scenario and the content digests of its two FMUs); running it
co-simulates the scenario through the FMUs (:func:`tapmuscle.cosim.master.co_simulate`, ``record="minimal"``)
and returns a :class:`RunResult` with :func:`tapmuscle.cosim.expect.scenario_metrics`. A run that raises is a
``failed`` result with the error's text; it never stops the others.

**FMUs on the workers.** Workers need not share a file system with the client: the FMU files
(:class:`FmuFiles`, a few hundred kB) are scattered to every worker once per sweep
(``Client.scatter(broadcast=True)``), and each worker process writes each file once into its own
cache folder, named by the file's SHA-256 (:meth:`FmuFiles.path`), and extracts it once
(:func:`tapmuscle.cosim.master.unpack` caches per process). A worker process keeps its FMU instances in an
:class:`~tapmuscle.cosim.master.InstancePool` and resets them (fmi2Reset) between runs instead of
instantiating anew. Workers must run the same tapmuscle version as the client (docs/sweeps.md).

Executors (:func:`run_serial`, :class:`DaskExecutor`) take the tasks and the FMU files and yield
results in the order they finish.
"""

from __future__ import annotations

import getpass
import hashlib
import logging
import os
import socket
import tempfile
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

from tapmuscle.cosim.expect import scenario_metrics
from tapmuscle.io.atomic import atomic_path
from tapmuscle.cosim.master import InstancePool, check_parameters, co_simulate
from tapmuscle.cosim.spec import FmuSpec, Scenario

__all__ = ["RunTask", "RunResult", "FmuFiles", "make_task", "execute_run", "run_serial", "DaskExecutor",
           "dask_client"]

_ROLES = (("MusclePlant", "plant"), ("AMPCController", "controller"))


@dataclass(frozen=True)
class RunTask:
    """One run to do: the scenario without FMU paths, and which FMU files it uses."""

    run_id: str
    scenario: Scenario
    fmus: tuple[tuple[str, str], ...]
    """``(("MusclePlant", sha256), ("AMPCController", sha256))``: content digests of the FMU files."""

    @property
    def fmu_tag(self) -> str:
        """Short text naming the FMU files (first 8 hex digits of each digest), for results.csv."""
        return "/".join(digest[:8] for _, digest in self.fmus)


@dataclass(frozen=True)
class RunResult:
    """What a run gives back."""

    run_id: str
    status: str
    """``ok`` or ``failed``."""
    metrics: Mapping[str, float] = field(default_factory=dict)
    """:data:`tapmuscle.cosim.expect.METRICS` (empty for a failed run)."""
    error: str = ""
    """``ExceptionType: message`` of a failed run."""
    worker: str = ""
    """``host:pid`` of the process that ran it."""
    fmu_warnings: tuple[str, ...] = ()
    """What the FMUs warned of during the run (:func:`tapmuscle.cosim.master.co_simulate`)."""


@dataclass(frozen=True)
class FmuFiles:
    """FMU files by content digest: their bytes (to ship to workers) and, where known, a local path."""

    data: Mapping[str, bytes]
    """SHA-256 hex digest -> file content."""
    names: Mapping[str, str]
    """digest -> file name (``MusclePlant.fmu``)."""
    local: Mapping[str, str] = field(default_factory=dict)
    """digest -> path of the file on the client (used when running in the client's process)."""

    @classmethod
    def read(cls, paths: Iterable[str | Path]) -> "FmuFiles":
        """Read the FMU files ``paths`` (each once)."""
        data, names, local = {}, {}, {}
        for path in {Path(p).resolve() for p in paths}:
            content = path.read_bytes()
            digest = hashlib.sha256(content).hexdigest()
            data[digest], names[digest], local[digest] = content, path.name, str(path)
        return cls(data, names, local)

    @classmethod
    def for_scenarios(cls, scenarios: Iterable[Scenario], fmus: Mapping[str, str | Path]) -> "FmuFiles":
        """The FMU files the ``scenarios`` use: their own, else ``fmus``' (:func:`make_task`)."""
        return cls.read({getattr(s, role).path or fmus[name] for s in scenarios for name, role in _ROLES})

    def digest_of(self, path: str | Path) -> str:
        """The digest of the local file ``path`` (one of those read)."""
        path = str(Path(path).resolve())
        for digest, p in self.local.items():
            if p == path:
                return digest
        raise KeyError(f"{path} is not among the FMU files read")

    def without_local(self) -> "FmuFiles":
        """The same files without the client's paths (what is shipped to workers)."""
        return FmuFiles(self.data, self.names)

    def path(self, digest: str, *, use_local: bool = True) -> Path:
        """A path of the file ``digest`` on this machine: the client's file (``use_local``) or a copy
        written once into this machine's cache folder ``$TMPDIR/tapmuscle-fmus-USER/<digest>/``."""
        if use_local and digest in self.local and Path(self.local[digest]).is_file():
            return Path(self.local[digest])
        target = _cache_root() / digest / self.names[digest]
        if _WRITTEN.get(digest) == target and target.is_file():
            return target  # checked by this process already
        if not target.is_file() or hashlib.sha256(target.read_bytes()).hexdigest() != digest:
            # atomic: other worker processes see the whole file or none
            with atomic_path(target) as tmp:
                tmp.write_bytes(self.data[digest])
        _WRITTEN[digest] = target
        return target


_WRITTEN: dict[str, Path] = {}
"""digest -> the cached copy this process wrote or checked (so later runs skip the hash)."""


def _cache_root() -> Path:
    return Path(tempfile.gettempdir()) / f"tapmuscle-fmus-{getpass.getuser()}"


def make_task(run_id: str, scenario: Scenario, fmus: Mapping[str, str | Path], files: FmuFiles) -> RunTask:
    """The task of running ``scenario``: its own FMU files if it names them, else ``fmus``'.

    Raises ScenarioError if the scenario sets a parameter the FMU does not have, or a value outside its
    declared range (before anything runs).
    """
    check_parameters(scenario, fmus)
    digests = []
    for name, role in _ROLES:
        spec: FmuSpec = getattr(scenario, role)
        digests.append((name, files.digest_of(spec.path or fmus[name])))
    plain = replace(scenario, plant=replace(scenario.plant, path=None),
                    controller=replace(scenario.controller, path=None))
    return RunTask(run_id, plain, tuple(digests))


def _where() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def execute_run(task: RunTask, files: FmuFiles, pool: InstancePool | None = None, *,
                use_local: bool = True) -> RunResult:
    """Run one task; any exception becomes a ``failed`` result with its text."""
    try:
        paths = {name: files.path(digest, use_local=use_local) for name, digest in task.fmus}
        said: list[str] = []
        cols = co_simulate(task.scenario, paths, record="minimal", pool=pool, fmu_warnings=said)
        return RunResult(task.run_id, "ok", scenario_metrics(task.scenario, cols), worker=_where(),
                         fmu_warnings=tuple(said))
    except Exception as exc:  # noqa: BLE001 - a failing run is recorded, the sweep goes on
        text = " | ".join(str(exc).splitlines()) or repr(exc)
        return RunResult(task.run_id, "failed", error=f"{type(exc).__name__}: {text}", worker=_where())


def run_serial(tasks: Sequence[RunTask], files: FmuFiles) -> Iterator[RunResult]:
    """Run ``tasks`` one after the other in this process (FMU instances reused between runs)."""
    pool = InstancePool()
    try:
        for task in tasks:
            yield execute_run(task, files, pool)
    finally:
        pool.close()


# ------------------------------------------------------------------------------------------- Dask
_WORKER_POOL: list[InstancePool] = []


def _worker_run(task: RunTask, files: FmuFiles) -> RunResult:
    """The Dask task: runs on a worker, with that worker process's instance pool."""
    if not _WORKER_POOL:
        _WORKER_POOL.append(InstancePool())
    return execute_run(task, files, _WORKER_POOL[0], use_local=False)


class DaskExecutor:
    """Runs tasks on a ``distributed.Client``'s cluster, yielding results as they finish.

    The FMU files go to every worker once (scattered, broadcast); one Dask task per run (``client.map``).
    A task whose worker died (``KilledWorker`` after Dask's retries) or that was cancelled is a
    ``failed`` result. Leaving the iteration early cancels the tasks not yet finished.
    """

    def __init__(self, client: Any) -> None:
        self.client = client

    def __call__(self, tasks: Sequence[RunTask], files: FmuFiles) -> Iterator[RunResult]:
        from distributed import as_completed

        if not tasks:
            return
        shipped = self.client.scatter(files.without_local(), broadcast=True, hash=False)
        tag = uuid.uuid4().hex[:8]
        submitted = self.client.map(_worker_run, tasks, [shipped] * len(tasks), pure=False,
                                    key=[f"tapmuscle-run-{task.run_id}-{tag}" for task in tasks])
        futures = dict(zip(submitted, tasks))
        try:
            # results gathered in batches by the event loop; errors returned, not raised
            for future, value in as_completed(submitted, with_results=True, raise_errors=False):
                task = futures.pop(future)
                if future.status == "finished":
                    result = value
                else:  # worker died (KilledWorker), cancelled: recorded as failed
                    result = RunResult(task.run_id, "failed", error=f"{type(value).__name__}: {value}")
                future.release()
                yield result
        finally:
            self.client.cancel(list(futures))
            shipped.release()


@contextmanager
def dask_client(workers: int, scheduler: str | None = None, *, wait_s: float = 60.0) -> Iterator[Any]:
    """A ``distributed.Client``: on a new local cluster of ``workers`` single-threaded worker processes,
    or connected to the running scheduler at ``scheduler`` (``tcp://host:port``), which must get at
    least one worker within ``wait_s`` seconds. Raises OSError/TimeoutError if it cannot connect.
    """
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        client = Client(scheduler, timeout=f"{wait_s}s")
        try:
            client.wait_for_workers(1, timeout=wait_s)
            yield client
        finally:
            client.close()
        return
    # no dashboard, so no use for the workers' statistical profiler (a thread sampling every 10 ms)
    with dask.config.set({"distributed.worker.profile.enabled": False}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                               scheduler_kwargs={"dashboard_address": ":0"},  # no fixed port 8787
                               silence_logs=logging.ERROR)
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()
