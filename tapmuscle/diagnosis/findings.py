"""What :func:`tapmuscle.diagnosis.diagnose` returns: the verdict, its findings and alternatives.

Plain data with ``to_json`` (the ``diagnosis.json`` document, docs/diagnosis.md "Outputs"); the
procedure that fills them is :mod:`tapmuscle.diagnosis.diagnose`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fmu_plant import PlantParams
from tapmuscle.diagnosis.calibration import Calibration
from tapmuscle.diagnosis.residual_analysis import Correlation

__all__ = ["Finding", "Alternative", "Diagnosis", "VERDICTS", "output_unit"]

#: What ``diagnose`` can conclude.
VERDICTS = ("no_significant_mismatch", "calibration_only", "mismatch", "ambiguous")


@dataclass
class Finding:
    """One entry of ``diagnosis.json``'s ``findings``."""

    effect: str
    """Candidate name, or ``"unexplained"``."""
    explanation: str
    """What was found, in plain words."""
    parameters: dict[str, float]
    """Fitted plant parameters (``group.field``: value, as the plant FMU names them)."""
    fit_gain_points: float
    """Held-out fit gained by adding this effect [percentage points], on all the held-out blocks; the
    acceptance (``evidence``) is judged on the blocks its significance test uses, which can leave some
    out, so the two can disagree in sign for an effect that acts in a short window."""
    located: list[tuple[float, float]]
    """Time windows [s] where it acts."""
    regime: str
    """Where in the operating range its contribution concentrates, in words
    (:func:`~tapmuscle.diagnosis.residual_analysis.regime_summary`)."""
    evidence: dict[str, Any] = field(default_factory=dict)
    """Numbers behind the acceptance (held-out SSE before/after, z-test p-value, ...)."""
    ci95: dict[str, tuple[float, float]] = field(default_factory=dict)
    """95 % intervals of the parameters re-fitted jointly with the calibrated constants (same units as
    ``parameters``; from the final joint fit's covariance, clipped to the parameter's bounds). A
    parameter only its candidate's own search fits (a band's edges, a sag's window, a map's knot
    inputs) has none: its cost is piecewise constant."""

    def to_json(self) -> dict[str, Any]:
        return {"effect": self.effect, "explanation": self.explanation, "parameters": self.parameters,
                "fit_gain_points": round(self.fit_gain_points, 3),
                "located": [{"t_start_s": round(a, 2), "t_end_s": round(b, 2)} for a, b in self.located],
                "regime": self.regime, "evidence": self.evidence,
                "ci95": {k: [float(lo), float(hi)] for k, (lo, hi) in self.ci95.items()}}


@dataclass
class Alternative:
    """One explanation of an ``ambiguous`` group: an effect re-fitted jointly with the calibration."""

    effect: str
    """Candidate name."""
    explanation: str
    """What it would be, in plain words."""
    parameters: dict[str, float]
    """Fitted plant parameters (``group.field``: value)."""
    params: PlantParams = field(repr=False)
    """The whole alternative plant (calibrated constants, accepted effects, this effect)."""
    y_hat: np.ndarray = field(repr=False)
    """Its noise-free prediction of the whole recording [mm]."""
    held_out_sse_mm2: float = 0.0
    """Squared error of that prediction on the held-out samples [mm^2]."""
    fit_after_percent: float = 0.0
    """Held-out fit of that prediction [%]."""
    evidence: dict[str, Any] = field(default_factory=dict)
    """Numbers behind its acceptance (held-out tests against the model without it)."""
    q_hat: np.ndarray | None = field(default=None, repr=False)
    """Its pressure prediction [MPa] when the held-out evidence uses the pressure, else None."""

    def to_json(self) -> dict[str, Any]:
        return {"effect": self.effect, "explanation": self.explanation, "parameters": self.parameters,
                "held_out_sse_mm2": round(self.held_out_sse_mm2, 6),
                "fit_after_percent": round(self.fit_after_percent, 3), "evidence": self.evidence}


def output_unit(output: tuple[str, str] | None) -> str:
    """The unit of the output ``(name, unit)`` a diagnosis is of (None: the muscle's displacement, mm).

    Parameters
    ----------
    output : (str, str) or None
        ``(name, unit)`` of a foreign model's output; None: the muscle's displacement.
    """
    return "mm" if output is None else output[1] or "-"


@dataclass
class Diagnosis:
    """Everything ``diagnose`` found (``to_json`` is ``diagnosis.json``)."""

    verdict: str
    """One of :data:`VERDICTS`: ``no_significant_mismatch``, ``calibration_only``, ``mismatch``,
    ``ambiguous``."""
    fit_before_percent: float
    """Held-out NRMSE fit of the nominal model [%]."""
    fit_after_percent: float
    """Held-out fit of the final model (calibration and accepted effects) [%]."""
    findings: list[Finding]
    """The effects named, ordered by evidence, and ``unexplained`` for a remaining structured residual."""
    calibrated: PlantParams = field(repr=False)
    """The model with the calibrated constants and the accepted effects' parameters (for an
    ``ambiguous`` verdict: with the best-scoring alternative)."""
    t_s: np.ndarray = field(repr=False)
    """The recording's time [s]."""
    u_v: np.ndarray = field(repr=False)
    """The recording's command [V]."""
    y_mm: np.ndarray = field(repr=False)
    """The recording's displacement [mm]."""
    y_before_mm: np.ndarray = field(repr=False)
    """The nominal model's re-simulation [mm]."""
    y_after_mm: np.ndarray = field(repr=False)
    """The final model's re-simulation [mm]."""
    train: np.ndarray = field(repr=False)
    """Indices of the training blocks."""
    test: np.ndarray = field(repr=False)
    """Indices of the held-out blocks."""
    tests_before: dict[str, Any] = field(repr=False)
    """Residual tests of the nominal model (whiteness, RMS, noise level, ``structured``)."""
    tests_after: dict[str, Any] = field(repr=False)
    """Residual tests of the final model."""
    correlations: dict[str, Correlation] = field(repr=False)
    """Autocorrelation and input cross-correlation of the residual, before and after."""
    candidates: list[dict[str, Any]] = field(repr=False)
    """Every candidate tried, per round: name, held-out gain, SSE reduction, significance."""
    simulations: int
    """Plant simulations the diagnosis ran."""
    elapsed_s: float
    """Wall time [s]."""
    calibration: Calibration | None = None
    """The final calibration (re-fitted jointly with the accepted effects); None when not run."""
    fit_calibrated_percent: float | None = None
    """Held-out fit of the calibrated plant without any effect [%]."""
    y_calibrated_mm: np.ndarray | None = field(default=None, repr=False)
    """The calibrated plant's re-simulation without effects [mm]; None without calibration."""
    ambiguous: list[list[Alternative]] = field(default_factory=list)
    """Groups of statistically indistinguishable explanations."""
    selection: list[dict[str, Any]] = field(default_factory=list, repr=False)
    """The forward and backward steps taken, in order."""
    nominal: PlantParams | None = field(default=None, repr=False)
    """The nominal model the diagnosis started from."""
    load_n: np.ndarray | None = field(default=None, repr=False)
    """The recorded load [N], if the recording had one."""
    ts_s: float = 0.0
    """Sampling period [s]."""
    unexplained: dict[str, Any] | None = None
    """The structured residual the final model leaves (None if white): ``share`` of the initial
    excess, ``rms_mm``, ``noise_mm``, ``material`` (RMS >= :data:`~tapmuscle.diagnosis.diagnose.MATERIAL_FACTOR` x noise: then it
    is also an ``unexplained`` finding)."""
    pressure_noise_mpa: float | None = None
    """White-noise level of the pressure residual [MPa] when the held-out evidence weighs the
    recorded pressure beside the displacement (:mod:`tapmuscle.diagnosis.held_out`); None: the
    displacement alone."""
    block_s: float | None = None
    """Length of the interleaved training / held-out blocks [s]."""
    start_left_out_s: float = 0.0
    """Seconds at the recording's start left out of the training blocks (the first block of a
    recording that starts mid-run: :meth:`~tapmuscle.diagnosis.model_space.ModelSpace.starts_mid_run`);
    0: none. ``diagnosis.json``'s ``split.start_left_out_s`` when not 0."""
    left_out_samples: int = 0
    """Samples left out of every fit and held-out test (``diagnose(left_out=...)``: samples the import
    put back); ``split.left_out_samples`` when not 0."""
    output: tuple[str, str] | None = None
    """``(name, unit)`` of another model's measured output, which the ``*_mm`` fields then hold in its
    unit; None: the muscle's displacement [mm]."""
    notes: list[str] = field(default_factory=list)
    """What the reader should know before the findings: about the recording (a start away from rest,
    jittered timestamps, a pressure in another unit) and a calibration not kept."""
    calibration_skipped: str = "off"
    """Why :attr:`calibration` is None (``diagnosis.json``'s ``calibration.skipped``): it was off, the
    residual was white or within the noise, or the calibrated model was not kept."""

    @property
    def unit(self) -> str:
        """The unit of the output diagnosed (and of every ``*_mm`` field)."""
        return output_unit(self.output)

    @property
    def named(self) -> list[str]:
        """Effects claimed (findings other than ``unexplained``)."""
        return [f.effect for f in self.findings if f.effect != "unexplained"]

    def to_json(self) -> dict[str, Any]:
        cal = None
        if self.calibration is not None:
            cal = self.calibration.to_json() | {
                "fit_calibrated_percent": None if self.fit_calibrated_percent is None
                else round(self.fit_calibrated_percent, 3)}
        return {"verdict": self.verdict, "fit_before_percent": round(self.fit_before_percent, 3),
                "fit_after_percent": round(self.fit_after_percent, 3),
                "findings": [f.to_json() for f in self.findings],
                "unexplained": self.unexplained,
                "calibration": cal if cal is not None else {"skipped": self.calibration_skipped},
                "notes": list(self.notes),
                "ambiguous": [{"alternatives": [a.to_json() for a in group], "discriminating_input": None,
                               "discriminate_plant": None}
                              for group in self.ambiguous],
                "selection": self.selection,
                "residual_tests": {"before": self.tests_before, "after": self.tests_after},
                "candidates_tried": self.candidates,
                "split": {"method": "interleaved blocks", "train_samples": int(self.train.sum()),
                          "held_out_samples": int(self.test.sum()), "block_s": self.block_s}
                         | ({"start_left_out_s": self.start_left_out_s} if self.start_left_out_s else {})
                         | ({"left_out_samples": self.left_out_samples} if self.left_out_samples else {}),
                "evidence": {"channels": ["l_mm"] + (["p_mpa"] if self.pressure_noise_mpa is not None else []),
                             "pressure_noise_mpa": self.pressure_noise_mpa},
                "simulations": self.simulations, "elapsed_s": round(self.elapsed_s, 2)}
