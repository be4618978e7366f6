"""Reference trajectories with preview (section 4.1: r = 35 + 30 sin(2 pi f t) mm, f = 0.1 or 0.2 Hz).

Section 4.1 gives the offset, amplitude and frequency; the phase (a sine from its mean, rising, with
the muscle at rest) is this project's reading, and the adaptive controllers' Eq. (21) errors depend
on it (docs/control.md, "The reference's phase is a decision").

The paper's controllers know the future reference ``r(k+i|k)`` (preview); every reference here gives
``at(k)`` (``r(k)`` [mm]) and ``preview(k, n)`` (``r(k..k+n)`` [mm]) on the sampling grid ``ts_s``:
:class:`SineReference` (the paper's), :class:`ArrayReference` (given samples, e.g. from a file) and
:class:`FunctionReference` (any ``r(t)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from .argument_checks import number_array, real_number

__all__ = ["Reference", "SineReference", "ArrayReference", "FunctionReference", "REFERENCE_SOURCES", "as_reference",
           "advanced_lead"]

#: The controller FMU's ``reference_source`` parameter (an Integer) -> where r(k..k+Hp) comes from
#: (fmu_controller.controller_slave explains each).
REFERENCE_SOURCES: dict[int, str] = {1: "builtin_sine", 2: "external_held", 3: "external_advanced"}


def advanced_lead(input_delay_samples: int) -> int:
    """``external_advanced``: how many samples beyond ``Hp`` ahead the host feeds the reference, for the
    controller FMU's ``input_delay_samples``: the delay, and 1 for -1 (which starts with the delayed
    law; should it decide for a longer delay, the samples beyond are the last one fed, held).

    Parameters
    ----------
    input_delay_samples : int
        The controller FMU's ``input_delay_samples`` [samples], or -1.
    """
    return 1 if input_delay_samples == -1 else input_delay_samples


@dataclass(frozen=True, kw_only=True)
class SineReference:
    """``r(t) = offset_mm + amplitude_mm sin(2 pi frequency_hz t)``, sampled every ``ts_s``."""

    offset_mm: float = 35.0
    """Offset [mm] (paper: 35)."""
    amplitude_mm: float = 30.0
    """Amplitude [mm] (paper: 30)."""
    frequency_hz: float = 0.1
    """Frequency [Hz] (paper: 0.1, and 0.2 in section 4.4)."""
    ts_s: float = 0.1
    """Sampling period [s] (paper: 0.1)."""

    def __post_init__(self) -> None:
        for name in ("offset_mm", "amplitude_mm", "frequency_hz", "ts_s"):  # numpy numbers as Python floats
            object.__setattr__(self, name, real_number(getattr(self, name), what=f"SineReference.{name}"))
        if self.frequency_hz < 0:
            raise ValueError(f"SineReference.frequency_hz must be >= 0, got {self.frequency_hz!r}")
        if self.ts_s <= 0:
            raise ValueError(f"SineReference.ts_s must be > 0, got {self.ts_s!r}")
        # 2 pi f [rad/s], cached: the product is formed left to right, so r(k) keeps its last bit
        object.__setattr__(self, "_omega", 2.0 * math.pi * self.frequency_hz)

    def at(self, k: int | np.ndarray) -> float | np.ndarray:
        """``r(k)`` [mm] at sample ``k`` (time ``k ts_s``)."""
        if isinstance(k, (int, np.integer)):
            return self._at(int(k))
        return self.offset_mm + self.amplitude_mm * np.sin(self._omega * np.asarray(k) * self.ts_s)

    def preview(self, k: int, n: int) -> np.ndarray:
        """``[r(k), r(k+1), ..., r(k+n)]`` [mm]: the present and ``n`` future samples."""
        # math.sin: a handful of samples per control step, where numpy's call overhead dominates
        offset, amplitude, omega, ts, sin = self.offset_mm, self.amplitude_mm, self._omega, self.ts_s, math.sin
        return np.array([offset + amplitude * sin(omega * i * ts) for i in range(k, k + n + 1)])

    def _at(self, k: int) -> float:
        return self.offset_mm + self.amplitude_mm * math.sin(self._omega * k * self.ts_s)


class Reference(Protocol):
    """What a closed loop needs from a reference: its grid and its samples with preview."""

    ts_s: float

    def at(self, k: int) -> float:
        """``r(k)`` [mm].

        Parameters
        ----------
        k : int
            Sample index.
        """

    def preview(self, k: int, n: int) -> np.ndarray:
        """``[r(k), ..., r(k+n)]`` [mm].

        Parameters
        ----------
        k : int
            Sample index of the first value.
        n : int
            How many samples beyond ``k`` (``n + 1`` values).
        """


def _check_ts(owner: str, ts_s: float) -> float:
    """``ts_s`` as a Python float > 0 [s], naming ``owner`` otherwise."""
    ts = real_number(ts_s, what=f"{owner}.ts_s")
    if ts <= 0:
        raise ValueError(f"{owner}.ts_s must be a finite number > 0 [s], got {ts_s!r}")
    return ts


@dataclass(frozen=True)
class ArrayReference:
    """``r(k) = values_mm[k]``; past the last sample the last value is held (also in the preview).

    Parameters
    ----------
    values_mm : array_like
        The reference at ``t_k = k ts_s`` [mm], one value per sample, all finite.
    ts_s : float
        Sampling period [s].
    """

    values_mm: np.ndarray = field(repr=False)
    ts_s: float = 0.1

    def __post_init__(self) -> None:
        v = np.array(self.values_mm, dtype=float)
        if v.ndim != 1 or v.size == 0:
            raise ValueError(f"ArrayReference.values_mm must be a non-empty 1-D array, got shape {v.shape}")
        bad = np.nonzero(~np.isfinite(v))[0]
        if bad.size:
            raise ValueError(f"ArrayReference.values_mm[{int(bad[0])}] = {float(v[bad[0]])!r} is not finite")
        object.__setattr__(self, "ts_s", _check_ts("ArrayReference", self.ts_s))
        v.setflags(write=False)
        object.__setattr__(self, "values_mm", v)

    def at(self, k: int) -> float:
        """``r(k)`` [mm]."""
        return float(self.values_mm[min(int(k), len(self.values_mm) - 1)])

    def preview(self, k: int, n: int) -> np.ndarray:
        """``[r(k), ..., r(k+n)]`` [mm]."""
        idx = np.minimum(np.arange(k, k + n + 1), len(self.values_mm) - 1)
        return self.values_mm[idx].copy()


@dataclass(frozen=True)
class FunctionReference:
    """``r(k) = function(k ts_s)`` for any callable of time.

    Parameters
    ----------
    function : callable
        ``r(t)`` [mm] of the time ``t`` [s]; it must return a finite number.
    ts_s : float
        Sampling period [s].
    """

    function: Callable[[float], float]
    ts_s: float = 0.1

    def __post_init__(self) -> None:
        if not callable(self.function):
            raise ValueError(f"FunctionReference.function must be callable r(t) [mm], got {self.function!r}")
        object.__setattr__(self, "ts_s", _check_ts("FunctionReference", self.ts_s))

    def at(self, k: int) -> float:
        """``r(k)`` [mm]; ``ValueError`` naming the time if the function returns a non-finite value."""
        t = k * self.ts_s
        value = self.function(t)
        if np.ndim(value) != 0:
            raise ValueError(f"reference r(t = {t:.12g} s) returned an array of shape {np.shape(value)}, not one "
                             f"number [mm]")
        try:
            r = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"reference r(t = {t:.12g} s) = {value!r} is not a number [mm]") from None
        if not math.isfinite(r):
            raise ValueError(f"reference r(t = {t:.12g} s) = {r!r} is not finite")
        return r

    def preview(self, k: int, n: int) -> np.ndarray:
        """``[r(k), ..., r(k+n)]`` [mm]."""
        return np.array([self.at(i) for i in range(k, k + n + 1)])


def as_reference(reference: "Reference | Callable[[float], float] | np.ndarray | None", ts_s: float) -> Reference:
    """The reference a loop sampled every ``ts_s`` runs on, from any form a caller gives.

    Parameters
    ----------
    reference : Reference, callable, array_like or None
        A reference object (its ``ts_s`` must be the loop's); ``r(t)`` [mm] of the time [s]
        (:class:`FunctionReference`); one value per sample [mm] (:class:`ArrayReference`); None: the
        paper's ``35 + 30 sin(2 pi 0.1 t)`` mm (:class:`SineReference`, section 4.1).
    ts_s : float
        The loop's sampling period [s].

    Raises
    ------
    ValueError
        A reference object on another grid, or samples that are not a non-empty 1-D array of finite
        numbers.
    TypeError
        A string, or anything else that is none of the above.
    """
    if reference is None:
        return SineReference(ts_s=ts_s)
    if all(hasattr(reference, a) for a in ("ts_s", "at", "preview")):  # a Reference (the protocol)
        if abs(reference.ts_s - ts_s) > 1e-12 * ts_s:
            raise ValueError(f"the reference's ts_s = {reference.ts_s!r} s differs from the loop's ts_s = {ts_s!r} s")
        return reference
    if callable(reference):
        return FunctionReference(reference, ts_s)
    return ArrayReference(number_array(reference, what="reference", expected="a function r(t) [mm], samples "
                                       "r(k) [mm], a Reference or None"), ts_s)
