"""Valve-command signals for open-loop recordings, parsed from compact specs.

A spec is ``KIND:key=value,key=value`` (e.g. ``sine:bias=5,amp=3,freq=0.1``). Kinds:

==========  =========================================================  ==============================
kind        meaning                                                    keys (defaults)
==========  =========================================================  ==============================
``const``   constant command                                           ``value`` (5)
``sine``    ``bias + amp sin(2 pi freq t + phase)``                    ``bias`` (5), ``amp`` (3),
                                                                        ``freq`` [Hz] (0.1), ``phase`` [rad] (0)
``step``    ``initial`` until ``at``, then ``final``                   ``initial`` (4), ``final`` (6), ``at`` [s] (10)
``steps``   piecewise constant, ``levels`` separated by ``/``,         ``levels``, ``period`` [s] (20)
            each held ``period`` seconds, cycling
``chirp``   sine whose frequency sweeps linearly from ``f0`` to        ``bias`` (5), ``amp`` (3), ``f0`` (0.01),
            ``f1`` over ``duration``                                   ``f1`` (0.5), ``duration`` [s] (the
                                                                        run's, else 240)
``random``  random steps: a new level uniform in ``lo..hi`` every      ``lo`` (2), ``hi`` (8), ``hold_min`` (2),
            hold drawn uniform in ``hold_min..hold_max`` seconds       ``hold_max`` (10), ``seed`` (0)
``csv``     replay the ``u_v`` column of a recording (``csv:PATH``);   (the path)
            held between its samples, last value after its end
==========  =========================================================  ==============================

Values are in volts and seconds. :func:`parse_input_spec` validates the spec and raises
``ValueError`` naming the bad kind, key or value.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

__all__ = ["InputSignal", "parse_input_spec", "SPEC_KINDS"]

InputSignal = Callable[[float], float]
"""A command as a function of time: ``u_v = signal(t_s)``."""

SPEC_KINDS: dict[str, dict[str, float | str]] = {
    "const": {"value": 5.0},
    "sine": {"bias": 5.0, "amp": 3.0, "freq": 0.1, "phase": 0.0},
    "step": {"initial": 4.0, "final": 6.0, "at": 10.0},
    "steps": {"levels": "", "period": 20.0},
    "chirp": {"bias": 5.0, "amp": 3.0, "f0": 0.01, "f1": 0.5, "duration": 240.0},
    "random": {"lo": 2.0, "hi": 8.0, "hold_min": 2.0, "hold_max": 10.0, "seed": 0.0},
}


def _number(spec: str, key: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"input spec {spec!r}: {key}={text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"input spec {spec!r}: {key}={text!r} is not finite")
    return value


def parse_input_spec(spec: str, *, run_duration_s: float | None = None) -> InputSignal:
    """Turn a spec string into a command signal ``u(t)`` [V].

    Parameters
    ----------
    spec : str
        See the module docstring, e.g. ``"sine:bias=5,amp=3,freq=0.1"`` or ``"csv:run.csv"``.
    run_duration_s : float, optional
        The length of the run the signal is for [s]: a ``chirp`` without ``duration=`` sweeps over
        it, so that it reaches ``f1`` by the end (without it, over 240 s).

    Raises
    ------
    ValueError
        Unknown kind or key, a value that is not a finite number, or an impossible combination
        (negative frequency, ``lo > hi``, a period <= 0, an empty ``levels`` list). A missing or
        malformed ``csv:`` file raises the recording reader's error, which names file and line.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"input spec must be a non-empty string like 'sine:bias=5,amp=3,freq=0.1', got {spec!r}")
    kind, _, rest = spec.strip().partition(":")
    kind = kind.strip().lower()
    if kind == "csv":
        return _csv_signal(rest.strip(), spec)
    if kind not in SPEC_KINDS:
        raise ValueError(f"input spec {spec!r}: unknown kind {kind!r}; expected one of "
                         f"{', '.join(list(SPEC_KINDS) + ['csv'])}")
    values: dict[str, float | str] = dict(SPEC_KINDS[kind])
    if kind == "chirp" and run_duration_s is not None:
        values["duration"] = float(run_duration_s)
    given: set[str] = set()
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq:
            raise ValueError(f"input spec {spec!r}: expected key=value, got {item!r}")
        if key not in values:
            raise ValueError(f"input spec {spec!r}: unknown key {key!r} for {kind}; expected "
                             f"{', '.join(values)}")
        if key in given:  # which one was meant cannot be told
            raise ValueError(f"input spec {spec!r}: {key!r} is given twice")
        given.add(key)
        values[key] = text.strip() if key == "levels" else _number(spec, key, text.strip())
    return _BUILDERS[kind](spec, values)


def _sine(spec: str, v: dict) -> InputSignal:
    if v["freq"] < 0:
        raise ValueError(f"input spec {spec!r}: freq must be >= 0, got {v['freq']}")
    bias, amp, w, ph = v["bias"], v["amp"], 2.0 * math.pi * v["freq"], v["phase"]
    return lambda t: bias + amp * math.sin(w * t + ph)


def _const(spec: str, v: dict) -> InputSignal:
    value = v["value"]
    return lambda t: value


def _step(spec: str, v: dict) -> InputSignal:
    a, b, at = v["initial"], v["final"], v["at"]
    return lambda t: a if t < at else b


def _steps(spec: str, v: dict) -> InputSignal:
    if not v["levels"]:
        raise ValueError(f"input spec {spec!r}: steps needs levels=L1/L2/..., e.g. levels=3/7/5")
    levels = [_number(spec, "levels", x) for x in str(v["levels"]).split("/")]
    period = v["period"]
    if period <= 0:
        raise ValueError(f"input spec {spec!r}: period must be > 0, got {period}")
    return lambda t: levels[int(max(t, 0.0) // period) % len(levels)]


def _chirp(spec: str, v: dict) -> InputSignal:
    f0, f1, dur = v["f0"], v["f1"], v["duration"]
    if f0 < 0 or f1 < 0 or dur <= 0:
        raise ValueError(f"input spec {spec!r}: need f0, f1 >= 0 and duration > 0")
    bias, amp, rate = v["bias"], v["amp"], (f1 - f0) / dur

    def chirp(t: float) -> float:
        tc = min(max(t, 0.0), dur)
        phase = 2.0 * math.pi * (f0 * tc + 0.5 * rate * tc * tc)
        if t > dur:  # keep the final frequency after the sweep
            phase += 2.0 * math.pi * f1 * (t - dur)
        return bias + amp * math.sin(phase)

    return chirp


#: Shortest hold of a ``random`` command [s]: far below the valve's 30-ms spool time, and it bounds the
#: number of levels a run draws (1000 per second).
MIN_HOLD_S = 1e-3


def _random(spec: str, v: dict) -> InputSignal:
    lo, hi, hmin, hmax = v["lo"], v["hi"], v["hold_min"], v["hold_max"]
    if lo > hi:
        raise ValueError(f"input spec {spec!r}: lo ({lo}) must not exceed hi ({hi})")
    if not MIN_HOLD_S <= hmin <= hmax:
        raise ValueError(f"input spec {spec!r}: need {MIN_HOLD_S:g} s <= hold_min <= hold_max, got {hmin:g}, {hmax:g} "
                         f"(the valve's spool needs 30 ms; shorter holds only make the signal endless)")
    if v["seed"] < 0 or v["seed"] != int(v["seed"]):
        raise ValueError(f"input spec {spec!r}: seed must be a non-negative integer, got {v['seed']}")
    rng = np.random.default_rng(int(v["seed"]))
    # Draw switching times lazily but deterministically: extend the table when t passes its end.
    times, levels = [0.0], [float(rng.uniform(lo, hi))]

    def random_steps(t: float) -> float:
        while times[-1] <= t:
            times.append(times[-1] + float(rng.uniform(hmin, hmax)))
            levels.append(float(rng.uniform(lo, hi)))
        i = int(np.searchsorted(times, t, side="right")) - 1
        return levels[max(i, 0)]

    return random_steps


def _csv_signal(path: str, spec: str) -> InputSignal:
    from tapmuscle.io.recording import read_recording  # recording imports nothing from here

    if not path:
        raise ValueError(f"input spec {spec!r}: csv needs a path, e.g. csv:run.csv")
    rec = read_recording(path)
    t, u = rec.t_s, rec.u_v

    def replay(tq: float) -> float:
        i = int(np.searchsorted(t, tq + 1e-9, side="right")) - 1
        return float(u[min(max(i, 0), len(u) - 1)])

    return replay


_BUILDERS = {"const": _const, "sine": _sine, "step": _step, "steps": _steps, "chirp": _chirp,
             "random": _random}
