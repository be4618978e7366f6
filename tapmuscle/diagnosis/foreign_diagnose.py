"""``tapmuscle diagnose --plant ANY.fmu``: diagnose a foreign plant FMU against its recording.

The same method as for the tapmuscle plant (docs/diagnosis.md): calibrate the FMU's Real
parameters that the recording identifies, then select the boundary effects
(:mod:`tapmuscle.diagnosis.boundary_candidates`) that recalibration cannot explain on held-out
blocks, with the backward step, ambiguity and the unexplained remainder. The FMU is run by the
diagnosis as a co-simulation master would (:class:`~tapmuscle.diagnosis.foreign_model.ForeignSimulator`).

Outputs (``--out DIR``, written into a temporary folder beside it and renamed at the end, so a
failure leaves no partial folder): ``diagnosis.json`` (the keys of the tapmuscle plant's document;
values named ``*_mm`` are in the diagnosed output's unit, stated in ``output``), ``calibrated_parameters.json``
(the FMU parameters to set and the boundary effects, as a master applies them), ``report.md`` and
``overlay.png``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from tapmuscle.io.atomic import staged_folder
from tapmuscle.io.recording import atomic_write_text, read_columns

from tapmuscle.diagnosis.boundary_candidates import (BoundarySpace, boundary_candidates, calibration_parameters,
                                                     nominal_values)
from tapmuscle.diagnosis.diagnose import Diagnosis, diagnose_with, split_length_s, validated_recording
from tapmuscle.diagnosis.fit_problem import SimulationError
from tapmuscle.diagnosis.foreign_model import FmuInterface, ForeignFmuError, ForeignSimulator, read_interface
from tapmuscle.diagnosis.report import json_text, overlay_figure, summary_lines
from tapmuscle.diagnosis.signal_map import SignalMap, SignalMapError, match_by_name, read_signal_map
from tapmuscle.provenance import produced_by

__all__ = ["diagnose_foreign", "diagnose_foreign_outputs", "ForeignSetup", "FOREIGN_OUTPUT_FILES",
           "FIT_SEGMENT_SAMPLES"]

#: Default fit segment: the whole recording, up to this many samples (the fits' simulations are the
#: cost, and a foreign plant's time constants are unknown: a long segment is safe, a short one may not
#: show them).
FIT_SEGMENT_SAMPLES = 4000

#: What :func:`diagnose_foreign` writes (the figure only with ``plots=True``).
FOREIGN_OUTPUT_FILES = ("diagnosis.json", "calibrated_parameters.json", "report.md", "overlay.png")


def _mapping(recording: str | Path, plant: str | Path, map_path: str | Path | None
             ) -> tuple[FmuInterface, dict[str, np.ndarray], SignalMap]:
    """The FMU's interface, the recording's columns and the signal map (``map_path``'s, or by name)."""
    iface = read_interface(plant)
    columns, _ = read_columns(recording)
    smap = (read_signal_map(map_path, iface, list(columns)) if map_path is not None
            else match_by_name(iface, list(columns)))
    return iface, columns, smap


class ForeignSetup:
    """A recording and a foreign FMU made ready for the search: the mapping, the simulator, the
    model space, the nominal parameters, the candidates and the calibration list.

    Parameters
    ----------
    recording : str or Path
        The recording CSV.
    plant : str or Path
        The foreign FMU.
    map_path : str or Path, optional
        The ``MAP.toml`` mapping columns to the FMU's variables; None (default): columns named as
        the variables (the mapping is echoed).
    output : str, optional
        The mapped output to diagnose; None (default): the first.
    block_s : float, optional
        Length of the training / held-out blocks [s]; None (default): balanced on the first
        input.
    echo : callable, optional
        Where the set-up's messages go; default :func:`print`.
    """

    def __init__(self, recording: str | Path, plant: str | Path, *, map_path: str | Path | None = None,
                 output: str | None = None, block_s: float | None = None, echo: Callable[[str], None] = print) -> None:
        self.recording, self.plant = str(recording), str(plant)
        iface, columns, smap = _mapping(recording, plant, map_path)
        if map_path is None:
            for line in smap.lines():
                echo(line)
        if smap.time_column not in columns:
            raise SignalMapError(f"{recording}: no time column {smap.time_column!r}")
        outs = {s.variable: s for s in smap.outputs}
        if output is None:
            out_sig = smap.outputs[0]
        elif output in outs:
            out_sig = outs[output]
        else:
            raise SignalMapError(f"--output {output!r}: not a mapped output (mapped: {', '.join(outs)})")
        first = smap.inputs[0]
        try:
            t, u, y, ts = validated_recording(columns[smap.time_column], columns[first.column], columns[out_sig.column],
                                              block_s, names=(smap.time_column, first.column, out_sig.column),
                                              units=(first.unit or "", out_sig.unit or ""))
        except ValueError as exc:  # about the recording's columns: which recording, as the command line says it
            raise ValueError(f"{recording}: {exc}") from exc
        #: Length of the training / held-out blocks [s]: as given, or balanced on the first input as
        #: for the muscle.
        self.block_s = split_length_s(u, ts, block_s)
        if smap.ts_s is not None and abs(ts - smap.ts_s) > 1e-3 * smap.ts_s:
            raise SignalMapError(f"{recording}: sampled every {ts:g} s, but {smap.source} states ts_s = {smap.ts_s:g} s")
        inputs: dict[str, np.ndarray] = {}
        ranges: dict[str, tuple[float, float]] = {}
        for s in smap.inputs:
            col = columns[s.column]
            bad = np.nonzero(~np.isfinite(col))[0]
            if bad.size:
                raise ValueError(f"{recording}: column {s.column}, sample {int(bad[0])}: {float(col[bad[0]])!r} is not "
                                 "finite")
            inputs[s.variable] = col
            lo, hi = float(np.min(col)), float(np.max(col))
            if hi - lo <= 0.0:
                pad = 0.1 * abs(lo) or 1.0
                lo, hi = lo - pad, hi + pad
            ranges[s.variable] = (lo, hi)
        self.map, self.interface, self.output = smap, iface, out_sig
        self.t, self.u, self.y, self.ts = t, u, y, ts
        units = {sig.variable: sig.unit for sig in (*smap.inputs, *smap.outputs) if sig.unit}
        self.sim = ForeignSimulator(iface, t, ts, inputs, out_sig.variable, ranges, dict(smap.parameters), units)
        self.space = BoundarySpace(self.sim)
        self.nominal = nominal_values(self.sim, self.space)
        self.candidates = boundary_candidates(self.sim)
        self.calibration = calibration_parameters(iface, smap.parameters, smap.calibrate)
        t0 = time.perf_counter()
        try:
            self.sim.run(self.nominal)
        except SimulationError as exc:
            raise ForeignFmuError(f"--plant {plant}: the FMU cannot re-simulate {recording} with its own start "
                                  f"values: {exc}") from None
        self.simulation_s = time.perf_counter() - t0
        self.sim.runs = 0
        echo(f"one simulation of the {len(t)}-sample recording ({(len(t) - 1) * ts:g} s) through "
             f"{iface.model_name} ({iface.kind}): {self.simulation_s:.3f} s")


def diagnose_foreign(recording: str | Path, plant: str | Path, out: str | Path, *, map_path: str | Path | None = None,
                     output: str | None = None, block_s: float | None = None, fit_segment_s: float | None = None,
                     effects: Sequence[str] | None = None, calibrate: bool = True, plots: bool = True,
                     progress: Callable[[int, int], None] | None = None,
                     echo: Callable[[str], None] = print) -> tuple[Diagnosis, dict[str, Any]]:
    """Diagnose a foreign FMU against a recording and write the outputs into ``out`` (module docstring).

    Parameters
    ----------
    recording : path
        CSV in the recording format (any column names; docs/recordings.md).
    plant : path
        An FMI 2.0 FMU: co-simulation, or (when it offers only that) model exchange, integrated
        between samples by CVode with the inputs held (slower: about 9x for the DC motor).
    out : path
        Output folder (replaced as a whole at the end).
    map_path : path, optional
        ``MAP.toml`` (:mod:`tapmuscle.diagnosis.signal_map`); without it, columns are matched to
        variables by name and the mapping is printed.
    output : str, optional
        The mapped output to diagnose (default: the first).
    block_s : float, optional
        Length of the interleaved training / held-out blocks [s]. Default: as for the muscle
        (:func:`~tapmuscle.diagnosis.diagnose.diagnose`), :data:`~tapmuscle.diagnosis.diagnose.BLOCK_S`
        unless the first input is continuous and locked to that split, then a balanced length; the
        length used is the report's ``split.block_s``.
    fit_segment_s : float, optional
        The calibration and the smooth effects are fitted on the first this many seconds (default:
        the whole recording, at most :data:`FIT_SEGMENT_SAMPLES` samples).
    effects : sequence of str, optional
        Only these candidates (names as ``transport_delay[V]``).
    calibrate : bool
        Re-estimate the FMU's parameters first (default).
    plots : bool
        Write ``overlay.png``.
    progress : callable, optional
        ``progress(done, total)`` as the diagnosis goes, in thousandths of the whole, never decreasing
        (:mod:`~tapmuscle.diagnosis.search_progress`); a :class:`~tapmuscle.progress.Progress` is also
        told the phase.
    echo : callable
        Where the mapping and the simulation time are printed.

    Raises
    ------
    ForeignFmuError, SignalMapError, tapmuscle.io.recording.RecordingError, ValueError
        Each naming the file, key, column or variable at fault; nothing is written then.
    """
    setup = ForeignSetup(recording, plant, map_path=map_path, output=output, block_s=block_s, echo=echo)
    block_s = setup.block_s
    cands = setup.candidates
    if effects is not None:
        known = {c.name: c for c in cands}
        unknown = [e for e in effects if e not in known]
        if unknown or not effects:
            raise ValueError(f"--effects: {'unknown effect ' + repr(unknown[0]) if unknown else 'names no effect'}; "
                             f"known for this FMU and recording: {', '.join(known)}")
        cands = [known[e] for e in effects]
    try:
        d = diagnose_with(setup.sim, setup.t, setup.u, setup.y, setup.ts, setup.nominal, space=setup.space,
                          candidates=cands, calibration=setup.calibration if calibrate else None, block_s=block_s,
                          fit_segment_s=(min(setup.t[-1] - setup.t[0], FIT_SEGMENT_SAMPLES * setup.ts)
                                         if fit_segment_s is None else fit_segment_s),
                          progress=progress, output=(setup.output.variable, setup.output.unit))
    finally:
        setup.sim.close()
    doc = _write(d, setup, Path(out), plots)
    return d, doc


def _calibrated_file(d: Diagnosis, setup: ForeignSetup) -> dict[str, Any]:
    values = d.calibrated.dotted()
    nominal = setup.nominal.dotted()
    own = {p.name for p in setup.interface.parameters}
    return {"fmu": setup.plant, "recording": setup.recording,
            "parameters": {k: v for k, v in values.items() if k in own and v != nominal[k]} | setup.map.parameters,
            "boundary_effects": {k: v for k, v in values.items() if k not in own and v != nominal[k]},
            "note": "set 'parameters' on the FMU; apply 'boundary_effects' in the master "
                    "(tapmuscle.diagnosis.boundary_effects: '<input>:delay_s', '<input>:map_*', '<input>:backlash', "
                    "'<input>:change/start_s/end_s', '<output>:gain/offset/drift_per_min')"}


def _report(d: Diagnosis, setup: ForeignSetup, doc: dict[str, Any]) -> str:
    unit = setup.output.unit or "(unit)"
    lines = [f"# Diagnosis of {setup.interface.model_name} against {Path(setup.recording).name}", "",
             f"- FMU: `{setup.plant}` ({setup.interface.kind}"
             f"{', integrated between samples by CVode' if setup.interface.model_exchange else ''}); "
             f"recording: `{setup.recording}` ({len(setup.t)} samples, Ts {setup.ts:g} s)",
             f"- diagnosed output: `{setup.output.variable}` (column `{setup.output.column}`, {unit}); values "
             f"named `*_mm` in diagnosis.json are in {unit}",
             f"- one simulation of the recording: {setup.simulation_s:.3f} s; the diagnosis ran {d.simulations} in "
             f"{d.elapsed_s:.1f} s", "", "## Mapping", ""]
    lines += [f"    {line}" for line in setup.map.lines()]
    lines += ["", "## Verdict", ""] + [f"    {line}" for line in summary_lines(d)]
    if d.ambiguous:
        lines += ["", "An ambiguous verdict on a foreign FMU comes without a designed discriminating input "
                  "(the experiment design simulates the tapmuscle plant); record the plant with an input that "
                  "exercises where the alternatives differ and diagnose again with `--effects`."]
    if d.calibration is not None:
        lines += ["", "## Calibration", "", "| parameter | unit | nominal | estimate | 95 % interval | identifiable |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {r.parameter} | {r.unit} | {r.nominal:.6g} | {r.estimate:.6g} | {r.ci95[0]:.4g} .. {r.ci95[1]:.4g} "
                  f"| {r.identifiable_text()} |" for r in d.calibration.rows]
    rejected = [c for c in d.candidates if "rejected" in c]
    if rejected:
        lines += ["", "## Candidates rejected", ""]
        lines += [f"- {c['effect']} (round {c['round']}): {c['rejected']}" for c in rejected]
    return "\n".join(lines) + "\n"


def _write(d: Diagnosis, setup: ForeignSetup, out: Path, plots: bool) -> dict[str, Any]:
    doc = d.to_json()
    doc = {k: doc[k] for k in ("verdict", "fit_before_percent", "fit_after_percent", "findings")} | {
        "recording": setup.recording, "plant": setup.plant, "model": setup.interface.model_name,
        "fmi_interface": setup.interface.kind,
        "output": {"variable": setup.output.variable, "column": setup.output.column, "unit": setup.output.unit},
        "mapping": setup.map.to_json(), "simulation_s": round(setup.simulation_s, 4), **produced_by()} | {
        k: v for k, v in doc.items() if k not in ("verdict", "fit_before_percent", "fit_after_percent", "findings")}
    with staged_folder(out) as tmp:
        atomic_write_text(tmp / "diagnosis.json", json_text(doc))
        atomic_write_text(tmp / "calibrated_parameters.json",
                          json.dumps(_calibrated_file(d, setup), indent=2, allow_nan=False) + "\n")
        atomic_write_text(tmp / "report.md", _report(d, setup, doc))
        if plots:
            overlay_figure(d, tmp / "overlay.png", quantity=setup.output.variable, unit=setup.output.unit or "-",
                           model="FMU", title=f"{setup.interface.model_name}: {', '.join(d.named) or d.verdict} "
                                              "(held-out fit in brackets)")
    return doc


def diagnose_foreign_outputs(recording: str | Path, plant: str | Path, out: str | Path, *,
                             map_path: str | Path | None = None, outputs: Sequence[str] | None = None,
                             echo: Callable[[str], None] = print, **options: Any
                             ) -> dict[str, tuple[Diagnosis, dict[str, Any]]]:
    """Diagnose each of several measured outputs in turn (``tapmuscle diagnose --output all``).

    Each output gets its own diagnosis, written into ``out/<variable>/`` as :func:`diagnose_foreign`
    writes it, and ``out/summary.md`` and ``out/summary.json`` set the verdicts side by side. An
    effect at an FMU input (delay, input map, backlash, secondary input) acts on every output, so
    the summary says for each one named on which outputs it was found: named on all of them, it is
    corroborated; on some only, the others' data did not show it (or it is spurious there). Output
    effects (drift, gain) belong to one sensor each.

    Parameters
    ----------
    recording, plant, map_path
        As for :func:`diagnose_foreign`.
    out : path
        Output folder, replaced as a whole at the end (nothing is written if any diagnosis fails).
    outputs : sequence of str, optional
        The mapped outputs to diagnose (default: every mapped output).
    echo : callable
        Where each output's heading, its mapping and simulation time are printed.
    **options
        Passed to :func:`diagnose_foreign` (``block_s``, ``effects``, ``calibrate``, ``plots``, ...);
        an effect named for one output's sensor is left out of the other outputs' diagnoses.

    Returns
    -------
    dict
        ``{variable: (Diagnosis, diagnosis.json document)}`` in the map's order.
    """
    iface, _, smap = _mapping(recording, plant, map_path)
    mapped = [sig.variable for sig in smap.outputs]
    chosen = mapped if outputs is None else list(outputs)
    unknown = [o for o in chosen if o not in mapped]
    if unknown or not chosen:
        raise SignalMapError(f"--output {unknown[0] if unknown else '(none)'!r}: not a mapped output "
                             f"(mapped: {', '.join(mapped)})")
    results: dict[str, tuple[Diagnosis, dict[str, Any]]] = {}
    with staged_folder(out) as tmp:
        effects = options.pop("effects", None)
        for variable in chosen:
            echo(f"== output {variable}")
            # an effect on another output's sensor is not a candidate of this output's diagnosis
            own = None if effects is None else [e for e in effects if _target(e) not in set(mapped) - {variable}]
            results[variable] = diagnose_foreign(recording, plant, tmp / variable, map_path=map_path, output=variable,
                                                 effects=own, echo=echo, **options)
        summary = _outputs_summary(results, {v.name for v in iface.inputs})
        atomic_write_text(tmp / "summary.json", json_text(summary))
        atomic_write_text(tmp / "summary.md", _outputs_markdown(summary, iface.model_name, Path(recording).name))
    return results


def _target(effect: str) -> str:
    """The variable a boundary effect acts on: ``transport_delay[V]`` -> ``V`` ('' if none)."""
    return effect[effect.find("[") + 1:-1] if effect.endswith("]") and "[" in effect else ""


def _outputs_summary(results: dict[str, tuple[Diagnosis, dict[str, Any]]], inputs: set[str]) -> dict[str, Any]:
    """Each output's verdict, and each input effect named with the outputs that named it."""
    per_output = {v: {"verdict": d.verdict, "named": d.named, "fit_before_percent": round(d.fit_before_percent, 3),
                      "fit_after_percent": round(d.fit_after_percent, 3), "folder": v}
                  for v, (d, _) in results.items()}
    input_effects: dict[str, list[str]] = {}
    for v, (d, _) in results.items():
        for name in d.named:
            if _target(name) in inputs:
                input_effects.setdefault(name, []).append(v)
    return {"outputs": per_output,
            "input_effects": {name: {"named_on": on, "on_every_output": len(on) == len(results)}
                              for name, on in input_effects.items()}}


def _outputs_markdown(summary: dict[str, Any], model: str, recording: str) -> str:
    lines = [f"# Diagnosis of {model} against {recording}, output by output", "",
             "| output | verdict | named | held-out fit before -> after |", "|---|---|---|---|"]
    lines += [f"| [{v}]({v}/report.md) | {o['verdict']} | {', '.join(o['named']) or '-'} | "
              f"{o['fit_before_percent']:.1f} % -> {o['fit_after_percent']:.1f} % |"
              for v, o in summary["outputs"].items()]
    lines += ["", "An effect at an input acts on every output: named on all of them it is corroborated; named on "
              "some only, the others did not show it (or it is spurious where named).", ""]
    if summary["input_effects"]:
        lines += [f"- {name}: named on {', '.join(e['named_on'])}"
                  + (" (every output)" if e["on_every_output"] else " only") for name, e in summary["input_effects"].items()]
    else:
        lines += ["- no input effect named on any output"]
    return "\n".join(lines) + "\n"
