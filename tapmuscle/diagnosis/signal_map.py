"""Which recording columns drive which FMU inputs, and which are measured outputs (``--map MAP.toml``).

::

    time = "t_s"            # the time column [s] (default "t_s")
    ts_s = 0.05             # optional: the sample time the recording must have [s]

    [inputs]                # FMU input = recording column, with the column's unit
    V = { column = "v_cmd", unit = "V" }

    [outputs]               # FMU output = measured column (the first one is diagnosed unless --output)
    omega = { column = "speed", unit = "rad/s" }

    [parameters]            # optional: values set on the FMU, not calibrated
    Tc = 0.03

    [calibrate]             # optional: only these parameters may be calibrated (default: every Real
    parameters = ["R", "K"] # parameter with a non-zero start value)

A unit must equal the FMU variable's declared unit when it declares one: the diagnosis converts
nothing, and a column in other units would be a mismatch it could only misname. Without a map,
every column whose name is an FMU input or output is used, and the mapping is printed.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from tapmuscle.diagnosis.foreign_model import FmuInterface
from tapmuscle.errors import TapmuscleError

__all__ = ["Signal", "SignalMap", "SignalMapError", "read_signal_map", "match_by_name"]


class SignalMapError(TapmuscleError):
    """A mapping that cannot be used; the message names the file and key (or the column/variable)."""


@dataclass(frozen=True)
class Signal:
    """One FMU variable and the recording column that holds it.

    Parameters
    ----------
    variable : str
        The FMU variable.
    column : str
        The recording column.
    unit : str or None, optional
        The column's unit, if given.
    """

    variable: str
    column: str
    unit: str | None = None


@dataclass(frozen=True)
class SignalMap:
    """The mapping between a recording and an FMU (module docstring).

    Parameters
    ----------
    inputs : tuple of Signal
        The FMU inputs and their columns.
    outputs : tuple of Signal
        The FMU outputs and their columns.
    time_column : str, optional
        The time column [s]; default ``"t_s"``.
    ts_s : float, optional
        The sampling period the map states [s], checked against the recording's.
    parameters : dict of str to float, optional
        FMU parameters fixed at these values.
    calibrate : tuple of str, optional
        Just these parameters are calibrated; None (default): every one that qualifies.
    source : str, optional
        Where the map came from (its file), for messages; default ``"matched by name"``.
    """

    inputs: tuple[Signal, ...]
    outputs: tuple[Signal, ...]
    time_column: str = "t_s"
    ts_s: float | None = None
    parameters: dict[str, float] = field(default_factory=dict)
    calibrate: tuple[str, ...] | None = None
    source: str = "matched by name"

    def lines(self) -> list[str]:
        """The mapping in words (printed when it was matched by name)."""
        out = [f"mapping ({self.source}): time = column {self.time_column}"]
        out += [f"  input  {s.variable} <- column {s.column}" + (f" [{s.unit}]" if s.unit else "") for s in self.inputs]
        out += [f"  output {s.variable} -> column {s.column}" + (f" [{s.unit}]" if s.unit else "") for s in self.outputs]
        return out

    def to_json(self) -> dict[str, Any]:
        return {"source": self.source, "time": self.time_column, "ts_s": self.ts_s,
                "inputs": {s.variable: {"column": s.column, "unit": s.unit} for s in self.inputs},
                "outputs": {s.variable: {"column": s.column, "unit": s.unit} for s in self.outputs},
                "parameters": self.parameters, "calibrate": None if self.calibrate is None else list(self.calibrate)}


def match_by_name(iface: FmuInterface, columns: Sequence[str], time_column: str = "t_s") -> SignalMap:
    """The mapping of columns named as the FMU's inputs and outputs; ``SignalMapError`` if no input or
    no output matches.

    Parameters
    ----------
    iface : FmuInterface
        The FMU.
    columns : sequence of str
        The recording's columns.
    time_column : str, optional
        The time column; default ``"t_s"``.
    """
    cols = set(columns)
    ins = tuple(Signal(v.name, v.name, v.unit) for v in iface.inputs if v.name in cols)
    outs = tuple(Signal(v.name, v.name, v.unit) for v in iface.outputs if v.name in cols)
    if not ins or not outs:
        raise SignalMapError(
            f"no --map given, and the recording's columns ({', '.join(columns)}) name "
            f"{'no input' if not ins else 'no output'} of {iface.model_name} (inputs: "
            f"{', '.join(v.name for v in iface.inputs) or 'none'}; outputs: "
            f"{', '.join(v.name for v in iface.outputs) or 'none'}); write a MAP.toml (docs/diagnosis.md)")
    if time_column not in cols:
        raise SignalMapError(f"no --map given, and the recording has no {time_column!r} column")
    return SignalMap(ins, outs, time_column)


def _signal(path: Path, table: str, var: str, spec: Any, iface: FmuInterface, columns: Sequence[str]) -> Signal:
    where = f"{path}: [{table}] {var}"
    known = iface.inputs if table == "inputs" else iface.outputs
    if var not in {v.name for v in known}:
        raise SignalMapError(f"{where}: {iface.model_name} has no Real {table[:-1]} {var!r} (its {table}: "
                             f"{', '.join(v.name for v in known) or 'none'})")
    if isinstance(spec, str):
        spec = {"column": spec}
    if not isinstance(spec, dict) or not isinstance(spec.get("column"), str):
        raise SignalMapError(f"{where}: expected {{ column = \"NAME\", unit = \"UNIT\" }}, got {spec!r}")
    unknown = set(spec) - {"column", "unit"}
    if unknown:
        raise SignalMapError(f"{where}: unknown key {sorted(unknown)[0]!r} (known: column, unit)")
    column = spec["column"]
    if column not in columns:
        raise SignalMapError(f"{where}: the recording has no column {column!r} (its columns: {', '.join(columns)})")
    unit = spec.get("unit")
    declared = iface.variable(var).unit
    if unit is not None and not isinstance(unit, str):
        raise SignalMapError(f"{where}: unit must be a string, got {unit!r}")
    if unit and declared and unit != declared:
        raise SignalMapError(f"{where}: column {column!r} is in {unit!r}, the FMU's {var} in {declared!r}; convert "
                             "the column (the diagnosis converts no units)")
    return Signal(var, column, unit or declared)


def read_signal_map(path: str | Path, iface: FmuInterface, columns: Sequence[str]) -> SignalMap:
    """Read and check ``MAP.toml`` against the FMU and the recording's ``columns``.

    Parameters
    ----------
    path : str or Path
        The ``MAP.toml`` file.
    iface : FmuInterface
        The FMU.
    columns : sequence of str
        The recording's columns.

    Raises
    ------
    SignalMapError
        An unreadable file, an unknown key, a variable the FMU lacks, a column the recording lacks,
        a unit that differs from the FMU's, a parameter that is not a finite number; the message
        names the file and the key.
    """
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SignalMapError(f"--map {path}: no such file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SignalMapError(f"--map {path}: not a readable TOML file: {exc}") from None
    except RecursionError:  # tomllib's parser recurses once per level of nesting
        raise SignalMapError(f"--map {path}: not a readable TOML file: its arrays or tables are nested too deep") from None
    unknown = set(doc) - {"time", "ts_s", "inputs", "outputs", "parameters", "calibrate"}
    if unknown:
        raise SignalMapError(f"{path}: unknown key {sorted(unknown)[0]!r} (known: time, ts_s, inputs, outputs, "
                             "parameters, calibrate)")
    time_column = doc.get("time", "t_s")
    if not isinstance(time_column, str) or time_column not in columns:
        raise SignalMapError(f"{path}: time = {time_column!r}: the recording has no such column "
                             f"(its columns: {', '.join(columns)})")
    ts = doc.get("ts_s")
    if ts is not None and (isinstance(ts, bool) or not isinstance(ts, (int, float)) or not math.isfinite(ts) or ts <= 0):
        raise SignalMapError(f"{path}: ts_s = {ts!r} must be a positive number [s]")
    for table in ("inputs", "outputs"):
        if not isinstance(doc.get(table), dict) or not doc[table]:
            raise SignalMapError(f"{path}: [{table}] is missing or empty (at least one FMU {table[:-1]} = column)")
    ins = tuple(_signal(path, "inputs", k, v, iface, columns) for k, v in doc["inputs"].items())
    outs = tuple(_signal(path, "outputs", k, v, iface, columns) for k, v in doc["outputs"].items())
    params: dict[str, float] = {}
    own = {p.name for p in iface.parameters}
    for k, v in (doc.get("parameters") or {}).items():
        if k not in own:
            raise SignalMapError(f"{path}: [parameters] {k}: {iface.model_name} has no tunable or fixed Real "
                                 f"parameter {k!r}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SignalMapError(f"{path}: [parameters] {k} = {v!r} must be a finite number")
        params[k] = float(v)
    cal = doc.get("calibrate")
    only = None
    if cal is not None:
        names = cal.get("parameters") if isinstance(cal, dict) else None
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise SignalMapError(f"{path}: [calibrate] parameters must be a list of parameter names")
        for n in names:
            if n not in own:
                raise SignalMapError(f"{path}: [calibrate] parameters: {iface.model_name} has no tunable or fixed "
                                     f"Real parameter {n!r}")
        only = tuple(names)
    return SignalMap(ins, outs, time_column, None if ts is None else float(ts), params, only, str(path))
