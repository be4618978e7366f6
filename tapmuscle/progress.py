"""Progress reports on stderr for long runs: a bar on a terminal, lines in a log or a notebook.

The command line reports every long run with a :class:`Progress`; the Python API's long calls
(``tm.diagnose``, ``tm.sweep``, ``tm.run_closed_loop``, ``tm.simulate_closed_loop``) take
``progress=True`` for the same report (:func:`reporter`), or any callable ``progress(done, total)``.

A run never goes quiet for more than 5 s: besides each update, a heartbeat re-reports the last state
with the elapsed time when nothing has been written for :data:`HEARTBEAT_TTY_S` (a terminal: the
bar's clock keeps moving) or :data:`HEARTBEAT_LOG_S` (a log file or CI: a "still running" line).
The heartbeat lasts as long as the call that reports: the outermost of this project's functions on
the reporting thread's stack at the first report (the command's ``main``, or ``tm.run_closed_loop``
called from a notebook). A call ended by an exception (a notebook's interrupt) stops it, though the
notebook still holds the ``Progress``.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import weakref
from typing import Any, Callable, TextIO

from fmu_plant.user_warning import in_project

__all__ = ["Progress", "reporter", "HEARTBEAT_TTY_S", "HEARTBEAT_LOG_S"]

#: Longest silence on a terminal [s].
HEARTBEAT_TTY_S = 5.0
#: Longest silence in a log (not a terminal) [s]; updates there also come every 10 %.
HEARTBEAT_LOG_S = 5.0

#: What ends a redrawn bar on a terminal beyond the spaces that cover a longer line before it: the
#: erase-to-end-of-line sequence, which covers wide characters too, but not on Windows, whose
#: console shows it as "<-[K" unless a program switches its VT processing on.
_ERASE_REST = "" if os.name == "nt" else "\033[K"


class Progress:
    """Callable ``progress(done, total)`` that reports on ``stream`` (default stderr).

    Silent when ``enabled`` is false or the run is short (fewer than ``min_total`` units). The
    heartbeat (module docstring) runs in a daemon thread from the first report to the last.

    Parameters
    ----------
    label : str
        What the report lines start with (``sweep:  40% (4/10, 12.3 s)``).
    enabled : bool
        False: report nothing (``--quiet``).
    stream : text stream, optional
        Where to write (default ``sys.stderr``): a bar where it is a terminal, a line every 10 % and a
        "still running" line after :data:`HEARTBEAT_LOG_S` without one elsewhere (a log, a notebook).
    min_total : int
        Runs of fewer units than this report nothing (default 1: every run; the command line's
        ``record`` and ``run`` stay quiet under 500 samples, a few seconds).
    counts : bool
        Show ``done/total`` in a log's lines (``sweep:  40% (4/10, 12.3 s)``); False: the percentage,
        the time and the detail only (``diagnose:  24% (61.2 s)  round 1 of at most 3: own fits 9/18``),
        for units that mean nothing to the reader (a diagnosis's thousandths of its work).

    Attributes
    ----------
    why_waiting : callable or None
        ``why_waiting()`` is asked at each heartbeat for what the run waits on (``"no worker
        connected for 12 s"``), said in the heartbeat instead of "still running"; None (default),
        or a None it returns: "still running".
    """

    def __init__(self, label: str, *, enabled: bool = True, stream: TextIO | None = None,
                 min_total: int = 1, counts: bool = True) -> None:
        self.label, self.enabled, self.min_total, self.counts = label, enabled, min_total, counts
        self.stream = stream if stream is not None else sys.stderr
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_decile = -1
        self._t0 = time.monotonic()
        self._lock = threading.Lock()
        self._state: tuple[int, int, str] | None = None
        self._last_write = self._t0
        self._shown = 0  # characters of the bar's line on the terminal now
        self._heart: threading.Thread | None = None
        self._ended = threading.Event()  # wakes the heartbeat at the end of its run
        self._owner: tuple[int, int, object] | None = None  # (thread, frame id, code) of the reporting call
        self.why_waiting: Callable[[], str | None] | None = None

    @property
    def heartbeat_s(self) -> float:
        """The longest silence allowed on this stream [s]."""
        return HEARTBEAT_TTY_S if self._tty else HEARTBEAT_LOG_S

    def __call__(self, done: int, total: int, detail: str = "") -> None:
        """Report ``done`` of ``total`` units; ``detail`` (e.g. ``3 failed, 10 remaining``) is appended."""
        if not self.enabled or total < self.min_total:
            return
        before = self._state
        # the same Progress given to another run, which counts from below the last report: afresh (one
        # run's count never decreases)
        again = before is not None and done < before[0]
        beating = self._heart is not None and self._heart.is_alive()
        if again:
            self._t0, self._last_decile = time.monotonic(), -1
        with self._lock:
            self._state = (done, total, detail)
            self._render(done, total, detail, heartbeat=False)
        if done < total and (again or not beating):
            self._owner = _reporting_call(sys._getframe(1))
        if done < total and not beating:
            # the thread holds only a weak reference: when the command is over and its Progress is
            # gone, the heartbeat stops too (a run that ends early never reaches done == total)
            self._ended = threading.Event()
            self._heart = threading.Thread(target=_beat, args=(weakref.ref(self), self._ended),
                                           name=f"progress-{self.label}", daemon=True)
            self._heart.start()
        elif done >= total and beating:
            # gone when the call returns: a fork right after it (multiprocessing's on Linux) warns of
            # a running thread from Python 3.12
            self._ended.set()
            self._heart.join(timeout=1.0)

    def _render(self, done: int, total: int, detail: str, *, heartbeat: bool) -> None:
        frac = done / total if total else 1.0
        extra = f"  {detail}" if detail else ""
        elapsed = time.monotonic() - self._t0
        why = self._why() if heartbeat else None
        if why:
            extra += f"  ({why})"
        if self._tty:
            bar = "#" * int(30 * frac)
            line = f"{self.label} [{bar:<30}] {100 * frac:5.1f}% {elapsed:6.1f} s{extra}"
            self.stream.write(f"\r{line:<{self._shown}}{_ERASE_REST}")
            self._shown = len(line)
            if done >= total:
                self.stream.write("\n")
                self._shown = 0
        else:
            decile = int(10 * frac)
            if decile > self._last_decile or heartbeat:
                self._last_decile = max(decile, self._last_decile)
                still = "  (still running)" if heartbeat and not why else ""
                count = f"{done}/{total}, " if self.counts else ""
                self.stream.write(f"{self.label}: {100 * frac:3.0f}% ({count}{elapsed:.1f} s){extra}{still}\n")
            else:
                return
        self.stream.flush()
        self._last_write = time.monotonic()

    def _why(self) -> str | None:
        """What :attr:`why_waiting` says, None where it is not set or fails (a report never stops a run)."""
        if self.why_waiting is None:
            return None
        try:
            return self.why_waiting()
        except Exception:  # noqa: BLE001 - a heartbeat's words are not worth a failed run
            return None

    def _beat_once(self) -> bool:
        """Re-report if silent too long; False once the run is complete."""
        with self._lock:
            if self._state is None:
                return True
            done, total, detail = self._state
            if done >= total or not _running(self._owner):
                return False
            if time.monotonic() - self._last_write >= self.heartbeat_s:
                self._render(done, total, detail, heartbeat=True)
        return True


def reporter(progress: Any, label: str, *, counts: bool = True) -> Any:
    """What a ``progress=`` argument of the Python API stands for: ``True`` is a :class:`Progress`
    labelled ``label`` on stderr, reporting from the first unit (showing ``done/total`` if ``counts``);
    ``None`` or ``False`` none; a callable is called as it is (``progress(done, total)``). Anything else
    is refused, naming it.

    Parameters
    ----------
    progress : bool, callable or None
        The ``progress=`` argument as given.
    label : str
        The label of a :class:`Progress` made for ``True``.
    counts : bool, optional
        Whether that :class:`Progress` shows ``done/total``; default True.
    """
    if progress is None or progress is False:
        return None
    if progress is True:
        return Progress(label, counts=counts)
    if callable(progress):
        return progress
    raise TypeError(f"progress must be True, False, None or a callable progress(done, total), got {progress!r}")


def _reporting_call(frame: Any) -> tuple[int, int, object]:
    """``(thread id, frame id, code)`` of the outermost frame of this project's packages above
    ``frame`` (``frame`` itself if there is none), on the current thread. Ids, not the frame: holding
    a frame would keep its locals (a run's arrays) alive."""
    owner = frame
    while frame is not None:
        if in_project(frame):
            owner = frame
        frame = frame.f_back
    return threading.get_ident(), id(owner), owner.f_code


def _running(owner: tuple[int, int, object] | None) -> bool:
    """Whether the call :func:`_reporting_call` named is still on its thread's stack."""
    if owner is None:
        return True
    thread, frame_id, code = owner
    frame = sys._current_frames().get(thread)
    while frame is not None:
        if id(frame) == frame_id and frame.f_code is code:
            return True
        frame = frame.f_back
    return False


def _beat(ref: "weakref.ReferenceType[Progress]", ended: threading.Event) -> None:
    while True:
        progress = ref()
        if progress is None:
            return
        pause = min(1.0, progress.heartbeat_s / 5)
        if not progress._beat_once():
            return
        del progress
        if ended.wait(pause):
            return
