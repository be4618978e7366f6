"""Scenario files (TOML): what to couple, with which parameters, reference, load and supply profile.

A scenario names the two FMUs and their parameters, the reference, the load (and supply-pressure)
profile with steps during the run, the duration and macro step, the Eq. (21) evaluation window and the
noise seed. Every key is checked; a problem raises :class:`ScenarioError` naming the file and the key::

    name = "ampc_servo_44N_0.1Hz"          # optional, default: the file name
    description = "Table 7, 44 N"          # optional
    duration_s = 45.0                      # a whole number of steps
    step_s = 0.1                           # macro (communication) step = controller Ts
    seed = 0                               # plant sensor-noise seed
    evaluation_window_s = [10.1, 40.1]     # Eq. (21) window t0..t1 [s] (inclusive), the default: the
                                           # paper's k = 101..401 at Ts = 0.1 s, ending at the run's end
                                           # when that comes first (a run of <= 10.1 s: every sample);
                                           # or evaluation_samples = [k0, k1] (sample numbers)

    [plant]
    fmu = "MusclePlant.fmu"                # optional, relative to this file; default: built from the sources
    parameters_file = "calibrated_plant.json"   # optional: a plant parameter file (tapmuscle diagnose writes one)
    parameters = { "friction.rate_gain" = 0.8 }   # any MusclePlant parameter, by FMU variable name (over the file's)

    [controller]
    fmu = "AMPCController.fmu"             # optional, as above
    method = "ampc_servo"                  # mpc_ucp | mpc_servo | ampc_ucp | ampc_servo
    identification = "id.json"             # optional: theta0 and the box C from `tapmuscle identify --json`
                                           # (its ts_s must be step_s; theta in mm and V)
    parameters = { "servo.R" = 15.0 }      # any AMPCController parameter (over the file's)

    # or a controller FMU of one's own (any FMI 2.0 co-simulation FMU): its law, its parameters; the
    # master feeds it the reading l(k) and the reference r(k) and applies its command, as the paper's
    # [controller]
    # fmu = "PIController.fmu"
    # interface = { measurement = "y", reference = "r", command = "u" }   # its variables' names
    # parameters = { "Kp" = 0.4 }          # any of its parameters (no method, no identification)

    [reference]                            # kind = "sine": the controller's built-in generator, exact preview
    kind = "sine"
    offset_mm = 35.0
    amplitude_mm = 30.0
    frequency_hz = 0.1
    # kind = "steps": values_mm = [20, 50], times_s = [0, 15] (on the step_s grid, within the run),
    # preview = "advanced" | "held"
    # (fed through the input r; "advanced" feeds r(t + Hp Ts), giving the exact preview; the values
    # within -400..400 mm, as the sine's offset and amplitude)

    [load]
    initial_n = 44.0                       # default: the parameters_file's load.load_n, else 44
    steps = [ { t_s = 20.0, load_n = 68.0 } ]   # optional; times on the step_s grid, before the last step

    [supply]                               # optional
    initial_mpa = 0.25                     # default: the parameters_file's supply pressure, else 0.25
    steps = [ { t_s = 30.0, pressure_mpa = 0.22 } ]

    [expect]                               # optional: bounds for `tapmuscle check` (tapmuscle/cosim/expect.py)
    mae_mm_max = 0.35
    u_within = [0, 10]
"""

from __future__ import annotations

import math
import os
import shlex
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from fmu_controller.methods import METHODS
from fmu_plant.seed import SEED_MAX
from tapmuscle.tracking_metrics import eq21_window
from tapmuscle.errors import TapmuscleError
from tapmuscle.io.identification_file import IdentificationFileError, read_identification
from tapmuscle.io.plant_file import PlantFileError, read_plant_file

if TYPE_CHECKING:
    from tapmuscle.cosim.expect import Expectations

__all__ = ["ScenarioError", "Profile", "Reference", "FmuSpec", "Scenario", "load_scenario", "parse_scenario",
           "read_toml", "INTERFACE_ROLES", "OWN_METHOD_PREFIX"]


class ScenarioError(TapmuscleError):
    """A scenario that cannot run; the message names the file and the key."""


@dataclass(frozen=True)
class Profile:
    """A piecewise-constant signal: ``initial`` until the first step, then each step's value from its time."""

    initial: float
    """The value before the first step (load [N], supply pressure [MPa])."""
    steps: tuple[tuple[float, float], ...] = ()
    """``(t_s, value)`` in increasing time."""

    def at(self, t_s: float) -> float:
        value = self.initial
        for t, v in self.steps:
            if t_s + 1e-9 >= t:
                value = v
        return value


@dataclass(frozen=True)
class Reference:
    """The reference ``r`` [mm]: ``kind = "sine"`` (built-in, exact preview) or ``"steps"`` (input r)."""

    kind: str = "sine"
    """``"sine"`` or ``"steps"``."""
    offset_mm: float = 35.0
    """For ``kind = "sine"``: the offset [mm]."""
    amplitude_mm: float = 30.0
    """For ``kind = "sine"``: the amplitude [mm]."""
    frequency_hz: float = 0.1
    """For ``kind = "sine"``: the frequency [Hz]."""
    steps: Profile | None = None
    """For ``kind = "steps"``: the profile."""
    preview: str = "advanced"
    """For ``kind = "steps"``: ``advanced`` (the master feeds ``r(t + Hp Ts)``: exact preview) or ``held``."""

    def at(self, t_s: float) -> float:
        if self.kind == "sine":
            return self.offset_mm + self.amplitude_mm * math.sin(2.0 * math.pi * self.frequency_hz * t_s)
        return self.steps.at(t_s)


@dataclass(frozen=True)
class FmuSpec:
    """One FMU of the scenario."""

    path: Path | None
    """The .fmu file; None = built from this checkout's sources."""
    parameters: Mapping[str, Any] = field(default_factory=dict)
    """FMU variable name -> value (float, int, or an enumeration item name)."""
    parameters_file: Path | None = None
    """The file whose values ``parameters`` holds (``[plant] parameters_file``, ``[controller]
    identification``), kept so that a run's ``summary.json`` says where its plant or its controller's
    model came from; None without one."""
    interface: Mapping[str, str] | None = None
    """For a controller FMU of one's own (``[controller] interface``): the names of its variables for
    the roles :data:`INTERFACE_ROLES` (``measurement``: the input that reads ``l`` [mm];
    ``reference``: the input that reads ``r`` [mm]; ``command``: the output the plant's valve takes
    as ``u`` [V]); None for the project's controller, whose interface the master knows."""

    @property
    def own(self) -> bool:
        """True for a controller FMU of one's own (one with an :attr:`interface`)."""
        return self.interface is not None


@dataclass(frozen=True)
class Scenario:
    """A parsed, checked scenario file (module docstring)."""

    name: str
    """The scenario's name (default: the file name)."""
    source: str
    """Where it came from (file path), for messages."""
    duration_s: float
    """Length of the run [s], a whole number of steps."""
    step_s: float
    """Macro (communication) step [s], the controller's Ts."""
    seed: int
    """The plant's sensor-noise seed."""
    plant: FmuSpec
    """The plant FMU and its parameters."""
    controller: FmuSpec
    """The controller FMU and its parameters."""
    method: str
    """The project controller's method (:data:`~fmu_controller.displacement_control.METHODS`), or for a
    controller FMU of one's own ``own:<the FMU file's stem>`` (:data:`OWN_METHOD_PREFIX`)."""
    reference: Reference
    """The reference ``r`` [mm]."""
    load: Profile
    """The hanging load's profile [N]."""
    supply: Profile
    """The supply pressure's profile [MPa]."""
    evaluation_samples: tuple[int, int] = (101, 401)
    """The Eq. (21) window as sample numbers ``(k0, k1)``, inclusive."""
    description: str = ""
    """Free text describing the scenario."""
    expect: "Expectations | None" = None
    """The ``[expect]`` table (:mod:`tapmuscle.cosim.expect`), None without one."""

    def __post_init__(self) -> None:
        # a scenario changed in code (dataclasses.replace with a shorter duration_s) is refused here,
        # not after its whole run
        k0, k1 = self.evaluation_samples
        if self.step_s > 0 and math.isfinite(self.duration_s) and not 0 <= k0 <= k1 < self.n_samples:
            raise ScenarioError(f"{self.source}: evaluation_samples = ({k0}, {k1}) is not within the run's samples "
                                f"k = 0 .. {self.n_samples - 1} ({self.duration_s:g} s at step {self.step_s:g} s): "
                                "change evaluation_samples with duration_s (dataclasses.replace(scenario, "
                                "duration_s=..., evaluation_samples=(k0, k1)))")

    @property
    def n_samples(self) -> int:
        """Rows of the result: ``t_k = k step_s`` for ``k = 0 .. duration_s / step_s``."""
        return int(round(self.duration_s / self.step_s)) + 1


#: The roles of a controller FMU of one's own's variables (``[controller] interface``), as
#: :attr:`FmuSpec.interface` describes them.
INTERFACE_ROLES = ("measurement", "reference", "command")

#: :attr:`Scenario.method` of a run with a controller FMU of one's own: this, then the FMU file's stem.
OWN_METHOD_PREFIX = "own:"

#: The top-level keys that make a TOML file a sweep (docs/sweeps.md), none of them a scenario's.
SWEEP_KEYS = ("base", "grid", "monte_carlo")

#: Most samples of one scenario run (24 h at Ts = 0.1 s).
MAX_RUN_SAMPLES = 864_001

_TOP = {"name", "description", "duration_s", "step_s", "seed", "evaluation_samples", "evaluation_window_s",
        "plant", "controller", "reference", "load", "supply", "expect"}


def _evaluation_window(top: "_Reader", data: Mapping[str, Any], n: int, step: float,
                       duration: float) -> list[int]:
    """The evaluation window ``[k0, k1]`` (samples, inclusive) of a scenario.

    By default Eq. (21)'s 10.1..40.1 s, in seconds whatever ``step_s`` is, ending at the run's end when
    that comes first, so a 40.0-s run is scored like a 40.1-s one; a run that ends by 10.1 s (all of it
    start-up) is evaluated whole. ``evaluation_samples = [k0, k1]`` or ``evaluation_window_s = [t0, t1]``
    (times on the ``step_s`` grid) choose another.
    """
    if "evaluation_samples" in data and "evaluation_window_s" in data:
        raise top.error("evaluation_window_s", "give the window either in samples (evaluation_samples) or in "
                                               "seconds (evaluation_window_s), not both")
    if "evaluation_window_s" in data:
        key, times = "evaluation_window_s", data["evaluation_window_s"]
        if (not isinstance(times, list) or len(times) != 2
                or not all(isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) for t in times)
                or not 0 <= times[0] <= times[1]):
            raise top.error(key, f"must be [t0, t1] with 0 <= t0 <= t1 finite numbers [s], got {times!r}")
        window = [int(round(t / step)) for t in times]
        for t, k in zip(times, window):
            if abs(k * step - t) > 1e-6 * step:
                raise top.error(key, f"{t:g} s is not a sample time of step_s = {step:g} s (nearest: "
                                     f"{k * step:.12g} s)")
    elif "evaluation_samples" in data:
        key, window = "evaluation_samples", data["evaluation_samples"]
        if (not isinstance(window, list) or len(window) != 2
                or not all(isinstance(k, int) and not isinstance(k, bool) for k in window)
                or not 0 <= window[0] <= window[1]):
            raise top.error(key, f"must be [k0, k1] with 0 <= k0 <= k1 integers, got {window!r}")
    else:
        k0, k1 = eq21_window(step)
        return [k0, min(k1, n - 1)] if k0 < n - 1 else [0, n - 1]
    if window[1] >= n:
        raise top.error(key, f"{window[1] * step:.12g} s (k1 = {window[1]}) is past the run's last sample "
                             f"k = {n - 1} ({duration:g} s at step {step:g} s)")
    return window


def _pythonfmu_source_hint(fmu: Path) -> str:
    """Where a missing ``NAME.fmu`` has its pythonfmu source beside it (a ``.py`` file defining class
    ``NAME``, as the shipped example's PIController), the command that builds it."""
    if fmu.suffix.lower() != ".fmu" or not fmu.parent.is_dir():
        return ""
    for source in sorted(fmu.parent.glob("*.py")):
        try:
            text = source.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            continue
        if f"class {fmu.stem}(" in text and "pythonfmu" in text:
            if os.access(fmu.parent, os.W_OK | os.X_OK):
                return (f": build it from {source.name} beside it first (pythonfmu build -f {source.name}, in "
                        f"{fmu.parent})")
            # an installed package's examples: read-only for a user
            return (f": build it from {source.name} beside it first; {fmu.parent} cannot be written (an installed "
                    f"package's?), so copy the folder and run there: cp -r {shlex.quote(str(fmu.parent))} my_copy && cd my_copy "
                    f"&& pythonfmu build -f {source.name}, then the scenario file in my_copy")
    return ""


class _Reader:
    """Typed access to one TOML table that names file and key in every error."""

    def __init__(self, source: str, table: Mapping[str, Any], prefix: str = "") -> None:
        self.source, self.table, self.prefix = source, table, prefix

    def error(self, key: str, message: str) -> ScenarioError:
        return ScenarioError(f"{self.source}: key '{self.prefix}{key}': {message}")

    def check_keys(self, allowed: set[str]) -> None:
        for key in self.table:
            if key not in allowed:
                raise self.error(key, f"unknown key; allowed here: {', '.join(sorted(allowed))}")

    def number(self, key: str, default: float | None = None, *, lo: float = -math.inf, hi: float = math.inf,
               lo_open: bool = False) -> float:
        if key not in self.table:
            if default is None:
                raise self.error(key, "missing (a number is required)")
            return default
        v = self.table[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.error(key, f"must be a number, got {type(v).__name__} {v!r}")
        v = float(v)
        if not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo):
            raise self.error(key, f"{v!r} is outside {'(' if lo_open else '['}{lo:g}, {hi:g}]{_unit_hint(key, v, hi)}")
        return v

    def integer(self, key: str, default: int, *, lo: int = 0, hi: int | None = None) -> int:
        v = self.table.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(key, f"must be an integer, got {type(v).__name__} {v!r}")
        if v < lo:
            raise self.error(key, f"{v!r} must be >= {lo}")
        if hi is not None and v > hi:
            raise self.error(key, f"{v!r} must be <= {hi}")
        return v

    def string(self, key: str, default: str | None = None, choices: tuple[str, ...] | None = None) -> str:
        if key not in self.table:
            if default is None:
                raise self.error(key, "missing (a string is required)")
            return default
        v = self.table[key]
        if not isinstance(v, str):
            raise self.error(key, f"must be a string, got {type(v).__name__} {v!r}")
        if choices is not None and v not in choices:
            raise self.error(key, f"{v!r} is not one of {', '.join(choices)}")
        return v

    def sub(self, key: str, required: bool = False) -> "_Reader":
        v = self.table.get(key, None)
        if v is None:
            if required:
                raise self.error(key, "missing table")
            v = {}
        if not isinstance(v, dict):
            raise self.error(key, f"must be a table, got {type(v).__name__} {v!r}")
        return _Reader(self.source, v, f"{self.prefix}{key}.")

    def path(self, key: str, base: Path | None) -> Path | None:
        if key not in self.table:
            return None
        text = self.string(key)
        broken = broken_path(text)
        if broken:
            raise self.error(key, broken)
        p = Path(text)
        p = p if p.is_absolute() or base is None else base / p
        if p.is_dir():
            raise self.error(key, f"{str(p)!r} is a folder, not a file")
        if not p.is_file():
            raise self.error(key, f"file {str(p)!r} does not exist{_pythonfmu_source_hint(p)}")
        return p

    def profile(self, initial_key: str, value_key: str, default: float, lo: float, hi: float, *,
                last_step_s: float, step_s: float) -> Profile:
        """The initial value and the steps, each at a time a step of the run acts on: a communication
        point (a multiple of ``step_s`` [s]: between two, the step would act at the next one without a
        word), at or before ``last_step_s`` [s], the start of the run's last step."""
        initial = self.number(initial_key, default, lo=lo, hi=hi)
        raw = self.table.get("steps", [])
        if not isinstance(raw, list):
            raise self.error("steps", f"must be an array of tables {{ t_s = ..., {value_key} = ... }}")
        steps, last = [], -math.inf
        for i, item in enumerate(raw):
            if not isinstance(item, dict):
                raise self.error(f"steps[{i}]", f"must be a table {{ t_s = ..., {value_key} = ... }}, got {item!r}")
            r = _Reader(self.source, item, f"{self.prefix}steps[{i}].")
            r.check_keys({"t_s", value_key})
            t = r.number("t_s", lo=0.0)
            if t <= last:
                raise r.error("t_s", f"{t!r} must be later than the previous step ({last!r})")
            if t > last_step_s + 1e-9:  # a step the file promises must act
                raise r.error("t_s", f"{t!r} s comes after the start of the run's last step, {last_step_s:.12g} s "
                                     "(duration_s - step_s): it would never act")
            off_grid = _off_grid(t, step_s)
            if off_grid:
                raise r.error("t_s", off_grid)
            steps.append((t, r.number(value_key, lo=lo, hi=hi)))
            last = t
        return Profile(initial, tuple(steps))


def _off_grid(t_s: float, step_s: float) -> str:
    """Why a step's time ``t_s`` [s] is not a communication point of ``step_s`` [s] (the nearest two
    named), or ``""`` where it is one."""
    if abs(round(t_s / step_s) * step_s - t_s) <= 1e-6 * step_s:
        return ""
    return (f"{t_s:g} s is not a sample time of step_s = {step_s:g} s (nearest: {math.floor(t_s / step_s) * step_s:.12g} "
            f"and {math.ceil(t_s / step_s) * step_s:.12g} s)")


#: A key's name suffix -> its unit, and the other units a value too large for it is likely in, with
#: their factor to it.
_OTHER_UNITS: dict[str, tuple[str, tuple[tuple[str, float], ...]]] = {
    "_mpa": ("MPa", (("bar", 0.1), ("kPa", 1e-3), ("Pa", 1e-6))),
    "_n": ("N", (("mN", 1e-3),)),
    "_s": ("s", (("ms", 1e-3),)),
    "_mm": ("mm", (("um", 1e-3),)),
}


def _unit_hint(key: str, value: float, hi: float) -> str:
    """``"; in bar? 2.5 bar is 0.25 MPa"`` for a value above its key's range that is in range in another
    likely unit (the first that fits), else ``""``."""
    if not (math.isfinite(value) and value > hi):
        return ""
    for suffix, (unit, others) in _OTHER_UNITS.items():
        if key.endswith(suffix):
            for other, factor in others:
                if value * factor <= hi:
                    return f"; in {other}? {value:g} {other} is {value * factor:.4g} {unit}"
    return ""


def _parameters(r: _Reader, *, booleans: bool = False) -> dict[str, Any]:
    """The ``parameters`` table: numbers and enumeration names, and with ``booleans`` true/false (a
    controller FMU of one's own may have Boolean parameters; the project's FMUs have none)."""
    params = r.table.get("parameters", {})
    if not isinstance(params, dict):
        raise r.error("parameters", f"must be a table of FMU variable name = value, got {params!r}")
    for key, value in params.items():
        if (isinstance(value, bool) and not booleans) or not isinstance(value, (int, float, str)):
            kinds = "a number, true/false or an enumeration name" if booleans else "a number or an enumeration name"
            raise _Reader(r.source, params, f"{r.prefix}parameters.").error(
                key, f"must be {kinds}, got {type(value).__name__} {value!r}")
    return dict(params)


def _identification_parameters(r: _Reader, base: Path | None, step_s: float, method: str) -> dict[str, Any]:
    """The AMPCController parameters of the ``tapmuscle identify --json`` file ``identification`` names
    (:meth:`~tapmuscle.io.identification_file.IdentifiedModel.fmu_start_values` for ``method``, but
    ``Ts``: the scenario's ``step_s``), checked for that period; the scenario's own parameters override
    them (a parallel master at h = Ts adds a sample to the rig's delay). Empty without one."""
    path = r.path("identification", base)
    if path is None:
        return {}
    try:
        model = read_identification(path)
        model.check_period(step_s)
        values = model.fmu_start_values(method)
    except IdentificationFileError as exc:
        raise r.error("identification", str(exc)) from None
    del values["Ts"]
    return values


def _own_controller(r: _Reader, base: Path | None) -> FmuSpec:
    """The ``[controller]`` table of a controller FMU of one's own: its file (required), the names of
    its variables in ``interface`` (every one of :data:`INTERFACE_ROLES`, a non-empty string) and its
    parameters; the project controller's keys ``method`` and ``identification`` refused."""
    for key in ("method", "identification"):
        if key in r.table:
            raise r.error(key, "chooses the project's AMPCController's law or model; a controller FMU of one's own "
                               "([controller] interface) runs its own: remove the key, or the interface to run the "
                               "project's controller")
    if "fmu" not in r.table:
        raise r.error("fmu", "missing: a controller with an interface is an FMU of one's own; name its file")
    iface = r.sub("interface")
    iface.check_keys(set(INTERFACE_ROLES))
    names = {}
    for role in INTERFACE_ROLES:
        name = iface.string(role)
        if not name.strip():
            raise iface.error(role, "must name a variable of the FMU, got an empty string")
        names[role] = name
    for i, role in enumerate(INTERFACE_ROLES):
        earlier = [r for r in INTERFACE_ROLES[:i] if names[r] == names[role]]
        if earlier:
            raise iface.error(role, f"names {names[role]!r}, as {earlier[0]} does: each role is a variable of its own")
    params = _parameters(r, booleans=True)
    for role, name in names.items():
        if name in params:
            raise _Reader(r.source, params, f"{r.prefix}parameters.").error(
                name, f"is the controller's {role} (interface), which the master sets every sample: remove it")
    return FmuSpec(r.path("fmu", base), params, interface=names)


def _plant_file_parameters(r: _Reader, base: Path | None) -> tuple[dict[str, Any], dict[str, float]]:
    """The MusclePlant parameters of the plant parameter file ``parameters_file`` names (e.g. the
    ``calibrated_plant.json`` that ``tapmuscle diagnose`` writes), by FMU variable name, and the file's
    load and supply pressure; both empty without a file. The load and the supply pressure are the plant
    FMU's inputs, which the scenario drives (``[load]``, ``[supply]``): the file's ``load.load_n`` and
    ``supply.supply_pressure_mpa`` are returned apart, as those sections' defaults (a rig file at
    100 N run at the scenario's default 44 N would be another rig); its effects (a ``load_mismatch`` on
    top of the load, a timed supply sag) are kept."""
    path = r.path("parameters_file", base)
    if path is None:
        return {}, {}
    try:
        params = read_plant_file(path, f"{r.source}: key '{r.prefix}parameters_file'")
    except PlantFileError as exc:
        raise ScenarioError(str(exc)) from None
    inputs = ("load.load_n", "supply.supply_pressure_mpa")
    dotted = params.dotted()
    return ({name: value for name, value in dotted.items() if name not in inputs},
            {name: float(dotted[name]) for name in inputs})


def parse_scenario(data: Mapping[str, Any], *, source: str = "<scenario>", base: Path | None = None,
                   default_name: str = "scenario") -> Scenario:
    """Check a scenario given as a mapping (the parsed TOML); ``base`` resolves relative FMU paths.

    Parameters
    ----------
    data : mapping
        The scenario, as parsed from TOML.
    source : str, optional
        Where it came from, for messages; default ``"<scenario>"``.
    base : Path, optional
        The folder relative FMU and parameter-file paths are resolved against.
    default_name : str, optional
        The scenario's name when ``data`` gives none; default ``"scenario"``.
    """
    top = _Reader(source, data)
    top.check_keys(_TOP)
    duration = top.number("duration_s", lo=0.0, hi=1e6, lo_open=True)
    step = top.number("step_s", 0.1, lo=0.0, hi=60.0, lo_open=True)
    n = int(round(duration / step)) + 1
    if n < 2:
        raise top.error("step_s", f"{step:g} s leaves no step in duration_s = {duration:g} s (step_s must be <= "
                                  "duration_s)")
    if abs((n - 1) * step - duration) > 1e-9 * max(duration, step):
        # the run ends on the step grid: a duration between two samples would be reported but not run
        raise top.error("duration_s", f"{duration:g} s is not a whole number of steps of step_s = {step:g} s "
                                      f"({duration / step:.6g}); the nearest: {(n - 1) * step:.12g} s")
    if n > MAX_RUN_SAMPLES:
        raise top.error("duration_s", f"{duration:g} s at step_s = {step:g} s makes {n} samples; at most "
                                      f"{MAX_RUN_SAMPLES} in one run")
    window = _evaluation_window(top, data, n, step, duration)

    plant_r = top.sub("plant")
    plant_r.check_keys({"fmu", "parameters", "parameters_file"})
    file_parameters, file_inputs = _plant_file_parameters(plant_r, base)
    plant = FmuSpec(plant_r.path("fmu", base), {**file_parameters, **_parameters(plant_r)},
                    plant_r.path("parameters_file", base))
    ctrl_r = top.sub("controller")
    ctrl_r.check_keys({"fmu", "parameters", "method", "identification", "interface"})
    if "interface" in ctrl_r.table:
        controller = _own_controller(ctrl_r, base)
        method = OWN_METHOD_PREFIX + controller.path.stem
    else:
        method = ctrl_r.string("method", "ampc_servo", METHODS)
        controller = FmuSpec(ctrl_r.path("fmu", base), {**_identification_parameters(ctrl_r, base, step, method),
                                                        **_parameters(ctrl_r)}, ctrl_r.path("identification", base))
        for key in ("method", "Ts", "reference_source", "sine.offset", "sine.amplitude", "sine.frequency"):
            if key in controller.parameters:
                raise _Reader(source, controller.parameters, "controller.parameters.").error(
                    key, "is set by the scenario itself (controller.method, step_s, [reference]); set it there")
    if "seed" in plant.parameters:
        raise _Reader(source, plant.parameters, "plant.parameters.").error("seed", "set the top-level key 'seed'")
    ref_r = top.sub("reference")
    kind = ref_r.string("kind", "sine", ("sine", "steps"))
    if kind == "sine":
        ref_r.check_keys({"kind", "offset_mm", "amplitude_mm", "frequency_hz"})
        # the muscle contracts at most 150 mm of its 400: a reference far beyond is a unit mistake
        reference = Reference("sine", ref_r.number("offset_mm", 35.0, lo=-400.0, hi=400.0),
                              ref_r.number("amplitude_mm", 30.0, lo=0.0, hi=400.0),
                              ref_r.number("frequency_hz", 0.1, lo=0.0, hi=0.5 / step))
    else:
        ref_r.check_keys({"kind", "values_mm", "times_s", "preview"})
        values, times = ref_r.table.get("values_mm"), ref_r.table.get("times_s")
        for key, seq in (("values_mm", values), ("times_s", times)):
            if not isinstance(seq, list) or not seq or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in seq):
                raise ref_r.error(key, f"must be a non-empty array of numbers, got {seq!r}")
        far = [v for v in values if not -400.0 <= v <= 400.0]
        if far:  # as the sine's offset and amplitude: a unit mistake
            raise ref_r.error("values_mm", f"holds {far[0]!r}, outside [-400, 400] mm (the muscle contracts at most "
                                           "150 mm of its 400: a value far beyond is in another unit)")
        if len(values) != len(times):
            raise ref_r.error("times_s", f"has {len(times)} entries, values_mm has {len(values)}")
        if times[0] != 0 or any(b <= a for a, b in zip(times, times[1:])):
            raise ref_r.error("times_s", f"must start at 0 and increase, got {times!r}")
        late = [t for t in times if t > duration * (1.0 + 1e-12)]
        if late:  # as a load step the run never reaches
            ms = (f"; times in ms? {late[0] / 1000.0:g} s falls within it"
                  if 10.0 * duration <= late[0] <= 1000.0 * duration else "")
            raise ref_r.error("times_s", f"{late[0]:g} s comes after the run's end, duration_s = {duration:g} s: the "
                                         f"reference would never take that value{ms}")
        # the controller samples r at k step_s: a step between two samples would act at the next one
        off_grid = next((why for why in (_off_grid(t, step) for t in times) if why), "")
        if off_grid:
            raise ref_r.error("times_s", off_grid)
        profile = Profile(float(values[0]), tuple((float(t), float(v)) for t, v in zip(times[1:], values[1:])))
        preview = ref_r.string("preview", "held" if controller.own else "advanced", ("advanced", "held"))
        if controller.own and preview == "advanced":
            # r(t + Hp Ts) is the project controller's way to rebuild its preview r(k..k+Hp)
            raise ref_r.error("preview", "'advanced' feeds r(t + Hp Ts) for the project's controller to rebuild "
                                         "its preview; a controller FMU of one's own reads r(k) at sample k: "
                                         "'held' (the default for it)")
        reference = Reference("steps", steps=profile, preview=preview)

    load_r = top.sub("load")
    load_r.check_keys({"initial_n", "steps"})
    # without a value of the scenario's own, the plant file's rig at its own load and supply pressure
    load = load_r.profile("initial_n", "load_n", file_inputs.get("load.load_n", 44.0), 0.0, 500.0,
                          last_step_s=(n - 2) * step, step_s=step)
    supply_r = top.sub("supply")
    supply_r.check_keys({"initial_mpa", "steps"})
    supply = supply_r.profile("initial_mpa", "pressure_mpa", file_inputs.get("supply.supply_pressure_mpa", 0.25),
                              0.0, 1.0, last_step_s=(n - 2) * step, step_s=step)
    for key, profile, where in (("load.load_n", load, "[load] initial_n (and steps)"),
                                ("supply.supply_pressure_mpa", supply, "[supply] initial_mpa (and steps)")):
        # the FMU's inputs load and supply_pressure set them (a parameters_file's are those inputs'
        # defaults); the same value is harmless, another would be silently unused
        if key in plant.parameters and plant.parameters[key] != profile.initial:
            raise _Reader(source, plant.parameters, "plant.parameters.").error(
                key, f"= {plant.parameters[key]!r} is set by the plant FMU's input, which the scenario drives "
                     f"(now {profile.initial:g}): set {where}")
    from tapmuscle.cosim.expect import parse_expectations  # noqa: PLC0415 - expect imports this module

    expect = parse_expectations(data["expect"], source=source) if "expect" in data else None
    return Scenario(name=top.string("name", default_name), source=source, duration_s=duration, step_s=step,
                    seed=top.integer("seed", 0, hi=SEED_MAX), plant=plant, controller=controller, method=method,
                    reference=reference, load=load, supply=supply, evaluation_samples=(window[0], window[1]),
                    description=top.string("description", ""), expect=expect)


#: What a path in a TOML file that its backslashes broke needs.
WINDOWS_PATH_HINT = ("a Windows path in a double-quoted TOML string reads its backslashes as escapes (\\n, \\t, \\f, "
                     "\\u...): write it in single quotes, 'C:\\Users\\me\\rig.json', or with forward slashes, "
                     "\"C:/Users/me/rig.json\"")


def broken_path(text: str) -> str:
    """Why the path ``text`` from a TOML file cannot be a file's name, else empty: a control character,
    as a Windows path in double quotes gets ("C:\\new\\file.json" reads as a newline and a form feed)."""
    control = next((c for c in text if c < " "), None)
    return "" if control is None else f"{text!r} holds the control character {control!r}: {WINDOWS_PATH_HINT}"


def read_toml(path: str | Path, what: str = "scenario") -> dict[str, Any]:
    """The parsed TOML file ``path``; a missing, unreadable or invalid file raises ScenarioError.

    Parameters
    ----------
    path : str or Path
        The TOML file.
    what : str, optional
        What kind of file it is, for messages; default ``"scenario"``.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError(f"{path}: {what} file does not exist{_shipped_hint(path)}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        escape = any(m in str(exc) for m in ("Unescaped '\\'", "Invalid hex value"))
        raise ScenarioError(f"{path}: not valid TOML: {exc}" + (f"; {WINDOWS_PATH_HINT}" if escape else "")) from None
    except RecursionError:  # tomllib's parser recurses once per level of arrays or tables nested in one another
        raise ScenarioError(f"{path}: not a {what} file: its arrays or tables are nested too deep to read") from None


def _shipped_hint(path: Path) -> str:
    """Where tapmuscle ships a file of that relative name (``paper/...``, ``scenarios/paper/...``: a
    name from the docs, typed outside the checkout), as a hint; else empty."""
    if path.is_absolute():
        return ""
    from tapmuscle.cosim import SCENARIO_FILES  # noqa: PLC0415 - the package imports this module

    parts = path.parts[1:] if path.parts[:1] == ("scenarios",) else path.parts
    shipped = SCENARIO_FILES.joinpath(*parts) if parts else None
    if shipped is None or not shipped.is_file():
        return ""
    return f" in {Path.cwd()}; tapmuscle ships one by that name: {shipped}"


def load_scenario(path: str | Path) -> Scenario:
    """Read and check a scenario file (module docstring); errors name the file and key.

    Parameters
    ----------
    path : path
        A scenario TOML file (docs/fmu.md); relative FMU paths in it are relative to its folder.

    Returns
    -------
    Scenario

    Raises
    ------
    ScenarioError
        A missing file, bad TOML, an unknown or out-of-range key (named with the file).
    """
    path = Path(path)
    data = read_toml(path)
    sweep_keys = [key for key in SWEEP_KEYS if key in data]
    if sweep_keys:
        raise ScenarioError(f"{path}: a sweep file (it has {', '.join(repr(k) for k in sweep_keys)}), not a scenario; "
                            "run it with tapmuscle sweep (or tapmuscle check)")
    return parse_scenario(data, source=str(path), base=path.parent, default_name=path.stem)
