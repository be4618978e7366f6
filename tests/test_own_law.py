"""A law of one's own in the project's closed loop (tapmuscle/own_law.py, run_closed_loop, simulate_closed_loop)."""

from __future__ import annotations

import itertools
import math
import re
import warnings

import numpy as np
import pytest

import tapmuscle as tm
from tapmuscle.own_law import LAW_PREVIEW_SAMPLES, ValveWatch, law_command


class PI:
    """A PI law with conditional integration at the valve's 0..10 V (Kp [V/mm], Ki [V/(mm s)])."""

    ts_s = 0.1

    def __init__(self, kp: float = 0.5, ki: float = 2.0) -> None:
        self.kp, self.ki = kp, ki
        self.integral = 0.0
        self.resets: list[float] = []
        self.previews: list[np.ndarray] = []

    def reset(self, l_mm: float) -> None:
        self.integral = 0.0
        self.resets.append(l_mm)

    def step(self, l_mm: float, preview_mm: np.ndarray) -> float:
        self.previews.append(preview_mm)
        e = float(preview_mm[0]) - l_mm
        v = self.kp * e + self.integral
        u = min(max(v, 0.0), 10.0)
        if u == v:  # no integration into a valve limit
            self.integral += self.ki * self.ts_s * e
        return u


def _delayed(delay_s: float) -> tm.PlantParams:
    return tm.PlantParams().with_values(**{"delay.delay_s": delay_s})


def _run_quietly(*args, **kwargs) -> tuple[dict, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = tm.simulate_closed_loop(*args, **kwargs)
    return run, [str(w.message) for w in caught]


def test_a_law_of_ones_own_runs_as_a_hand_written_loop_bit_for_bit():
    # the timing contract of run_closed_loop: u(k) from l(k) and r(k..k+n), held until t_k+1
    ref = tm.SineReference(frequency_hz=0.1)
    law = PI()
    run = tm.run_closed_loop(tm.Plant(seed=3), law, ref, duration_s=20.0, load_n=lambda t: 44.0 + (t > 10.0) * 24.0)
    plant, mine = tm.Plant(seed=3), PI()
    meas, rows = plant.measurement, []
    for k in range(201):
        plant.update(load_n=44.0 + (k * 0.1 > 10.0) * 24.0)
        u = mine.step(meas.l_mm, ref.preview(k, LAW_PREVIEW_SAMPLES))
        rows.append((k * 0.1, ref.at(k), meas.l_mm, u, meas.p_mpa, plant.load_n, plant.l_mm))
        if k < 200:
            meas = plant.step(u, 0.1)
    expected = np.array(rows)
    got = np.column_stack([run[c] for c in ("t_s", "r_mm", "l_mm", "u_v", "p_mpa", "load_n", "l_true_mm")])
    np.testing.assert_array_equal(got, expected)
    assert sorted(run) == sorted(["t_s", "r_mm", "l_mm", "l_true_mm", "u_v", "p_mpa", "load_n"])
    assert law.resets == [run["l_mm"][0]] and len(law.previews[0]) == LAW_PREVIEW_SAMPLES + 1


def test_simulate_closed_loop_scores_a_law_beside_the_methods():
    # measured: 0.41 mm (Eq. (21), seed 0, the paper's sine at 44 N), between MPC-UCP and MPC-servo;
    # 1 mm leaves room for another CPU's rounding, a P law alone (ki = 0) tracks far worse
    run, said = _run_quietly(PI(), None)
    assert tm.eq21_error_mm(run) < 1.0 and said == []
    p_only, _ = _run_quietly(PI(ki=0.0), None)
    assert tm.eq21_error_mm(p_only) > 3.0 * tm.eq21_error_mm(run)
    again, _ = _run_quietly(PI(), None)  # a new run resets nothing the law does not reset itself: a new law
    np.testing.assert_array_equal(again["l_mm"], run["l_mm"])


def test_the_same_law_object_is_reset_between_runs():
    law = PI()
    first, _ = _run_quietly(law, None, duration_s=20.0)
    second, _ = _run_quietly(law, None, duration_s=20.0)
    np.testing.assert_array_equal(first["u_v"], second["u_v"])
    assert len(law.resets) == 2


def test_a_reset_without_argument_is_called_without_one():
    class NoArgReset(PI):
        def reset(self) -> None:  # type: ignore[override]
            self.integral = 0.0
            self.resets.append(math.nan)

    law = NoArgReset()
    _run_quietly(law, None, duration_s=2.0)
    assert len(law.resets) == 1


def test_a_law_limit_cycling_under_a_delay_is_told_and_one_without_is_not():
    # measured: 6.2 mm and the valve swung limit to limit from t = 12.7 s under 0.1 s (one sample at
    # Ts = 0.1 s); 0.41 mm without a word on the rig without delay
    run, said = _run_quietly(PI(), None, params=_delayed(0.1))
    assert tm.eq21_error_mm(run) > 3.0
    assert len(said) == 1 and "a limit cycle" in said[0] and "transport delay" in said[0]
    t_said = float(said[0].split("t = ")[1].split(" s")[0])
    assert 10.0 <= t_said <= 20.0  # not in the run's first 10 s, soon after
    _, quiet = _run_quietly(PI(), None, params=_delayed(0.1), watch=False)
    assert quiet == []


def test_a_law_of_the_wrong_sign_is_told():
    run, said = _run_quietly(PI(kp=-0.5, ki=0.0), None, duration_s=30.0)
    assert any("wrong sign" in m for m in said), said
    assert np.mean(run["u_v"] == 0.0) > 0.5


def test_a_reference_out_of_reach_is_told_as_for_the_paper_controllers():
    _, said = _run_quietly(PI(), lambda t: 300.0, duration_s=20.0)
    assert any("out of the rig's reach" in m and "10 V" in m for m in said), said


def test_loop_delay_samples_applies_the_laws_command_a_sample_late():
    law_now, law_late = PI(), PI()
    late, _ = _run_quietly(law_late, None, duration_s=5.0, loop_delay_samples=1)
    assert late["u_v"][0] == 0.0
    # the command recorded at k is what the law said at k - 1, computed from the readings it had
    outputs = [law_now.step(l, p) for l, p in zip(late["l_mm"], law_late.previews)]
    np.testing.assert_array_equal(late["u_v"][1:], outputs[:-1])


@pytest.mark.parametrize("bad, error, words", [
    (math.nan, ValueError, "u = nan V at sample k = 7 (t = 0.7 s, l = "),
    (math.inf, ValueError, "must be finite"),
    ("5", TypeError, "returned '5' at sample k = 7"),
    (None, TypeError, "returned None"),
    (np.array([1.0, 2.0]), TypeError, "expected the valve command"),
])
def test_a_command_that_is_no_number_stops_the_run_naming_its_sample(bad, error, words):
    class Breaks(PI):
        def step(self, l_mm, preview_mm):
            u = super().step(l_mm, preview_mm)
            return bad if len(self.previews) == 8 else u

    with pytest.raises(error, match=re.escape(words)):
        tm.simulate_closed_loop(Breaks(), None, duration_s=2.0)


def test_the_command_may_come_as_a_numpy_number_or_a_step_object():
    class Step:
        u_v = np.float32(2.5)

    assert law_command(np.float64(1.5), 0, 0.0) == 1.5 and law_command(np.array([3.0]), 0, 0.0) == 3.0
    assert law_command(Step(), 0, 0.0) == 2.5
    with pytest.raises(TypeError):
        law_command(True, 0, 0.0)


def test_the_period_comes_from_the_law_or_the_call_and_must_agree():
    class NoPeriod:
        def step(self, l_mm, preview_mm):
            return 2.0

    with pytest.raises(ValueError, match="has no ts_s attribute: give the loop's sampling period"):
        tm.run_closed_loop(tm.Plant(), NoPeriod(), None, duration_s=1.0)
    run = tm.run_closed_loop(tm.Plant(), NoPeriod(), None, duration_s=1.0, ts_s=0.05)
    assert len(run["t_s"]) == 21 and run["t_s"][-1] == pytest.approx(1.0)
    with pytest.raises(ValueError, match=r"ts_s = 0.05 s disagrees with the law's own PI.ts_s = 0.1 s"):
        tm.run_closed_loop(tm.Plant(), PI(), None, duration_s=1.0, ts_s=0.05)
    with pytest.raises(ValueError, match=r"ts_s = 0.05 s disagrees"):
        tm.simulate_closed_loop(PI(), None, duration_s=1.0, ts_s=0.05)
    for bad in (-0.1, 100.0, math.nan):  # 100 s would give a run of one sample without a word
        with pytest.raises(ValueError, match=r"must be a finite number within 0.001 .. 10 s"):
            tm.run_closed_loop(tm.Plant(), NoPeriod(), None, duration_s=1.0, ts_s=bad)


def test_the_preview_length_is_the_laws_or_the_calls():
    law = PI()
    tm.run_closed_loop(tm.Plant(), law, None, duration_s=1.0, preview_samples=0)
    assert {len(p) for p in law.previews} == {1}
    law = PI()
    law.preview_samples = 12
    tm.run_closed_loop(tm.Plant(), law, None, duration_s=1.0)
    assert {len(p) for p in law.previews} == {13}
    with pytest.raises(ValueError, match=r"preview_samples must be an integer in 0\.\.10000 .*got 1\.5"):
        tm.run_closed_loop(tm.Plant(), PI(), None, duration_s=1.0, preview_samples=1.5)
    # a typo's billion samples, built anew every sample, would fill the memory instead
    law = PI()
    law.preview_samples = 10**9
    with pytest.raises(ValueError, match=r"must be an integer in 0\.\.10000 .*got 1000000000"):
        tm.simulate_closed_loop(law, None, duration_s=1.0)
    law = PI()
    tm.run_closed_loop(tm.Plant(), law, None, duration_s=0.2, preview_samples=10_000)
    assert {len(p) for p in law.previews} == {10_001}
    law = PI()
    tm.simulate_closed_loop(law, None, duration_s=1.0, preview_samples=2)
    assert {len(p) for p in law.previews} == {3}
    with pytest.raises(ValueError, match="preview_samples = 2 is for a law of your own"):
        tm.simulate_closed_loop("ampc_servo", None, duration_s=1.0, preview_samples=2)


def test_the_paper_controllers_refuse_a_preview_or_another_period():
    ctrl = tm.DisplacementController(tm.ControllerSettings(), tm.THETA0_44N)
    with pytest.raises(ValueError, match="preview_samples = 3 is for a law of your own"):
        tm.run_closed_loop(tm.Plant(), ctrl, None, duration_s=1.0, preview_samples=3)
    with pytest.raises(ValueError, match="ts_s = 0.05 s disagrees with the controller's settings.ts_s = 0.1 s"):
        tm.run_closed_loop(tm.Plant(), ctrl, None, duration_s=1.0, ts_s=0.05)
    same = tm.run_closed_loop(tm.Plant(seed=1), ctrl, None, duration_s=3.0, ts_s=0.1)
    without = tm.run_closed_loop(tm.Plant(seed=1), ctrl, None, duration_s=3.0)
    np.testing.assert_array_equal(same["l_mm"], without["l_mm"])


def test_a_law_takes_no_theta0_or_settings_and_an_object_without_step_is_refused():
    with pytest.raises(ValueError, match="takes neither"):
        tm.simulate_closed_loop(PI(), None, theta0=tm.THETA0_44N)
    with pytest.raises(TypeError, match="or a law of your own with a step"):  # as run_closed_loop's
        tm.simulate_closed_loop(object(), None)
    with pytest.raises(TypeError, match="or a law of your own: an object with a step"):
        tm.run_closed_loop(tm.Plant(), object(), None, duration_s=1.0)
    with pytest.raises(TypeError, match=re.escape("got the class PI itself: give the law, an instance (PI(...))")):
        tm.simulate_closed_loop(PI, None)
    assert isinstance(PI(), tm.ControlLaw) and not isinstance(object(), tm.ControlLaw)


def test_a_function_is_a_law_on_the_period_given():
    gains = PI()
    run, said = _run_quietly(lambda l_mm, preview_mm: gains.step(l_mm, preview_mm), None, ts_s=0.1)
    law, _ = _run_quietly(PI(), None)
    np.testing.assert_array_equal(run["u_v"], law["u_v"])
    with pytest.raises(ValueError, match="the law <lambda> has no ts_s attribute"):
        tm.run_closed_loop(tm.Plant(), lambda l_mm, preview_mm: 2.0, None, duration_s=1.0)


def test_the_valve_watch_counts_no_swing_in_the_first_window_nor_after_a_reference_step():
    watch = ValveWatch(0.1, 0.0, 10.0)
    # a bang-bang command, limit to limit every sample, over the first 10 s: nothing
    said = [m for k in range(100) for m in watch.observe(k, k * 0.1, 30.0, 30.0, 10.0 * (k % 2), 10.0 * (1 - k % 2))]
    assert len(said) == 1 and "slams the valve end to end" in said[0]  # the jumps are told, not a limit cycle
    # a reference step at 10 s restarts the count for its settling time (3 s), then it is told
    said = []
    for k in range(100, 200):
        r = 30.0 if k < 100 else 60.0
        said += watch.observe(k, k * 0.1, 30.0, r if k > 100 else 30.0, 10.0 * (k % 2), 10.0 * (1 - k % 2))
    swings = [m for m in said if "limit cycle" in m]
    assert len(swings) == 1
    assert float(swings[0].split("t = ")[1].split(" s")[0]) >= 13.0


def test_a_law_switching_between_the_limits_is_not_pinned():
    # a bang-bang law on a reachable reference: the valve never sat at one limit for long (measured: at
    # most 0.2 s), so neither limit is "out of the rig's reach"
    run, said = _run_quietly(lambda l_mm, p: 10.0 if p[0] > l_mm else 0.0, lambda t: 40.0, duration_s=30.0)
    assert not any("out of the rig's reach" in m for m in said), said
    assert abs(np.mean(run["l_mm"][100:]) - 40.0) < 2.0


def test_the_watch_judges_the_command_the_valve_takes():
    # 15 and 45 V in turn hold the valve at 10 V: nothing slams (and the reference at 300 mm is out of
    # reach, told once)
    commands = itertools.cycle((15.0, 45.0))
    run, said = _run_quietly(lambda l_mm, p: next(commands), lambda t: 300.0, duration_s=20.0, ts_s=0.1)
    assert set(run["u_v"]) == {15.0, 45.0}  # recorded as the law gave them
    assert not any("slams the valve" in m for m in said), said
    assert sum("out of the rig's reach" in m for m in said) == 1


def test_a_functions_own_period_preview_and_reset_are_the_laws():
    seen: list[int] = []

    def law(l_mm, preview_mm):
        seen.append(len(preview_mm))
        return 3.0

    law.ts_s, law.preview_samples = 0.05, 10
    law.reset = lambda: seen.clear()
    seen.append(-1)
    run = tm.run_closed_loop(tm.Plant(), law, None, duration_s=1.0)
    assert len(run["t_s"]) == 21 and set(seen) == {11}
    assert len(tm.simulate_closed_loop(law, None, duration_s=1.0)["t_s"]) == 21  # its period, not 0.1 s


def test_simulate_closed_loop_takes_the_laws_period_and_single_precision_agrees():
    class Fast(PI):
        ts_s = 0.05

    assert len(tm.simulate_closed_loop(Fast(), None, duration_s=2.0)["t_s"]) == 41
    single = PI()
    single.ts_s = np.float32(0.1)
    assert len(tm.simulate_closed_loop(single, None, duration_s=2.0, ts_s=0.1)["t_s"]) == 21
    settings = tm.ControllerSettings(method="ampc_servo", ts_s=0.05, box_lower={}, box_upper={})
    run = tm.simulate_closed_loop("ampc_servo", None, duration_s=1.0, settings=settings, theta0=tm.THETA0_44N,
                                  watch=False)
    assert len(run["t_s"]) == 21  # the settings' period when none is given


def test_a_load_function_that_returns_no_load_is_named_with_its_time():
    with pytest.raises(TypeError, match=r"load_n\(t\) returned None at t = 2 s"):
        tm.simulate_closed_loop(PI(), None, duration_s=5.0, load_n=lambda t: 44.0 if t < 2.0 else None)
    with pytest.raises(ValueError, match="load_n") as caught:
        tm.simulate_closed_loop(PI(), None, duration_s=5.0, load_n=lambda t: 44.0 if t < 3.0 else math.nan)
    assert "load_n(t) at t = 3 s" in caught.value.__notes__


def test_an_error_in_the_law_names_its_sample_and_the_watch_still_speaks():
    class Breaks(PI):
        def step(self, l_mm, preview_mm):
            if len(self.previews) == 300:
                raise IndexError("my bug")
            return super().step(l_mm, preview_mm)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(IndexError, match="my bug") as err:
            tm.simulate_closed_loop(Breaks(kp=-0.5, ki=0.0), None, duration_s=45.0)
    assert err.value.__notes__[0].startswith("in the law's step at sample k = 300 (t = 30 s, l = ")
    assert any("wrong sign" in str(w.message) for w in caught)  # told before 30 s, not lost with the run


def test_a_reset_with_keyword_options_only_is_called_without_the_reading():
    class Hard(PI):
        def reset(self, *, hard: bool = False) -> None:  # type: ignore[override]
            self.integral = 0.0
            self.resets.append(math.nan)

    law = Hard()
    _run_quietly(law, None, duration_s=1.0)
    assert len(law.resets) == 1


def test_a_reset_that_fails_or_is_no_method_and_a_preview_too_short_are_named():
    """A reset raising a TypeError (two arguments) must name reset; a reset that is no method must not be
    skipped without a word; an IndexError into the preview must say how long the preview is."""
    class TwoArgs(PI):
        def reset(self, a, b) -> None:  # type: ignore[override]
            pass

    with pytest.raises(TypeError) as err:
        tm.simulate_closed_loop(TwoArgs(), None, duration_s=1.0)
    assert err.value.__notes__ == ["in the law's reset before the run (given the reading 0 mm)"]
    law = PI()
    law.reset = 5
    with pytest.raises(TypeError, match="the law's reset is 5, not a method: define reset"):
        tm.simulate_closed_loop(law, None, duration_s=1.0)

    def far_ahead(l_mm, preview_mm):
        return 5.0 + 0.01 * (preview_mm[3] - l_mm)

    with pytest.raises(IndexError) as err:
        tm.simulate_closed_loop(far_ahead, None, duration_s=1.0, preview_samples=2)
    assert err.value.__notes__[0].endswith("preview_mm of 3 samples, r(k..k+2): preview_samples = 2)")


@pytest.mark.parametrize("args", [(0.0, 0.0, 10.0), (math.nan, 0.0, 10.0), (0.1, 10.0, 0.0), (0.1, 0.0, math.inf)])
def test_the_valve_watch_refuses_a_period_or_range_that_is_none(args):
    with pytest.raises(ValueError, match="ts_s must be|the valve's range"):
        ValveWatch(*args)


def test_a_load_function_may_return_a_0d_array():
    # np.where(t > 1, 68.0, 44.0) gives array(44.), a load as good as a float
    run = tm.simulate_closed_loop(PI(), None, duration_s=2.0, load_n=lambda t: np.where(t > 1.0, 68.0, 44.0))
    assert run["load_n"][0] == 44.0 and run["load_n"][-1] == 68.0


def test_the_error_names_the_function_not_its_wrapper():
    def my_law(l_mm, preview_mm):
        return 3.0

    with pytest.raises(ValueError, match="the law my_law of your own takes neither"):
        tm.simulate_closed_loop(my_law, None, theta0=tm.THETA0_44N)
    with pytest.raises(TypeError, match=r"^got the class PI itself"):
        tm.run_closed_loop(tm.Plant(), PI, None, duration_s=1.0)


def test_a_reference_out_of_reach_at_every_peak_is_told_for_a_law_too():
    # the sag rig of the paper controllers' test: the valve at 10 V at each peak, the reading flat short
    rig = tm.PlantParams().with_values(**{
        "supply.supply_pressure_mpa": 0.209981, "muscle.rubber_stiffness_n_per_mm": 1.342857,
        "load_mismatch.extra_n": 11.01, "supply_variation.sag_mpa": 0.079, "supply_variation.start_s": 38.0,
        "supply_variation.end_s": 61.3, "supply_variation.ramp_s": 3.69})
    _, said = _run_quietly(PI(), None, duration_s=90.0, params=rig, load_n=68.0)
    assert sum("out of the rig's reach at times" in m for m in said) == 1, said
    _, quiet = _run_quietly(PI(), None, duration_s=90.0, load_n=68.0)
    assert quiet == []
