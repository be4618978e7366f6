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

__all__ = ["MLS_BITS", "PROBING_HOLD_SAMPLES", "max_length_sequence", "probe_v"]

#: Register length of the sequence: 2**7 - 1 = 127 bits, longer than any warm-up at the default clock.
MLS_BITS = 7
#: Each bit is held for this many samples (0.4 s at Ts = 0.1 s): the probe's power then lies mostly
#: below 1.25 Hz, the band of the reference and of the Table 5 horizons (0.5 s), and not at the Nyquist
#: frequency. Measured (docs/control.md, "Start-up"): held 4 samples, the cure of the ripple does not
#: depend on where the sequence starts (2-5 % above smooth for three starting bits); held 3, it does.
PROBING_HOLD_SAMPLES = 4


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


def probe_v(sample: int, amplitude_v: float) -> float:
    """The probing signal [V] at ``sample`` (0, 1, ... from the start of the warm-up).

    ``amplitude_v`` times the sequence's sign (+-1), each bit held for :data:`PROBING_HOLD_SAMPLES`
    samples, the sequence repeated after its 127 bits.
    """
    return amplitude_v * _SIGNS[(sample // PROBING_HOLD_SAMPLES) % len(_SIGNS)]
