"""``tapmuscle sweep``: run a sweep's runs, log each as it finishes, resume, summarise.

Outputs in ``DIR``:

* ``results.csv``: one row per run: ``run_id``, ``status`` (``ok`` / ``failed``), the base
  ``scenario``, ``method``, ``load_n``, ``supply_mpa``, ``frequency_hz`` (empty for a step reference),
  ``seed``, the swept fields, the metrics of :data:`tapmuscle.cosim.expect.METRICS`, ``expect`` (``pass``,
  ``fail: ...`` or empty without expectations), ``error``, ``worker`` and ``fmus`` (first 8 hex digits
  of the FMU files' SHA-256). While the sweep runs the file is a log: each finished run appends its row
  (flushed and fsynced), so an interrupted sweep loses nothing it finished. At the end it is rewritten
  (atomically) with one row per run, the last one logged, in the sweep's order; rows of run ids the
  sweep no longer has are kept after them (``summary.md`` and the command's last lines say how many).
* ``summary.md``: per method, runs, failures, expectation violations and the Eq. (21) error's mean,
  median and maximum; per grid cell where the sweep varies a few discrete values; the failed runs; what
  the FMUs warned of in the runs made this time; the releases that summarised it
  (:func:`tapmuscle.provenance.software_text`).
* ``mae_by_method.png`` and, when load, reference frequency, supply or another numeric field varies,
  ``mae_map.png`` (:mod:`tapmuscle.plots.sweep_figures`; PDF or SVG with ``figure_format``).

**Resume.** A rerun of the same sweep into the same ``DIR`` skips every run whose last row is ``ok``
and was made with the same FMU files; failed runs are run again (their new row replaces the old one at
the end). A ``results.csv`` with other columns (another sweep, or this one with other swept fields) is
refused rather than mixed.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

try:  # POSIX: the output folder's lock
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

from fmu_plant.user_warning import warn_at_caller
from tapmuscle.cosim.distributed_sweep import FmuFiles, RunResult, RunTask, make_task
from tapmuscle.cosim.expect import METRICS, Expectations, check_expectations
from tapmuscle.cosim.spec import Scenario, ScenarioError
from tapmuscle.cosim.sweep import Sweep, SweepRun
from tapmuscle.io.inert_text import inert_cell, markdown_text
from tapmuscle.plots.figure_formats import FIGURE_FORMATS, checked_figure_format
from tapmuscle.provenance import software_text

__all__ = ["DESCRIPTIVE", "SUMMARY_FIGURES", "SUMMARY_FILES", "SweepReport", "ResultsLog", "result_columns",
           "run_sweep", "summary_markdown", "describe_scenario"]

#: Columns that describe every run, whether swept or not.
DESCRIPTIVE = ("scenario", "method", "load_n", "supply_mpa", "frequency_hz", "seed")
_TAIL = ("expect", "error", "worker", "fmus")

Executor = Callable[[Sequence[RunTask], FmuFiles], Iterable[RunResult]]


def describe_scenario(scenario: Scenario) -> dict[str, Any]:
    """The :data:`DESCRIPTIVE` columns of a run (initial load and supply, built-in sine frequency).

    Parameters
    ----------
    scenario : Scenario
        The run's scenario.
    """
    return {"method": scenario.method, "load_n": scenario.load.initial, "supply_mpa": scenario.supply.initial,
            "frequency_hz": scenario.reference.frequency_hz if scenario.reference.kind == "sine" else None,
            "seed": scenario.seed}


def result_columns(sweep: Sweep) -> tuple[str, ...]:
    """The header of ``results.csv`` for ``sweep``.

    Parameters
    ----------
    sweep : Sweep
        The sweep (its swept fields become columns).
    """
    swept = tuple(f for f in sweep.fields if f not in DESCRIPTIVE)
    return ("run_id", "status") + DESCRIPTIVE + swept + tuple(METRICS) + _TAIL


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)  # round-trips exactly
    if isinstance(value, (list, dict)):
        return json.dumps(value, sort_keys=True)
    # a name or an error's text from the sweep's files: never a formula in a spreadsheet
    return inert_cell(value) if isinstance(value, str) else str(value)


class ResultsLog:
    """``results.csv`` (module docstring): append rows, read the last row per run, rewrite compacted.

    Parameters
    ----------
    path : str or Path
        The ``results.csv`` file.
    columns : sequence of str
        Its header (:func:`result_columns`).
    """

    def __init__(self, path: str | Path, columns: Sequence[str]) -> None:
        self.path, self.columns = Path(path), tuple(columns)
        #: The lines of the last :meth:`rows` that were not a whole row (an edit gone wrong): ignored.
        self.malformed: list[int] = []

    def rows(self) -> list[dict[str, str]]:
        """Every complete row, in file order (a line cut short by a crash is ignored)."""
        if not self.path.is_file():
            return []
        try:
            text = self.path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ScenarioError(f"{self.path}: cannot be read as a results file ({exc}); move it away or write "
                                "into another --out folder") from None
        if not text:
            return []
        if not text.endswith("\n"):
            text = text[:text.rfind("\n") + 1]
        reader = csv.reader(io.StringIO(text))
        try:
            header = tuple(next(reader, ()))
            if header != self.columns:
                extra = sorted(set(header) ^ set(self.columns))
                raise ScenarioError(f"{self.path}: holds results of another sweep (columns differ: "
                                    f"{', '.join(extra)[:120] or 'order'}); write into another --out folder")
            whole, self.malformed = [], []
            for row in reader:
                if len(row) == len(header):
                    whole.append(dict(zip(header, row)))
                else:
                    self.malformed.append(reader.line_num)
            return whole
        except csv.Error as exc:
            raise ScenarioError(f"{self.path}, line {reader.line_num}: not a results file ({exc}); move it away "
                                "or write into another --out folder") from None

    def latest(self) -> dict[str, dict[str, str]]:
        """run_id -> its last row."""
        return {row["run_id"]: row for row in self.rows()}

    def cells(self, row: Mapping[str, Any]) -> dict[str, str]:
        """``row`` as :meth:`rows` reads it back: every column, as its text."""
        return {c: _cell(row.get(c)) for c in self.columns}

    def check_appendable(self) -> None:
        """Open the file for appending and close it again, so that a file that cannot take a row is
        named before the first run.

        Raises
        ------
        PermissionError
            Naming the file and what to do (:meth:`append`).
        """
        if not self.path.is_file():
            return
        try:
            open(self.path, "a", encoding="utf-8").close()
        except PermissionError as exc:
            raise self._held(exc, "no run has started") from None

    def _held(self, exc: PermissionError, lost: str) -> PermissionError:
        return PermissionError(exc.errno, f"{self.path}: rows cannot be appended ({exc.strerror}; on Windows a file that "
                                          f"another program holds open, a spreadsheet, cannot take them): close it and "
                                          f"rerun the same command to go on ({lost})")

    def append(self, row: Mapping[str, Any]) -> None:
        """Append one row (the header first if the file is new), flushed to disk."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            new = not self.path.is_file() or self.path.stat().st_size == 0
            if not new:
                self._drop_partial_line()
            with open(self.path, "a", encoding="utf-8", newline="") as fh:
                writer = csv.writer(fh, lineterminator="\n")
                if new:
                    writer.writerow(self.columns)
                writer.writerow(self.cells(row).values())
                fh.flush()
                os.fsync(fh.fileno())
        except PermissionError as exc:
            raise self._held(exc, "that run is not kept") from None
        except OSError as exc:  # a full disk says only "No space left on device": the file is named
            if exc.filename is not None:
                raise
            raise type(exc)(exc.errno, f"{exc.strerror}, appending a run's row (that run is not kept: free space and rerun the "
                            "same command to go on)",
                            str(self.path)) from None

    def _drop_partial_line(self) -> None:
        with open(self.path, "rb+") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            fh.seek(max(0, size - 1))
            if fh.read(1) == b"\n":
                return
            fh.seek(0)
            content = fh.read()
            fh.truncate(content.rfind(b"\n") + 1)

    def rewrite(self, rows: Iterable[Mapping[str, Any]]) -> None:
        """Replace the file with ``rows`` (atomically)."""
        from tapmuscle.io.recording import atomic_write_text

        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(self.columns)
        for row in rows:
            writer.writerow([_cell(row.get(c)) for c in self.columns])
        atomic_write_text(self.path, buf.getvalue())


@dataclass(frozen=True)
class SweepReport:
    """What :func:`run_sweep` did."""

    total: int
    """Runs in the sweep."""
    skipped: int
    """Runs already finished in ``results.csv`` (not run again)."""
    ran: int
    """Runs this call ran."""
    failed: int
    """Runs of the sweep whose last row is ``failed``."""
    violated: int
    """Runs that finished but miss their expectations."""
    rows: tuple[dict[str, str], ...] = field(repr=False)
    """The final row of every run of the sweep, in its order (not in the repr: a notebook's cell shows
    the counts, not a thousand rows)."""
    other_rows: int = 0
    """Rows of runs this sweep no longer has (an earlier version of the file), kept in ``results.csv``
    after its own and left out of the summary."""
    fmu_warnings: tuple[tuple[str, str], ...] = field(default=(), repr=False)
    """``(run_id, message)``: what the FMUs warned of in the runs this call ran (``summary.md`` lists them)."""


def _expect_cell(expect: Expectations | None, metrics: Mapping[str, float]) -> str:
    if not expect:
        return ""
    outcome = check_expectations(expect, metrics)
    return "pass" if outcome.passed else "fail: " + "; ".join(outcome.violations)


def _row(run: SweepRun, task: RunTask, result: RunResult) -> dict[str, Any]:
    row: dict[str, Any] = {"run_id": run.run_id, "status": result.status, "scenario": run.base,
                           **describe_scenario(run.scenario), **dict(run.params), **result.metrics,
                           "error": result.error, "worker": result.worker, "fmus": task.fmu_tag}
    if result.status == "ok":
        row["expect"] = _expect_cell(run.scenario.expect, result.metrics)
    return row


def _metrics_of(row: Mapping[str, str]) -> dict[str, float]:
    return {m: float(row[m]) for m in METRICS if row.get(m, "") != ""}


def run_sweep(sweep: Sweep, out: str | Path, fmus: Mapping[str, str | Path], execute: Executor, *,
              progress: Callable[..., None] | None = None, plots: bool = True,
              figure_format: str = "png") -> SweepReport:
    """Run the runs of ``sweep`` not yet finished in ``out/results.csv``, then write the summary.

    Parameters
    ----------
    sweep : Sweep
    out : path
        Output folder (module docstring).
    fmus : mapping
        ``{"MusclePlant": path, "AMPCController": path}`` for runs whose scenario names no FMU file.
    execute : callable
        ``execute(tasks, files)`` yielding a :class:`RunResult` per task as it finishes
        (:func:`tapmuscle.cosim.distributed_sweep.run_serial`, :class:`~tapmuscle.cosim.distributed_sweep.DaskExecutor`).
    progress : callable, optional
        Called as ``progress(done, total, detail)`` after each run (``detail``: failed and remaining).
    plots : bool
        Draw the figures (:data:`SUMMARY_FIGURES`).
    figure_format : {"png", "pdf", "svg"}
        Their format (:data:`~tapmuscle.plots.figure_formats.FIGURE_FORMATS`).

    Raises
    ------
    ScenarioError
        ``results.csv`` holds another sweep's results, or another sweep writes into ``out`` now.
    ValueError
        A figure format not in :data:`~tapmuscle.plots.figure_formats.FIGURE_FORMATS`.
    """
    checked_figure_format(figure_format)
    out = Path(out)
    lock = _FolderLock(out)
    try:
        return _run_sweep(sweep, out, fmus, execute, progress, (figure_format if plots else None), lock)
    finally:
        lock.release()


def _run_sweep(sweep: Sweep, out: Path, fmus: Mapping[str, str | Path], execute: Executor,
               progress: Callable[..., None] | None, plots: str | None, lock: "_FolderLock") -> SweepReport:
    """:func:`run_sweep`'s work: everything checked, then the output folder made and locked."""
    log = ResultsLog(out / "results.csv", result_columns(sweep))
    log.latest()  # refuses another sweep's file before anything runs
    files = FmuFiles.for_scenarios((r.scenario for r in sweep.runs), fmus)
    tasks = {run.run_id: make_task(run.run_id, run.scenario, fmus, files) for run in sweep.runs}
    lock.acquire()
    latest = log.latest()  # again: a sweep into the folder may have ended since
    log.check_appendable()  # a file held open elsewhere: named before a run is lost to it
    if log.malformed:
        lines = ", ".join(map(str, log.malformed[:5])) + (" ..." if len(log.malformed) > 5 else "")
        warn_at_caller(f"{log.path}: {len(log.malformed)} line{'s' if len(log.malformed) > 1 else ''} ({lines}) not a "
                       f"whole row of {len(log.columns)} columns, ignored: their runs are run again")
    by_id = {run.run_id: run for run in sweep.runs}
    todo = [tasks[r.run_id] for r in sweep.runs
            if not (latest.get(r.run_id, {}).get("status") == "ok"
                    and latest[r.run_id].get("fmus") == tasks[r.run_id].fmu_tag)]
    total, skipped = len(sweep.runs), len(sweep.runs) - len(todo)
    done, failed = skipped, 0
    if progress is not None:
        progress(done, total, f"{skipped} already done, {len(todo)} to run")
    warned: list[tuple[str, str]] = []
    for result in execute(todo, files):
        row = _row(by_id[result.run_id], tasks[result.run_id], result)
        log.append(row)
        latest[result.run_id] = log.cells(row)
        warned += [(result.run_id, text) for text in result.fmu_warnings]
        done += 1
        failed += result.status != "ok"
        if progress is not None:
            progress(done, total, f"{done - skipped - failed} ok, {failed} failed, {total - done} remaining")
    final, other = _compact(log, sweep, latest)
    report = SweepReport(total=total, skipped=skipped, ran=done - skipped,
                         failed=sum(r["status"] != "ok" for r in final),
                         violated=sum(r["expect"].startswith("fail") for r in final), rows=tuple(final),
                         other_rows=other, fmu_warnings=tuple(warned))
    _write_summary(sweep, out, final, plots, other, warned)
    return report


class _FolderLock:
    """An exclusive lock on a sweep's output folder (``flock`` on the folder itself: no file of its
    own) from :meth:`acquire`, which makes the folder, to :meth:`release`: a second sweep into the
    same folder (another terminal, a CI job beside this one) is refused, instead of running every run
    a second time. Where ``fcntl`` is missing (Windows) there is no lock."""

    def __init__(self, folder: Path) -> None:
        self.folder, self._fd = folder, None

    def acquire(self) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        if fcntl is None:
            return
        fd = os.open(self.folder, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise ScenarioError(f"{self.folder}: another sweep writes into this folder now (another terminal, a CI "
                                "job?); wait for it to end and run again (its finished runs are then skipped), or "
                                "give another output folder") from None
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def _compact(log: ResultsLog, sweep: Sweep, held: Mapping[str, Mapping[str, Any]]) -> tuple[list[dict[str, str]], int]:
    """Rewrite the log with one row per run (expectations re-checked); the sweep's rows in its order,
    and how many rows of other runs follow them. ``held``: the rows this sweep read at its start and
    wrote since, which keep a run whose row the file lost meanwhile (its folder removed mid-sweep)."""
    latest = {**held, **log.latest()}
    final = []
    for run in sweep.runs:
        row = dict(latest[run.run_id])
        if row["status"] == "ok":
            row["expect"] = _expect_cell(run.scenario.expect, _metrics_of(row))
        final.append(row)
    ids = {run.run_id for run in sweep.runs}
    other = [row for rid, row in latest.items() if rid not in ids]
    log.rewrite(final + other)
    return final, len(other)


# ------------------------------------------------------------------------------------------ summary
def _stats(values: list[float]) -> tuple[str, str, str]:
    if not values:
        return ("", "", "")
    return (f"{statistics.fmean(values):.3f}", f"{statistics.median(values):.3f}", f"{max(values):.3f}")


def _value(text: str) -> float | str:
    try:
        return float(text)
    except ValueError:
        return text


def _distinct(rows: Sequence[Mapping[str, str]], columns: Sequence[str]) -> list[str]:
    """``columns`` less repeats and those equal in every row to an earlier one (a swept
    ``load.initial_n`` next to the ``load_n`` derived from it), which would only repeat an axis."""
    out: list[str] = []
    seen: list[list[float | str]] = []
    for c in columns:
        values = [_value(row.get(c, "")) for row in rows]
        if c not in out and values not in seen:
            out.append(c)
            seen.append(values)
    return out


def _swept_fields(sweep: Sweep) -> list[str]:
    """The sweep's own fields that may be an axis of the summary (method and seed are not, nor the
    whole ``controller`` table, whose values the method column names)."""
    return [f for f in sweep.fields if f not in DESCRIPTIVE and not f.endswith("method") and f != "controller"]


def _cell_fields(rows: Sequence[Mapping[str, str]], sweep: Sweep) -> list[str]:
    """Columns that vary over a few discrete values (grid-like), method and seed left out."""
    out = []
    for c in _distinct(rows, ["scenario", "load_n", "supply_mpa", "frequency_hz"] + _swept_fields(sweep)):
        values = {row.get(c, "") for row in rows}
        if 1 < len(values) <= 12:
            out.append(c)
    if "scenario" in out and len(out) > 1:
        out.remove("scenario")  # the base's name repeats its load and frequency
    return out


def summary_markdown(sweep: Sweep, rows: Sequence[Mapping[str, str]], other_rows: int = 0,
                     fmu_warnings: Sequence[tuple[str, str]] = ()) -> str:
    """``summary.md``: tables per method (and per grid cell), failed runs (module docstring);
    ``other_rows``: rows of runs ``results.csv`` keeps that this sweep no longer has;
    ``fmu_warnings``: ``(run_id, message)`` the FMUs logged in the runs made this time.

    Parameters
    ----------
    sweep : Sweep
        The sweep.
    rows : sequence of mapping of str to str
        The last row of each of its runs in ``results.csv``.
    other_rows : int, optional
        Rows of runs ``results.csv`` keeps that this sweep no longer has; default 0.
    fmu_warnings : sequence of (str, str), optional
        ``(run_id, message)`` the FMUs logged as warnings in the runs made this time.
    """
    methods = sorted({row["method"] for row in rows})
    # the sweep file's and the runs' own text (names, descriptions, errors) as literal text: a sweep
    # file from elsewhere must not put HTML or links into the summary a viewer renders
    md = markdown_text
    lines = [f"# Sweep {md(sweep.name)}", ""]
    if sweep.description:
        lines += [md(sweep.description), ""]
    n_failed = sum(row["status"] != "ok" for row in rows)
    windows = sorted({(r.scenario.evaluation_samples, r.scenario.step_s) for r in sweep.runs})
    window = (f"samples {windows[0][0][0]}..{windows[0][0][1]} ({windows[0][0][0] * windows[0][1]:.6g}-"
              f"{windows[0][0][1] * windows[0][1]:.6g} s) of each run" if len(windows) == 1
              else f"each scenario's evaluation window ({len(windows)} different: their `evaluation_samples` and "
                   "`step_s`)")
    lines += [f"Source: `{sweep.source.replace('`', chr(39))}`; {len(rows)} runs, {n_failed} failed. Eq. (21) error `mae_mm` [mm], "
              f"the mean |r - l| over {window}, over the runs that finished. What a scenario does not set runs at "
              "the controller FMU's defaults: the start-up mode, the hysteresis notch and the stored `theta0` "
              "(`tapmuscle paper` identifies its own; docs/fmu.md).", "",
              # the FMUs run the host's numpy, scipy and osqp: a resumed run is skipped by its FMU
              # files alone, and a release of those moves a chaotic loop's last digits
              f"Summarised with {software_text()}; a run kept from an earlier `results.csv` was made with the "
              "software of its time, a run on a Dask worker with the worker's.", ""]
    if other_rows:
        lines += [f"`results.csv` also keeps, after this sweep's rows, {other_rows} rows whose run ids the sweep does "
                  "not have (an earlier version of its file, or runs of an earlier tapmuscle, whose ids were made "
                  "otherwise); they are not summarised here.", ""]
    lines += ["## Per method", "",
              "| method | runs | failed | expectations missed | mae mean | mae median | mae max |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for m in methods:
        sel = [row for row in rows if row["method"] == m]
        mae = [float(row["mae_mm"]) for row in sel if row["status"] == "ok" and row["mae_mm"] != ""]
        missed = sum(row["expect"].startswith("fail") for row in sel)
        lines.append(f"| {md(m)} | {len(sel)} | {sum(r['status'] != 'ok' for r in sel)} | {missed} | "
                     + " | ".join(_stats(mae)) + " |")
    cells = _cell_fields(rows, sweep)
    if cells:
        lines += ["", f"## Per method and {', '.join(cells)}", "",
                  "| method | " + " | ".join(cells) + " | runs | failed | mae mean | mae median | mae max |",
                  "|---|" + "---:|" * (len(cells) + 5)]
        groups: dict[tuple[str, ...], list[Mapping[str, str]]] = {}
        for row in rows:
            groups.setdefault((row["method"],) + tuple(row.get(c, "") for c in cells), []).append(row)
        for key in sorted(groups, key=lambda k: tuple(_sort_key(v) for v in k)):
            sel = groups[key]
            mae = [float(r["mae_mm"]) for r in sel if r["status"] == "ok" and r["mae_mm"] != ""]
            lines.append("| " + " | ".join(map(md, key)) + f" | {len(sel)} | {sum(r['status'] != 'ok' for r in sel)} | "
                         + " | ".join(_stats(mae)) + " |")
    failed = [row for row in rows if row["status"] != "ok"]
    if failed:
        lines += ["", "## Failed runs", ""]
        lines += [f"- `{row['run_id']}` ({md(row['scenario'])}, {md(row['method'])}): {md(row['error'])}"
                  for row in failed[:50]]
        if len(failed) > 50:
            lines.append(f"- ... and {len(failed) - 50} more (results.csv)")
    missed = [row for row in rows if row["expect"].startswith("fail")]
    if missed:
        lines += ["", "## Expectations missed", ""]
        lines += [f"- `{row['run_id']}` ({md(row['scenario'])}, {md(row['method'])}): {md(row['expect'][6:])}"
                  for row in missed[:50]]
    if fmu_warnings:
        runs = len({rid for rid, _ in fmu_warnings})
        lines += ["", "## FMU warnings", "", f"What the FMUs logged as warnings in {runs} of the runs made this time (a run "
                  "resumed from `results.csv` is not run again, so its warnings are not here):", ""]
        lines += [f"- `{rid}`: {md(text)}" for rid, text in fmu_warnings[:50]]
        if len(fmu_warnings) > 50:
            lines.append(f"- ... and {len(fmu_warnings) - 50} more")
    return "\n".join(lines) + "\n"


def _sort_key(text: str) -> tuple[int, float, str]:
    value = _value(text)
    return (1, math.inf, text) if isinstance(value, str) else (0, value, text)


#: The figures :func:`run_sweep` draws, without their format's suffix.
SUMMARY_FIGURES = ("mae_by_method", "mae_map")

#: What :func:`run_sweep` writes at the end beside ``results.csv`` (together: a figure an earlier sweep
#: into the folder drew and this one does not, or drew in another format, is removed).
SUMMARY_FILES = ("summary.md",) + tuple(f"{name}.{fmt}" for fmt in FIGURE_FORMATS for name in SUMMARY_FIGURES)


def _write_summary(sweep: Sweep, out: Path, rows: Sequence[Mapping[str, str]], plots: str | None, other_rows: int,
                   fmu_warnings: Sequence[tuple[str, str]] = ()) -> None:
    """``summary.md`` and, in the format ``plots`` (None: none), the figures."""
    from tapmuscle.io.atomic import staged_folder
    from tapmuscle.io.recording import atomic_write_text

    with staged_folder(out, owned=SUMMARY_FILES) as tmp:
        atomic_write_text(tmp / "summary.md", summary_markdown(sweep, rows, other_rows, fmu_warnings))
        if plots:
            from tapmuscle.plots.sweep_figures import plot_mae_by_method, plot_mae_map

            numeric = _distinct(rows, ["load_n", "frequency_hz", "supply_mpa"] + _swept_fields(sweep))
            plot_mae_by_method(rows, tmp / f"mae_by_method.{plots}", title=f"{sweep.name}: Eq. (21) error per method",
                               pooled=numeric)
            plot_mae_map(rows, numeric, tmp / f"mae_map.{plots}", title=f"{sweep.name}: Eq. (21) error")

