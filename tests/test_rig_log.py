"""A rig's data-acquisition log into the recording format (tapmuscle/io/rig_log.py, ``tapmuscle import``):
column names, units, separators, decimal commas, units rows, text columns and time stamps as loggers
write them, read back to the recording they came from; and every malformed log refused by file, line
and column, with nothing written."""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

import tapmuscle as tm
from tapmuscle.cli.main import main
from tapmuscle.diagnosis.demo import DEMO_MODEL, record
from tapmuscle.io.recording import RecordingError, read_recording
from tapmuscle.io.rig_log import UNITS, LogColumn, parse_column_spec, read_rig_log, rig_log_runs


@pytest.fixture(scope="module")
def truth():
    return record(DEMO_MODEL, "sine", 1, duration_s=30.0)


def _comma(x: float, fmt: str) -> str:
    return format(x, fmt).replace(".", ",")


_NAMES = ["time_ms", "valve_pct", "position_um", "p_kpa", "status"]
#: Names that say nothing of a unit: a log whose units only the caller knows.
_PLAIN = ["time_ms", "valve", "position", "p", "status"]


def _logger(path, cols, *, jitter_s=0.004, epoch_ms=1.7e12, units_row=True, seed=0, names=_NAMES):
    """What a PC logger writes: ';' and a decimal comma, epoch milliseconds with jitter, the command
    in percent, the position in micrometres, the pressure in kPa, a text status and a units row."""
    jitter = np.random.default_rng(seed).uniform(-jitter_s, jitter_s, len(cols["t_s"]))
    with open(path, "w", newline="", encoding="utf-8-sig") as f:
        f.write("# DAQ export, rig 2\n\n")
        w = csv.writer(f, delimiter=";")
        w.writerow(names)
        if units_row:
            w.writerow(["ms", "%", "um", "kPa", "-"])
        for t, u, l, p in zip(epoch_ms + 1e3 * (cols["t_s"] + jitter), cols["u_v"], cols["l_mm"], cols["p_mpa"]):
            w.writerow([_comma(t, ".1f"), _comma(10 * u, ".4f"), f"{1e3 * l:.0f}", _comma(1e3 * p, ".3f"), "OK"])
    return jitter


def test_a_pc_loggers_file_reads_back_as_the_recording_it_came_from(tmp_path, truth):
    log = tmp_path / "logger.csv"
    jitter = _logger(log, truth)
    rec = read_rig_log(log, time="time_ms:ms", u="valve_pct:%", l="position_um:um", p=LogColumn("p_kpa", "kPa"),
                       load_n=44.0)
    # each value to the resolution the logger wrote it with
    assert np.max(np.abs(rec.u_v - truth["u_v"])) <= 0.5e-4 / 10 + 1e-12
    assert np.max(np.abs(rec.l_mm - truth["l_mm"])) <= 0.5e-3 + 1e-12
    assert np.max(np.abs(rec.columns["p_mpa"] - truth["p_mpa"])) <= 0.5e-6 + 1e-12
    # seconds from the first stamp, the logger's jitter kept (0.05 ms: the stamps' 0.1-ms digit)
    assert rec.t_s[0] == 0.0
    assert np.max(np.abs(rec.t_s - (truth["t_s"] + jitter - jitter[0]))) <= 1e-4
    assert rec.ts_s == pytest.approx(0.1, rel=1e-4) and rec.sampling.jitter_s < 0.005
    assert set(rec.columns) == {"t_s", "u_v", "l_mm", "p_mpa"}  # the text status is not a column
    assert rec.metadata["start"] == _comma(1.7e12 + 1e3 * jitter[0], ".1f")
    assert rec.metadata["load_n"] == "44" and rec.metadata["units_row"] == "line 4, skipped"
    assert rec.lines.tolist() == list(range(5, 5 + len(rec)))  # each sample's line in the log
    assert "u_v <- valve_pct [%]" in rec.metadata["source"]


def test_tabs_iso_stamps_metres_and_bar(tmp_path, truth):
    start = datetime(2025, 3, 14, 9, 26, 53, 589000, tzinfo=timezone(timedelta(hours=1)))
    log = tmp_path / "rig.tsv"
    lines = ["stamp\tLength [m]\tCmd [V]\tp [bar]"]
    for t, u, l, p in zip(truth["t_s"], truth["u_v"], truth["l_mm"], truth["p_mpa"]):
        lines.append(f"{(start + timedelta(seconds=float(t))).isoformat()}\t{l / 1e3:.7f}\t{u:.6f}\t{10 * p:.6f}")
    log.write_text("\r\n".join(lines) + "\r\n")
    rec = read_rig_log(log, time="stamp:iso", u="Cmd [V]", l="Length [m]:m", p="p [bar]:bar")
    assert np.max(np.abs(rec.t_s - truth["t_s"])) <= 1e-6
    assert np.max(np.abs(rec.l_mm - truth["l_mm"])) <= 0.5e-4 + 1e-12
    assert np.max(np.abs(rec.u_v - truth["u_v"])) <= 0.5e-6 + 1e-12
    assert np.max(np.abs(rec.columns["p_mpa"] - truth["p_mpa"])) <= 0.5e-7 + 1e-12
    assert rec.metadata["start"] == start.isoformat() and "units_row" not in rec.metadata


def test_an_absolute_pressure_becomes_gauge_against_the_ambient(tmp_path, truth, capsys):
    """A sensor that reads absolute pressure (psia, bar(a)): the ambient is subtracted, the standard
    atmosphere's unless given; the drained muscle's reading off by a few kPa is said, with the
    --ambient-kpa that zeroes it. An ambient with a gauge unit is refused."""
    ambient_kpa = 97.2  # a low-pressure day, or 400 m up
    log = tmp_path / "abs.csv"
    lines = ["t,u,pos,p_psia"] + [f"{t:.1f},{u:.6f},{l:.4f},{(1e3 * p + ambient_kpa) / 6.894757293168361:.6f}"
                                  for t, u, l, p in zip(truth["t_s"], truth["u_v"], truth["l_mm"], truth["p_mpa"])]
    log.write_text("\n".join(lines) + "\n")
    rec = read_rig_log(log, time="t", u="u", l="pos", p="p_psia:psi_abs", ambient_kpa=ambient_kpa)
    assert np.max(np.abs(rec.columns["p_mpa"] - truth["p_mpa"])) <= 0.5e-6 * 6.894757293168361e-3 + 1e-12
    assert rec.metadata["ambient_kpa"] == "97.2, subtracted from the absolute pressure"
    rec = read_rig_log(log, time="t", u="u", l="pos", p="p_psia:psi_abs")
    np.testing.assert_allclose(rec.columns["p_mpa"] - truth["p_mpa"], -(101.325 - ambient_kpa) * 1e-3, atol=1e-8)
    assert "(the standard atmosphere)" in rec.metadata["ambient_kpa"]
    with pytest.raises(RecordingError, match=r"ambient_kpa is for an absolute pressure .*the pressure is in psi"):
        read_rig_log(log, time="t", u="u", l="pos", p="p_psia:psi", ambient_kpa=97.2)
    with pytest.raises(RecordingError, match=r"ambient_kpa = 970 is not an atmosphere's pressure"):
        read_rig_log(log, time="t", u="u", l="pos", p="p_psia:psi_abs", ambient_kpa=970)
    # the command line says how far the drained muscle reads from 0, and what zeroes it
    out = tmp_path / "rec.csv"
    assert main(["import", str(log), "--out", str(out), "--time", "t", "--u", "u", "--l", "pos", "--p",
                 "p_psia:psi_abs"]) == 0
    assert re.search(r"the pressure reads -4.1\d kPa \(median of the first \d+ samples\) against the ambient 101.325 kPa",
                     capsys.readouterr().err)
    assert main(["import", str(log), "--out", str(out), "--time", "t", "--u", "u", "--l", "pos", "--p",
                 "p_psia:psi_abs", "--ambient-kpa", "97.2"]) == 0
    assert "At rest, the pressure reads" not in capsys.readouterr().err
    assert abs(read_recording(out).columns["p_mpa"][0]) <= 1e-6
    # declared gauge, it is said to look absolute
    assert main(["import", str(log), "--out", str(out), "--time", "t", "--u", "u", "--l", "pos", "--p",
                 "p_psia:psi"]) == 0
    assert "an absolute pressure" in capsys.readouterr().err


def test_a_comma_separated_log_keeps_its_decimal_point(tmp_path):
    log = tmp_path / "plain.csv"
    log.write_text("t,u,x\n0,1.5,0\n0.1,2.5,1.25\n0.2,3.5,2.5\n")
    rec = read_rig_log(log, time="t", u="u", l="x:cm")
    np.testing.assert_array_equal(rec.l_mm, [0.0, 12.5, 25.0])
    np.testing.assert_array_equal(rec.u_v, [1.5, 2.5, 3.5])


def test_every_unit_has_a_factor_and_column_specs_parse():
    assert all(f is None or f > 0 for units in UNITS.values() for f in units.values())
    assert UNITS["u_v"]["%"] * 100.0 == 10.0  # 100 % is the valve's 10 V
    assert UNITS["u_v"]["pwm"] * 255.0 == pytest.approx(10.0, rel=1e-15)  # a full 8-bit duty cycle too
    assert parse_column_spec("pos", "l_mm") == LogColumn("pos", "mm")
    assert parse_column_spec("a:b:um", "l_mm") == LogColumn("a:b", "um")
    with pytest.raises(ValueError, match=r"column 'a': unknown unit 'b' for l_mm \(known: mm, um \(or µm\), cm, m\)"):
        parse_column_spec("a:b", "l_mm")
    with pytest.raises(ValueError, match="no column name"):
        parse_column_spec(":ms", "t_s")


@pytest.mark.parametrize("micro", ["\u00b5", "\u03bc"], ids=["micro-sign", "greek-mu"])
def test_micro_is_read_as_loggers_write_it(tmp_path, truth, capsys, micro):
    """``µm`` and ``µs`` (the micro sign or the Greek mu) are ``um`` and ``us``: by the reader and the
    command line; a micro prefix on a unit that has none is refused as written."""
    assert parse_column_spec(f"Weg:{micro}m", "l_mm").factor("l_mm") == UNITS["l_mm"]["um"]
    assert LogColumn("Zeit", f"{micro}s").factor("t_s") == UNITS["t_s"]["us"]
    with pytest.raises(ValueError, match=f"unknown unit '{micro}V' for u_v"):
        parse_column_spec(f"u:{micro}V", "u_v")
    log = tmp_path / "logger.csv"
    log.write_text(f"Zeit;Ventil;Weg\n{micro}s;V;{micro}m\n"
                   + "".join(f"{100_000 * k};{u:.5f};{1e3 * l:.0f}\n" for k, (u, l) in enumerate(zip(truth["u_v"], truth["l_mm"]))),
                   encoding="utf-8")
    out = tmp_path / "rec.csv"
    assert main(["import", str(log), "--out", str(out), "--time", f"Zeit:{micro}s", "--u", "Ventil",
                 "--l", f"Weg:{micro}m", "--load-n", "44"]) == 0
    rec = read_recording(out)
    assert rec.ts_s == pytest.approx(0.1) and np.max(np.abs(rec.l_mm - truth["l_mm"])) <= 0.5e-3 + 1e-12
    assert f"l_mm <- Weg [{micro}m]" in rec.metadata["source"]


@pytest.mark.parametrize("body,message", [
    ("time;u;l\n0;1;0\n0,1;;0\n", r"line 3, column 'u': '' is not a number"),
    ("time;u;l\n0;1;0\n0,1;x;0\n", r"line 3, column 'u': 'x' is not a number"),
    ("time;u;l\n0;1;0\n0;2;0\n", r"line 3, column 'time': time does not increase \('0', then '0'\)"),
    ("time;u;l\n0;1;0\n0,1;2\n", r"line 3: 2 fields, no column 'l'"),
    # a decimal comma in a comma-separated log: every value after it would be shifted by one column
    ("time,u,l,p\n0,1,64.9,0.12\n0.1,1,64,9000,0.12\n", r"line 3: 5 fields, the header has 4 \(a decimal comma or a "
                                                       r"stray ',' in a value\?\): '0.1,1,64,9000,0.12'"),
    ("time;u;pos\n0;1;0\n", r"line 1: no column 'l' for l_mm \(found, separated by ';': time, u, pos\)"),
    ("# only a comment\n\n", r"no header row"),
    ("time;u;l\nms;V;mm\n", r"header but no data rows"),
])
def test_a_malformed_log_is_refused_by_line_and_column(tmp_path, body, message):
    log = tmp_path / "bad.csv"
    log.write_text(body)
    with pytest.raises(RecordingError, match=message):
        read_rig_log(log, time="time", u="u", l="l")


def test_empty_trailing_fields_are_a_loggers_habit_not_an_error(tmp_path):
    log = tmp_path / "trailing.csv"
    log.write_text("time;u;l;\n0;1;0;\n0,1;2;0,5;;\n")
    rec = read_rig_log(log, time="time", u="u", l="l")
    assert rec.columns["l_mm"].tolist() == [0.0, 0.5] and rec.columns["u_v"].tolist() == [1.0, 2.0]


def test_iso_stamps_that_cannot_be_compared_and_iso_values_are_refused(tmp_path):
    """Only the time's unit may be ISO 8601 text."""
    log = tmp_path / "mixed.csv"
    log.write_text("t,u,l\n2025-03-14T09:00:00+00:00,1,0\n2025-03-14T09:00:00.1,1,0\n")
    with pytest.raises(RecordingError, match=r"line 3, column 't': '2025-03-14T09:00:00.1' is not an ISO 8601 \(or day.month.year\) time"):
        read_rig_log(log, time="t:iso", u="u", l="l")
    with pytest.raises(RecordingError, match=r"column 'u': unknown unit 'iso' for u_v \(known: V, mV, %, pwm\)"):
        read_rig_log(log, time="t:iso", u=LogColumn("u", "iso"), l="l")


def test_import_writes_the_recording_and_says_what_diagnose_would(tmp_path, truth, capsys):
    log = tmp_path / "logger.csv"
    _logger(log, truth)
    out = tmp_path / "rec.csv"
    assert main(["import", str(log), "--out", str(out), "--time", "time_ms:ms", "--u", "valve_pct:%",
                 "--l", "position_um:um", "--p", "p_kpa:kPa", "--load-n", "44"]) == 0
    io = capsys.readouterr()
    assert "30" in io.out and "Ts 0.1" in io.out and "line 4, skipped (units row)" in io.out
    assert "scatter by up to" in io.err  # the logger's jitter, taken as on the grid
    rec = read_recording(out)
    assert rec.metadata["load_n"] == "44" and len(rec) == len(truth["t_s"])
    # the command left in percent (its unit given nowhere): refused, unless written as it is on purpose
    _logger(log, truth, units_row=False, names=_PLAIN)
    pct = ["import", str(log), "--out", str(tmp_path / "pct.csv"), "--time", "time_ms:ms", "--u", "valve",
           "--l", "position:um"]
    assert main(pct) == 2
    # named by the log's line and column, as every other refusal of a log (line 4 holds sample 0), with
    # the COLUMN:UNIT that reads it as a command
    err = capsys.readouterr().err
    assert "logger.csv, line 4, column 'valve' (u_v): 50 V is outside the -1..11 V" in err
    assert "the column is likely in % (--u valve:%)" in err and "Scale it" not in err
    assert not (tmp_path / "pct.csv").exists()
    assert main(pct + ["--no-checks"]) == 0
    assert "the diagnosis would refuse it: " + str(log) + ", line 4, column 'valve' (u_v): 50 V" in capsys.readouterr().err


def test_a_value_in_a_wrong_unit_is_named_by_its_line_not_its_sample(tmp_path, truth, capsys):
    """Micrometres declared as millimetres: the first reading beyond 500 mm is named by the log's line
    (the units row and the remarks before the header are lines, not samples)."""
    log = tmp_path / "logger.csv"
    _logger(log, truth, names=_PLAIN, units_row=False)
    k = int(np.argmax(1e3 * truth["l_mm"] > 500.0))
    assert k > 0
    argv = ["import", str(log), "--out", str(tmp_path / "rec.csv"), "--time", "time_ms:ms", "--u", "valve:%",
            "--l", "position"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"logger.csv, line {4 + k}, column 'position' (l_mm): {1e3 * truth['l_mm'][k]:.0f} mm is further from 0" in err
    assert "sample" not in err.partition("(l_mm)")[0]
    assert "the column is likely in um (--l position:um)" in err


def test_a_pressure_no_tap_water_rig_has_is_refused_with_the_unit_it_likely_is(tmp_path, truth, capsys):
    """kPa declared as MPa (or as bar) reads 200 MPa: refused as a command or a length in a wrong unit
    is, naming the column, the unit given, the largest value and its line, and the unit that reads it
    as a rig's pressure; --no-checks writes it with a note."""
    log = tmp_path / "logger.csv"
    _logger(log, truth, names=_PLAIN, units_row=False)
    k = int(np.argmax(truth["p_mpa"]))
    largest = f"{1e3 * truth['p_mpa'][k]:.3f}".rstrip("0")
    out = tmp_path / "rec.csv"
    base = ["import", str(log), "--time", "time_ms:ms", "--u", "valve:%", "--l", "position:um", "--out"]
    base_out = base + [str(out)]
    assert main(base_out + ["--p", "p:MPa"]) == 2
    err = capsys.readouterr().err
    assert (f"logger.csv, line {4 + k}, column 'p' (p_mpa, given in MPa): its largest value, {largest} MPa, is no "
            "tap-water rig's pressure" in err)
    assert f"the column is likely in kPa ({largest} kPa is 0.2" in err and "--p p:kPa" in err
    assert not out.exists()
    assert main(base_out + ["--p", "p:bar"]) == 2
    err = capsys.readouterr().err
    assert f"(p_mpa, given in bar): its largest value, {largest} bar (" in err and "--p p:kPa" in err
    assert main(base_out + ["--p", "p:MPa", "--no-checks"]) == 0
    assert "Column p_mpa reaches" in capsys.readouterr().err and out.exists()
    assert main(base + [str(tmp_path / "right.csv"), "--p", "p:kPa"]) == 0  # the right unit passes


def test_units_declared_wrong_are_refused_or_noted_as_the_diagnosis_would(tmp_path, truth, capsys):
    """Millimetres declared as micrometres are refused (a span 1000 times below the nominal plant's);
    volts declared as percent (a tenth of them) and a load in kN are noted."""
    log = tmp_path / "logger.csv"

    log.write_text("t_s;u;l\n" + "".join(f"{0.1 * k:.1f};{u:.5f};{l:.3f}\n"
                                         for k, (u, l) in enumerate(zip(truth["u_v"], truth["l_mm"]))))
    base = ["import", str(log), "--time", "t_s", "--u", "u"]
    out = tmp_path / "mm_as_um.csv"
    assert main(base + ["--out", str(out), "--l", "l:um", "--load-n", "44"]) == 2
    err = capsys.readouterr().err
    assert "column 'l' (l_mm, given in um) spans" in err and "where the nominal model, driven by the same command, spans" in err
    assert "the column is likely in mm (--l l:mm)" in err  # the COLUMN:UNIT that fits, not "scale it"
    assert not out.exists()
    assert main(base + ["--out", str(out), "--l", "l", "--load-n", "44"]) == 0  # right: nothing said of units
    err = capsys.readouterr().err
    assert "another unit" not in err and "kN" not in err
    # volts declared as percent: read as a tenth of them
    assert main(["import", str(log), "--out", str(tmp_path / "tenth.csv"), "--time", "t_s", "--u", "u:%",
                 "--l", "l", "--load-n", "44"]) == 0
    assert "is the command in another unit (volts imported as percent are a tenth of them)?" in capsys.readouterr().err
    assert main(base + ["--out", str(out), "--l", "l", "--load-n", "0.044"]) == 0
    err = capsys.readouterr().err
    assert "The load never exceeds 0.044 N" in err and "kN?" in err
    # a mass in kg: noted, and read as its weight in newtons with the unit
    assert main(base + ["--out", str(out), "--l", "l", "--load-n", "4.49"]) == 0
    assert "is it a mass logged in kg (4.49 kg weighs 44 N; tapmuscle import --load COLUMN:kg" in \
        capsys.readouterr().err


@pytest.mark.parametrize("repeated", [["--u", "valve_pct:%", "--u", "position_um"], ["--p", "p_kpa:kPa", "--p", "p_kpa:bar"],
                                      ["--skip-lines", "0", "--skip-lines", "2"]])
def test_an_option_given_twice_is_refused_naming_both(tmp_path, truth, capsys, repeated):
    """argparse takes the last of a repeated option in silence (``--u A --u B`` read B)."""
    log = tmp_path / "logger.csv"
    _logger(log, truth)
    out = tmp_path / "rec.csv"
    argv = ["import", str(log), "--out", str(out), "--time", "time_ms:ms", "--l", "position_um:um", *repeated]
    if "--u" not in repeated:
        argv += ["--u", "valve_pct:%"]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and not out.exists()
    option, first, _, second = repeated
    assert (f"tapmuscle import: error: argument {option}: given twice, {first!r} and {second!r}: give it once"
            in capsys.readouterr().err)


def test_a_failed_import_leaves_the_output_as_it_was(tmp_path, truth):
    log = tmp_path / "logger.csv"
    _logger(log, truth, units_row=False)
    out = tmp_path / "rec.csv"
    out.write_text("precious\n")
    lines = log.read_text(encoding="utf-8-sig").splitlines()
    del lines[20]  # a dropped sample
    log.write_text("\n".join(lines) + "\n")
    r = subprocess.run([sys.executable, "-m", "tapmuscle.cli", "import", str(log), "--out", str(out), "--time",
                        "time_ms:ms", "--u", "valve_pct:%", "--l", "position_um:um"], capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    # named by the log's line: the sample after the gap
    assert "logger.csv, line 21: column time_ms, sample 17:" in r.stderr and "a dropped or doubled sample" in r.stderr
    assert out.read_text() == "precious\n"
    r = subprocess.run([sys.executable, "-m", "tapmuscle.cli", "import", str(log), "--out", str(out), "--time",
                        "time_ms:seconds", "--u", "valve_pct:%", "--l", "position_um:um"], capture_output=True, text=True)
    assert r.returncode == 2 and "--time column 'time_ms': unknown unit 'seconds' for t_s" in r.stderr
    assert out.read_text() == "precious\n"


def test_the_package_root_reads_a_log():
    """tm.read_rig_log is this reader with tapmuscle import's checks (tests/test_rig_log_checks.py)."""
    from tapmuscle import api

    assert tm.read_rig_log is api.read_rig_log and tm.LogColumn is LogColumn


def test_dropped_samples_are_put_back_only_when_asked_and_marked(tmp_path, truth):
    log = tmp_path / "logger.csv"
    _logger(log, truth, units_row=False)
    lines = log.read_text(encoding="utf-8-sig").splitlines()
    header_at = 2  # a comment and a blank line first
    keep = [i for i in range(len(lines)) if i not in (header_at + 1 + 50, header_at + 1 + 120, header_at + 1 + 121)]
    log.write_text("\n".join(lines[i] for i in keep) + "\n")
    spec = {"time": "time_ms:ms", "u": "valve_pct:%", "l": "position_um:um"}
    # the first gap in the file, named by the line of the sample after it (line 4 + k holds sample k; 50 gone)
    with pytest.raises(RecordingError, match=r"logger.csv, line 54: column time_ms, sample 50: .*a dropped or doubled "
                                             r"sample.*; or --fill-gaps S\)"):
        read_rig_log(log, **spec)
    with pytest.raises(RecordingError, match=r"line 123, column 'time_ms': 0.2\d* s of samples are missing after "
                                             r"t = 11.8\d* s .*more than the 0.15 s --fill-gaps fills"):
        read_rig_log(log, **spec, fill_gaps_s=0.15)
    rec = read_rig_log(log, **spec, fill_gaps_s=0.3)
    assert len(rec) == len(truth["t_s"])
    np.testing.assert_array_equal(np.nonzero(rec.columns["filled"])[0], [50, 120, 121])
    assert rec.sampling.jitter_s < 0.005  # back on the grid
    kept = rec.columns["filled"] == 0
    assert np.max(np.abs(rec.l_mm[kept] - truth["l_mm"][kept])) <= 0.5e-3 + 1e-12  # the others as logged
    # a filled sample lies between its neighbours (linear), here within the step the muscle moved
    for k in (50, 120, 121):
        lo, hi = sorted((rec.l_mm[k - 1 if k != 121 else 119], rec.l_mm[k + 1 if k != 120 else 122]))
        assert lo - 1e-9 <= rec.l_mm[k] <= hi + 1e-9
    assert rec.metadata["filled"].startswith("3 dropped samples in 2 gaps put back")


def test_a_log_whose_period_changes_is_not_filled_as_dropped_samples(tmp_path):
    """A logger switched from 10 to 20 Hz at 30 s: --fill-gaps must not put 300 "dropped" samples back
    (the first 30 s interpolated onto the faster grid); it names the change and its line."""
    t = np.concatenate([np.arange(300) * 0.1, 30.0 + np.arange(600) * 0.05])
    log = tmp_path / "logger.csv"
    log.write_text("time,cmd,pos\n" + "".join(f"{x:.3f},{5 + 3 * np.sin(0.6 * x):.4f},{20 + 10 * np.sin(0.6 * x):.4f}\n"
                                               for x in t))
    spec = {"time": "time", "u": "cmd", "l": "pos"}
    with pytest.raises(RecordingError, match=r"logger.csv, line 303, column 'time': the sampling period changes between "
                                             r"t = 30 and 30.05 s .* from 0.1 s to 0.05 s; --fill-gaps puts back samples a "
                                             r"logger dropped and does not resample: split the log there"):
        read_rig_log(log, **spec, fill_gaps_s=1.0)
    with pytest.raises(RecordingError, match=r"line 303: column time, sample 301: the sampling period changes") as info:
        read_rig_log(log, **spec)
    assert "--fill-gaps" not in str(info.value)


@pytest.mark.parametrize("body,options,message", [
    # integers with '.' thousands separators (a German export): read with a decimal point, 1.350 um was 1.35
    ("t;u;pos\n0;5;12\n1;5;999\n2;5;1.350\n3;5;2.001\n", {},
     r"line 4, column 'pos': '1.350' reads as a thousands separator .*remove the separators"),
    # the same under a units row (which is text, not an integer), and comma-separated
    ("t;u;pos\ns;V;um\n0;5;12\n1;5;999\n2;5;1.350\n3;5;2.001\n", {},
     r"line 5, column 'pos': '1.350' reads as a thousands separator"),
    ("t,u,pos\n0,5,12\n1,5,999\n2,5,1.350\n", {}, r"line 4, column 'pos': '1.350' reads as a thousands separator"),
    ("t;u;pos\n0;5;12,5\n1;5;999,0\n2;5;1.350,0\n", {},
     r"line 4, column 'pos': '1.350,0' is not a number with the decimal mark ',': '.' as a thousands separator\?"),
    ("t;u;pos\n0;5;12.5\n1;5;1,350.0\n", {}, r"line 3, column 'pos': '1,350.0' is not a number with the decimal "
                                             r"mark '.': a decimal comma \(--decimal ','\) or a thousands separator"),
    # a first data row with empty cells is not a units row
    ("t;u;pos\n0;;\n1;5;2\n2;5;3\n", {}, r"line 2, column 'u': '' is not a number"),
    ("t,u,pos\n0,5,1\n1,5,2\n", {"delimiter": "::"}, r"delimiter '::' is not one separating character"),
    ("t,u,pos\n0,5,1\n1,5,2\n", {"load_n": float("nan")}, r"load_n = nan is not a positive number of newtons"),
    ("t,u,pos\n0,5,1\n1,5,2\n", {"load_n": "44"}, r"load_n = '44' is not a positive number of newtons"),
])
def test_what_a_logger_writes_wrongly_is_refused_with_a_remedy(tmp_path, body, options, message):
    log = tmp_path / "log.csv"
    log.write_text(body)
    with pytest.raises(RecordingError, match=message):
        read_rig_log(log, time="t", u="u", l="pos:um", **options)


@pytest.mark.parametrize("name", ["tab", "\\t", "\t"])
def test_a_tab_can_be_named(tmp_path, name):
    log = tmp_path / "log.txt"
    log.write_text("t\tu\tpos,um\n0\t5\t1,5\n0,1\t5\t2,5\n0,2\t5\t3,5\n")  # a comma in a name: not the separator
    rec = read_rig_log(log, time="t", u="u", l="pos,um:um", delimiter=name)
    np.testing.assert_allclose(rec.l_mm, [1.5e-3, 2.5e-3, 3.5e-3], rtol=1e-12)


def test_import_never_writes_over_the_log(tmp_path, capsys):
    log = tmp_path / "log.csv"
    log.write_text("t,u,pos\n0,5,1\n0.1,5,2\n0.2,5,3\n")
    before = log.read_text()
    assert main(["import", str(log), "--out", str(tmp_path / "." / "log.csv"), "--time", "t", "--u", "u",
                 "--l", "pos"]) == 2
    assert "is the log itself" in capsys.readouterr().err and log.read_text() == before


def test_a_preamble_and_another_encoding(tmp_path):
    """A LabVIEW-style preamble before the header, in Latin-1 (a degree sign) and in UTF-16."""
    text = ("LabVIEW Measurement\nOperator\trig\nTemperature [°C]\t21\n***End_of_Header***\n"
            "Time [s]\tValve [V]\tPosition [µm]\n0,0\t2,5\t0\n0,1\t2,6\t10\n0,2\t2,7\t25\n")
    for encoding in ("latin-1", "utf-16"):
        log = tmp_path / f"{encoding}.lvm"
        log.write_bytes(text.encode(encoding))
        if encoding == "latin-1":  # UTF-16 is told by its byte-order mark
            with pytest.raises(RecordingError, match=r"line 3: not utf-8 text \(byte 0xb0\): give its encoding"):
                read_rig_log(log, time="Time [s]", u="Valve [V]", l="Position [µm]:um")
        with pytest.raises(RecordingError, match=r"line 1: no column 'Time \[s\]' for t_s .*; line 5 holds every column "
                                                 r"named: --skip-lines 4 reads the header there"):
            read_rig_log(log, time="Time [s]", u="Valve [V]", l="Position [µm]:um", encoding=encoding)
        rec = read_rig_log(log, time="Time [s]", u="Valve [V]", l="Position [µm]:um", encoding=encoding, skip_lines=4)
        np.testing.assert_allclose(rec.l_mm, [0.0, 0.01, 0.025], rtol=1e-12)
        np.testing.assert_allclose(rec.u_v, [2.5, 2.6, 2.7], rtol=1e-12)


def test_a_remark_among_the_data_is_skipped_and_said(tmp_path):
    log = tmp_path / "log.csv"
    log.write_text("t,u,pos\n0,5,1\n0.1,5,2\n# operator paused logging\n0.2,5,3\n  # again\n0.3,5,4\n")
    rec = read_rig_log(log, time="t", u="u", l="pos")
    np.testing.assert_array_equal(rec.l_mm, [1.0, 2.0, 3.0, 4.0])
    assert rec.metadata["remarks"] == "2 '#' lines among the data skipped (line 4 and more)"


def test_a_restarted_logger_writes_runs_one_of_which_is_read(tmp_path, capsys):
    """A logger restarted into the same file repeats its header (and units row) with a new clock:
    refused without ``run``, naming where each run starts; each run read on its own."""
    log = tmp_path / "restarted.csv"
    log.write_text("t;u;pos\ns;V;mm\n0;5;1\n0,1;5;2\n0,2;5;3\n"
                   "t;u;pos\ns;V;mm\n0;6;7\n0,1;6;8\n"
                   "t ; u ; pos\n0;7;9\n0,1;7;10\n0,2;7;11\n0,3;7;12\n")
    with pytest.raises(RecordingError, match=r"restarted.csv, line 6: the header again, a logger restarted into the "
                                             r"same file: 3 runs \(1 at line 1, 2 at line 6, 3 at line 10\), each "
                                             r"with its own clock; import one with --run K"):
        read_rig_log(log, time="t", u="u", l="pos")
    for run, l_mm, u_v in ((1, [1, 2, 3], 5.0), (2, [7, 8], 6.0), (3, [9, 10, 11, 12], 7.0)):
        rec = read_rig_log(log, time="t", u="u", l="pos", run=run)
        np.testing.assert_array_equal(rec.l_mm, l_mm)
        np.testing.assert_array_equal(rec.u_v, u_v)
        assert rec.t_s[0] == 0.0 and rec.ts_s == pytest.approx(0.1)
        assert rec.metadata["run"].startswith(f"run {run} of 3")
    with pytest.raises(RecordingError, match=r"run 4 asked for, the log holds 3 \(1 at line 1"):
        read_rig_log(log, time="t", u="u", l="pos", run=4)
    with pytest.raises(RecordingError, match=r"run = 0 is not a run number"):
        read_rig_log(log, time="t", u="u", l="pos", run=0)
    out = tmp_path / "rec.csv"
    assert main(["import", str(log), "--out", str(out), "--time", "t", "--u", "u", "--l", "pos", "--run", "2"]) == 0
    assert "run 2 of 3 (header at line 6)" in capsys.readouterr().out
    np.testing.assert_array_equal(read_recording(out).l_mm, [7.0, 8.0])
    # a log of one run: --run 1 reads it, --run 2 is refused
    single = tmp_path / "single.csv"
    single.write_text("t,u,pos\n0,5,1\n0.1,5,2\n")
    np.testing.assert_array_equal(read_rig_log(single, time="t", u="u", l="pos", run=1).l_mm, [1.0, 2.0])
    with pytest.raises(RecordingError, match=r"run 2 asked for, the log holds 1 \(1 at line 1\)"):
        read_rig_log(single, time="t", u="u", l="pos", run=2)
    assert (rig_log_runs(log), rig_log_runs(single)) == (3, 1)


def test_every_run_of_a_restarted_log_is_imported_to_its_own_file_or_none_is(tmp_path, capsys):
    """``--run all`` writes OUT_runK per run, each the same as ``--run K``; one run refused (a command
    in percent in the second run) writes none, names the run, and leaves earlier files untouched."""
    log = tmp_path / "restarted.csv"
    log.write_text("t,u,pos\n0,5,1\n0.1,5,2\nt,u,pos\n0,6,7\n0.1,6,8\n0.2,6,9\n")
    args = ["--time", "t", "--u", "u", "--l", "pos"]
    assert main(["import", str(log), "--out", str(tmp_path / "rec.csv"), "--run", "all"] + args) == 0
    assert not (tmp_path / "rec.csv").exists()
    for k in (1, 2):
        assert main(["import", str(log), "--out", str(tmp_path / f"one{k}.csv"), "--run", str(k)] + args) == 0
        assert (tmp_path / f"rec_run{k}.csv").read_text() == (tmp_path / f"one{k}.csv").read_text()
    np.testing.assert_array_equal(read_recording(tmp_path / "rec_run2.csv").l_mm, [7.0, 8.0, 9.0])
    capsys.readouterr()

    bad = tmp_path / "bad.csv"
    bad.write_text("t,u,pos\n0,5,3\n0.1,5,4\nt,u,pos\n0,60,7\n0.1,60,8\n")
    before = (tmp_path / "rec_run1.csv").read_text()
    assert main(["import", str(bad), "--out", str(tmp_path / "rec.csv"), "--run", "all"] + args) == 2
    err = capsys.readouterr().err
    assert "run 2 of 2: " in err and "60 V is outside" in err and "nothing written" in err
    assert (tmp_path / "rec_run1.csv").read_text() == before
    assert sorted(f.name for f in tmp_path.glob("rec*")) == ["rec_run1.csv", "rec_run2.csv"]
    with pytest.raises(SystemExit) as exc:
        main(["import", str(bad), "--out", str(tmp_path / "x.csv"), "--run", "0"] + args)
    assert exc.value.code == 2
    assert "--run must be a run number (1 = the first) or 'all', got '0'" in capsys.readouterr().err


def test_day_first_dotted_dates_as_a_german_locale_writes_them(tmp_path):
    log = tmp_path / "de.csv"
    log.write_text("Zeit;Ventil [V];Weg [mm]\n"
                   "31.12.2024 23:59:59,9;2,5;0\n01.01.2025 00:00:00;2,5;0,5\n01.01.2025 00:00:00,1;2,5;1\n"
                   "1.1.2025 00:00:00.2;2,5;1,5\n")
    rec = read_rig_log(log, time="Zeit:iso", u="Ventil [V]", l="Weg [mm]")
    np.testing.assert_allclose(rec.t_s, [0.0, 0.1, 0.2, 0.3], atol=1e-9)  # across a year's end
    np.testing.assert_array_equal(rec.l_mm, [0.0, 0.5, 1.0, 1.5])
    assert rec.metadata["start"] == "31.12.2024 23:59:59,9"
    # a dotted date that is not a day-first date is refused like any other text
    log.write_text("Zeit;u;l\n13.31.2024 10:00:00;1;0\n")
    with pytest.raises(RecordingError, match=r"line 2, column 'Zeit': '13.31.2024 10:00:00' is not an ISO 8601 "
                                             r"\(or day.month.year\) time"):
        read_rig_log(log, time="Zeit:iso", u="u", l="l")


@pytest.mark.parametrize("kwargs, match", [
    (dict(decimal=",,"), r"decimal = ',,' is not a decimal mark \('.' or ','\)"),
    (dict(fill_gaps_s=-1.0), r"fill_gaps_s = -1.0 is not a number of seconds >= 0"),
    (dict(fill_gaps_s=float("nan")), r"fill_gaps_s = nan is not a number"),
])
def test_reading_options_are_checked_before_the_file_is_read(tmp_path, kwargs, match):
    with pytest.raises(RecordingError, match=match):
        read_rig_log(tmp_path / "not_read.csv", time="t", u="u", l="l", **kwargs)


@pytest.mark.parametrize("sep,decimal", [(",", "."), (";", ",")])
def test_every_number_reads_to_the_bit_as_float_reads_its_text(tmp_path, sep, decimal):
    """The columns are read all at once: the values are float()'s of the cells, in any notation."""
    rng = np.random.default_rng(5)
    n = 3000
    t_text = [f"{0.01 * k:.2f}" for k in range(n)]
    x = (rng.standard_normal(n) * 10.0 ** rng.integers(-8, 9, n)).tolist()
    notations = [repr, lambda v: f"{v:.17g}", lambda v: f"{v:.3f}", lambda v: f"{v:.20e}", lambda v: f"{v:+.1E}"]
    u_text = [notations[k % len(notations)](v) for k, v in enumerate(x)]
    log = tmp_path / "numbers.csv"
    with open(log, "w") as f:
        f.write(sep.join(["t", "u", "l"]) + "\n")
        for tk, uk in zip(t_text, u_text):
            f.write(sep.join(c.replace(".", decimal) for c in (tk, uk, " 1.5 ")) + "\n")
    rec = read_rig_log(log, time="t", u="u", l="l")
    expected = np.array([float(c) for c in u_text])
    assert np.array_equal(rec.columns["u_v"].view(np.int64), expected.view(np.int64))
    assert rec.columns["l_mm"].tolist() == [1.5] * n


@pytest.mark.parametrize("cell,message", [
    ("1e999", r"line 5003, column 'u': '1e999' is not finite"),
    ("nan", r"line 5003, column 'u': 'nan' is not finite"),
    ("0x1p3", r"line 5003, column 'u': '0x1p3' is not a number"),
    ("1.5", r"line 5003, column 'u': '1.5' is not a number with the decimal mark ','"),
])
def test_the_first_bad_cell_of_a_long_column_is_named(tmp_path, cell, message):
    rows = [f"{0.1 * k:.1f};{k % 7}.5;{k}".replace(".", ",") for k in range(8000)]
    rows[5000] = rows[5000].split(";")[0] + f";{cell};0"
    rows[7000] = rows[7000].split(";")[0] + ";x;0"  # a later bad cell is not the one named
    log = tmp_path / "late.csv"
    log.write_text("t;u;l\n# a remark\n" + "\n".join(rows) + "\n")
    with pytest.raises(RecordingError, match=message):
        read_rig_log(log, time="t", u="u", l="l")


def test_the_likely_pressure_unit_is_the_one_reading_nearest_the_supply():
    from tapmuscle.io.rig_log import likely_pressure_unit

    # a 0.25-MPa supply logged in kPa but declared MPa; in psi declared kPa; gauge units only
    assert likely_pressure_unit(250.0, "MPa", near_mpa=0.25, within_mpa=2.0) == ("kPa", pytest.approx(0.25))
    assert likely_pressure_unit(36.26, "kPa", near_mpa=0.25, within_mpa=2.0) == ("psi", pytest.approx(0.25, rel=1e-3))
    # an absolute sensor: the ambient taken off (the standard atmosphere unless given), absolute units only
    unit, reading = likely_pressure_unit(3.5, "MPa_abs", near_mpa=0.25, within_mpa=2.0)
    assert unit == "bar_abs" and reading == pytest.approx(0.35 - 0.101325)
    assert likely_pressure_unit(3.5, "MPa_abs", near_mpa=0.25, within_mpa=2.0, ambient_mpa=0.09)[1] == pytest.approx(0.26)
    assert likely_pressure_unit(1e12, "MPa", near_mpa=0.25, within_mpa=2.0) is None  # no unit reads it so


@pytest.mark.parametrize("gap, double, nan", [(100, 300, 200), (300, 100, 200), (300, 200, 100)])
def test_the_first_problem_in_the_file_is_named_with_the_others(tmp_path, gap, double, nan):
    """A dropped sample, a doubled time and a NaN: the error names whichever comes first in the file and
    lists the lines of the others, by column, so that the log is mended in one pass."""
    rows = [[f"{0.1 * k:.1f}", f"{k % 7}.5", f"{k}"] for k in range(400)]
    rows[nan][2] = "nan"
    rows[gap] = None
    rows.insert(double, list(rows[double - 1] or rows[double - 2])[:2] + ["-1"])  # its time again, not its row
    rows = [r for r in rows if r is not None]
    t = [float(r[0]) for r in rows]
    line = {"nan": next(k for k, r in enumerate(rows) if r[2] == "nan") + 2,  # the header is line 1
            "double": next(k for k in range(1, len(t)) if t[k] <= t[k - 1]) + 2,
            "gap": next(k for k in range(1, len(t)) if t[k] - t[k - 1] > 0.15) + 2}
    log = tmp_path / "log.csv"
    log.write_text("t;u;l\n" + "\n".join(";".join(r) for r in rows) + "\n")
    first = min(line, key=line.get)
    with pytest.raises(RecordingError) as info:
        read_rig_log(log, time="t", u="u", l="l")
    assert info.value.line == line[first]
    message = str(info.value)
    assert re.search(rf"line {line[first]}\b", message.split("(further")[0]), message
    column = {"nan": "l", "double": "t", "gap": "t"}
    for k, v in line.items():
        if k != first:
            assert re.search(rf"further problems: .*column '{column[k]}' at lines? [\d, ]*\b{v}\b", message), message


def test_a_linear_map_is_a_conversion_with_an_offset_not_a_factor():
    col = LogColumn("Ventil", "mA")
    assert col.conversion("u_v") == pytest.approx((0.625, -2.5))  # 4..20 mA -> 0..10 V
    with pytest.raises(ValueError, match="'mA' is a linear map with an offset, not a factor"):
        col.factor("u_v")
    assert LogColumn("Weg", "cm").factor("l_mm") == 10.0


def test_a_load_logged_as_a_mass_in_kg_is_read_as_its_weight(tmp_path):
    log = tmp_path / "mass.csv"
    log.write_text("t,u,l,mass\n" + "".join(f"{0.1 * k:.1f},5,{0.01 * k:.2f},4.4868\n" for k in range(50)))
    rec = read_rig_log(log, time="t", u="u", l="l", load="mass:kg")
    assert np.allclose(rec.load_n, 4.4868 * 9.80665) and abs(rec.load_n[0] - 44.0) < 0.01


def test_a_column_named_with_its_unit_is_not_shown_with_it_twice(tmp_path):
    """"Weg [mm]" read as mm is said as "l_mm <- Weg [mm]", not "l_mm <- Weg [mm] [mm]"."""
    log = tmp_path / "log.csv"
    log.write_text("Zeit [s];Ventil [V];Weg [mm]\n" + "".join(f"{0.1 * k:.1f};{5 + k % 3};{10 + k % 5}\n" for k in range(50)))
    rec = tm.read_rig_log(log, time="Zeit [s]", u="Ventil [V]", l="Weg [mm]", load_n=44.0, checks=False)
    assert rec.metadata["source"].endswith("t_s <- Zeit [s], u_v <- Ventil [V], l_mm <- Weg [mm]")
