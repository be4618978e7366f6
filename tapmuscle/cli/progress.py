"""Progress reports on stderr for long runs: a bar on a terminal, a line every 10% otherwise."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress"]


class Progress:
    """Callable ``progress(done, total)`` that reports on ``stream`` (default stderr).

    Silent when ``enabled`` is false or the run is short (fewer than ``min_total`` units).
    """

    def __init__(self, label: str, *, enabled: bool = True, stream: TextIO | None = None,
                 min_total: int = 500) -> None:
        self.label, self.enabled, self.min_total = label, enabled, min_total
        self.stream = stream if stream is not None else sys.stderr
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_decile = -1
        self._t0 = time.monotonic()

    def __call__(self, done: int, total: int, detail: str = "") -> None:
        """Report ``done`` of ``total`` units; ``detail`` (e.g. ``3 failed, 10 remaining``) is appended."""
        if not self.enabled or total < self.min_total:
            return
        frac = done / total if total else 1.0
        extra = f"  {detail}" if detail else ""
        if self._tty:
            bar = "#" * int(30 * frac)
            self.stream.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}% "
                              f"{time.monotonic() - self._t0:6.1f} s{extra}\033[K")
            if done >= total:
                self.stream.write("\n")
        else:
            decile = int(10 * frac)
            if decile > self._last_decile:
                self._last_decile = decile
                self.stream.write(f"{self.label}: {100 * frac:3.0f}% ({done}/{total}, "
                                  f"{time.monotonic() - self._t0:.1f} s){extra}\n")
        self.stream.flush()
