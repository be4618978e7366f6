"""DAQ exports as users bring them to ``tapmuscle import`` (tapmuscle/io/rig_log.py,
tapmuscle/cli/rig_import.py): units the log writes itself, wrong units that stay within the hard
bounds, 4-20 mA commands, clock changes and sample counters, sensor faults, spreadsheet error
values, and refusals that name every bad line and the COLUMN:UNIT that fits."""

from __future__ import annotations

import re
from datetime import datetime, timedelta

import numpy as np
import pytest

from tapmuscle.cli.main import main
from tapmuscle.diagnosis.demo import DEMO_MODEL, record
from tapmuscle.io.recording import RecordingError, read_recording
from tapmuscle.io.rig_log import LogColumn, parse_column_spec, read_rig_log


@pytest.fixture(scope="module")
def truth():
    return record(DEMO_MODEL, "sine", 1, duration_s=30.0)


def _write(path, header, rows, *, sep=";", pre=(), units=None, encoding="utf-8"):
    lines = list(pre) + [sep.join(header)] + ([sep.join(units)] if units else [])
    lines += [sep.join(r) for r in rows]
    path.write_text("\n".join(lines) + "\n", encoding=encoding)
    return path


def _rows(truth, *, t=lambda t: f"{t:.1f}", u=lambda u: f"{u:.5f}", l=lambda l: f"{l:.3f}",  # noqa: E741
          p=lambda p: f"{p:.5f}"):
    return [[t(a), u(b), l(c), p(d)] for a, b, c, d in zip(truth["t_s"], truth["u_v"], truth["l_mm"], truth["p_mpa"])]


def _import(log, out, *options):
    return main(["import", str(log), "--out", str(out), "--load-n", "44", *options])


# -- 1. units the log gives ------------------------------------------------------------------------

def test_a_units_row_and_units_in_names_are_read_where_none_is_given(tmp_path, truth, capsys):
    """``s;V;cm;bar`` under the header, ``Druck [bar]``, ``Position_mm``: read in those units, and said;
    a unit given that agrees passes silently."""
    log = _write(tmp_path / "row.csv", ["Zeit", "Ventil", "Position", "Druck"],
                 _rows(truth, l=lambda l: f"{l / 10:.4f}", p=lambda p: f"{10 * p:.5f}"), units=["s", "V", "cm", "bar"])
    rec = read_rig_log(log, time="Zeit", u="Ventil", l="Position", p="Druck")
    assert np.max(np.abs(rec.l_mm - truth["l_mm"])) <= 0.5e-3 + 1e-12
    assert np.max(np.abs(rec.columns["p_mpa"] - truth["p_mpa"])) <= 0.5e-6 + 1e-12
    assert rec.metadata["units"] == ("l_mm in cm, as the log says ('Position': the units row, line 2; no unit given); "
                                     "p_mpa in bar, as the log says ('Druck': the units row, line 2; no unit given)")
    assert "l_mm <- Position [cm]" in rec.metadata["source"]
    assert _import(log, tmp_path / "rec.csv", "--time", "Zeit", "--u", "Ventil", "--l", "Position", "--p", "Druck") == 0
    assert "note: Units: l_mm in cm, as the log says ('Position': the units row, line 2; no unit given)" in (
        capsys.readouterr().err)
    names = _write(tmp_path / "names.csv", ["t", "u", "Position_mm", "Druck [bar]"], _rows(truth, p=lambda p: f"{10 * p:.5f}"))
    rec = read_rig_log(names, time="t", u="u", l="Position_mm", p="Druck [bar]")
    assert np.max(np.abs(rec.columns["p_mpa"] - truth["p_mpa"])) <= 0.5e-6 + 1e-12
    assert rec.metadata["units"] == "p_mpa in bar, as the log says ('Druck [bar]': its name; no unit given)"  # mm: the default
    assert "units" not in read_rig_log(names, time="t", u="u", l="Position_mm:mm", p="Druck [bar]:bar").metadata
    # a name's suffix is a weaker claim than brackets or a units row: a column renamed to the
    # recording's t_s and left in ms is read as given, and the difference said
    ms = _write(tmp_path / "ms.csv", ["t_s", "u_v", "l_mm"], [[f"{100 * k}"] + r[1:3] for k, r in enumerate(_rows(truth))],
                sep=",")
    rec = read_rig_log(ms, time="t_s:ms", u="u_v", l="l_mm")
    assert rec.ts_s == pytest.approx(0.1) and rec.metadata["units"] == "t_s in ms as given, though its name 't_s' says s"
    assert _import(ms, tmp_path / "rec.csv", "--time", "t_s", "--u", "u_v", "--l", "l_mm") == 2  # so the remedy is
    assert "the column is likely in ms (--time t_s:ms)" in capsys.readouterr().err
    # a name's suffix counts only where it is a unit: Valve_cmd is no unit, and nothing is said of it
    cmd = _write(tmp_path / "cmd.csv", ["t", "Valve_cmd", "l"], [r[:3] for r in _rows(truth)])
    assert "units_unknown" not in read_rig_log(cmd, time="t", u="Valve_cmd", l="l").metadata


def test_a_unit_given_that_contradicts_the_logs_is_refused_naming_both_and_the_line(tmp_path, truth):
    log = _write(tmp_path / "row.csv", ["Zeit", "Ventil", "Position", "Druck [bar]"], _rows(truth), units=["s", "V", "cm", ""])
    with pytest.raises(RecordingError, match=r"row.csv, line 2, column 'Position' \(l_mm\): the log gives its unit as 'cm' "
                                             r"\(the units row, line 2\), the unit given is 'mm': give it as the log does "
                                             r"\(Position:cm\), or as scale=A,offset=B"):
        read_rig_log(log, time="Zeit", u="Ventil", l="Position:mm")
    with pytest.raises(RecordingError, match=r"line 1, column 'Druck \[bar\]' \(p_mpa\): the log gives its unit as 'bar' "
                                             r"\(its name\), the unit given is 'kPa': give it as the log does "
                                             r"\('Druck \[bar\]:bar'\)"):
        read_rig_log(log, time="Zeit", u="Ventil", l="Position", p="Druck [bar]:kPa")
    # a map overrides the log's unit (a label that is wrong)
    rec = read_rig_log(log, time="Zeit", u="Ventil", l="Position:scale=1", p="Druck [bar]:scale=1")
    assert np.max(np.abs(rec.l_mm - truth["l_mm"])) <= 0.5e-3 + 1e-12
    both = _write(tmp_path / "both.csv", ["t", "u", "Weg [mm]"], [r[:3] for r in _rows(truth)], units=["s", "V", "cm"])
    with pytest.raises(RecordingError, match=r"line 2, column 'Weg \[mm\]' \(l_mm\): its name says 'mm', the units row, "
                                             r"line 2 'cm': give the column's unit"):
        read_rig_log(both, time="t", u="u", l="Weg [mm]")


def test_a_unit_the_log_writes_that_is_none_known_is_said_not_guessed(tmp_path, truth, capsys):
    log = _write(tmp_path / "counts.csv", ["t", "u", "Weg [counts]"], [r[:3] for r in _rows(truth)], units=["s", "V", "inc"])
    rec = read_rig_log(log, time="t", u="u", l="Weg [counts]")
    assert np.max(np.abs(rec.l_mm - truth["l_mm"])) <= 0.5e-3 + 1e-12  # read in the default, mm
    assert rec.metadata["units_unknown"] == (
        "column 'Weg [counts]' (l_mm): 'counts' (its name) is no unit known for l_mm, read as mm (the default; give its "
        "unit as COLUMN:UNIT); column 'Weg [counts]' (l_mm): 'inc' (the units row, line 2) is no unit known for l_mm, "
        "read as mm (the default; give its unit as COLUMN:UNIT)")
    assert _import(log, tmp_path / "rec.csv", "--time", "t", "--u", "u", "--l", "Weg [counts]") == 0
    assert "note: A unit the log writes is none known: column 'Weg [counts]'" in capsys.readouterr().err


# -- 2. and 3. wrong units within the hard bounds ---------------------------------------------------

def test_a_pressure_no_muscle_of_the_plant_has_is_noted_with_the_unit_it_likely_is(tmp_path, truth, capsys):
    """bar declared as kPa reads at most 2 kPa while the muscle moves 90 mm (it contracts only above
    40 kPa); kPa declared as psi reads 1.4 MPa, more than twice the 0.25-MPa supply."""
    bar = _write(tmp_path / "bar.csv", ["t", "u", "l", "Druck"], _rows(truth, p=lambda p: f"{10 * p:.5f}"))
    assert _import(bar, tmp_path / "rec.csv", "--time", "t", "--u", "u", "--l", "l", "--p", "Druck:kPa") == 0
    err = capsys.readouterr().err
    assert ("note: Column 'Druck' (p_mpa, given in kPa) never exceeds 0.002 MPa while the muscle moves 89.8 mm, where a "
            "muscle contracts only above its threshold pressure (0.04 MPa): bar given as kPa? (1.99951 bar is 0.2 "
            "MPa(G): --p Druck:bar)") in err
    kpa = _write(tmp_path / "kpa.csv", ["t", "u", "l", "Druck"], _rows(truth, p=lambda p: f"{1e3 * p:.2f}"))
    assert _import(kpa, tmp_path / "rec.csv", "--time", "t", "--u", "u", "--l", "l", "--p", "Druck:psi") == 0
    err = capsys.readouterr().err
    assert "(p_mpa, given in psi) reaches 1.38 MPa (line " in err and "kPa given as psi? (199.95 kPa is 0.2 MPa(G): --p Druck:kPa)" in err
    assert _import(kpa, tmp_path / "rec.csv", "--time", "t", "--u", "u", "--l", "l", "--p", "Druck:kPa") == 0
    assert "Druck" not in capsys.readouterr().err  # the right unit: nothing said


def test_centimetres_declared_as_millimetres_are_noted_with_the_unit(tmp_path, truth, capsys):
    log = _write(tmp_path / "cm.csv", ["t", "u", "Weg"], [r[:3] for r in _rows(truth, l=lambda l: f"{l / 10:.4f}")])
    assert _import(log, tmp_path / "rec.csv", "--time", "t", "--u", "u", "--l", "Weg") == 0
    err = capsys.readouterr().err
    assert "note: Column 'Weg' (l_mm) spans 8.98 mm where the nominal model, driven by the same command, spans" in err
    assert "is it in cm rather than mm (--l Weg:cm) (read in cm, it spans 89.8 mm)?" in err


# -- 4. 4-20 mA and linear maps ---------------------------------------------------------------------

def test_a_4_to_20_ma_command_and_a_linear_map(tmp_path, truth, capsys):
    ma = _write(tmp_path / "ma.csv", ["t", "Valve_mA", "l"], [r[:3] for r in _rows(truth, u=lambda u: f"{4 + 1.6 * u:.5f}")])
    rec = read_rig_log(ma, time="t", u="Valve_mA:mA", l="l")
    assert np.max(np.abs(rec.u_v - truth["u_v"])) <= 0.5e-5 / 1.6 + 1e-12
    # the name says mA: read so without the unit, and said
    rec = read_rig_log(ma, time="t", u="Valve_mA", l="l")
    assert np.max(np.abs(rec.u_v - truth["u_v"])) <= 0.5e-5 / 1.6 + 1e-12 and "u_v in mA" in rec.metadata["units"]
    lin = read_rig_log(ma, time="t", u="Valve_mA:scale=0.625,offset=-2.5", l="l")
    np.testing.assert_allclose(lin.u_v, rec.u_v, rtol=0, atol=1e-12)
    assert parse_column_spec("v:scale=2", "u_v").conversion("u_v") == (2.0, 0.0)
    assert LogColumn("v", "mA").conversion("u_v") == (0.625, -2.5)
    with pytest.raises(ValueError, match=r"'scale=x' is not a linear map scale=A,offset=B"):
        parse_column_spec("v:scale=x", "u_v")
    with pytest.raises(ValueError, match=r"unknown unit 'A' for u_v \(known: V, mV, %, pwm\); mA \(a 4-20 mA current "
                                         r"loop of the valve's 0..10 V\); or a linear map scale=A,offset=B"):
        parse_column_spec("v:A", "u_v")
    # a broken loop (below 3.5 mA) refused, every such line named
    rows = [r[:3] for r in _rows(truth, u=lambda u: f"{4 + 1.6 * u:.5f}")]
    rows[10][1], rows[20][1] = "0.00", "21.3"
    broken = _write(tmp_path / "broken.csv", ["t", "Valve_mA", "l"], rows)
    with pytest.raises(RecordingError, match=r"line 12, column 'Valve_mA': 0.00 mA is outside the 3.5..20.5 mA of a 4-20 "
                                             r"mA current loop .*a 0-20 mA signal of 0..10 V is Valve_mA:scale=0.5 "
                                             r"\(further problems: column 'Valve_mA' at line 22\)"):
        read_rig_log(broken, time="t", u="Valve_mA", l="l")
    assert _import(ma, tmp_path / "rec.csv", "--time", "t", "--u", "Valve_mA:mA", "--l", "l") == 0
    assert read_recording(tmp_path / "rec.csv").metadata["source"].endswith("u_v <- Valve_mA [mA], l_mm <- l [mm]")


# -- 5. and 6. clocks ---------------------------------------------------------------------------------

def test_a_clock_change_in_local_stamps_is_named_at_its_line(tmp_path, truth):
    """Local ISO stamps without an offset across the spring-forward change: a 1-h step, named at its
    own line (not line 3) and said to be a clock change; the autumn one goes back an hour."""
    rows = _rows(truth)
    spring = datetime(2024, 3, 31, 1, 59, 50)
    for k, r in enumerate(rows):
        stamp = spring + timedelta(seconds=0.1 * k)
        r[0] = (stamp + timedelta(hours=1) if stamp.hour >= 2 else stamp).isoformat(timespec="milliseconds")
    k = next(k for k, r in enumerate(rows) if r[0].startswith("2024-03-31T03"))
    log = _write(tmp_path / "dst.csv", ["stamp", "u", "l", "p"], rows, sep=",")
    with pytest.raises(RecordingError, match=rf"dst.csv, line {k + 2}: column stamp, sample {k}: t = 3610.0\d* s follows "
                                             r"9.9\d* s, a step of 3600.1 s .*a gap of 3600.1 s.*the step at line "
                                             rf"{k + 2} is an hour: a clock change \(DST\)\? The stamps carry no UTC "
                                             r"offset") as info:
        read_rig_log(log, time="stamp:iso", u="u", l="l")
    assert info.value.line == k + 2
    autumn = datetime(2024, 10, 27, 2, 59, 50)
    for j, r in enumerate(rows):
        stamp = autumn + timedelta(seconds=0.1 * j)
        r[0] = (stamp - timedelta(hours=1) if stamp.hour >= 3 else stamp).isoformat(timespec="milliseconds")
    log = _write(tmp_path / "dst2.csv", ["stamp", "u", "l", "p"], rows, sep=",")
    with pytest.raises(RecordingError, match=rf"line {k + 2}, column 'stamp': time does not increase \('2024-10-27T02:59:59"
                                             r".900', then '2024-10-27T02:00:00.000'\): a clock change \(DST\)\?"):
        read_rig_log(log, time="stamp:iso", u="u", l="l")


def test_a_sample_counter_is_said_and_ts_builds_the_times(tmp_path, truth, capsys):
    rows = [[str(k)] + r[1:3] for k, r in enumerate(_rows(truth))]
    log = _write(tmp_path / "counter.csv", ["Sample", "u", "l"], rows, sep=",")
    rec = read_rig_log(log, time="Sample", u="u", l="l")
    assert rec.ts_s == 1.0 and "column 'Sample' counts 0, 1, 2, ... (consecutive integers), read as seconds" in (
        rec.metadata["time_counter"])
    assert _import(log, tmp_path / "rec.csv", "--time", "Sample", "--u", "u", "--l", "l") == 0
    assert "note: Time: column 'Sample' counts 0, 1, 2, ..." in capsys.readouterr().err
    # --ts with the counter: its counts times the period; without --time: the row numbers
    for options in (["--time", "Sample", "--ts", "0.1"], ["--ts", "0.1"]):
        assert _import(log, tmp_path / "rec.csv", *options, "--u", "u", "--l", "l") == 0
        rec = read_recording(tmp_path / "rec.csv")
        np.testing.assert_allclose(rec.t_s, truth["t_s"], atol=1e-9)
        assert "counts" not in capsys.readouterr().err
    assert "t_s <- row number x 0.1 s" in rec.metadata["source"]
    # a count skipped is a dropped sample, named by its line
    del rows[100]
    skipped = _write(tmp_path / "skipped.csv", ["Sample", "u", "l"], rows, sep=",")
    with pytest.raises(RecordingError, match=r"line 102: column Sample, sample 100: .*a dropped or doubled sample"):
        read_rig_log(skipped, time="Sample", u="u", l="l", ts_s=0.1)
    with pytest.raises(RecordingError, match=r"ts_s builds the times from a column of sample numbers: give the time "
                                             r"column 'Sample' without a unit"):
        read_rig_log(log, time="Sample:s", u="u", l="l", ts_s=0.1)
    assert _import(log, tmp_path / "rec.csv", "--u", "u", "--l", "l") == 2
    assert "--time COLUMN[:UNIT] or --ts S" in capsys.readouterr().err
    # whole seconds given as seconds (a 1-s recording, --time t:s) are not taken for a counter
    assert "time_counter" not in read_rig_log(log, time="Sample:s", u="u", l="l").metadata


def test_a_row_with_a_missing_value_keeps_its_slot_when_times_are_row_numbers(tmp_path, truth):
    """--ts without a time column and --fill-gaps: the row is put back in its own slot (the rows after
    it keep their times), and one at the log's end is said not to be put back."""
    rows = [r[1:3] for r in _rows(truth)]
    rows[20][1] = "#VALUE!"
    rows[-1][1] = ""
    log = _write(tmp_path / "notime.csv", ["u", "l"], rows, sep=",")
    rec = read_rig_log(log, u="u", l="l", ts_s=0.1, fill_gaps_s=1.0)
    np.testing.assert_allclose(rec.t_s, truth["t_s"][:-1], atol=1e-9)
    assert rec.columns["l_mm"][21] == pytest.approx(truth["l_mm"][21], abs=1e-3)  # line 23's reading at 2.1 s
    assert rec.columns["filled"][20] == 1.0
    assert re.search(r"at the log's end, not put back .*: the recording starts or ends there", rec.metadata["missing"])


# -- 7. sensor faults -----------------------------------------------------------------------------------

def test_a_clipped_reading_and_a_wrap_are_noted_with_their_lines(tmp_path, truth, capsys):
    l = np.asarray(truth["l_mm"])  # noqa: E741
    rows = _rows(truth, l=lambda v: f"{min(v, 60.0):.3f}")
    log = _write(tmp_path / "clip.csv", ["t", "u", "l", "p"], rows)
    assert _import(log, tmp_path / "rec.csv", "--time", "t", "--u", "u", "--l", "l") == 0
    k = int(np.argmax(l >= 60.0))
    assert re.search(r"note: Column 'l' \(l_mm\) is held at exactly 60 mm, its largest reading, \d times, each reached at "
                     rf"speed: from line {k + 2} \(", capsys.readouterr().err)
    wrapped = _write(tmp_path / "wrap.csv", ["t", "u", "l", "p"], _rows(truth, l=lambda v: f"{v % 75.0:.3f}"))
    assert _import(wrapped, tmp_path / "rec.csv", "--time", "t", "--u", "u", "--l", "l") == 0
    k = int(np.argmax(l >= 75.0))
    assert "An encoder's count wrapping at" in capsys.readouterr().err.partition(f"at line {k + 2} (-")[2]


# -- 8. and 9. missing values, every bad line ----------------------------------------------------------

def test_a_spreadsheet_error_value_is_a_missing_value_not_a_remark(tmp_path, truth, capsys):
    rows = [r[:3] for r in _rows(truth)]
    rows[120][0] = "#N/A"
    log = _write(tmp_path / "na.csv", ["t", "u", "l"], rows, sep=",")
    with pytest.raises(RecordingError, match=r"line 122, column 't': '#N/A' is not a number: a missing value \(mend the "
                                             r"log, or --fill-gaps S puts the row back"):
        read_rig_log(log, time="t", u="u", l="l")
    rec = read_rig_log(log, time="t", u="u", l="l", fill_gaps_s=0.5)
    assert "remarks" not in rec.metadata and rec.metadata["missing"].startswith("1 row with a missing value dropped (line 122)")
    assert rec.columns["filled"][120] == 1.0 and len(rec) == len(truth["t_s"])
    assert _import(log, tmp_path / "rec.csv", "--time", "t", "--u", "u", "--l", "l", "--fill-gaps", "0.5") == 0
    assert "note: Missing values: 1 row with a missing value dropped (line 122)" in capsys.readouterr().err


def test_every_bad_line_of_every_column_is_named(tmp_path, truth):
    rows = _rows(truth)
    rows[10][2], rows[50][2], rows[60][3], rows[70][1] = "NaN", "#DIV/0!", "abc", "#VALUE!"
    del rows[200], rows[100]  # two dropped samples
    log = _write(tmp_path / "bad.csv", ["t", "u", "l", "p"], rows)
    with pytest.raises(RecordingError) as info:
        read_rig_log(log, time="t", u="u", l="l", p="p")
    message = str(info.value)
    assert message.startswith(f"{log}, line 12, column 'l': 'NaN' is not finite: a missing value")
    assert message.endswith("(further problems: column 'l' at line 52; column 'p' at line 62; column 'u' at line 72; "
                            "column 't' at lines 102, 201)")


# -- 10. a padded preamble ----------------------------------------------------------------------------

def test_a_preamble_padded_with_separators_names_the_header_line(tmp_path, truth):
    pre = ["Messprogramm;DAQ-Studio 7.1;;;", "Datum;05.03.2024;;;", "Abtastrate;10 Hz;;;", ";;;;"]
    log = _write(tmp_path / "pre.csv", ["Zeit", "Ventil", "Weg", "Druck"], _rows(truth), pre=pre)
    with pytest.raises(RecordingError, match=r"line 1: no column 'Zeit' for t_s \(found, separated by ';': Messprogramm, "
                                             r"DAQ-Studio 7.1, , , \); line 5 holds every column named: --skip-lines 4 "
                                             r"reads the header there"):
        read_rig_log(log, time="Zeit", u="Ventil", l="Weg")
    assert len(read_rig_log(log, time="Zeit", u="Ventil", l="Weg", skip_lines=4)) == len(truth["t_s"])


# -- 11. the remedy names the COLUMN:UNIT that fits --------------------------------------------------

@pytest.mark.parametrize("column, cell, option, expected", [
    ("Zeit", lambda r: r, ["--time", "Zeit:ms"], r"column 'Zeit' \(t_s, given in ms\): the sampling period is 0.0001 s "
                                                  r"\(0.1 ms\), outside the 0.001..10 s of a muscle recording: the column "
                                                  r"is likely in s \(--time Zeit:s\)"),
    ("Ventil", lambda r: r[:1] + [f"{10 * float(r[1]):.4f}"] + r[2:], ["--u", "Ventil"],
     r"column 'Ventil' \(u_v\): 50 V is outside .*\): the column is likely in % \(--u Ventil:%\)"),
    ("Weg", lambda r: r[:2] + [f"{float(r[2]) / 1e3:.7f}"] + r[3:], ["--l", "Weg"],
     r"column 'Weg' \(l_mm, given in mm\) spans 0.0898 mm .*: is it in another unit \(the column is likely in m "
     r"\(--l Weg:m\)\), the encoder stuck"),
])
def test_a_unit_refused_is_named_with_the_column_unit_that_fits(tmp_path, truth, capsys, column, cell, option, expected):
    log = _write(tmp_path / "log.csv", ["Zeit", "Ventil", "Weg", "Druck"], [cell(r) for r in _rows(truth)])
    options = {"--time": "Zeit", "--u": "Ventil", "--l": "Weg"}
    options[option[0]] = option[1]
    assert _import(log, tmp_path / "rec.csv", *[x for kv in options.items() for x in kv]) == 2
    err = capsys.readouterr().err
    assert re.search(expected, err), err
    assert "Scale it" not in err and "scale it" not in err


# -- 12. duplicates, names in another case, UTF-16 ------------------------------------------------------

def test_a_row_written_twice_is_dropped_and_said(tmp_path, truth):
    rows = _rows(truth)
    rows.insert(101, list(rows[100]))
    log = _write(tmp_path / "dup.csv", ["t", "u", "l", "p"], rows)
    rec = read_rig_log(log, time="t", u="u", l="l")
    assert len(rec) == len(truth["t_s"]) and rec.metadata["duplicates"] == (
        "1 row repeating the row before exactly (the time too) dropped: line 103")
    rows[101][1] = "9.99999"  # its time again, another value: a doubled sample, refused
    log = _write(tmp_path / "dup.csv", ["t", "u", "l", "p"], rows)
    with pytest.raises(RecordingError, match=r"line 103, column 't': time does not increase"):
        read_rig_log(log, time="t", u="u", l="l")


def test_names_in_another_case_match_and_a_near_name_is_proposed(tmp_path, truth):
    log = _write(tmp_path / "case.csv", ["Time", "Valve", "Position", "p"], _rows(truth))
    rec = read_rig_log(log, time="time", u="VALVE", l="position")
    assert rec.metadata["names"] == ("'time' is the log's 'Time'; 'VALVE' is the log's 'Valve'; 'position' is the "
                                     "log's 'Position' (names differ in case or spacing)")
    with pytest.raises(RecordingError, match=r"no column 'Postion' for l_mm .*; did you mean 'Position'\?"):
        read_rig_log(log, time="Time", u="Valve", l="Postion")


def test_a_utf16_log_is_told_by_its_byte_order_mark(tmp_path, truth):
    log = _write(tmp_path / "unicode.txt", ["Zeit", "Ventil", "Weg [µm]", "p"],
                 _rows(truth, l=lambda v: f"{1e3 * v:.0f}"), sep="\t", encoding="utf-16")
    rec = read_rig_log(log, time="Zeit", u="Ventil", l="Weg [µm]")
    assert np.max(np.abs(rec.l_mm - truth["l_mm"])) <= 0.5e-3 + 1e-12 and "l_mm in um" in rec.metadata["units"]


def test_a_channel_named_in_brackets_is_not_taken_for_a_unit(tmp_path, truth):
    rows = [r[:3] for r in _rows(truth)]
    log = _write(tmp_path / "chan.csv", ["time", "valve (ch1)", "pos [AI0]"], rows, sep=",")
    rec = read_rig_log(log, time="time", u="valve (ch1)", l="pos [AI0]")
    assert "units_unknown" not in rec.metadata and "units" not in rec.metadata
    np.testing.assert_allclose(rec.columns["l_mm"], truth["l_mm"], atol=1e-3)
