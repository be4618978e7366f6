"""The recording format: round trip, errors that name file/line/column, atomic writes."""

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


@pytest.mark.parametrize("body, match", [
    ("t_s,u_v\n0,1\n", r"line 1: header has no 'l_mm'"),
    ("t_s,u_v,l_mm\n0,1,2\n0.1,1,abc\n", r"line 3, column 'l_mm': 'abc' is not a number"),
    ("t_s,u_v,l_mm\n0,1,2\n0.1,nan,2\n", r"line 3, column 'u_v': 'nan' is not finite"),
    ("t_s,u_v,l_mm\n0,1,2\n0.1,1\n", r"line 3: 2 fields, header has 3"),
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
    """Spreadsheet exports start with a UTF-8 BOM; it used to make the header's first name '\\ufefft_s'."""
    path = tmp_path / "bom.csv"
    path.write_bytes("\ufefft_s,u_v,l_mm\n0,1,2\n0.1,1,2.5\n".encode("utf-8"))
    rec = read_recording(path)
    assert list(rec.columns) == ["t_s", "u_v", "l_mm"] and rec.l_mm.tolist() == [2.0, 2.5]
