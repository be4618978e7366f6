"""A rig's data-acquisition log read into a :class:`~tapmuscle.io.recording.Recording` (``tapmuscle import``).

A logger writes its own file: other column names, its own units (a command in percent, a length in
micrometres, a pressure in kPa, times in milliseconds, Unix seconds or ISO 8601 stamps), a semicolon
or a tab between fields and a decimal comma, a units row under the header, text columns. The caller
names the log's column of each quantity and its unit; everything else is read as it is:

* the field separator is the one of ``; <tab> ,`` the header row holds most of (or ``delimiter``);
* the decimal mark is a comma when the separator is not and a mapped cell reads ``12,5`` (or
  ``decimal``);
* leading ``#`` lines and blank lines are skipped, and so are ``#`` lines among the data (a
  logger's remarks) and one row under the header in which every mapped value is text (a units row);
* columns not mapped are ignored (text, status flags);
* times become seconds from the first sample (the first stamp as written is kept in the metadata
  ``start``): the recording format's ``t_s``; a time given as text is ISO 8601 or a day-first dotted
  date (``05.03.2024 10:00:00,5``, as a German locale writes it; dots never put the month first);
* a pressure from an absolute sensor (a unit of :data:`ABSOLUTE_UNITS`, ``bar_abs``) becomes the
  recording's gauge pressure: the ambient (``ambient_kpa``) is subtracted;
* a row that repeats the header among the data is a logger restarted into the same file: the log
  then holds several runs, each with its own clock, and one of them is read (``run``;
  :func:`rig_log_runs` counts them).

The values are converted, nothing else: no resampling. Timestamps that scatter about a uniform grid
by up to a quarter period are read as they are (the recording format accepts them,
docs/recordings.md); a dropped or doubled sample is refused by the recording's sampling check,
naming its line, unless ``fill_gaps_s`` puts dropped samples back (interpolated, and marked). A cell
that is empty or not a number is refused with its file, line and column.
"""

from __future__ import annotations

import csv
import math
import os
import re
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from tapmuscle.io.gc_paused import gc_paused
from tapmuscle.io.recording import Recording, RecordingError, read_text
from tapmuscle.io.sampling import SamplingError, uniform_sampling

__all__ = ["UNITS", "DEFAULT_UNITS", "ABSOLUTE_UNITS", "STANDARD_ATMOSPHERE_KPA", "MICRO_SIGNS", "LogColumn",
           "read_rig_log", "rig_log_runs", "parse_column_spec", "parse_time_text", "unit_key", "likely_pressure_unit"]

#: Per recording column, the units a log may hold it in and the factor to the recording's unit
#: (``None``: ISO 8601 date-time text). A command in percent is of the valve's 0..10 V range, one in
#: ``pwm`` an 8-bit duty cycle 0..255 (a microcontroller's ``analogWrite``) of the same range.
UNITS: dict[str, dict[str, float | None]] = {
    "t_s": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "min": 60.0, "h": 3600.0, "iso": None},
    "u_v": {"V": 1.0, "mV": 1e-3, "%": 0.1, "pwm": 10.0 / 255.0},
    "l_mm": {"mm": 1.0, "um": 1e-3, "cm": 10.0, "m": 1e3},
    "p_mpa": {"MPa": 1.0, "kPa": 1e-3, "bar": 0.1, "Pa": 1e-6, "psi": 6.894757293168361e-3,
              "MPa_abs": 1.0, "kPa_abs": 1e-3, "bar_abs": 0.1, "Pa_abs": 1e-6, "psi_abs": 6.894757293168361e-3},
    "load_n": {"N": 1.0, "kN": 1e3},
}
#: Pressure units of an absolute sensor: the recording holds gauge pressure, the reading less the
#: ambient (``ambient_kpa``, the standard atmosphere's 101.325 kPa unless given).
ABSOLUTE_UNITS = frozenset(unit for unit in UNITS["p_mpa"] if unit.endswith("_abs"))
STANDARD_ATMOSPHERE_KPA = 101.325
#: The micro prefix as loggers write it, the micro sign (U+00B5) and the Greek mu (U+03BC): read as
#: the ``u`` of :data:`UNITS` (``µm`` is ``um``, ``µs`` is ``us``).
MICRO_SIGNS = ("\u00b5", "\u03bc")
#: The unit assumed when a column is named without one: the recording format's.
DEFAULT_UNITS = {"t_s": "s", "u_v": "V", "l_mm": "mm", "p_mpa": "MPa", "load_n": "N"}

_SEPARATORS = (";", "\t", ",")
#: Names a user may give the tab (a shell passes ``'\t'`` as two characters).
DELIMITER_NAMES = {"tab": "\t", "\\t": "\t", "TAB": "\t"}
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")
_THOUSANDS = re.compile(r"^[+-]?\d{1,3}(\.\d{3})+$")
_INTEGER = re.compile(r"^[+-]?\d+$")
_DOTTED_DATE = re.compile(r"^(\d{1,2})\.(\d{1,2})\.(\d{4})[ T]+(\d{1,2}):(\d{2})(?::(\d{2})(?:[.,](\d{1,6}))?)?$")


def unit_key(unit: str) -> str:
    """``unit`` as :data:`UNITS` spells it: a leading micro sign or Greek mu (:data:`MICRO_SIGNS`) as ``u``."""
    return "u" + unit[1:] if unit[:1] in MICRO_SIGNS else unit


def likely_pressure_unit(written: float, given: str, *, near_mpa: float, within_mpa: float,
                         ambient_mpa: float | None = None) -> tuple[str, float] | None:
    """The pressure unit of :data:`UNITS` that reads the value ``written`` (as the log holds it, in the
    unit ``given``) nearest ``near_mpa`` [MPa(G)] (a rig's supply) within ``0 < p <= within_mpa``, and
    that reading [MPa(G)]; units of the same kind only (gauge, or absolute less the ambient
    ``ambient_mpa``, default the standard atmosphere). None if no unit reads it so."""
    units, absolute = UNITS["p_mpa"], unit_key(given) in ABSOLUTE_UNITS
    ambient = (1e-3 * STANDARD_ATMOSPHERE_KPA if ambient_mpa is None else ambient_mpa) if absolute else 0.0
    readings = {u: written * f - ambient for u, f in units.items()
                if u != unit_key(given) and (u in ABSOLUTE_UNITS) == absolute}
    fitting = {u: r for u, r in readings.items() if 0.0 < r <= within_mpa}
    if not fitting:
        return None
    best = min(fitting, key=lambda u: abs(math.log(fitting[u] / near_mpa)))
    return best, fitting[best]


def parse_time_text(cell: str) -> datetime:
    """A time stamp written as text: ISO 8601 (``2024-03-05T10:00:00.5``, as
    :meth:`datetime.fromisoformat` reads it) or a day-first dotted date (``05.03.2024 10:00:00,5``,
    the German locale's, with a decimal point or comma in the seconds). ``ValueError`` otherwise."""
    m = _DOTTED_DATE.match(cell)
    if m is None:
        return datetime.fromisoformat(cell)
    day, month, year, hour, minute, second, frac = m.groups()
    return datetime(int(year), int(month), int(day), int(hour), int(minute), int(second or 0),
                    int((frac or "0").ljust(6, "0")))


@dataclass(frozen=True)
class LogColumn:
    """The log's column that holds one recording column, and its unit.

    Parameters
    ----------
    column : str
        The column's name in the log's header row.
    unit : str
        Its unit, a key of :data:`UNITS` for the recording column it is read into (``"ms"``, ``"%"``,
        ``"um"``, ``"kPa"``, ``"iso"`` for time text, :func:`parse_time_text`, ...); ``µm`` and ``µs``
        (a micro sign or a Greek mu, :data:`MICRO_SIGNS`) are ``um`` and ``us``.
    """

    column: str
    unit: str

    def factor(self, target: str) -> float | None:
        """The factor to ``target``'s unit (None: ISO date-time text); ``ValueError`` naming the units known."""
        units = UNITS[target]
        key = unit_key(self.unit)
        if key not in units:
            known = ", ".join(f"{u} (or µ{u[1:]})" if u.startswith("u") and len(u) > 1 else u for u in units)
            raise ValueError(f"column {self.column!r}: unknown unit {self.unit!r} for {target} (known: {known})")
        return units[key]


def parse_column_spec(text: str, target: str) -> LogColumn:
    """``"NAME"`` or ``"NAME:UNIT"`` as a :class:`LogColumn` for the recording column ``target``.

    A colon followed by something that is not a unit of ``target`` is refused, naming the known
    units (a column whose name itself holds a colon can only be given with its unit)."""
    name, sep, unit = text.rpartition(":")
    if not sep:
        name, unit = text, DEFAULT_UNITS[target]
    name = name.strip()
    if not name:
        raise ValueError(f"{text!r}: no column name (expected NAME or NAME:UNIT)")
    col = LogColumn(name, unit.strip())
    col.factor(target)
    return col


def _refuse_thousands(path: Path, body: list, index: dict[str, int], header: list[str]) -> None:
    """Refuse a column of integers written with '.' thousands separators (``12``, ``1.350``), which a
    decimal point would read a thousand times too small: in it every cell with a '.' has groups of
    three digits after it, and other cells have none."""
    for j in index.values():
        cells = [(lineno, row[j].strip()) for lineno, row in body if j < len(row)]
        dotted = [(lineno, c) for lineno, c in cells if "." in c]
        if (0 < len(dotted) < len(cells) and all(_THOUSANDS.match(c) for _, c in dotted)
                and all(_INTEGER.match(c) for _, c in cells if "." not in c)):
            lineno, cell = dotted[0]
            raise RecordingError(f"{path}, line {lineno}, column {header[j]!r}: {cell!r} reads as a thousands separator "
                                 f"(the column holds integers without a '.' too): remove the separators, or give "
                                 f"--decimal '.' if they are decimals")


def _one_run(path: Path, body: list, header: list[str], header_line: int,
             run: int | None) -> tuple[list, str | None]:
    """The rows of run ``run`` (1-based) of a log whose rows repeating ``header`` separate runs, and
    which run it was of how many (None for a log of one run and no ``run``). A log of several runs
    without ``run``, or ``run`` beyond them, is refused naming the lines where each run starts."""
    repeats = _run_starts(body, header)
    if run is not None and not (isinstance(run, int) and not isinstance(run, bool) and run >= 1):
        raise RecordingError(f"{path}: run = {run!r} is not a run number (1 = the first)")
    if not repeats and run in (None, 1):
        return body, None
    starts = [header_line] + [body[k][0] for k in repeats]
    where = ", ".join(f"{i + 1} at line {line}" for i, line in enumerate(starts))
    if run is None:
        raise RecordingError(f"{path}, line {starts[1]}: the header again, a logger restarted into the same file: "
                             f"{len(starts)} runs ({where}), each with its own clock; import one with --run K")
    if run > len(starts):
        raise RecordingError(f"{path}: run {run} asked for, the log holds {len(starts)} ({where})")
    bounds = [-1] + repeats + [len(body)]
    rows = body[bounds[run - 1] + 1:bounds[run]]
    return rows, f"run {run} of {len(starts)} (header at line {starts[run - 1]})"


def _header_and_rows(path: Path, delimiter: str | None, skip_lines: int,
                     encoding: str) -> tuple[str, list[str], int, list[tuple[int, list[str]]]]:
    """The field separator, the header's column names, the header's line number and the rows under
    it with their line numbers (blank rows dropped; ``#`` remarks kept) of a log file."""
    if delimiter is not None:
        delimiter = DELIMITER_NAMES.get(delimiter, delimiter)
        if len(delimiter) != 1 or delimiter in "\"\r\n" or delimiter.isalnum() or delimiter in ".-+":
            raise RecordingError(f"{path}: delimiter {delimiter!r} is not one separating character (e.g. ';', ',', '|' "
                                 f"or {', '.join(repr(k) for k in DELIMITER_NAMES)})")
    if not (isinstance(skip_lines, int) and skip_lines >= 0):
        raise RecordingError(f"{path}: skip_lines = {skip_lines!r} is not a number of lines")
    lines = read_text(path, "log", encoding, "give its encoding (--encoding latin-1, cp1252, utf-16)").splitlines()
    i = skip_lines
    while i < len(lines) and (lines[i].lstrip().startswith("#") or not lines[i].strip()):
        i += 1
    if i >= len(lines):
        raise RecordingError(f"{path}: no header row")
    header_line = i + 1
    sep = delimiter or _separator(lines[i])
    rows = csv.reader(lines[i:], delimiter=sep)
    header = [h.strip() for h in next(rows)]
    # blank rows dropped (the first cell decides for most rows); a '#' line among the data is a
    # logger's remark (an operator's marker)
    body = [(lineno, row) for lineno, row in enumerate(rows, header_line + 1)
            if any(row) and (row[0].strip() or any(cell.strip() for cell in row))]
    return sep, header, header_line, body


def _run_starts(body: list, header: list[str]) -> list[int]:
    """Indices into ``body`` of the rows that repeat ``header``: a logger restarted into the file."""
    n, first = len(header), header[0] if header else None
    return [k for k, (_, row) in enumerate(body)
            if len(row) == n and row[0].strip() == first and [c.strip() for c in row] == header]


@gc_paused()
def rig_log_runs(path: str | os.PathLike, *, delimiter: str | None = None, skip_lines: int = 0,
                 encoding: str = "utf-8-sig") -> int:
    """How many runs a log holds: 1, plus one per row among the data that repeats the header (a
    logger restarted into the same file, each run with its own clock).

    Parameters
    ----------
    path : path
        The log file.
    delimiter, skip_lines, encoding
        As for :func:`read_rig_log`.

    Returns
    -------
    int
        The number of runs; :func:`read_rig_log` reads run ``K`` (``run=K``) for ``K = 1 .. runs``.
    """
    path = Path(path)
    _, header, _, rows = _header_and_rows(path, delimiter, skip_lines, encoding)
    return 1 + len(_run_starts(rows, header))


def _separator(header: str) -> str:
    counts = [header.count(s) for s in _SEPARATORS]
    return _SEPARATORS[int(np.argmax(counts))] if max(counts) else ","


def _filled(columns: dict[str, np.ndarray], line_of: np.ndarray, longest_s: float,
            where: str) -> tuple[dict[str, np.ndarray], np.ndarray, str | None]:
    """``columns`` with the samples a logger dropped put back, each column interpolated linearly
    across the gap (the command too: what the controller sent there was not logged), the log's line
    of each sample (a filled one: the line after its gap), and what was filled (None: nothing).
    A step more than 1.5 median periods long is a gap of ``round(step / period) - 1`` samples; one
    missing more than ``longest_s`` seconds is refused (``where`` names its line)."""
    t = columns["t_s"]
    dt = np.diff(t)
    ts = float(np.median(dt))
    gaps = np.nonzero(dt > 1.5 * ts)[0]
    if not gaps.size:
        return columns, line_of, None
    missing_s = dt[gaps] - ts
    if float(np.max(missing_s)) > longest_s + 0.5 * ts:
        g = int(gaps[np.argmax(missing_s > longest_s + 0.5 * ts)])
        raise RecordingError(f"{where.format(line_of[g + 1])}: {dt[g] - ts:.6g} s of samples are missing after "
                             f"t = {t[g]:.6g} s (from the first stamp), more than the {longest_s:g} s --fill-gaps fills")
    counts = np.maximum(np.rint(dt[gaps] / ts).astype(int) - 1, 1)
    at = np.repeat(gaps + 1, counts)
    new_t = np.concatenate([t[g] + dt[g] * np.arange(1, n + 1) / (n + 1) for g, n in zip(gaps, counts)])
    t_all = np.insert(t, at, new_t)
    out = {name: (t_all if name == "t_s" else np.interp(t_all, t, v)) for name, v in columns.items()}
    out["filled"] = np.insert(np.zeros(len(t)), at, 1.0)
    note = (f"{int(counts.sum())} dropped sample{'s' if counts.sum() > 1 else ''} in {gaps.size} "
            f"gap{'s' if gaps.size > 1 else ''} put back, each column interpolated linearly "
            f"(column filled = 1), the longest gap {float(np.max(missing_s)):.3g} s, the first after t = {t[gaps[0]]:.6g} s")
    return out, np.insert(line_of, at, line_of[at]), note


def _number(cell: str, decimal: str) -> float:
    """A cell as a number with the decimal mark ``decimal``; ``ValueError`` otherwise. A mark of the
    other kind is a thousands separator (1.350,5 or 1,350.5): refused, not read as a decimal (1.350 um
    read as 1.35 mm, off by a thousand)."""
    if ("." if decimal == "," else ",") in cell:
        raise ValueError(cell)
    return float(cell.replace(decimal, ".") if decimal != "." else cell)


def _is_number(cell: str, decimal: str) -> bool:
    try:
        _number(cell.strip(), decimal)
    except ValueError:
        return False
    return True


def _numbers(path: Path, lines: list[int], cells: list[str], column: str, decimal: str) -> np.ndarray:
    """The cells (of the log's ``lines``) of ``column`` as finite numbers, or a :class:`RecordingError`
    naming the first cell that is not one. All at once (numpy reads text as :func:`float` does, to
    the bit); cell by cell only to find the offending one."""
    other_mark = "." if decimal == "," else ","
    if not any(other_mark in cell for cell in cells):
        try:
            values = np.array(cells if decimal == "." else [c.replace(decimal, ".") for c in cells], dtype=float)
        except ValueError:
            pass
        else:
            bad = np.flatnonzero(~np.isfinite(values))
            if not bad.size:
                return values
            k = int(bad[0])
            raise RecordingError(f"{path}, line {lines[k]}, column {column!r}: {cells[k]!r} is not finite", lines[k])
    values = np.empty(len(cells))
    for k, (lineno, cell) in enumerate(zip(lines, cells)):
        try:
            values[k] = v = _number(cell, decimal)
        except ValueError:
            hint = ""
            if other_mark in cell:
                hint = (" with the decimal mark '.': a decimal comma (--decimal ',') or a thousands separator "
                        "(remove it)?" if other_mark == "," else
                        " with the decimal mark ',': '.' as a thousands separator? Remove it")
            raise RecordingError(f"{path}, line {lineno}, column {column!r}: {cell!r} is not a number{hint}",
                                 lineno) from None
        if not math.isfinite(v):
            raise RecordingError(f"{path}, line {lineno}, column {column!r}: {cell!r} is not finite", lineno)
    return values


def _seconds_from_text(path: Path, lines: list[int], cells: list[str], column: str) -> np.ndarray:
    """Time stamps written as text (:func:`parse_time_text`) as seconds from the first, or a
    :class:`RecordingError` naming the first that is not one or not comparable with the first."""
    values = np.empty(len(cells))
    first = None
    for k, (lineno, cell) in enumerate(zip(lines, cells)):
        try:
            stamp = parse_time_text(cell)
            first = first or stamp
            values[k] = (stamp - first).total_seconds()
        except (ValueError, TypeError) as exc:
            raise RecordingError(f"{path}, line {lineno}, column {column!r}: {cell!r} is not an ISO 8601 "
                                 f"(or day.month.year) time comparable with the first ({exc})", lineno) from None
    return values


@gc_paused()
def read_rig_log(path: str | os.PathLike, *, time: LogColumn | str, u: LogColumn | str, l: LogColumn | str,  # noqa: E741
                 p: LogColumn | str | None = None, load: LogColumn | str | None = None, load_n: float | None = None,
                 delimiter: str | None = None, decimal: str | None = None, fill_gaps_s: float = 0.0,
                 skip_lines: int = 0, encoding: str = "utf-8-sig", run: int | None = None,
                 ambient_kpa: float | None = None) -> Recording:
    """Read a rig's log as a recording (module docstring).

    Parameters
    ----------
    path : path
        The log file (text; a byte-order mark is ignored).
    time, u, l : LogColumn or str
        The log's columns of the time, the valve command and the encoder displacement, with their
        units (:data:`UNITS`): ``t_s`` [s from the first sample], ``u_v`` [V], ``l_mm`` [mm]. A string
        is ``"NAME"`` or ``"NAME:UNIT"`` (:func:`parse_column_spec`).
    p, load : LogColumn or str, optional
        The muscle pressure (``p_mpa`` [MPa]) and the load (``load_n`` [N]) columns.
    load_n : float, optional
        The hanging load [N] for the metadata (the recording's ``# load_n:``), when it is not a column.
    delimiter, decimal : str, optional
        Field separator and decimal mark (default: detected, module docstring).
    skip_lines : int
        Lines before the header to skip (a data-acquisition program's preamble, a board's boot
        messages), besides the leading ``#`` and blank lines.
    encoding : str
        The file's text encoding (default UTF-8, with or without a byte-order mark; e.g. ``latin-1``,
        ``cp1252``, ``utf-16`` for a spreadsheet's "Unicode text").
    fill_gaps_s : float
        Put back the samples a logger dropped, in gaps of up to this many seconds: every column
        interpolated linearly, a column ``filled`` (1 in a filled sample) and the metadata ``filled``
        saying what was done. 0 (default): a dropped sample is refused, naming its line.
    run : int, optional
        Which run to read (1 = the first) of a log a restarted logger wrote on: rows repeating the
        header separate the runs. Default: a log of one run; one of several is refused, naming the
        lines where the runs start.
    ambient_kpa : float, optional
        The ambient pressure [kPa] an absolute pressure (a unit of :data:`ABSOLUTE_UNITS`, e.g.
        ``"p_abs:bar_abs"``) is read against, to the recording's gauge pressure: the local
        barometric pressure, or the sensor's reading of the drained muscle. Default: the standard
        atmosphere, 101.325 kPa. Only with an absolute unit.

    Returns
    -------
    Recording
        Columns ``t_s, u_v, l_mm`` (and ``p_mpa``, ``load_n``); metadata ``source`` (the file and the
        conversions), ``start`` (the first time stamp as written) and ``load_n`` when given; the log's
        line of each sample as ``lines`` (a filled sample: the line after its gap).

    Raises
    ------
    RecordingError
        The file cannot be read, a mapped column is not in the header (naming the columns found),
        an unknown unit, a cell that is empty or not a number or not an ISO 8601 time (file, line,
        column), times that do not increase, a dropped or doubled sample or a clock that drifts, a gap
        longer than ``fill_gaps_s`` (line), a log of several runs without ``run`` or ``run`` beyond
        them.
    """
    path = Path(path)
    if load_n is not None and not (isinstance(load_n, (int, float)) and math.isfinite(load_n) and load_n > 0):
        raise RecordingError(f"{path}: load_n = {load_n!r} is not a positive number of newtons")
    if ambient_kpa is not None and not (isinstance(ambient_kpa, (int, float)) and 30.0 <= ambient_kpa <= 120.0):
        raise RecordingError(f"{path}: ambient_kpa = {ambient_kpa!r} is not an atmosphere's pressure (30..120 kPa)")
    if decimal is not None and decimal not in (".", ","):
        raise RecordingError(f"{path}: decimal = {decimal!r} is not a decimal mark ('.' or ',')")
    if (isinstance(fill_gaps_s, bool) or not isinstance(fill_gaps_s, (int, float)) or not math.isfinite(fill_gaps_s)
            or fill_gaps_s < 0):
        raise RecordingError(f"{path}: fill_gaps_s = {fill_gaps_s!r} is not a number of seconds >= 0 (0: refuse gaps)")
    given = {"t_s": time, "u_v": u, "l_mm": l, "p_mpa": p, "load_n": load}
    try:
        mapping = {target: parse_column_spec(col, target) if isinstance(col, str) else col
                   for target, col in given.items() if col is not None}
        factors = {target: col.factor(target) for target, col in mapping.items()}
    except ValueError as exc:
        raise RecordingError(f"{path}: {exc}") from None
    absolute = "p_mpa" in mapping and mapping["p_mpa"].unit in ABSOLUTE_UNITS
    if ambient_kpa is not None and not absolute:
        raise RecordingError(f"{path}: ambient_kpa is for an absolute pressure (a unit of {', '.join(sorted(ABSOLUTE_UNITS))}), "
                             f"the pressure is " + (f"in {mapping['p_mpa'].unit}" if "p_mpa" in mapping else "not mapped"))
    sep, header, header_line, rows = _header_and_rows(path, delimiter, skip_lines, encoding)
    index = {}
    for target, col in mapping.items():
        if col.column not in header:
            hint = ("; is a preamble before the header? --skip-lines N skips it" if len(header) < len(mapping) else "")
            raise RecordingError(f"{path}, line {header_line}: no column {col.column!r} for {target} (found, "
                                 f"separated by {sep!r}: {', '.join(header)}){hint}")
        index[target] = header.index(col.column)
    remarks = [lineno for lineno, row in rows if row[0].lstrip().startswith("#")]
    body = [(lineno, row) for lineno, row in rows if not row[0].lstrip().startswith("#")]
    body, run_note = _one_run(path, body, header, header_line, run)
    check_thousands = decimal is None  # a decimal mark given says what a '.' is
    if decimal is None:
        decimal = "."
        if sep != ",":
            cells = (row[j].strip() for _, row in body[:50] for j in index.values() if j < len(row))
            decimal = "," if any(_DECIMAL_COMMA.match(c) for c in cells) else "."

    skipped = None
    first = [body[0][1][j].strip() for target, j in index.items() if target != "t_s" and j < len(body[0][1])] if body else []
    if first and all(cell and not _is_number(cell, decimal) for cell in first):
        skipped, body = body[0][0], body[1:]  # a units row under the header: text in every mapped column
    if not body:
        raise RecordingError(f"{path}: header but no data rows")
    for lineno, row in body:
        # more fields than the header names shift every value after the extra one into the wrong
        # column (a decimal comma in a comma-separated log); empty trailing fields are a logger's habit
        if len(row) > len(header) and any(cell.strip() for cell in row[len(header):]):
            raise RecordingError(f"{path}, line {lineno}: {len(row)} fields, the header has {len(header)} (a decimal "
                                 f"comma or a stray {sep!r} in a value?): {sep.join(row)[:80]!r}")
    if check_thousands and decimal == ".":  # on the values alone: a units row is text in every column
        _refuse_thousands(path, body, {t: j for t, j in index.items() if factors[t] is not None}, header)
    columns: dict[str, np.ndarray] = {}
    start = ""
    line_numbers = [lineno for lineno, _ in body]
    # every column's first problem, so that the one reported is the first in the file (fixing the
    # log in one pass rather than one error per try)
    problems: list[RecordingError] = []
    times = None  # the time column's seconds, once read
    for target, j in index.items():
        col = mapping[target]
        try:
            cells = [row[j].strip() for _, row in body]
        except IndexError:
            lineno, row = next((lineno, row) for lineno, row in body if j >= len(row))
            raise RecordingError(f"{path}, line {lineno}: {len(row)} fields, no column {col.column!r} "
                                 f"(header has {len(header)})") from None
        try:
            if factors[target] is None:
                values = _seconds_from_text(path, line_numbers, cells, col.column)
            else:
                values = _numbers(path, line_numbers, cells, col.column, decimal)
        except RecordingError as exc:
            problems.append(exc)
            continue
        if target != "t_s":
            columns[target] = values * factors[target]
            if target == "p_mpa" and absolute:  # the recording holds gauge pressure
                columns[target] = columns[target] - 1e-3 * (ambient_kpa or STANDARD_ATMOSPHERE_KPA)
            continue
        start = body[0][1][j].strip()
        if factors[target] is not None:  # from the first sample in the log's own unit, then scaled:
            values = (values - values[0]) * factors[target]  # epoch stamps keep their digits
        bad = np.nonzero(np.diff(values) <= 0)[0]
        if bad.size:
            k = int(bad[0]) + 1
            problems.append(RecordingError(f"{path}, line {body[k][0]}, column {col.column!r}: time does not "
                                           f"increase ({body[k - 1][1][j].strip()!r}, then "
                                           f"{body[k][1][j].strip()!r})", body[k][0]))
            times = values
            continue
        columns[target] = times = values
    if problems and times is not None and not fill_gaps_s:  # a dropped sample among them
        # the stamps that go beyond all before them: a doubled or backward one left out, the grid stays
        keep = np.flatnonzero(times > np.maximum.accumulate(np.concatenate([[-np.inf], times[:-1]])))
        try:
            uniform_sampling(times[keep], column=mapping["t_s"].column)
        except SamplingError as exc:
            if exc.sample is not None:
                lineno = body[int(keep[exc.sample])][0]
                problems.append(RecordingError(f"{path}, line {lineno}: {exc} (times from the first stamp; or "
                                               "--fill-gaps S)", lineno))
    if problems:
        first = min(problems, key=lambda e: e.line)
        others = sorted({e.line for e in problems} - {first.line})
        if others:
            raise RecordingError(f"{first} (further problems at line{'s' if len(others) > 1 else ''} "
                                 f"{', '.join(map(str, others))})", first.line)
        raise first
    line_of = np.array([lineno for lineno, _ in body])
    filled = None
    if fill_gaps_s:
        columns, line_of, filled = _filled(columns, line_of, fill_gaps_s, f"{path}, line {{}}, column {mapping['t_s'].column!r}")
    try:  # a dropped or doubled sample named by the log's line
        uniform_sampling(columns["t_s"], column=mapping["t_s"].column)
    except SamplingError as exc:
        where = "" if exc.sample is None else f", line {line_of[exc.sample]}"
        raise RecordingError(f"{path}{where}: {exc} (times from the first stamp"
                             + ("; or --fill-gaps S" if not fill_gaps_s else "") + ")",
                             None if exc.sample is None else int(line_of[exc.sample])) from None
    used = ", ".join(f"{target} <- {col.column} [{col.unit}]" for target, col in mapping.items())
    metadata = {"source": f"tapmuscle import {path.name}: {used}", "start": start}
    if run_note:
        metadata["run"] = run_note
    if skipped is not None:
        metadata["units_row"] = f"line {skipped}, skipped"
    if remarks:
        metadata["remarks"] = (f"{len(remarks)} '#' line{'s' if len(remarks) > 1 else ''} among the data skipped "
                               f"(line {remarks[0]}" + (" and more)" if len(remarks) > 1 else ")"))
    if filled is not None:
        metadata["filled"] = filled
    if absolute:
        metadata["ambient_kpa"] = (f"{ambient_kpa or STANDARD_ATMOSPHERE_KPA:g}, subtracted from the absolute pressure"
                                   + ("" if ambient_kpa else " (the standard atmosphere)"))
    if load_n is not None:
        metadata["load_n"] = f"{load_n:g}"
    return Recording(columns, metadata, lines=line_of)
