"""What the diagnosis needs to know of a model family besides its simulator.

The search of :mod:`tapmuscle.diagnosis.diagnose` works on any model whose parameter sets have
``value(key)``, ``dotted()`` and ``with_values(**values)`` (as :class:`fmu_plant.PlantParams` does),
and a simulator with ``run`` / ``run_many``. The rest it asks a :class:`ModelSpace`:

* the bounds of a parameter (where the calibration and the joint re-fits may move it);
* which effect parameters are re-fitted jointly with the calibrated constants, with their scale;
* an effect's parameters at their "off" values (the backward step switches an effect off);
* further starts of an effect's joint re-fit, where the calibrated constants hold its own fit near
  its off value (an amplifier's map, a load, a rate dependence);
* the sensor noise the model states (the materiality reference of the residual tests).

:data:`MUSCLE` is the tapmuscle plant's; a foreign FMU has its own
(:class:`tapmuscle.diagnosis.boundary_candidates.BoundarySpace`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any, Iterable, Mapping

import numpy as np

from fmu_plant import PlantParams
from tapmuscle.diagnosis.recording_checks import AT_REST_MM, DRAINED_MPA

__all__ = ["ModelSpace", "MuscleSpace", "MUSCLE", "JOINT_PARAMETERS", "PROFILED", "JOINT_STARTS", "OFF_AT_NOMINAL",
           "OPERATING_CONDITIONS", "SUPPLY_STARTS", "STARTS_FROM_NOMINAL", "EXCLUSIVE", "sensor_noise_mm"]

#: Effect parameters re-fitted jointly with the calibrated constants (smooth in the prediction), with
#: the scale of their coordinate. The others keep the value their candidate's own search found (a
#: band's edges and a sag's window make the cost piecewise constant). A sensor drift's offset and rate
#: are joint although its own fit is linear least squares: the offset shifts the reading as the
#: constants or a load shift the muscle's equilibrium, so an offset fitted once on constants that the
#: joint re-fits then move stays wrong, and a spurious load is found to correct it. The play of a
#: backlash is joint although it acts on the measurement side: the friction's hysteresis mimics a play
#: (a higher base friction with a shorter presliding range), so the calibration absorbs much of it and
#: a play fitted on the calibrated constants comes out near zero; only a joint step that widens the
#: play while it gives the friction back its width finds the rig's. An input map's four outputs are
#: joint (its two knots' inputs are its own search's): an amplifier's gain and offset are taken up by
#: the flow coefficient, the threshold and the bladder in the calibration, so a map fitted on the
#: calibrated constants comes out near the identity; only a joint step moves the outputs and gives the
#: constants back (docs/diagnosis.md, step 5).
JOINT_PARAMETERS: dict[str, tuple[tuple[str, float], ...]] = {
    "rate_dependent_hysteresis": (("friction.rate_gain", 0.2),),
    "transport_delay": (("delay.delay_s", 0.02),),
    "supply_pressure_variation": (("supply_variation.sag_mpa", 0.01),),
    "load_mismatch": (("load_mismatch.extra_n", 2.0),),
    "supply_pressure_offset": (("supply.supply_pressure_mpa", 0.01),),
    "backlash": (("backlash.slack_mm", 0.5),),
    "sensor_drift": (("sensor_drift.offset_mm", 0.2), ("sensor_drift.rate_mm_per_min", 0.2)),
    "input_map": tuple((f"input_map.{k}", 0.2) for k in ("out_at_0_v", "knot1_out_v", "knot2_out_v", "out_at_10_v")),
}


#: Own-search parameters profiled with the constants re-fitted at each value, and the multiples tried.
#: A valve band's stall is partly mimicked by the constants calibrated before it was found (a softer
#: bladder, a smaller flow coefficient), and its own search on them then finds it about half as wide:
#: the profile looks wider only (docs/diagnosis.md, method step 6).
PROFILED: dict[str, tuple[str, tuple[float, ...]]] = {
    "valve_dead_zone": ("dead_zone.width_v", (1.4, 1.8, 2.4, 3.2)),
}


#: Further starts of an effect's joint re-fit (each a set of its parameters' values; the re-fit that
#: fits the training blocks best is kept). The calibration moves the flow coefficient, the bladder's
#: stiffness, threshold and braid first, and they take up much of an amplifier's map or a load's
#: weight: the effect's own fit on the calibrated constants then comes out near its off value, and a
#: joint step from there stays in the constants' valley. The map starts again from the identity (its
#: knots at 10/3 and 20/3 V, where a gain and an offset are two outputs away); the load from weights
#: either way (the field suite draws 5-16 N). A rate dependence is taken up by the friction's level:
#: calibrated without it, the base and per-MPa friction rise to the level the recording's typical speed
#: needs, and a rate gain re-fitted from its own fit on those constants stops short (a 0.88 gain re-fitted
#: to 0.21 on a sine); it starts again from gains either way of the paper-calibrated
#: 0.8 (the field suite draws 0.5-1.4). docs/diagnosis.md, step 5.
JOINT_STARTS: dict[str, tuple[dict[str, float], ...]] = {
    "input_map": ({k: v for k, v in PlantParams().dotted().items() if k.startswith("input_map.")},),
    "load_mismatch": tuple({"load_mismatch.extra_n": w} for w in (-12.0, -6.0, 6.0, 12.0)),
    "rate_dependent_hysteresis": tuple({"friction.rate_gain": g} for g in (0.6, 1.2)),
}


#: Effect parameters that are operating conditions the user states in the plant file (the supply
#: pressure): their "off" value is the nominal model's, which may differ from the default plant's (a
#: building at 0.3 MPa), so that switching the effect off gives back the plant file's rig.
OPERATING_CONDITIONS: tuple[str, ...] = ("supply.supply_pressure_mpa",)

#: Effect parameters whose "off" value is the nominal model's (the plant file's), not the default
#: plant's: the operating conditions, and the friction's rate dependence ``rate_gain``, which every
#: plant has (the default 0.8, calibrated to the paper's section 4.4; 0 in a model calibrated without
#: it, as the demos' ``DEMO_MODEL``). Switched "off", ``rate_dependent_hysteresis`` is the model's own
#: rate dependence: at 0 instead, the backward step and the discriminating experiment's plant took
#: the nominal 0.8 away, and the experiment then favoured the rate dependence whatever the truth.
#: Every other effect is off at its group's defaults (``fmu_plant/effect_library.py``).
OFF_AT_NOMINAL: tuple[str, ...] = OPERATING_CONDITIONS + ("friction.rate_gain",)

#: Further starts of the supply offset's joint re-fit, as factors of the nominal supply pressure [-].
#: The calibrated constants take up much of a supply error (a smaller flow coefficient and a softer
#: bladder mimic a lower pressure), and its own fit on them then stops near the nominal pressure; a
#: joint step from there stays in the constants' valley, as a load's does (buildings deliver 0.2-0.6
#: MPa, so a plant file's pressure may be 20 % or more off either way).
SUPPLY_STARTS: tuple[float, ...] = (0.8, 0.9, 1.1, 1.25)

#: Effects whose joint starts are also tried from the nominal constants
#: (:attr:`ModelSpace.starts_from_nominal`). A supply pressure trades with the flow coefficient, the
#: bladder's stiffness and the radius along a long valley: on a rig with the flow coefficient 10 % low
#: and a 0.22-MPa supply, the calibration put it at 1.03 (1.35 true) and the radius 8 % low, a joint
#: re-fit from there stopped at 0.244 MPa, and a load 3.7 N light was named instead; from the nominal
#: constants the re-fit reaches the rig (0.221 MPa, the flow coefficient 1.33, prior cost 1.8 sd^2
#: against 12).
STARTS_FROM_NOMINAL: frozenset[str] = frozenset({"supply_pressure_offset"})

#: The operating conditions' mismatches (:attr:`ModelSpace.exclusive`): a load off and a supply pressure
#: off both move the muscle's equilibrium under every command, and with the constants re-fitted the two
#: trade along a valley. Accepted together on field recordings they named a pair where the truth had
#: neither (seed 1 case 020, a rate dependence: both added, 99.64 -> 99.88 %) or one (seed 2 case 069).
EXCLUSIVE: tuple[frozenset[str], ...] = (frozenset({"load_mismatch", "supply_pressure_offset"}),)


def sensor_noise_mm(model: PlantParams) -> float:
    """The encoder noise the model states [mm]: white noise and 0.01 mm quantisation, sqrt(s^2 + q^2/12).

    Parameters
    ----------
    model : PlantParams
        The model (its encoder's noise std and resolution [mm]).
    """
    sp = model.sensor
    return math.sqrt(sp.encoder_noise_std_mm ** 2 + sp.encoder_resolution_mm ** 2 / 12.0)


class ModelSpace(ABC):
    """The model family's answers to the search (module docstring). Subclasses must pickle (the
    search sends them to worker processes)."""

    joint_parameters: Mapping[str, tuple[tuple[str, float], ...]] = {}
    profiled: Mapping[str, tuple[str, tuple[float, ...]]] = {}
    """Per effect, an own-search parameter that the calibrated constants bias, and the multiples of its
    fitted value at which it is profiled with the constants re-fitted jointly (as soon as the effect is accepted)."""
    joint_starts: Mapping[str, tuple[Mapping[str, float], ...]] = {}
    """Per effect, further starts of its joint re-fit (values of its parameters; the re-fit that fits
    the training blocks best is kept): for an effect whose own fit the calibrated constants hold near
    its off value. A start also makes the effect's joint parameters score-tested
    (:func:`~tapmuscle.diagnosis.score_test.score_gain`) on a model whose own parameters are at the start's."""
    starts_from_nominal: frozenset[str] = frozenset()
    """Effects whose joint starts are also tried with the calibrated constants back at their prior's
    centre (the nominal values): for an effect the calibration takes up along a long valley of the
    constants, which a short joint re-fit from the calibrated constants does not leave."""
    exclusive: tuple[frozenset[str], ...] = ()
    """Groups of effects of which a model holds one at most: explanations of the same mismatch whose
    parameters trade along a valley (accepted together they compensate each other and fit what neither
    is). Another of a group may be accepted on top of one (it may explain the data better); the
    backward step then keeps the one whose removal costs the training blocks most. They remain each
    other's alternatives where the data cannot tell them apart (an ``ambiguous`` verdict)."""
    combinations: bool = False
    """Calibrate with ``combinations=True`` (:func:`~tapmuscle.diagnosis.calibration.calibrate`): keep every
    constant's MAP estimate, for models whose constants the data pin only in combinations."""

    @abstractmethod
    def bounds(self, key: str) -> tuple[float, float]:
        """``(lo, hi)`` of parameter ``key``."""

    @abstractmethod
    def off_values(self, keys: Iterable[str]) -> dict[str, float]:
        """Each of ``keys`` (an effect's parameters) at its "off" value."""

    def sensor_noise(self, model: Any) -> float | None:
        """The output noise level the model states (None: unknown, the residual's own level is used)."""
        return None

    def first_reading(self, y: np.ndarray, y_hat: np.ndarray,
                      p_mpa: np.ndarray | None) -> tuple[str, dict[str, float]] | None:
        """The effect that the recording's first sample alone evidences, and its start values (None:
        none): the model's initial output is fixed whatever its constants, so no calibration explains
        a first reading away from it, and a calibration left to it bends the constants to take it up."""
        return None

    def starts_mid_run(self, y: np.ndarray, p_mpa: np.ndarray | None) -> bool:
        """Whether the recording starts where the model's initial state cannot be (a run already under
        way): its start-up transient is then no parameter's to explain, and the search leaves the first
        block out of the training blocks."""
        return False


class MuscleSpace(ModelSpace):
    """The tapmuscle plant: :class:`~fmu_plant.PlantParams`, its fields' bounds, its effect library.

    Parameters
    ----------
    nominal : PlantParams, optional
        The nominal model the diagnosis compares with (the user's plant file). Its values of
        :data:`OFF_AT_NOMINAL` (the supply pressure [MPa], the friction's rate gain [-]) are their
        effects' "off" values, and the supply offset's joint starts are taken around its supply
        pressure. Default: the default plant's.
    own_joint : mapping of str to tuple of (str, float), optional
        Candidates of one's own whose parameters are re-fitted jointly with the constants (their
        :attr:`~tapmuscle.diagnosis.candidates.Candidate.joint`), beside :data:`JOINT_PARAMETERS`.
    """

    joint_parameters = JOINT_PARAMETERS
    profiled = PROFILED
    starts_from_nominal = STARTS_FROM_NOMINAL
    exclusive = EXCLUSIVE

    def __init__(self, nominal: PlantParams | None = None, *,
                 own_joint: Mapping[str, tuple[tuple[str, float], ...]] | None = None) -> None:
        self.nominal = nominal
        if own_joint:
            self.joint_parameters = {**JOINT_PARAMETERS, **own_joint}
        ps = (PlantParams() if nominal is None else nominal).supply.supply_pressure_mpa
        self.joint_starts = JOINT_STARTS | {
            "supply_pressure_offset": tuple({"supply.supply_pressure_mpa": ps * k} for k in SUPPLY_STARTS)}

    def bounds(self, key: str) -> tuple[float, float]:
        return PlantParams.bounds(key)

    def off_values(self, keys: Iterable[str]) -> dict[str, float]:
        defaults = PlantParams().dotted()
        nominal = defaults if self.nominal is None else self.nominal.dotted()
        return {k: nominal[k] if k in OFF_AT_NOMINAL else defaults[k] for k in keys}

    def sensor_noise(self, model: PlantParams) -> float:
        return sensor_noise_mm(model)

    def first_reading(self, y: np.ndarray, y_hat: np.ndarray,
                      p_mpa: np.ndarray | None) -> tuple[str, dict[str, float]] | None:
        """An encoder zeroed elsewhere: the plant starts drained at rest (``l = 0``) whatever its
        constants, and a first reading more than :data:`~tapmuscle.diagnosis.recording_checks.AT_REST_MM`
        away from it, with the recorded pressure (if any) that of a drained muscle, is the encoder's
        offset [mm], clipped to its bounds. A first pressure above a drained muscle's is a recording
        started mid-run instead: no offset (its start-up transient is no constant's either)."""
        e0 = float(y[0] - y_hat[0])
        if abs(e0) <= AT_REST_MM or (p_mpa is not None and float(p_mpa[0]) > DRAINED_MPA):
            return None
        lo, hi = self.bounds("sensor_drift.offset_mm")
        return "sensor_drift", {"sensor_drift.offset_mm": min(max(e0, lo), hi)}

    def starts_mid_run(self, y: np.ndarray, p_mpa: np.ndarray | None) -> bool:
        """A first recorded pressure above a drained muscle's
        (:data:`~tapmuscle.diagnosis.recording_checks.DRAINED_MPA`): the model starts drained. Without
        a pressure column a mid-run start cannot be told from an encoder offset
        (:meth:`first_reading`)."""
        return p_mpa is not None and float(p_mpa[0]) > DRAINED_MPA


#: The tapmuscle plant's model space.
MUSCLE = MuscleSpace()
