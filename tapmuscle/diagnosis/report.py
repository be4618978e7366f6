"""Files of a diagnosis: ``diagnosis.json``, the calibrated plant file, ``report.md`` and the figures;
and :func:`diagnose_files`, the recording-file-in, report-out entry point ``tapmuscle diagnose`` and
``tapmuscle demo-mismatch`` share. Every file is written atomically.
"""

from __future__ import annotations

import json
import os
import shlex
from concurrent.futures import Executor
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from fmu_controller.displacement_control import MAX_INPUT_DELAY_SAMPLES
from fmu_controller.loop_watch import horizon_past_delay
from fmu_controller.prediction import delay_samples_for
from fmu_controller.servo_settings import TABLE5_SERVO
from fmu_plant import PlantParams

from tapmuscle.plots.figures import input_jumps, loop_line, new_figure, save_figure
from tapmuscle.errors import TapmuscleError
from tapmuscle.io.atomic import staged_folder
from tapmuscle.io.plant_file import plant_file_text
from tapmuscle.io.recording import Recording, RecordingError, atomic_write_text, read_recording

from tapmuscle.diagnosis.candidates import CANDIDATES, Candidate
from tapmuscle.diagnosis.diagnose import MATERIAL_EFFECT_FACTOR, MATERIAL_FACTOR, Diagnosis, diagnose
from tapmuscle.diagnosis.experiment_design import U_MIN_V, U_MAX_V, design_input, write_experiment
from tapmuscle.diagnosis.model_space import MUSCLE, MuscleSpace
from tapmuscle.diagnosis.residual_analysis import STRUCTURE_ALPHA, STRUCTURE_MATERIALITY, unstructured_reason
from tapmuscle.io.atomic import probe_output_folder
from tapmuscle.diagnosis.plant_source import load_plant, simulate_plant_fmu
from tapmuscle.diagnosis.simulation import worker_pool
from tapmuscle.provenance import produced_by

__all__ = ["diagnose_files", "write_outputs", "finite_json", "json_text", "summary_lines", "overlay_figure", "OUTPUT_FILES",
           "EXPERIMENT_FILE", "EXPERIMENT_PLANT_FILE", "OWNED_FILES"]

#: What ``write_outputs`` writes (figures only with ``plots=True``).
OUTPUT_FILES = ("diagnosis.json", "calibrated_plant.json", "report.md", "residual.png", "overlay.png",
                "hysteresis.png", "residual_tests.png")
#: Written as well when the verdict is ``ambiguous`` (one per ambiguous group, numbered from the second).
EXPERIMENT_FILE = "discriminating_input.csv"
#: With it: the plant to re-diagnose the experiment's recording with (the calibrated plant, the group's effects off).
EXPERIMENT_PLANT_FILE = "discriminate_plant.json"
#: The files of an output folder that a diagnosis owns: written anew or removed by each diagnosis into it.
#: Only the names a diagnosis writes (the experiments numbered 2-99): a file of one's own beside them,
#: such as the experiment's recording saved as ``discriminating_input_run.csv``, is kept.
OWNED_FILES = OUTPUT_FILES + tuple(f"{stem}{number}.{suffix}" for stem, suffix in
                                   (("discriminating_input", "csv"), ("discriminate_plant", "json"))
                                   for number in ("", "_[2-9]", "_[1-9][0-9]"))

#: Located windows of a finding the console summary lists, at most (the rest are in ``diagnosis.json``).
SUMMARY_WINDOWS = 10

#: The located windows' shades, none a residual line's colour (grey, green, blue), and a hatch each
#: after the first: windows of two findings that overlap show both (a blend of two tints named neither).
_COLOURS = ("tab:red", "tab:purple", "tab:orange", "tab:brown", "tab:olive")
_HATCHES = ("", "//", "\\\\", "..", "xx")


def summary_lines(d: Diagnosis) -> list[str]:
    """The short human summary ``tapmuscle diagnose`` prints.

    Parameters
    ----------
    d : Diagnosis
        The diagnosis.
    """
    if d.verdict == "no_significant_mismatch":
        t = d.tests_before
        if t["structured"]:
            # the model taken as it is (no calibration, or none kept) leaves a structure below the
            # materiality level of a finding
            why = (f"a structured residual below the materiality level remains (whiteness p = {t['whiteness_p']:.2g}, "
                   f"RMS {t['rms_mm']:.4f} {d.unit} against {t['noise_reference_mm']:.4f} {d.unit} of noise, "
                   f"< {MATERIAL_FACTOR:g} x); reported, not claimed")
        else:
            why = unstructured_reason(t, d.unit)
            sizes = f", RMS {t['rms_mm']:.4f} {d.unit}, noise {t['white_noise_mm']:.4f} {d.unit}" if why == "residual white" else ""
            why = f"{why} (whiteness p = {t['whiteness_p']:.2g}{sizes})"
        return [f"no significant mismatch: {why}; held-out fit {d.fit_before_percent:.2f} %"]
    out = []
    if d.calibration is not None:
        changed = ", ".join(f"{r.parameter} {r.nominal:.4g} -> {r.estimate:.4g}{' (at its bound)' if r.at_bound else ''}"
                            for r in d.calibration.rows
                            # relative: a constant of 1e-5 (a compliance in m^3/MPa) moves by less than 1e-9
                            if r.identifiable and abs(r.estimate - r.nominal) > 1e-9 * abs(r.nominal))
        # the constants are the final model's (re-fitted with the effects found); the fit is the first
        # calibration's, before any effect: said so, as the two can differ much
        final = " (in the final model, re-fitted with the effects)" if d.named or d.ambiguous else ""
        # a fit that falls: the training blocks' constants do not carry to the held-out ones without
        # the effects (the first calibration stretches them to take up what an effect does)
        worse = (" (lower: the constants fitted to the training blocks without the effects below do not carry to "
                 "the held-out ones)" if d.fit_calibrated_percent is not None
                 and d.fit_calibrated_percent < d.fit_before_percent else "")
        out.append(f"calibration: held-out fit {d.fit_before_percent:.2f} % -> {d.fit_calibrated_percent:.2f} % "
                   f"without any effect{worse}; constants{final}: {changed or 'none changed'}; not identifiable: "
                   f"{', '.join(r.parameter for r in d.calibration.rows if not r.identifiable) or 'none'}")
    immaterial = _immaterial_remainder(d)
    remainder = [] if immaterial is None else [f"  {immaterial}"]
    rem = d.unexplained
    if d.verdict == "calibration_only":
        after = d.tests_after
        if rem is not None:
            white = "residual within the materiality level"
        else:
            white = unstructured_reason(after, d.unit)
        return out + [f"calibration only: the recalibrated plant explains the recording ({white}, "
                      f"whiteness p = {d.tests_after['whiteness_p']:.2g}); no left-out effect is claimed"] + remainder
    for group in d.ambiguous:
        out.append(f"ambiguous: {' / '.join(a.effect for a in group)} explain the recording equally well on "
                   f"held-out data (fits {', '.join(f'{a.fit_after_percent:.2f} %' for a in group)}); "
                   f"see discriminating_input.csv; {_kept_alternative(d, group)}")
    out.append(f"{d.verdict}: held-out fit {d.fit_before_percent:.2f} % -> {d.fit_after_percent:.2f} % with "
               f"{', '.join(d.named) or 'no candidate effect claimed'}")
    for i, f in enumerate(d.findings, 1):
        where = _windows_text(f.located)
        # signed: on all held-out blocks it can be below 0 where the acceptance, judged on the blocks
        # its significance test uses, was clear
        gain = f" ({f.fit_gain_points:+.2f} points)" if f.effect != "unexplained" else ""
        out.append(f"  {i}. {f.effect}{gain}: {f.explanation}; located {where}; {f.regime}")
    delay = _named_delay_s(d)
    return out + ([f"  {delay_advice(delay, d.ts_s)}"] if delay else []) + remainder


def _named_delay_s(d: Diagnosis) -> float | None:
    """The transport delay [s] the findings name, if any."""
    return next((f.parameters.get("delay.delay_s") for f in d.findings if f.effect == "transport_delay"), None)


def delay_advice(delay_s: float, ts_s: float) -> str:
    """What the displacement controller needs for a transport delay of ``delay_s`` [s] at the
    sampling period ``ts_s`` [s]: its ``input_delay_samples``, in whole samples (a delay between two,
    the longer, which the servo methods track better with and the controller's own decision takes:
    docs/control.md, "Transport delay"), and where to set it; beyond
    :data:`~fmu_controller.displacement_control.MAX_INPUT_DELAY_SAMPLES`, that it cannot."""
    n = delay_s / ts_s
    k = delay_samples_for(delay_s, ts_s)
    whole = abs(n - round(n)) <= 0.25  # a whole number of samples, not the longer of two
    if k == 0:
        return (f"for control: the delay is {n:.2f} samples at Ts = {ts_s:g} s, under a quarter of a sample: the "
                "controller needs no input_delay_samples for it")
    if k > MAX_INPUT_DELAY_SAMPLES:
        return (f"for control: the delay is {n:.1f} samples at Ts = {ts_s:g} s, more than the controller compensates "
                f"(input_delay_samples up to {MAX_INPUT_DELAY_SAMPLES}); shorten it on the rig (docs/control.md, "
                "\"Transport delay\")")
    between = "" if whole else (f" ({n:.2f} samples: the longer of {k - 1} and {k}, which the servo methods track "
                                "better with and input_delay_samples = -1 decides)")
    horizon = horizon_past_delay(TABLE5_SERVO["hp"], ts_s, k)  # the servo methods' default horizon
    return (f"for control: set the controller's input_delay_samples = {k} at Ts = {ts_s:g} s{between}, with a theta0 "
            f"identified under it (tapmuscle identify --input-delay-samples {k}, whose file gives a scenario both); "
            "tapmuscle run with a plant file alone leaves it at 0 (docs/control.md, \"Transport delay\")"
            + (f"; for the servo methods, Table 5's {horizon}" if horizon else ""))


def _windows_text(located: Sequence[tuple[float, float]]) -> str:
    """The first :data:`SUMMARY_WINDOWS` of a finding's located windows [s], and how many more
    ``diagnosis.json`` lists: a long recording's effect is located in hundreds of windows, which on
    one console line would bury the verdict."""
    shown = ", ".join(f"{a:.0f}-{b:.0f} s" for a, b in located[:SUMMARY_WINDOWS]) or "nowhere in particular"
    more = len(located) - SUMMARY_WINDOWS
    return shown + (f", ... +{more} more in diagnosis.json" if more > 0 else "")


def _immaterial_remainder(d: Diagnosis) -> str | None:
    """The structured remainder below the materiality level that no finding claims, in words (None
    when there is none)."""
    rem = d.unexplained
    if rem is None or rem["material"]:
        return None
    return (f"a structured remainder below the materiality level: RMS {rem['rms_mm']:.4f} {d.unit} against "
            f"{rem['noise_mm']:.4f} {d.unit} of noise (< {MATERIAL_FACTOR:g} x), {100.0 * rem['share']:.4f} % of the "
            f"nominal model's excess over the noise; reported, not claimed")


def _kept_alternative(d: Diagnosis, group: list) -> str:
    """What the calibrated plant file holds of an ambiguous group: its best-scoring alternative, as the
    final joint re-fit left it (its value can differ from the alternative's own, in the table)."""
    best = next((a for a in group if not a.evidence.get("versus_best")), group[0])
    values = ", ".join(f"{k} = {d.calibrated.value(k):.4g}" for k in best.parameters)
    return (f"the calibrated plant file and the headline fit hold {best.effect} as re-fitted jointly with the "
            f"constants and the other effects ({values})")


def _interval_text(lo: float, hi: float) -> str:
    """``lo to hi`` with as many significant digits (4 to 8) as tell the two ends apart."""
    digits = next((k for k in range(4, 9) if f"{lo:.{k}g}" != f"{hi:.{k}g}"), 8)
    return f"{lo:.{digits}g} to {hi:.{digits}g}"


def _report_md(d: Diagnosis, recording: str, plant: str, fmu_check: dict[str, Any] | None,
               experiments: list[dict[str, Any]] | None = None, plots: bool = True) -> str:
    lines = [f"# Mismatch diagnosis of `{recording}`", "",
             f"Plant model: `{plant}`. Verdict: **{d.verdict}**. Held-out fit (NRMSE, interleaved "
             f"{int(d.test.sum())} of {len(d.test)} samples): **{d.fit_before_percent:.2f} % -> "
             f"{d.fit_after_percent:.2f} %**.", ""]
    if d.notes:
        lines += ["## Notes", ""] + [f"- {n}." for n in d.notes] + [""]
    if d.calibration is not None:
        lines += ["## Calibration", "",
                  f"The nominal constants the recording can identify were re-estimated first (MAP least squares on "
                  f"the training blocks, prior 20 % sd around nominal; identifiable when the data shrink the sd to "
                  f"<= 25 % of the prior's; an identifiable constant's interval includes what the constants left "
                  f"nominal may be off, within their prior). Held-out fit of the calibrated plant without any effect: "
                  f"**{d.fit_calibrated_percent:.2f} %**."
                  + (" The estimates below are those of the final model, re-fitted jointly with the effects found "
                     "(the calibrated plant file's)." if d.named or d.ambiguous else ""), "",
                  "| parameter | unit | nominal | estimate | 95 % interval | identifiable |", "|---|---|---|---|---|---|"]
        for r in d.calibration.rows:
            lines.append(f"| `{r.parameter}` | {r.unit} | {r.nominal:.5g} | {r.estimate:.5g} | "
                         f"{r.ci95[0]:.5g} .. {r.ci95[1]:.5g} | {r.identifiable_text()} |")
        lines.append("")
    for i, group in enumerate(d.ambiguous, 1):
        lines += [f"## Ambiguous ({i}): the held-out data cannot tell these apart", "",
                  "| alternative | explanation | held-out fit [%] | held-out SSE [mm^2] | vs best: SSE ratio, p |",
                  "|---|---|---|---|---|"]
        for a in group:
            vs = a.evidence.get("versus_best")
            lines.append(f"| `{a.effect}` | {a.explanation} | {a.fit_after_percent:.2f} | {a.held_out_sse_mm2:.4g} | "
                         + (f"{vs['sse_ratio']:.3f}, {vs['p_value']:.2g} |" if vs else "best |"))
        lines += ["In the table, each alternative as fitted alone; " + _kept_alternative(d, group) + ".", ""]
        if experiments and i - 1 < len(experiments):
            e = experiments[i - 1]
            lines += [f"Discriminating experiment: `{e['file']}`, {e['duration_s']:g} s of {e['input']}; the "
                      f"alternatives' predictions differ by at least {e['separation_sigma']:.0f} noise sd "
                      f"({e['min_rms_difference_mm']:.3f} mm RMS). Apply it to the rig at this recording's load "
                      f"(a simulated rig: `{e['record']}`, with the `--params` or `--set` options that made "
                      "this recording added: without them it records the nominal plant, not your rig) and "
                      f"diagnose the new recording with `{e['plant']}` "
                      f"(this calibrated plant without them) among the alternatives: `{e['rediagnose']}` (the "
                      "commands' paths are from the folder `tapmuscle diagnose` ran in, as the recording's).", ""]
    lines += ["## Findings", ""]
    if not d.findings:
        lines += [f"None: no cause is named ({_immaterial_remainder(d) or unstructured_reason(d.tests_after, d.unit)}).",
                  ""]
    else:
        lines += ["| # | effect | explanation | held-out gain [points] | located | regime |", "|---|---|---|---|---|---|"]
        for i, f in enumerate(d.findings, 1):
            where = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in f.located) or "-"
            lines.append(f"| {i} | `{f.effect}` | {f.explanation} | {f.fit_gain_points:.2f} | {where} | {f.regime} |")
        lines.append("")
        for f in d.findings:
            if f.parameters:
                lines.append(f"* `{f.effect}` parameters: " + ", ".join(
                    f"`{k}` = {v:.6g}" + (f" (95 %: {_interval_text(*f.ci95[k])})" if k in f.ci95 else "")
                    for k, v in f.parameters.items()))
        lines.append("")
        delay = _named_delay_s(d)
        if delay:
            advice = delay_advice(delay, d.ts_s)
            lines += [advice[0].upper() + advice[1:] + ".", ""]
        if any(k not in f.ci95 for f in d.findings for k in f.parameters):
            lines += ["A parameter without an interval is one only its effect's own search fits (a band's edges, a "
                      "sag's window, a map's knot inputs: the fit is piecewise constant in them).", ""]
        if any(f.ci95 for f in d.findings):
            lines += ["The 95 % intervals are linearised at the final model, jointly with the calibrated constants; "
                      "on a rig whose constants are off they can be too narrow (docs/diagnosis.md, step 9, "
                      "\"Intervals of the effects' parameters\").", ""]
        if not d.named and not d.ambiguous:
            # a residual no candidate explains: what the reader can do next
            lines += ["Next: nothing in the vocabulary explains what is left. Its location and regime above say where "
                      "the model departs from the rig; physics outside the vocabulary, or constants the recording "
                      "cannot pin there, are the usual causes. A recording that moves through that regime in other "
                      "ways (held levels, random steps, another load) separates the two; with a guess at the physics, "
                      "a candidate of your own can be tried (docs/diagnosis.md, \"A candidate of your own\").", ""]
    tb, ta = d.tests_before, d.tests_after
    lines += ["## Residual tests", "",
              "| | before | after |", "|---|---|---|",
              f"| RMS residual [mm] | {tb['rms_mm']:.4f} | {ta['rms_mm']:.4f} |",
              f"| white-noise level [mm] | {tb['white_noise_mm']:.4f} | {ta['white_noise_mm']:.4f} |",
              f"| whiteness (Ljung-Box, 25 lags) p | {tb['whiteness_p']:.2g} | {ta['whiteness_p']:.2g} |",
              f"| autocorrelation lags outside the 99 % band | {tb['autocorrelation_lags_outside']} / 25 "
              f"| {ta['autocorrelation_lags_outside']} / 25 |",
              f"| input cross-correlation lags outside the band | {tb['cross_correlation_lags_outside']} / 51 "
              f"| {ta['cross_correlation_lags_outside']} / 51 |",
              f"| structured (whiteness or zero mean rejected at p < {STRUCTURE_ALPHA:g}, and RMS > "
              f"{STRUCTURE_MATERIALITY:g} x the smaller of its own white-noise level and the sensor's) | "
              f"{tb['structured']} | {ta['structured']} |", ""]
    lines += ["## Candidates tried", "", "| round | effect | held-out gain [points] | SSE reduction | p |", "|---|---|---|---|---|"]
    for c in d.candidates:
        if c.get("joint"):
            if "rejected" in c:
                lines.append(f"| {c['round']} | `{c['effect']}` re-fitted with the calibration | not fitted ({c['rejected']}) | | |")
            else:
                lines.append(f"| {c['round']} | `{c['effect']}` re-fitted with the calibration | | "
                             f"{100 * c['held_out_sse_reduction']:.1f} % | {c['p_value']:.2g} |")
        elif c["fitted"]:
            lines.append(f"| {c['round']} | `{c['effect']}` | {c['fit_gain_points']:.3f} | "
                         f"{100 * c['held_out_sse_reduction']:.1f} % | {c['p_value']:.2g} |")
        else:  # a simulation that failed says why; otherwise its fit found nothing to gain
            why = c.get("rejected", "not applicable").replace("|", "\\|")
            lines.append(f"| {c['round']} | `{c['effect']}` | not fitted ({why}) | | |")
    lines += ["", "Columns: the held-out gain is the candidate's own fit on the model of that round, in points of "
              "held-out fit over all held-out blocks; the SSE reduction (negative: the error grew) and p are over "
              "the held-out blocks its test uses (those no accepted effect's edge touches), so the two can differ "
              "in sign; p is that of 'the held-out residual's projection on the effect's contribution is only "
              "noise'.",
              "", "An effect is accepted when, re-fitted jointly with the calibrated constants, it removes >= 10 % of "
              "the held-out squared error of the model re-fitted without it, the held-out residual's projection on "
              f"its contribution rejects 'only noise' at p < 0.001, and its contribution exceeds {MATERIAL_EFFECT_FACTOR:g} x "
              "the noise "
              "(docs/diagnosis.md).", ""]
    for step in d.selection or []:
        blocks = step.get("held_out_blocks_left_out_s")
        if blocks:
            where = ", ".join(f"{a:g}-{b:g} s" for a, b in blocks)
            what = {"add": f"added `{step.get('effect')}`", "drop": f"dropped `{step.get('effect')}`",
                    "stop": "found no further effect"}[step["step"]]
            lines += [f"The held-out tests that {what} (round "
                      f"{step['round']}) left out the held-out blocks {where}: an edge of an effect in the model lies "
                      "there, which the training blocks do not place (docs/diagnosis.md, step 5).", ""]
    if fmu_check is not None:
        lines += ["## FMU check", "", f"The plant FMU re-simulated the recording's command; it differs from the "
                  f"in-process model the fits use by at most {fmu_check['max_abs_difference_mm']:.2e} mm.", ""]
    lines += ["## Files", "", "* `calibrated_plant.json`: the model with the fitted effects; every `group.field` is a "
              "parameter of the MusclePlant FMU (set them as start values) and `tapmuscle record --params` reads it.",
              *(["* `residual.png`, `overlay.png`, `hysteresis.png`, `residual_tests.png`."] if plots else []),
              f"* {d.simulations} simulations, {d.elapsed_s:.1f} s.", ""]
    return "\n".join(lines)


def _shade(ax, d: Diagnosis) -> None:
    from matplotlib.colors import to_rgba

    for i, f in enumerate(d.findings):
        for j, (a, b) in enumerate(f.located):
            colour = _COLOURS[i % len(_COLOURS)]
            ax.axvspan(a, b, facecolor=to_rgba(colour, 0.12), edgecolor=to_rgba(colour, 0.5), lw=0,
                       hatch=_HATCHES[i % len(_HATCHES)], label=f"located: {f.effect}" if j == 0 else None)


def overlay_figure(d: Diagnosis, path: Path, *, quantity: str, unit: str, title: str, model: str = "model") -> None:
    """The recording against the model before, calibrated and after (held-out fits in the legend), and
    the held-out residuals before and after: ``overlay.png``.

    Parameters
    ----------
    d : Diagnosis
        The diagnosis.
    path : Path
        The figure to write.
    quantity : str
        The output's name, for the axis label.
    unit : str
        Its unit.
    title : str
        The figure's title.
    model : str, optional
        How the legend names the model; default ``"model"``.
    """
    t = d.t_s
    fig, (a1, a2) = new_figure(2, 1, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    a1.plot(t, d.y_mm, color="k", lw=1.0, label="recording")
    a1.plot(t, d.y_before_mm, color="0.5", lw=1.0, ls="--", label=f"{model} before ({d.fit_before_percent:.2f} %)")
    if d.y_calibrated_mm is not None:
        a1.plot(t, d.y_calibrated_mm, color="tab:green", lw=0.9, ls="-.",
                label=f"calibrated, no effect ({d.fit_calibrated_percent:.2f} %)")
    a1.plot(t, d.y_after_mm, color="tab:blue", lw=1.0, ls=":", label=f"{model} after ({d.fit_after_percent:.2f} %)")
    a1.set(ylabel=f"{quantity} [{unit}]", title=title)
    # above the title, as the residual figure's: inside, it covered the peaks compared
    a1.legend(loc="lower left", bbox_to_anchor=(0.0, 1.08), ncol=4, fontsize=8, frameon=False)
    a1.grid(alpha=0.3)
    held = np.where(d.test, 1.0, np.nan)
    a2.plot(t, (d.y_mm - d.y_before_mm) * held, color="0.4", lw=0.8, label="residual before (held-out blocks)")
    a2.plot(t, (d.y_mm - d.y_after_mm) * held, color="tab:blue", lw=0.8, label="residual after (held-out blocks)")
    a2.set(xlabel="time [s]", ylabel=f"residual [{unit}]")
    # above the panel, between the two: inside, "best" still covered a trough where both residuals ran
    a2.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, fontsize=8, frameon=False)
    a2.grid(alpha=0.3)
    save_figure(fig, path)


def _figures(d: Diagnosis, out: Path, title: str) -> None:
    t = d.t_s
    e0, e1 = d.y_mm - d.y_before_mm, d.y_mm - d.y_after_mm
    # below the residuals before, the final one on its own scale: a remainder of a few hundredths of a
    # millimetre (what "unexplained" reports) cannot be seen beside a residual of millimetres
    fig, (ax, zoom) = new_figure(2, 1, figsize=(10, 6.2), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    # three line styles: the residuals are told apart printed in grey too
    ax.plot(t, e0, lw=0.8, color="0.3", label="before")
    if d.y_calibrated_mm is not None:
        ax.plot(t, d.y_mm - d.y_calibrated_mm, lw=0.9, color="tab:green", ls="--", label="after calibration")
    if d.named or d.ambiguous:
        ax.plot(t, e1, lw=0.9, color="tab:blue", ls="-.", label="after calibration and effects")
    _shade(ax, d)
    ax.set(ylabel="residual l_meas - l_sim [mm]", title=f"{title}: residual, located windows shaded")
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.08), ncol=3, fontsize=8, frameon=False)
    ax.grid(alpha=0.3)
    final = "after calibration and effects" if d.named or d.ambiguous else (
        "after calibration" if d.y_calibrated_mm is not None else "before")
    noise = float(d.tests_after.get("noise_reference_mm", d.tests_after.get("white_noise_mm", 0.0)))
    zoom.plot(t, e1, lw=0.7, color="tab:blue")
    if noise > 0:
        zoom.axhspan(-2.0 * noise, 2.0 * noise, color="0.85", lw=0, label=f"+-2 x the noise level ({noise:.3g} mm)")
        zoom.legend(loc="upper right", fontsize=8)
    _shade(zoom, d)
    zoom.set(xlabel="time [s]", ylabel=f"residual {final}\n(own scale) [mm]")
    zoom.grid(alpha=0.3)
    save_figure(fig, out / "residual.png")

    overlay_figure(d, out / "overlay.png", quantity="displacement l", unit="mm",
                   title=f"{title}: before / after (held-out fit in brackets)")

    fig, ax = new_figure(figsize=(6, 5))
    jumps = input_jumps(d.u_v)
    # the recording on top: a model after that fits it drew over it and hid it
    ax.plot(d.u_v, d.y_before_mm, **loop_line(jumps, color="0.5", lw=0.8, ls="--", label="model before", zorder=2))
    ax.plot(d.u_v, d.y_after_mm, **loop_line(jumps, color="tab:blue", lw=1.6, alpha=0.6, label="model after",
                                              zorder=2))
    ax.plot(d.u_v, d.y_mm, **loop_line(jumps, color="k", lw=0.6, label="recording", zorder=3))
    ax.set(xlabel="valve input u(k) [V]", ylabel="displacement l(k) [mm]",
           title=f"{title}: " + ("(u, l) samples\n(the input jumps: points, not a loop)" if jumps else
                                 "hysteresis loops"))
    ax.legend(fontsize=8, markerscale=4)
    ax.grid(alpha=0.3)
    save_figure(fig, out / "hysteresis.png")

    fig, (a1, a2) = new_figure(2, 1, figsize=(8, 6))
    for key, colour, label in (("before", "0.4", "before"), ("after", "tab:blue", "after")):
        ac, xc = d.correlations[f"autocorrelation_{key}"], d.correlations[f"cross_correlation_{key}"]
        a1.stem(ac.lags + (0.15 if key == "after" else 0), ac.values, linefmt=colour, markerfmt=" ", basefmt=" ", label=label)
        a2.stem(xc.lags + (0.15 if key == "after" else 0), xc.values, linefmt=colour, markerfmt=" ", basefmt=" ", label=label)
    lag = f"lag [samples of {d.ts_s:g} s]" if d.ts_s > 0 else "lag [samples]"
    for ax, c, name, xlabel in (
            (a1, d.correlations["autocorrelation_before"], "autocorrelation of the residual", lag),
            (a2, d.correlations["cross_correlation_before"], "cross-correlation input u -> residual",
             f"{lag}; positive: the residual after the input")):
        ax.axhspan(-c.band, c.band, color="tab:orange", alpha=0.2, label="99 % band (white)")
        ax.set(title=name, ylabel="normalised", xlabel=xlabel)
        # beside the axes: inside, it covered the first lags' stems, the ones a reader looks at
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{title}: residual tests, before (the plant given) and after (the final model)", fontsize=10)
    fig.set_layout_engine("tight")  # laid out as it is drawn: inside save_figure, with its warnings
    save_figure(fig, out / "residual_tests.png")


def finite_json(doc: Any, path: str = "") -> tuple[Any, list[str]]:
    """``doc`` with every float that is not finite replaced by None (strict JSON has no NaN), and the
    paths of those replaced (``.findings[0].fit_gain_points``).

    Parameters
    ----------
    doc : object
        A JSON-like document (dicts, lists, tuples, floats, ...).
    path : str, optional
        The document's path within the whole, for the paths returned.
    """
    if isinstance(doc, float):
        return (doc, []) if np.isfinite(doc) else (None, [path or "."])
    if isinstance(doc, dict):
        pairs = [(k, finite_json(v, f"{path}.{k}")) for k, v in doc.items()]
        return {k: v for k, (v, _) in pairs}, [p for _, (_, ps) in pairs for p in ps]
    if isinstance(doc, (list, tuple)):
        items = [finite_json(v, f"{path}[{i}]") for i, v in enumerate(doc)]
        return [v for v, _ in items], [p for _, ps in items for p in ps]
    return doc, []


def json_text(doc: dict[str, Any]) -> str:
    """``doc`` as strict JSON text (indented, a final newline). A value that is not a number is
    written as null and named in the document's ``notes``: a crash there would lose the run.

    Parameters
    ----------
    doc : dict
        The document.
    """
    doc, nonfinite = finite_json(doc)
    if nonfinite:
        doc.setdefault("notes", []).append(f"not a finite number, written as null: {', '.join(nonfinite[:10])}"
                                            + (f" and {len(nonfinite) - 10} more" if len(nonfinite) > 10 else ""))
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def write_outputs(d: Diagnosis, out: str | Path, *, recording: str, plant: str, model_note: str = "",
                  fmu_check: dict[str, Any] | None = None, plots: bool = True,
                  executor: Executor | None = None) -> dict[str, Any]:
    """Write the diagnosis files into ``out``; returns the ``diagnosis.json`` document (``executor``:
    worker processes for the discriminating experiments' designs).

    Parameters
    ----------
    d : Diagnosis
        The diagnosis.
    out : str or Path
        The output folder (written all or nothing).
    recording : str
        The recording, as the files name it.
    plant : str
        The plant, as the files name it.
    model_note : str, optional
        Added to the note of ``calibrated_plant.json``.
    fmu_check : dict, optional
        The plant FMU's re-simulation against the in-process model (``max_abs_difference_mm``),
        if made.
    plots : bool, optional
        Write the figures; default True.
    executor : concurrent.futures.Executor, optional
        Worker processes for the discriminating experiments' designs.
    """
    out = Path(out)
    doc = d.to_json()
    doc = {**{k: doc[k] for k in ("verdict", "fit_before_percent", "fit_after_percent", "findings")},
           "recording": recording, "plant": plant, **produced_by(), **{k: v for k, v in doc.items() if k not in
                                                       ("verdict", "fit_before_percent", "fit_after_percent", "findings")}}
    if fmu_check is not None:
        doc["fmu_check"] = fmu_check
    experiments = []
    # all or nothing, and no file of an earlier diagnosis left beside these (its figures, its experiments)
    with staged_folder(out, owned=OWNED_FILES) as tmp:
        for i, (group, entry) in enumerate(zip(d.ambiguous, doc["ambiguous"])):
            experiments.append(_write_experiment(d, group, tmp, i, executor, shown=out))
            entry.update(discriminating_input=experiments[-1]["file"], discriminate_plant=experiments[-1]["plant"],
                         experiment=experiments[-1])
        atomic_write_text(tmp / "diagnosis.json", json_text(doc))
        # what the file holds beyond the plant given: recalibrated constants, fitted effects (an ambiguous
        # verdict's best alternative among them), either, or neither
        fitted = {(True, True): "with the constants tapmuscle diagnose recalibrated and the effects it fitted to",
                  (True, False): "with the constants tapmuscle diagnose recalibrated to",
                  (False, True): "with the effects tapmuscle diagnose fitted to",
                  (False, False): "as given: tapmuscle diagnose recalibrated and fitted nothing on"}[
            (d.calibration is not None and bool(d.calibration.changed), bool(d.named or d.ambiguous))]
        loaded = (d.nominal is not None and d.calibrated.load.load_n != d.nominal.load.load_n)
        atomic_write_text(tmp / "calibrated_plant.json", plant_file_text(
            d.calibrated, f"{plant} {fitted} {recording}" + (f" ({model_note})" if model_note else "")
            + (f", at the recording's load ({d.calibrated.load.load_n:g} N)" if loaded else "")))
        atomic_write_text(tmp / "report.md", _report_md(d, recording, plant, fmu_check, experiments, plots))
        if plots:
            _figures(d, tmp, Path(recording).stem)
    return doc


def _write_experiment(d: Diagnosis, group: list, out: Path, index: int,
                      executor: Executor | None = None, shown: Path | None = None) -> dict[str, Any]:
    """Design the experiment that separates an ambiguous group and write it (``discriminating_input.csv``)
    with the plant to re-diagnose its recording with (``discriminate_plant.json``), both numbered from
    the second group on. The commands name them in ``shown`` (the output folder as given, from where
    the diagnosis ran: a command copied from the report runs there, as its recording's path does)."""
    suffix = "" if index == 0 else f"_{index + 1}"
    name = EXPERIMENT_FILE.replace(".csv", f"{suffix}.csv")
    plant_name = EXPERIMENT_PLANT_FILE.replace(".json", f"{suffix}.json")
    # the load the diagnosis simulated: the recording's column, else the model's (a rig's load is not in doubt)
    load = (float(d.load_n[0]) if d.load_n is not None
            else float(d.nominal.load.load_n) if d.nominal is not None else None)
    duration = float(min(max(60.0, 0.5 * (d.t_s[-1] - d.t_s[0])), 180.0))
    # within the commands the recording covered, where the alternatives were fitted (design_input)
    span = (float(np.clip(np.min(d.u_v), U_MIN_V, U_MAX_V)), float(np.clip(np.max(d.u_v), U_MIN_V, U_MAX_V)))
    effects = [a.effect for a in group]
    space = MUSCLE if d.nominal is None else MuscleSpace(d.nominal)
    passing = _passing_effects(d.calibrated, space, effects)
    exp = design_input({a.effect: _without(a.params, space, passing) for a in group}, ts_s=d.ts_s, duration_s=duration,
                       noise_mm=max(d.tests_before["white_noise_mm"], 1e-6), load_n=load, u_span_v=span,
                       executor=executor)
    where = Path("") if shown is None else Path(shown)
    record = write_experiment(exp, out / name, alternatives=effects, ts_s=d.ts_s, load_n=load, shown=str(where / name))
    # The re-diagnosis starts from the constants this recording identified: the experiment's recording
    # was designed to separate the alternatives, not to pin the constants, and recalibrated from the
    # nominal plant on it they would take up again what the alternatives differ in.
    # the effects off at the nominal model's operating conditions (the plant file's supply pressure)
    base = _without(d.calibrated.with_values(**space.off_values([k for a in group for k in a.parameters])), space,
                    passing)
    left = f" and {', '.join(passing)} (the recording's, at its times)" if passing else ""
    atomic_write_text(out / plant_name, plant_file_text(
        base, f"the calibrated plant without {', '.join(effects)}{left}: re-diagnose the recording of {name} with it"))
    command = _rediagnose_command(where / plant_name, effects)
    return {"file": name, "plant": plant_name, "record": record, "rediagnose": command} | exp.to_json()


def _rediagnose_command(plant: Path, effects: Sequence[str]) -> str:
    """The command that re-diagnoses the experiment's recording among ``effects`` with ``plant``; a
    candidate of one's own among them needs its file again."""
    own = [e for e in effects if e not in {c.name for c in CANDIDATES}]
    return (f"tapmuscle diagnose --recording NEW.csv --plant {shlex.quote(str(plant))} --effects {','.join(effects)}"
            + (" --candidates YOUR_CANDIDATES.py" if own else "") + " --out NEW_DIAGNOSIS")


def _passing_effects(params: PlantParams, space: MuscleSpace, keep: Sequence[str]) -> list[str]:
    """The effects on in ``params`` that act only for a while at the recording's times (a supply sag:
    :attr:`~tapmuscle.diagnosis.candidates.Candidate.edges`), other than those in ``keep``. An
    experiment recorded later has its own clock: such an effect is not in it."""
    return [c.name for c in CANDIDATES if c.edges is not None and c.name not in keep
            and any(params.value(spec.key) != off for spec, off in
                    zip(c.parameters, space.off_values([spec.key for spec in c.parameters]).values()))]


def _without(params: PlantParams, space: MuscleSpace, effects: Sequence[str]) -> PlantParams:
    """``params`` with the built-in ``effects`` off."""
    keys = [spec.key for c in CANDIDATES if c.name in effects for spec in c.parameters]
    return params.with_values(**space.off_values(keys)) if keys else params


def _one_or_many(items: Any) -> list[Any]:
    """A name or candidate as a list of one, as :func:`~tapmuscle.diagnosis.diagnose.diagnose` takes them."""
    return [items] if isinstance(items, (str, Candidate)) else list(items)


def diagnose_files(recording: str | Path, plant: str | Path, out: str | Path, *, plots: bool = True,
                   progress: Callable[[int, int], None] | None = None, effects: Sequence[str] | None = None,
                   workers: int = 1, **options: Any) -> tuple[Diagnosis, dict]:
    """Read a recording CSV and a plant (file or FMU), diagnose, write the outputs into ``out``.

    Parameters
    ----------
    recording : path
        The rig's recording CSV (docs/recordings.md): ``t_s,u_v,l_mm`` [, ``load_n``, ``p_mpa``]; without
        a ``load_n`` column, its ``# load_n:`` header line gives the load.
    plant : path
        A MusclePlant FMU or a plant parameter JSON file: the nominal model.
    out : path
        Folder for ``diagnosis.json``, ``calibrated_plant.json``, ``report.md`` and the PNGs
        (docs/diagnosis.md), each written atomically.
    plots : bool
        Write the PNGs.
    progress : callable, optional
        ``progress(done, total)`` as the diagnosis goes, in thousandths of the whole, never decreasing
        (:mod:`~tapmuscle.diagnosis.search_progress`); a :class:`~tapmuscle.progress.Progress` is also
        told the phase.
    effects : sequence of str, optional
        Limit the candidates to these names (e.g. the alternatives of an ambiguous verdict,
        re-diagnosed on the recording of the discriminating experiment). Given with ``candidates``
        (in ``options``), the candidates are these names and those.
    workers : int
        Processes for the independent simulations of the diagnosis and of the discriminating
        experiments (:func:`tapmuscle.diagnosis.simulation.worker_pool`); the outputs are the same.
    **options
        Passed to :func:`tapmuscle.diagnosis.diagnose` (``block_s``, ``fit_segment_s``,
        ``calibration``, ``candidates`` with candidates of one's own, ...).

    Returns
    -------
    (Diagnosis, dict)
        The diagnosis and the ``diagnosis.json`` document.

    Raises ``tapmuscle.io.recording.RecordingError`` (file, line, column) for a malformed recording,
    ``PlantSourceError`` for a bad plant, ``ValueError`` naming the recording file for a recording the
    diagnosis cannot use (too short, a constant command, ...) or an option it refuses.
    """
    for name, value, instead in (("recording", recording, "tm.diagnose(rec.t_s, rec.u_v, rec.l_mm, ...) takes a "
                                  "Recording's columns"),
                                 ("plant", plant, "tm.diagnose(..., params) takes a PlantParams"),
                                 ("out", out, "")):
        if not isinstance(value, (str, os.PathLike)):
            raise TypeError(f"diagnose_files: {name} must be a path (it reads and writes files), got "
                            f"{type(value).__name__} {value!r:.60}" + (f"; {instead}" if instead else ""))
    rec: Recording = read_recording(recording)
    model, kind = load_plant(plant)
    probe_output_folder(out)  # before the work, not after it
    if effects is not None:  # names, checked by diagnose; beside them the candidates (of one's own) given
        options["candidates"] = [*_one_or_many(effects), *_one_or_many(options.get("candidates", ()))]
    cols = rec.columns
    try:  # (read_recording has checked the sampling and a '# ts_s:' header)
        load = rec.load_n  # the column, else the '# load_n:' header
    except RecordingError as e:
        raise RecordingError(f"{recording}: {e}") from None
    with worker_pool(workers) as pool:
        put_back = cols["filled"] != 0 if "filled" in cols else None  # tapmuscle import --fill-gaps
        filled = np.zeros(0, int) if put_back is None else np.flatnonzero(put_back)
        try:
            d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], model, load_n=load, p_mpa=cols.get("p_mpa"),
                         progress=progress, executor=pool, left_out=put_back if filled.size else None, **options)
        except TapmuscleError:  # names its file already
            raise
        except ValueError as exc:  # about the recording's columns: which recording
            raise ValueError(f"{recording}: {exc}") from exc
        if load is None:
            d.notes.append(f"The recording gives no load (no load_n column, no '# load_n:' line): the plant's "
                           f"{model.load.load_n:g} N is assumed (a rig at another load shows as load_mismatch, or, where the "
                           "recalibrated constants take it up, in them: give the rig's load to tell)")
        if filled.size:
            d.notes.append(f"{filled.size} samples were put back by interpolation (column filled, from t = "
                           f"{float(cols['t_s'][filled[0]] - cols['t_s'][0]):g} s): left out of the fits and the held-out "
                           "tests; the command there was not logged, so a gap of more than a few samples may leave an "
                           "unexplained window after it")
        fmu_check = None
        if kind == "fmu":
            sim_fmu = simulate_plant_fmu(plant, model.noise_free().dotted(), cols["u_v"], d.ts_s, load)
            fmu_check = {"max_abs_difference_mm": float(np.max(np.abs(sim_fmu - d.y_before_mm)))}
        doc = write_outputs(d, out, recording=str(recording), plant=str(plant), fmu_check=fmu_check, plots=plots,
                            executor=pool)
    return d, doc

