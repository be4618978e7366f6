"""Sweep files (TOML): a base scenario and a grid and/or Monte-Carlo sample over its fields.

A sweep expands into runs, each a complete :class:`~tapmuscle.cosim.spec.Scenario`; ``tapmuscle sweep`` runs
them (locally or on a Dask cluster, :mod:`tapmuscle.cosim.distributed_sweep`) and ``tapmuscle check`` checks
those with expectations. Every key is checked; a problem raises :class:`~tapmuscle.cosim.spec.ScenarioError`
naming the file and the key::

    name = "robustness_mc"                 # optional, default: the file name
    description = "four controllers, random load and supply"
    base = "../paper/ampc_servo_44N_0.1Hz.toml"
    # base: a scenario file (relative to this file), a glob pattern ("../paper/*.toml") or an array of
    # them (every base is crossed with the grid and the sample), or an inline table [base] holding the
    # keys of a scenario file.

    [grid]                                 # every combination (cartesian product, in this order)
    "controller.method" = ["mpc_ucp", "mpc_servo", "ampc_ucp", "ampc_servo"]
    "reference.frequency_hz" = [0.1, 0.2]

    [monte_carlo]                          # n samples, the same for every grid point and base
    n = 50
    sample_seed = 1                        # the sampler's own seed (default 0)
    "load.initial_n" = { uniform = [30.0, 90.0] }       # uniform on [lo, hi)
    "supply.initial_mpa" = { uniform = [0.20, 0.30] }
    seed = { integers = [0, 999] }                      # the plant's noise seed, uniform on lo..hi
    "controller.parameters.servo.R" = { choice = [10.0, 15.0, 20.0] }

    [expect]                               # optional, for every run; default: the base scenario's
    mae_mm_max = 1.5

**Fields** are the scenario file's keys with dots: ``seed``, ``duration_s``, ``load.initial_n``,
``supply.initial_mpa``, ``reference.frequency_hz``, ``controller.method``; under
``plant.parameters.`` and ``controller.parameters.`` the rest is one FMU variable name
(``controller.parameters.servo.R``, ``plant.parameters.friction.rate_gain``). A value may be any TOML
value the scenario key accepts (e.g. ``"load.steps"`` = an array of step tables). Each run is checked as
a scenario; a bad value is reported with the run's values. A file named in the grid or the sample
(``plant.fmu``, ``plant.parameters_file``, ``controller.fmu``, ``controller.identification``) is relative
to the sweep file, where it is written (a base's own files are relative to the base's file).

**Run ids** are the first 12 hex digits of a SHA-256 of the run's complete scenario (the base with the
run's values; name, description and expectations left out), so the same run has the same id in every
expansion: a rerun of the sweep recognises finished runs, and an edited base file gives new ids.
Two runs with the same scenario are an error.

Expansion is pure (numpy's PCG64 for the sample): the same file gives the same runs on every machine.
"""

from __future__ import annotations

import copy
import dataclasses
import glob
import hashlib
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from tapmuscle.cosim.expect import Expectations, parse_expectations
from tapmuscle.cosim.spec import SWEEP_KEYS, Scenario, ScenarioError, broken_path, parse_scenario, read_toml

__all__ = ["SweepRun", "Sweep", "load_sweep", "parse_sweep", "is_sweep_data", "run_id_of", "set_field"]

#: Most Monte-Carlo samples of a sweep (per grid point and base): 10^5 runs is days of computing.
MAX_MONTE_CARLO = 100_000
#: Most runs of a sweep in all (bases x grid points x samples), refused before they are made: making
#: 10^6 runs' scenarios alone takes minutes before the first line.
MAX_SWEEP_RUNS = 100_000

_TOP = {"name", "description", "base", "grid", "monte_carlo", "expect"}
#: Fields that name a file (module docstring: relative to the sweep file when the grid or sample sets them).
_FILE_FIELDS = frozenset({"plant.fmu", "plant.parameters_file", "controller.fmu", "controller.identification"})


def _files_from(folder: Path | None, field: str, value: Any) -> Any:
    """``value`` of ``field`` with the files it names (:data:`_FILE_FIELDS`, also inside a table: a grid
    over the whole ``controller``) found relative to the sweep file's ``folder``, where they are
    written, whatever folder the base is in."""
    if folder is None:
        return value
    if isinstance(value, dict):
        return {key: _files_from(folder, f"{field}.{key}", item) for key, item in value.items()}
    if field in _FILE_FIELDS and isinstance(value, str) and not Path(value).is_absolute():
        return str(folder.resolve() / value)
    return value


_PARAMETER_TABLES = ("plant", "controller")
_DISTRIBUTIONS = ("uniform", "integers", "choice")


@dataclass(frozen=True)
class SweepRun:
    """One run of a sweep."""

    run_id: str
    """12 hex digits, a digest of the run's scenario (module docstring)."""
    index: int
    """Position in the sweep's expansion (0-based)."""
    base: str
    """Name of the base scenario."""
    params: tuple[tuple[str, Any], ...]
    """The swept fields and this run's values, in the sweep's field order."""
    scenario: Scenario
    """The run's scenario, with the swept values set."""


@dataclass(frozen=True)
class Sweep:
    """A parsed, checked and expanded sweep file (module docstring)."""

    name: str
    """The sweep's name (default: the file name)."""
    source: str
    """Where it came from (file path), for messages."""
    fields: tuple[str, ...]
    """Swept fields: the grid's, then the Monte-Carlo sample's."""
    runs: tuple[SweepRun, ...]
    """The runs of its expansion, in order."""
    description: str = ""
    """Free text describing the sweep."""
    expect: Expectations | None = None
    """The sweep's own ``[expect]`` (each run's scenario carries the expectations that apply to it)."""

    def __repr__(self) -> str:
        # a sweep's runs are hundreds of whole scenarios: counted, not written out
        return (f"Sweep(name={self.name!r}, source={self.source!r}, fields={self.fields!r}, "
                f"runs=<{len(self.runs)} runs>, expect={self.expect!r})")


def is_sweep_data(data: Mapping[str, Any]) -> bool:
    """Whether a parsed TOML file is a sweep (has ``base``, ``grid`` or ``monte_carlo``), not a scenario.

    Parameters
    ----------
    data : mapping
        The parsed TOML file.
    """
    return any(key in data for key in SWEEP_KEYS)


def set_field(data: dict[str, Any], field: str, value: Any) -> None:
    """Set the dotted scenario ``field`` (module docstring) in the raw scenario table ``data``, in place.

    Parameters
    ----------
    data : dict
        The raw scenario table, changed in place.
    field : str
        The dotted field (e.g. ``plant.parameters.friction.rate_gain``).
    value : object
        The value to set.
    """
    parts = field.split(".")
    if len(parts) >= 3 and parts[0] in _PARAMETER_TABLES and parts[1] == "parameters":
        path, leaf = parts[:2], ".".join(parts[2:])
    else:
        path, leaf = parts[:-1], parts[-1]
    node = data
    for i, part in enumerate(path):
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ScenarioError(f"field {field!r}: {'.'.join(path[:i + 1])!r} is not a table in the scenario")
        node = child
    node[leaf] = value


def _canonical(value: Any) -> Any:
    """``value`` with a whole float written as the integer TOML reads for it (``68.0`` as ``68``):
    the same number is the same scenario however the file spells it."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, Mapping):
        return {k: _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    return value


def run_id_of(data: Mapping[str, Any]) -> str:
    """The run id of a raw scenario table: 12 hex digits of SHA-256 over its canonical JSON (whole
    numbers written alike, :func:`_canonical`).

    Parameters
    ----------
    data : mapping
        The raw scenario table (its ``name``, ``description`` and ``expect`` do not count).
    """
    core = {k: _canonical(v) for k, v in data.items() if k not in ("name", "description", "expect")}
    text = json.dumps(core, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:12]


def _error(source: str, key: str, message: str) -> ScenarioError:
    return ScenarioError(f"{source}: key '{key}': {message}")


def _bases(data: Mapping[str, Any], source: str, folder: Path | None,
           default_name: str) -> list[tuple[str, dict[str, Any], Path | None]]:
    """``(name, raw scenario table, folder for relative paths)`` of every base scenario."""
    raw = data.get("base")
    if raw is None:
        raise _error(source, "base", "missing: a scenario file, a glob pattern, an array of them, or a table")
    if isinstance(raw, dict):
        return [(default_name, copy.deepcopy(raw), folder)]
    items = [raw] if isinstance(raw, str) else raw
    if not isinstance(items, list) or not items or not all(isinstance(i, str) for i in items):
        raise _error(source, "base", f"must be a file name, a glob pattern, an array of them, or a table; "
                                     f"got {raw!r}")
    bases = []
    for item in items:
        if broken_path(item):
            raise _error(source, "base", broken_path(item))
        pattern = item if Path(item).is_absolute() or folder is None else str(folder / item)
        if any(c in item for c in "*?[") and not Path(pattern).is_file():  # a file named "run [v2].toml" is itself
            paths = sorted(Path(p) for p in glob.glob(pattern))
            if not paths:
                raise _error(source, "base", f"pattern {item!r} matches no file")
        else:
            paths = [Path(pattern)]
            if not paths[0].is_file():
                raise _error(source, "base", f"scenario file {pattern!r} does not exist")
        for path in paths:
            base = read_toml(path)
            if is_sweep_data(base):
                raise _error(source, "base", f"{str(path)!r} is a sweep file, not a scenario")
            bases.append((path.stem if "name" not in base else str(base["name"]), base, path.parent))
    return bases


def _grid(data: Mapping[str, Any], source: str) -> list[tuple[str, list[Any]]]:
    grid = data.get("grid", {})
    if not isinstance(grid, dict):
        raise _error(source, "grid", f"must be a table of field = [values], got {grid!r}")
    out = []
    for field, values in grid.items():
        if not isinstance(values, list) or not values:
            raise _error(source, f"grid.{field}", f"must be a non-empty array of values, got {values!r}")
        out.append((field, values))
    return out


def _number(source: str, key: str, value: Any, *, integer: bool = False) -> float | int:
    ok = not isinstance(value, bool) and (isinstance(value, int) if integer else isinstance(value, (int, float)))
    if not ok or (not integer and not math.isfinite(value)):
        raise _error(source, key, f"must be {'an integer' if integer else 'a finite number'}, got {value!r}")
    return value


def _monte_carlo(data: Mapping[str, Any], source: str) -> tuple[list[str], list[list[Any]]]:
    """The sampled fields and, per field, its ``n`` values."""
    mc = data.get("monte_carlo")
    if mc is None:
        return [], []
    if not isinstance(mc, dict):
        raise _error(source, "monte_carlo", f"must be a table, got {mc!r}")
    if "n" not in mc:
        raise _error(source, "monte_carlo.n", "missing (the number of samples)")
    n = _number(source, "monte_carlo.n", mc["n"], integer=True)
    if not 1 <= n <= MAX_MONTE_CARLO:
        raise _error(source, "monte_carlo.n", f"must be within 1..{MAX_MONTE_CARLO}, got {n}")
    sample_seed = _number(source, "monte_carlo.sample_seed", mc.get("sample_seed", 0), integer=True)
    if sample_seed < 0:
        raise _error(source, "monte_carlo.sample_seed", f"must be >= 0, got {sample_seed}")
    rng = np.random.default_rng(sample_seed)
    fields, columns = [], []
    for field, dist in mc.items():
        if field in ("n", "sample_seed"):
            continue
        key = f"monte_carlo.{field}"
        if not isinstance(dist, dict) or len(dist) != 1 or next(iter(dist)) not in _DISTRIBUTIONS:
            hint = " (the sampler's own seed is sample_seed)" if field == "seed" and not isinstance(dist, dict) else ""
            raise _error(source, key, f"must be {{ uniform = [lo, hi] }}, {{ integers = [lo, hi] }} or "
                                      f"{{ choice = [values] }}, got {dist!r}{hint}")
        kind, arg = next(iter(dist.items()))
        if kind == "choice":
            if not isinstance(arg, list) or not arg:
                raise _error(source, f"{key}.choice", f"must be a non-empty array, got {arg!r}")
            column = [arg[int(i)] for i in rng.integers(0, len(arg), n)]
        else:
            integer = kind == "integers"
            if not isinstance(arg, list) or len(arg) != 2:
                raise _error(source, f"{key}.{kind}", f"must be [lo, hi], got {arg!r}")
            lo, hi = (_number(source, f"{key}.{kind}", v, integer=integer) for v in arg)
            if lo > hi or (not integer and lo == hi):
                raise _error(source, f"{key}.{kind}", f"needs lo < hi, got {arg!r}")
            if integer and not (-2**63 <= lo and hi < 2**63 or 0 <= lo and hi < 2**64):
                raise _error(source, f"{key}.{kind}", f"{arg!r} is beyond 64-bit integers (seeds: 0 .. 2**64 - 1)")
            if integer and hi >= 2**63:  # unsigned 64-bit seeds
                column = [int(v) for v in rng.integers(lo, hi, n, dtype=np.uint64, endpoint=True)]
            else:
                column = ([int(v) for v in rng.integers(lo, hi + 1, n)] if integer
                          else [float(v) for v in rng.uniform(lo, hi, n)])
        fields.append(field)
        columns.append(column)
    if not fields:
        raise _error(source, "monte_carlo", "names no field to sample")
    return fields, columns


def _describe(params: tuple[tuple[str, Any], ...]) -> str:
    return ", ".join(f"{f}={v!r}" for f, v in params) or "no swept fields"


def parse_sweep(data: Mapping[str, Any], *, source: str = "<sweep>", folder: Path | None = None,
                default_name: str = "sweep") -> Sweep:
    """Check and expand a sweep given as a mapping (the parsed TOML; module docstring).

    Parameters
    ----------
    data : mapping
        The parsed sweep file.
    source : str
        The file, for messages.
    folder : Path, optional
        Folder that relative ``base`` paths are relative to.
    default_name : str
        The sweep's name when the file has none.
    """
    for key in data:
        if key not in _TOP:
            raise _error(source, key, f"unknown key; allowed here: {', '.join(sorted(_TOP))}")
    name = data.get("name", default_name)
    description = data.get("description", "")
    for key, value in (("name", name), ("description", description)):
        if not isinstance(value, str):
            raise _error(source, key, f"must be a string, got {value!r}")
    expect = parse_expectations(data["expect"], source=source) if "expect" in data else None
    bases = _bases(data, source, folder, name)
    grid = _grid(data, source)
    mc_fields, mc_columns = _monte_carlo(data, source)
    fields = tuple(f for f, _ in grid) + tuple(mc_fields)
    if len(set(fields)) != len(fields):
        dup = next(f for f in fields if fields.count(f) > 1)
        raise _error(source, f"monte_carlo.{dup}", "is also a grid field")
    samples = list(zip(*mc_columns)) if mc_columns else [()]
    total = len(bases) * math.prod(len(values) for _, values in grid) * len(samples)
    if total > MAX_SWEEP_RUNS:
        counts = [f"{len(bases)} base{'s' if len(bases) != 1 else ''}"] + [f"{len(v)} {f}" for f, v in grid] + \
            ([f"{len(samples)} samples"] if mc_columns else [])
        raise _error(source, "grid" if grid else "monte_carlo",
                     f"makes {total:,} runs ({' x '.join(counts)}), more than a sweep's {MAX_SWEEP_RUNS:,}: split it "
                     "into several sweeps")
    runs: list[SweepRun] = []
    seen: dict[str, int] = {}
    for base_name, base, base_folder in bases:
        for point in itertools.product(*(values for _, values in grid)):
            for sample in samples:
                params = tuple(zip(fields, point + tuple(sample)))
                raw = copy.deepcopy(base)  # the run as written: what its id is made of
                resolved = copy.deepcopy(base)  # the same, its files found
                where = f"{source} [run of {base_name}: {_describe(params)}]"
                for field, value in params:
                    try:
                        set_field(raw, field, value)
                        set_field(resolved, field, _files_from(folder, field, value))
                    except ScenarioError as exc:
                        raise ScenarioError(f"{where}: {exc}") from None
                scenario = parse_scenario(resolved, source=where, base=base_folder, default_name=base_name)
                hashed = raw
                for role, key in (("plant", "parameters_file"), ("controller", "identification")):
                    if key in raw.get(role, {}):
                        # the file's values, not its name: a rerun after the file changed runs anew
                        spec = getattr(scenario, role)
                        hashed = {**hashed, role: {**hashed[role], key: dict(spec.parameters)}}
                run_id = run_id_of(hashed)
                if run_id in seen:
                    raise ScenarioError(f"{where}: the same scenario as run {seen[run_id]} (duplicate values in "
                                        f"the grid or base?)")
                seen[run_id] = len(runs)
                scenario = dataclasses.replace(scenario, name=f"{base_name}-{run_id}",
                                               expect=expect if expect is not None else scenario.expect)
                runs.append(SweepRun(run_id, len(runs), base_name, params, scenario))
    return Sweep(name=name, source=source, fields=fields, runs=tuple(runs), description=description, expect=expect)


def load_sweep(path: str | Path) -> Sweep:
    """Read, check and expand a sweep file (module docstring); errors name the file and key.

    Parameters
    ----------
    path : str or Path
        The sweep file (TOML).
    """
    path = Path(path)
    data = read_toml(path, "sweep")
    if not is_sweep_data(data):
        raise ScenarioError(f"{path}: not a sweep file (it has no 'base', 'grid' or 'monte_carlo'); "
                            f"run a scenario file with tapmuscle run")
    return parse_sweep(data, source=str(path), folder=path.parent, default_name=path.stem)
