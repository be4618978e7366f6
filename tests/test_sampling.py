"""The uniform grid of a time column: exact recordings as written, a logger's jitter accepted, a
dropped, doubled or drifting sample refused by name."""

import numpy as np
import pytest

from tapmuscle.io.recording import Recording, RecordingError
from tapmuscle.io.sampling import (JITTER_TOLERANCE, PERIOD_CHANGE_MIN_STEPS, SamplingError, period_change,
                                   uniform_sampling)

TS = 0.1
N = 2401


def _grid(start: float = 0.0) -> np.ndarray:
    return start + np.arange(N) * TS


def test_a_uniform_column_gives_its_median_step_and_no_jitter():
    t = np.round(_grid(), 10)  # as written with rounded decimals
    s = uniform_sampling(t)
    assert s.ts_s == float(np.median(np.diff(t))) and s.jitter_s == 0.0 and not s.jittered


@pytest.mark.parametrize("seed", range(20))
@pytest.mark.parametrize("start", [0.0, 12.3, 1.7e9])  # from zero, mid-run, Unix time
def test_jitter_within_a_quarter_period_is_the_grid_it_scatters_about(seed, start):
    rng = np.random.default_rng(seed)
    amp = rng.uniform(0.001, 0.9 * JITTER_TOLERANCE) * TS
    t = _grid(start) + rng.uniform(-amp, amp, N)
    s = uniform_sampling(t)
    # the least-squares slope of N stamps with the jitter's sd amp/sqrt(3): sd sqrt(12) amp/sqrt(3) / N^1.5
    # = 2 amp / N^1.5; five of them (the 1.2e-7 s rounding of a stamp near 1.7e9 s is far below amp)
    assert abs(s.ts_s - TS) < 10.0 * amp / N ** 1.5
    # measured about the fitted line, whose own error at the run's ends is about 4 amp / sqrt(N) (2 sd)
    assert s.jittered and 0.5 * amp < s.jitter_s <= amp * (1.0 + 8.0 / np.sqrt(N))


@pytest.mark.parametrize("ppm, nominal", [(0.0, True), (0.42, True), (-0.6, True), (3.0, False)])
def test_a_jittered_logs_period_is_its_nominal_one_within_a_ppm(ppm, nominal):
    """A 20-Hz logger's jittered stamps (+-2 ms) fit a slope of 0.0499999999 or 0.100000042 s, which a
    model identified on them carried as its Ts: the period is the logger's nominal 0.05 s where the slope
    lies within 1 ppm of it, and the slope itself beyond (a clock 3 ppm fast is the log's own)."""
    rng = np.random.default_rng(7)
    t = 1.7e9 + np.arange(4801) * 0.05 * (1.0 + ppm * 1e-6) + rng.uniform(-0.002, 0.002, 4801)
    s = uniform_sampling(t)
    assert s.jittered
    if nominal:
        assert s.ts_s == 0.05
    else:
        # the slope's own error is 2 x 2 ms / sqrt(3) / 4801^1.5 = 7e-9 s, its rounding up to 1 ppm
        assert s.ts_s != 0.05 and s.ts_s == pytest.approx(0.05 * (1.0 + 3e-6), rel=1.5e-6)

@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("where", [1, 7, 1200, N - 3])
def test_a_dropped_sample_is_named_wherever_it_lies_even_under_jitter(seed, where):
    rng = np.random.default_rng(seed)
    t = np.delete(_grid() + rng.uniform(-0.2, 0.2, N) * TS, where)
    with pytest.raises(SamplingError, match=rf"sample {where}: t = .* a dropped or doubled sample"):
        uniform_sampling(t)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("first, second, split", [(0.1, 0.05, 300), (0.05, 0.1, 900), (0.1, 0.2, 40), (0.01, 0.1, 1700)])
def test_a_period_that_changes_part_way_is_named_as_such_even_under_jitter(seed, first, second, split):
    """(Stamps jittered by up to a tenth of their period.) A logger set to another rate part way (or
    two recordings appended) is one change of period at one sample, not hundreds of dropped or
    doubled samples; no sample is missing, so filling gaps cannot mend it (period_change)."""
    rng = np.random.default_rng(seed)
    t = np.concatenate([np.arange(split) * first, split * first + np.arange(N - split) * second])
    t = t + rng.uniform(-0.1, 0.1, N) * np.where(np.arange(N) < split, first, second)
    # the sample after the first step at the second period (jitter may move the split by one step)
    k, got_first, got_second = period_change(t)
    # each period a median of jittered steps: within a few per cent for the 39 steps of the shortest side
    assert k in (split, split + 1, split + 2) and (got_first, got_second) == pytest.approx((first, second), rel=0.05)
    with pytest.raises(SamplingError, match=rf"sample {k}: the sampling period changes between t = [\d.]+ and [\d.]+ s, "
                                            r"from "
                                            r".* one recording has one period; split it there") as info:
        uniform_sampling(t)
    assert info.value.period_change and info.value.sample == k and info.value.steps == ()


@pytest.mark.parametrize("first, second, n_first, n_second", [(0.1, 0.05, 1000, 600), (0.1, 0.2, 300, 500),
                                                              (0.1, 0.13, 500, 500), (0.1, 0.077, 500, 500)])
def test_a_change_of_period_that_no_step_flags_as_dropped_is_named_too(first, second, n_first, n_second):
    """Steps within half the median of it (the faster rate the minority, or a change of a third or
    less) are no dropped samples, and the first sample off the grid is no drifting clock: the change
    is named."""
    t = np.round(np.concatenate([np.arange(n_first) * first, n_first * first + np.arange(n_second) * second]), 3)
    with pytest.raises(SamplingError, match=r"the sampling period changes between t = ") as info:
        uniform_sampling(t)
    assert info.value.period_change and info.value.sample in (n_first, n_first + 1)


def test_a_clock_that_restarts_between_two_appended_recordings_is_named_as_going_back():
    t = np.concatenate([np.arange(300) * 0.1, np.arange(600) * 0.05])
    assert period_change(t) is None
    with pytest.raises(SamplingError, match=r"sample 300: t = 0.0 s follows 29.9\d* s, a step of -29.9 s in a recording "
                                            r"sampled every 0.05 s: time goes back \(a clock that restarted") as info:
        uniform_sampling(t)
    assert not info.value.period_change


def test_dropped_samples_here_and_there_and_a_short_stretch_are_not_a_change_of_period():
    t = _grid()
    assert period_change(np.delete(t, [100, 900, 1500])) is None  # drops in the middle
    assert period_change(np.delete(t, np.arange(N - 2 * (PERIOD_CHANGE_MIN_STEPS - 1), N, 2))) is None  # 9 at the end
    ten = np.delete(t, np.arange(N - 2 * PERIOD_CHANGE_MIN_STEPS, N, 2))  # every other one of the last 20: 10 steps
    assert period_change(ten) == (len(ten) - PERIOD_CHANGE_MIN_STEPS, pytest.approx(TS), pytest.approx(2 * TS))
    with pytest.raises(SamplingError, match="a dropped or doubled sample") as info:
        uniform_sampling(np.delete(t, [100, 900, 1500]))
    assert not info.value.period_change


def test_a_doubled_sample_and_a_backward_step_are_named():
    t = _grid()
    with pytest.raises(SamplingError, match=r"sample 701: t = 70\.001 s follows 70\.0+\d* s, a step of 0\.001 s"):
        uniform_sampling(np.insert(t, 701, t[700] + 0.001))
    back = t.copy()
    back[300] = back[299] - 0.01
    with pytest.raises(SamplingError, match=r"sample 300: .* a dropped or doubled sample"):
        uniform_sampling(back)


def test_a_drifting_clock_is_refused_though_no_single_step_is():
    t = _grid()
    t[1000:] += np.minimum(np.arange(N - 1000) * 0.01, 2.0)  # 10 % slow for 20 s: every step within 10 %
    with pytest.raises(SamplingError, match=r"lies [+-][\d.]+ s off the uniform grid .* more than a quarter period"):
        uniform_sampling(t)


def test_too_few_or_no_increasing_times_are_refused():
    with pytest.raises(SamplingError, match="fewer than 2"):
        uniform_sampling(np.array([0.0]))
    with pytest.raises(SamplingError, match="median time step is 0.0 s"):
        uniform_sampling(np.zeros(5))


def test_a_recording_with_jittered_stamps_has_the_grid_period_and_a_header_must_agree():
    rng = np.random.default_rng(0)
    t = _grid() + rng.uniform(-0.005, 0.005, N)
    cols = {"t_s": t, "u_v": np.full(N, 5.0), "l_mm": np.zeros(N)}
    rec = Recording(dict(cols), {})
    assert abs(rec.ts_s - TS) < 1e-6 and 0.0045 < rec.sampling.jitter_s <= 0.0055
    assert Recording(dict(cols), {"ts_s": "0.1"}).ts_s == 0.1  # as written
    with pytest.raises(RecordingError, match="contradicts the t_s column"):
        _ = Recording(dict(cols), {"ts_s": "0.1002"}).ts_s


def test_a_long_gap_is_named_by_its_own_step_not_the_first_sample():
    """A 1-hour gap pulls a least-squares slope through the times to 2 s, which made every 0.1-s step
    look off and named sample 1: steps are measured against the median step."""
    t = np.arange(1801) * TS
    t[900:] += 3600.0
    with pytest.raises(SamplingError, match=r"sample 900: t = 3690\.0\d* s follows 89\.9\d* s, a step of 3600\.1 s in a "
                                            r"recording sampled every 0\.1 s: a gap of 3600\.1 s, about 36000 samples "
                                            r"missing") as info:
        uniform_sampling(t)
    assert (info.value.sample, info.value.steps, info.value.largest) == (900, (900,), 900)


def test_every_step_off_the_period_is_counted_and_the_largest_named():
    t = np.delete(_grid(), [400, 900, 901, 1500])
    with pytest.raises(SamplingError, match=r"sample 400: .*a step of 0\.2 s .*a dropped or doubled sample; 3 such steps "
                                            r"in all, the largest 0\.3 s at line 901;") as info:
        uniform_sampling(t, where=lambda k: f"line {k + 2}")
    assert info.value.steps == (400, 899, 1497) and info.value.largest == 899


@pytest.mark.parametrize("late, dropped", [(0.49, False), (0.5, False), (0.51, True)])
def test_a_step_half_a_period_off_is_the_boundary_of_a_dropped_sample(late, dropped):
    """One sample written ``late`` periods after its slot (times as a logger writes them, to 0.1 ms):
    up to half a period, written exactly, it is a late sample (the grid check's business, here a
    refusal of a time off its slot by more than the jitter allowed, not a dropped sample); beyond it,
    a dropped or doubled sample."""
    t = np.round(_grid(), 4)
    t[200] = round(t[200] + late * TS, 4)
    with pytest.raises(SamplingError) as err:
        uniform_sampling(t)
    assert ("dropped or doubled" in str(err.value)) == dropped, str(err.value)


@pytest.mark.parametrize("ts, error, nominal", [
    (0.1 * (1 + 8e-7), 0.0, 0.1),               # a clock 0.8 ppm fast: the logger's 0.1 s
    (0.1 * (1 + 3e-6), 0.0, 0.1 * (1 + 3e-6)),  # 3 ppm: its own
    (0.1 * (1 + 3e-6), 1e-7, 0.1),              # unless the estimate's own error covers it
    (0.1234561, 0.0, 0.123456),                 # six significant digits are a nominal period
    (0.12345671, 0.0, 0.12345671),              # seven are not: kept as estimated
])
def test_a_period_is_its_nominal_value_within_a_ppm_and_three_standard_errors(ts, error, nominal):
    from tapmuscle.io.sampling import nominal_period

    assert nominal_period(ts, error) == nominal


def test_a_stamp_more_than_a_quarter_period_off_the_grid_is_named_and_a_slow_drift_is_not_uniform():
    """0.027 s off a 0.1-s grid (a quarter is 0.025) is refused at that sample; a clock whose steps
    wander by 0.9 % (each within 1 %, none within the 0.1 % of exactly uniform) ends 0.34 s off the
    grid through all samples and is refused, not taken as uniform."""
    from tapmuscle.io.sampling import SamplingError, uniform_sampling

    t = np.arange(2401) * 0.1
    t[1200] += 0.027
    with pytest.raises(SamplingError) as late:
        uniform_sampling(t)
    assert late.value.sample == 1200
    k = np.arange(2400)
    drifting = np.concatenate([[0.0], np.cumsum(0.1 * (1 + 0.009 * np.sin(2 * np.pi * k / 2400)))])
    with pytest.raises(SamplingError, match="off the uniform grid"):
        uniform_sampling(drifting)
