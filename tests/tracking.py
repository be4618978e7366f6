"""Where and how the closed-loop tests in third-party masters score tracking."""

import math

import numpy as np

#: Mean |r - l| is taken from here on [s]: after the controller's start-up mode, which lasts 12 s from
#: the start, or from the switch when the controller detects a parallel master's delay (at about 5 s).
TRACKING_FROM_S = 20.0


def tracking_error_mm(t_s, l_mm) -> float:
    """Mean |r - l| [mm] from :data:`TRACKING_FROM_S` on, for the controller FMU's built-in reference
    ``r = 35 + 30 sin(2 pi 0.1 t)`` mm, with ``l_mm`` sampled at the times ``t_s`` [s]."""
    t, l = np.asarray(t_s, dtype=float), np.asarray(l_mm, dtype=float)
    r = 35.0 + 30.0 * np.sin(2 * math.pi * 0.1 * t)
    return float(np.mean(np.abs(r - l)[t >= TRACKING_FROM_S]))
