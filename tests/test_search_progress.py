"""A diagnosis's progress report (tapmuscle/diagnosis/search_progress.py): one fraction over its
phases that never decreases, reaches 100 % at the end and names the phase on the command line's
report."""

from __future__ import annotations

import importlib
import io

import numpy as np
import pytest

from tapmuscle.diagnosis import diagnose
from tapmuscle.diagnosis.demo import DEMO_MODEL, record
from tapmuscle.diagnosis.search_progress import (CALIBRATION_SHARE, FINAL_SHARE, JOINT_REFITS, OWN_FITS, TESTS, UNITS,
                                                 SearchProgress)
from tapmuscle.progress import Progress


class _Phases(Progress):
    """A Progress that keeps every report with its phase in ``events`` (and writes into a string)."""

    def __init__(self, events: list[tuple]) -> None:
        super().__init__("diagnose", stream=io.StringIO(), min_total=1, counts=False)
        self.events = events
        self.reports: list[tuple[int, int, str]] = []

    def __call__(self, done: int, total: int, detail: str = "") -> None:
        self.reports.append((done, total, detail))
        self.events.append(("report", done, detail))
        super().__call__(done, total, detail)


@pytest.fixture(scope="module")
def delayed_rig():
    """A 60-s random-steps recording of a rig whose valve acts 0.3 s late: a calibration and a round
    that accepts the delay."""
    cols = record(DEMO_MODEL.with_values(**{"delay.delay_s": 0.3}), "steps", 0, duration_s=60.0)
    return {k: cols[k] for k in ("t_s", "u_v", "l_mm")}


def test_the_reported_fraction_never_decreases_over_a_diagnosis_and_ends_at_100(delayed_rig, monkeypatch):
    """Counting candidate fits per round, the report stood at 0 % through the calibration, reached
    100 % at the end of the first round's fits and fell back to 59 % in the second. Over the phases,
    it rises to 100 %, each own fit is reported as it ends (also when the fits run in this process),
    and the Progress is told the phase."""
    events: list[tuple] = []
    own_fit = importlib.import_module("tapmuscle.diagnosis.joint_fits").own_fit

    def fit_then_note(*args):
        out = own_fit(*args)
        events.append(("fit",))
        return out

    # where the rounds' own fits are started, and where an effect is fitted afresh on re-fitted constants
    for module in ("tapmuscle.diagnosis.joint_fits", "tapmuscle.diagnosis.diagnose"):
        monkeypatch.setattr(importlib.import_module(module), "own_fit", fit_then_note)
    report = _Phases(events)
    d = diagnose(delayed_rig["t_s"], delayed_rig["u_v"], delayed_rig["l_mm"], DEMO_MODEL, progress=report,
                 candidates=["transport_delay", "sensor_drift", "supply_pressure_variation"])
    assert d.named == ["transport_delay"]
    done = [r[0] for r in report.reports]
    assert all(r[1] == UNITS for r in report.reports)
    assert done[0] == 0 and done[-1] == UNITS and all(b >= a for a, b in zip(done, done[1:])), done
    assert done.count(UNITS) == 1  # 100 % only at the end
    phases = [r[2] for r in report.reports]
    assert phases[0] == "calibrating the nominal constants" and phases[-1] == "done"
    assert phases[-2] == "re-fitting the final model"
    # the calibration's share is reported once it is over, the final re-fit's from its start
    assert done[phases.index("round 1 of at most 3: reference re-fit")] == int(UNITS * CALIBRATION_SHARE)
    assert done[-2] == int(UNITS * (1 - FINAL_SHARE))
    # the rounds' parts in order, own fits counted one by one (from two starts in round 1)
    own = [p for p in phases if p.startswith(f"round 1 of at most 3: {OWN_FITS} ")]
    assert own == [f"round 1 of at most 3: {OWN_FITS} {i}/6" for i in range(7)]
    first = [p.split(": ", 1)[1].rsplit(" ", 1)[0] if p[-1].isdigit() else p.split(": ", 1)[1]
             for p in phases if p.startswith("round 1 ")]
    assert list(dict.fromkeys(first)) == ["reference re-fit", OWN_FITS, JOINT_REFITS, TESTS]
    # the residual is white once the delay is in: the rounds planned after it are passed over
    assert not any(p.startswith("round 2 ") for p in phases)
    # each own fit is reported when it ends, not all of them after the last
    fits_and_counts = [e for e in events if e[0] == "fit" or OWN_FITS in e[-1]]
    counted = [e for e in fits_and_counts if e[0] == "report" and not e[-1].endswith(" 0/6")]
    assert len(counted) >= 6
    for k, e in enumerate(fits_and_counts):
        if e[0] == "report" and e in counted[:6]:
            assert fits_and_counts[k - 1] == ("fit",), fits_and_counts
    # the log's lines: the percentage, the time and the phase (no thousandths of the work)
    lines = report.stream.getvalue().splitlines()
    assert lines[0].startswith("diagnose:   0% (") and lines[0].endswith(" s)  calibrating the nominal constants")
    assert lines[-1].startswith("diagnose: 100% (") and lines[-1].endswith(" s)  done")


def test_a_plain_callable_gets_done_and_total_only(delayed_rig):
    calls = []
    diagnose(delayed_rig["t_s"], delayed_rig["u_v"], delayed_rig["l_mm"], DEMO_MODEL, calibration=None,
             candidates=["transport_delay"], progress=lambda done, total: calls.append((done, total)))
    assert calls[0] == (0, UNITS) and calls[-1] == (UNITS, UNITS)
    assert all(b[0] >= a[0] for a, b in zip(calls, calls[1:]))


def test_skipped_and_extra_rounds_keep_the_fraction_rising():
    """A search that stops after its first round passes over the others; a round beyond those planned
    (a removal made room) takes half of what is left before the final re-fit; nothing goes back."""
    seen = []
    p = SearchProgress(lambda done, total: seen.append(done), calibrating=True)
    p.start()
    p.plan(2)
    for round_no in (1, 2, 3, 4):  # two beyond the plan
        p.begin_round(round_no)
        step = p.counter(round_no, OWN_FITS, 4)
        for _ in range(4):
            step()
        p.counter(round_no, JOINT_REFITS, 2)()
        p.round(round_no, TESTS)
    p.final()
    p.finish()
    assert seen[0] == 0 and seen[-1] == UNITS and all(b >= a for a, b in zip(seen, seen[1:]))
    assert seen[-2] == int(UNITS * (1 - FINAL_SHARE)) > max(seen[:-2])
    # the planned rounds fill the span between the calibration and the final re-fit, the first twice
    # as wide as the second; the extra ones stay below the final re-fit's start
    stopped = []
    q = SearchProgress(lambda done, total: stopped.append(done), calibrating=False)
    q.start()
    q.plan(3)
    q.begin_round(1)
    assert stopped[-1] == 0
    q.final()
    assert stopped[-1] == int(UNITS * (1 - FINAL_SHARE))
    q.finish()
    assert stopped[-1] == UNITS and np.all(np.diff(stopped) >= 0)


def test_without_a_reporter_nothing_is_called():
    p = SearchProgress(None, calibrating=True)
    p.start()
    p.plan(1)
    p.begin_round(1)
    p.counter(1, OWN_FITS, 2)()
    p.finish()
