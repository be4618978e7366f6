"""The start-up mode's probing signal: a maximum-length sequence added to the valve command.

An adaptive controller identifies its plant in closed loop, where the command is a function of the
measurement. A gentle start (the reference led in from rest) then leaves Algorithm 1 with regressors
that barely excite the directions separating ``b1`` from ``a1, a2`` and the hysteresis terms, and the
estimate drifts along them to wherever the feedback law makes the data consistent: on the simulated
rig ``b1`` sinks to the Table 2 box's lower bound within 20 s, a model whose input gain is too low,
and the servo law answers the cycle's turning points with a period-2 ripple. The classic remedy is a
persistently exciting input during the estimator's warm-up (Astrom and Wittenmark, *Adaptive
Control*, on persistent excitation and perturbation signals), while the law still runs on the prior ``theta0``: a pseudo-random binary
sequence, whose spectrum is flat up to its clock frequency and whose sign carries no information
about the loop's state.

The sequence is the 127-bit maximum-length sequence of a 7-bit linear feedback shift register with
the feedback polynomial ``x^7 + x^6 + 1`` (all-ones seed), the same as ``scipy.signal.max_len_seq(7)``
(written out here so that the controller FMU does not import ``scipy.signal``, a third of a second
per instantiation).
"""

from __future__ import annotations

import numbers

import numpy as np

__all__ = ["MLS_BITS", "MLS_LENGTH", "PROBING_HOLD_SAMPLES", "max_length_sequence", "probe_v", "probing_phases"]

#: Register length of the sequence: 2**7 - 1 = 127 bits, longer than any warm-up at the default clock.
MLS_BITS = 7
#: Each bit is held for this many samples (0.4 s at Ts = 0.1 s): the probe's power then lies mostly
#: below 1.25 Hz, the band of the reference and of the Table 5 horizons (0.5 s), and not at the Nyquist
#: frequency. Measured (docs/control.md, "Start-up"): held 4 samples, the cure of the ripple does not
#: depend on where the sequence starts (2-5 % above smooth for three starting bits); held 3, it does.
PROBING_HOLD_SAMPLES = 4
#: Bits of the sequence before it repeats: ``2**MLS_BITS - 1``; a probe may start at any of them
#: (``ControllerSettings.probing_phase``, 0 .. ``MLS_LENGTH - 1``).
MLS_LENGTH = 2 ** MLS_BITS - 1


def max_length_sequence(nbits: int = MLS_BITS) -> tuple[int, ...]:
    """The ``2**nbits - 1`` bits (0/1) of the maximum-length sequence for ``nbits`` = 7.

    Fibonacci form of ``scipy.signal.max_len_seq``: an all-ones register, one tap at position 6.

    Parameters
    ----------
    nbits : int
        Register length; only 7 is tabulated (its tap).

    Returns
    -------
    tuple of int
        The sequence, first bit first.
    """
    taps = {7: (6,)}
    if nbits not in taps:
        raise ValueError(f"nbits must be one of {sorted(taps)}, got {nbits!r}")
    state = [1] * nbits
    seq = []
    idx = 0
    for _ in range(2 ** nbits - 1):
        feedback = state[idx]
        seq.append(feedback)
        for tap in taps[nbits]:
            feedback ^= state[(tap + idx) % nbits]
        state[idx] = feedback
        idx = (idx + 1) % nbits
    return tuple(seq)


_SIGNS = tuple(2.0 * b - 1.0 for b in max_length_sequence())


def probe_v(sample: int, amplitude_v: float, phase_bits: int = 0) -> float:
    """The probing signal [V] at ``sample`` (0, 1, ... from the start of the warm-up).

    ``amplitude_v`` times the sequence's sign (+-1), each bit held for :data:`PROBING_HOLD_SAMPLES`
    samples, starting at bit ``phase_bits`` of the sequence and repeated after its 127 bits. Two
    probes of different phases are two shifts of one maximum-length sequence, whose correlation over
    the whole period is -1/127; over a warm-up of a few bits it may be large (:func:`probing_phases`
    picks phases that are not).

    Parameters
    ----------
    sample : int
        Sample index from the start of the warm-up.
    amplitude_v : float
        Amplitude of the probe [V].
    phase_bits : int, optional
        The bit of the sequence to start at; default 0.
    """
    return amplitude_v * _SIGNS[(sample // PROBING_HOLD_SAMPLES + phase_bits) % len(_SIGNS)]


def probing_phases(count: int, warm_samples: int = 60) -> tuple[int, ...]:
    """Phases for ``count`` controllers started together whose probes are least alike over the warm-up.

    Over a whole period two shifts of the sequence correlate at -1/127, but a warm-up sees only a few
    bits of it (the default 6 s at Ts = 0.1 s: 60 samples, 15 bits), over which a shift may repeat
    much of the probe (phases 0 and 96: 0.66). Greedy, from phase 0: each next phase is the one whose
    probe's largest absolute correlation with those chosen is least, over the warm-up's samples 1 ..
    ``warm_samples - 1`` (where the controller probes).

    Parameters
    ----------
    count : int
        Controllers, 1 .. 127.
    warm_samples : int
        The warm-up in samples: ``round(startup_s / 2 / ts_s)`` (60 at the defaults), at least 5 (a
        shorter one probes within one bit, the same for every phase). Over a warm-up of a few bits a
        probe may be constant: such probes are compared by the share of samples of one sign.

    Returns
    -------
    tuple of int
        ``count`` phases (``ControllerSettings.probing_phase``, the FMU's ``probing_phase``), 0 first.
    """
    if isinstance(count, bool) or not isinstance(count, numbers.Integral) or not 1 <= count <= MLS_LENGTH:
        raise ValueError(f"count must be an integer 1 .. {MLS_LENGTH}, got {count!r}")
    least = PROBING_HOLD_SAMPLES + 1  # samples 1 .. least - 1 reach the sequence's second bit
    if isinstance(warm_samples, bool) or not isinstance(warm_samples, numbers.Integral) or warm_samples < least:
        raise ValueError(f"warm_samples must be an integer >= {least} (the warm-up in samples; a shorter one probes "
                         f"within one bit, the same for every phase), got {warm_samples!r}")
    probes = np.array([[probe_v(j, 1.0, phase) for j in range(1, int(warm_samples))] for phase in range(MLS_LENGTH)])
    centred = probes - probes.mean(axis=1, keepdims=True)
    spread = np.linalg.norm(centred, axis=1)
    varies = spread > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = np.abs(centred @ centred.T) / np.outer(spread, spread)
    # a probe constant over a short warm-up has no correlation: alike by the share of samples of one sign
    agreement = np.abs(probes @ probes.T) / probes.shape[1]
    likeness = np.where(np.outer(varies, varies), correlation, agreement)
    chosen = [0]
    while len(chosen) < count:
        worst = likeness[:, chosen].max(axis=1)
        worst[chosen] = np.inf
        # equals (to rounding: shifts of one sequence tie exactly) to the lowest phase
        chosen.append(int(np.argmin(np.round(worst, 12))))
    return tuple(chosen)
