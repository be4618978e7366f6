"""Running sweep runs: in this process, or as tasks on a dask.distributed cluster.

A run is a :class:`RunTask` (the scenario and the content digests of its two FMUs); running it
co-simulates the scenario through the FMUs (:func:`tapmuscle.cosim.master.co_simulate`, ``record="minimal"``)
and returns a :class:`RunResult` with :func:`tapmuscle.cosim.expect.scenario_metrics`. A run that raises is a
``failed`` result with the error's text; it never stops the others.

**FMUs on the workers.** Workers need not share a file system with the client: the FMU files
(:class:`FmuFiles`, a few hundred kB) go to the cluster once per sweep as plain data, the input of
one task the runs depend on (not scattered: the scheduler keeps its input, so the files outlive the
loss of every worker that held them, and a worker that cannot import tapmuscle fails its own runs, not
the files' transfer), and each worker process writes each file once into its own
cache folder, named by the file's SHA-256 (:meth:`FmuFiles.path`), and extracts it once
(:func:`tapmuscle.cosim.master.unpack` caches per process). A worker process keeps its FMU instances in an
:class:`~tapmuscle.cosim.master.InstancePool` and resets them (fmi2Reset) between runs instead of
instantiating anew. Workers must run the client's tapmuscle sources: checked before the first run
(:func:`check_workers`) and, by a worker that joins later, before each run it is given (a run refused
goes to another worker: :class:`DaskExecutor`; docs/sweeps.md).

Executors (:func:`run_serial`, :class:`DaskExecutor`) take the tasks and the FMU files and yield
results in the order they finish.
"""

from __future__ import annotations

import getpass
import hashlib
import logging
import math
import os
import signal
import socket
import tempfile
import threading
import time
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

from build_scripts.own_folder import own_folder, remove_foreign
from fmu_plant.user_warning import warn_at_caller
from tapmuscle.cosim.expect import scenario_metrics
from tapmuscle.io.atomic import atomic_path
from tapmuscle.cosim.master import InstancePool, check_parameters, co_simulate
from tapmuscle.cosim.spec import FmuSpec, Scenario
from tapmuscle.cosim.worker_start import check_workers_can_start

__all__ = ["RunTask", "RunResult", "FmuFiles", "make_task", "execute_run", "run_serial", "DaskExecutor",
           "ClusterError", "ClusterWarning", "check_workers", "dask_client", "probe_scheduler"]

_ROLES = (("MusclePlant", "plant"), ("AMPCController", "controller"))


@dataclass(frozen=True)
class RunTask:
    """One run to do: the scenario without FMU paths, and which FMU files it uses."""

    run_id: str
    """The run's id (the sweep run's ``run_id``)."""
    scenario: Scenario
    """The scenario, its FMU paths removed (``fmus`` names the files)."""
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
    """The id of the run (:attr:`RunTask.run_id`)."""
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
            return target  # checked by this process already: every run after the first takes this way
        _private_folder(_private_folder(_cache_root()) / digest)
        # what another user left there while the folder was open to them (a link to a file of this
        # user's, a file of theirs) is removed, not written through, and the FMU written anew
        if remove_foreign(target) or not target.is_file() or hashlib.sha256(target.read_bytes()).hexdigest() != digest:
            # atomic: other worker processes see the whole file or none
            with atomic_path(target) as tmp:
                tmp.write_bytes(self.data[digest])
        _WRITTEN[digest] = target
        return target


_WRITTEN: dict[str, Path] = {}
"""digest -> the cached copy this process wrote or checked (so later runs skip the hash)."""


def _cache_root() -> Path:
    return Path(tempfile.gettempdir()) / f"tapmuscle-fmus-{getpass.getuser()}"


def _private_folder(folder: Path) -> Path:
    """``folder``, this user's alone (:func:`build_scripts.own_folder.own_folder`): its name in a shared
    temporary folder is predictable, and another user who made it, or a link in its place, could
    swap a checked FMU for one whose code then runs as this user."""
    return own_folder(folder, closed=0o077, what="the sweep's FMU folder",
                      remedy="Remove it, or set TMPDIR to a folder of your own, and run again")


def make_task(run_id: str, scenario: Scenario, fmus: Mapping[str, str | Path], files: FmuFiles) -> RunTask:
    """The task of running ``scenario``: its own FMU files if it names them, else ``fmus``'.

    Raises ScenarioError if the scenario sets a parameter the FMU does not have, or a value outside its
    declared range (before anything runs).

    Parameters
    ----------
    run_id : str
        The run's id.
    scenario : Scenario
        The scenario to run.
    fmus : mapping of str to path
        The default FMU files by model name (``"MusclePlant"``, ``"AMPCController"``), for a
        scenario that names none.
    files : FmuFiles
        The sweep's FMU files, which give each file's digest.
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
    """Run one task; any exception becomes a ``failed`` result with its text.

    Parameters
    ----------
    task : RunTask
        The run to do.
    files : FmuFiles
        The FMU files, by digest.
    pool : InstancePool, optional
        Idle FMU instances to reuse; None (default): new instances.
    use_local : bool, optional
        Use the client's own FMU files where they exist (True, default), else copies in this
        machine's cache folder.
    """
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
    """Run ``tasks`` one after the other in this process (FMU instances reused between runs).

    Parameters
    ----------
    tasks : sequence of RunTask
        The runs, in order.
    files : FmuFiles
        The FMU files, by digest.
    """
    pool = InstancePool()
    try:
        for task in tasks:
            yield execute_run(task, files, pool)
    finally:
        pool.close()


# ------------------------------------------------------------------------------------------- Dask
_WORKER_POOL: list[InstancePool] = []


#: :attr:`RunResult.status` of a run a worker would not do, its sources not the client's: never a
#: sweep's result (:class:`DaskExecutor` sends the run to another worker).
REFUSED = "refused"

_CODE_HERE: list[tuple[str, str]] = []


def _code_here() -> tuple[str, str]:
    """:func:`_code_and_home` of this process, taken once: what a worker is checked by and runs with."""
    if not _CODE_HERE:
        _CODE_HERE.append(_code_and_home())
    return _CODE_HERE[0]


def _worker_run(task: RunTask, files: Mapping[str, Any]) -> RunResult:
    """The Dask task: runs on a worker, with that worker process's instance pool; ``files`` is an
    :class:`FmuFiles`' ``data`` and ``names`` as a plain dict, and ``client_code``, the client's
    :func:`_code_here`. A worker whose sources are not the client's (one that joined after
    :func:`check_workers`) runs nothing: a :data:`REFUSED` result whose ``worker`` is its address."""
    client_code = files.get("client_code")
    if client_code is not None and _code_here()[0] != client_code[0]:
        from distributed import get_worker

        address = get_worker().address
        return RunResult(task.run_id, REFUSED, error=_other_sources(f"worker {address}", _code_here(), client_code),
                         worker=address)
    if not _WORKER_POOL:
        _WORKER_POOL.append(InstancePool())
    return execute_run(task, FmuFiles(data=files["data"], names=files["names"]), _WORKER_POOL[0], use_local=False)


def _error_text(value: Any) -> str:
    """``Type: message`` of what an erred Dask future gave back (the exception, or Dask's
    ``(type, exception, traceback)`` of a task whose worker died)."""
    if isinstance(value, tuple) and len(value) == 3 and isinstance(value[1], BaseException):
        value = value[1]
    if type(value).__name__ == "KilledWorker":
        return (f"KilledWorker: every worker that ran it died (Dask's allowed failures spent): {value.args[0] if value.args else value}")
    return f"{type(value).__name__}: {value}"


class DaskExecutor:
    """Runs tasks on a ``distributed.Client``'s cluster, yielding results as they finish.

    The FMU files go to the cluster once, as the input of a task the runs depend on (module
    docstring); one Dask task per run. A task whose worker died (``KilledWorker`` after Dask's
    retries) or that was cancelled is a ``failed`` result. A cluster lost mid-sweep is not a run's
    failure: the scheduler's connection lost, or no worker connected for ``no_worker_s`` seconds
    (every worker stopped, none restarted), raises :class:`ClusterError`, after the results yielded
    so far. Leaving the iteration early cancels the tasks not yet finished. No run is sent to the
    workers of ``refused`` (what :func:`check_workers` found); a worker whose tapmuscle sources are
    not the client's and that joined later refuses each run, which is sent again, to the workers
    that have not refused one (:attr:`refused`). Each such worker is named once in a
    :class:`ClusterWarning`.

    Parameters
    ----------
    client : distributed.Client
        The cluster's client.
    no_worker_s : float
        How long [s] the cluster may be without a worker before the sweep stops (above).
    one_run_per_thread : bool
        The command's own local cluster, whose scheduler holds back what it would queue on a worker
        (:func:`dask_client`: ``worker-saturation`` 1.0): a task waiting on a worker whose run's FMU
        ends the process counts as a suspect of the crash and fails as ``KilledWorker`` once the
        crashing run has spent Dask's retries. Dask holds tasks back only in a sweep of more than
        twice as many runs as worker threads; a smaller one is submitted one run per thread, the next
        as one finishes (a round trip through this client per run, which the scheduler's own queue
        saves a larger sweep). False (a cluster of one's own): every run at once, so that an adaptive
        cluster sees the backlog and grows.
    refused : mapping of str to str, optional
        Workers to send no run to, by address: why (what :func:`check_workers` returns), each warned
        of (:class:`ClusterWarning`).
    """

    def __init__(self, client: Any, *, no_worker_s: float = 60.0, one_run_per_thread: bool = False,
                 refused: Mapping[str, str] | None = None) -> None:
        self.client = client
        self.no_worker_s = no_worker_s
        self.one_run_per_thread = one_run_per_thread
        self.refused: dict[str, str] = {}
        """Workers no run is sent to, by address: why (what :func:`check_workers` found, or a worker
        that joined after it and refused a run, its sources not the client's)."""
        for address, why in (refused or {}).items():
            self._refuse(RunResult("", REFUSED, error=why, worker=address), joined_later=False)
        self._watch: _ClusterWatch | None = None

    def waiting(self) -> str | None:
        """What the sweep waits on where it is a cluster without a worker (``"no worker connected to
        the scheduler for 12 s; the sweep stops at 60 s"``), for a progress report; None otherwise."""
        watch = self._watch
        alone = watch.alone_s() if watch is not None else None
        if alone is None:
            return None
        who = "no worker with the client's tapmuscle sources" if self.refused else "no worker"
        return f"{who} connected to the scheduler for {alone:.0f} s; the sweep stops at {self.no_worker_s:g} s"

    def ship(self, files: FmuFiles, tag: str) -> Any:
        """The future of ``files`` on the cluster, what :func:`_worker_run` takes (module docstring)."""
        # dict, a builtin: the files' task runs on any worker, whatever it can import (no client paths)
        return self.client.submit(dict, {"data": dict(files.data), "names": dict(files.names),
                                         "client_code": _code_here()}, pure=False, key=f"tapmuscle-fmus-{tag}")

    def _usable(self) -> dict[str, int]:
        """The connected workers that have not refused a run, by address, with their threads (none
        where the connection went while asking: the cluster watch says so)."""
        try:
            return {w: n for w, n in self.client.nthreads().items() if w not in self.refused}
        except Exception:  # noqa: BLE001
            return {}

    def _threads(self) -> int:
        """The usable workers' threads."""
        return sum(self._usable().values())

    def __call__(self, tasks: Sequence[RunTask], files: FmuFiles) -> Iterator[RunResult]:
        from distributed import as_completed

        if not tasks:
            return
        tag = uuid.uuid4().hex[:8]
        shipped = self.ship(files, tag)
        waiting = list(tasks)  # not submitted yet
        futures: dict[Any, RunTask] = {}
        refusals: dict[str, int] = {}  # run id -> times a worker refused it
        pending = as_completed([], with_results=True, raise_errors=False)
        # Dask's own queue (root-ish tasks: a group of more than twice the cluster's threads) or ours
        windowed = self.one_run_per_thread and len(tasks) <= 2 * self._threads()

        def submit() -> None:
            usable = self._usable() if self.refused or windowed else {}
            if self.refused and not usable:
                return  # every worker has other sources: the runs wait for one that has the client's
            batch = waiting[:max(sum(usable.values()) - len(futures), 0)] if windowed else waiting[:]
            if batch:
                del waiting[:len(batch)]
                # once a worker refused: the others only, as Dask would send it run after run (it
                # finishes them at once); loose, so that a run whose every listed worker left goes to
                # one that joined since (and comes back here if that one refuses it too)
                where = {"workers": sorted(usable), "allow_other_workers": True} if self.refused else {}
                # a run sent again is a new task: a key of its own
                submitted = self.client.map(_worker_run, batch, [shipped] * len(batch), pure=False, **where,
                                            key=[f"tapmuscle-run-{task.run_id}-{tag}" + (f"-{refusals[task.run_id]}" if
                                                 refusals.get(task.run_id) else "") for task in batch])
                futures.update(zip(submitted, batch))
                pending.update(submitted)

        watch = self._watch = _ClusterWatch(self.client, self.no_worker_s, len(tasks), self.refused)
        try:
            submit()
            submitted_at = time.monotonic()
            # results gathered in batches by the event loop; errors returned, not raised
            while futures or waiting:
                batch = pending.next_batch(block=False) if futures else []
                if not batch:
                    watch.check(len(futures) + len(waiting))  # nothing finished: still a cluster to finish it?
                    if waiting and time.monotonic() - submitted_at >= 1.0:  # a worker (re)started
                        submit()
                        submitted_at = time.monotonic()
                    # a worker waits for the next run in a windowed sweep: looked for often
                    time.sleep(0.005 if futures and waiting else 0.05)
                    continue
                for future, value in batch:
                    task = futures.pop(future)
                    if isinstance(value, RunResult) and value.status == REFUSED:
                        self._refuse(value)
                        future.release()
                        refusals[task.run_id] = refusals.get(task.run_id, 0) + 1
                        waiting.insert(0, task)  # to a worker with the client's sources
                        continue
                    # by what came back, not the future's status: a worker that dies after a run
                    # finished (another run crashed it) changes the status of a result already here
                    if isinstance(value, RunResult):
                        result = value
                    else:  # worker died (KilledWorker), cancelled: recorded as failed
                        watch.check(len(futures) + len(waiting) + 1, at_once=True)  # unless the scheduler is gone
                        result = RunResult(task.run_id, "failed", error=_error_text(value))
                    future.release()
                    yield result
                if waiting:
                    submit()
                    submitted_at = time.monotonic()
        finally:
            self._watch = None
            self.client.cancel(list(futures))
            shipped.release()

    def _refuse(self, refusal: RunResult, joined_later: bool = True) -> None:
        """Send no more runs to the worker of ``refusal``, and say so once (a warning)."""
        if refusal.worker not in self.refused:
            self.refused[refusal.worker] = refusal.error
            when = "; it joined after the sweep's check of the workers" if joined_later else ""
            warn_at_caller(f"{refusal.error}{when}: no run is sent to it, the others run them (docs/sweeps.md, "
                           "'Pointing a sweep at a real cluster')", ClusterWarning)


class ClusterWarning(UserWarning):
    """A worker of a sweep's cluster that cannot run the client's tapmuscle (:func:`check_workers`), or
    that joined after that check and runs other sources: no run is sent to it (:class:`DaskExecutor`)."""


class _ClusterWatch:
    """Whether a client still has a cluster to run on: its scheduler connected and, within
    ``no_worker_s`` seconds of the last one leaving, a worker that has not refused a run (``refused``,
    by address; asked at most once a second)."""

    def __init__(self, client: Any, no_worker_s: float, n_tasks: int, refused: Mapping[str, str] | None = None) -> None:
        self.client, self.no_worker_s, self.n_tasks = client, no_worker_s, n_tasks
        self.refused = refused if refused is not None else {}
        self._asked, self._alone_since = -math.inf, None

    def alone_s(self) -> float | None:
        """How long [s] the cluster has been seen without a worker; None while it has one."""
        since = self._alone_since
        return None if since is None else time.monotonic() - since

    def check(self, unfinished: int, *, at_once: bool = False) -> None:
        """Raise :class:`ClusterError` if the cluster is gone (``unfinished``: runs without a result)."""
        done = self.n_tasks - unfinished
        kept = (f"{done} run{'s' if done != 1 else ''} finished here, kept; the {unfinished} others are not "
                "recorded as failed")

        def lost(cause: str, remedy: str) -> ClusterError:
            error = ClusterError(f"{cause} ({kept}): {remedy}, and rerun the same command to go on")
            error.cause, error.remedy, error.finished = cause, remedy, done
            return error

        if self.client.status != "running":
            raise lost(f"lost the connection to the scheduler {self.client.scheduler.address}",
                       "start it and its workers again")
        now = time.monotonic()
        if not at_once and now - self._asked < 1.0:
            return
        self._asked = now
        try:
            workers = set(self.client.scheduler_info().get("workers", {})) - set(self.refused)
        except Exception:  # noqa: BLE001 - the connection went while asking: said at the next check
            return
        if workers:
            self._alone_since = None
            return
        self._alone_since = self._alone_since or now
        if now - self._alone_since >= self.no_worker_s:
            address = self.client.scheduler.address
            if self.refused:
                raise lost(f"no worker with the client's tapmuscle sources has been connected to the scheduler "
                           f"{address} for {self.no_worker_s:g} s ({'; '.join(self.refused.values())})",
                           f"give the workers the client's tapmuscle (or start ones that have it: dask worker {address})")
            raise lost(f"no worker has been connected to the scheduler {address} for "
                       f"{self.no_worker_s:g} s", f"start workers (dask worker {address})")


class ClusterError(OSError):
    """A scheduler that is not one, workers that cannot run tapmuscle's runs or did not start, or a
    cluster lost mid-sweep (named, with why and what was kept).

    A cluster lost mid-sweep also carries its parts, for a caller that words its own message:
    ``cause`` (what was lost), ``remedy`` (what to start again) and ``finished`` (runs with a result);
    None otherwise."""

    cause: str | None = None
    remedy: str | None = None
    finished: int | None = None


def probe_scheduler(address: str, wait_s: float) -> None:
    """Check that a Dask scheduler answers at ``address`` (``tcp://host:port`` or ``host:port``) within
    ``wait_s`` seconds, before ``distributed`` connects: a scheduler greets a new connection with a
    message frame; an HTTP server (the dashboard's port, a proxy) waits or answers text, on which
    ``distributed``'s client waits without its timeout or misreads the text as a frame length.
    Other schemes (``tls://``, ``inproc://``) are left to ``distributed``.

    Parameters
    ----------
    address : str
        The scheduler's address.
    wait_s : float
        How long to wait for the connection and the greeting together [s].

    Raises
    ------
    ClusterError
        Nothing listens there, the host is unknown, no greeting comes within ``wait_s``, or the
        greeting is not a Dask frame (an HTTP server's, named as such).
    """
    scheme, _, rest = address.rpartition("://")
    if scheme not in ("", "tcp"):
        return
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit():
        raise ClusterError(f"{address}: not a scheduler address tcp://HOST:PORT")
    host = host.strip("[]")
    deadline = time.monotonic() + wait_s  # connecting and the greeting together
    try:
        with socket.create_connection((host, int(port)), timeout=wait_s) as sock:
            greeting = b""
            while len(greeting) < 16:
                sock.settimeout(max(deadline - time.monotonic(), 1e-3))
                chunk = sock.recv(16 - len(greeting))
                if not chunk:
                    break
                greeting += chunk
    except socket.gaierror as exc:
        raise ClusterError(f"{address}: unknown host {host} ({exc.strerror})") from None
    except ConnectionRefusedError:
        raise ClusterError(f"{address}: nothing listens on port {port} of {host} (is the scheduler started?)") from None
    except (socket.timeout, TimeoutError):
        raise ClusterError(f"{address}: no Dask scheduler answered within {wait_s:g} s (a scheduler greets at once; "
                           "the dashboard's HTTP port, 8787 by default, waits: the scheduler's own is 8786 by "
                           "default)") from None
    except OSError as exc:
        raise ClusterError(f"{address}: cannot connect: {exc}") from None
    # a frame: its length (little-endian 64 bits) and its number of parts, both small
    if len(greeting) == 16 and 0 < int.from_bytes(greeting[:8], "little") < 1 << 30 \
            and 0 < int.from_bytes(greeting[8:16], "little") < 1 << 16:
        return
    if greeting.startswith(b"HTTP") or greeting[:4].isascii() and greeting[:4].isalpha():
        raise ClusterError(f"{address}: an HTTP server answers there, not a Dask scheduler (the dashboard's port, "
                           f"or a proxy: {greeting[:16]!r}); the scheduler's own port is 8786 by default")
    raise ClusterError(f"{address}: the answer is not a Dask scheduler's ({greeting[:16]!r})")


def _code_and_home() -> tuple[str, str]:
    """This process's :func:`~tapmuscle.provenance.code_digest` and the folder its tapmuscle is from."""
    from tapmuscle.provenance import code_digest

    return code_digest(), str(Path(__file__).resolve().parents[1])


def check_workers(client: Any) -> dict[str, str]:
    """Check that the workers of ``client``'s cluster import tapmuscle's run code, the client's
    code, before any run: a worker without osqp (say) would fail each run it took, and one of
    another version, or of the same version with other sources (another commit, a local edit:
    :func:`tapmuscle.provenance.code_digest`), could compute other numbers. The sweep runs on the
    workers that can (give what this returns to :class:`DaskExecutor`'s ``refused``); a cluster
    none of whose workers can is refused.

    Parameters
    ----------
    client : distributed.Client
        A client connected to the cluster.

    Returns
    -------
    dict
        The workers that cannot, by address: what is said of each (its address and name, with what
        it lacks, the version it has, or where its other code is); empty where every one can.

    Raises
    ------
    ClusterError
        No worker, or none that can: each named as above.
    """
    import importlib.metadata

    # builtins and the standard library's functions: they reach a worker whatever it can import
    imported = client.run(exec, "import tapmuscle.cosim.distributed_sweep", on_error="return")
    if not imported:  # the runs would wait for ever
        address = getattr(getattr(client, "scheduler", None), "address", None) or "SCHEDULER_ADDRESS"
        # a cluster made in the same script or notebook (a LocalCluster) restarts no worker it lost to
        # an interrupt: it is made again
        raise ClusterError(f"the cluster has no worker: start one (dask worker {address} --nthreads 1), or, for a "
                           "LocalCluster made in this process, close it and make it again")
    versions = client.run(importlib.metadata.version, "tapmuscle", on_error="return")
    try:
        mine = importlib.metadata.version("tapmuscle")
    except importlib.metadata.PackageNotFoundError:  # a checkout on sys.path, not installed: no version to hold
        mine = None
    digests = client.run(_code_here, on_error="return")
    my_digest, my_home = _code_here()
    names = {address: info.get("name") for address, info in client.scheduler_info().get("workers", {}).items()}
    problems: dict[str, str] = {}
    for worker in sorted(imported):
        error, version, code = imported[worker], versions.get(worker), digests.get(worker)
        # a worker is named as its admin started it (dask worker --name) as well as by address
        named = f"worker {worker}" + (f" ({names[worker]})" if names.get(worker) not in (None, worker) else "")
        if isinstance(error, BaseException):
            problems[worker] = f"{named} cannot import tapmuscle's run code: {type(error).__name__}: {error}"
        elif mine is not None and (isinstance(version, BaseException) or version != mine):
            has = f"{type(version).__name__}: {version}" if isinstance(version, BaseException) else f"tapmuscle {version}"
            problems[worker] = f"{named} has {has}, the client tapmuscle {mine}"
        elif isinstance(code, BaseException) or code is None:
            problems[worker] = f"{named} cannot tell its tapmuscle's sources: {type(code).__name__}: {code}"
        elif code[0] != my_digest:
            problems[worker] = _other_sources(named, code, (my_digest, my_home))
    if len(problems) == len(imported):
        raise ClusterError("; ".join(problems.values()) + " (every worker needs the client's tapmuscle and its "
                           "dependencies: docs/sweeps.md, 'Pointing a sweep at a real cluster')")
    return problems


def _other_sources(named: str, code: Sequence[str], client_code: Sequence[str]) -> str:
    """What is said of a worker whose ``(digest, folder)`` of its tapmuscle is not the client's."""
    return (f"{named} runs other tapmuscle sources (digest {code[0]}, from {code[1]}) than the client "
            f"(digest {client_code[0]}, from {client_code[1]}): another commit or a local change")


@contextmanager
def dask_client(workers: int, scheduler: str | None = None, *, wait_s: float = 60.0) -> Iterator[Any]:
    """A ``distributed.Client``: on a new local cluster of ``workers`` single-threaded worker processes,
    or connected to the running scheduler at ``scheduler`` (``tcp://host:port``), which must get at
    least one worker within ``wait_s`` seconds (whose workers the caller checks: :func:`check_workers`).
    Raises OSError/TimeoutError if it cannot connect (:class:`ClusterError` naming why).

    Parameters
    ----------
    workers : int
        Worker processes of a new local cluster (unused with ``scheduler``).
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:port``); None (default): a new local
        cluster.
    wait_s : float, optional
        How long to wait for the scheduler and its first worker [s]; default 60.
    """
    import dask
    from distributed import Client, LocalCluster
    from distributed.security import Security

    if scheduler:
        probe_scheduler(scheduler, wait_s)
        client = Client(scheduler, timeout=f"{wait_s}s")
        try:
            try:
                client.wait_for_workers(1, timeout=wait_s)
            except TimeoutError:  # Dask's "Only 0/1 workers arrived after 60": said as check_workers does
                raise ClusterError(f"the cluster has no worker after {wait_s:g} s: start one (dask worker "
                                   f"{scheduler} --nthreads 1), or wait longer (--timeout)") from None
            yield client
        finally:
            client.close()
        return
    check_workers_can_start(f"workers={workers}")  # the nannies spawn the worker processes
    # no dashboard, so no use for the workers' statistical profiler (a thread sampling every 10 ms);
    # one task at a time on each single-threaded worker (Dask's default sends 2 there): a task waiting
    # on a worker that a run's FMU crashes counts as a suspect of the crash and fails as KilledWorker once
    # the crashing run has spent Dask's retries (DaskExecutor's one_run_per_thread also for small sweeps,
    # which Dask sends out at once)
    with dask.config.set({"distributed.worker.profile.enabled": False,
                          "distributed.scheduler.worker-saturation": 1.0}):
        # Its scheduler and workers listen on local TCP ports, which any user of the machine can reach:
        # with Dask's temporary TLS credentials (mutual TLS, a certificate made for this cluster) only
        # this process's client and workers get in, not another user's code that would run as yours.
        # Its scheduler's HTTP server (health, metrics) is on a free port of this machine only.
        try:
            security = Security.temporary()
        except ImportError as exc:  # the credentials are made with the cryptography package
            raise ClusterError(f"the local cluster's TLS credentials need the cryptography package ({exc}): pip "
                               "install \"tapmuscle[dist]\" (or cryptography), or run with --workers 0") from None
        try:
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                   scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}, security=security,
                                   silence_logs=logging.ERROR)
        except RuntimeError as exc:  # "Nanny failed to start": the processes said why, on stderr
            raise ClusterError(f"the local cluster's {workers} worker processes did not start ({exc}); their "
                               "message is above") from None
    client = None
    try:
        client = Client(cluster)
        # a terminal's Ctrl-C reaches these worker processes too (one process group): they ignore
        # it, also once a nanny restarts one, and the client stops them and says what it kept
        client.register_plugin(_ignore_interrupts())
        yield client
    finally:
        _close_local_cluster(client, cluster)


#: Seconds the command's own local cluster is given to close before its worker processes are killed.
LOCAL_CLOSE_S = 10.0


def _close_local_cluster(client: Any, cluster: Any, timeout_s: float = LOCAL_CLOSE_S) -> None:
    """Close ``client`` and ``cluster``, within ``timeout_s`` seconds: a worker inside an FMU's step
    that never returns (a hung FMU holds the GIL through its call) answers nothing, so the close would
    wait for it for ever; its process is killed then, and the close finishes."""
    pids = [nanny.process.process.pid for nanny in cluster.workers.values()
            if getattr(getattr(nanny, "process", None), "process", None) is not None]

    def close() -> None:
        if client is not None:
            try:  # the workers' log lines from here on are shutdown races (a heartbeat to a closed scheduler)
                client.run(_quiet_logs)
            except Exception:  # noqa: BLE001 - a cluster that cannot be reached has nothing left to say
                pass
            client.close()
        cluster.close()

    closing = threading.Thread(target=close, name="tapmuscle-close-cluster", daemon=True)
    closing.start()
    closing.join(timeout_s)
    if closing.is_alive():
        for pid in pids:
            try:
                os.kill(pid, getattr(signal, "SIGKILL", signal.SIGTERM))
            except (ProcessLookupError, PermissionError):
                pass
        closing.join(timeout_s)


def _quiet_logs() -> None:
    """On a worker of the command's own local cluster about to close: its ``distributed`` loggers say
    nothing more (a heartbeat racing the scheduler's close logged an error and a traceback over the
    command's last line; every run's failure reaches the client, which reports it)."""
    logging.getLogger("distributed").setLevel(logging.CRITICAL + 1)


def _ignore_interrupts() -> Any:
    """A worker plugin that makes its worker process ignore SIGINT (set in the process's main thread,
    where the worker runs; made here, as ``distributed`` is imported only for a cluster)."""
    from distributed import WorkerPlugin

    class IgnoreInterrupts(WorkerPlugin):
        name = "tapmuscle-ignore-interrupts"

        def setup(self, worker: Any) -> None:
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return IgnoreInterrupts()
