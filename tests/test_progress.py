"""Progress reports (tapmuscle/progress.py): no run goes quiet for longer than the heartbeat."""

from __future__ import annotations

import gc
import io
import threading
import time

import tapmuscle.progress as progress_module
from tapmuscle.progress import Progress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_silent_stretch_gets_heartbeats_and_they_stop_at_the_end(monkeypatch):
    monkeypatch.setattr(progress_module, "HEARTBEAT_TTY_S", 0.05)
    out = _Tty()
    p = Progress("job", stream=out, min_total=1)
    p(1, 10)
    time.sleep(0.3)  # a long unit of work without an update
    beats = out.getvalue().count("\r")
    assert beats >= 3  # the first report and at least two heartbeats with a moving clock
    p(10, 10)
    n = len(out.getvalue())
    time.sleep(0.2)
    assert len(out.getvalue()) == n and out.getvalue().endswith("\n")  # done: silent


def test_a_log_gets_a_still_running_line(monkeypatch):
    monkeypatch.setattr(progress_module, "HEARTBEAT_LOG_S", 0.05)
    out = io.StringIO()
    p = Progress("job", stream=out, min_total=1)
    p(3, 10)
    time.sleep(0.25)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("job:  30% (3/10") and any(line.endswith("(still running)") for line in lines[1:])


def test_the_heartbeat_ends_with_its_command(monkeypatch):
    monkeypatch.setattr(progress_module, "HEARTBEAT_LOG_S", 0.05)
    out = io.StringIO()

    def command():
        Progress("job", stream=out, min_total=1)(1, 10)  # fails before the end: never done == total

    command()
    gc.collect()
    time.sleep(0.2)
    assert not [t for t in threading.enumerate() if t.name == "progress-job"]


def test_no_stream_is_left_quiet_for_more_than_5_s():
    assert progress_module.HEARTBEAT_TTY_S <= 5.0 and progress_module.HEARTBEAT_LOG_S <= 5.0


def test_the_heartbeat_ends_with_an_interrupted_call_though_its_progress_is_kept(monkeypatch):
    """In a notebook, a Progress passed to tm.run_closed_loop and kept in a variable kept writing
    "(still running)" into later cells after the call was interrupted: the heartbeat lasts as long as
    the call that reports."""
    import pytest

    import tapmuscle as tm

    monkeypatch.setattr(progress_module, "HEARTBEAT_LOG_S", 0.05)
    out = io.StringIO()
    kept = Progress("loop", stream=out, min_total=1)

    def reference(t):
        if t > 5.0:
            raise KeyboardInterrupt  # the notebook's interrupt, inside the run
        return 30.0

    controller = tm.DisplacementController(tm.ControllerSettings(method="mpc_ucp"), tm.THETA0_44N)
    with pytest.raises(KeyboardInterrupt):
        tm.run_closed_loop(tm.Plant(seed=0), controller, reference, duration_s=60.0, progress=kept)
    time.sleep(0.3)
    written = out.getvalue()
    time.sleep(0.3)
    assert out.getvalue() == written and written.startswith("loop:")  # reported while it ran, silent after
    assert not [t for t in threading.enumerate() if t.name == "progress-loop"]


def test_a_progress_given_to_a_second_run_counts_it_afresh(monkeypatch):
    """The same Progress passed to two runs in a script on a terminal: the second run's bar stays one
    line (its own clock from 0), and it gets a heartbeat of its own."""
    import tapmuscle as tm

    monkeypatch.setattr(progress_module, "HEARTBEAT_TTY_S", 0.05)
    out = _Tty()
    p = Progress("loop", stream=out, min_total=1)
    for _ in range(2):
        before = out.getvalue().count("\n")
        controller = tm.DisplacementController(tm.ControllerSettings(method="mpc_ucp"), tm.THETA0_44N)
        tm.run_closed_loop(tm.Plant(seed=0), controller, None, duration_s=20.0, progress=p)
        assert out.getvalue().count("\n") - before == 1
    assert out.getvalue().split("\n")[1].startswith("\rloop [")
    p(1, 10)  # a third, slow one: its heartbeat runs
    time.sleep(0.3)
    assert out.getvalue().rstrip("\n").count("\r", out.getvalue().rfind("\n")) >= 3


def test_progress_true_reports_the_api_s_long_calls_on_stderr(capsys):
    """A notebook's ``progress=True``: the command line's report, labelled with the call, to the end."""
    import numpy as np

    import tapmuscle as tm

    tm.simulate_closed_loop(duration_s=5.0, progress=True)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("simulate_closed_loop:") and lines[-1].startswith("simulate_closed_loop: 100% (51/51")
    rec = tm.simulate(lambda t: 5.0 + 3.0 * np.sin(2 * np.pi * 0.1 * t), duration_s=40.0, seed=1)
    tm.diagnose(rec["t_s"], rec["u_v"], rec["l_mm"], tm.PlantParams(), calibration=None, progress=True)
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("diagnose:   0% (") and err[0].endswith(" s)  the nominal run"), err
    assert err[-1].startswith("diagnose: 100%"), err
    # False and None report nothing; a callable is called as given
    calls = []
    tm.simulate_closed_loop(duration_s=2.0, progress=False)
    tm.simulate_closed_loop(duration_s=2.0, progress=lambda done, total: calls.append((done, total)))
    assert capsys.readouterr().err == "" and calls[-1] == (21, 21)


def test_a_progress_that_is_neither_a_flag_nor_a_callable_is_refused_naming_it():
    import pytest

    import tapmuscle as tm

    for call in (lambda: tm.simulate_closed_loop(duration_s=1.0, progress="yes"),
                 lambda: tm.sweep("no_such.toml", "out", progress=1)):
        with pytest.raises(TypeError, match=r"progress must be True, False, None or a callable .*got ('yes'|1)"):
            call()


def test_a_log_line_without_counts_shows_the_percentage_the_time_and_the_detail():
    """For units that mean nothing to the reader (a diagnosis's thousandths of its work)."""
    out = io.StringIO()
    p = Progress("diagnose", stream=out, min_total=1, counts=False)
    p(240, 1000, "round 1 of at most 3: own fits 9/18")
    p(1000, 1000, "done")
    first, last = out.getvalue().splitlines()
    assert first.startswith("diagnose:  24% (") and first.endswith(" s)  round 1 of at most 3: own fits 9/18")
    assert "240/1000" not in first and last.startswith("diagnose: 100% (") and last.endswith(" s)  done")


def test_a_reporter_made_by_hand_reports_a_short_run_and_a_minimum_silences_one():
    """``progress=tm.Progress("run A")`` labels a run of 301 samples (a 30-s loop): it reports from the
    first sample; ``min_total`` (the command line's 500 for ``record`` and ``run``) silences it."""
    out = io.StringIO()
    p = Progress("run A", stream=out)
    for k in range(1, 302):
        p(k, 301)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("run A:") and lines[-1].startswith("run A: 100% (301/301")
    quiet = io.StringIO()
    q = Progress("run B", stream=quiet, min_total=500)
    for k in range(1, 302):
        q(k, 301)
    assert quiet.getvalue() == ""


def test_the_heartbeat_is_gone_when_the_last_unit_is_reported():
    """No thread of the reporter outlives its run's end (a fork right after the call would warn of
    it from Python 3.12)."""
    p = Progress("ends", stream=io.StringIO())
    p(1, 3)
    assert p._heart is not None and p._heart.is_alive()
    p(3, 3)
    assert not p._heart.is_alive()
    assert not [t for t in threading.enumerate() if t.name == "progress-ends"]


def test_a_shorter_bar_line_covers_the_longer_one_before_it_without_an_escape_on_windows(monkeypatch):
    """The bar is redrawn over itself with a carriage return: what a longer line before it left is
    covered with spaces, and on Windows without the erase-to-end-of-line sequence, which its console
    prints as "<-[K" unless VT processing is on."""
    monkeypatch.setattr(progress_module, "_ERASE_REST", "")
    out = _Tty()
    p = Progress("job", stream=out)
    p(1, 10, "a long detail of the first unit")
    p(2, 10, "short")
    first, second = out.getvalue().split("\r")[1:]
    assert "\033" not in out.getvalue()
    assert len(second) == len(first) and second.rstrip().endswith("short") and second.endswith(" " * 20)
    p(10, 10)
    p(1, 10, "x")  # another run after the finished one, on a fresh line: nothing to cover
    assert out.getvalue().split("\n")[1] == out.getvalue().split("\n")[1].rstrip()


def test_a_heartbeat_says_what_the_run_waits_on_where_it_is_told(monkeypatch):
    """A sweep on a cluster left without workers: its heartbeat says so instead of "still running",
    and a reason that fails or is None leaves the plain heartbeat."""
    monkeypatch.setattr(progress_module, "HEARTBEAT_LOG_S", 0.05)
    reasons = iter(["no worker connected to the scheduler for 3 s; the sweep stops at 60 s", None])

    def why():
        try:
            return next(reasons)
        except StopIteration:
            raise RuntimeError("the watch is gone") from None

    out = io.StringIO()
    p = Progress("sweep", stream=out)
    p.why_waiting = why
    p(2, 8)
    time.sleep(0.4)
    p(8, 8)
    lines = out.getvalue().splitlines()
    assert lines[1] == ("sweep:  25% (2/8, " + lines[1].split("(2/8, ")[1].split(" s)")[0]
                        + " s)  (no worker connected to the scheduler for 3 s; the sweep stops at 60 s)")
    assert lines[2].endswith("(still running)") and lines[3].endswith("(still running)")
