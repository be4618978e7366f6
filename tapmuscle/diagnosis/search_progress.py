"""The progress report of a diagnosis: one fraction of the whole over its phases, never decreasing.

A diagnosis calibrates the nominal constants, searches for left-out effects in rounds (each: the
current model re-fitted as the reference, the candidates' own fits, the joint re-fits of the most
promising with the constants, then the tests and the backward step), and re-fits the final model.
How many rounds it takes is known only at its end: it stops when no candidate passes, when the
residual is white or at ``max_effects``. A count of candidate fits per round would stand still
through the calibration, reach its total at the end of one round's fits and fall back in the next.

*Decided:* each phase has a fixed share of the whole: :data:`CALIBRATION_SHARE` first,
:data:`FINAL_SHARE` last, and the rounds the rest, the first :data:`FIRST_ROUND_WEIGHT` times as
wide as each later one, up to as many rounds as ``max_effects`` and the candidates allow; each round
is split by :data:`ROUND_PARTS`. The shares are those the phases took on recordings of 1 minute to
4 hours (docs/diagnosis.md, "Progress"). A round the search does not need is passed over at once;
a round beyond those planned (the backward step dropped an effect, which makes room for another)
gets half of what is left before the final re-fit. The report is at 100 % when the diagnosis returns.

The reporter gets ``(done, total)`` in :data:`UNITS` of the whole; a
:class:`~tapmuscle.progress.Progress` also gets the phase as its detail
(``round 2 of at most 3: joint re-fits 1/3``).
"""

from __future__ import annotations

from typing import Any, Callable

from tapmuscle.progress import Progress

__all__ = ["SearchProgress", "UNITS", "CALIBRATION_SHARE", "FINAL_SHARE", "FIRST_ROUND_WEIGHT", "ROUND_PARTS",
           "REFERENCE", "OWN_FITS", "JOINT_REFITS", "TESTS"]

#: The whole diagnosis, in the reporter's units.
UNITS = 1000
#: Share of the whole before the first round: the nominal run and the calibration of the constants.
CALIBRATION_SHARE = 0.10
#: Share of the whole after the last round: the final model's calibration and joint re-fit.
FINAL_SHARE = 0.10
#: The first round's weight among the planned rounds (each later one weighs 1): it fits every
#: candidate, and from two starts where the constants were calibrated.
FIRST_ROUND_WEIGHT = 2.0
#: The parts of a search round, as the report names them: the current model re-fitted as the round's
#: reference, the candidates' own fits, their joint re-fits with the constants, and the held-out
#: tests, the accepted effect's own search again and the backward step ...
REFERENCE, OWN_FITS, JOINT_REFITS, TESTS = "reference re-fit", "own fits", "joint re-fits", "tests"
#: ... and their shares of the round.
ROUND_PARTS = {REFERENCE: 0.1, OWN_FITS: 0.5, JOINT_REFITS: 0.3, TESTS: 0.1}


class SearchProgress:
    """Reports a diagnosis's progress through ``report`` (None: nothing), monotonically.

    Parameters
    ----------
    report : callable or None
        ``report(done, total)`` (and, for a :class:`~tapmuscle.progress.Progress`, the phase as
        ``detail``), with ``total`` = :data:`UNITS`.
    calibrating : bool
        Whether the diagnosis calibrates the nominal constants (otherwise that share goes to the
        rounds).
    """

    def __init__(self, report: Callable[..., Any] | None, *, calibrating: bool) -> None:
        self.report = report
        self._labelled = isinstance(report, Progress)
        self._calibration = CALIBRATION_SHARE if calibrating else 0.0
        self._rounds_end = 1.0 - FINAL_SHARE
        self._planned = 0
        self._done = 0  # units reported so far
        self._round_span = (self._calibration, self._rounds_end)  # the current round's share of the whole

    def start(self) -> None:
        """The diagnosis starts: the nominal run and (if any) the calibration."""
        self._emit(0.0, "calibrating the nominal constants" if self._calibration else "the nominal run")

    def plan(self, rounds: int) -> None:
        """The search will take at most ``rounds`` rounds."""
        self._planned = max(int(rounds), 0)

    def begin_round(self, round_no: int) -> None:
        """Round ``round_no`` (from 1) starts, with its reference re-fit."""
        self._round_span = self._next_round(round_no)
        self.round(round_no, REFERENCE)

    def round(self, round_no: int, part: str, done: int = 0, total: int = 0) -> None:
        """Round ``round_no`` is in ``part`` (a key of :data:`ROUND_PARTS`), ``done`` of its ``total``
        steps (0: a part not counted in steps)."""
        lo, hi = self._round_span
        before = 0.0
        for name, share in ROUND_PARTS.items():
            if name == part:
                break
            before += share
        within = before + ROUND_PARTS[part] * (min(done, total) / total if total else 0.0)
        most = f" of at most {self._planned}" if round_no <= self._planned else ""
        self._emit(lo + (hi - lo) * within, f"round {round_no}{most}: {part}" + (f" {done}/{total}" if total else ""))

    def counter(self, round_no: int, part: str, total: int) -> Callable[[], None]:
        """Reports ``part`` of round ``round_no`` at 0 of ``total`` steps now, and returns what to
        call as each step is done."""
        done = [0]
        self.round(round_no, part, 0, total)

        def step() -> None:
            done[0] += 1
            self.round(round_no, part, done[0], total)
        return step

    def final(self) -> None:
        """The search is over: the final model's calibration and re-fit."""
        self._emit(self._rounds_end, "re-fitting the final model")

    def finish(self) -> None:
        """The diagnosis is done: 100 %."""
        self._emit(1.0, "done")

    def _next_round(self, round_no: int) -> tuple[float, float]:
        """The share of the whole [from, to] of round ``round_no``: its planned place, or half of what
        is left before the final re-fit for a round beyond the plan; never before what was reported."""
        now = self._done / UNITS
        if round_no <= self._planned:
            unit = (self._rounds_end - self._calibration) / (FIRST_ROUND_WEIGHT + self._planned - 1)
            lo = self._calibration + (0.0 if round_no == 1 else (FIRST_ROUND_WEIGHT + round_no - 2) * unit)
            hi = lo + (FIRST_ROUND_WEIGHT if round_no == 1 else 1.0) * unit
            return max(lo, now), max(hi, now)
        return now, now + (self._rounds_end - now) / 2.0

    def _emit(self, fraction: float, phase: str) -> None:
        done = max(self._done, min(UNITS, int(UNITS * fraction)))
        self._done = done
        if self.report is None:
            return
        if self._labelled:
            self.report(done, UNITS, phase)
        else:
            self.report(done, UNITS)
