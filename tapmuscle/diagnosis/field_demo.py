"""The proof at scale: "field recordings" of rigs whose constants are off, diagnosed from the CSV alone.

``tapmuscle demo-mismatch`` (the default suite ``field``) runs :func:`run_field_demo`. Each recording
comes from a *truth rig*: the nominal model handed to the diagnosis, with

* 3-6 of its physical constants (:data:`FIELD_ERROR_PARAMETERS`) off by 5-20 %, either sign (every
  real rig differs from its simulator by that much);
* and, by the case's category (:data:`CATEGORY_MIX`): nothing more (``none``), one effect of the
  vocabulary (``single``), two different, physically compatible effects (``pair``), or one
  disturbance outside the vocabulary (``oov``, :data:`OOV_KINDS`).

The recording is open loop (``sine``, ``sinesum``, ``steps``, ``random`` inputs) or closed loop
(``ampc``: the AMPC-servo controller tracking a sine; the direct loop of
:func:`tapmuscle.closed_loop.run_closed_loop` is bit-identical to the AMPC FMU driving the plant
FMU, docs/fmu.md), 180 s at Ts = 0.1 s with the encoder's noise and quantisation on. The CSV and the
nominal model's plant file go to :func:`tapmuscle.diagnosis.report.diagnose_files`, nothing else; the verdict
is scored against the truth (:func:`score_results`). When the verdict is ``ambiguous`` and the
diagnosis wrote ``discriminating_input.csv``, the same truth rig is recorded again with that input
(fresh noise) and re-diagnosed among the alternatives: does it pick the right one?

Every draw is seeded (``numpy.random.default_rng([seed, ...])``), so ``field_cases(n, seed)`` is the
same list on every machine. The magnitudes of the effects span levels 1-2 of the concealed-effect
demo (:data:`tapmuscle.diagnosis.demo.MAGNITUDES`), where an effect is visible above the noise; each case's
*cost* (how much held-out fit the noise-free truth loses without that effect) tells the visible
cases (cost >= :data:`VISIBLE_POINTS`) from those that leave nothing to find.
"""

from __future__ import annotations

import json
import math
import os
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from fmu_plant import Plant, PlantParams
from fmu_plant.effects import Effect
from fmu_plant.open_loop import run_open_loop
from tapmuscle.io.plant_file import plant_file_text
from tapmuscle.io.recording import Recording, atomic_write_text, read_recording, write_recording

from tapmuscle.diagnosis.candidates import CANDIDATES
from tapmuscle.diagnosis.demo import DEMO_MODEL, MAGNITUDES
from tapmuscle.diagnosis.residual_analysis import fit_percent, interleaved_split
from tapmuscle.diagnosis.simulation import noise_free

__all__ = ["FIELD_ERROR_PARAMETERS", "CATEGORY_MIX", "CATEGORIES", "EXCITATIONS", "OOV_KINDS", "LOADS_N",
           "EFFECT_RANGES", "INCOMPATIBLE_PAIRS", "TARGETS", "FIT_AFTER_PERCENT", "VISIBLE_POINTS",
           "DURATION_S", "TS_S", "FieldCase", "vocabulary", "compatible_pairs", "field_cases",
           "record_case", "run_field_case", "run_field_demo", "score_results", "scores_markdown",
           "confusion_figure"]

# ------------------------------------------------------------------------------------- settings
#: Physical constants of the rig that a field rig has off (not the operating conditions load and
#: supply pressure, whose mismatches are effects of the vocabulary, nor the effect groups).
FIELD_ERROR_PARAMETERS: tuple[str, ...] = (
    "valve.cv_max", "valve.leak_fraction", "supply.compliance_m3_per_mpa",
    "muscle.rubber_stiffness_n_per_mm", "muscle.threshold_pressure_mpa", "muscle.braid_angle_deg",
    "muscle.radius_mm", "muscle.damping_n_s_per_mm",
    "friction.base_n", "friction.per_mpa_n", "friction.asymmetry", "friction.presliding_mm",
)
#: How many constants each truth has off (inclusive range).
ERRORS_PER_CASE = (3, 6)
#: Relative error of each such constant: uniform in this range [-], sign random. A value beyond the
#: field's bounds (only ``valve.cv_max``: its datasheet rating 1.6 is +6.7 % over the nominal 1.5) is
#: clipped to the bound, so that error is smaller than drawn; the case records the error it has.
ERROR_REL_RANGE = (0.05, 0.20)

#: Share of each category in a suite (largest-remainder rounding: 30/42/30/18 of 120 recordings).
CATEGORY_MIX: tuple[tuple[str, float], ...] = (("none", 0.25), ("single", 0.35), ("pair", 0.25), ("oov", 0.15))
CATEGORIES = tuple(c for c, _ in CATEGORY_MIX)

#: Excitations: four open-loop inputs and the closed loop (AMPC-servo tracking a sine).
EXCITATIONS = ("sine", "sinesum", "steps", "random", "ampc")
#: Nominal hanging loads [N] (the paper's two); the recording's ``load_n`` column says which.
LOADS_N = (44.0, 68.0)

#: Disturbances outside the vocabulary (not candidates of the diagnosis), applied by the generator:
#: ``vibration``: a mechanical vibration of the encoder's slider (a pump or fan on the frame),
#: ``l_seen = l + A sin(2 pi f t + phi)``, A 0.3-1.5 mm, f 0.4-1.5 Hz;
#: ``end_stop``: the encoder's slider runs into a stop 5-15 mm below the run's peak (after its first
#: 10 %, which holds the closed loop's start-up overshoot), so the reading saturates there while the
#: muscle moves on (in the closed loop the controller sees the saturated reading);
#: ``varying_load``: a load that changes and is not recorded (the ``load_n`` column keeps the nominal):
#: either a swinging or pumped extra load ``dW sin(2 pi f t + phi)``, dW 3-8 N, f 0.01-0.04 Hz, or a
#: weight of 3-8 N hung on for 20-60 s in mid-run.
OOV_KINDS = ("vibration", "end_stop", "varying_load")

#: Ranges [low, high] of each effect's main magnitude: levels 1-2 of the concealed-effect demo (there
#: the effect is visible above the noise), drawn uniformly; sign random where both are physical.
#: ``input_map`` (not in that demo): the width of a dead band [V], or ``1 - gain`` of an amplifier
#: gain error [-] (half the cases each).
EFFECT_RANGES: dict[str, tuple[float, float]] = {
    **{name: (levels[1][0], levels[2][1]) for name, levels in MAGNITUDES.items()},
    "input_map": (0.6, 1.5),
}
#: Gain error range of the ``input_map`` amplifier-gain form [-].
INPUT_MAP_GAIN = (0.8, 0.9)

#: Pairs never drawn together: a valve dead zone and an input map's dead band are two models of the
#: one band in the valve's static characteristic (a rig has one spool and one amplifier), and together
#: they would make a band no single effect describes.
INCOMPATIBLE_PAIRS: frozenset[frozenset[str]] = frozenset({frozenset({"valve_dead_zone", "input_map"})})

#: An effect (or disturbance) that costs the noise-free truth less held-out fit than this [points]
#: leaves nothing above the noise to find; such cases are scored, and scored apart as well.
VISIBLE_POINTS = 0.3
#: Held-out NRMSE fit [%] the diagnosed model must reach where every effect is in the vocabulary.
FIT_AFTER_PERCENT = 95.0
#: Target rates [%] of the proof (the requirement, for at least 100 recordings).
TARGETS: dict[str, float] = {
    "none_no_effect_claimed": 90.0,
    "single_named": 90.0,
    "single_named_alone": 80.0,
    "pair_both_found": 75.0,
    "oov_unexplained": 80.0,
    "fit_after_at_least_95": 100.0,
}

DURATION_S = 180.0
TS_S = 0.1
#: The discriminating experiment's folder inside a case's folder.
DISCRIMINATE_DIR = "discriminate"
#: A finished case's result in its folder (what ``resume`` reuses).
RESULT_FILE = "result.json"
#: What a case's folder keeps (the recording CSVs are deleted unless ``keep``).
KEPT_FILES = ("diagnosis.json", "report.md")


# ------------------------------------------------------------------------------------- the cases
@dataclass(frozen=True)
class FieldCase:
    """One field recording to make and diagnose (all draws made, :func:`field_cases`)."""

    index: int
    seed: int
    """Seed of the suite the case belongs to."""
    category: str
    """``none``, ``single``, ``pair`` or ``oov``."""
    effects: tuple[str, ...]
    """Vocabulary effects of the truth (0, 1 or 2)."""
    effect_values: tuple[tuple[str, float], ...]
    """Plant parameters (``group.field``, value) that switch those effects on."""
    parameter_errors: tuple[tuple[str, float], ...]
    """Constants off in the truth: (``group.field``, relative error [-]) after clipping to bounds."""
    load_n: float
    """Nominal hanging load [N] (the recording's ``load_n`` column)."""
    excitation: str
    excitation_params: tuple[tuple[str, float], ...]
    noise_seed: int
    """Seed of the plant's sensor noise."""
    duration_s: float = DURATION_S
    oov: str | None = None
    """Out-of-vocabulary disturbance (one of :data:`OOV_KINDS`), or None."""
    oov_params: tuple[tuple[str, float], ...] = ()

    @property
    def name(self) -> str:
        what = {"none": "", "single": "".join(self.effects), "pair": "+".join(self.effects),
                "oov": str(self.oov)}[self.category]
        return "_".join(p for p in (f"{self.index:03d}", self.category, what, self.excitation) if p)

    def model(self) -> PlantParams:
        """The nominal model handed to the diagnosis: the demo's model (no rate dependence) at the load."""
        return DEMO_MODEL.with_values(**{"load.load_n": self.load_n})

    def truth(self) -> PlantParams:
        """The truth rig's parameters: the model with the constants off and the effects on (not the
        out-of-vocabulary disturbance, see :meth:`disturbances`)."""
        return self.model().with_values(**self.true_constants(), **dict(self.effect_values))

    def true_constants(self) -> dict[str, float]:
        """The truth's values of the constants that are off (``group.field`` -> value)."""
        model = self.model()
        return {key: _value(model, key) * (1.0 + rel) for key, rel in self.parameter_errors}

    def input_spec(self) -> str | None:
        """The ``tapmuscle record --input`` spec of an open-loop excitation (None: sinesum, ampc)."""
        p = dict(self.excitation_params)
        if self.excitation == "sine":
            return f"sine:bias={p['offset_v']:.6g},amp={p['amplitude_v']:.6g},freq={p['frequency_hz']:.6g}"
        if self.excitation in ("steps", "random"):
            return (f"random:lo={p['lo_v']:g},hi={p['hi_v']:g},hold_min={p['hold_min_s']:g},"
                    f"hold_max={p['hold_max_s']:g},seed={int(p['seed'])}")
        return None

    def describe(self) -> dict[str, Any]:
        """The truth as plain data (for ``scores.json``)."""
        return {"case": self.name, "index": self.index, "seed": self.seed, "category": self.category,
                "effects": list(self.effects), "effect_values": dict(self.effect_values),
                "parameter_errors": dict(self.parameter_errors), "true_constants": self.true_constants(),
                "load_n": self.load_n, "excitation": self.excitation,
                "excitation_params": dict(self.excitation_params), "input_spec": self.input_spec(),
                "noise_seed": self.noise_seed, "duration_s": self.duration_s, "oov": self.oov,
                "oov_params": dict(self.oov_params)}


def _value(params: PlantParams, key: str) -> float:
    group, _, name = key.partition(".")
    return float(getattr(getattr(params, group), name))


def _bounds(key: str) -> tuple[float, float]:
    """A plant parameter's bounds from its field metadata (open lower bounds as closed: values drawn
    here are never at them)."""
    group, _, name = key.partition(".")
    for f in fields(getattr(PlantParams(), group)):
        if f.name == name:
            return float(f.metadata.get("lo", -math.inf)), float(f.metadata.get("hi", math.inf))
    raise ValueError(f"unknown plant parameter {key!r}")


def vocabulary() -> tuple[str, ...]:
    """The effects a truth may have: the diagnosis' candidates, and ``input_map`` once the plant has
    its parameter group (it may come before its candidate). Candidates this generator cannot draw
    are left out (``tests/test_field_demo.py`` checks there are none)."""
    names = [c.name for c in CANDIDATES]
    if "input_map" not in names and "input_map" in {f.name for f in fields(PlantParams)}:
        names.append("input_map")
    return tuple(n for n in names if n in _DRAWERS)


def compatible_pairs(vocab: Sequence[str] | None = None) -> list[tuple[str, str]]:
    """Every unordered pair of different vocabulary effects that may act together."""
    vocab = tuple(vocab if vocab is not None else vocabulary())
    return [(a, b) for i, a in enumerate(vocab) for b in vocab[i + 1:]
            if frozenset({a, b}) not in INCOMPATIBLE_PAIRS]


def _category_counts(n: int) -> dict[str, int]:
    """Cases per category for ``n`` recordings: :data:`CATEGORY_MIX`, largest remainders rounded up."""
    exact = {c: n * share for c, share in CATEGORY_MIX}
    counts = {c: int(math.floor(v)) for c, v in exact.items()}
    for c in sorted(exact, key=lambda c: exact[c] - counts[c], reverse=True)[:n - sum(counts.values())]:
        counts[c] += 1
    return counts


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def _draw_rate(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    return {"friction.rate_gain": float(rng.uniform(*EFFECT_RANGES["rate_dependent_hysteresis"]))}


def _draw_dead_zone(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    return {"dead_zone.center_v": float(rng.uniform(3.5, 6.5)),
            "dead_zone.width_v": float(rng.uniform(*EFFECT_RANGES["valve_dead_zone"]))}


def _draw_delay(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    return {"delay.delay_s": float(rng.uniform(*EFFECT_RANGES["transport_delay"]))}


def _draw_sag(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    # a sag of 12-25 % of the run starting in its middle part: inside the run, with data on both sides
    start = float(rng.uniform(0.15, 0.55)) * duration_s
    end = start + float(rng.uniform(0.12, 0.25)) * duration_s
    return {"supply_variation.sag_mpa": float(rng.uniform(*EFFECT_RANGES["supply_pressure_variation"])),
            "supply_variation.start_s": start, "supply_variation.end_s": end}


def _draw_load(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    return {"load_mismatch.extra_n": _sign(rng) * float(rng.uniform(*EFFECT_RANGES["load_mismatch"]))}


def _draw_drift(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    lo, hi = EFFECT_RANGES["sensor_drift"]
    return {"sensor_drift.offset_mm": _sign(rng) * float(rng.uniform(lo, hi)),
            "sensor_drift.rate_mm_per_min": _sign(rng) * float(rng.uniform(lo, hi))}


def _draw_backlash(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    return {"backlash.slack_mm": float(rng.uniform(*EFFECT_RANGES["backlash"]))}


def _draw_input_map(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    if rng.random() < 0.5:
        # a dead band: every command inside it gives the centre's opening, slope 1 outside
        c, w = float(rng.uniform(3.5, 6.5)), float(rng.uniform(*EFFECT_RANGES["input_map"]))
        return {"input_map.out_at_0_v": w / 2, "input_map.knot1_in_v": c - w / 2, "input_map.knot1_out_v": c,
                "input_map.knot2_in_v": c + w / 2, "input_map.knot2_out_v": c, "input_map.out_at_10_v": 10.0 - w / 2}
    # an amplifier gain error with an offset: map(u) = g u + o, o in 0..10 (1 - g) so 0..10 V maps into 0..10 V
    g = float(rng.uniform(*INPUT_MAP_GAIN))
    o = float(rng.uniform(0.1, 0.9)) * 10.0 * (1.0 - g)
    k1, k2 = 10.0 / 3.0, 20.0 / 3.0
    return {"input_map.out_at_0_v": o, "input_map.knot1_in_v": k1, "input_map.knot1_out_v": g * k1 + o,
            "input_map.knot2_in_v": k2, "input_map.knot2_out_v": g * k2 + o, "input_map.out_at_10_v": 10.0 * g + o}


_DRAWERS: dict[str, Callable[[np.random.Generator, float], dict[str, float]]] = {
    "rate_dependent_hysteresis": _draw_rate, "valve_dead_zone": _draw_dead_zone, "transport_delay": _draw_delay,
    "supply_pressure_variation": _draw_sag, "load_mismatch": _draw_load, "sensor_drift": _draw_drift,
    "backlash": _draw_backlash, "input_map": _draw_input_map,
}


def _draw_errors(rng: np.random.Generator, model: PlantParams) -> tuple[tuple[str, float], ...]:
    k = int(rng.integers(ERRORS_PER_CASE[0], ERRORS_PER_CASE[1] + 1))
    keys = rng.choice(len(FIELD_ERROR_PARAMETERS), size=k, replace=False)
    out = []
    for i in sorted(int(j) for j in keys):
        key = FIELD_ERROR_PARAMETERS[i]
        rel = _sign(rng) * float(rng.uniform(*ERROR_REL_RANGE))
        nominal = _value(model, key)
        lo, hi = _bounds(key)
        value = min(max(nominal * (1.0 + rel), lo), hi)
        out.append((key, value / nominal - 1.0))
    return tuple(out)


def _draw_excitation(kind: str, rng: np.random.Generator) -> tuple[tuple[str, float], ...]:
    if kind == "sine":
        return (("offset_v", float(rng.uniform(4.0, 6.0))), ("amplitude_v", float(rng.uniform(2.0, 4.0))),
                ("frequency_hz", float(rng.uniform(0.05, 0.2))))
    if kind == "sinesum":
        k = int(rng.integers(2, 4))
        # the total amplitude 2-4 V split at random, so offset +- total stays within 0..10 V
        amps = float(rng.uniform(2.0, 4.0)) * rng.dirichlet(np.ones(k))
        freqs = np.exp(rng.uniform(math.log(0.02), math.log(0.3), size=k))
        phases = rng.uniform(0.0, 2.0 * math.pi, size=k)
        out = [("offset_v", float(rng.uniform(4.0, 6.0)))]
        for i in range(k):
            out += [(f"amplitude{i}_v", float(amps[i])), (f"frequency{i}_hz", float(freqs[i])),
                    (f"phase{i}_rad", float(phases[i]))]
        return tuple(out)
    if kind == "steps":
        return (("lo_v", 2.0), ("hi_v", 8.0), ("hold_min_s", 2.0), ("hold_max_s", 6.0),
                ("seed", float(rng.integers(0, 2 ** 31))))
    if kind == "random":
        return (("lo_v", 1.0), ("hi_v", 9.0), ("hold_min_s", 0.3), ("hold_max_s", 1.5),
                ("seed", float(rng.integers(0, 2 ** 31))))
    if kind == "ampc":
        return (("offset_mm", 35.0), ("amplitude_mm", float(rng.uniform(20.0, 30.0))),
                ("frequency_hz", float(rng.uniform(0.05, 0.15))))
    raise ValueError(f"unknown excitation {kind!r}; known: {', '.join(EXCITATIONS)}")


def _draw_oov(kind: str, rng: np.random.Generator, duration_s: float) -> tuple[tuple[str, float], ...]:
    if kind == "vibration":
        return (("amplitude_mm", float(rng.uniform(0.3, 1.5))), ("frequency_hz", float(rng.uniform(0.4, 1.5))),
                ("phase_rad", float(rng.uniform(0.0, 2.0 * math.pi))))
    if kind == "end_stop":
        return (("below_peak_mm", float(rng.uniform(5.0, 15.0))),)
    if kind == "varying_load":
        if rng.random() < 0.5:
            return (("form", 0.0), ("extra_n", float(rng.uniform(3.0, 8.0))),
                    ("frequency_hz", float(rng.uniform(0.01, 0.04))), ("phase_rad", float(rng.uniform(0, 2 * math.pi))))
        on = float(rng.uniform(0.2, 0.5)) * duration_s
        return (("form", 1.0), ("extra_n", float(rng.uniform(3.0, 8.0))), ("on_s", on),
                ("off_s", min(on + float(rng.uniform(20.0, 60.0)), 0.9 * duration_s)))
    raise ValueError(f"unknown out-of-vocabulary disturbance {kind!r}; known: {', '.join(OOV_KINDS)}")


def field_cases(n: int = 120, seed: int = 0, *, duration_s: float = DURATION_S) -> list[FieldCase]:
    """The suite's ``n`` cases, drawn reproducibly from ``seed``.

    The plan (``default_rng([seed])``) fixes each case's category (:data:`CATEGORY_MIX`, exact
    counts), its effects (the single effects and the compatible pairs each taken in a shuffled order
    and cycled, so every effect and pair appears as often as the count allows), its disturbance and
    its excitation (cycled within each category). Everything else is drawn per case from
    ``default_rng([seed, index])``: the constants off and their errors, the load, the magnitudes and
    places of the effects, the excitation's parameters, the noise seed.

    Parameters
    ----------
    n : int
        Number of recordings (>= 1).
    seed : int
        Seed of the suite (>= 0).
    duration_s : float
        Length of every recording [s] (the diagnosis needs >= 30 s at Ts = 0.1 s).
    """
    if n < 1 or seed < 0:
        raise ValueError(f"need n >= 1 and seed >= 0, got n={n!r}, seed={seed!r}")
    plan = np.random.default_rng([seed])
    counts = _category_counts(n)
    categories = [c for c in CATEGORIES for _ in range(counts[c])]
    categories = [categories[i] for i in plan.permutation(n)]
    vocab = vocabulary()
    singles = [vocab[i] for i in plan.permutation(len(vocab))]
    pairs_all = compatible_pairs(vocab)
    pairs = [pairs_all[i] for i in plan.permutation(len(pairs_all))]
    oovs = [OOV_KINDS[i] for i in plan.permutation(len(OOV_KINDS))]
    exc_offset = {c: int(plan.integers(0, len(EXCITATIONS))) for c in CATEGORIES}
    seen = {c: 0 for c in CATEGORIES}
    cases = []
    for index, category in enumerate(categories):
        j = seen[category]
        seen[category] += 1
        rng = np.random.default_rng([seed, index])
        model = DEMO_MODEL
        errors = _draw_errors(rng, model)
        load = float(LOADS_N[int(rng.integers(0, len(LOADS_N)))])
        excitation = EXCITATIONS[(j + exc_offset[category]) % len(EXCITATIONS)]
        exc_params = _draw_excitation(excitation, rng)
        effects: tuple[str, ...] = ()
        if category == "single":
            effects = (singles[j % len(singles)],)
        elif category == "pair":
            effects = pairs[j % len(pairs)]
        values: dict[str, float] = {}
        for e in effects:
            values.update(_DRAWERS[e](rng, duration_s))
        oov, oov_params = None, ()
        if category == "oov":
            oov = oovs[j % len(oovs)]
            oov_params = _draw_oov(oov, rng, duration_s)
        cases.append(FieldCase(index=index, seed=seed, category=category, effects=effects,
                               effect_values=tuple(values.items()), parameter_errors=errors, load_n=load,
                               excitation=excitation, excitation_params=exc_params,
                               noise_seed=int(rng.integers(0, 2 ** 31)), duration_s=duration_s,
                               oov=oov, oov_params=oov_params))
    return cases


# ------------------------------------------------------------------------ out-of-vocabulary physics
class _Vibration(Effect):
    """The encoder's slider vibrates with the frame: ``l_seen = l + A sin(2 pi f t + phi)``."""

    name = "vibration"

    def __init__(self, amplitude_mm: float, frequency_hz: float, phase_rad: float) -> None:
        self.a, self.w, self.phi = amplitude_mm, 2.0 * math.pi * frequency_hz, phase_rad

    def measurement(self, t_s: float, l_mm: float) -> float:
        return l_mm + self.a * math.sin(self.w * t_s + self.phi)


class _EndStop(Effect):
    """The encoder's slider runs into a stop: the reading saturates at ``level_mm``."""

    name = "end_stop"

    def __init__(self, level_mm: float) -> None:
        self.level = level_mm

    def measurement(self, t_s: float, l_mm: float) -> float:
        return min(l_mm, self.level)


class _VaryingLoad(Effect):
    """An extra load the recording does not know: a sine, or a weight hung on from ``on_s`` to ``off_s``."""

    name = "varying_load"

    def __init__(self, p: dict[str, float]) -> None:
        self.p = p

    def load(self, t_s: float, load_n: float) -> float:
        p = self.p
        if p["form"] == 0.0:
            return load_n + p["extra_n"] * math.sin(2.0 * math.pi * p["frequency_hz"] * t_s + p["phase_rad"])
        return load_n + (p["extra_n"] if p["on_s"] <= t_s < p["off_s"] else 0.0)

    def breakpoints(self, t0_s: float, t1_s: float, u_v: float) -> list[float]:
        # the weight goes on and off at its own instants, not on the sampling grid
        if self.p["form"] == 0.0:
            return []
        return [t for t in (self.p["on_s"], self.p["off_s"]) if t0_s < t < t1_s]


def _disturbances(case: FieldCase, end_stop_mm: float | None) -> list[Effect]:
    p = dict(case.oov_params)
    if case.oov == "vibration":
        return [_Vibration(p["amplitude_mm"], p["frequency_hz"], p["phase_rad"])]
    if case.oov == "end_stop":
        return [] if end_stop_mm is None else [_EndStop(end_stop_mm)]
    if case.oov == "varying_load":
        return [_VaryingLoad(p)]
    return []


# ------------------------------------------------------------------------------------ recording
def _excitation_signal(case: FieldCase) -> Callable[[float], float]:
    from tapmuscle.io.signals import parse_input_spec

    spec = case.input_spec()
    if spec is not None:
        return parse_input_spec(spec)
    if case.excitation == "sinesum":
        p = dict(case.excitation_params)
        k = sum(1 for key in p if key.startswith("amplitude"))
        terms = [(p[f"amplitude{i}_v"], 2.0 * math.pi * p[f"frequency{i}_hz"], p[f"phase{i}_rad"]) for i in range(k)]
        offset = p["offset_v"]
        return lambda t: offset + sum(a * math.sin(w * t + ph) for a, w, ph in terms)
    raise ValueError(f"{case.excitation!r} is not an open-loop excitation")


def record_case(case: FieldCase, *, signal: Callable[[float], float] | None = None,
                duration_s: float | None = None, ts_s: float = TS_S, noise_seed: int | None = None,
                end_stop_mm: float | None = None, params: PlantParams | None = None,
                disturbances: bool = True) -> dict[str, np.ndarray]:
    """Record the case's truth rig (sensor noise and quantisation on).

    Parameters
    ----------
    case : FieldCase
    signal : callable, optional
        Open-loop command [V] of time [s] instead of the case's excitation (a discriminating input).
    duration_s, ts_s : float, optional
        Length [s] (default: the case's) and sampling period [s].
    noise_seed : int, optional
        Seed of the sensor noise (default: the case's).
    end_stop_mm : float, optional
        Level of an ``end_stop`` disturbance [mm] (it depends on the run's peak, :func:`run_field_case`).
    params : PlantParams, optional
        The rig (default: ``case.truth()``); e.g. a noise-free variant.
    disturbances : bool
        Apply the out-of-vocabulary disturbance.

    Returns
    -------
    dict of ndarray
        ``t_s, u_v, l_mm, p_mpa, load_n`` (and ``r_mm`` for the closed loop). ``load_n`` is the
        nominal load throughout, also under a ``varying_load`` disturbance: the rig does not record it.
    """
    rig = case.truth() if params is None else params
    extra = _disturbances(case, end_stop_mm) if disturbances else []
    plant = Plant(rig, seed=case.noise_seed if noise_seed is None else noise_seed, effects=extra)
    duration = case.duration_s if duration_s is None else duration_s
    if signal is None and case.excitation == "ampc":
        from fmu_controller.displacement_control import P0_TABLE5, ControllerSettings, DisplacementController
        from fmu_controller.preliminary_model import THETA0_44N
        from fmu_controller.reference import SineReference
        from tapmuscle.closed_loop import run_closed_loop

        p = dict(case.excitation_params)
        ctrl = DisplacementController(ControllerSettings(method="ampc_servo", p0=P0_TABLE5), THETA0_44N)
        ref = SineReference(offset_mm=p["offset_mm"], amplitude_mm=p["amplitude_mm"],
                            frequency_hz=p["frequency_hz"], ts_s=ts_s)
        cols = run_closed_loop(plant, ctrl, ref, duration_s=duration)
        return {k: cols[k] for k in ("t_s", "u_v", "l_mm", "p_mpa", "load_n", "r_mm")}
    return run_open_loop(plant, signal if signal is not None else _excitation_signal(case),
                         duration_s=duration, ts_s=ts_s)


def _replay(params: PlantParams, u_v: np.ndarray, ts_s: float, extra: Sequence[Effect] = ()) -> np.ndarray:
    """Noise-free displacement reading [mm] of ``params`` (and disturbances) driven by the recorded command."""
    plant = Plant(noise_free(params), seed=0, effects=extra)
    y = np.empty(len(u_v))
    y[0] = plant.measurement.l_mm
    for k in range(len(u_v) - 1):
        y[k + 1] = plant.step(float(u_v[k]), ts_s).l_mm
    return y


def _costs(case: FieldCase, cols: dict[str, np.ndarray], end_stop_mm: float | None) -> dict[str, Any]:
    """Held-out fits of noise-free variants of the truth, and what each part of the truth costs.

    ``cost`` of an effect (or the disturbance, or the constants' errors) = held-out fit of the whole
    truth minus that of the truth without it [points]: how much there is to find.
    """
    _, test = interleaved_split(len(cols["t_s"]), TS_S, 10.0)
    u, y = cols["u_v"], cols["l_mm"]
    extra = _disturbances(case, end_stop_mm)
    truth = case.truth()
    model = case.model()

    def fit(params: PlantParams, with_disturbance: bool = True) -> float:
        # fresh disturbance objects each run: an effect may keep memory
        return fit_percent(y, _replay(params, u, TS_S, _disturbances(case, end_stop_mm) if with_disturbance else []),
                           test)

    fit_truth = fit(truth)
    out: dict[str, Any] = {"fit_truth_percent": fit_truth, "effect_cost_points": {}}
    for e in case.effects:
        others = {k: v for f in case.effects if f != e for k, v in _effect_values(case, f).items()}
        without = model.with_values(**case.true_constants(), **others)
        out["effect_cost_points"][e] = fit_truth - fit(without)
    if extra:
        out["oov_cost_points"] = fit_truth - fit(truth, with_disturbance=False)
    # the constants' errors: the truth with the model's constants
    out["constants_cost_points"] = fit_truth - fit(model.with_values(**dict(case.effect_values)))
    # the ideal calibration: the true constants, no effect, no disturbance
    out["fit_true_constants_only_percent"] = fit(model.with_values(**case.true_constants()), with_disturbance=False)
    return out


def _effect_values(case: FieldCase, effect: str) -> dict[str, float]:
    """The plant parameters of one of the case's effects."""
    groups = {"rate_dependent_hysteresis": "friction", "valve_dead_zone": "dead_zone", "transport_delay": "delay",
              "supply_pressure_variation": "supply_variation", "load_mismatch": "load_mismatch",
              "sensor_drift": "sensor_drift", "backlash": "backlash", "input_map": "input_map"}
    return {k: v for k, v in case.effect_values if k.partition(".")[0] == groups[effect]}


# ------------------------------------------------------------------------------------ one case
def _claims(doc: dict[str, Any]) -> dict[str, Any]:
    """What a ``diagnosis.json`` claims (defensive: older documents lack ``ambiguous``, ``calibration``)."""
    findings = [str(f.get("effect")) for f in (doc.get("findings") or []) if isinstance(f, dict)]
    groups = [[str(a.get("effect")) for a in (g.get("alternatives") or []) if isinstance(a, dict)]
              for g in (doc.get("ambiguous") or []) if isinstance(g, dict)]
    return {"verdict": doc.get("verdict"), "findings": findings, "ambiguous": groups}


def _calibration_check(doc: dict[str, Any], case: FieldCase) -> dict[str, Any] | None:
    """How the diagnosis' calibration compares with the truth's constants (None without a calibration)."""
    cal = doc.get("calibration")
    rows = cal.get("parameters") if isinstance(cal, dict) else None
    if not isinstance(rows, list):
        return None
    truth = case.truth()
    out = {"identifiable": 0, "true_in_ci95": 0, "off_identified": 0, "off": len(case.parameter_errors)}
    off = {k for k, _ in case.parameter_errors}
    for r in rows:
        if not isinstance(r, dict) or not r.get("identifiable"):
            continue
        key = r.get("parameter")
        try:
            true = _value(truth, str(key))
        except (AttributeError, ValueError):
            continue
        out["identifiable"] += 1
        out["off_identified"] += key in off
        ci = r.get("ci95")
        est = r.get("estimate")
        if isinstance(ci, (list, tuple)) and len(ci) == 2:
            lo, hi = float(ci[0]), float(ci[1])
        elif isinstance(ci, (int, float)) and isinstance(est, (int, float)):
            lo, hi = float(est) - float(ci), float(est) + float(ci)  # a half-width
        else:
            continue
        out["true_in_ci95"] += lo <= true <= hi
    return out


def _diagnose(rec: Path, plant: Path, folder: Path, effects: Sequence[str] | None = None) -> dict[str, Any]:
    from tapmuscle.diagnosis.report import diagnose_files

    if effects is None:
        return diagnose_files(rec, plant, folder, plots=False)[1]
    try:
        return diagnose_files(rec, plant, folder, plots=False, effects=list(effects))[1]
    except TypeError as exc:
        if "effects" not in str(exc):
            raise
        # a diagnosis without the keyword: the re-diagnosis tries every candidate
        return diagnose_files(rec, plant, folder, plots=False)[1]


def _tidy(folder: Path, keep: bool) -> None:
    if keep or not folder.is_dir():
        return
    for p in folder.iterdir():
        if p.is_file() and p.name not in KEPT_FILES:
            p.unlink()


def _discriminate(case: FieldCase, doc: dict[str, Any], folder: Path, plant_path: Path,
                  end_stop_mm: float | None, keep: bool) -> dict[str, Any] | None:
    """The discriminating experiment of an ``ambiguous`` verdict, run on the truth and re-diagnosed."""
    groups = [g for g in (doc.get("ambiguous") or []) if isinstance(g, dict)]
    if doc.get("verdict") != "ambiguous" and not groups:
        return None
    alternatives = sorted({str(a.get("effect")) for g in groups for a in (g.get("alternatives") or [])
                           if isinstance(a, dict)})
    names = {g.get("discriminating_input") for g in groups if g.get("discriminating_input")}
    path = next((folder / str(n) for n in sorted(names) if (folder / str(n)).is_file()), None)
    if path is None and (folder / "discriminating_input.csv").is_file():
        path = folder / "discriminating_input.csv"
    truth_in = sorted(set(case.effects) & set(alternatives))
    out: dict[str, Any] = {"alternatives": alternatives, "true_alternatives": truth_in, "input_written": path is not None}
    if path is None:
        return out
    from tapmuscle.io.signals import parse_input_spec

    stim = read_recording(path)
    ts = stim.ts_s
    duration = float(stim.t_s[-1] - stim.t_s[0])
    sub = folder / DISCRIMINATE_DIR
    cols = record_case(case, signal=parse_input_spec(f"csv:{path}"), duration_s=duration, ts_s=ts,
                       noise_seed=case.noise_seed + 1, end_stop_mm=end_stop_mm)
    rec = sub / "recording.csv"
    write_recording(rec, Recording(cols, {"ts_s": f"{ts:g}", "source": "tapmuscle demo-mismatch (discriminating input)"}))
    doc2 = _diagnose(rec, plant_path, sub, alternatives or None)
    c2 = _claims(doc2)
    named2 = _named(c2["findings"], c2["ambiguous"])
    picked = sorted(named2 & set(alternatives))
    out.update({"duration_s": duration, "verdict": c2["verdict"], "findings": c2["findings"],
                "ambiguous": c2["ambiguous"], "picked": picked,
                "right": picked == truth_in and not c2["ambiguous"],
                "fit_before_percent": doc2.get("fit_before_percent"), "fit_after_percent": doc2.get("fit_after_percent")})
    _tidy(sub, keep)
    return out


def _named(findings: Sequence[str], ambiguous: Sequence[Sequence[str]]) -> set[str]:
    """The effects a verdict names: its findings' (not ``unexplained``) and every ambiguous alternative."""
    return {e for e in findings if e != "unexplained"} | {a for g in ambiguous for a in g}


def run_field_case(case: FieldCase, workdir: str | Path, *, keep: bool = False) -> dict[str, Any]:
    """Record the case's truth, write the CSV and the nominal model's plant file, diagnose, score.

    Parameters
    ----------
    case : FieldCase
    workdir : path
        The case's folder is ``workdir / case.name``; it keeps ``diagnosis.json`` and ``report.md``
        (and those of the discriminating experiment in ``discriminate/``); the CSVs and the plant
        files are deleted unless ``keep``. A case that raises keeps them, for a look at what failed.

    Returns
    -------
    dict
        The truth (:meth:`FieldCase.describe`), what the diagnosis claimed (``verdict``, ``findings``,
        ``ambiguous`` as lists of alternatives), its held-out fits, the costs (:func:`_costs`), the
        calibration check and the discriminating experiment (``discrimination``, None unless
        ``ambiguous``). Scored by :func:`score_results`.
    """
    workdir = Path(workdir)
    folder = workdir / case.name
    t0 = time.monotonic()
    end_stop_mm = None
    if case.oov == "end_stop":
        # the stop sits below the peak of the same run without it (same input, same noise), after the
        # run's first 10 %: the closed loop's start-up overshoot (t ~ 1.5 s) would put it out of reach
        free = record_case(case, disturbances=False)
        late = free["t_s"] >= 0.1 * case.duration_s
        end_stop_mm = float(np.max(free["l_mm"][late])) - dict(case.oov_params)["below_peak_mm"]
    cols = record_case(case, end_stop_mm=end_stop_mm)
    rec_path = folder / "recording.csv"
    plant_path = folder / "plant.json"
    write_recording(rec_path, Recording(cols, {"ts_s": f"{TS_S:g}", "source": "tapmuscle demo-mismatch (field)"}))
    atomic_write_text(plant_path, plant_file_text(case.model(), "the nominal model of the field demo"))
    doc = _diagnose(rec_path, plant_path, folder)
    claims = _claims(doc)
    result: dict[str, Any] = {**case.describe(), **claims,
                              "named": sorted(_named(claims["findings"], claims["ambiguous"])),
                              "fit_before_percent": doc.get("fit_before_percent"),
                              "fit_after_percent": doc.get("fit_after_percent"),
                              "end_stop_mm": end_stop_mm,
                              "diagnosis_elapsed_s": doc.get("elapsed_s")}
    result.update(_costs(case, cols, end_stop_mm))
    result["calibration_check"] = _calibration_check(doc, case)
    try:
        result["discrimination"] = _discriminate(case, doc, folder, plant_path, end_stop_mm, keep)
    except Exception as exc:  # noqa: BLE001 - the first diagnosis stands; the experiment's failure is reported
        result["discrimination"] = {"input_written": True, "error": f"{type(exc).__name__}: {exc}"}
    result["elapsed_s"] = time.monotonic() - t0
    _tidy(folder, keep)
    atomic_write_text(folder / RESULT_FILE, json.dumps(result, indent=2, default=_json_default) + "\n")
    return result


def _stored_result(case: FieldCase, workdir: Path) -> dict[str, Any] | None:
    """The case's stored result if an earlier run finished it with the same truth (else None)."""
    path = workdir / case.name / RESULT_FILE
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    truth = json.loads(json.dumps(case.describe(), default=_json_default))
    return stored if all(stored.get(k) == v for k, v in truth.items()) else None


def _run_safe(args: tuple[FieldCase, str, bool]) -> dict[str, Any]:
    case, workdir, keep = args
    try:
        return run_field_case(case, workdir, keep=keep)
    except Exception as exc:  # noqa: BLE001 - a failing case is scored as failed, with its error
        return {**case.describe(), "error": f"{type(exc).__name__}: {exc}"}


# ------------------------------------------------------------------------------------ the suite
def run_field_demo(out: str | Path, *, n: int = 120, seed: int = 0, jobs: int | None = None,
                   duration_s: float = DURATION_S, keep: bool = False, resume: bool = False,
                   progress: Callable[..., None] | None = None, heartbeat_s: float = 5.0) -> dict[str, Any]:
    """Make, diagnose and score ``n`` field recordings (module docstring).

    Parameters
    ----------
    out : path
        Output folder: ``scores.md``, ``scores.json`` (every case's truth and result),
        ``confusion.png`` and ``cases/<name>/`` (``diagnosis.json``, ``report.md``).
    n, seed, duration_s : see :func:`field_cases`.
    jobs : int, optional
        Worker processes (default: all cores).
    keep : bool
        Keep the recordings and plant files in the case folders.
    resume : bool
        Reuse the results of cases that an earlier (interrupted) run into ``out`` finished: each
        finished case leaves ``cases/<name>/result.json``, reused only if its truth is the same.
        The caller vouches that the diagnosis code has not changed in between.
    progress : callable, optional
        ``progress(done, total, detail)``, called as cases finish and at least every ``heartbeat_s``.

    Returns
    -------
    dict
        The scores (:func:`score_results`).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cases = field_cases(n, seed, duration_s=duration_s)
    jobs = jobs or os.cpu_count() or 1
    t0 = time.monotonic()
    results: dict[int, dict[str, Any]] = {}
    if resume:
        for c in cases:
            stored = _stored_result(c, out / "cases")
            if stored is not None:
                results[c.index] = stored
    todo = [c for c in cases if c.index not in results]
    with ProcessPoolExecutor(max_workers=max(1, min(jobs, len(todo)))) as pool:
        pending: dict[Future, FieldCase] = {pool.submit(_run_safe, (c, str(out / "cases"), keep)): c for c in todo}
        # wait() rather than as_completed(): the same results as they finish, plus a heartbeat while
        # the slowest cases run (as_completed's timeout would end the iteration instead)
        while pending:
            done, _ = wait(pending, timeout=heartbeat_s, return_when=FIRST_COMPLETED)
            for f in done:
                results[pending.pop(f).index] = f.result()
            if progress is not None:
                failed = sum("error" in r for r in results.values())
                progress(len(results), len(cases), f"{failed} failed, {time.monotonic() - t0:.0f} s")
    ordered = [results[c.index] for c in cases]
    scores = score_results(ordered)
    settings = {"recordings": n, "seed": seed, "duration_s": duration_s, "ts_s": TS_S, "jobs": jobs,
                "resumed_cases": len(cases) - len(todo),
                "vocabulary": list(vocabulary()), "wall_s": time.monotonic() - t0}
    scores["settings"] = settings
    atomic_write_text(out / "scores.json", json.dumps({"scores": scores, "cases": ordered}, indent=2,
                                                      default=_json_default) + "\n")
    atomic_write_text(out / "scores.md", scores_markdown(scores))
    confusion_figure(scores, out / "confusion.png")
    return scores


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, (set, frozenset, tuple)):
        return sorted(o) if isinstance(o, (set, frozenset)) else list(o)
    return str(o)


# ------------------------------------------------------------------------------------ scoring
def _rate(k: int, n: int) -> float | None:
    return 100.0 * k / n if n else None


def _row_label(r: dict[str, Any]) -> str:
    c = r.get("category")
    if c == "single":
        return f"single: {r['effects'][0]}"
    if c == "oov":
        return f"oov: {r.get('oov')}"
    return str(c)


def _visible(r: dict[str, Any]) -> bool:
    """Every effect (or the disturbance) of the truth costs >= VISIBLE_POINTS of held-out fit (a case
    without costs, e.g. failed before they were computed, counts as visible)."""
    costs = list((r.get("effect_cost_points") or {}).values())
    if r.get("category") == "oov" and r.get("oov_cost_points") is not None:
        costs.append(r["oov_cost_points"])
    return all(c >= VISIBLE_POINTS for c in costs)


def _judge(r: dict[str, Any]) -> dict[str, bool]:
    """The pass flags of one case (see :func:`score_results`)."""
    if "error" in r:
        return {"ok": False, "alone": False, "strict": False, "unexplained": False, "fit_ok": False}
    findings = list(r.get("findings") or [])
    groups = list(r.get("ambiguous") or [])
    named = _named(findings, groups)
    truth = set(r.get("effects") or [])
    fa = r.get("fit_after_percent")
    fit_ok = isinstance(fa, (int, float)) and fa >= FIT_AFTER_PERCENT
    c = r.get("category")
    # alone: the truth's effects are the only effects named (Diagnosis.named: an `unexplained`
    # remainder reported beside them is not a named effect); strict: and no remainder either
    alone = named == truth and not groups
    strict = set(findings) == truth and not groups
    if c == "none":
        return {"ok": not named and "unexplained" not in findings, "alone": alone, "strict": strict,
                "unexplained": False, "fit_ok": fit_ok}
    if c in ("single", "pair"):
        return {"ok": truth <= named, "alone": alone, "strict": strict, "unexplained": "unexplained" in findings,
                "fit_ok": fit_ok}
    unexplained = "unexplained" in findings
    return {"ok": unexplained, "alone": unexplained and not named, "strict": unexplained and not named,
            "unexplained": unexplained, "fit_ok": fit_ok}


def score_results(results: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Score the per-case results of :func:`run_field_case` (pure: a test can feed made-up results).

    A case's *named* effects are its findings' effects (not ``unexplained``) and every alternative of
    its ``ambiguous`` groups. Per category:

    * ``none``: no effect named and no ``unexplained`` finding (calibration alone);
    * ``single``: the effect is named (``single_named``); *named alone*: it is the only effect named
      and there is no ambiguous group (an ``unexplained`` remainder reported beside it is not a named
      effect, as in :attr:`Diagnosis.named`); ``more.single_named_alone_no_remainder`` is the
      stricter count that also wants no ``unexplained`` finding;
    * ``pair``: both effects named (``pair_both_found``);
    * ``oov``: an ``unexplained`` finding (``oov_unexplained``); *alone*: no vocabulary effect
      named besides;
    * ``fit_after_at_least_95``: the held-out fit after >= :data:`FIT_AFTER_PERCENT` in the
      ``none``, ``single`` and ``pair`` cases (every effect in the vocabulary).

    A failed case (``error``) counts as a miss in its category. Each rate is also given over the
    *visible* cases (every effect costs >= :data:`VISIBLE_POINTS` of the truth's held-out fit).

    Returns
    -------
    dict
        ``targets`` (rate, passed, cases, target, met; and the same over visible cases),
        ``confusion`` (rows, columns, counts), ``pairs`` (per pair: both, one, neither),
        ``discrimination`` (ambiguous verdicts, inputs written, re-diagnosed, right), ``calibration``,
        ``misses`` (every case that misses its category's target, with what it claimed), ``failed``.
    """
    flags = [_judge(r) for r in results]
    by_cat: dict[str, list[int]] = {c: [] for c in CATEGORIES}
    for i, r in enumerate(results):
        by_cat.setdefault(str(r.get("category")), []).append(i)
    in_vocab = by_cat["none"] + by_cat["single"] + by_cat["pair"]

    def target(key: str, idx: list[int], flag: str) -> dict[str, Any]:
        k = sum(flags[i][flag] for i in idx)
        vis = [i for i in idx if _visible(results[i])]
        kv = sum(flags[i][flag] for i in vis)
        rate = _rate(k, len(idx))
        return {"passed": k, "cases": len(idx), "rate_percent": rate, "target_percent": TARGETS[key],
                "met": None if rate is None else rate >= TARGETS[key],
                "visible_passed": kv, "visible_cases": len(vis), "visible_rate_percent": _rate(kv, len(vis))}

    targets = {
        "none_no_effect_claimed": target("none_no_effect_claimed", by_cat["none"], "ok"),
        "single_named": target("single_named", by_cat["single"], "ok"),
        "single_named_alone": target("single_named_alone", by_cat["single"], "alone"),
        "pair_both_found": target("pair_both_found", by_cat["pair"], "ok"),
        "oov_unexplained": target("oov_unexplained", by_cat["oov"], "ok"),
        "fit_after_at_least_95": target("fit_after_at_least_95", in_vocab, "fit_ok"),
    }
    extra = {
        "pair_found_alone": {"passed": sum(flags[i]["alone"] for i in by_cat["pair"]), "cases": len(by_cat["pair"])},
        "single_named_alone_no_remainder": {"passed": sum(flags[i]["strict"] for i in by_cat["single"]),
                                            "cases": len(by_cat["single"])},
        "pair_found_alone_no_remainder": {"passed": sum(flags[i]["strict"] for i in by_cat["pair"]),
                                          "cases": len(by_cat["pair"])},
        "oov_unexplained_alone": {"passed": sum(flags[i]["alone"] for i in by_cat["oov"]), "cases": len(by_cat["oov"])},
        "none_verdicts": _count(results[i].get("verdict") or "failed" for i in by_cat["none"]),
    }

    # confusion table: rows the truth, columns what was claimed (a case counts in every column it claims)
    vocab = list(vocabulary())
    claimed_effects = sorted({e for r in results for e in _named(r.get("findings") or [], r.get("ambiguous") or [])}
                             - set(vocab))  # names outside today's vocabulary, if a diagnosis has them
    columns = ["nothing", *vocab, *claimed_effects, "unexplained", "ambiguous", "failed"]
    rows = ["none", *[f"single: {e}" for e in vocab], "pair", *[f"oov: {k}" for k in OOV_KINDS]]
    rows += sorted({_row_label(r) for r in results} - set(rows))
    counts = {row: {col: 0 for col in columns} for row in rows}
    row_cases = {row: 0 for row in rows}
    row_ok = {row: 0 for row in rows}
    for r, f in zip(results, flags):
        row = _row_label(r)
        row_cases[row] += 1
        row_ok[row] += f["ok"]
        if "error" in r:
            counts[row]["failed"] += 1
            continue
        findings = r.get("findings") or []
        groups = r.get("ambiguous") or []
        named = _named(findings, groups)
        for e in named:
            counts[row][e] += 1
        if "unexplained" in findings:
            counts[row]["unexplained"] += 1
        if groups:
            counts[row]["ambiguous"] += 1
        if not named and "unexplained" not in findings:
            counts[row]["nothing"] += 1

    pairs: dict[str, dict[str, int]] = {}
    for i in by_cat["pair"]:
        r = results[i]
        key = "+".join(r["effects"])
        p = pairs.setdefault(key, {"cases": 0, "both": 0, "one": 0, "neither": 0, "failed": 0})
        p["cases"] += 1
        if "error" in r:
            p["failed"] += 1
            continue
        k = len(set(r["effects"]) & _named(r.get("findings") or [], r.get("ambiguous") or []))
        p[("neither", "one", "both")[k]] += 1

    disc = [r["discrimination"] for r in results if isinstance(r.get("discrimination"), dict)]
    discrimination = {"ambiguous_verdicts": sum(1 for r in results if r.get("verdict") == "ambiguous" or r.get("ambiguous")),
                      "inputs_written": sum(bool(d.get("input_written")) for d in disc),
                      "re_diagnosed": sum("right" in d for d in disc),
                      "right": sum(bool(d.get("right")) for d in disc),
                      "failed": sum("error" in d for d in disc)}

    checks = [r["calibration_check"] for r in results if isinstance(r.get("calibration_check"), dict)]
    calibration = {"cases_with_calibration": len(checks),
                   "identifiable_estimates": sum(c["identifiable"] for c in checks),
                   "true_value_in_ci95": sum(c["true_in_ci95"] for c in checks),
                   "constants_off": sum(c["off"] for c in checks),
                   "constants_off_identified": sum(c["off_identified"] for c in checks)}

    misses = []
    for r, f in zip(results, flags):
        c = r.get("category")
        missed = not f["ok"] or (c == "single" and not f["alone"]) or (c in ("none", "single", "pair") and not f["fit_ok"])
        if missed:
            misses.append({"case": r.get("case"), "truth": _row_label(r) if c != "pair" else "pair: " + "+".join(r["effects"]),
                           "verdict": r.get("verdict"), "findings": r.get("findings"), "ambiguous": r.get("ambiguous"),
                           "fit_before_percent": r.get("fit_before_percent"), "fit_after_percent": r.get("fit_after_percent"),
                           "visible": _visible(r), "effect_cost_points": r.get("effect_cost_points"),
                           "oov_cost_points": r.get("oov_cost_points"), "error": r.get("error"),
                           "why": _why(r, f)})
    fits = [(r.get("fit_before_percent"), r.get("fit_after_percent")) for r in results if "error" not in r]
    return {
        "recordings": len(results),
        "categories": {c: len(idx) for c, idx in by_cat.items()},
        "visible": sum(_visible(r) for r in results),
        "failed": sum("error" in r for r in results),
        "targets": targets,
        "more": extra,
        "confusion": {"rows": rows, "columns": columns, "counts": counts, "cases": row_cases, "correct": row_ok},
        "pairs": pairs,
        "discrimination": discrimination,
        "calibration": calibration,
        "median_fit_before_percent": _median([a for a, _ in fits]),
        "median_fit_after_percent": _median([b for _, b in fits]),
        "misses": misses,
    }


def _why(r: dict[str, Any], f: dict[str, bool]) -> str:
    if "error" in r:
        return "failed"
    c = r.get("category")
    out = []
    if not f["ok"]:
        out.append({"none": "claimed something", "single": "not named", "pair": "not both found",
                    "oov": "no unexplained finding"}.get(str(c), "missed"))
    elif c == "single" and not f["alone"]:
        out.append("named, not alone")
    if c in ("none", "single", "pair") and not f["fit_ok"]:
        out.append(f"fit after < {FIT_AFTER_PERCENT:g} %")
    return "; ".join(out)


def _count(items: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for x in items:
        out[str(x)] = out.get(str(x), 0) + 1
    return out


def _median(xs: list[Any]) -> float | None:
    v = [float(x) for x in xs if isinstance(x, (int, float)) and math.isfinite(x)]
    return float(np.median(v)) if v else None


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f} %"


def _num(x: Any, fmt: str = ".2f") -> str:
    return format(float(x), fmt) if isinstance(x, (int, float)) else "-"


def scores_markdown(s: dict[str, Any]) -> str:
    """The scores as markdown (``scores.md``, and what ``tapmuscle demo-mismatch`` prints)."""
    labels = {"none_no_effect_claimed": "no effect -> no effect claimed (calibration only)",
              "single_named": "one effect -> named (or an ambiguous alternative)",
              "single_named_alone": "one effect -> named alone",
              "pair_both_found": "two effects -> both found",
              "oov_unexplained": "out of vocabulary -> `unexplained`",
              "fit_after_at_least_95": f"held-out fit after >= {FIT_AFTER_PERCENT:g} % (no, one or two effects)"}
    cats = s["categories"]
    lines = [f"Field recordings: {s['recordings']} ({', '.join(f'{c} {k}' for c, k in cats.items())}); "
             f"{s['visible']} visible (every effect costs >= {VISIBLE_POINTS} points of held-out fit); "
             f"{s['failed']} failed.", ""]
    if s["recordings"] < 100:
        lines += ["*Fewer than 100 recordings: the targets are stated for at least 100.*", ""]
    lines += ["| target | passed | rate | target | met | visible cases: rate |", "|---|---|---|---|---|---|"]
    for key, t in s["targets"].items():
        met = "-" if t["met"] is None else "yes" if t["met"] else "**no**"
        vis = f"{_pct(t['visible_rate_percent'])} of {t['visible_cases']}" if t["visible_cases"] else "-"
        lines.append(f"| {labels[key]} | {t['passed']} / {t['cases']} | {_pct(t['rate_percent'])} | "
                     f">= {t['target_percent']:g} % | {met} | {vis} |")
    m = s["more"]
    lines += ["", f"* one effect, named alone with no `unexplained` remainder either: "
              f"{m['single_named_alone_no_remainder']['passed']} / {m['single_named_alone_no_remainder']['cases']}",
              f"* two effects, found alone (exactly the two named, no ambiguous group): "
              f"{m['pair_found_alone']['passed']} / {m['pair_found_alone']['cases']}; with no `unexplained` "
              f"remainder either: {m['pair_found_alone_no_remainder']['passed']}",
              f"* out of vocabulary, `unexplained` with no vocabulary effect named: "
              f"{m['oov_unexplained_alone']['passed']} / {m['oov_unexplained_alone']['cases']}",
              "* verdicts of the no-effect cases: " + (", ".join(f"`{k}` {v}" for k, v in m["none_verdicts"].items()) or "-"),
              f"* median held-out fit before / after: {_num(s['median_fit_before_percent'])} % / "
              f"{_num(s['median_fit_after_percent'])} %"]
    d = s["discrimination"]
    lines.append(f"* ambiguous verdicts: {d['ambiguous_verdicts']}; discriminating inputs written: "
                 f"{d['inputs_written']}; re-diagnosed on the truth: {d['re_diagnosed']}; right alternative "
                 f"picked: {d['right']}" + (f"; experiments that failed: {d['failed']}" if d["failed"] else ""))
    c = s["calibration"]
    if c["cases_with_calibration"]:
        lines.append(f"* calibration ({c['cases_with_calibration']} cases): {c['identifiable_estimates']} "
                     f"identifiable estimates, true value within the 95 % interval in {c['true_value_in_ci95']}; "
                     f"{c['constants_off_identified']} of the {c['constants_off']} constants that were off identified")
    else:
        lines.append("* calibration: the diagnosis reported none")
    conf = s["confusion"]
    short = {col: col.replace("_", " ") for col in conf["columns"]}
    lines += ["", "Confusion table (rows: the truth; columns: what the diagnosis claimed; a case counts in every "
              "column it claims; `nothing`: no effect and no `unexplained`):", "",
              "| truth | cases | correct | " + " | ".join(short[col] for col in conf["columns"]) + " |",
              "|---|---|---|" + "---|" * len(conf["columns"])]
    for row in conf["rows"]:
        if not conf["cases"][row]:
            continue
        cells = [str(conf["counts"][row][col]) if conf["counts"][row][col] else "." for col in conf["columns"]]
        lines.append(f"| {row} | {conf['cases'][row]} | {conf['correct'][row]} | " + " | ".join(cells) + " |")
    if s["pairs"]:
        lines += ["", "| pair | cases | both found | one | neither | failed |", "|---|---|---|---|---|---|"]
        for key, p in sorted(s["pairs"].items()):
            lines.append(f"| {key} | {p['cases']} | {p['both']} | {p['one']} | {p['neither']} | {p['failed']} |")
    lines += ["", f"Misses ({len(s['misses'])}):", ""]
    if s["misses"]:
        lines += ["| case | truth | why | verdict | claimed | fit before -> after [%] | costs [points] |",
                  "|---|---|---|---|---|---|---|"]
        for x in s["misses"]:
            claimed = ", ".join(x["findings"] or []) or "-"
            if x["ambiguous"]:
                claimed += "; ambiguous: " + " / ".join("|".join(g) for g in x["ambiguous"])
            costs = ", ".join(f"{k} {v:.2f}" for k, v in (x["effect_cost_points"] or {}).items())
            if x.get("oov_cost_points") is not None:
                costs = (costs + ", " if costs else "") + f"disturbance {x['oov_cost_points']:.2f}"
            if x["error"]:
                claimed = f"error: {x['error']}"
            lines.append(f"| `{x['case']}` | {x['truth']} | {x['why']}{'' if x['visible'] else ' (not visible)'} | "
                         f"{x['verdict'] or '-'} | {claimed} | {_num(x['fit_before_percent'])} -> "
                         f"{_num(x['fit_after_percent'])} | {costs or '-'} |")
    lines.append("")
    return "\n".join(lines)


def confusion_figure(s: dict[str, Any], path: str | Path) -> Path:
    """Heat map of the confusion table (share of each row's cases claiming each column), counts written in."""
    from tapmuscle.plots.figures import plt, save_figure

    conf = s["confusion"]
    rows = [r for r in conf["rows"] if conf["cases"][r]]
    cols = conf["columns"]
    share = np.array([[conf["counts"][r][c] / conf["cases"][r] for c in cols] for r in rows]) if rows else np.zeros((1, len(cols)))
    fig, ax = plt.subplots(figsize=(1.0 + 0.62 * len(cols), 1.4 + 0.42 * max(len(rows), 1)))
    im = ax.imshow(share, cmap="Blues", vmin=0.0, vmax=1.0, aspect="auto")
    for i, r in enumerate(rows):
        for j, c in enumerate(cols):
            k = conf["counts"][r][c]
            if k:
                ax.text(j, i, str(k), ha="center", va="center", fontsize=8,
                        color="white" if share[i, j] > 0.6 else "black")
    ax.set_xticks(range(len(cols)), [c.replace("_", " ") for c in cols], rotation=40, ha="right", fontsize=8)
    ax.set_yticks(range(len(rows)), [f"{r} ({conf['cases'][r]})" for r in rows], fontsize=8)
    # the correct column of each row, outlined: what a perfect diagnosis would fill
    for i, r in enumerate(rows):
        want = ("nothing" if r == "none" else r.split(": ", 1)[1] if r.startswith("single: ")
                else "unexplained" if r.startswith("oov: ") else None)
        if want in cols:
            j = cols.index(want)
            ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="tab:orange", lw=1.6))
    ax.set_xlabel("claimed by the diagnosis (orange box: the right answer)")
    ax.set_ylabel("truth (cases)")
    t = s["targets"]
    ax.set_title(f"Field recordings: {s['recordings']}; named {_pct(t['single_named']['rate_percent'])}, "
                 f"alone {_pct(t['single_named_alone']['rate_percent'])}, pairs {_pct(t['pair_both_found']['rate_percent'])}, "
                 f"none {_pct(t['none_no_effect_claimed']['rate_percent'])}, oov {_pct(t['oov_unexplained']['rate_percent'])}",
                 fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.03, pad=0.02, label="share of the row's cases")
    return save_figure(fig, path)
