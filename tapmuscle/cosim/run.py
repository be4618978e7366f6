"""``tapmuscle run SCENARIO.toml --out DIR``: one scenario through the FMUs, with its outputs.

Writes into ``DIR``, all files at once (:func:`tapmuscle.io.atomic.staged_folder`: a failed run
leaves the folder as it was, and a figure of an earlier run that this run does not draw is removed):

* ``result.csv``: one row per sample (docs/recordings.md format; columns as the direct loop's,
  :func:`tapmuscle.closed_loop.run_closed_loop`), with the scenario in its header;
* ``summary.json``: the metrics of :data:`tapmuscle.cosim.expect.METRICS` (``mae_mm`` = Eq. 21 over
  ``evaluation_samples``, command range, wall time, real-time factor, ...), the FMUs' GUIDs, the scenario,
  and ``fmu_warnings``: what the FMUs warned of during the run;
* ``tracking.png`` (r, l, error, u), ``prediction_error.png`` (not for a
  controller FMU of one's own) and, for the adaptive methods, ``parameters.png`` (theta-hat over time).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.rls import TABLE2_LOWER, TABLE2_UPPER
from tapmuscle.io.atomic import staged_folder
from tapmuscle.io.json_file import json_text
from tapmuscle.io.recording import Recording, atomic_write_text, write_recording
from tapmuscle.plots.figure_formats import FIGURE_FORMATS, checked_figure_format

from tapmuscle.cosim.expect import scenario_metrics
from tapmuscle.cosim.master import co_simulate, sample_columns, unpack
from tapmuscle.cosim.spec import Scenario
from tapmuscle.provenance import produced_by

__all__ = ["RUN_FILES", "RUN_FIGURES", "run_scenario", "summarise"]

#: The figures :func:`run_scenario` draws (the parameters' only for the adaptive methods), without
#: their format's suffix.
RUN_FIGURES = ("tracking", "prediction_error", "parameters")

#: What :func:`run_scenario` writes into its folder (figures only with ``plots=True``, in any of
#: :data:`~tapmuscle.plots.figure_formats.FIGURE_FORMATS`): a rerun replaces or removes these, and
#: leaves other files in the folder alone.
RUN_FILES = ("result.csv", "summary.json") + tuple(f"{name}.{fmt}" for fmt in FIGURE_FORMATS for name in RUN_FIGURES)


def _spec(scenario: Scenario) -> dict[str, Any]:
    """The scenario as plain data, its reference with the fields of its kind only (a steps reference
    has no sine offset, amplitude, frequency; a sine none of the steps' fields)."""
    spec = json.loads(json.dumps(asdict(scenario), default=str))
    unused = ("steps", "preview") if scenario.reference.kind == "sine" else ("offset_mm", "amplitude_mm", "frequency_hz")
    for key in unused:
        spec["reference"].pop(key, None)
    return spec


def summarise(scenario: Scenario, cols: Mapping[str, np.ndarray], fmus: Mapping[str, Path]) -> dict[str, Any]:
    """The ``summary.json`` document of a run.

    Parameters
    ----------
    scenario : Scenario
        The scenario run.
    cols : mapping of str to ndarray
        The run's recorded columns.
    fmus : mapping of str to Path
        The FMU files the run used.
    """
    k0, k1 = scenario.evaluation_samples
    metrics = scenario_metrics(scenario, cols)
    return {
        "scenario": scenario.name, "source": scenario.source, "method": scenario.method, "seed": scenario.seed,
        **metrics, "real_time_factor": metrics["real_time_factor"] if metrics["wall_time_s"] > 0 else None,
        # the window's times as decimals: 10.1, not 10.100000000000001
        "evaluation_samples": [k0, k1], "evaluation_window_s": [float(f"{k * scenario.step_s:.12g}") for k in (k0, k1)],
        # by model name: a controller FMU of one's own is named as what it is
        "fmus": {unpack(p).model_description.modelName: {"path": str(p), "guid": unpack(p).model_description.guid}
                 for p in fmus.values()},
        **produced_by(),
        **({"controller_interface": dict(scenario.controller.interface)} if scenario.controller.own else {}),
        "scenario_spec": _spec(scenario),
        # the delay the controller's law ran for at the end (what input_delay_samples = -1 decided)
        **({"input_delay_samples_used": int(cols["input_delay"])} if "input_delay" in cols else {}),
    }


def scenario_events(scenario: Scenario) -> list[tuple[float, str]]:
    """The scenario's load and supply steps as ``(t_s, text)`` for the figures (a load step explains
    the error that follows it)."""
    events = []
    for profile, what, unit in ((scenario.load, "load", "N"), (scenario.supply, "supply", "MPa")):
        before = profile.initial
        for t, value in profile.steps:
            events.append((t, f"{what} {before:g} -> {value:g} {unit}"))
            before = value
    return sorted(events)


def scenario_box(scenario: Scenario) -> dict[str, tuple[float, float]]:
    """The adaptive controller's constraint region C in ``scenario``: ``(lower, upper)`` by parameter,
    Table 2's where the scenario sets no bound (``box_lower.a1 = -inf`` lifts one)."""
    params = scenario.controller.parameters
    return {n: (float(params.get(f"box_lower.{n}", TABLE2_LOWER[n])), float(params.get(f"box_upper.{n}", TABLE2_UPPER[n])))
            for n in TABLE2_LOWER}


def estimator_name(scenario: Scenario) -> str:
    """What the adaptive controller's estimator is in ``scenario``: Algorithm 1's constrained RLS, or
    Eq. (4)'s RLS where every bound of the box is infinite (a bound not set is Table 2's)."""
    unbounded = all(math.isinf(v) for pair in scenario_box(scenario).values() for v in pair)
    return "RLS, Eq. (4)" if unbounded else "constrained RLS, Algorithm 1"


def run_scenario(scenario: Scenario, out: str | Path, fmus: Mapping[str, str | Path], *,
                 controller_parameters: Mapping[str, Any] | None = None, plots: bool = True,
                 progress: Callable[[int, int], None] | None = None, figure_format: str = "png") -> dict[str, Any]:
    """Co-simulate ``scenario`` (:func:`tapmuscle.cosim.master.co_simulate`) and write the outputs into ``out``.

    Parameters
    ----------
    scenario : Scenario
        The scenario.
    out : path
        The output folder (:data:`RUN_FILES`, put in place together once all are written).
    fmus : mapping
        ``{"MusclePlant": path, "AMPCController": path}``; the scenario's own FMU paths win.
    controller_parameters : mapping, optional
        Controller FMU parameters set on top of the scenario's.
    plots : bool
        Draw the figures (:data:`RUN_FIGURES`).
    progress : callable, optional
        ``progress(done, total)`` as the co-simulation goes.
    figure_format : {"png", "pdf", "svg"}
        The figures' format (:data:`~tapmuscle.plots.figure_formats.FIGURE_FORMATS`).

    Returns
    -------
    dict
        The summary (also written as ``summary.json``) with the columns under ``"cols"``.
    """
    checked_figure_format(figure_format)
    out = Path(out)
    used = {"MusclePlant": Path(scenario.plant.path or fmus["MusclePlant"]),
            "AMPCController": Path(scenario.controller.path or fmus["AMPCController"])}
    # staged before the run: an output folder that cannot be written is named before the run, not after
    with staged_folder(out, owned=RUN_FILES) as tmp:
        said: list[str] = []
        cols = co_simulate(scenario, used, controller_parameters=controller_parameters, progress=progress,
                           fmu_warnings=said)
        summary = summarise(scenario, cols, used)
        summary["fmu_warnings"] = said
        table = sample_columns(cols)
        meta = {"scenario": scenario.name, "method": scenario.method, "seed": str(scenario.seed),
                "ts_s": f"{scenario.step_s:g}", "mae_mm": f"{summary['mae_mm']:.4f}",
                "source": f"tapmuscle run {scenario.source} (FMU co-simulation)"}
        write_recording(tmp / "result.csv", Recording(table, meta))
        atomic_write_text(tmp / "summary.json", json_text(summary, indent=2))
        if plots:
            # imported here: matplotlib is a third of importing tapmuscle.cosim, which a run
            # without plots (a sweep's worker, a test, a host's clean-up) does not need
            from tapmuscle.plots.figures import plot_parameter_convergence, plot_prediction_errors, plot_tracking

            k0, k1 = scenario.evaluation_samples
            window = (k0 * scenario.step_s, k1 * scenario.step_s)
            title = f"{scenario.name}: {scenario.method}, Eq. (21) error {summary['mae_mm']:.3f} mm"
            events = scenario_events(scenario)
            plot_tracking({scenario.method: table}, tmp / f"tracking.{figure_format}", title=title, window_s=window, events=events)
            if "pred_error_mm" in table:  # a controller FMU of one's own has no prediction to show
                plot_prediction_errors({scenario.method: table}, tmp / f"prediction_error.{figure_format}",
                                       title=f"{scenario.name}: one-step prediction error", window_s=window,
                                       events=events)
            if scenario.method.startswith("ampc") and "theta_a1" in table:
                history = np.column_stack([table[f"theta_{n}"] for n in ASYMMETRIC.names])
                plot_parameter_convergence(table["t_s"], history, ASYMMETRIC.names, tmp / f"parameters.{figure_format}",
                                           title=f"{scenario.name}: theta-hat ({estimator_name(scenario)})",
                                           events=events, bounds=scenario_box(scenario))
    summary["cols"] = cols
    return summary
