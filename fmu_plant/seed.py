"""Noise seeds: unsigned 64-bit integers everywhere, carried by an FMU as two FMI Integers.

FMI 2.0 Integers are 32-bit signed, so the plant FMU takes a seed as ``seed`` (its low 32 bits) and
``seed_high`` (its high 32 bits), each the *bit pattern* of an FMI Integer: a seed of 2**31 sets
``seed = -2147483648``. A seed below 2**31 needs ``seed`` alone (``seed_high`` stays 0). The same seed gives the
same noise in the FMU and in :class:`fmu_plant.Plant` directly (``Plant(seed=...)``).
"""

from __future__ import annotations

from typing import Any

__all__ = ["SEED_MAX", "check_seed", "split_seed", "join_seed"]

#: Largest seed: 2**64 - 1.
SEED_MAX = 2 ** 64 - 1


def check_seed(seed: Any, name: str = "seed") -> int:
    """``seed`` as a Python int in ``0 .. 2**64 - 1``; ``ValueError`` naming ``name`` otherwise.

    Parameters
    ----------
    seed : int
        The seed to check (any integer type with ``__index__``, not a bool).
    name : str, optional
        Its name in the error message.
    """
    if isinstance(seed, bool) or not hasattr(seed, "__index__"):
        raise ValueError(f"{name} = {seed!r} must be an integer in 0 .. 2**64 - 1")
    value = int(seed.__index__())
    if not 0 <= value <= SEED_MAX:
        raise ValueError(f"{name} = {value} is outside 0 .. 2**64 - 1 = {SEED_MAX}")
    return value


def _int32(bits: int) -> int:
    return bits - (1 << 32) if bits >= 1 << 31 else bits


def split_seed(seed: int) -> tuple[int, int]:
    """``(seed, seed_high)``: the FMI Integers (signed 32-bit bit patterns) that carry ``seed``.

    Parameters
    ----------
    seed : int
        A seed in ``0 .. 2**64 - 1``.
    """
    value = check_seed(seed)
    return _int32(value & 0xFFFFFFFF), _int32(value >> 32)


def join_seed(low: int, high: int = 0) -> int:
    """The seed two FMI Integers carry (:func:`split_seed`'s inverse).

    Parameters
    ----------
    low : int
        The FMU's ``seed``: the low 32 bits as a signed 32-bit FMI Integer.
    high : int, optional
        The FMU's ``seed_high``: the high 32 bits, likewise; default 0.
    """
    for name, v in (("seed", low), ("seed_high", high)):
        if not -(1 << 31) <= v < 1 << 31:
            raise ValueError(f"{name} = {v} is not a 32-bit FMI Integer")
    return ((high & 0xFFFFFFFF) << 32) | (low & 0xFFFFFFFF)
