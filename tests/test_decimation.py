"""Merging a fast log's samples (tapmuscle.io.decimation) and the import that does it."""

import re

import numpy as np
import pytest

from tapmuscle.cli.main import main
from tapmuscle.io.decimation import MAX_DECIMATION, decimated
from tapmuscle.io.recording import Recording, read_recording
from tapmuscle.io.sampling import TS_RANGE_S, check_sampling_period


def _fast(n=1001, ts=0.0005):
    """A 2-kHz recording whose command steps mid-block and ramps at the end."""
    t = np.arange(n) * ts
    u = np.where(t < 0.2013, 3.0, 7.0)
    u[-100:] = np.linspace(7.0, 8.0, 100)
    return Recording({"t_s": t, "u_v": u, "l_mm": np.sin(t), "p_mpa": 0.1 + t}, {"load_n": "44"}, np.arange(n) + 5)


def test_every_block_keeps_its_first_readings_and_its_mean_command():
    rec = _fast()
    merged, note = decimated(rec, 20)
    starts = np.arange(0, len(rec), 20)
    assert len(merged) == len(starts) == 51 and merged.metadata == {"load_n": "44", "decimated": "20"}
    for name in ("t_s", "l_mm", "p_mpa"):
        assert np.array_equal(merged.columns[name], rec.columns[name][starts])
    assert np.array_equal(merged.lines, rec.lines[starts])
    means = [rec.u_v[k:k + 20].mean() for k in starts]  # the last block holds one sample
    np.testing.assert_allclose(merged.u_v, means, rtol=0, atol=1e-12)
    assert merged.ts_s == pytest.approx(0.01, rel=1e-9)
    # the step at 0.2013 s lies within the block from 0.2 s; the ramp moves the last five blocks
    assert 3.0 < merged.u_v[20] < 7.0 and merged.u_v[19] == 3.0 and merged.u_v[21] == 7.0
    assert note.startswith("the command moved within 6 of the 51 blocks of 20 samples (by up to 4 V)")


def test_one_is_the_recording_itself_and_a_bad_factor_is_refused():
    rec = _fast()
    assert decimated(rec, 1) == (rec, None)
    assert decimated(Recording({"t_s": rec.t_s, "u_v": np.full(len(rec), 5.0), "l_mm": rec.l_mm}), 10)[1] is None
    for bad in (0, -3, 2.0, True, MAX_DECIMATION + 1, "10"):
        with pytest.raises(ValueError, match="decimation n = "):
            decimated(rec, bad)


def test_a_period_shorter_than_a_millisecond_asks_to_merge_samples_not_for_another_unit():
    """A 2-kHz log in seconds asks for a merge, not for minutes (which would write a 50-s log as
    3000 s); one beyond the largest merge says so; a period too long asks about milliseconds."""
    with pytest.raises(ValueError, match=r"0.0005 s \(2000 Hz\), shorter than the 0.001 s .* Merge every 40 samples "
                                         r"into one \(tapmuscle import --decimate 40, tm.read_rig_log\(..., decimate=40\), "
                                         r"tm.decimated: Ts = 0.02 s\)"):
        check_sampling_period(0.0005)
    with pytest.raises(ValueError, match=r"Merge every 1000 samples into one \(.*Ts = 0.001 s\)"):
        check_sampling_period(1e-6)  # 1000 x 1 us: not below the bound, the largest merge
    with pytest.raises(ValueError, match=r"Ts = 0.0005 s, still shorter than 0.001 s: resample the log before"):
        check_sampling_period(5e-7)
    with pytest.raises(ValueError, match="milliseconds"):
        check_sampling_period(50.0)
    check_sampling_period(TS_RANGE_S[0])


def test_import_refuses_a_2_khz_log_with_the_factor_and_merges_it_with_decimate(tmp_path, capsys):
    t = np.arange(4001) * 0.0005
    u = 5.0 + 3.0 * np.sin(2 * np.pi * 0.5 * t)
    log = tmp_path / "daq.csv"
    log.write_text("time_s,valve_v,pos_mm\n" + "".join(f"{a:.4f},{b:.5f},{0.0:.3f}\n" for a, b in zip(t, u)))
    out = tmp_path / "rec.csv"
    base = ["import", str(log), "--out", str(out), "--time", "time_s:s", "--u", "valve_v:V", "--l", "pos_mm:mm",
            "--load-n", "44", "--no-checks"]
    assert main(base[:-1]) == 2
    refused = capsys.readouterr().err
    assert re.search(r"column 'time_s' \(t_s, given in s\): the sampling period is 0.0005 s \(2000 Hz\).*--decimate 40",
                     refused) and ":min" not in refused and not out.exists()
    assert main(base + ["--decimate", "20"]) == 0
    rec = read_recording(out)
    assert rec.ts_s == pytest.approx(0.01) and len(rec) == 201 and rec.metadata["decimated"] == "20"
    written = np.round(u, 5)  # as the log holds it; the recording is written to 1e-6 V
    np.testing.assert_allclose(rec.u_v[:-1], written[:-1].reshape(200, 20).mean(axis=1), rtol=0, atol=1e-6)
    assert "Decimated: every 20 samples merged into one (Ts 0.0005 -> 0.01 s" in capsys.readouterr().err


def test_a_period_too_short_in_a_unit_other_than_seconds_offers_both_remedies(tmp_path, capsys):
    """Times in s (0.1 s apart) declared as ms read as a 10-kHz log: the unit that fits comes first, the
    merge second (the unit may be right and the acquisition fast)."""
    t = np.arange(301) * 0.1
    log = tmp_path / "log.csv"
    log.write_text("t,u,l\n" + "".join(f"{a:.1f},{5.0 + np.sin(a):.4f},{10.0 + 8.0 * np.sin(a):.3f}\n" for a in t))
    assert main(["import", str(log), "--out", str(tmp_path / "r.csv"), "--time", "t:ms", "--u", "u", "--l", "l",
                 "--load-n", "44"]) == 2
    err = capsys.readouterr().err
    assert re.search(r"the column is likely in s \(--time t:s\); or, if ms is right, a data acquisition faster than the "
                     r"muscle needs: merge every 200 samples into one \(tapmuscle import --decimate 200, "
                     r"tm.read_rig_log\(..., decimate=200\), tm.decimated: Ts = 0.02 s\)",
                     err), err


def test_a_period_header_is_the_merged_one_and_merging_twice_counts_the_product():
    rec = _fast()
    rec = Recording(rec.columns, {"ts_s": "0.0005", "load_n": "44"}, rec.lines)
    once, _ = decimated(rec, 20)
    assert once.metadata["ts_s"] == "0.01" and once.ts_s == pytest.approx(0.01)
    twice, _ = decimated(once, 5)
    assert twice.metadata["decimated"] == "100" and twice.ts_s == pytest.approx(0.05)
    np.testing.assert_array_equal(twice.l_mm, rec.l_mm[::100])


def test_a_merge_too_small_for_the_log_names_the_logs_own_period_and_the_total(tmp_path, capsys):
    """A 10-kHz log with --decimate 5 (0.5 ms) was told the merged period and a factor for it (40),
    where the log needs 200 in all; a merge beyond 10 s is told to merge fewer."""
    t = np.arange(20001) * 0.0001
    log = tmp_path / "daq.csv"
    log.write_text("time_s,valve_v,pos_mm\n" + "".join(f"{a:.4f},{5.0 + np.sin(a):.4f},{3.0 * np.sin(a):.3f}\n"
                                                         for a in t))
    base = ["import", str(log), "--out", str(tmp_path / "r.csv"), "--time", "time_s:s", "--u", "valve_v", "--l",
            "pos_mm", "--load-n", "44"]
    assert main(base + ["--decimate", "5"]) == 2
    err = capsys.readouterr().err
    assert ("the log is sampled every 0.0001 s (10000 Hz), and --decimate 5 gives 0.0005 s, still shorter than 0.001 s: "
            "merge every 200 samples into one (tapmuscle import --decimate 200") in err, err
    slow = tmp_path / "slow.csv"
    slow.write_text("time_s,valve_v,pos_mm\n" + "".join(f"{a:.1f},{5.0 + np.sin(a):.4f},{3.0 * np.sin(a):.3f}\n"
                                                          for a in np.arange(3001) * 0.1))
    assert main([base[0], str(slow), *base[2:], "--decimate", "200"]) == 2
    assert "--decimate 200 merges the log's 0.1-s samples to 20 s, longer than the 10 s" in capsys.readouterr().err


def test_the_import_option_takes_what_the_merge_takes(tmp_path, capsys):
    """--decimate's range is MAX_DECIMATION's (the command line states it without importing numpy)."""
    from tapmuscle.io.sampling import MAX_DECIMATION

    args = ["import", str(tmp_path / "none.csv"), "--out", str(tmp_path / "r.csv"), "--u", "u", "--l", "l", "--ts", "0.1"]
    with pytest.raises(SystemExit):
        main(args + ["--decimate", str(MAX_DECIMATION + 1)])
    assert "--decimate" in capsys.readouterr().err
    assert main(args + ["--decimate", str(MAX_DECIMATION)]) == 2  # accepted; then the missing file is refused
    assert "none.csv" in capsys.readouterr().err
