"""Recordings: the CSV format every tapmuscle tool reads and writes (docs/recordings.md).

::

    # tapmuscle recording v1
    # ts_s: 0.1
    # load_n: 44
    # seed: 0
    # source: tapmuscle record --load 44 --input sine:bias=5,amp=3,freq=0.1 ...
    t_s,u_v,l_mm,p_mpa,load_n
    0.1,5.0,0.00,0.0002,44
    ...

* leading ``#`` lines carry metadata as ``key: value`` (free text; tools use ``ts_s``, ``load_n``,
  ``seed``, ``source`` when present);
* one header row; required columns ``t_s,u_v,l_mm``; optional ``p_mpa,load_n,r_mm``; other columns
  are kept and ignored by tools that do not know them;
* ``t_s`` strictly increasing; every value a finite number.

:func:`read_recording` raises :class:`RecordingError` (a ``ValueError``) naming the file, line and
column of the first problem. :func:`write_recording` writes atomically: a temporary file in the same
folder is renamed over the target, so a failure never leaves a half-written or truncated file.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from fmu_plant.parameters import LoadParams
from tapmuscle.errors import TapmuscleError
from tapmuscle.io.inert_text import inert_csv_text
from tapmuscle.io.atomic import atomic_path
from tapmuscle.io.gc_paused import gc_paused
from tapmuscle.io.sampling import Sampling, SamplingError, uniform_sampling

__all__ = ["Recording", "RecordingError", "read_recording", "read_columns", "write_recording", "atomic_write_text",
           "REQUIRED_COLUMNS", "OPTIONAL_COLUMNS"]

REQUIRED_COLUMNS = ("t_s", "u_v", "l_mm")
OPTIONAL_COLUMNS = ("p_mpa", "load_n", "r_mm")
MAGIC = "tapmuscle recording v1"


class RecordingError(TapmuscleError):
    """A recording file that cannot be read; the message names file, line and column, and
    :attr:`line` is the file's line where one is to blame (None: the whole file)."""

    def __init__(self, message: str, line: int | None = None) -> None:
        super().__init__(message)
        self.line = line


@dataclass
class Recording:
    """A recording in memory: columns as float arrays, plus metadata.

    Attributes
    ----------
    columns : dict of str to ndarray
        At least ``t_s`` [s], ``u_v`` [V], ``l_mm`` [mm]; optionally ``p_mpa`` [MPa],
        ``load_n`` [N], ``r_mm`` [mm] and any other column.
    metadata : dict of str to str
        From the ``# key: value`` lines.
    lines : ndarray of int, optional
        The file's line of each sample, for a recording read from a file (:func:`read_recording`,
        :func:`~tapmuscle.io.rig_log.read_rig_log`): what a message about a sample names. None for
        one made in memory.
    """

    columns: dict[str, np.ndarray] = field(repr=False)
    metadata: dict[str, str] = field(default_factory=dict)
    lines: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __repr__(self) -> str:
        # its columns are thousands of samples: their names and the run's length stand for them
        t = self.columns["t_s"]
        span = f", {t[-1] - t[0]:g} s" if len(t) else ""
        return f"Recording({len(t)} samples{span}, columns {', '.join(self.columns)}, metadata={self.metadata!r})"

    def __post_init__(self) -> None:
        for name in REQUIRED_COLUMNS:
            if name not in self.columns:
                raise RecordingError(f"recording has no {name!r} column (required: {', '.join(REQUIRED_COLUMNS)})")
        self.columns = {k: np.asarray(v, dtype=float) for k, v in self.columns.items()}
        flat = [k for k, v in self.columns.items() if v.ndim != 1]
        if flat:
            raise RecordingError(f"recording column {flat[0]!r} has shape {self.columns[flat[0]].shape}: each column "
                                 "must be one value per sample (1-D)")
        n = {len(v) for v in self.columns.values()}
        if len(n) != 1:
            raise RecordingError(f"recording columns differ in length: "
                                 f"{ {k: len(v) for k, v in self.columns.items()} }")
        if self.lines is not None:
            self.lines = np.asarray(self.lines, dtype=int)
            if self.lines.shape != (len(self),):
                raise RecordingError(f"recording lines has shape {self.lines.shape}: one file line per sample "
                                     f"({len(self)}) expected")

    @property
    def t_s(self) -> np.ndarray:
        return self.columns["t_s"]

    @property
    def u_v(self) -> np.ndarray:
        return self.columns["u_v"]

    @property
    def l_mm(self) -> np.ndarray:
        return self.columns["l_mm"]

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def load_n(self) -> np.ndarray | None:
        """The hanging load per sample [N]: the ``load_n`` column, else the ``# load_n:`` header line
        as a constant column, else None (the tool's default load).

        Raises
        ------
        RecordingError
            A ``load_n`` header that is not a number within the plant's range (``LoadParams.load_n``).
        """
        if "load_n" in self.columns:
            return self.columns["load_n"]
        if "load_n" not in self.metadata:
            return None
        text = self.metadata["load_n"]
        try:
            value = float(text)
        except ValueError:
            raise RecordingError(f"header '# load_n: {text}' is not a number [N]") from None
        try:
            LoadParams(load_n=value)  # the plant's own range check
        except ValueError as exc:
            raise RecordingError(f"header '# load_n: {text}': {exc}") from None
        return np.full(len(self), value)

    @property
    def sampling(self) -> Sampling:
        """The uniform grid of ``t_s`` (:func:`tapmuscle.io.sampling.uniform_sampling`): its period and the
        timestamps' largest jitter about it [s].

        Raises
        ------
        RecordingError
            Fewer than 2 rows, or a sample off the uniform sampling (naming the sample and its time).
        """
        lines = self.lines
        try:
            return uniform_sampling(self.t_s, where=None if lines is None else (lambda k: f"line {lines[k]}"))
        except SamplingError as exc:
            raise RecordingError(str(exc)) from None

    @property
    def ts_s(self) -> float:
        """Sampling period [s] of the uniformly sampled recording.

        The median step of ``t_s`` when every step is within 0.1 % of it; times that scatter about a
        uniform grid by up to a quarter period (a logger's jitter) give the grid's period
        (:attr:`sampling`). A ``# ts_s:`` header line must agree with it to 0.1 % (its value is returned
        then, as written).

        Raises
        ------
        RecordingError
            Fewer than 2 rows; a sample off the uniform sampling (naming the sample and its time); a
            ``ts_s`` header that is not a positive number or contradicts the ``t_s`` column.
        """
        ts = self.sampling.ts_s
        if "ts_s" in self.metadata:
            text = self.metadata["ts_s"]
            try:
                meta = float(text)
            except ValueError:
                raise RecordingError(f"header '# ts_s: {text}' is not a number (the t_s column says {ts:g} s)") from None
            if not (math.isfinite(meta) and meta > 0.0) or abs(meta - ts) > 1e-3 * ts:
                raise RecordingError(f"header '# ts_s: {text}' contradicts the t_s column, sampled every {ts:g} s")
            return meta
        return ts


def read_recording(path: str | os.PathLike) -> Recording:
    """Read a recording CSV (see module docstring).

    Parameters
    ----------
    path : path
        The CSV file: ``t_s,u_v,l_mm`` and optional columns, ``#`` header lines (docs/recordings.md).

    Returns
    -------
    Recording
        The columns as arrays, the header's key-value lines and the sampling period ``ts_s`` [s].

    Raises
    ------
    RecordingError
        Missing file, no header, a missing required column, a duplicate column, a row with the
        wrong number of fields, a value that is not a finite number, ``t_s`` not increasing, off a
        uniform grid (a dropped sample, a clock that changes its period) or against a ``# ts_s:``
        header line; the message names the file, the line and the column.
    """
    lines: dict[str, Any] = {}
    columns, metadata = _read_columns(path, REQUIRED_COLUMNS, "t_s", lines)
    rec = Recording(columns, metadata, lines=np.array(lines["samples"]))
    if len(rec) >= 2:  # the period the fits assume: checked where the file can still be named
        try:
            rec.ts_s
        except RecordingError as exc:
            samples = lines["samples"]
            message = re.sub(r"\bsample (\d+)\b", lambda m: f"line {samples[int(m[1])]} (sample {m[1]})", str(exc),
                             count=1)
            line = f", line {lines['ts_s']}" if message.startswith("header '# ts_s:") else ""
            raise RecordingError(f"{path}{line}: {message}") from None
    return rec


def read_text(path: Path, what: str, encoding: str = "utf-8-sig", remedy: str = "save it as UTF-8") -> str:
    """The text of the ``what`` file ``path`` (UTF-8 by default; a byte-order mark, as spreadsheet
    exports write, is not data); :class:`RecordingError` naming the file when it is missing or
    unreadable, and the line of a byte the encoding cannot read (with ``remedy``)."""
    try:
        return path.read_text(encoding=encoding)
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such {what} file") from None
    except UnicodeDecodeError as exc:
        line = exc.object[:exc.start].count(b"\n") + 1
        raise RecordingError(f"{path}, line {line}: not {exc.encoding} text (byte {exc.object[exc.start]:#04x}): "
                             f"{remedy}") from None
    except (OSError, LookupError) as exc:
        raise RecordingError(f"{path}: cannot read {what}: {exc}") from None


def read_columns(path: str | os.PathLike, required: tuple[str, ...] = (), time_column: str = "t_s"
                 ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The columns and ``# key: value`` metadata of any CSV in the recording format (other column
    names; ``required`` must be there, ``time_column``, if present, must increase).

    Raises :class:`RecordingError` as :func:`read_recording` does.

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.
    required : tuple of str, optional
        Columns that must be there.
    time_column : str, optional
        The column that, if present, must increase; default ``"t_s"``.
    """
    return _read_columns(path, required, time_column, {})


@gc_paused()
def _read_columns(path: str | os.PathLike, required: tuple[str, ...], time_column: str,
                  lines_of: dict[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """:func:`read_columns`, storing in ``lines_of`` the line number of each ``# key:`` line (by key)
    and of each sample (``"samples"``, a list)."""
    path = Path(path)
    text = read_text(path, "recording")

    metadata: dict[str, str] = {}
    lines = text.splitlines()
    i = 0
    while i < len(lines) and (lines[i].startswith("#") or not lines[i].strip()):
        body = lines[i].lstrip("#").strip()
        key, sep, value = body.partition(":")
        if sep and key.strip() and " " not in key.strip():
            metadata[key.strip()] = value.strip()
            lines_of[key.strip()] = i + 1
        i += 1
    if i >= len(lines):
        raise RecordingError(f"{path}: no header row (expected e.g. 't_s,u_v,l_mm')")
    header_line = i + 1
    header = [h.strip() for h in next(csv.reader([lines[i]]))]
    for name in required:
        if name not in header:
            one_field = len(header) == 1 and any(sep in header[0] for sep in (";", "\t"))
            hint = ("; the header is one field: separated by ';' or tabs? " if one_field else "; a logger's file? ")
            raise RecordingError(f"{path}, line {header_line}: header has no {name!r} column "
                                 f"(required: {', '.join(required)}; found: {', '.join(header)}){hint}"
                                 "`tapmuscle import` reads it with its own column names, units and separator")
    seen = set()
    for name in header:
        if name in seen:
            raise RecordingError(f"{path}, line {header_line}: column {name!r} appears twice")
        seen.add(name)

    data: list[list[float]] = []
    linenos = lines_of.setdefault("samples", [])
    for lineno, row in enumerate(csv.reader(lines[i + 1:]), start=header_line + 1):
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        if len(row) != len(header):
            # "0,05" split at its comma: a logger's decimal comma in a comma-separated file
            commas = len(row) > len(header) and any(c.strip().isdigit() for c in row[1:]) and re.fullmatch(
                r"\s*-?\d+", row[0]) is not None
            hint = (" (decimal commas in a comma-separated file? tapmuscle import reads a log's decimal mark and "
                    "separator)" if commas else "")
            raise RecordingError(f"{path}, line {lineno}: {len(row)} fields, header has {len(header)}{hint}")
        values = []
        for col, cell in zip(header, row):
            try:
                v = float(cell)
            except ValueError:
                raise RecordingError(f"{path}, line {lineno}, column {col!r}: {cell.strip()!r} is not a number") from None
            if not math.isfinite(v):
                raise RecordingError(f"{path}, line {lineno}, column {col!r}: {cell.strip()!r} is not finite")
            values.append(v)
        data.append(values)
        linenos.append(lineno)
    if not data:
        raise RecordingError(f"{path}: header but no data rows")
    arr = np.array(data, dtype=float)
    if time_column in header:
        t = arr[:, header.index(time_column)]
        bad = np.nonzero(np.diff(t) <= 0)[0]
        if bad.size:
            k = int(bad[0]) + 1
            raise RecordingError(f"{path}, line {linenos[k]}, column '{time_column}': time {float(t[k])!r} does not "
                                 f"increase (previous row {float(t[k - 1])!r})")
    return {name: arr[:, j].copy() for j, name in enumerate(header)}, metadata


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` atomically with the user's umask (:func:`tapmuscle.io.atomic.atomic_path`).

    UTF-8; a file name that the file-system encoding could not decode (a non-ASCII folder under an
    ASCII locale with ``PYTHONUTF8=0``) is written as its original bytes, not refused.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    text : str
        Its content.
    """
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", errors="surrogateescape", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())


#: Time to 15 significant digits: a 1-ms sampling after a day, or epoch time stamps to the microsecond,
#: stay distinct and uniform, while the last-bit noise of ``k * ts`` is rounded away (``0.1``, not
#: ``0.30000000000000004``).
_FORMATS = {"t_s": "{:.15g}", "u_v": "{:.6f}", "l_mm": "{:.4f}", "p_mpa": "{:.6f}", "load_n": "{:.10g}",
            "r_mm": "{:.6f}"}

#: Characters that would break the CSV header row or a ``# key: value`` line.
_NAME_BREAKERS = (",", '"', "\n", "\r")


def write_recording(path: str | os.PathLike, rec: Recording | Mapping[str, Any]) -> None:
    """Write ``rec`` as CSV to ``path`` atomically (see :func:`atomic_write_text`).

    Parameters
    ----------
    path : path
        The CSV file to write (replaced whole, or left as it was on error).
    rec : Recording or mapping
        Columns (``t_s``, ``u_v``, ``l_mm`` required) and header lines; or the columns alone (what
        :func:`tapmuscle.simulate` returns), written without header lines.

    Raises
    ------
    RecordingError
        What :func:`read_recording` or the tools reading the file would refuse, so nothing is written
        then: a required column missing, a column that is not one value per row of ``t_s``, fewer
        than 2 rows, a value that is not finite (named by column and row), ``t_s`` not strictly
        increasing (named by row), a column name with a comma, quote or line break, a metadata key
        with a colon or line break. (A ``# ts_s`` header that the times contradict, or a dropped
        sample, is written as given: files like that are what the readers' checks are for.)
    """
    if not isinstance(rec, Recording):
        if not isinstance(rec, Mapping):
            raise RecordingError(f"cannot write {path}: expected a Recording or a mapping of columns, got "
                                 f"{type(rec).__name__}")
        try:
            rec = Recording(dict(rec), {})  # checks the columns
        except RecordingError as exc:
            raise RecordingError(f"cannot write {path}: {exc}") from None
    if len(rec.t_s) < 2:
        raise RecordingError(f"cannot write {path}: {len(rec.t_s)} row(s); a recording needs at least 2 samples")
    names = list(REQUIRED_COLUMNS) + [c for c in OPTIONAL_COLUMNS if c in rec.columns] + \
        [c for c in rec.columns if c not in REQUIRED_COLUMNS and c not in OPTIONAL_COLUMNS]
    for name in names:
        if not name or any(ch in name for ch in _NAME_BREAKERS):
            raise RecordingError(f"cannot write {path}: column name {name!r} is empty or holds a comma, "
                                 f"quote or line break")
        bad = np.nonzero(~np.isfinite(rec.columns[name]))[0]
        if bad.size:
            raise RecordingError(f"cannot write {path}: column {name!r} row {int(bad[0]) + 1} is "
                                 f"{float(rec.columns[name][bad[0]])!r}")
    for key in rec.metadata:
        if not key or ":" in key or "\n" in key or "\r" in key:
            raise RecordingError(f"cannot write {path}: metadata key {key!r} is empty or holds a colon or "
                                 f"line break")
    t_text = [_FORMATS["t_s"].format(v) for v in rec.t_s]
    back = np.array([float(v) for v in t_text])
    if not np.all(np.diff(back) > 0.0):
        # times closer than 15 digits tell apart: every bit of them (Python's shortest round-trip form)
        t_text = [repr(float(v)) for v in rec.t_s]
        back = rec.t_s
    bad = np.nonzero(~(np.diff(back) > 0.0))[0]
    if bad.size:
        k = int(bad[0]) + 1
        raise RecordingError(f"cannot write {path}: column 't_s' row {k + 1} is {float(rec.t_s[k])!r}, not after "
                             f"row {k}'s {float(rec.t_s[k - 1])!r} (time must increase strictly)")
    buf = io.StringIO()
    buf.write(f"# {MAGIC}\n")
    for key, value in rec.metadata.items():
        # a value from elsewhere (a scenario's name) makes no formula in a spreadsheet opening the file
        buf.write(f"# {key}: {inert_csv_text(' '.join(str(value).splitlines()))}\n")
    buf.write(",".join(names) + "\n")
    cols = [t_text if n == "t_s" else [_FORMATS.get(n, "{:.10g}").format(v) for v in rec.columns[n]] for n in names]
    for row in zip(*cols):
        buf.write(",".join(row) + "\n")
    atomic_write_text(path, buf.getvalue())
