"""The field recordings of the proof at scale: truth rigs, their recordings and what each effect costs.

A *truth rig* is the nominal model (:data:`tapmuscle.diagnosis.demo.DEMO_MODEL` at the case's load)
with 3-6 constants off and 0, 1 or 2 effects of the vocabulary, or one disturbance outside it
(:mod:`tapmuscle.diagnosis.field_demo` has the whole design and runs and scores the diagnosis on
them). :func:`field_cases` draws the cases (seeded: the same list on every machine),
:func:`record_case` records one, open or closed loop, and :func:`effect_costs` measures how much
held-out fit each effect costs the noise-free truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Callable, Sequence

import numpy as np

from fmu_plant import Plant, PlantParams
from fmu_plant.effects import Effect
from fmu_plant.open_loop import run_open_loop
from tapmuscle.diagnosis.candidates import CANDIDATES
from tapmuscle.diagnosis.demo import DEMO_MODEL, MAGNITUDES
from tapmuscle.diagnosis.diagnose import BLOCK_S
from tapmuscle.diagnosis.residual_analysis import fit_percent, interleaved_split

__all__ = ["FIELD_ERROR_PARAMETERS", "CATEGORY_MIX", "CATEGORIES", "EXCITATIONS", "OOV_KINDS", "LOADS_N",
           "EFFECT_RANGES", "INCOMPATIBLE_PAIRS", "NOT_DRAWN", "DURATION_S", "TS_S", "FieldCase", "vocabulary",
           "compatible_pairs", "field_cases", "record_case", "effect_costs", "parameter_value", "draw_parameter_errors",
           "off_nominal", "off_values"]

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


#: Candidates of the diagnosis that the field generator does not draw: a constant supply pressure
#: other than the plant file's (``supply_pressure_offset``) came after the suites whose tables
#: docs/diagnosis.md reports, and drawing it would change every later draw of a seed. It is measured
#: on cases of its own (docs/diagnosis.md, "A supply at another constant pressure").
NOT_DRAWN: frozenset[str] = frozenset({"supply_pressure_offset"})


DURATION_S = 180.0
TS_S = 0.1


# ------------------------------------------------------------------------------------- the cases
@dataclass(frozen=True)
class FieldCase:
    """One field recording to make and diagnose (all draws made, :func:`field_cases`)."""

    index: int
    """The case's number in the suite (0, 1, ...)."""
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
    """The recording's input, one of :data:`EXCITATIONS`."""
    excitation_params: tuple[tuple[str, float], ...]
    """The input's drawn parameters (name, value), e.g. ``offset_v``, ``amplitude_v``, ``frequency_hz``."""
    noise_seed: int
    """Seed of the plant's sensor noise."""
    duration_s: float = DURATION_S
    """Length of the recording [s]."""
    oov: str | None = None
    """Out-of-vocabulary disturbance (one of :data:`OOV_KINDS`), or None."""
    oov_params: tuple[tuple[str, float], ...] = ()
    """The disturbance's drawn parameters (name, value); empty without one."""

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
        return off_values(self.model(), self.parameter_errors)

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


def off_values(model: PlantParams, errors: Sequence[tuple[str, float]]) -> dict[str, float]:
    """The values (``group.field`` -> value) of ``model``'s constants with each ``(group.field, relative
    error)`` of ``errors`` applied.

    Parameters
    ----------
    model : PlantParams
        The nominal model.
    errors : sequence of (str, float)
        ``(group.field, relative error)`` pairs [-].
    """
    return {key: parameter_value(model, key) * (1.0 + rel) for key, rel in errors}


def off_nominal(model: PlantParams, errors: Sequence[tuple[str, float]]) -> PlantParams:
    """``model`` with each ``(group.field, relative error)`` of ``errors`` applied.

    Parameters
    ----------
    model : PlantParams
        The nominal model.
    errors : sequence of (str, float)
        ``(group.field, relative error)`` pairs [-].
    """
    return model.with_values(**off_values(model, errors))


def parameter_value(params: PlantParams, key: str) -> float:
    """The value of the plant parameter ``key`` (``group.field``) in ``params``.

    Parameters
    ----------
    params : PlantParams
        The plant's parameters.
    key : str
        The parameter, ``"group.field"``.
    """
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
    are left out: :data:`NOT_DRAWN`, and no other (``tests/test_field_demo.py``)."""
    names = [c.name for c in CANDIDATES]
    if "input_map" not in names and "input_map" in {f.name for f in fields(PlantParams)}:
        names.append("input_map")
    return tuple(n for n in names if n in _DRAWERS)


def compatible_pairs(vocab: Sequence[str] | None = None) -> list[tuple[str, str]]:
    """Every unordered pair of different vocabulary effects that may act together.

    Parameters
    ----------
    vocab : sequence of str, optional
        The effects; None (default): :func:`vocabulary`.
    """
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


def draw_parameter_errors(rng: np.random.Generator, model: PlantParams) -> tuple[tuple[str, float], ...]:
    """Draw a field rig's off constants: 3-6 of :data:`FIELD_ERROR_PARAMETERS`, each off by 5-20 %
    with a random sign, clipped to the parameter's bounds.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    model : PlantParams
        The nominal model the errors are relative to.

    Returns
    -------
    tuple of (str, float)
        ``(group.field, relative error)`` pairs, the error after clipping.
    """
    k = int(rng.integers(ERRORS_PER_CASE[0], ERRORS_PER_CASE[1] + 1))
    keys = rng.choice(len(FIELD_ERROR_PARAMETERS), size=k, replace=False)
    out = []
    for i in sorted(int(j) for j in keys):
        key = FIELD_ERROR_PARAMETERS[i]
        rel = _sign(rng) * float(rng.uniform(*ERROR_REL_RANGE))
        nominal = parameter_value(model, key)
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
        errors = draw_parameter_errors(rng, model)
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
        # the recordings' controller is part of the suite's definition (Eq. (18) without the
        # anti-windup hold, no start-up guard): a later change of the controller's defaults does not
        # change its data
        ctrl = DisplacementController(ControllerSettings(method="ampc_servo", p0=P0_TABLE5, ts_s=ts_s,
                                                         anti_windup=False, startup_guard=False), THETA0_44N)
        ref = SineReference(offset_mm=p["offset_mm"], amplitude_mm=p["amplitude_mm"],
                            frequency_hz=p["frequency_hz"], ts_s=ts_s)
        cols = run_closed_loop(plant, ctrl, ref, duration_s=duration, watch=False)
        return {k: cols[k] for k in ("t_s", "u_v", "l_mm", "p_mpa", "load_n", "r_mm")}
    return run_open_loop(plant, signal if signal is not None else _excitation_signal(case),
                         duration_s=duration, ts_s=ts_s)


def _replay(params: PlantParams, u_v: np.ndarray, ts_s: float, extra: Sequence[Effect] = ()) -> np.ndarray:
    """Noise-free displacement reading [mm] of ``params`` (and disturbances) driven by the recorded command."""
    plant = Plant(params.noise_free(), seed=0, effects=extra)
    y = np.empty(len(u_v))
    y[0] = plant.measurement.l_mm
    for k in range(len(u_v) - 1):
        y[k + 1] = plant.step(float(u_v[k]), ts_s).l_mm
    return y


def effect_costs(case: FieldCase, cols: dict[str, np.ndarray], end_stop_mm: float | None, *,
                 block_s: float = BLOCK_S) -> dict[str, Any]:
    """Held-out fits of noise-free variants of the truth, and what each part of the truth costs.

    ``cost`` of an effect (or the disturbance, or the constants' errors) = held-out fit of the whole
    truth minus that of the truth without it [points]: how much there is to find. The held-out
    blocks are those of a split into ``block_s``-long blocks [s]: the diagnosis's own, so that its
    fit and the truth's are taken on the same samples.

    Parameters
    ----------
    case : FieldCase
        The case.
    cols : dict of str to ndarray
        Its recording's columns (``t_s``, ``u_v``, ``l_mm``).
    end_stop_mm : float or None
        Where an ``end_stop`` disturbance stops the muscle [mm]; None for other cases.
    block_s : float, optional
        Length of the training / held-out blocks [s]; default :data:`BLOCK_S`.
    """
    _, test = interleaved_split(len(cols["t_s"]), TS_S, block_s)
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
              "sensor_drift": "sensor_drift", "backlash": "backlash", "input_map": "input_map",
              "supply_pressure_offset": "supply"}
    return {k: v for k, v in case.effect_values if k.partition(".")[0] == groups[effect]}
