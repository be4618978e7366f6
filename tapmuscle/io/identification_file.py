"""The identification file ``tapmuscle identify --json`` writes, read back as a controller's ``theta0``.

A controller needs Eq. (1) at its own sampling period, in millimetres and volts, and an adaptive one
a ``theta0`` inside its constraint region C. The file has ``theta`` (by name, in the units of the
recording it was identified on: mm and V in the recording format), ``ts_s`` and ``constraint`` (the box
it used, empty off Ts = 0.1 s). :func:`read_identification` refuses the standard model (the controllers
use the asymmetric one), and :meth:`IdentifiedModel.check_period` a model identified at another period
than the controller's: one at 0.05 s used at 0.2 s gave 9 mm of Eq. (21) error instead of 0.19, without
a word. (Its ``scaling`` is how the identification normalised the data internally, by magnitude: a
recording with a small stroke in mm has ``l_scale`` 0.1, so it tells the unit only at the extremes,
where :func:`read_identification` warns: a largest displacement under 1.9 or over 1900, a command
under 0.19 or of 19 or more, as in metres, micrometres, millivolts, or a command in % of the valve's
opening or volts x 10, which the 0..10-V valve never takes.)
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

from fmu_controller.argument_checks import sampling_period
from fmu_controller.box_projection import named_box
from fmu_controller.methods import METHODS
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.identification import PAPER_TS_S, units_note
from fmu_controller.rls import TABLE2_LOWER, TABLE2_UPPER
from fmu_controller.prediction import checked_input_delay
from fmu_controller.preliminary_model import THETA0_LIMIT
from fmu_plant.user_warning import warn_at_caller
from tapmuscle.errors import TapmuscleError
from tapmuscle.io.recording import atomic_write_text
from tapmuscle.io.json_file import read_json
from tapmuscle.provenance import produced_by

__all__ = ["identified_model", "IdentificationFileError", "IdentifiedModel", "read_identification", "write_identification", "checked_box"]

#: Relative difference of two sampling periods taken as the same (a period read back from times).
_SAME_PERIOD = 1e-6


class IdentificationFileError(TapmuscleError):
    """An identification file that cannot serve as a controller's theta0; the message names the file
    and the key."""


@dataclass(frozen=True)
class IdentifiedModel:
    """Eq. (1) as ``tapmuscle identify`` identified it, in mm and V."""

    theta: dict[str, float]
    """The 15 parameters by name (:data:`~fmu_controller.hysteresis_model.ASYMMETRIC`'s)."""
    ts_s: float
    """The sampling period [s] of the recording it was identified on: the controller's Ts."""
    box_lower: dict[str, float]
    """Lower bounds of the constraint region C it was identified in (empty: none)."""
    box_upper: dict[str, float]
    """Upper bounds of C (empty: none)."""
    path: str
    """The file it was read from."""
    input_delay_samples: int = 0
    """The rig's transport delay [samples] it was identified under (``tapmuscle identify
    --input-delay-samples``): the controller's ``input_delay_samples`` it predicts for."""

    def fmu_start_values(self, method: str = "ampc_servo") -> dict[str, float | int]:
        """The AMPCController FMU's parameters that put this model in it, by FMU variable name.

        ``Ts`` (the model's period), ``theta0.*``, for an adaptive method the box C on
        ``a1, a2, b1`` (``box_lower.*``/``box_upper.*``, -inf/inf where this model has none: left unset,
        the FMU keeps Table 2's, for Ts = 0.1 s in mm and V), and ``input_delay_samples`` where it was
        identified under a transport delay (a parallel master at h = Ts adds one sample to it). Set them
        before ``fmi2ExitInitializationMode``; in fmpy, ``simulate_fmu(..., start_values=
        model.fmu_start_values(), output_interval=model.ts_s)``. A scenario's ``[controller]
        identification`` sets the same (its ``step_s`` is ``Ts``).

        Parameters
        ----------
        method : {"mpc_ucp", "mpc_servo", "ampc_ucp", "ampc_servo"}
            The controller's method: a fixed one (MPC) takes no box.

        Raises
        ------
        IdentificationFileError
            An unknown method, or a box on other parameters than ``a1, a2, b1`` (the FMU's C bounds
            only these).
        """
        if method not in METHODS:
            raise IdentificationFileError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
        values: dict[str, float | int] = {"Ts": self.ts_s, **{f"theta0.{n}": v for n, v in self.theta.items()}}
        if method.startswith("ampc"):
            extra = sorted((set(self.box_lower) | set(self.box_upper)) - set(TABLE2_LOWER))
            if extra:
                raise IdentificationFileError(f"{self.path}: its constraint region bounds {', '.join(extra)}; the "
                                              f"controller FMU's C bounds only {', '.join(TABLE2_LOWER)}")
            values |= {f"box_lower.{n}": self.box_lower.get(n, -math.inf) for n in TABLE2_LOWER}
            values |= {f"box_upper.{n}": self.box_upper.get(n, math.inf) for n in TABLE2_LOWER}
        if self.input_delay_samples:
            values["input_delay_samples"] = self.input_delay_samples
        return values

    def check_period(self, ts_s: float) -> None:
        """Refuse a controller period ``ts_s`` [s] other than :attr:`ts_s`: Eq. (1) is a model of one
        sampling period.

        Raises
        ------
        IdentificationFileError
            Naming both periods and the file.
        """
        if abs(ts_s - self.ts_s) > _SAME_PERIOD * self.ts_s:
            raise IdentificationFileError(f"{self.path}: identified at ts_s = {self.ts_s:g} s, the controller samples "
                                          f"at {ts_s:g} s: Eq. (1) is a model of one sampling period (identify on a "
                                          f"recording at {ts_s:g} s)")


def read_identification(path: str | Path) -> IdentifiedModel:
    """Read a ``tapmuscle identify --json`` file as a controller's ``theta0``.

    Parameters
    ----------
    path : path
        The JSON file.

    Returns
    -------
    IdentifiedModel
        ``theta`` (pass it as ``theta0``), ``ts_s``, the box ``box_lower``/``box_upper`` for an
        adaptive controller's :class:`~fmu_controller.displacement_control.ControllerSettings`, and
        ``input_delay_samples`` (0 in a file without the key).

    Raises
    ------
    IdentificationFileError
        No such file, not JSON, a missing or non-finite key, or the standard model (the controllers use
        the asymmetric one).
    """
    where = str(path)
    data = read_json(path, IdentificationFileError, where=where, missing=f"{where}: no such identification file")
    return identified_model(data, where)


def identified_model(data: object, where: str) -> IdentifiedModel:
    """The :class:`IdentifiedModel` of an identification's ``to_dict()`` (what ``tapmuscle identify
    --json`` writes), checked as :func:`read_identification` checks a file; ``where`` names it in the
    errors and warnings (the file, or ``theta0 (tm.identify's result)``).

    Parameters
    ----------
    data : object
        The identification's ``to_dict()``, or a file's parsed JSON.
    where : str
        How the errors and warnings name it.
    """
    if not isinstance(data, dict) or not {"model", "ts_s", "theta"} <= set(data):
        missing = sorted({"model", "ts_s", "theta"} - set(data)) if isinstance(data, dict) else ["model", "ts_s", "theta"]
        raise IdentificationFileError(f"{where}: key{'s' if len(missing) > 1 else ''} {', '.join(repr(k) for k in missing)} "
                                      "missing: not a `tapmuscle identify --json` file (which has model, ts_s, theta, "
                                      "constraint)")
    if data["model"] != "asymmetric":
        raise IdentificationFileError(f"{where}: key 'model' is {data['model']!r}; the controllers use the asymmetric "
                                      "model of Eq. (1) (identify with --model asymmetric, the default)")
    ts = data["ts_s"]
    if isinstance(ts, bool) or not isinstance(ts, (int, float)) or not math.isfinite(ts) or ts <= 0:
        raise IdentificationFileError(f"{where}: key 'ts_s' must be a positive number of seconds, got {ts!r}")
    try:
        sampling_period(ts, what="key 'ts_s'")
    except ValueError as exc:
        raise IdentificationFileError(f"{where}: {exc}") from None
    theta = data["theta"]
    if not isinstance(theta, dict) or set(theta) != set(ASYMMETRIC.names):
        missing = sorted(set(ASYMMETRIC.names) - set(theta)) if isinstance(theta, dict) else ASYMMETRIC.names
        raise IdentificationFileError(f"{where}: key 'theta' must map the 15 names of Eq. (1) to numbers "
                                      f"(missing: {', '.join(missing) or 'none'}; extra: "
                                      f"{', '.join(sorted(set(theta) - set(ASYMMETRIC.names))) if isinstance(theta, dict) else '-'})")
    for name in ASYMMETRIC.names:
        v = theta[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise IdentificationFileError(f"{where}: key 'theta.{name}' must be a finite number, got {v!r}")
        if abs(v) > THETA0_LIMIT:
            raise IdentificationFileError(f"{where}: key 'theta.{name}' = {v!r} is outside -{THETA0_LIMIT:g}.."
                                          f"{THETA0_LIMIT:g}, the controllers' range of theta0 (an identification's "
                                          "coefficients are below 2 in mm and V: a hand edit, or another unit?)")
    box = data.get("constraint") or {}
    bounds = []
    for side, unbounded in (("lower", "-inf"), ("upper", "inf")):
        b = box.get(side) or {}
        # a strict-JSON writer's "-inf" / "inf" (tapmuscle.io.json_file.json_text) is no bound on that side
        b = {k: v for k, v in b.items() if v != unbounded} if isinstance(b, dict) else b
        if not isinstance(b, dict) or not all(isinstance(k, str) and isinstance(v, (int, float)) and not isinstance(v, bool)
                                              for k, v in b.items()):
            raise IdentificationFileError(f"{where}: key 'constraint.{side}' must map parameter names to numbers "
                                          f"(or \"{unbounded}\": none), got {box.get(side)!r}")
        bounds.append({k: float(v) for k, v in b.items()})
    try:
        bounds = list(checked_box(*bounds, what="key 'constraint'"))
    except ValueError as exc:
        raise IdentificationFileError(f"{where}: {exc}") from None
    delay = data.get("input_delay_samples", 0)  # files written before the key: identified without a delay
    if isinstance(delay, float) and delay.is_integer():
        delay = int(delay)  # a JSON writer's 2.0
    try:
        delay = checked_input_delay(delay)
    except ValueError as exc:
        raise IdentificationFileError(f"{where}: key 'input_delay_samples': {exc}") from None
    _warn_if_not_mm_and_v(data.get("scaling"), where)
    return IdentifiedModel({n: float(theta[n]) for n in ASYMMETRIC.names}, float(ts), bounds[0], bounds[1], where,
                           delay)


def _warn_if_not_mm_and_v(scaling: object, where: str) -> None:
    """Warn when the file's ``scaling`` (the powers of ten that brought the recording's largest
    displacement near 60 and command near 6, :func:`~fmu_controller.identification.decade_scale`) says
    the recording was not in mm and V as the controllers need
    (:func:`~fmu_controller.identification.units_note`). A model identified on
    displacements in metres ran the MPC-servo loop at 22 mm of Eq. (21) error against 0.11 mm in mm,
    one on a command in volts x 10 AMPC-servo at 22 mm, their warnings blaming the readings or theta0."""
    said = units_note(scaling)
    if said is not None:
        warn_at_caller(f"{where}: identified on {said}", UserWarning)


def checked_box(lower: Mapping[str, float], upper: Mapping[str, float], *, what: str
                ) -> tuple[dict[str, float], dict[str, float]]:
    """The constraint region C of Algorithm 1 on Eq. (1)'s parameters, checked as the controller
    checks it (:func:`fmu_controller.box_projection.named_box`; ``ValueError`` naming ``what``).

    Parameters
    ----------
    lower, upper : mapping of str to float
        Lower and upper bounds by parameter name of Eq. (1).
    what : str
        How the error message names the box.
    """
    return named_box(lower, upper, names=ASYMMETRIC.names, what=what)


def _auto_box(path: str | Path, theta: Sequence[float], ts_s: float, box_lower: object, box_upper: object
              ) -> tuple[object, object]:
    """:func:`write_identification`'s ``"auto"`` box: Table 2's at Ts = 0.1 s for a ``theta`` within it."""
    for name, side in (("box_lower", box_lower), ("box_upper", box_upper)):
        if isinstance(side, str) and side != "auto":
            raise ValueError(f"{name} must be a mapping, None or 'auto', got {side!r}")
    if not (box_lower == "auto" and box_upper == "auto"):  # one side given: the other "auto" is none
        return (None if box_lower == "auto" else box_lower), (None if box_upper == "auto" else box_upper)
    if abs(ts_s - PAPER_TS_S) > 1e-3 * PAPER_TS_S:
        return None, None
    outside = [f"{n} = {theta[ASYMMETRIC.index(n)]:.6g} (Table 2: {TABLE2_LOWER[n]:g} .. {TABLE2_UPPER[n]:g})"
               for n in TABLE2_LOWER if not TABLE2_LOWER[n] <= theta[ASYMMETRIC.index(n)] <= TABLE2_UPPER[n]]
    if outside:
        warn_at_caller(f"{path}: no constraint box written: theta's {outside[0]} lies outside Table 2's box, so an "
                       "adaptive controller started from this file runs Algorithm 1 without one; give "
                       "box_lower/box_upper (a box of this rig's spread: docs/identification.md)", UserWarning)
        return None, None
    return dict(TABLE2_LOWER), dict(TABLE2_UPPER)


def write_identification(path: str | Path, theta: Mapping[str, float] | Sequence[float], *, ts_s: float,
                         box_lower: Mapping[str, float] | None | str = "auto",
                         box_upper: Mapping[str, float] | None | str = "auto",
                         note: str = "", input_delay_samples: int = 0) -> None:
    """Write a model as ``tapmuscle identify --json`` does, for :func:`read_identification` and a
    scenario's ``[controller] identification``: a ``theta`` refined in closed loop
    (:func:`tapmuscle.paper.preliminary_theta`, or a controller FMU's final ``theta.*``), say. The
    file also records the releases that wrote it (``software``, :func:`tapmuscle.provenance.software`).

    Parameters
    ----------
    path : path
        The JSON file, written atomically.
    theta : mapping or sequence of 15 floats
        Eq. (1)'s parameters by name or in :data:`~fmu_controller.hysteresis_model.ASYMMETRIC`'s order
        [mm, V].
    ts_s : float
        The sampling period [s] it holds for.
    box_lower, box_upper : mapping, None or "auto"
        The constraint region C for an adaptive controller started from it (None: none). "auto"
        (both left at it, the default): Table 2's at the paper's Ts = 0.1 s where ``theta`` lies
        within it, as ``tapmuscle identify`` writes at that period (a theta refined in closed loop and
        written without it ran AMPC-servo unconstrained: 0.295 against 0.243 mm of Eq. (21) on a
        user's rig); none at another Ts, and none, with a ``UserWarning`` naming the parameter, where
        ``theta`` lies outside Table 2's.
    note : str
        Where it comes from (the file's ``notes``).
    input_delay_samples : int
        The transport delay [samples] it was identified under (0 .. 25; a scenario's controller
        takes it as its ``input_delay_samples``).

    Raises
    ------
    IdentificationFileError
        A theta that is not 15 finite numbers, a period outside the muscle's 1 ms .. 10 s (a
        period in milliseconds), a box that names no parameter of Eq. (1), holds a value that is not
        a number or NaN, or has a lower bound above its upper one, or a delay outside 0 .. 25 samples.
    """
    try:
        values = ASYMMETRIC.as_theta(theta, what="theta")
    except (TypeError, ValueError) as exc:
        raise IdentificationFileError(f"{path}: {exc}") from None
    try:
        ts_s = sampling_period(ts_s)
        if isinstance(box_lower, str) or isinstance(box_upper, str):
            box_lower, box_upper = _auto_box(path, values, ts_s, box_lower, box_upper)
        lower, upper = checked_box(box_lower or {}, box_upper or {}, what="box_lower, box_upper")
        delay = checked_input_delay(input_delay_samples)
    except (TypeError, ValueError) as exc:
        raise IdentificationFileError(f"{path}: {exc}") from None
    doc = {"model": "asymmetric", "ts_s": ts_s, "theta": dict(zip(ASYMMETRIC.names, values.tolist())),
           "constraint": {"lower": lower, "upper": upper},
           "input_delay_samples": delay, "notes": [note] if note else [], **produced_by()}
    atomic_write_text(Path(path), json.dumps(doc, indent=2) + "\n")
