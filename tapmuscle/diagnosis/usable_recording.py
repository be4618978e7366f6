"""What a recording must be for the diagnosis to run on it: one-dimensional columns of one length,
finite, uniformly sampled, a command that changes, an output that responds, and long enough for its
residual tests and for two training and two held-out blocks; and the blocks' length.

Each refusal names the column and the sample, or states the duration needed.
"""

from __future__ import annotations

import math

import numpy as np

from tapmuscle.diagnosis.residual_analysis import balanced_block_s
from tapmuscle.io.sampling import uniform_sampling

__all__ = ["MIN_SAMPLES", "BLOCK_S", "split_length_s", "validated_recording"]

#: Fewest samples a recording must have (the tests need ~10x their 25 lags per part).
MIN_SAMPLES = 300

#: Default length of the interleaved training / held-out blocks [s]. An edge of a localised effect (a
#: supply sag's start or end) inside a held-out block leaves the training cost flat across the block,
#: so shorter blocks would place it closer; but a block of half an input's period makes every training
#: block see the same half of every cycle (5-s blocks and the paper's 0.1-Hz sine: a valve band in the
#: other half is never trained on). docs/diagnosis.md, step 2, has both measurements.
BLOCK_S = 10.0


def split_length_s(u_v: np.ndarray, ts_s: float, block_s: float | None) -> float:
    """Length of the training / held-out blocks [s] for the command ``u_v``: ``block_s`` as given, or
    by default :data:`BLOCK_S` balanced for a continuous command locked to it
    (:func:`~tapmuscle.diagnosis.residual_analysis.balanced_block_s`, no longer than the quarter of
    the recording that :func:`validated_recording` allows).

    Parameters
    ----------
    u_v : ndarray
        The command [V].
    ts_s : float
        Sampling period [s].
    block_s : float or None
        The block length given [s], or None for the default.
    """
    if block_s is not None:
        return block_s
    # every block holds a sample (a recording sampled more slowly than BLOCK_S: one per block)
    return max(balanced_block_s(u_v, ts_s, BLOCK_S, longest_s=(len(u_v) - 1) * ts_s / 4.0), ts_s)


def validated_recording(t_s: np.ndarray, u_v: np.ndarray, y: np.ndarray, block_s: float | None, *,
                        load_n: np.ndarray | None = None, names: tuple[str, str, str] = ("t_s", "u_v", "l_mm"),
                        units: tuple[str, str] = ("V", "mm")) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``(t, u, y, Ts)`` of a recording the diagnosis can use, or ``ValueError`` naming the column
    (``names``: the time, input and output columns' names; ``units``: the input's and output's) and
    sample (:func:`diagnose`'s Raises). ``block_s`` None checks the default (:func:`split_length_s`).

    Parameters
    ----------
    t_s : ndarray
        Time [s].
    u_v : ndarray
        The input (the command [V]).
    y : ndarray
        The output (the displacement [mm]).
    block_s : float or None
        Length of the training / held-out blocks [s]; None: the default ones
        (:func:`split_length_s`) are checked.
    load_n : ndarray, optional
        Load [N], checked for its length.
    names : tuple of str, optional
        The time, input and output columns' names, for messages.
    units : tuple of str, optional
        The input's and output's units, for messages.
    """
    # copies: the diagnosis keeps them, and a notebook's later `l -= 10` must not change its recording
    t = np.array(t_s, float)
    u = np.array(u_v, float)
    y = np.array(y, float)
    tn, un, yn = names
    for name, arr in ((tn, t), (un, u), (yn, y)):
        if arr.ndim != 1:  # a column vector would broadcast into a matrix further on
            raise ValueError(f"column {name} must be one-dimensional (one value per sample), got shape {arr.shape}")
    for name, arr in ((un, u), (yn, y)) + ((("load_n", load_n),) if load_n is not None else ()):
        if len(arr) != len(t):
            raise ValueError(f"column {name} has {len(arr)} samples, {tn} has {len(t)}")
    if len(t) < 2:  # no sampling period, so no duration to state
        raise ValueError(f"the recording has {len(t)} sample(s); the diagnosis needs at least {MIN_SAMPLES}")
    for name, arr in ((tn, t), (un, u), (yn, y)):
        bad = np.nonzero(~np.isfinite(arr))[0]
        if bad.size:
            raise ValueError(f"column {name}, sample {int(bad[0])}: {float(arr[bad[0]])!r} is not finite")
    ts = uniform_sampling(t, tn).ts_s
    # the duration comes from the period read back from written times, a few ulps off: 20 s at 1 ms
    # is 19.9999999999978 s, and 5-s blocks still fit four times
    duration = (len(t) - 1) * ts
    too_short = _too_short(len(t), ts, duration, block_s)
    if too_short:
        raise ValueError(too_short)
    if float(np.ptp(u)) == 0.0:
        raise ValueError(f"column {un}: the command is constant ({u[0]:g} {units[0]}); nothing excites the plant")
    if float(np.ptp(y)) == 0.0:
        what = "displacement" if yn == "l_mm" else "output"
        raise ValueError(f"column {yn}: the {what} is constant ({y[0]:g} {units[1]}); the recording shows no "
                         "response to compare with the model (a disconnected sensor?)")
    if block_s is None:
        return t, u, y, ts  # the default blocks fit: _too_short
    if math.isfinite(block_s) and 0.0 < block_s < ts:
        # shorter blocks skip block numbers, and with a period of two blocks or more every sample
        # falls in a training block: no held-out sample, every fit NaN
        raise ValueError(f"block_s (--block) = {block_s!r} s is shorter than the sampling period {ts:g} s: every "
                         "training and held-out block must hold a sample")
    if not (math.isfinite(block_s) and 0.0 < block_s <= duration / 4.0 * (1.0 + 1e-9)):
        raise ValueError(f"block_s (--block) = {block_s!r} s: a {duration:g}-s recording needs blocks of more than 0 and at "
                         f"most {duration / 4.0:g} s (two training and two held-out blocks at least)")
    return t, u, y, ts


def _too_short(n: int, ts: float, duration: float, block_s: float | None) -> str | None:
    """Why a recording of ``n`` samples every ``ts`` [s], ``duration`` [s] long, is too short for the
    diagnosis, as a duration (None: long enough). It needs :data:`MIN_SAMPLES` samples (the residual
    tests) and, with the default blocks (``block_s`` None), four of them (two training, two held-out);
    a ``block_s`` given is checked by :func:`validated_recording`, which names it."""
    floor_s = (MIN_SAMPLES - 1) * ts
    what = f"the recording lasts {duration:g} s ({n} samples at {ts:g} s)"
    tests = f"{MIN_SAMPLES} samples, for the residual tests"
    if block_s is not None or floor_s >= 4.0 * max(BLOCK_S, ts):  # the blocks do not set the minimum
        if n >= MIN_SAMPLES:
            return None
        return f"{what}; the diagnosis needs at least {floor_s:g} s at this sampling period ({tests})"
    block = max(BLOCK_S, ts)
    if n >= MIN_SAMPLES and duration >= 4.0 * block * (1.0 - 1e-9):
        return None
    why = (f"{what}; the diagnosis needs at least {4.0 * block:g} s with its default {block:g}-s blocks (two training "
           "and two held-out blocks at least); shorter blocks (block_s, --block) lower that to four times their length")
    if n >= MIN_SAMPLES:
        return f"{why}: this recording takes blocks of at most {duration / 4.0:g} s"
    return f"{why}, but not below {floor_s:g} s at this sampling period ({tests})"
