"""The discriminating experiment: an input that separates explanations the recording could not tell apart.

When the diagnosis ends ``ambiguous``, two or more fitted plants (each the calibrated plant with one
alternative effect) predict the recording equally well. They still differ elsewhere: a transport
delay shows on fast reversals, a load mismatch at low pressure, a dead band where the command dwells
in it. :func:`design_input` searches for a command within the valve's 0..10 V (and within the
recording's commands, below), of a stated duration, for which their noise-free predictions differ
most: it maximises the **smallest** pairwise distance between the alternatives' predicted
displacements (every pair must be separated), in units of the recording's noise.

Search (each evaluation one simulation per alternative):

1. a library of inputs people run on such rigs: held steps (staircases up and down, random levels,
   for three hold times), sines (three offsets, two amplitudes, four frequencies) and slow ramps;
2. from the best, a seeded random local search that changes one to three held levels (or the
   sine's offset, amplitude and frequency) at a time and keeps a change that separates better (each
   step depends on the last, so it runs in this process).

The result is a ``tapmuscle record --input csv:`` file: ``t_s, u_v`` and, in ``l_mm`` and one
``l_<effect>_mm`` column per alternative, what each alternative predicts. Effects that act at given
times (a supply sag's window) are predicted in the new experiment's own time base from 0 s.

The input stays within ``u_span_v``, which the diagnosis sets to the commands its recording covered.
The alternatives were fitted there; beyond it their parameters (a map's knots, a band's edges, the
constants' reach) are extrapolations, and an input that separates them there separates guesses, not
explanations (on the field proof's ambiguous verdicts, the right alternative predicted the new
recording to 0.04-0.76 mm within the recorded commands and to 1.2-3.1 mm beyond them). It also keeps
the rig where it has already been driven.
"""

from __future__ import annotations

import math
import shlex
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from fmu_plant import PlantParams

from tapmuscle.diagnosis.simulation import Simulator
from tapmuscle.diagnosis.reproducible import norm

__all__ = ["Experiment", "design_input", "separation", "write_experiment"]

#: Commands the designed input stays within [V] (the valve's range).
U_MIN_V, U_MAX_V = 0.0, 10.0


@dataclass
class Experiment:
    """A designed discriminating input and what each alternative predicts for it."""

    t_s: np.ndarray
    """Time [s] of the input's samples."""
    u_v: np.ndarray
    """The designed command [V]."""
    predictions: dict[str, np.ndarray] = field(repr=False)
    """Alternative name -> predicted noise-free displacement [mm]."""
    separation_sigma: float
    """Smallest pairwise distance of the predictions, ``|y_i - y_j| / sigma`` (whole run) [-]."""
    rms_difference_mm: float
    """Smallest pairwise RMS difference of the predictions [mm]."""
    description: str
    """What kind of input it is, in words."""
    evaluations: int
    """Candidate inputs whose predictions the design simulated."""

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    def to_json(self) -> dict[str, Any]:
        return {"duration_s": round(self.duration_s, 3), "samples": len(self.t_s),
                "separation_sigma": round(self.separation_sigma, 2),
                "min_rms_difference_mm": round(self.rms_difference_mm, 4), "input": self.description,
                "evaluations": self.evaluations}

    def columns(self) -> dict[str, np.ndarray]:
        """Recording columns: ``t_s, u_v, l_mm`` (the first alternative's prediction) and one
        ``l_<name>_mm`` per alternative."""
        first = next(iter(self.predictions.values()))
        # k Ts to the nanosecond: the file reads 0.1, not 0.0999999999999979 (a period taken from a recording)
        cols = {"t_s": np.round(self.t_s, 9), "u_v": self.u_v, "l_mm": first}
        for name, y in self.predictions.items():
            cols[f"l_{name}_mm"] = y
        return cols


def separation(predictions: Sequence[np.ndarray]) -> float:
    """Smallest pairwise Euclidean distance between predictions [mm] (0 for fewer than two).

    Parameters
    ----------
    predictions : sequence of ndarray
        Predicted displacements [mm], one per alternative.
    """
    best = math.inf
    for i in range(len(predictions)):
        for j in range(i + 1, len(predictions)):
            best = min(best, norm(predictions[i] - predictions[j]))
    return 0.0 if best == math.inf else best


def _held(levels: Sequence[float], hold_s: float, t: np.ndarray) -> np.ndarray:
    k = np.minimum((t / hold_s).astype(int), len(levels) - 1)
    return np.asarray(levels, float)[k]


def _sine(offset: float, amp: float, freq: float, t: np.ndarray) -> np.ndarray:
    return offset + amp * np.sin(2 * math.pi * freq * t)


def design_input(alternatives: dict[str, PlantParams], *, ts_s: float, duration_s: float = 120.0,
                 noise_mm: float = 0.01, load_n: float | None = None, seed: int = 0, local_steps: int = 30,
                 u_span_v: tuple[float, float] = (1.0, 9.0),
                 progress: Callable[[int, int], None] | None = None,
                 executor: Executor | None = None) -> Experiment:
    """Design the input that separates the ``alternatives`` best (module docstring).

    Parameters
    ----------
    alternatives : dict of str to PlantParams
        Name -> fitted plant, at least two.
    ts_s : float
        Sampling period of the experiment [s] (the recording's).
    duration_s : float
        Length of the experiment [s].
    noise_mm : float
        Encoder noise [mm]: the separation is reported in its units.
    load_n : float, optional
        Load to run at [N] (default: each plant's own).
    seed : int
        Seed of the local search.
    local_steps : int
        Local-search moves after the library.
    u_span_v : (float, float)
        Commands the input stays within [V] (within 0..10 V). The diagnosis passes the range its
        recording covered: beyond it the alternatives' parameters (a map's knots, a band's edges,
        the constants' reach) are extrapolations, and a difference between their predictions there
        is no evidence for either.
    progress : callable, optional
        ``progress(done, total)`` after each input scored.
    executor : Executor, optional
        Worker processes (:func:`~tapmuscle.diagnosis.simulation.worker_pool`) for the library's
        inputs (independent of each other); the design is the same with or without.

    Raises
    ------
    ValueError
        Fewer than two alternatives, a duration / sampling period that gives fewer than 10 samples,
        or a ``u_span_v`` not within 0..10 V.
    """
    lo, hi = (float(v) for v in u_span_v)
    if not (U_MIN_V <= lo <= hi <= U_MAX_V):
        raise ValueError(f"u_span_v = {u_span_v!r} V: need {U_MIN_V:g} <= low <= high <= {U_MAX_V:g}")
    if len(alternatives) < 2:
        raise ValueError(f"a discriminating experiment needs at least two alternatives, got {len(alternatives)}")
    n = int(round(duration_s / ts_s)) + 1
    if n < 10 or ts_s <= 0:
        raise ValueError(f"duration_s = {duration_s!r} s at ts_s = {ts_s!r} s gives {n} samples; need at least 10")
    t = np.arange(n) * ts_s
    names = list(alternatives)
    plants = [alternatives[k] if load_n is None else alternatives[k].with_values(**{"load.load_n": load_n})
              for k in names]
    evals = 0

    def predict(u: np.ndarray) -> list[np.ndarray]:
        nonlocal evals
        evals += 1
        return _predict(u, ts_s, plants)

    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    a_min = min(0.2, 0.5 * half)  # [V], the smallest sine amplitude of the local search
    rng = np.random.default_rng(seed)
    # the library: (kind, parameters)
    library: list[tuple[str, tuple]] = []
    for hold in (2.0, 5.0, 10.0):
        k = int(math.ceil(duration_s / hold)) + 1
        up = np.linspace(lo, hi, k)
        library += [("steps", (tuple(up), hold)), ("steps", (tuple(up[::-1]), hold)),
                    ("steps", (tuple(np.where(np.arange(k) % 2 == 0, up, up[::-1])), hold)),
                    ("steps", (tuple(rng.uniform(lo, hi, k)), hold))]
    for offset in (mid - 0.5 * half, mid, mid + 0.5 * half):
        for amp in (0.5 * half, half):
            for freq in (0.05, 0.1, 0.2, 0.4):
                library.append(("sine", (offset, min(amp, offset - lo, hi - offset), freq)))

    def build(kind: str, args: tuple) -> np.ndarray:
        return _held(args[0], args[1], t) if kind == "steps" else _sine(*args, t)

    scored = []
    inputs = [build(kind, args) for kind, args in library]
    if executor is None:
        preds = map(predict, inputs)
    else:  # the library's inputs are independent: in the worker processes, in order
        preds = executor.map(_predict, inputs, [ts_s] * len(inputs), [plants] * len(inputs))
        evals += len(inputs)
    for i, ((kind, args), pred) in enumerate(zip(library, preds)):
        scored.append((separation(pred), kind, args))
        if progress is not None:
            progress(i + 1, len(library) + local_steps)
    scored.sort(key=lambda s: -s[0])
    best_sep, kind, args = scored[0]
    # local search from the best: move one to three held levels, or the sine's parameters, by steps
    # in proportion to the span (1.5 V and 0.5 V on the default 8-V span)
    for step in range(local_steps):
        if kind == "steps":
            levels = np.array(args[0], float)
            idx = rng.choice(len(levels), size=min(len(levels), int(rng.integers(1, 4))), replace=False)
            levels[idx] = np.clip(levels[idx] + rng.normal(0.0, 1.5 * half / 4.0, len(idx)), lo, hi)
            trial = (tuple(levels), args[1])
        else:
            offset, amp, freq = args
            # a sine keeps at least a_min of amplitude: a constant command excites nothing, and the
            # diagnosis refuses a recording of one
            offset = float(np.clip(offset + rng.normal(0.0, 0.5 * half / 4.0), lo + a_min, hi - a_min))
            amp = float(np.clip(amp * math.exp(rng.normal(0.0, 0.2)), a_min, min(offset - lo, hi - offset)))
            freq = float(np.clip(freq * math.exp(rng.normal(0.0, 0.3)), 0.02, 0.5 / (4 * ts_s)))
            trial = (offset, amp, freq)
        u_trial = build(kind, trial)
        if np.ptp(u_trial) > 0.0:  # held levels moved onto one value are a constant command, as above
            sep = separation(predict(u_trial))
            if sep > best_sep:
                best_sep, args = sep, trial
        if progress is not None:
            progress(len(library) + step + 1, len(library) + local_steps)
    u = build(kind, args)
    preds = predict(u)
    rms = separation(preds) / math.sqrt(n)
    if kind == "steps":
        text = f"held levels every {args[1]:g} s between {min(args[0]):.2f} and {max(args[0]):.2f} V"
    else:
        text = f"sine {args[0]:.2f} + {args[1]:.2f} sin(2 pi {args[2]:.3f} t) V"
    return Experiment(t, u, dict(zip(names, preds)), best_sep / max(noise_mm, 1e-12), rms, text, evals)


def _predict(u: np.ndarray, ts_s: float, plants: Sequence[PlantParams]) -> list[np.ndarray]:
    """Each plant's noise-free response [mm] to the command ``u``."""
    sim = Simulator(u, ts_s)
    return [sim.run(p)[0] for p in plants]


def record_command(file: str, *, duration_s: float, ts_s: float, load_n: float | None,
                   out: str = "NEW.csv") -> str:
    """The ``tapmuscle record`` command that runs the experiment file ``file`` on the simulated rig at
    the diagnosed recording's load [N] and sampling period [s] (``LOAD_N`` where it had no load), into
    ``out``: as printed, it runs, on the nominal plant; a simulated rig that made the recording needs
    that recording's ``--params`` or ``--set`` options added (which the diagnosis cannot know)."""
    load = "LOAD_N" if load_n is None else f"{load_n:g}"
    return (f"tapmuscle record --load {load} --ts {ts_s:g} --input {shlex.quote(f'csv:{file}')} "
            f"--duration {duration_s:g} --out {shlex.quote(out)}")


def write_experiment(exp: Experiment, path: str | Path, *, alternatives: Sequence[str], ts_s: float,
                     load_n: float | None = None, shown: str | None = None) -> str:
    """Write ``exp`` as a ``tapmuscle record --input csv:`` file (atomically); ``load_n`` [N] is the
    load to run it at (the diagnosed recording's); ``shown``: the file as the command names it (default
    its name). Returns the :func:`record_command` its note gives.

    Parameters
    ----------
    exp : Experiment
        The designed experiment.
    path : str or Path
        The file to write.
    alternatives : sequence of str
        The alternatives it separates, named in the file's metadata.
    ts_s : float
        Sampling period [s].
    load_n : float, optional
        Load to run it at [N].
    shown : str, optional
        The file as the command names it; default its name.
    """
    from tapmuscle.io.recording import Recording, write_recording

    command = record_command(shown or Path(path).name, duration_s=exp.duration_s, ts_s=ts_s, load_n=load_n)
    meta = {"ts_s": f"{ts_s:g}", "source": "tapmuscle diagnose: discriminating experiment",
            "alternatives": ", ".join(alternatives),
            "note": f"apply it to the rig, or to a simulated rig with: {command} plus the --params or --set "
                    "options that made the diagnosed recording; "
                    f"predicted separation {exp.separation_sigma:.0f} sigma"}
    if load_n is not None:
        meta["load_n"] = f"{load_n:g}"
    write_recording(path, Recording(exp.columns(), meta))
    return command
