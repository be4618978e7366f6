"""`tapmuscle record`: outputs, plots, and errors that name the bad value and write nothing."""

import re
import subprocess
import sys

import pytest

from tapmuscle.cli.main import main
from tapmuscle.io.recording import read_recording


def test_record_writes_csv_and_png(tmp_path):
    out = tmp_path / "sub" / "rec.csv"
    assert main(["record", "--load", "68", "--input", "chirp:f0=0.02,f1=0.3,duration=20", "--duration", "20",
                 "--ts", "0.05", "--seed", "2", "--out", str(out), "--plot", "--quiet"]) == 0
    rec = read_recording(out)
    assert len(rec) == 401 and rec.ts_s == 0.05 and rec.metadata["load_n"] == "68"
    assert set(rec.columns) >= {"t_s", "u_v", "l_mm", "p_mpa", "load_n"}
    png = out.with_suffix(".png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_the_load_is_given_once(tmp_path, capsys):
    """``--set load.load_n=68`` (and a --params file's load) must not be silently replaced by --load's
    default 44 N: without --load the file's or --set's load is recorded; --load overrides the file;
    --load and a different --set load.load_n are refused."""
    from tapmuscle.io.plant_file import plant_file_text
    from fmu_plant import PlantParams

    common = ["record", "--input", "const:value=6", "--duration", "2", "--quiet"]
    assert main([*common, "--out", str(tmp_path / "set.csv"), "--set", "load.load_n=68"]) == 0
    assert read_recording(tmp_path / "set.csv").metadata["load_n"] == "68"
    assert read_recording(tmp_path / "set.csv").columns["load_n"][-1] == 68.0
    (tmp_path / "p.json").write_text(plant_file_text(PlantParams().with_values(**{"load.load_n": 30.0}), "rig"))
    assert main([*common, "--out", str(tmp_path / "file.csv"), "--params", str(tmp_path / "p.json")]) == 0
    assert read_recording(tmp_path / "file.csv").metadata["load_n"] == "30"
    assert main([*common, "--out", str(tmp_path / "over.csv"), "--params", str(tmp_path / "p.json"), "--load", "44"]) == 0
    assert read_recording(tmp_path / "over.csv").metadata["load_n"] == "44"
    assert main([*common, "--out", str(tmp_path / "plain.csv")]) == 0
    assert read_recording(tmp_path / "plain.csv").metadata["load_n"] == "44"
    capsys.readouterr()
    assert main([*common, "--out", str(tmp_path / "both.csv"), "--load", "30", "--set", "load.load_n=44"]) == 2
    assert "--load 30 and --set load.load_n=44 name two loads" in capsys.readouterr().err
    assert not (tmp_path / "both.csv").exists()
    assert main([*common, "--out", str(tmp_path / "same.csv"), "--load", "30", "--set", "load.load_n=30"]) == 0


def test_no_load_is_recorded_as_the_plant_runs_it_with_the_braid_lock_note(tmp_path, capsys):
    """0 N is a load the plant, its FMU, scenarios and the API take (with the braid lock's note);
    ``record --load 0`` must not be refused as outside 1e-09..500."""
    assert main(["record", "--input", "const:value=5", "--duration", "2", "--load", "0", "--quiet",
                 "--out", str(tmp_path / "free.csv")]) == 0
    assert read_recording(tmp_path / "free.csv").metadata["load_n"] == "0"
    assert "load_n = 0 N is below the braid lock's 40 N" in capsys.readouterr().err
    with pytest.raises(SystemExit) as refused:
        main(["record", "--input", "const:value=5", "--duration", "2", "--load", "-1", "--quiet",
              "--out", str(tmp_path / "minus.csv")])
    assert refused.value.code == 2
    assert "--load must be within 0..500, got '-1'" in capsys.readouterr().err


def test_parameter_overrides_change_the_rig(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    common = ["--input", "const:value=6", "--duration", "20", "--quiet", "--no-noise"]
    assert main(["record", *common, "--out", str(a)]) == 0
    assert main(["record", *common, "--out", str(b), "--set", "supply.supply_pressure_mpa=0.2"]) == 0
    assert read_recording(a).l_mm[-1] - read_recording(b).l_mm[-1] > 2.0


@pytest.mark.slow
@pytest.mark.parametrize("args, message", [
    (["--load", "-5"], "--load must be within"),
    (["--load", "nan"], "--load must be within"),
    (["--load", "1000"], "--load must be within"),
    (["--duration", "0"], "--duration must be within"),
    (["--duration", "inf"], "--duration must be within"),
    (["--ts", "0"], "--ts must be within"),
    (["--ts", "50", "--duration", "10"], "--ts must be within"),
    (["--ts", "5", "--duration", "1"], "must not exceed --duration"),
    (["--duration", "10.05"], "--duration 10.05 s is not a whole number of sampling periods --ts 0.1 s (100.5); the "
                              "nearest: 10 and 10.1 s"),
    (["--input", "sine:amp=x"], "amp='x' is not a number"),
    (["--input", "triangle:amp=1"], "unknown kind 'triangle'"),
    (["--input", "csv:/nonexistent/u.csv"], "no such recording file"),
    (["--seed", "-1"], "--seed must be within 0..18446744073709551615, got -1"),
    (["--set", "valve.cv_max=-2"], "cv_max"),
    (["--set", "valve.bogus=1"], "bogus"),
])
def test_bad_input_names_the_value_and_writes_nothing(tmp_path, args, message):
    out = tmp_path / "rec.csv"
    base = {"--input": "sine:bias=5,amp=3,freq=0.1", "--duration": "10", "--out": str(out)}
    argv = ["record", "--quiet"]
    for key, value in base.items():
        if key not in args:
            argv += [key, value]
    proc = subprocess.run([sys.executable, "-m", "tapmuscle.cli", *argv, *args], capture_output=True, text=True)
    assert proc.returncode == 2
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_existing_output_survives_a_failed_run(tmp_path):
    out = tmp_path / "rec.csv"
    out.write_text("precious")
    rc = main(["record", "--input", "sine:amp=oops", "--duration", "10", "--out", str(out), "--quiet"])
    assert rc == 2 and out.read_text() == "precious"


@pytest.mark.parametrize("extra, pattern", [
    (["--input", "const:value=1e308"], r"the command is 1e\+308 V at t = 0 s; the valve takes 0\.\.10 V"),
    (["--input", "const:value=-5"], r"the command is -5 V at t = 0 s"),
    (["--input", "sine:bias=5,amp=1e308,freq=0.1"], r"the valve takes 0\.\.10 V"),
    (["--input", "random:hold_min=1e-7,hold_max=1e-7"], r"0\.001 s <= hold_min"),
    (["--input", "const:value=5", "--duration", "86400", "--ts", "0.01"], r"makes 8640001 samples; at most 864001"),
])
def test_commands_outside_the_valve_or_endless_are_refused_before_running(tmp_path, capsys, extra, pattern):
    """The recorded u_v is what the valve receives: out-of-range commands, endless random signals and
    absurd lengths are named at once (rather than written unclipped, or left to hang)."""
    out = tmp_path / "rec.csv"
    args = ["record", "--load", "44", "--duration", "20", "--out", str(out), "--quiet"]
    assert main(args + extra) == 2  # a repeated --duration: the last one counts
    err = capsys.readouterr().err
    assert re.search(pattern, err) and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_a_plot_that_cannot_be_written_leaves_no_csv(tmp_path, capsys):
    out = tmp_path / "rec.csv"
    (tmp_path / "rec.png").mkdir()  # the plot's path is a directory
    assert main(["record", "--load", "44", "--input", "const:value=5", "--duration", "2", "--out", str(out),
                 "--plot", "--quiet"]) == 2
    assert "rec.png is a directory" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.png"]


def test_seeds_are_unsigned_64_bit_on_the_command_line(tmp_path, capsys):
    from fmu_plant.seed import SEED_MAX

    assert sys.modules["tapmuscle.cli.main"]._SEED_MAX == SEED_MAX  # the parser's copy of the bound
    out = tmp_path / "rec.csv"
    base = ["record", "--load", "44", "--input", "const:value=5", "--duration", "1", "--out", str(out), "--quiet"]
    with pytest.raises(SystemExit):
        main(base + ["--seed", str(2 ** 64)])
    assert "--seed must be within 0..18446744073709551615" in capsys.readouterr().err
    assert main(base + ["--seed", str(2 ** 64 - 1)]) == 0
    assert read_recording(out).metadata["seed"] == str(2 ** 64 - 1)


@pytest.mark.parametrize("setting, pattern", [
    ("sensor.encoder_noise_std_mm=1e300", r"encoder_noise_std_mm.*1e\+300"),
    ("friction.rate_gain=1e308", r"rate_gain.*1e\+308"),
])
def test_absurd_plant_parameters_are_refused_in_one_line(tmp_path, capsys, setting, pattern):
    """Every plant parameter has bounds (physically generous): 1e308 must not end in a FloatingPointError
    and a 1.3 kB parameter dump."""
    out = tmp_path / "rec.csv"
    assert main(["record", "--load", "44", "--input", "const:value=5", "--duration", "2", "--out", str(out),
                 "--set", setting, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert re.search(pattern, err) and len(err.splitlines()) == 1 and len(err) <= 300, err
    assert not out.exists()


@pytest.mark.parametrize("argv", [
    ["record", "--load", "44", "--input", "const:value=5", "--duration", "1", "--out", ""],
    ["run", "x.toml", "--out", "  "],
    ["diagnose", "--recording", "r.csv", "--plant", "p.json", "--out", ""],
    ["sweep", "s.toml", "--out", ""],
])
def test_an_empty_output_path_is_refused_in_one_line(capsys, argv):
    """``--out ''`` must not mean the current folder and end in 'Device or resource busy' naming a temp file."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "must name a file or folder, got an empty string" in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("argv, said", [
    (["identify", "r.csv", "--json", "DIR"], "--json DIR: a folder, not a file to write"),
    (["check", "s.toml", "--junit", "DIR"], "--junit DIR: a folder, not a file to write"),
    (["diagnose", "--recording", "r.csv", "--plant", "p.json", "--out", "FILE"], "--out FILE: a file, not a folder"),
    (["record", "--load", "44", "--input", "const:value=5", "--duration", "1", "--out", "FILE/r.csv"],
     "--out FILE/r.csv: FILE is a file, not a folder"),
    # a folder no one may write into (another process's: also for root), found before the runs
    (["check", "s.toml", "--junit", "/proc/1/report.xml"], "--junit /proc/1/report.xml: the folder /proc/1 cannot be "
     "written"),
    # an existing output folder that cannot take files is named itself, not its parent
    (["sweep", "s.toml", "--out", "/proc/1"], "--out /proc/1: the folder /proc/1 cannot be written"),
])
def test_an_output_path_of_the_wrong_kind_is_refused_before_any_work(tmp_path, monkeypatch, capsys, argv, said):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "DIR").mkdir()
    (tmp_path / "FILE").write_text("keep")
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and said in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DIR", "FILE"] and (tmp_path / "FILE").read_text() == "keep"


def test_an_effect_given_twice_is_refused(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # its relative output: a source tree may be read-only
    assert main(["diagnose", "--recording", "r.csv", "--plant", "p.json", "--out", "o",
                 "--effects", "transport_delay,backlash,transport_delay"]) == 2
    assert "'transport_delay' is given twice" in capsys.readouterr().err


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A 60-s noise-free recording of random steps, and copies of it with its times shifted by 1000 s
    and with a logger's +-3 ms jitter."""
    import numpy as np

    from tapmuscle.io.recording import Recording, write_recording

    d = tmp_path_factory.mktemp("replay")
    assert main(["record", "--input", "random:lo=2,hi=8,hold_min=0.2,hold_max=1,seed=3", "--duration", "60",
                 "--no-noise", "--out", str(d / "a.csv"), "--quiet"]) == 0
    a = read_recording(d / "a.csv")
    shifts = {"shifted": np.full(len(a), 1000.0), "jittered": np.random.default_rng(1).uniform(-0.003, 0.003, len(a))}
    for name, dt in shifts.items():
        write_recording(d / f"{name}.csv", Recording({**a.columns, "t_s": a.t_s + dt}, {}))
    return d, a


def _replay(d, name):
    out = d / f"b_{name}.csv"
    if not out.exists():
        assert main(["record", "--input", f"csv:{d / name}.csv", "--duration", "60", "--no-noise", "--out", str(out),
                     "--quiet"]) == 0
    return read_recording(out)


@pytest.mark.parametrize("name", ["shifted", "jittered"])
def test_a_replay_runs_the_recorded_commands_sample_by_sample(recorded, name):
    """Replaying a recording that starts at 1000 s must not run one constant command, nor one with logger
    jitter run some commands a period late (l off by several mm): both run as the recording itself."""
    import numpy as np

    d, a = recorded
    b, b0 = _replay(d, name), _replay(d, "a")
    assert np.array_equal(b.u_v, a.u_v) and np.array_equal(b.t_s, a.t_s)
    assert np.array_equal(b.l_mm, b0.l_mm)
    # the response too, but for the 0.01-mm quantisation (the file keeps the commands to 1 uV)
    assert np.max(np.abs(b.l_mm - a.l_mm)) <= 0.0100001


@pytest.mark.parametrize("extra, pattern", [
    (["--duration", "220"], r"the run's duration 220 s \(2201 samples\) is longer than .*shifted\.csv's 60 s \(601 "
                            r"samples every 0\.1 s\): there is no command after its end; run for at most 60 s"),
    (["--duration", "60", "--ts", "0.05"], r"shifted\.csv is sampled every 0\.1 s, the run every 0\.05 s: a replay "
                                           r"goes sample by sample; run it at 0\.1 s"),
])
def test_a_replay_is_not_resampled_silently(recorded, tmp_path, capsys, extra, pattern):
    """A run longer than the recording would hold its last command, and another --ts would resample it,
    with no word: both are refused, naming both values, and nothing is written."""
    d, _ = recorded
    out = tmp_path / "refused.csv"
    assert main(["record", "--input", f"csv:{d / 'shifted.csv'}", "--out", str(out), "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert re.search(pattern, err) and len(err.splitlines()) == 1, err
    assert not out.exists()
    # a shorter run replays the recording's start
    assert main(["record", "--input", f"csv:{d / 'shifted.csv'}", "--duration", "30", "--no-noise", "--out", str(out),
                 "--quiet"]) == 0
    assert len(read_recording(out)) == 301


def test_an_output_under_a_folder_one_may_not_enter_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    """A folder on the way that this user may not enter (another user's home, mode 0700): Python
    3.11's Path.exists and is_dir raise PermissionError on it; the command refuses the path in one
    line. Emulated (root enters every folder): every stat below ``closed`` is refused."""
    import errno
    import os
    import pathlib

    closed = tmp_path / "closed"
    real_stat = pathlib.Path.stat

    def stat(self, *args, **kwargs):
        if str(self).startswith(str(closed) + os.sep):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))
        return real_stat(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "stat", stat)
    with pytest.raises(SystemExit) as exc:
        main(["record", "--load", "44", "--input", "const:value=5", "--duration", "1", "--out",
              str(closed / "x.csv")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"--out {closed / 'x.csv'}: {closed / 'x.csv'} cannot be reached (Permission denied; no permission" in err
    # another reason (a name too long for the file system) is said without the hint
    long = tmp_path / ("a" * 300) / "x.csv"
    with pytest.raises(SystemExit):
        main(["record", "--load", "44", "--input", "const:value=5", "--duration", "1", "--out", str(long)])
    err = capsys.readouterr().err
    assert "cannot be reached (File name too long)" in err and "permission" not in err
