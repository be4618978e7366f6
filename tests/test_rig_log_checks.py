"""A rig's log checked as the diagnosis would (diagnosis/rig_log_checks.py): ``tm.read_rig_log`` in
Python refuses what ``tapmuscle import`` refuses, each naming the unit in its own spelling."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import tapmuscle as tm
from tapmuscle.cli.main import main
from tapmuscle.io.recording import RecordingError


@pytest.fixture(scope="module")
def rig():
    """A 120-s random-command run of the simulated rig at 0.1 s."""
    return tm.simulate("random:lo=2,hi=8,hold_min=2,hold_max=6,seed=3", duration_s=120.0)


def _log(path, t, u, l, header=("time", "valve", "pos")):  # noqa: E741
    rows = "\n".join(f"{a:.6f},{b:.6f},{c:.6f}" for a, b, c in zip(t, u, l))
    path.write_text(",".join(header) + "\n" + rows + "\n")
    return path


@pytest.mark.parametrize("scale, spec, python_hint, cli_hint", [
    ((1.0, 10.0, 1.0), {"u": "valve"}, "u='valve:%'", "--u valve:%"),          # percent read as volts
    ((1e3, 1.0, 1.0), {"time": "time"}, "time='time:ms'", "--time time:ms"),    # milliseconds read as seconds
    ((1.0, 1.0, 1e3), {"l": "pos"}, "l='pos:um'", "--l pos:um"),               # micrometres read as millimetres
])
def test_a_log_in_another_unit_is_refused_in_python_as_on_the_command_line(rig, tmp_path, capsys, scale, spec,
                                                                           python_hint, cli_hint):
    """tm.read_rig_log must not read a command in percent as 78 V, times in ms as a 100-s period and a position
    in micrometres as 88 m without a word, where tapmuscle import refuses them; both refuse the same
    finding, each naming the unit as its caller gives one."""
    log = _log(tmp_path / "log.csv", rig["t_s"] * scale[0], rig["u_v"] * scale[1], rig["l_mm"] * scale[2])
    columns = {"time": "time", "u": "valve", "l": "pos"} | spec
    with pytest.raises(RecordingError) as python:
        tm.read_rig_log(log, **columns)
    message = str(python.value)
    assert message.startswith(f"{log}") and python_hint in message and message.endswith("(checks=False reads it as it is)")
    assert main(["import", str(log), "--out", str(tmp_path / "rec.csv"), "--time", columns["time"], "--u", columns["u"],
                 "--l", columns["l"]]) == 2
    cli = capsys.readouterr().err
    assert cli_hint in cli and "(--no-checks writes it as it is)" in cli
    said = message.replace(python_hint, cli_hint).replace("(checks=False reads it as it is)", "")
    assert said.strip() in cli  # the same finding, the same numbers
    assert not (tmp_path / "rec.csv").exists()
    with warnings.catch_warnings(record=True) as caught:  # with the sensor notes a unit this far off brings
        warnings.simplefilter("always")
        taken = tm.read_rig_log(log, checks=False, **columns)
    refused = [str(w.message) for w in caught if "the diagnosis would refuse it" in str(w.message)]
    assert len(refused) == 1 and refused[0].startswith(f"the diagnosis would refuse it: {log}") \
        and python_hint in refused[0] and refused[0].count(str(log)) == 1
    assert len(taken) == len(rig["t_s"])


def test_a_sound_log_reads_without_a_warning_and_as_the_reader_reads_it(rig, tmp_path):
    from tapmuscle.io.rig_log import read_rig_log as unchecked

    log = _log(tmp_path / "log.csv", rig["t_s"], rig["u_v"], rig["l_mm"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = tm.read_rig_log(log, time="time", u="valve", l="pos", load_n=44)
    plain = unchecked(log, time="time", u="valve", l="pos", load_n=44)
    assert all(np.array_equal(rec.columns[k], plain.columns[k]) for k in plain.columns) and rec.metadata == plain.metadata


def test_a_fast_log_is_merged_before_its_checks(rig, tmp_path):
    """A 2-kHz log is refused with the merge that makes it a muscle recording, which decimate then does."""
    t = np.arange(24001) * 5e-4
    u = np.interp(t, rig["t_s"], rig["u_v"])
    log = _log(tmp_path / "fast.csv", t, u, np.interp(t, rig["t_s"], rig["l_mm"]))
    with pytest.raises(RecordingError, match=r"0.0005 s \(2000 Hz\).*Merge every 40 samples into one"):
        tm.read_rig_log(log, time="time", u="valve", l="pos")
    rec = tm.read_rig_log(log, time="time", u="valve", l="pos", decimate=40)
    assert rec.ts_s == pytest.approx(0.02) and len(rec) == 601
    for bad in (0, 2.5, True):
        with pytest.raises(RecordingError, match=r"decimate = .* must be an integer >= 1"):
            tm.read_rig_log(log, time="time", u="valve", l="pos", decimate=bad)
    with pytest.raises(RecordingError, match=rf"{log}: decimation n = 4000 must be an integer within 1..1000"):
        tm.read_rig_log(log, time="time", u="valve", l="pos", decimate=4000)


def test_spreadsheet_serial_dates_are_named_by_their_line_not_taken_for_a_fast_logger(tmp_path, capsys):
    """A spreadsheet's serial dates (45356,4166: days since 1899-12-30) read as seconds look like a
    1-MHz logger, and the refusal must not advise merging 1000 samples; a log that does not move must not name
    a ratio of 5e299."""
    rows = [f"{45356.4166 + k * 0.1 / 86400:.9f};{5 + (k % 50) / 25:.3f};{(k % 50) * 0.3:.3f}".replace(".", ",")
            for k in range(600)]
    log = tmp_path / "serial.csv"
    log.write_text("Zeit;Ventil;Weg\n" + "\n".join(rows) + "\n")
    with pytest.raises(RecordingError, match=r"line 2, column 'Zeit' \(t_s, given in s\): 45356,416600000 looks like a "
                                             r"spreadsheet's serial date \(2024-03-05 09:59:54: days since 1899-12-30, "
                                             r"stepping 0.1 s\), not seconds: .* time='Zeit:s' or time='Zeit:iso'"):
        tm.read_rig_log(log, time="Zeit", u="Ventil", l="Weg")
    assert main(["import", str(log), "--out", str(tmp_path / "r.csv"), "--time", "Zeit", "--u", "Ventil", "--l", "Weg"]) == 2
    err = capsys.readouterr().err
    assert "looks like a spreadsheet's serial date" in err and "--time Zeit:s or --time Zeit:iso" in err
    assert "Merge every" not in err
    still = tmp_path / "still.csv"
    still.write_text("t,u,l\n" + "".join(f"{0.1 * k:.1f},{5 + (k % 50) / 25:.3f},0\n" for k in range(600)))
    with pytest.raises(RecordingError, match=r"spans 0 mm where the nominal model, driven by the same command, spans "
                                             r"[\d.]+ mm \(the column does not move at all\)"):
        tm.read_rig_log(still, time="t", u="u", l="l")
