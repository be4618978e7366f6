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
``csv``     replay the ``u_v`` column of a recording (``csv:PATH``)    (the path)
            sample by sample (:class:`Replay`)
==========  =========================================================  ==============================

Values are in volts and seconds. :func:`parse_input_spec` validates the spec and raises
``ValueError`` naming the bad kind, key or value.

*Decided:* a replay goes sample by sample, on the recording's uniform grid, with time counted from
its first sample: command ``u_k`` of row ``k`` is applied from ``k Ts`` to ``(k+1) Ts``, as the
diagnosis simulates the recording (times that start anywhere, a logger's jitter taken as on the
grid, docs/recordings.md). A run that would need another command than the recorded ones is refused,
naming both values: a sampling period other than the recording's (a resampled command is not the
recorded one: decimation drops commands and moves edges by up to a period), or a run longer than the
recording (there is no command after its end).
"""

from __future__ import annotations

import bisect
import math
from typing import Callable

import numpy as np

__all__ = ["InputSignal", "Replay", "parse_input_spec", "SPEC_KINDS"]

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


def parse_input_spec(spec: str, *, run_duration_s: float | None = None,
                     run_ts_s: float | None = None) -> InputSignal:
    """Turn a spec string into a command signal ``u(t)`` [V].

    Parameters
    ----------
    spec : str
        See the module docstring, e.g. ``"sine:bias=5,amp=3,freq=0.1"`` or ``"csv:run.csv"``.
    run_duration_s : float, optional
        The length of the run the signal is for [s]: a ``chirp`` without ``duration=`` sweeps over
        it, so that it reaches ``f1`` by the end (without it, over 240 s); a ``csv`` replay must
        hold a command for each of its samples.
    run_ts_s : float, optional
        The sampling period of the run the signal is for [s]: a ``csv`` replay must be run at its
        recording's period (to 0.1 %), and then counts its samples on the run's grid.

    Raises
    ------
    ValueError
        Unknown kind or key, a value that is not a finite number, or an impossible combination
        (negative frequency, ``lo > hi``, a period <= 0, an empty ``levels`` list). A ``csv``
        replay for a run at another sampling period than its recording's, or longer than it, naming
        both. A missing or malformed ``csv:`` file raises the recording reader's error, which names
        file and line.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"input spec must be a non-empty string like 'sine:bias=5,amp=3,freq=0.1', got {spec!r}")
    kind, _, rest = spec.strip().partition(":")
    kind = kind.strip().lower()
    if kind == "csv":
        return _csv_signal(rest.strip(), spec, run_duration_s, run_ts_s)
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
        # bisect on the list itself: np.searchsorted would copy the whole table into an array at every
        # call, which made a long run quadratic in its number of holds
        i = bisect.bisect_right(times, t) - 1
        return levels[max(i, 0)]

    return random_steps


class Replay:
    """The ``u_v`` column of a recording as a command signal, sample by sample.

    ``u(t) = u_k`` for ``k Ts <= t < (k+1) Ts``: time counts from the recording's first sample, and
    its samples are taken as on a uniform grid of period ``Ts``, as the recording reader and the
    diagnosis take them (a recording whose times start anywhere, a logger's jitter).

    Parameters
    ----------
    u_v : array_like
        The recorded commands [V], one per sample.
    ts_s : float
        The grid's period [s].
    source : str
        What the commands are (a file name), for the messages.

    Raises
    ------
    ValueError
        No command or a period that is not > 0 (naming ``source``); on a call at a time before the
        first sample or past the last one's period (there is no command there), naming the time and
        the recording's span.
    """

    def __init__(self, u_v: np.ndarray, ts_s: float, source: str) -> None:
        self.u_v = np.asarray(u_v, dtype=float)
        if self.u_v.ndim != 1 or not self.u_v.size:
            raise ValueError(f"{source}: a replay needs one command per sample, got shape {self.u_v.shape}")
        self.ts_s = float(ts_s)
        if not (math.isfinite(self.ts_s) and self.ts_s > 0.0):
            raise ValueError(f"{source}: the replay's period must be a finite number of seconds > 0, got {ts_s!r}")
        self.source = source

    @property
    def duration_s(self) -> float:
        """Time from the first sample to the last [s]: ``(len - 1) ts_s``."""
        return (len(self.u_v) - 1) * self.ts_s

    def __call__(self, t: float) -> float:
        k = math.floor(t / self.ts_s + 1e-6)  # a time on the grid, to rounding, is its sample's
        if not 0 <= k < len(self.u_v):
            raise ValueError(f"{self.source} holds {len(self.u_v)} commands every {self.ts_s:g} s, from 0 to "
                             f"{self.duration_s:g} s (time from its first sample): none at t = {t:.12g} s")
        return float(self.u_v[k])


def _csv_signal(path: str, spec: str, run_duration_s: float | None, run_ts_s: float | None) -> Replay:
    from tapmuscle.io.recording import read_recording  # recording imports nothing from here
    from tapmuscle.io.sampling import STRICT_TOLERANCE

    if not path:
        raise ValueError(f"input spec {spec!r}: csv needs a path, e.g. csv:run.csv")
    rec = read_recording(path)
    try:
        ts = rec.ts_s  # the grid its samples are taken on, as every tool takes them
    except ValueError as exc:
        raise ValueError(f"input spec {spec!r}: {path}: {exc}") from None
    if run_ts_s is not None:
        if abs(run_ts_s - ts) > STRICT_TOLERANCE * ts:
            raise ValueError(f"input spec {spec!r}: {path} is sampled every {ts:g} s, the run every {run_ts_s:g} s: "
                             f"a replay goes sample by sample; run it at {ts:g} s, or resample the recording "
                             "to the run's period first")
        ts = run_ts_s  # the run's grid: its k-th sample is the recording's k-th
    replay = Replay(rec.u_v, ts, str(path))
    if run_duration_s is not None:
        n = int(round(run_duration_s / ts)) + 1
        if n > len(rec):
            raise ValueError(f"input spec {spec!r}: the run's duration {run_duration_s:g} s ({n} samples) is longer "
                             f"than {path}'s {replay.duration_s:g} s ({len(rec)} samples every {ts:g} s): there is "
                             f"no command after its end; run for at most {replay.duration_s:g} s")
    return replay


_BUILDERS = {"const": _const, "sine": _sine, "step": _step, "steps": _steps, "chirp": _chirp,
             "random": _random}
