"""A rig's data-acquisition log read into a :class:`~tapmuscle.io.recording.Recording` (``tapmuscle import``).

A logger writes its own file: other column names, its own units (a command in percent, a length in
micrometres, a pressure in kPa, times in milliseconds, Unix seconds or ISO 8601 stamps), a semicolon
or a tab between fields and a decimal comma, a units row under the header, text columns. The caller
names the log's column of each quantity and its unit; everything else is read as it is:

* the field separator is the one of ``; <tab> ,`` the header row holds most of (or ``delimiter``);
* the decimal mark is a comma when the separator is not and a mapped cell reads ``12,5`` (or
  ``decimal``);
* leading ``#`` lines and blank lines are skipped, and so are ``#`` lines among the data (a
  logger's remarks; a spreadsheet's error value such as ``#N/A`` is a missing value, not a remark)
  and one row under the header in which every mapped value is text (a units row);
* a column's unit that the log itself gives, in its name (``Druck [bar]``, ``Weg (mm)``,
  ``position_um``) or in the units row, is used where the caller gave none, and said in the
  metadata ``units``; one that contradicts the unit given is refused (a unit written that is none
  of :data:`UNITS` is said in ``units_unknown``);
* columns not mapped are ignored (text, status flags); a mapped name matches regardless of case;
* a row that repeats the row before it exactly (its time too) is a row written twice: dropped, and
  said in the metadata ``duplicates``;
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
naming its line, unless ``fill_gaps_s`` puts dropped samples back (interpolated, and marked; a row
with a missing value is then dropped and put back the same way). A cell that is empty or not a
number is refused with its file, line and column, and so is every other such cell the file holds. A
log without a time column, or with a sample counter for one, gets its times from ``ts_s``.
"""

from __future__ import annotations

import csv
import difflib
import math
import os
import re
import shlex
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path

import numpy as np

from tapmuscle.io.gc_paused import gc_paused
from tapmuscle.io.recording import Recording, RecordingError, read_text
from tapmuscle.io.sampling import SamplingError, period_change, uniform_sampling

__all__ = ["UNITS", "DEFAULT_UNITS", "ABSOLUTE_UNITS", "LINEAR_UNITS", "MA_RANGE", "UNIT_ALIASES", "MISSING_CELLS", "NAME_SUFFIX",
           "STANDARD_ATMOSPHERE_KPA", "MICRO_SIGNS", "LogColumn", "read_rig_log", "read_rig_log_columns",
           "rig_log_runs", "parse_column_spec", "parse_time_text", "unit_key", "unit_from_text",
           "likely_pressure_unit", "STANDARD_GRAVITY"]

#: Standard gravity [m/s^2]: a load logged as a mass in kg weighs this many newtons.
STANDARD_GRAVITY = 9.80665

#: Per recording column, the units a log may hold it in and the factor to the recording's unit
#: (``None``: ISO 8601 date-time text). A command in percent is of the valve's 0..10 V range, one in
#: ``pwm`` an 8-bit duty cycle 0..255 (a microcontroller's ``analogWrite``) of the same range.
UNITS: dict[str, dict[str, float | None]] = {
    "t_s": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "min": 60.0, "h": 3600.0, "iso": None},
    "u_v": {"V": 1.0, "mV": 1e-3, "%": 0.1, "pwm": 10.0 / 255.0},
    "l_mm": {"mm": 1.0, "um": 1e-3, "cm": 10.0, "m": 1e3},
    "p_mpa": {"MPa": 1.0, "kPa": 1e-3, "bar": 0.1, "Pa": 1e-6, "psi": 6.894757293168361e-3,
              "MPa_abs": 1.0, "kPa_abs": 1e-3, "bar_abs": 0.1, "Pa_abs": 1e-6, "psi_abs": 6.894757293168361e-3},
    "load_n": {"N": 1.0, "kN": 1e3, "kg": STANDARD_GRAVITY},  # kg: a mass hanging, its weight
}
#: Pressure units of an absolute sensor: the recording holds gauge pressure, the reading less the
#: ambient (``ambient_kpa``, the standard atmosphere's 101.325 kPa unless given).
ABSOLUTE_UNITS = frozenset(unit for unit in UNITS["p_mpa"] if unit.endswith("_abs"))
STANDARD_ATMOSPHERE_KPA = 101.325
#: The micro prefix as loggers write it, the micro sign (U+00B5) and the Greek mu (U+03BC): read as
#: the ``u`` of :data:`UNITS` (``µm`` is ``um``, ``µs`` is ``us``).
MICRO_SIGNS = ("\u00b5", "\u03bc")
#: The unit assumed when a column is named without one and the log gives none: the recording format's.
DEFAULT_UNITS = {"t_s": "s", "u_v": "V", "l_mm": "mm", "p_mpa": "MPa", "load_n": "N"}
#: Units read by a linear map rather than a factor: per recording column, ``(scale, offset)``, the
#: recording's value being ``scale * written + offset``. A 4-20 mA current loop carries the valve's
#: 0..10 V (4 mA is 0 V, 20 mA is 10 V).
LINEAR_UNITS: dict[str, dict[str, tuple[float, float]]] = {"u_v": {"mA": (10.0 / 16.0, -2.5)}}
#: The currents [mA] a 4-20 mA loop carries: a transmitter's under- and over-range about 4 and 20 mA
#: (NAMUR NE 43: 3.8..20.5); below 3.6 mA the loop is broken or the transmitter failed.
MA_RANGE = (3.5, 20.5)
#: Units as loggers write them in a header or a units row where :data:`UNITS` spells them otherwise
#: (a ``COL:UNIT`` given is spelt as :data:`UNITS` spells it). Case aside: ``KPA`` is ``kPa``.
UNIT_ALIASES = {"sec": "s", "secs": "s", "msec": "ms", "pct": "%", "percent": "%", "volt": "V", "volts": "V",
                "psig": "psi", "barg": "bar", "bar(g)": "bar", "psia": "psi_abs", "bara": "bar_abs",
                "bar(a)": "bar_abs"}
#: A spreadsheet's error values: a missing value in a cell, not a logger's ``#`` remark.
SPREADSHEET_ERRORS = ("#N/A", "#DIV/0!", "#VALUE!", "#NAME?", "#REF!", "#NUM!", "#NULL!", "#SPILL!", "#CALC!")
#: Cells (as written, any case) that stand for a missing value.
MISSING_CELLS = frozenset({"", "nan", "na", "n/a", "null", "none", "-", "--", *(e.lower() for e in SPREADSHEET_ERRORS)})
#: A step of time this close to an hour [s] in local stamps is a clock change.
_HOUR_S = 3600.0
#: Further problems listed per column in a refusal; beyond, they are counted.
_LISTED = 50

_SEPARATORS = (";", "\t", ",")
#: Names a user may give the tab (a shell passes ``'\t'`` as two characters).
DELIMITER_NAMES = {"tab": "\t", "\\t": "\t", "TAB": "\t"}
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")
_THOUSANDS = re.compile(r"^[+-]?\d{1,3}(\.\d{3})+$")
_INTEGER = re.compile(r"^[+-]?\d+$")
_DOTTED_DATE = re.compile(r"^(\d{1,2})\.(\d{1,2})\.(\d{4})[ T]+(\d{1,2}):(\d{2})(?::(\d{2})(?:[.,](\d{1,6}))?)?$")


def unit_key(unit: str) -> str:
    """``unit`` as :data:`UNITS` spells it: a leading micro sign or Greek mu (:data:`MICRO_SIGNS`) as ``u``.

    Parameters
    ----------
    unit : str
        A unit as written.
    """
    return "u" + unit[1:] if unit[:1] in MICRO_SIGNS else unit


def unit_from_text(text: str, target: str) -> str | None:
    """The unit of :data:`UNITS` (or :data:`LINEAR_UNITS`) for ``target`` that ``text`` names as a
    logger writes it (``[mm]``, ``µm``, ``KPA``, ``sec``, ``pct``: :data:`UNIT_ALIASES`); None if
    none.

    Parameters
    ----------
    text : str
        The unit as the log writes it (brackets and parentheses around it are ignored).
    target : str
        The recording column it is for (a key of :data:`UNITS`).
    """
    text = text.strip().strip("[]()").strip()
    known = {**UNITS[target], **LINEAR_UNITS.get(target, {})}
    key = unit_key(text)
    if key in known:
        return key
    alias = UNIT_ALIASES.get(key, UNIT_ALIASES.get(key.lower()))
    if alias in known:
        return alias
    folded = [unit for unit in known if unit.lower() == key.lower()]
    return folded[0] if len(folded) == 1 else None


def _linear_spec(unit: str) -> tuple[float, float] | None:
    """``scale=A,offset=B`` (either may be left out) as ``(A, B)``; None for a unit without ``=``."""
    if "=" not in unit:
        return None
    parts: dict[str, float] = {}
    for item in unit.split(","):
        key, eq, value = (x.strip() for x in item.partition("="))
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not eq or key not in ("scale", "offset") or key in parts or not math.isfinite(number):
            raise ValueError(f"{unit!r} is not a linear map scale=A,offset=B (finite numbers with a decimal "
                             "point, each at most once)")
        parts[key] = number
    if parts.get("scale", 1.0) == 0.0:
        raise ValueError(f"{unit!r}: a scale of 0 maps every value to the offset")
    return parts.get("scale", 1.0), parts.get("offset", 0.0)


def likely_pressure_unit(written: float, given: str, *, near_mpa: float, within_mpa: float,
                         ambient_mpa: float | None = None) -> tuple[str, float] | None:
    """The pressure unit of :data:`UNITS` that reads the value ``written`` (as the log holds it, in the
    unit ``given``) nearest ``near_mpa`` [MPa(G)] (a rig's supply) within ``0 < p <= within_mpa``, and
    that reading [MPa(G)]; units of the same kind only (gauge, or absolute less the ambient
    ``ambient_mpa``, default the standard atmosphere). None if no unit reads it so.

    Parameters
    ----------
    written : float
        The value as the log holds it.
    given : str
        The unit it was given in.
    near_mpa : float
        The reading to come nearest to [MPa(G)] (a rig's supply).
    within_mpa : float
        The largest reading taken [MPa(G)].
    ambient_mpa : float, optional
        The ambient pressure [MPa] subtracted from an absolute unit's reading; None (default):
        the standard atmosphere.
    """
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
    the German locale's, with a decimal point or comma in the seconds). ``ValueError`` otherwise.

    Parameters
    ----------
    cell : str
        The cell's text.
    """
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
        Its unit, a key of :data:`UNITS` or :data:`LINEAR_UNITS` for the recording column it is read
        into (``"ms"``, ``"%"``, ``"um"``, ``"kPa"``, ``"mA"``, ``"iso"`` for time text,
        :func:`parse_time_text`, ...), or a linear map ``"scale=A,offset=B"`` (the recording's value
        is ``A * written + B``); ``µm`` and ``µs`` (a micro sign or a Greek mu, :data:`MICRO_SIGNS`)
        are ``um`` and ``us``.
    declared : bool
        Whether the caller gave the unit (False: the default, which a unit the log gives replaces).
    origin : str
        Where in the log a unit not given was read (``"its name"``, ``"the units row, line 2"``, or
        :data:`NAME_SUFFIX`, which a unit given overrides); empty for a unit given or the default.
    """

    column: str
    unit: str
    declared: bool = field(default=True, compare=False)
    origin: str = field(default="", compare=False)

    def conversion(self, target: str) -> tuple[float, float] | None:
        """``(scale, offset)`` to ``target``'s unit (None: ISO date-time text); ``ValueError`` naming
        the units known."""
        linear = self._linear(target)
        if linear is not None:
            return linear
        factor = self.factor(target)
        return None if factor is None else (factor, 0.0)

    def _linear(self, target: str) -> tuple[float, float] | None:
        """The linear map (``scale=A,offset=B``, or a unit such as ``mA`` that is one), else None."""
        return _linear_spec(self.unit) or LINEAR_UNITS.get(target, {}).get(unit_key(self.unit))

    def factor(self, target: str) -> float | None:
        """The factor to ``target``'s unit of a plain unit (None: ISO date-time text); ``ValueError``
        naming the units known, or for a linear map, which has an offset too (:meth:`conversion`)."""
        units = UNITS[target]
        key = unit_key(self.unit)
        if self._linear(target) is not None:
            raise ValueError(f"column {self.column!r}: {self.unit!r} is a linear map with an offset, not a factor "
                             "(LogColumn.conversion gives its scale and offset)")
        if key not in units:
            known = ", ".join(f"{u} (or µ{u[1:]})" if u.startswith("u") and len(u) > 1 else u for u in units)
            extra = "".join(f"; {u} ({_LINEAR_MEANING[target, u]})" for u in LINEAR_UNITS.get(target, {}))
            raise ValueError(f"column {self.column!r}: unknown unit {self.unit!r} for {target} (known: {known}){extra}; "
                             "or a linear map scale=A,offset=B (the value is A x written + B)")
        return units[key]


_LINEAR_MEANING = {("u_v", "mA"): "a 4-20 mA current loop of the valve's 0..10 V"}


def parse_column_spec(text: str, target: str) -> LogColumn:
    """``"NAME"`` or ``"NAME:UNIT"`` as a :class:`LogColumn` for the recording column ``target``.

    A colon followed by something that is not a unit of ``target`` is refused, naming the known
    units (a column whose name itself holds a colon can only be given with its unit). Without a
    unit, the column's unit is the default (:data:`DEFAULT_UNITS`, ``declared`` False), which a unit
    the log gives replaces.

    Parameters
    ----------
    text : str
        ``"NAME"`` or ``"NAME:UNIT"``.
    target : str
        The recording column it is read into (``"t_s"``, ``"u_v"``, ``"l_mm"``, ``"p_mpa"``,
        ``"load_n"``).
    """
    name, sep, unit = text.rpartition(":")
    declared = bool(sep)
    if not sep:
        name, unit = text, DEFAULT_UNITS[target]
    name = name.strip()
    if not name:
        raise ValueError(f"{text!r}: no column name (expected NAME or NAME:UNIT)")
    col = LogColumn(name, unit.strip(), declared)
    try:
        col.conversion(target)
    except ValueError as exc:
        if str(exc).startswith("column "):
            raise
        raise ValueError(f"column {name!r}: {exc}") from None
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
    lines = _log_lines(path, encoding)
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


def _log_lines(path: Path, encoding: str) -> list[str]:
    """The log's lines; a file that starts with a UTF-16 byte-order mark (a spreadsheet's "Unicode
    text") is read as UTF-16 when no other encoding than the default was given."""
    if encoding == "utf-8-sig":
        try:
            with open(path, "rb") as f:
                if f.read(2) in (b"\xff\xfe", b"\xfe\xff"):
                    encoding = "utf-16"
        except OSError:
            pass  # read_text names the problem
    return read_text(path, "log", encoding, "give its encoding (--encoding latin-1, cp1252, utf-16)").splitlines()


def _is_remark(row: list[str]) -> bool:
    """A '#' line among the data: a logger's remark; a spreadsheet's error value (``#N/A``) in the
    first cell is a missing value, not a remark."""
    first = row[0].strip() if row else ""
    return first.startswith("#") and first.upper() not in SPREADSHEET_ERRORS


def _missing(cell: str) -> bool:
    return cell.strip().lower() in MISSING_CELLS


def _is_units_row(row: list[str], index: dict[str, int], decimal: str) -> bool:
    """Whether the first row under the header is a units row: no number in a mapped column, and text
    in at least one besides the time's (which may be empty: ISO text has no unit)."""
    cells = {target: row[j].strip() if j < len(row) else "" for target, j in index.items()}
    if any(_is_number(cell, decimal) or cell.upper() in SPREADSHEET_ERRORS for cell in cells.values()):
        return False
    return any(cell for target, cell in cells.items() if target != "t_s")


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
    change = period_change(t)
    if change is not None:  # the samples of the longer period are not dropped ones: filling would resample
        k, first, second = change
        raise RecordingError(f"{where.format(line_of[k])}: the sampling period changes between t = {t[k - 1]:.6g} and "
                             f"{t[k]:.6g} s (from the first stamp), from {first:.6g} s to {second:.6g} s; --fill-gaps puts back samples a "
                             "logger dropped and does not resample: split the log there into two recordings")
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


def _cell_problem(cell: str, decimal: str, finite_number: bool) -> str:
    """Why a cell of a numeric column is refused (``finite_number``: it reads as a number, not finite)."""
    other_mark = "." if decimal == "," else ","
    if _missing(cell):
        what = "is not finite" if finite_number or cell.strip().lower() == "nan" else "is not a number"
        return f"{cell!r} {what}: a missing value (mend the log, or --fill-gaps S puts the row back, interpolated)"
    if finite_number:
        return f"{cell!r} is not finite"
    hint = ""
    if other_mark in cell:
        hint = (" with the decimal mark '.': a decimal comma (--decimal ',') or a thousands separator "
                "(remove it)?" if other_mark == "," else
                " with the decimal mark ',': '.' as a thousands separator? Remove it")
    return f"{cell!r} is not a number{hint}"


def _numbers(path: Path, lines: list[int], cells: list[str], column: str,
             decimal: str) -> tuple[np.ndarray, list[_Problem]]:
    """The cells (of the log's ``lines``) of ``column`` as numbers, NaN where a cell is not a finite
    number, and a problem for each such cell. All at once (numpy reads text as :func:`float` does,
    to the bit); cell by cell only to find the offending ones."""
    other_mark = "." if decimal == "," else ","
    if not any(other_mark in cell for cell in cells):
        try:
            values = np.array(cells if decimal == "." else [c.replace(decimal, ".") for c in cells], dtype=float)
        except ValueError:
            pass
        else:
            bad = np.flatnonzero(~np.isfinite(values))
            values[bad] = np.nan
            return values, [_Problem(lines[k], column, f"{path}, line {lines[k]}, column {column!r}: "
                                     + _cell_problem(cells[k], decimal, True)) for k in bad]
    values = np.full(len(cells), np.nan)
    problems = []
    for k, (lineno, cell) in enumerate(zip(lines, cells)):
        try:
            v = _number(cell, decimal)
        except ValueError:
            problems.append(_Problem(lineno, column, f"{path}, line {lineno}, column {column!r}: "
                                     + _cell_problem(cell, decimal, False)))
            continue
        if not math.isfinite(v):
            problems.append(_Problem(lineno, column, f"{path}, line {lineno}, column {column!r}: "
                                     + _cell_problem(cell, decimal, True)))
            continue
        values[k] = v
    return values, problems


def _seconds_from_text(path: Path, lines: list[int], cells: list[str],
                       column: str) -> tuple[np.ndarray, list[_Problem], bool]:
    """Time stamps written as text (:func:`parse_time_text`) as seconds from the first (NaN where a
    stamp is not one), a problem for each stamp that is not one or not comparable with the first,
    and whether the stamps are local times (no UTC offset)."""
    values = np.full(len(cells), np.nan)
    problems = []
    first = None
    for k, (lineno, cell) in enumerate(zip(lines, cells)):
        try:
            stamp = parse_time_text(cell)
            first = first or stamp
            values[k] = (stamp - first).total_seconds()
        except (ValueError, TypeError) as exc:
            what = ("a missing value (mend the log, or --fill-gaps S puts the row back, interpolated)" if _missing(cell)
                    else f"not an ISO 8601 (or day.month.year) time comparable with the first ({exc})")
            problems.append(_Problem(lineno, column, f"{path}, line {lineno}, column {column!r}: {cell!r} is {what}"))
    return values, problems, first is not None and first.tzinfo is None


@dataclass(frozen=True)
class _Problem:
    """One thing wrong in a log: its line, what it is grouped by in a refusal's list of further
    problems (a column's name, or a kind of row), and the message that names it."""

    line: int
    label: str
    message: str


def _refusal(problems: list[_Problem]) -> RecordingError:
    """The refusal of a log: the first problem in the file, and the lines of every other, grouped by
    column (:data:`_LISTED` each, the rest counted), so that the log is mended in one pass."""
    first = min(problems, key=lambda e: e.line)
    others: dict[str, set[int]] = {}
    for e in problems:
        if (e.line, e.label) != (first.line, first.label):
            others.setdefault(e.label, set()).add(e.line)
    if not others:
        return RecordingError(first.message, first.line)
    parts = []
    for label, found in sorted(others.items(), key=lambda item: min(item[1])):
        lines = sorted(found)
        more = f" and {len(lines) - _LISTED} more" if len(lines) > _LISTED else ""
        name = f"column {label!r}" if not label.startswith("(") else label[1:-1]
        parts.append(f"{name} at line{'s' if len(lines) > 1 else ''} {', '.join(map(str, lines[:_LISTED]))}{more}")
    return RecordingError(f"{first.message} (further problems: {'; '.join(parts)})", first.line)


def _file_units(path: Path, mapping: dict[str, LogColumn], header_line: int, units_row: tuple[int, list[str]] | None,
                index: dict[str, int], counter: bool) -> tuple[dict[str, LogColumn], list[str], list[str]]:
    """The columns with the units the log gives (in a column's name, ``Druck [bar]``, ``position_um``,
    or in its units row) where the caller gave none; what was taken from the log, and the units the
    log writes that are none known. A unit the log gives that contradicts the one given, or a name
    and a units row that contradict each other, is refused naming the column, both units and the
    line."""
    used, unknown, out = [], [], dict(mapping)
    for target, col in mapping.items():
        if target == "t_s" and (counter or (col.declared and col.conversion(target) is None)):
            continue  # a sample counter, or ISO text: a unit written there is a format, not a factor
        if col.declared and _linear_spec(col.unit) is not None:
            continue  # a map given for this log: its own unit is what it maps from
        found = []  # (as written, the unit it names or None, where, line)
        m = _BRACKETED.search(col.column)
        # a unit has no digits (none this log's columns take does): "(ch1)", "[AI0]" name a channel
        if m and m[1] and len(m[1]) <= 12 and not any(c.isspace() or c.isdigit() for c in m[1]):
            found.append((m[1], unit_from_text(m[1], target), "its name", header_line))
        elif "_" in col.column.strip("_"):
            suffix = col.column.rpartition("_")[2]
            key = unit_from_text(suffix, target)  # a name's suffix counts only as a unit known
            if key is not None and col.declared and key.removesuffix("_abs") != unit_key(col.unit).removesuffix("_abs"):
                # a weaker claim than brackets (t_s may be a column renamed to the recording's name
                # and left in ms): the unit given is read, and the difference said
                used.append(f"{target} in {col.unit} as given, though its name {col.column!r} says {key}")
            elif key is not None:
                found.append((suffix, key, NAME_SUFFIX, header_line))
        if units_row is not None:
            line, cells = units_row
            cell = cells[index[target]].strip() if index[target] < len(cells) else ""
            if cell and cell not in ("-", "--"):
                found.append((cell, unit_from_text(cell, target), f"the units row, line {line}", line))
        for text, key, where, _ in found:
            if key is None:
                unknown.append(f"column {col.column!r} ({target}): {text!r} ({where}) is no unit known for {target}, "
                               f"read as {col.unit}" + ("" if col.declared else " (the default; give its unit as "
                                                                                 "COLUMN:UNIT)"))
        known = [(text, key, where, line) for text, key, where, line in found if key is not None]
        if not known:
            continue
        given = unit_key(col.unit).removesuffix("_abs") if col.declared else None
        for text, key, where, line in known:
            if given is not None and key.removesuffix("_abs") != given:
                raise RecordingError(f"{path}, line {line}, column {col.column!r} ({target}): the log gives its unit as "
                                     f"{text!r} ({where}), the unit given is {col.unit!r}: give it as the log does "
                                     f"({shlex.quote(col.column + ':' + key)}), or as scale=A,offset=B if the log's "
                                     "unit is wrong", line)
        if len({key.removesuffix("_abs") for _, key, _, _ in known}) > 1:
            (t1, _, w1, _), (t2, _, w2, line) = known[0], known[-1]
            raise RecordingError(f"{path}, line {line}, column {col.column!r} ({target}): {w1} says {t1!r}, {w2} "
                                 f"{t2!r}: give the column's unit (COLUMN:UNIT)", line)
        if not col.declared:
            text, key, where, _ = known[-1]
            out[target] = LogColumn(col.column, key, False, where)
            if key != col.unit:
                used.append(f"{target} in {key}, as the log says ({col.column!r}: {where}; no unit given)")
    return out, used, unknown


#: Where a unit read from a name's ``_suffix`` came from (:attr:`LogColumn.origin`): a weaker claim
#: than brackets or a units row, which a unit given overrides.
NAME_SUFFIX = "its name's suffix"
_BRACKETED = re.compile(r"[\[(]\s*([^\[\]()]*?)\s*[\])]\s*$")


def _column_index(path: Path, mapping: dict[str, LogColumn], header: list[str], header_line: int, sep: str,
                  encoding: str, delimiter: str | None) -> tuple[dict[str, LogColumn], dict[str, int], list[str]]:
    """Each mapped column's index in the header, the columns as the header spells them (a name
    given in another case matches one header name), and what was matched so. A name not in the
    header is refused, naming the columns found and a line that holds every name given (a preamble
    before the header: ``--skip-lines``) or the header's name nearest it."""
    index, renamed, out = {}, [], dict(mapping)
    folded = {}
    for j, h in enumerate(header):
        folded.setdefault(" ".join(h.split()).casefold(), []).append(j)
    for target, col in mapping.items():
        if col.column in header:
            index[target] = header.index(col.column)
            continue
        near = folded.get(" ".join(col.column.split()).casefold(), [])
        if len(near) == 1:
            index[target] = near[0]
            out[target] = replace(col, column=header[near[0]])
            renamed.append(f"{col.column!r} is the log's {header[near[0]]!r}")
            continue
        hint = ""
        holding = _line_holding(path, encoding, delimiter, [c.column for c in mapping.values()])
        if holding is not None and holding != header_line:
            hint = f"; line {holding} holds every column named: --skip-lines {holding - 1} reads the header there"
        elif len(header) < len(mapping):
            hint = "; is a preamble before the header? --skip-lines N skips it"
        else:
            close = difflib.get_close_matches(col.column, header, n=1, cutoff=0.6)
            hint = f"; did you mean {close[0]!r}?" if close else ""
        raise RecordingError(f"{path}, line {header_line}: no column {col.column!r} for {target} (found, "
                             f"separated by {sep!r}: {', '.join(header)}){hint}")
    return out, index, renamed


def _line_holding(path: Path, encoding: str, delimiter: str | None, names: list[str]) -> int | None:
    """The first line (1-based, of the first thousand) whose fields hold every one of ``names``
    (any case)."""
    wanted = {" ".join(n.split()).casefold() for n in names}
    for k, line in enumerate(_log_lines(path, encoding)[:1000]):
        sep = DELIMITER_NAMES.get(delimiter, delimiter) if delimiter else _separator(line)
        cells = next(csv.reader([line], delimiter=sep), [])
        if wanted <= {" ".join(c.split()).casefold() for c in cells}:
            return k + 1
    return None


def _clock_change(steps_s: np.ndarray, ts_s: float) -> np.ndarray:
    """Which steps [s] are a local clock put forward or back by an hour, one period either side."""
    return np.abs(np.abs(steps_s) - _HOUR_S) <= 2.0 * ts_s + 1e-3 * _HOUR_S


_DST = ("a clock change (DST)? The stamps carry no UTC offset (local time): log UTC or with the offset "
        "(2024-03-31T03:00:00+02:00)")


def _sampling_problems(path: Path, times: np.ndarray, line_of: np.ndarray, column: str, fill_gaps_s: float,
                       local: bool, alone: bool) -> list[_Problem]:
    """The problems of times off a uniform grid, each step off it by its line (the sample after it);
    a step of an hour in local stamps is said to be a clock change. A problem of no one sample (too
    few samples) is refused when ``alone`` (no other problems), else left to them."""
    try:
        uniform_sampling(times, column=column, where=lambda k: f"line {line_of[k]}")
    except SamplingError as exc:
        if exc.sample is None:
            if alone:
                raise RecordingError(f"{path}: {exc} (times from the first stamp)") from None
            return []
        message = f"{path}, line {line_of[exc.sample]}: {exc} (times from the first stamp" + (
            "; or --fill-gaps S)" if not fill_gaps_s and not exc.period_change else ")")
        steps = np.array(exc.steps or (exc.sample,))
        if local:
            dt = times[steps] - times[steps - 1]
            hour = steps[_clock_change(dt, float(np.median(np.diff(times))))]
            if hour.size:
                message += f"; the step at line {line_of[hour[0]]} is an hour: {_DST}"
        main = _Problem(int(line_of[exc.sample]), column, message)
        return [main] + [_Problem(int(line_of[k]), column, message) for k in steps if k != exc.sample]
    return []


def _counter_note(column: str, values: np.ndarray) -> str | None:
    """A note when a time column in seconds holds consecutive integers: a sample counter, which makes
    the period 1 s."""
    if len(values) > 2 and np.all(values == np.round(values)) and np.all(np.diff(values) == 1.0):
        return (f"column {column!r} counts {values[0]:.0f}, {values[1]:.0f}, {values[2]:.0f}, ... (consecutive "
                "integers), read as seconds: a sampling period of 1 s. If it counts samples, give the period "
                "(tapmuscle import --ts S, with or without --time; ts_s=S)")
    return None


def read_rig_log(path: str | os.PathLike, *, time: LogColumn | str | None = None, u: LogColumn | str,
                 l: LogColumn | str,  # noqa: E741
                 p: LogColumn | str | None = None, load: LogColumn | str | None = None, load_n: float | None = None,
                 delimiter: str | None = None, decimal: str | None = None, fill_gaps_s: float = 0.0,
                 skip_lines: int = 0, encoding: str = "utf-8-sig", run: int | None = None,
                 ambient_kpa: float | None = None, ts_s: float | None = None) -> Recording:
    """Read a rig's log as a recording (module docstring).

    Parameters
    ----------
    path : path
        The log file (text; a byte-order mark is ignored).
    time, u, l : LogColumn or str
        The log's columns of the time, the valve command and the encoder displacement, with their
        units (:data:`UNITS`): ``t_s`` [s from the first sample], ``u_v`` [V], ``l_mm`` [mm]. A string
        is ``"NAME"`` or ``"NAME:UNIT"`` (:func:`parse_column_spec`); without a unit, the one the log
        gives for the column (in its name, ``Druck [bar]``, or its units row) is used, else the
        default (:data:`DEFAULT_UNITS`). ``time`` may be left out with ``ts_s``.
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
        The file's text encoding (default UTF-8, with or without a byte-order mark, or UTF-16 when the
        file starts with its byte-order mark; e.g. ``latin-1``, ``cp1252``).
    fill_gaps_s : float
        Put back the samples a logger dropped, in gaps of up to this many seconds: every column
        interpolated linearly, a column ``filled`` (1 in a filled sample) and the metadata ``filled``
        saying what was done; a row with a missing value in a mapped column (empty, ``NaN``, ``#N/A``:
        :data:`MISSING_CELLS`) is dropped first (the metadata ``missing``) and put back so. 0
        (default): a dropped sample or a missing value is refused, naming its line.
    run : int, optional
        Which run to read (1 = the first) of a log a restarted logger wrote on: rows repeating the
        header separate the runs. Default: a log of one run; one of several is refused, naming the
        lines where the runs start.
    ambient_kpa : float, optional
        The ambient pressure [kPa] an absolute pressure (a unit of :data:`ABSOLUTE_UNITS`, e.g.
        ``"p_abs:bar_abs"``) is read against, to the recording's gauge pressure: the local
        barometric pressure, or the sensor's reading of the drained muscle. Default: the standard
        atmosphere, 101.325 kPa. Only with an absolute unit.
    ts_s : float, optional
        The sampling period [s] for a log without a time column (``time`` left out: sample ``k`` of
        the log, counted from its first data row, is at ``k * ts_s``) or with a sample counter for one
        (``time`` given without a unit: its integers times ``ts_s``, so that a count skipped is a
        dropped sample).

    Returns
    -------
    Recording
        Columns ``t_s, u_v, l_mm`` (and ``p_mpa``, ``load_n``); metadata ``source`` (the file and the
        conversions), ``start`` (the first time stamp as written) and ``load_n`` when given, and
        what was read other than as given (``units``, ``units_unknown``, ``names``, ``duplicates``,
        ``missing``, ``time_counter``, ...); the log's line of each sample as ``lines`` (a filled
        sample: the line after its gap).

    Raises
    ------
    RecordingError
        The file cannot be read, a mapped column is not in the header (naming the columns found,
        and the line that holds them all), an unknown unit or one that contradicts the log's own,
        a cell that is empty or not a number or not an ISO 8601 time (file, line, column), a current
        outside a 4-20 mA loop's, times that do not increase, a dropped or doubled sample or a clock
        that drifts, a gap longer than ``fill_gaps_s`` (line), a log of several runs without ``run``
        or ``run`` beyond them. The first problem in the file is named, with the lines of every other.
    """
    return read_rig_log_columns(path, time=time, u=u, l=l, p=p, load=load, load_n=load_n, delimiter=delimiter,
                                decimal=decimal, fill_gaps_s=fill_gaps_s, skip_lines=skip_lines, encoding=encoding,
                                run=run, ambient_kpa=ambient_kpa, ts_s=ts_s)[0]


@gc_paused()
def read_rig_log_columns(path: str | os.PathLike, *, time: LogColumn | str | None = None, u: LogColumn | str,
                         l: LogColumn | str,  # noqa: E741
                         p: LogColumn | str | None = None, load: LogColumn | str | None = None,
                         load_n: float | None = None, delimiter: str | None = None, decimal: str | None = None,
                         fill_gaps_s: float = 0.0, skip_lines: int = 0, encoding: str = "utf-8-sig",
                         run: int | None = None, ambient_kpa: float | None = None,
                         ts_s: float | None = None) -> tuple[Recording, dict[str, LogColumn]]:
    """:func:`read_rig_log`, and the log's columns as read: per recording column, the log's name of
    it and the unit it was read in (the one given, else the log's own, else the default).

    Parameters
    ----------
    path, time, u, l, p, load, load_n, delimiter, decimal, fill_gaps_s, skip_lines, encoding, run, ambient_kpa, ts_s
        As :func:`read_rig_log`'s.
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
    if ts_s is not None and (isinstance(ts_s, bool) or not isinstance(ts_s, (int, float)) or not math.isfinite(ts_s)
                             or ts_s <= 0):
        raise RecordingError(f"{path}: ts_s = {ts_s!r} is not a sampling period [s]")
    if time is None and ts_s is None:
        raise RecordingError(f"{path}: no time column and no ts_s: give the log's time column, or the sampling "
                             "period that builds the times from the row numbers")
    given = {"t_s": time, "u_v": u, "l_mm": l, "p_mpa": p, "load_n": load}
    try:
        mapping = {target: parse_column_spec(col, target) if isinstance(col, str) else col
                   for target, col in given.items() if col is not None}
        for target, col in mapping.items():
            col.conversion(target)
    except ValueError as exc:
        raise RecordingError(f"{path}: {exc}") from None
    counter = ts_s is not None and "t_s" in mapping
    if counter and mapping["t_s"].declared:
        raise RecordingError(f"{path}: ts_s builds the times from a column of sample numbers: give the time column "
                             f"{mapping['t_s'].column!r} without a unit (it is given in {mapping['t_s'].unit}), or "
                             "leave ts_s out")
    if ambient_kpa is not None and ("p_mpa" not in mapping or mapping["p_mpa"].declared):
        _refuse_ambient(path, mapping)
    sep, header, header_line, rows = _header_and_rows(path, delimiter, skip_lines, encoding)
    mapping, index, renamed = _column_index(path, mapping, header, header_line, sep, encoding, delimiter)
    remarks = [lineno for lineno, row in rows if _is_remark(row)]
    body = [(lineno, row) for lineno, row in rows if not _is_remark(row)]
    body, run_note = _one_run(path, body, header, header_line, run)
    check_thousands = decimal is None  # a decimal mark given says what a '.' is
    if decimal is None:
        decimal = "."
        if sep != ",":
            cells = (row[j].strip() for _, row in body[:50] for j in index.values() if j < len(row))
            decimal = "," if any(_DECIMAL_COMMA.match(c) for c in cells) else "."

    units_row = None
    if body and _is_units_row(body[0][1], index, decimal):
        units_row, body = (body[0][0], body[0][1]), body[1:]
    if not body:
        raise RecordingError(f"{path}: header but no data rows")
    mapping, units_used, units_unknown = _file_units(path, mapping, header_line, units_row, index, counter)
    conversions = {target: col.conversion(target) for target, col in mapping.items()}
    absolute = "p_mpa" in mapping and unit_key(mapping["p_mpa"].unit) in ABSOLUTE_UNITS
    if ambient_kpa is not None:
        _refuse_ambient(path, mapping)
    duplicates = []
    if "t_s" in mapping:  # without a time column, equal rows are samples of a muscle at rest
        duplicates = [body[k][0] for k in range(1, len(body)) if body[k][1] == body[k - 1][1]]
        if duplicates:
            body = [body[0]] + [body[k] for k in range(1, len(body)) if body[k][1] != body[k - 1][1]]
    problems: list[_Problem] = []
    needed = max(index.values()) + 1
    for lineno, row in body:
        # more fields than the header names shift every value after the extra one into the wrong
        # column (a decimal comma in a comma-separated log); empty trailing fields are a logger's habit
        if len(row) > len(header) and any(cell.strip() for cell in row[len(header):]):
            problems.append(_Problem(lineno, "(more fields than the header)",
                                     f"{path}, line {lineno}: {len(row)} fields, the header has {len(header)} (a "
                                     f"decimal comma or a stray {sep!r} in a value?): {sep.join(row)[:80]!r}"))
        elif len(row) < needed:
            j = needed - 1
            problems.append(_Problem(lineno, "(fewer fields than the header)",
                                     f"{path}, line {lineno}: {len(row)} fields, no column {header[j]!r} (header has "
                                     f"{len(header)})"))
    if problems:
        raise _refusal(problems)
    if check_thousands and decimal == ".":  # on the values alone: a units row is text in every column
        _refuse_thousands(path, body, {t: j for t, j in index.items() if conversions[t] is not None}, header)
    missing = []
    # each row's place among the data rows: times built from row numbers keep a dropped row's slot
    position = {lineno: i for i, (lineno, _) in enumerate(body)}
    if fill_gaps_s:  # a row with a missing value is a dropped sample, put back with the others
        missing = [lineno for lineno, row in body if any(_missing(row[j]) for j in index.values())]
        drop = set(missing)
        body = [(lineno, row) for lineno, row in body if lineno not in drop]
        if not body:
            raise RecordingError(f"{path}: every data row has a missing value")
    columns: dict[str, np.ndarray] = {}
    start = ""
    line_numbers = [lineno for lineno, _ in body]
    line_of = np.array(line_numbers)
    # every problem in every column, so that the one reported is the first in the file and the
    # others are listed (the log is mended in one pass rather than one error per try)
    times = None  # the time column's seconds, once read (NaN where a cell is not a time)
    local = False  # time stamps without a UTC offset
    time_note = None
    for target, j in index.items():
        col, conversion = mapping[target], conversions[target]
        cells = [row[j].strip() for _, row in body]
        if conversion is None:
            values, found, local = _seconds_from_text(path, line_numbers, cells, col.column)
        else:
            values, found = _numbers(path, line_numbers, cells, col.column, decimal)
        problems += found
        if target == "u_v" and unit_key(col.unit) == "mA":
            lo, hi = MA_RANGE
            for k in np.flatnonzero((values < lo) | (values > hi)):
                problems.append(_Problem(line_numbers[k], col.column, (
                    f"{path}, line {line_numbers[k]}, column {col.column!r}: {cells[k]} mA is outside the {lo:g}..{hi:g} "
                    f"mA of a 4-20 mA current loop (below 3.6 mA: a broken loop or a failed transmitter); a 0-20 mA "
                    f"signal of 0..10 V is {col.column}:scale=0.5")))
        if target != "t_s":
            scale, offset = conversion
            columns[target] = values * scale + offset if offset else values * scale  # -0.0 stays as written
            if target == "p_mpa" and absolute:  # the recording holds gauge pressure
                columns[target] = columns[target] - 1e-3 * (ambient_kpa or STANDARD_ATMOSPHERE_KPA)
            continue
        start = body[0][1][j].strip()
        read = np.flatnonzero(np.isfinite(values))
        origin = values[read[0]] if read.size else 0.0  # the first time read: a bad first cell names itself
        if counter:
            for k in np.flatnonzero(np.isfinite(values) & (values != np.round(values))):
                problems.append(_Problem(line_numbers[k], col.column, (
                    f"{path}, line {line_numbers[k]}, column {col.column!r}: {cells[k]!r} is not a sample number "
                    f"(ts_s builds the times from a column that counts samples)")))
            values = (values - origin) * ts_s
        elif conversion is not None:  # from the first sample in the log's own unit, then scaled:
            if conversion == (1.0, 0.0) and not col.declared and not col.origin:
                # seconds by default only: a unit given or written in the log is the log's word for it
                time_note = _counter_note(col.column, values)
            values = (values - origin) * conversion[0]  # epoch stamps keep their digits
        step = np.diff(values)
        for k in np.flatnonzero(step <= 0) + 1:
            back = local and _clock_change(step[k - 1:k], float(np.nanmedian(step)))[0]
            problems.append(_Problem(line_numbers[k], col.column, (
                f"{path}, line {line_numbers[k]}, column {col.column!r}: time does not increase "
                f"({body[k - 1][1][j].strip()!r}, then {body[k][1][j].strip()!r})" + (f": {_DST}" if back else ""))))
        times = values
    if "t_s" not in mapping:
        times = np.array([position[lineno] for lineno in line_numbers], float) * float(ts_s)
    if problems and times is not None and not fill_gaps_s and np.isfinite(times).sum() >= 2:  # a dropped sample among them
        # the stamps that go beyond all before them: a doubled or backward one left out, the grid
        # stays; a stamp that is not one is taken between its neighbours, not as a gap
        ok = np.isfinite(times)
        at = np.interp(np.arange(len(times)), np.flatnonzero(ok), times[ok])
        keep = np.flatnonzero(at > np.maximum.accumulate(np.concatenate([[-np.inf], at[:-1]])))
        problems += _sampling_problems(path, at[keep], line_of[keep], mapping["t_s"].column if "t_s" in mapping else
                                       "t_s", fill_gaps_s, local, False)
    if problems:
        raise _refusal(problems)
    columns["t_s"] = times
    filled = None
    if fill_gaps_s:
        where = f"{path}, line {{}}, column {mapping['t_s'].column if 't_s' in mapping else 't_s'!r}"
        columns, line_of, filled = _filled(columns, line_of, fill_gaps_s, where)
    found = _sampling_problems(path, columns["t_s"], line_of, mapping["t_s"].column if "t_s" in mapping else "t_s",
                               fill_gaps_s, local, True)
    if found:
        raise _refusal(found)
    def read_as(col: LogColumn) -> str:  # a column named "Weg [mm]" already shows its unit
        return col.column if col.column.rstrip().endswith(f"[{col.unit}]") else f"{col.column} [{col.unit}]"

    if "t_s" in mapping:
        used = ", ".join(f"{target} <- {read_as(col)}" if not (target == "t_s" and counter) else
                         f"t_s <- {col.column} (sample number) x {ts_s:g} s" for target, col in mapping.items())
    else:
        used = ", ".join([f"t_s <- row number x {ts_s:g} s"] + [f"{target} <- {read_as(col)}"
                                                                  for target, col in mapping.items()])
    metadata = {"source": f"tapmuscle import {path.name}: {used}"}
    if start:
        metadata["start"] = start
    if run_note:
        metadata["run"] = run_note
    if units_row is not None:
        metadata["units_row"] = f"line {units_row[0]}, skipped"
    if units_used:
        metadata["units"] = "; ".join(units_used)
    if units_unknown:
        metadata["units_unknown"] = "; ".join(units_unknown)
    if renamed:
        metadata["names"] = "; ".join(renamed) + " (names differ in case or spacing)"
    if remarks:
        metadata["remarks"] = (f"{len(remarks)} '#' line{'s' if len(remarks) > 1 else ''} among the data skipped "
                               f"(line {remarks[0]}" + (" and more)" if len(remarks) > 1 else ")"))
    if duplicates:
        metadata["duplicates"] = (f"{len(duplicates)} row{'s' if len(duplicates) > 1 else ''} repeating the row before "
                                  f"exactly (the time too) dropped: line{'s' if len(duplicates) > 1 else ''} "
                                  f"{_lines_text(duplicates)}")
    if missing:
        # only a row between two kept ones is put back; one before the first or after the last is not
        ends = [m for m in missing if m < line_numbers[0] or m > line_numbers[-1]]
        metadata["missing"] = (f"{len(missing)} row{'s' if len(missing) > 1 else ''} with a missing value dropped "
                               f"(line{'s' if len(missing) > 1 else ''} {_lines_text(missing)})"
                               + (", put back as dropped samples" if len(ends) < len(missing) else "")
                               + (f"; line{'s' if len(ends) > 1 else ''} {_lines_text(ends)} at the log's "
                                  f"{'ends' if len(ends) > 1 else 'end'}, not put back (nothing to interpolate from "
                                  "on that side): the recording starts or ends there" if ends else ""))
    if time_note:
        metadata["time_counter"] = time_note
    if filled is not None:
        metadata["filled"] = filled
    if absolute:
        metadata["ambient_kpa"] = (f"{ambient_kpa or STANDARD_ATMOSPHERE_KPA:g}, subtracted from the absolute pressure"
                                   + ("" if ambient_kpa else " (the standard atmosphere)"))
    if load_n is not None:
        metadata["load_n"] = f"{load_n:g}"
    return Recording(columns, metadata, lines=line_of), mapping


def _lines_text(lines: list[int]) -> str:
    more = f" and {len(lines) - _LISTED} more" if len(lines) > _LISTED else ""
    return ", ".join(map(str, lines[:_LISTED])) + more


def _refuse_ambient(path: Path, mapping: dict[str, LogColumn]) -> None:
    """An ambient pressure is for an absolute pressure only."""
    if "p_mpa" not in mapping or unit_key(mapping["p_mpa"].unit) not in ABSOLUTE_UNITS:
        raise RecordingError(f"{path}: ambient_kpa is for an absolute pressure (a unit of {', '.join(sorted(ABSOLUTE_UNITS))}), "
                             f"the pressure is " + (f"in {mapping['p_mpa'].unit}" if "p_mpa" in mapping else "not mapped"))
