"""``tapmuscle check``: scenario tests for CI.

Every scenario file and every run of a sweep file that carries expectations (``[expect]``,
:mod:`tapmuscle.cosim.expect`) is a test case: run it through the FMUs, compare its metrics with the bounds.
This module collects the cases from files and folders, and formats the outcome as a text table and as
JUnit XML (the format CI systems display: GitLab, Jenkins, GitHub actions' test reporters, Azure).
Running the cases is :mod:`tapmuscle.cosim.distributed_sweep`'s; writing files is the CLI's.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

from tapmuscle.cosim.distributed_sweep import RunResult
from tapmuscle.cosim.expect import Outcome, check_expectations
from tapmuscle.cosim.spec import Scenario, ScenarioError, parse_scenario, read_toml
from tapmuscle.cosim.sweep import is_sweep_data, parse_sweep

__all__ = ["CheckCase", "CheckResult", "CollectionError", "collect_cases", "evaluate", "result_table", "junit_xml"]


@dataclass(frozen=True)
class CheckCase:
    """One scenario to run and check."""

    file: str
    """The scenario or sweep file."""
    name: str
    """The case's name: the scenario's, or for a sweep's run ``sweep/scenario [swept values]``."""
    scenario: Scenario
    """With its expectations (``scenario.expect``)."""


@dataclass(frozen=True)
class CheckResult:
    """A case, its run and the comparison with its expectations (None if the run failed).

    Parameters
    ----------
    case : CheckCase
        The case that was run.
    run : RunResult
        Its run.
    outcome : Outcome or None
        The comparison with the case's expectations; None if the run failed.
    """

    case: CheckCase
    run: RunResult
    outcome: Outcome | None

    @property
    def status(self) -> str:
        """``pass``, ``fail`` (an expectation missed) or ``error`` (the run failed)."""
        if self.outcome is None:
            return "error"
        return "pass" if self.outcome.passed else "fail"


def _files(path: Path) -> list[Path]:
    if path.is_dir():
        return sorted(path.rglob("*.toml"))
    if path.is_file():
        return [path]
    raise ScenarioError(f"{path}: no such file or folder")


@dataclass(frozen=True)
class CollectionError:
    """A path whose cases could not be collected: a bad scenario or sweep file, a missing path."""

    file: str
    """The path that could not be collected."""
    message: str
    """The :class:`ScenarioError`'s message, naming the file and the key."""


def collect_cases(paths: Iterable[str | Path], *,
                  errors: list[CollectionError] | None = None) -> tuple[list[CheckCase], list[str]]:
    """The cases under ``paths`` (files, or folders searched for ``*.toml``), and the files without
    expectations (skipped).

    Parameters
    ----------
    paths : iterable of str or Path
        Scenario or sweep files, or folders.
    errors : list, optional
        Where a bad file or a missing path is appended as a :class:`CollectionError` and collection
        goes on with the next file. Without it the first one raises.

    Raises
    ------
    ScenarioError
        A bad file (naming it and the key) or a missing path, without ``errors``.
    """
    cases: list[CheckCase] = []
    skipped: list[str] = []
    seen: set[Path] = set()
    for path in paths:
        try:
            files = _files(Path(path))
        except ScenarioError as exc:
            if errors is None:
                raise
            errors.append(CollectionError(str(path), str(exc)))
            continue
        for file in files:
            if file.resolve() in seen:
                continue
            seen.add(file.resolve())
            try:
                found = _file_cases(file)
            except ScenarioError as exc:
                if errors is None:
                    raise
                errors.append(CollectionError(str(file), str(exc)))
                continue
            cases += found
            if not found:
                skipped.append(str(file))
    return cases, skipped


def _file_cases(file: Path) -> list[CheckCase]:
    """The cases of one scenario or sweep file (those with expectations)."""
    cases: list[CheckCase] = []
    data = read_toml(file)
    if is_sweep_data(data):
        sweep = parse_sweep(data, source=str(file), folder=file.parent, default_name=file.stem)
        for run in sweep.runs:
            if run.scenario.expect:
                label = ", ".join(f"{f}={v!r}" for f, v in run.params)
                cases.append(CheckCase(str(file), f"{sweep.name}/{run.scenario.name}"
                                       + (f" [{label}]" if label else ""), run.scenario))
    else:
        scenario = parse_scenario(data, source=str(file), base=file.parent, default_name=file.stem)
        if scenario.expect:
            cases.append(CheckCase(str(file), scenario.name, scenario))
    return cases


def evaluate(case: CheckCase, run: RunResult) -> CheckResult:
    """Compare a finished run with its case's expectations.

    Parameters
    ----------
    case : CheckCase
        The case, with its expectations.
    run : RunResult
        Its finished run.
    """
    if run.status != "ok":
        return CheckResult(case, run, None)
    return CheckResult(case, run, check_expectations(case.scenario.expect, run.metrics))


def result_table(results: Sequence[CheckResult]) -> str:
    """A plain-text pass/fail table, one line per case, and a count. A name that several files give
    their cases is followed by the file, which tells them apart.

    Parameters
    ----------
    results : sequence of CheckResult
        The cases' results, one line each, in this order.
    """
    shared = {name for name in (r.case.name for r in results)
              if len({r.case.file for r in results if r.case.name == name}) > 1}
    names = [f"{r.case.name} ({r.case.file})" if r.case.name in shared else r.case.name for r in results]
    width = max([len(n) for n in names] + [8])
    # a controller of one's own's method (own:<its file>) is as long as its file's name
    method_width = max([len(r.case.scenario.method) for r in results] + [10])
    lines = [f"{'result':<6}  {'scenario':<{width}}  {'method':<{method_width}}  {'mae_mm':>7}  details"]
    for r, name in zip(results, names):
        mae = f"{r.run.metrics['mae_mm']:7.3f}" if "mae_mm" in r.run.metrics else f"{'-':>7}"
        if r.status == "error":
            detail = r.run.error
        elif r.status == "fail":
            detail = "; ".join(r.outcome.violations)
        else:
            n = len(r.outcome.checked)
            detail = f"{n} bound{'s' if n != 1 else ''} met"
        if r.run.fmu_warnings:
            detail += f" ({len(r.run.fmu_warnings)} FMU warnings: {r.run.fmu_warnings[0]})"
        lines.append(f"{r.status.upper():<6}  {name:<{width}}  {r.case.scenario.method:<{method_width}}  {mae}  {detail}")
    counts = {s: sum(r.status == s for r in results) for s in ("pass", "fail", "error")}
    lines.append(f"{len(results)} scenarios: {counts['pass']} passed, {counts['fail']} failed, "
                 f"{counts['error']} errors")
    return "\n".join(lines) + "\n"


def _classname(file: str) -> str:
    """A test case's class: its file's folder, dotted, as a CI's test view groups it (``scenarios.paper``);
    relative to the working folder where it lies under it, else without the root (no ``/.work...``)."""
    folder = Path(file).parent
    if folder.is_absolute():
        try:
            folder = folder.relative_to(Path.cwd())
        except ValueError:
            folder = folder.relative_to(folder.anchor)
    return ".".join(part for part in folder.parts if part not in (".", "..")) or "scenarios"


def junit_xml(results: Sequence[CheckResult], *, name: str = "tapmuscle check",
              errors: Sequence[CollectionError] = ()) -> str:
    """The results as JUnit XML: a ``testsuite`` per file, a ``testcase`` per scenario run; a missed
    expectation is a ``failure``, a run that failed an ``error``; the checked bounds and the metrics
    are in ``system-out``, what the FMUs warned of during the run in ``system-err``. Each of
    ``errors`` (files that could not be collected) is a ``testsuite`` of its file with one
    ``testcase`` whose ``error`` is the file's problem, as pytest reports a collection error.

    Parameters
    ----------
    results : sequence of CheckResult
        The cases' results.
    name : str, optional
        Name of the ``testsuites`` element; default ``"tapmuscle check"``.
    errors : sequence of CollectionError, optional
        Files whose cases could not be collected.
    """
    root = ET.Element("testsuites", name=name)
    for error in errors:
        suite = ET.SubElement(root, "testsuite", name=error.file, tests="1", failures="0", errors="1",
                              skipped="0", time="0.000")
        case = ET.SubElement(suite, "testcase", classname=_classname(error.file), name=Path(error.file).name,
                             time="0.000")
        ET.SubElement(case, "error", message=error.message[:500], type="ScenarioError").text = error.message
    suites: dict[str, list[CheckResult]] = {}
    for r in results:
        suites.setdefault(r.case.file, []).append(r)
    # a CI keys its test history on classname + name: a name that files in one folder share gets its file
    files_of: dict[tuple[str, str], set[str]] = {}
    for r in results:
        files_of.setdefault((_classname(r.case.file), r.case.name), set()).add(r.case.file)
    for file, members in suites.items():
        suite = ET.SubElement(root, "testsuite", name=file)
        classname = _classname(file)
        for r in members:
            wall = r.run.metrics.get("wall_time_s", 0.0)
            shown = r.case.name if len(files_of[classname, r.case.name]) == 1 else f"{r.case.name} ({Path(file).name})"
            case = ET.SubElement(suite, "testcase", classname=classname, name=shown, time=f"{wall:.3f}")
            if r.status == "error":
                ET.SubElement(case, "error", message=r.run.error[:500], type="RunFailed").text = r.run.error
            elif r.status == "fail":
                text = "\n".join(r.outcome.violations)
                ET.SubElement(case, "failure", message="; ".join(r.outcome.violations)[:500],
                              type="ExpectationNotMet").text = text
            out = [f"scenario file: {file}", f"method: {r.case.scenario.method}"]
            if r.outcome is not None:
                out += ["bounds:"] + [f"  {c}" for c in r.outcome.checked]
            out += ["metrics:"] + [f"  {k} = {v:.6g}" for k, v in r.run.metrics.items()]
            ET.SubElement(case, "system-out").text = "\n".join(out)
            if r.run.fmu_warnings:  # what the FMUs warned of: a CI's test view shows it beside the case
                ET.SubElement(case, "system-err").text = "\n".join(f"FMU warning: {w}" for w in r.run.fmu_warnings)
        _count(suite, members)
    _count(root, results)
    if errors:
        root.set("tests", str(len(results) + len(errors)))
        root.set("errors", str(int(root.get("errors")) + len(errors)))
    _xml_characters_only(root)
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


#: Characters XML 1.0 does not allow, escaped or not (control characters but tab and line breaks,
#: lone surrogates, U+FFFE/U+FFFF): one in a report makes the whole file unreadable to a CI.
_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def _xml_characters_only(root: ET.Element) -> None:
    """Show each character XML cannot carry as ``\\xNN`` (``\\uNNNN``) in every text and attribute
    of ``root``'s tree: an FMU's coloured message (ESC, BEL) or a name with a control character."""
    def shown(text: str) -> str:
        return _NOT_XML.sub(lambda m: f"\\x{ord(m[0]):02x}" if ord(m[0]) < 0x100 else f"\\u{ord(m[0]):04x}", text)

    for element in root.iter():
        if element.text:
            element.text = shown(element.text)
        for key, value in list(element.attrib.items()):
            element.set(key, shown(value))


def _count(element: ET.Element, results: Sequence[CheckResult]) -> None:
    element.set("tests", str(len(results)))
    element.set("failures", str(sum(r.status == "fail" for r in results)))
    element.set("errors", str(sum(r.status == "error" for r in results)))
    element.set("skipped", "0")
    element.set("time", f"{sum(r.run.metrics.get('wall_time_s', 0.0) for r in results):.3f}")
