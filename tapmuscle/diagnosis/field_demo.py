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
(fresh noise) and re-diagnosed among the alternatives, with the plant the diagnosis wrote for it
(``discriminate_plant.json``: its calibrated constants, the alternatives off): does it pick the right one?

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
from concurrent.futures import FIRST_COMPLETED, Future, wait
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from tapmuscle.io.plant_file import plant_file_text
from tapmuscle.io.recording import Recording, atomic_write_text, read_recording, write_recording

from tapmuscle.diagnosis.diagnose import BLOCK_S
from tapmuscle.diagnosis.field_cases import (CATEGORIES, CATEGORY_MIX, DURATION_S, EFFECT_RANGES, EXCITATIONS,
                                             FIELD_ERROR_PARAMETERS, INCOMPATIBLE_PAIRS, LOADS_N, OOV_KINDS, TS_S,
                                             FieldCase, compatible_pairs, effect_costs, field_cases,
                                             parameter_value, record_case, vocabulary)
from tapmuscle.diagnosis.simulation import process_pool
from tapmuscle.provenance import produced_by

__all__ = ["FIELD_ERROR_PARAMETERS", "CATEGORY_MIX", "CATEGORIES", "EXCITATIONS", "OOV_KINDS", "LOADS_N",
           "EFFECT_RANGES", "INCOMPATIBLE_PAIRS", "TARGETS", "FIT_AFTER_PERCENT", "VISIBLE_POINTS",
           "DURATION_S", "TS_S", "FieldCase", "vocabulary", "compatible_pairs", "field_cases",
           "record_case", "run_field_case", "run_field_demo", "score_results", "scores_markdown",
           "confusion_figure"]

# ------------------------------------------------------------------------------------- settings
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
#: The discriminating experiment's folder inside a case's folder.
DISCRIMINATE_DIR = "discriminate"
#: A finished case's result in its folder (what ``resume`` reuses).
RESULT_FILE = "result.json"
#: What a case's folder keeps (the recording CSVs are deleted unless ``keep``).
KEPT_FILES = ("diagnosis.json", "report.md")


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
            true = parameter_value(truth, str(key))
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


def _diagnose(rec: Path, plant: Path, folder: Path, effects: Sequence[str] | None = None, *,
              use_pressure: bool = False) -> dict[str, Any]:
    from tapmuscle.diagnosis.report import diagnose_files

    opts: dict[str, Any] = {"plots": False, "use_pressure": use_pressure}
    if effects is not None:
        try:
            return diagnose_files(rec, plant, folder, effects=list(effects), **opts)[1]
        except TypeError as exc:
            if "effects" not in str(exc):
                raise
            # a diagnosis without the keyword: the re-diagnosis tries every candidate
    return diagnose_files(rec, plant, folder, **opts)[1]


def _tidy(folder: Path, keep: bool) -> None:
    """Delete the case's files but :data:`KEPT_FILES` (unless ``keep``), and say so in its report, which
    names some of them (the designed experiment, the calibrated plant) as files to use."""
    if keep or not folder.is_dir():
        return
    gone = sorted(p.name for p in folder.iterdir() if p.is_file() and p.name not in KEPT_FILES)
    for name in gone:
        (folder / name).unlink()
    report = folder / "report.md"
    if gone and report.is_file():
        atomic_write_text(report, report.read_text(encoding="utf-8").rstrip("\n") + "\n\n---\n"
                          f"demo-mismatch deleted this case's other files ({', '.join(gone)}) to save space; "
                          "`tapmuscle demo-mismatch --keep-files` keeps them.\n")


def _discriminate(case: FieldCase, doc: dict[str, Any], folder: Path, plant_path: Path,
                  end_stop_mm: float | None, keep: bool, use_pressure: bool = False) -> dict[str, Any] | None:
    """The discriminating experiments of an ``ambiguous`` verdict, run on the truth and re-diagnosed.

    Each ambiguous group's experiment is run as the report tells a user to: its input recorded on
    the rig (a fresh noise seed per group), then diagnosed from the plant the diagnosis wrote for it
    among that group's alternatives. The verdict is right when every group's re-diagnosis names
    exactly the truth's effects among its alternatives (none, for a group without one) and is not
    ambiguous again (a group without an input is not). ``groups`` holds each group's run; the keys
    beside it are the first re-diagnosed group's, with ``picked`` and ``right`` over all groups.
    """
    groups = [g for g in (doc.get("ambiguous") or []) if isinstance(g, dict)]
    if doc.get("verdict") != "ambiguous" and not groups:
        return None
    group_alternatives = [sorted({str(a.get("effect")) for a in (g.get("alternatives") or []) if isinstance(a, dict)})
                          for g in groups]
    alternatives = sorted({a for alts in group_alternatives for a in alts})
    truth = set(case.effects)
    out: dict[str, Any] = {"alternatives": alternatives, "true_alternatives": sorted(truth & set(alternatives))}
    runs = []
    for i, (g, alts) in enumerate(zip(groups or [{}], group_alternatives or [alternatives])):
        name = g.get("discriminating_input") or ("discriminating_input.csv" if i == 0 else None)
        path = folder / str(name) if name and (folder / str(name)).is_file() else None
        base = g.get("discriminate_plant")
        plant = folder / str(base) if base and (folder / str(base)).is_file() else plant_path
        sub = folder / (DISCRIMINATE_DIR if i == 0 else f"{DISCRIMINATE_DIR}_{i + 1}")
        runs.append(_rediagnosed(case, path, plant, sub, alts, truth, i, end_stop_mm, keep, use_pressure))
    done = [r for r in runs if r["input_written"]]
    out["input_written"] = bool(done)
    if not done:
        return out
    out.update({k: v for k, v in done[0].items() if k not in ("alternatives", "true_alternatives", "input_written")})
    out["picked"] = sorted({a for r in runs for a in r.get("picked", [])})
    out["right"] = all(r.get("right", False) for r in runs)
    out["groups"] = runs
    return out


def _rediagnosed(case: FieldCase, path: Path | None, plant: Path, sub: Path, alternatives: list[str], truth: set[str],
                 index: int, end_stop_mm: float | None, keep: bool, use_pressure: bool) -> dict[str, Any]:
    """One group's experiment (the input at ``path``) recorded on the truth and diagnosed from ``plant``
    among ``alternatives`` in ``sub``."""
    from tapmuscle.io.signals import parse_input_spec

    truth_in = sorted(truth & set(alternatives))
    out: dict[str, Any] = {"alternatives": alternatives, "true_alternatives": truth_in, "input_written": path is not None}
    if path is None:
        return out
    stim = read_recording(path)
    ts = stim.ts_s
    duration = float(stim.t_s[-1] - stim.t_s[0])
    signal = parse_input_spec(f"csv:{path}", run_duration_s=duration, run_ts_s=ts)
    cols = record_case(case, signal=signal, duration_s=duration, ts_s=ts,
                       noise_seed=case.noise_seed + 1 + index, end_stop_mm=end_stop_mm)
    rec = sub / "recording.csv"
    write_recording(rec, Recording(cols, {"ts_s": f"{ts:g}", "source": "tapmuscle demo-mismatch (discriminating input)"}))
    doc2 = _diagnose(rec, plant, sub, alternatives or None, use_pressure=use_pressure)
    c2 = _claims(doc2)
    picked = sorted(_named(c2["findings"], c2["ambiguous"]) & set(alternatives))
    out.update({"duration_s": duration, "verdict": c2["verdict"], "findings": c2["findings"],
                "ambiguous": c2["ambiguous"], "picked": picked,
                "right": picked == truth_in and not c2["ambiguous"],
                "fit_before_percent": doc2.get("fit_before_percent"), "fit_after_percent": doc2.get("fit_after_percent")})
    _tidy(sub, keep)
    return out


def _named(findings: Sequence[str], ambiguous: Sequence[Sequence[str]]) -> set[str]:
    """The effects a verdict names: its findings' (not ``unexplained``) and every ambiguous alternative."""
    return {e for e in findings if e != "unexplained"} | {a for g in ambiguous for a in g}


def run_field_case(case: FieldCase, workdir: str | Path, *, keep: bool = False,
                   use_pressure: bool = False) -> dict[str, Any]:
    """Record the case's truth, write the CSV and the nominal model's plant file, diagnose, score.

    Parameters
    ----------
    case : FieldCase
    workdir : path
        The case's folder is ``workdir / case.name``; it keeps ``diagnosis.json`` and ``report.md``
        (and those of each ambiguous group's discriminating experiment in ``discriminate/``,
        ``discriminate_2/``, ...); the CSVs and the plant files are deleted unless ``keep``. A case
        that raises keeps them, for a look at what failed.
    keep : bool, optional
        Keep the recordings and plant files; default False.
    use_pressure : bool
        Diagnose with the recorded pressure beside the displacement (``diagnose(use_pressure=True)``).

    Returns
    -------
    dict
        The truth (:meth:`FieldCase.describe`), what the diagnosis claimed (``verdict``, ``findings``,
        ``ambiguous`` as lists of alternatives), its held-out fits, the costs (:func:`effect_costs`), the
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
    doc = _diagnose(rec_path, plant_path, folder, use_pressure=use_pressure)
    claims = _claims(doc)
    result: dict[str, Any] = {**case.describe(), **claims,
                              "named": sorted(_named(claims["findings"], claims["ambiguous"])),
                              "fit_before_percent": doc.get("fit_before_percent"),
                              "fit_after_percent": doc.get("fit_after_percent"),
                              "end_stop_mm": end_stop_mm,
                              "diagnosis_elapsed_s": doc.get("elapsed_s"), "use_pressure": use_pressure}
    # the truth's fits on the held-out blocks of the diagnosis's own split
    block_s = (doc.get("split") or {}).get("block_s") or BLOCK_S
    result.update(effect_costs(case, cols, end_stop_mm, block_s=block_s))
    result["calibration_check"] = _calibration_check(doc, case)
    try:
        result["discrimination"] = _discriminate(case, doc, folder, plant_path, end_stop_mm, keep, use_pressure)
    except Exception as exc:  # noqa: BLE001 - the first diagnosis stands; the experiment's failure is reported
        result["discrimination"] = {"input_written": True, "error": f"{type(exc).__name__}: {exc}"}
    result["elapsed_s"] = time.monotonic() - t0
    _tidy(folder, keep)
    atomic_write_text(folder / RESULT_FILE, json.dumps(result, indent=2, default=_json_default) + "\n")
    return result


def _stored_result(case: FieldCase, workdir: Path, use_pressure: bool = False) -> dict[str, Any] | None:
    """The case's stored result if an earlier run finished it with the same truth and the same
    ``use_pressure`` (else None)."""
    path = workdir / case.name / RESULT_FILE
    try:
        stored = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    truth = json.loads(json.dumps(case.describe(), default=_json_default))
    same = all(stored.get(k) == v for k, v in truth.items()) and bool(stored.get("use_pressure")) == use_pressure
    return stored if same else None


def _run_safe(args: tuple[FieldCase, str, bool, bool]) -> dict[str, Any]:
    case, workdir, keep, use_pressure = args
    try:
        return run_field_case(case, workdir, keep=keep, use_pressure=use_pressure)
    except Exception as exc:  # noqa: BLE001 - a failing case is scored as failed, with its error
        return {**case.describe(), "error": f"{type(exc).__name__}: {exc}"}


# ------------------------------------------------------------------------------------ the suite
def run_field_demo(out: str | Path, *, n: int = 120, seed: int = 0, jobs: int | None = None,
                   duration_s: float = DURATION_S, keep: bool = False, resume: bool = False,
                   progress: Callable[..., None] | None = None, heartbeat_s: float = 5.0,
                   use_pressure: bool = False) -> dict[str, Any]:
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
    heartbeat_s : float, optional
        Longest time between two calls of ``progress`` while cases run [s]; default 5.
    use_pressure : bool
        Diagnose with the recorded pressure beside the displacement (``diagnose(use_pressure=True)``).

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
            stored = _stored_result(c, out / "cases", use_pressure)
            if stored is not None:
                results[c.index] = stored
    todo = [c for c in cases if c.index not in results]
    with process_pool(max(1, min(jobs, len(todo))), f"jobs={jobs}") as pool:
        pending: dict[Future, FieldCase] = {pool.submit(_run_safe, (c, str(out / "cases"), keep, use_pressure)): c
                                            for c in todo}
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
                "use_pressure": use_pressure,
                "resumed_cases": len(cases) - len(todo),
                "vocabulary": list(vocabulary()), "wall_s": time.monotonic() - t0}
    scores["settings"] = settings
    atomic_write_text(out / "scores.json", json.dumps({"scores": scores, "cases": ordered, **produced_by()}, indent=2,
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

    Parameters
    ----------
    results : sequence of dict
        Per-case results of :func:`run_field_case` (a failed case's with an ``error``).

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
    """The scores as markdown (``scores.md``, and what ``tapmuscle demo-mismatch`` prints).

    Parameters
    ----------
    s : dict
        The scores (:func:`score_results`).
    """
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
    """Heat map of the confusion table (share of each row's cases claiming each column), counts written in.

    Parameters
    ----------
    s : dict
        The scores (:func:`score_results`).
    path : str or Path
        The figure to write.
    """
    from matplotlib.patches import Rectangle

    from tapmuscle.plots.figures import new_figure, save_figure

    conf = s["confusion"]
    rows = [r for r in conf["rows"] if conf["cases"][r]]
    cols = conf["columns"]
    share = np.array([[conf["counts"][r][c] / conf["cases"][r] for c in cols] for r in rows]) if rows else np.zeros((1, len(cols)))
    fig, ax = new_figure(figsize=(1.0 + 0.62 * len(cols), 1.4 + 0.42 * max(len(rows), 1)))
    im = ax.imshow(share, cmap="Blues", vmin=0.0, vmax=1.0, aspect="auto")
    for i, r in enumerate(rows):
        for j, c in enumerate(cols):
            k = conf["counts"][r][c]
            if k:
                ax.text(j, i, str(k), ha="center", va="center", fontsize=8,
                        color="white" if share[i, j] > 0.6 else "black")
    ax.set_xticks(range(len(cols)), [c.replace("_", " ") for c in cols], rotation=40, ha="right", fontsize=8)
    ax.set_yticks(range(len(rows)), [f"{r.replace('_', ' ')} ({conf['cases'][r]})" for r in rows], fontsize=8)
    # the correct column of each row, outlined: what a perfect diagnosis would fill
    for i, r in enumerate(rows):
        want = ("nothing" if r == "none" else r.split(": ", 1)[1] if r.startswith("single: ")
                else "unexplained" if r.startswith("oov: ") else None)
        if want in cols:
            j = cols.index(want)
            ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="tab:orange", lw=1.6))
    ax.set_xlabel("claimed by the diagnosis (orange box: the right answer; the pair row's two differ by case)")
    ax.set_ylabel("truth (cases)")
    t = s["targets"]
    ax.set_title(f"Field recordings: {s['recordings']}; named {_pct(t['single_named']['rate_percent'])}, "
                 f"alone {_pct(t['single_named_alone']['rate_percent'])}, pairs {_pct(t['pair_both_found']['rate_percent'])}, "
                 f"none {_pct(t['none_no_effect_claimed']['rate_percent'])}, oov {_pct(t['oov_unexplained']['rate_percent'])}",
                 fontsize=9)
    # a case may claim several effects: a row's shares can add up to more than 1
    fig.colorbar(im, ax=ax, fraction=0.03, pad=0.02, label="share of the row's cases claiming it")
    return save_figure(fig, path)
