"""The proof of the diagnosis: recordings of a rig with one effect concealed, diagnosed from the CSV alone.

``tapmuscle demo-mismatch`` (and the tests) run :func:`run_demo`: for every effect, magnitude level,
excitation and seed, a rig = the demo model + that effect (a random magnitude within the level's
range, random location) is recorded with sensor noise and quantisation; the CSV is handed to
:func:`tapmuscle.diagnosis.report.diagnose_files` with the model's parameter file (nothing else), and the
top finding is scored. Also: clean recordings (the rig is the model), a supply sag present only from
60 s to 90 s (is it located?), and the paper's Fig. 20 case (a plant calibrated on 0.1 Hz data
without rate dependence, against a 0.2 Hz recording of a rig that has it).

The demo model is the default plant with ``friction.rate_gain = 0``: a model calibrated without rate
dependence, so that ``rate_dependent_hysteresis`` can be concealed like the others.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fmu_plant import Plant, PlantParams
from fmu_plant.open_loop import run_open_loop
from tapmuscle.io.plant_file import plant_file_text
from tapmuscle.io.recording import Recording, atomic_write_text, write_recording

from tapmuscle.diagnosis.diagnose import BLOCK_S
from tapmuscle.diagnosis.residual_analysis import fit_percent, iou, interleaved_split
from tapmuscle.diagnosis.simulation import Simulator, process_pool
from tapmuscle.diagnosis.reproducible import sse
from tapmuscle.provenance import produced_by

__all__ = ["DEMO_MODEL", "EXCITATIONS", "MAGNITUDES", "Case", "concealed_cases", "record", "run_case",
           "run_demo", "calibrate_without_rate"]

#: The model handed to the diagnosis: calibrated, but without rate dependence.
DEMO_MODEL = PlantParams().with_values(**{"friction.rate_gain": 0.0})

#: Excitations of the recordings: the identification sine (open loop), closed-loop AMPC-servo tracking,
#: random steps (open loop).
EXCITATIONS = ("sine", "ampc", "steps")

#: Per effect, three magnitude levels: (low, high) ranges of the main parameter; a random value is
#: drawn within the range (sign random where both signs are physical).
MAGNITUDES: dict[str, tuple[tuple[float, float], ...]] = {
    "rate_dependent_hysteresis": ((0.2, 0.4), (0.5, 0.8), (0.9, 1.4)),      # friction.rate_gain [-]
    "valve_dead_zone": ((0.3, 0.5), (0.6, 0.9), (1.0, 1.5)),                # width [V]
    "transport_delay": ((0.03, 0.07), (0.1, 0.18), (0.2, 0.35)),            # delay [s]
    "supply_pressure_variation": ((0.01, 0.02), (0.025, 0.04), (0.045, 0.07)),  # sag [MPa]
    "load_mismatch": ((2.0, 4.0), (5.0, 9.0), (10.0, 16.0)),                # |extra load| [N]
    "sensor_drift": ((0.05, 0.15), (0.2, 0.4), (0.5, 1.0)),                 # |offset| [mm] and |rate| [mm/min]
    "backlash": ((0.2, 0.4), (0.5, 0.9), (1.0, 2.0)),                       # play [mm]
}

#: A concealed effect that costs less held-out fit than this [points] is below the noise: nothing to find.
VISIBLE_POINTS = 0.3

DURATION_S = 150.0
TS_S = 0.1


@dataclass(frozen=True)
class Case:
    """One concealed-effect recording to make and diagnose."""

    effect: str
    """Concealed effect, or ``"none"`` for a clean recording."""
    level: int
    """Magnitude level of the concealed effect, 0, 1 or 2 (:data:`MAGNITUDES`)."""
    excitation: str
    """The recording's input, one of :data:`EXCITATIONS`."""
    seed: int
    """Seed of the case: its magnitude draw, the random steps' input and the recording's sensor noise."""
    overrides: dict[str, float]
    """Plant parameters of the rig beyond the model (the concealed effect)."""
    true_window: tuple[float, float] | None = None
    """Where a windowed effect acts [s] (for the IoU)."""
    model: str = "demo"
    """``"demo"`` (DEMO_MODEL) or ``"fig20"`` (calibrated on 0.1 Hz without rate dependence)."""
    frequency_hz: float = 0.1
    """Frequency of the sine input, or of the closed loop's sine reference [Hz]."""

    @property
    def name(self) -> str:
        return f"{self.effect}_L{self.level}_{self.excitation}_s{self.seed}"


def _draw(effect: str, level: int, rng: np.random.Generator) -> tuple[dict[str, float], tuple[float, float] | None]:
    lo, hi = MAGNITUDES[effect][level]
    m = float(rng.uniform(lo, hi))
    sign = 1.0 if rng.random() < 0.5 else -1.0
    if effect == "rate_dependent_hysteresis":
        return {"friction.rate_gain": m}, None
    if effect == "valve_dead_zone":
        return {"dead_zone.center_v": float(rng.uniform(3.5, 6.5)), "dead_zone.width_v": m}, None
    if effect == "transport_delay":
        return {"delay.delay_s": m}, None
    if effect == "supply_pressure_variation":
        start = float(rng.uniform(30.0, 80.0))
        end = start + float(rng.uniform(20.0, 40.0))
        return ({"supply_variation.sag_mpa": m, "supply_variation.start_s": start, "supply_variation.end_s": end},
                (start, end + PlantParams().supply_variation.ramp_s))
    if effect == "load_mismatch":
        return {"load_mismatch.extra_n": sign * m}, None
    if effect == "sensor_drift":
        return {"sensor_drift.offset_mm": sign * m,
                "sensor_drift.rate_mm_per_min": (1.0 if rng.random() < 0.5 else -1.0) * float(rng.uniform(lo, hi))}, None
    if effect == "backlash":
        return {"backlash.slack_mm": m}, None
    raise ValueError(f"unknown effect {effect!r}")


def concealed_cases(seeds: int = 3, *, effects: tuple[str, ...] | None = None,
                    excitations: tuple[str, ...] = EXCITATIONS, levels: tuple[int, ...] = (0, 1, 2)) -> list[Case]:
    """Every effect x level x excitation x seed (``seeds`` seeds), magnitudes drawn reproducibly.

    A case is seeded by its effect's and excitation's places in the whole suite (:data:`MAGNITUDES`,
    :data:`EXCITATIONS`), its level and its seed, so a run of some rows (``effects``, ``excitations``)
    draws the very cases, under the same names, that the whole suite does.

    Parameters
    ----------
    seeds : int, optional
        Seeds per effect, level and excitation; default 3.
    effects : tuple of str, optional
        The effects (keys of :data:`MAGNITUDES`); None (default): all.
    excitations : tuple of str, optional
        The excitations; default all of :data:`EXCITATIONS`.
    levels : tuple of int, optional
        The magnitude levels; default ``(0, 1, 2)``.

    Raises
    ------
    ValueError
        An effect or excitation the suite does not know.
    """
    for name, given, known in (("effect", effects or (), tuple(MAGNITUDES)), ("excitation", excitations, EXCITATIONS)):
        unknown = [x for x in given if x not in known]
        if unknown:
            raise ValueError(f"unknown {name} {unknown[0]!r}; known: {', '.join(known)}")
    cases = []
    for effect in effects or tuple(MAGNITUDES):
        ei = tuple(MAGNITUDES).index(effect)
        for level in levels:
            for exc in excitations:
                xi = EXCITATIONS.index(exc)
                for seed in range(seeds):
                    rng = np.random.default_rng([ei, level, xi, seed])
                    overrides, window = _draw(effect, level, rng)
                    cases.append(Case(effect, level, exc, seed, overrides, window))
    return cases


def calibrate_without_rate(recording_u: np.ndarray, recording_l: np.ndarray, ts_s: float) -> PlantParams:
    """The Fig. 20 model: ``friction.rate_gain = 0``, friction level (``base_n``, ``per_mpa_n`` scaled
    together) fitted by least squares to a 0.1 Hz recording; what a careful calibration without rate
    dependence yields.

    Parameters
    ----------
    recording_u : ndarray
        The recording's command [V].
    recording_l : ndarray
        The recording's displacement [mm].
    ts_s : float
        Sampling period [s].
    """
    from scipy import optimize

    sim = Simulator(recording_u, ts_s)
    base = PlantParams()

    def params(scale: float) -> PlantParams:
        return base.with_values(**{"friction.rate_gain": 0.0, "friction.base_n": base.friction.base_n * scale,
                                   "friction.per_mpa_n": base.friction.per_mpa_n * scale})

    def cost(scale: float) -> float:
        r = recording_l - sim.run(params(scale))[0]
        return sse(r)
    res = optimize.minimize_scalar(cost, bounds=(1.0, 3.0), method="bounded", options={"xatol": 1e-3})
    return params(float(res.x))


def record(rig: PlantParams, excitation: str, seed: int, *, frequency_hz: float = 0.1,
           duration_s: float = DURATION_S) -> dict[str, np.ndarray]:
    """A recording of ``rig`` (sensor noise on, seed ``seed``): columns ``t_s, u_v, l_mm, p_mpa, load_n``
    (plus ``r_mm`` for the closed loop).

    Parameters
    ----------
    rig : PlantParams
        The rig recorded.
    excitation : str
        ``"sine"`` (5 +- 3 V open loop), ``"steps"`` (random levels 2..8 V) or ``"ampc"`` (the
        AMPC servo tracking a sine reference).
    seed : int
        Seed of the sensor noise (the plant's seed is ``1000 + seed``) and of the random steps.
    frequency_hz : float, optional
        Frequency of the sine input or reference [Hz]; default 0.1.
    duration_s : float, optional
        Length of the recording [s]; default :data:`DURATION_S`.
    """
    plant = Plant(rig, seed=1000 + seed)
    if excitation == "sine":
        return run_open_loop(plant, lambda t: 5.0 + 3.0 * math.sin(2 * math.pi * frequency_hz * t),
                             duration_s=duration_s, ts_s=TS_S)
    if excitation == "steps":
        from tapmuscle.io.signals import parse_input_spec

        return run_open_loop(plant, parse_input_spec(f"random:lo=2,hi=8,hold_min=2,hold_max=6,seed={seed}"),
                             duration_s=duration_s, ts_s=TS_S)
    if excitation == "ampc":
        from fmu_controller.displacement_control import P0_TABLE5, ControllerSettings, DisplacementController
        from fmu_controller.preliminary_model import THETA0_44N
        from fmu_controller.reference import SineReference
        from tapmuscle.closed_loop import run_closed_loop

        # the recordings' controller is fixed with them: Eq. (18) without the anti-windup hold, no
        # start-up guard
        ctrl = DisplacementController(ControllerSettings(method="ampc_servo", p0=P0_TABLE5, anti_windup=False,
                                                         startup_guard=False), THETA0_44N)
        cols = run_closed_loop(plant, ctrl, SineReference(frequency_hz=frequency_hz), duration_s=duration_s, watch=False)
        return {k: cols[k] for k in ("t_s", "u_v", "l_mm", "p_mpa", "load_n", "r_mm")}
    raise ValueError(f"unknown excitation {excitation!r}; known: {', '.join(EXCITATIONS)}")


def run_case(case: Case, workdir: str | Path, *, plots: bool = False, fig20_model: PlantParams | None = None,
             keep: bool = False) -> dict[str, Any]:
    """Make the recording of ``case``, write it as CSV, diagnose the CSV alone, score the result.

    Parameters
    ----------
    case : Case
        The case.
    workdir : str or Path
        The case's files go into ``workdir / case.name``.
    plots : bool, optional
        Write the diagnosis's figures; default False.
    fig20_model : PlantParams, optional
        The model handed over for a case of ``model = "fig20"`` (:func:`calibrate_without_rate`).
    keep : bool, optional
        Keep every file of the case; default False: only ``diagnosis.json``, ``report.md`` and
        the figures.
    """
    from tapmuscle.diagnosis.report import diagnose_files

    workdir = Path(workdir)
    model = fig20_model if case.model == "fig20" else DEMO_MODEL
    rig = (PlantParams() if case.model == "fig20" else DEMO_MODEL).with_values(**case.overrides)
    cols = record(rig, case.excitation, case.seed, frequency_hz=case.frequency_hz)
    folder = workdir / case.name
    rec_path = folder / "recording.csv"
    plant_path = folder / "plant.json"
    write_recording(rec_path, Recording(cols, {"ts_s": f"{TS_S:g}", "source": "tapmuscle demo-mismatch"}))
    atomic_write_text(plant_path, plant_file_text(model, "the demo's calibrated plant model"))
    # the concealed-effect proof hands over the exact model: it proves the effect search alone
    d, doc = diagnose_files(rec_path, plant_path, folder, plots=plots, calibration=None)
    # the concealed effect's cost: held-out fit of the true rig (noise-free) against the model's
    train, test = interleaved_split(len(cols["t_s"]), TS_S, BLOCK_S)
    y_true = Simulator(cols["u_v"], TS_S, cols["load_n"]).run(rig)[0]
    fit_true = fit_percent(cols["l_mm"], y_true, test)
    top = doc["findings"][0]["effect"] if doc["findings"] else "none"
    result = {"case": case.name, "effect": case.effect, "level": case.level, "excitation": case.excitation,
              "seed": case.seed, "model": case.model, "concealed": case.overrides, "verdict": doc["verdict"],
              "top_finding": top, "findings": [f["effect"] for f in doc["findings"]],
              "correct": top == case.effect if case.effect != "none" else doc["verdict"] == "no_significant_mismatch",
              "fit_before_percent": doc["fit_before_percent"], "fit_after_percent": doc["fit_after_percent"],
              "fit_true_percent": fit_true, "cost_points": fit_true - doc["fit_before_percent"],
              "gain_points": doc["fit_after_percent"] - doc["fit_before_percent"],
              "elapsed_s": doc["elapsed_s"], "fitted_parameters": (doc["findings"][0]["parameters"] if doc["findings"] else {})}
    if case.true_window is not None:
        located = [(w["t_start_s"], w["t_end_s"]) for f in doc["findings"] if f["effect"] == case.effect
                   for w in f["located"]]
        result["true_window"] = list(case.true_window)
        result["iou"] = iou(located, [case.true_window])
    if not keep:
        for name in os.listdir(folder):
            if name not in ("diagnosis.json", "report.md") and not name.endswith(".png"):
                (folder / name).unlink()
    return result


def _run(args: tuple[Case, str, bool, PlantParams | None, bool]) -> dict[str, Any]:
    case, workdir, plots, fig20, keep = args
    try:
        return run_case(case, workdir, plots=plots, fig20_model=fig20, keep=keep)
    except Exception as exc:  # noqa: BLE001 - a failing case is scored as failed, with its error
        return {"case": case.name, "effect": case.effect, "level": case.level, "excitation": case.excitation,
                "seed": case.seed, "correct": False, "error": f"{type(exc).__name__}: {exc}"}


def run_demo(out: str | Path, *, seeds: int = 3, clean_seeds: int = 20, jobs: int | None = None,
             effects: tuple[str, ...] | None = None, excitations: tuple[str, ...] = EXCITATIONS,
             levels: tuple[int, ...] = (0, 1, 2),
             progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Run the whole proof (module docstring); returns the scores (also ``out/scores.json``, ``scores.md``).

    Parameters
    ----------
    out : str or Path
        Output folder.
    seeds : int, optional
        Seeds per effect, level and excitation; default 3.
    clean_seeds : int, optional
        Clean recordings (no effect); default 20.
    jobs : int, optional
        Worker processes; default all cores.
    effects, excitations, levels : optional
        The suite's rows, as :func:`concealed_cases` takes them.
    progress : callable, optional
        ``progress(done, total)`` as cases finish.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cases = concealed_cases(seeds, effects=effects, excitations=excitations, levels=levels)
    clean = [Case("none", 0, excitations[i % len(excitations)], i, {}) for i in range(clean_seeds)]
    window = Case("supply_pressure_variation", 1, "sine", 0,
                  {"supply_variation.sag_mpa": 0.03, "supply_variation.start_s": 60.0, "supply_variation.end_s": 90.0},
                  (60.0, 91.0))
    # Fig. 20: the model calibrated on a 0.1 Hz recording of the rig with rate dependence switched off
    cal = record(PlantParams(), "sine", 99, frequency_hz=0.1)
    fig20_model = calibrate_without_rate(cal["u_v"], cal["l_mm"], TS_S)
    fig20 = Case("rate_dependent_hysteresis", 1, "sine", 0, {}, model="fig20", frequency_hz=0.2)
    special = [(window, True), (fig20, True)]
    work = out / "cases"
    jobs = jobs or os.cpu_count() or 1
    tasks = [(c, str(out / "showcase"), True, fig20_model, True) for c, _ in special] + \
            [(c, str(work), False, None, False) for c in cases + clean]
    results: list[dict[str, Any]] = []
    if progress is not None:
        progress(0, len(tasks))
    with process_pool(jobs, f"jobs={jobs}") as pool:
        for i, r in enumerate(pool.map(_run, tasks), 1):
            results.append(r)
            if progress is not None:
                progress(i, len(tasks))
    showcase, rest = results[:2], results[2:]
    concealed, clean_results = rest[:len(cases)], rest[len(cases):]
    scores = _scores(concealed, clean_results, showcase)
    atomic_write_text(out / "scores.json", json.dumps({"scores": scores, "cases": results,
                                                       "fig20_model": fig20_model.friction.__dict__,
                                                       **produced_by()}, indent=2,
                                                      default=str) + "\n")
    atomic_write_text(out / "scores.md", scores_markdown(scores))
    return scores


def _scores(concealed: list[dict], clean: list[dict], showcase: list[dict]) -> dict[str, Any]:
    per_effect: dict[str, dict[str, Any]] = {}
    for r in concealed:
        e = per_effect.setdefault(r["effect"], {"cases": 0, "correct": 0, "costly": 0, "costly_gain_ok": 0,
                                               "errors": 0, "confused_with": {}})
        e["cases"] += 1
        e["correct"] += bool(r["correct"])
        if "error" in r:
            e["errors"] += 1
            continue
        if not r["correct"]:
            e["confused_with"][r["top_finding"]] = e["confused_with"].get(r["top_finding"], 0) + 1
        if r["cost_points"] >= 3.0:
            e["costly"] += 1
            e["costly_gain_ok"] += r["gain_points"] >= 3.0
    n = len(concealed)
    costly = sum(e["costly"] for e in per_effect.values())
    visible = [r for r in concealed if r.get("cost_points", 0.0) >= VISIBLE_POINTS]
    window, fig20 = showcase
    return {
        "concealed_cases": n,
        "correct_top_finding_percent": _percent(sum(e["correct"] for e in per_effect.values()), n),
        "visible_cases": len(visible),
        "correct_top_finding_visible_percent": _percent(sum(bool(r["correct"]) for r in visible), len(visible)),
        "costly_cases": costly,
        "costly_with_gain_3_points_percent": _percent(sum(e["costly_gain_ok"] for e in per_effect.values()), costly),
        "per_effect": per_effect,
        "clean_cases": len(clean),
        "clean_no_significant_mismatch_percent": _percent(sum(bool(r["correct"]) for r in clean), len(clean)),
        "window_case": window, "fig20_case": fig20,
    }


def _percent(k: int, n: int) -> float | None:
    """``k`` of ``n`` in percent; None when there is nothing to count (``scores.json`` stays strict JSON)."""
    return 100.0 * k / n if n else None


def _share(percent: float | None, n: int, what: str) -> str:
    """``**87.5 %** of 8 <what>``, or ``no <what>`` when none were run."""
    return f"**{percent:.1f} %** of {n} {what}" if percent is not None else f"no {what}"


def scores_markdown(s: dict[str, Any]) -> str:
    """The scores table docs/diagnosis.md shows."""
    lines = ["| concealed effect | cases | correct top finding | cost >= 3 points | ... with gain >= 3 points | confused with |",
             "|---|---|---|---|---|---|"]
    for name, e in s["per_effect"].items():
        conf = ", ".join(f"{k} ({v})" for k, v in sorted(e["confused_with"].items(), key=lambda kv: -kv[1])) or "-"
        lines.append(f"| `{name}` | {e['cases']} | {e['correct']} ({100 * e['correct'] / e['cases']:.0f} %) | "
                     f"{e['costly']} | {e['costly_gain_ok']} | {conf} |")
    w, f = s["window_case"], s["fig20_case"]
    lines += ["", f"* correct top finding: {_share(s['correct_top_finding_percent'], s['concealed_cases'], 'concealed-effect recordings')} "
              f"(target >= 90 %); {_share(s['correct_top_finding_visible_percent'], s['visible_cases'], 'recordings')} "
              f"where the effect costs >= {VISIBLE_POINTS} points of held-out fit (the others leave nothing above the "
              f"noise to find)",
              f"* held-out gain >= 3 points where the effect cost >= 3 points: "
              f"{_share(s['costly_with_gain_3_points_percent'], s['costly_cases'], 'recordings')} (target 100 %)",
              f"* clean recordings judged `no_significant_mismatch`: "
              f"{_share(s['clean_no_significant_mismatch_percent'], s['clean_cases'], 'clean recordings')} (target >= 95 %)",
              f"* supply sag 60-90 s: top finding `{w.get('top_finding')}`, located IoU **{w.get('iou', float('nan')):.2f}** "
              f"(target >= 0.5)",
              f"* Fig. 20 case (model calibrated at 0.1 Hz without rate dependence, 0.2 Hz recording): top finding "
              f"`{f.get('top_finding')}`, fit {f.get('fit_before_percent', float('nan')):.2f} % -> "
              f"{f.get('fit_after_percent', float('nan')):.2f} %", ""]
    return "\n".join(lines)
