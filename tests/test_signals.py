"""Input specs for `tapmuscle record`."""

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


def test_csv_replays_the_u_column(tmp_path):
    path = tmp_path / "u.csv"
    t = np.arange(10) * 0.5
    write_recording(path, Recording({"t_s": t, "u_v": t + 1, "l_mm": 0 * t}))
    s = parse_input_spec(f"csv:{path}")
    assert s(0.0) == 1.0 and s(0.6) == 1.5 and s(100.0) == 5.5


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
