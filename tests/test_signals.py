"""Input specs for `tapmuscle record`."""

import bisect
import math

import numpy as np
import pytest

from tapmuscle.io.recording import Recording, write_recording
from tapmuscle.io.signals import parse_input_spec


def test_sine_matches_the_paper_identification_input():
    s = parse_input_spec("sine:bias=5,amp=3,freq=0.1")
    for t in (0.0, 1.3, 2.5, 7.5):
        assert s(t) == pytest.approx(5 + 3 * math.sin(2 * math.pi * 0.1 * t))


def test_step_steps_chirp_random_const():
    assert parse_input_spec("step:initial=4,final=6,at=10")(9.99) == 4
    assert parse_input_spec("step:initial=4,final=6,at=10")(10.0) == 6
    steps = parse_input_spec("steps:levels=3/7/5,period=2")
    assert [steps(t) for t in (0, 2.1, 4.1, 6.1)] == [3, 7, 5, 3]
    chirp = parse_input_spec("chirp:bias=5,amp=1,f0=0,f1=1,duration=10")
    values = np.array([chirp(t) for t in np.arange(0, 10, 0.01)])
    assert values.min() >= 4 - 1e-9 and values.max() <= 6 + 1e-9
    r1, r2 = parse_input_spec("random:lo=2,hi=8,seed=3"), parse_input_spec("random:lo=2,hi=8,seed=3")
    a = [r1(t) for t in np.arange(0, 100, 0.1)]
    assert a == [r2(t) for t in np.arange(0, 100, 0.1)]
    assert 2 <= min(a) and max(a) <= 8 and len(set(a)) > 5
    assert parse_input_spec("const:value=7.5")(123.0) == 7.5


def _random_reference(lo, hi, hold_min, hold_max, seed, t_end):
    """A ``random`` command as its definition reads: the first level at 0 s, then (hold, level) pairs
    drawn in that order from the seed's generator, the whole table at once up to ``t_end`` [s];
    the level of the last switching time at or before ``t`` (the first level before 0 s)."""
    rng = np.random.default_rng(seed)
    times, levels = [0.0], [float(rng.uniform(lo, hi))]
    while times[-1] <= t_end:
        times.append(times[-1] + float(rng.uniform(hold_min, hold_max)))
        levels.append(float(rng.uniform(lo, hi)))

    def level(t):
        # the last of the sorted switching times at or before t (index 0 before 0 s)
        return levels[max(bisect.bisect_right(times, t) - 1, 0)]

    return level, times


@pytest.mark.parametrize("lo, hi, hold_min, hold_max, seed", [
    (2.0, 8.0, 2.0, 10.0, 0), (2.0, 8.0, 2.0, 10.0, 1), (0.0, 10.0, 0.5, 1.0, 3),
    (3.0, 3.5, 0.001, 0.002, 12345),  # the shortest holds: many levels per query step
])
def test_random_command_is_its_definition_wherever_it_is_asked(lo, hi, hold_min, hold_max, seed):
    """The lazily extended table gives the same bits as the table drawn at once: on a run's grid, at
    the switching times themselves (the new level from there on), before 0 s and when asked again for
    an earlier time."""
    t_end = 60.0
    ref, switches = _random_reference(lo, hi, hold_min, hold_max, seed, t_end)
    signal = parse_input_spec(f"random:lo={lo},hi={hi},hold_min={hold_min},hold_max={hold_max},seed={seed}")
    grid = list(np.arange(0.0, t_end, 0.01))
    at_switches = [s for s in switches[1:40] if s <= t_end]
    asked = [-1.0] + grid + at_switches + [np.nextafter(s, -np.inf) for s in at_switches] + [0.0, 30.0, -0.5]
    assert [signal(t) for t in asked] == [ref(t) for t in asked]


def test_csv_replays_the_u_column(tmp_path):
    path = tmp_path / "u.csv"
    t = np.arange(10) * 0.5
    write_recording(path, Recording({"t_s": t, "u_v": t + 1, "l_mm": 0 * t}))
    s = parse_input_spec(f"csv:{path}")
    assert s(0.0) == 1.0 and s(0.6) == 1.5 and s(4.9) == 5.5
    with pytest.raises(ValueError, match=r"u\.csv holds 10 commands every 0\.5 s, from 0 to 4\.5 s .*none at t = 5 s"):
        s(5.0)


def _replayed(path, ts_s, n):
    """The commands a run of ``n`` samples every ``ts_s`` takes from ``csv:path``."""
    s = parse_input_spec(f"csv:{path}", run_duration_s=(n - 1) * ts_s, run_ts_s=ts_s)
    return np.array([s(k * ts_s) for k in range(n)])


def _random_commands(n, seed=0):
    # written as the recording writes them (6 decimals), so that a replay gives them back exactly
    return np.round(np.repeat(np.random.default_rng(seed).uniform(2.0, 8.0, n // 5 + 1), 5)[:n], 6)


def test_csv_replay_counts_time_from_the_first_sample(tmp_path):
    """Times that start at 1000 s (a mid-run time; Unix time) replay the same commands as from 0 s:
    they replayed the first command alone, throughout the run."""
    u = _random_commands(601)
    for start in (0.0, 1000.0, 1.7e9):
        path = tmp_path / f"from_{start:g}.csv"
        write_recording(path, Recording({"t_s": start + np.arange(601) * 0.1, "u_v": u, "l_mm": 0 * u}))
        assert np.array_equal(_replayed(path, 0.1, 601), u), start


def test_csv_replay_takes_jittered_times_as_on_the_grid(tmp_path):
    """A logger's +-3 ms jitter about a 0.1-s grid: sample k is the grid's k-th, as the diagnosis
    takes it (a sample stamped early was replayed a period late)."""
    u = _random_commands(601, seed=1)
    t = np.arange(601) * 0.1 + np.random.default_rng(2).uniform(-0.003, 0.003, 601)
    write_recording(tmp_path / "jit.csv", Recording({"t_s": t, "u_v": u, "l_mm": 0 * u}))
    assert np.array_equal(_replayed(tmp_path / "jit.csv", 0.1, 601), u)
    # and a run of part of it replays its start
    assert np.array_equal(_replayed(tmp_path / "jit.csv", 0.1, 301), u[:301])


@pytest.mark.parametrize("duration, ts, match", [
    (220.0, 0.1, r"the run's duration 220 s \(2201 samples\) is longer than .*r\.csv's 60 s \(601 samples every "
                 r"0\.1 s\): there is no command after its end; run for at most 60 s"),
    (60.0, 0.05, r"r\.csv is sampled every 0\.1 s, the run every 0\.05 s: a replay goes sample by sample; run it at "
                 r"0\.1 s, or resample"),
    (60.0, 0.2, r"r\.csv is sampled every 0\.1 s, the run every 0\.2 s"),
])
def test_csv_replay_refuses_a_run_it_has_no_commands_for(tmp_path, duration, ts, match):
    """A longer run held the last command, another period resampled the recording: both silently."""
    t = 1000.0 + np.arange(601) * 0.1
    write_recording(tmp_path / "r.csv", Recording({"t_s": t, "u_v": 0 * t + 5, "l_mm": 0 * t}))
    with pytest.raises(ValueError, match=match):
        parse_input_spec(f"csv:{tmp_path / 'r.csv'}", run_duration_s=duration, run_ts_s=ts)


@pytest.mark.parametrize("spec, match", [
    ("", "non-empty"), ("square:amp=1", "unknown kind 'square'"), ("sine:ampl=3", "unknown key 'ampl'"),
    ("sine:amp=three", "amp='three' is not a number"), ("sine:amp=inf", "not finite"),
    ("sine:freq=-1", "freq must be >= 0"), ("steps:period=2", "levels"), ("random:lo=8,hi=2", "lo"),
    ("sine:amp", "expected key=value"), ("csv:", "needs a path"),
    ("sine:freq=0.1,freq=0.2", "'freq' is given twice"),
])
def test_bad_specs_name_the_problem(spec, match):
    with pytest.raises(ValueError, match=match):
        parse_input_spec(spec)


def test_a_chirp_without_its_duration_sweeps_over_the_run():
    """``record --input chirp:f0=0.01,f1=0.5 --duration 60`` swept over the default 240 s and never
    reached f1; given the run's length it is the chirp with ``duration=`` that length, and a duration
    in the spec still wins."""
    t = np.arange(0.0, 60.0, 0.1)
    over_run = parse_input_spec("chirp:f0=0.01,f1=0.5", run_duration_s=60.0)
    explicit = parse_input_spec("chirp:f0=0.01,f1=0.5,duration=60")
    assert [over_run(x) for x in t] == [explicit(x) for x in t]
    default = parse_input_spec("chirp:f0=0.01,f1=0.5")
    assert [default(x) for x in t] == [parse_input_spec("chirp:f0=0.01,f1=0.5,duration=240")(x) for x in t]
    given = parse_input_spec("chirp:f0=0.01,f1=0.5,duration=30", run_duration_s=60.0)
    assert [given(x) for x in t] == [parse_input_spec("chirp:f0=0.01,f1=0.5,duration=30")(x) for x in t]


def test_record_sweeps_a_chirp_over_its_duration(tmp_path):
    from tapmuscle.cli.main import main
    from tapmuscle.io.recording import read_recording

    out = tmp_path / "c.csv"
    assert main(["record", "--input", "chirp:f0=0.01,f1=0.5", "--duration", "60", "--out", str(out), "--quiet"]) == 0
    u = read_recording(out).u_v
    expected = parse_input_spec("chirp:f0=0.01,f1=0.5,duration=60")
    assert np.allclose(u, [expected(k * 0.1) for k in range(len(u))], atol=1e-6)


def test_a_replay_is_made_of_commands_on_a_period_and_has_none_before_its_first_sample():
    from tapmuscle.io.signals import Replay

    replay = Replay([1.0, 2.0, 3.0], 0.1, "rec.csv")
    assert [replay(t) for t in (0.0, 0.1, 0.25)] == [1.0, 2.0, 3.0] and replay.duration_s == pytest.approx(0.2)
    with pytest.raises(ValueError, match=r"rec.csv holds 3 commands every 0.1 s, from 0 to 0.2 s .*none at t = -0.1 s"):
        replay(-0.1)
    with pytest.raises(ValueError, match=r"x.csv: the replay's period must be a finite number of seconds > 0, got 0.0"):
        Replay([1.0], 0.0, "x.csv")
    with pytest.raises(ValueError, match=r"x.csv: a replay needs one command per sample, got shape \(0,\)"):
        Replay([], 0.1, "x.csv")
