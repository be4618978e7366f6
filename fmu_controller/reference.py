"""Reference trajectories with preview (section 4.1: r = 35 + 30 sin(2 pi f t) mm, f = 0.1 or 0.2 Hz).

The paper's controllers know the future reference ``r(k+i|k)`` (preview); :meth:`SineReference.preview`
returns it exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SineReference", "REFERENCE_SOURCES"]

#: The controller FMU's ``reference_source`` parameter (an Integer) -> where r(k..k+Hp) comes from
#: (fmu_controller.controller_slave explains each).
REFERENCE_SOURCES: dict[int, str] = {1: "builtin_sine", 2: "external_held", 3: "external_advanced"}


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
        for name in ("offset_mm", "amplitude_mm", "frequency_hz", "ts_s"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"SineReference.{name} must be a finite number, got {v!r}")
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
