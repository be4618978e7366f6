"""Scores of a closed-loop run (tapmuscle.closed_loop)."""

from __future__ import annotations

import numpy as np
import pytest

from fmu_controller.displacement_control import ControllerSettings, DisplacementController
from fmu_controller.preliminary_model import THETA0_44N
from fmu_plant import Plant, PlantParams
from tapmuscle.closed_loop import EQ21_WINDOW, command_tv_excess, eq21_error_mm, run_closed_loop


def _sine_command(f: float, n: int = 451) -> np.ndarray:
    t = 0.1 * np.arange(n)
    return 5.0 + 3.0 * np.sin(2 * np.pi * f * t)


@pytest.mark.parametrize("f", [0.1, 0.2])
def test_a_smooth_command_travels_twice_its_range_per_cycle(f):
    # a sampled sine over whole cycles: its samples miss the exact peaks by at most 1 - cos(pi f Ts)
    assert abs(command_tv_excess(_sine_command(f), f)) <= 1.0 - np.cos(np.pi * f * 0.1) + 1e-12


def test_a_period_two_ripple_adds_its_travel():
    """A ripple +-a at the Nyquist frequency larger than the sine's steps (2a > its 0.19 V largest
    step) makes every step 2a long, give or take the sine's: 300 steps of 2a against a smooth travel
    of 2 (6 V + 2a) per cycle over 3 cycles."""
    f, a = 0.1, 0.5
    u = _sine_command(f) + a * (-1.0) ** np.arange(451)
    expected = 300 * 2 * a / (2 * (6.0 + 2 * a) * 3) - 1.0
    assert command_tv_excess(u, f) == pytest.approx(expected, abs=0.05)


def test_too_short_a_run_is_refused_naming_the_window():
    with pytest.raises(ValueError, match=f"k = {EQ21_WINDOW[1]}"):
        command_tv_excess(np.zeros(300), 0.1)
    with pytest.raises(ValueError, match="Eq. \\(21\\)"):
        eq21_error_mm(np.zeros(300), np.zeros(300))
    # a 40.0-s run: the window it has is offered, the one a scenario's default is cut to
    with pytest.raises(ValueError, match=r"the run has 401; .*window=\(101, 400\)"):
        eq21_error_mm(np.zeros(401), np.zeros(401))
    assert eq21_error_mm(np.zeros(401), np.ones(401), (101, 400)) == 1.0


def test_eq21_refuses_shapes_and_windows_that_gave_a_wrong_number():
    """A column-vector reference against a row of displacements broadcast to a matrix (24.3 mm for a
    0.083-mm run, silently); a reversed window gave NaN."""
    r = 35.0 + 30.0 * np.sin(2 * np.pi * 0.1 * 0.1 * np.arange(451))
    l = r + 0.1
    assert eq21_error_mm(r, l) == pytest.approx(0.1, abs=1e-12)  # |r - l| is 0.1 to the rounding of r + 0.1 (~1e-14)
    assert eq21_error_mm(list(r), tuple(l)) == eq21_error_mm(r, l)
    for bad_r, bad_l, message in ((r[:, None], l, r"shapes \(451, 1\) and \(451,\)"), (r, l[:400], "same length")):
        with pytest.raises(ValueError, match=message):
            eq21_error_mm(bad_r, bad_l)
    with pytest.raises(ValueError, match=r"0 <= k0 <= k1, got \(300, 200\)"):
        eq21_error_mm(r, l, window=(300, 200))
    with pytest.raises(ValueError, match=r"needs samples k = 0..401 \(402 samples\), the run has 401"):
        eq21_error_mm(r[:401], l[:401])
    # the period given where the window goes is named as such
    with pytest.raises(ValueError, match=r"window must be the samples \(k0, k1\), got the number 0.1; .* give it by "
                                         r"name: ts_s=0.1"):
        eq21_error_mm(r, l, 0.1)
    assert eq21_error_mm(r, l, ts_s=0.1) == eq21_error_mm(r, l)


def test_a_loop_whose_period_is_longer_than_the_run_is_refused():
    """ControllerSettings(ts_s=100) (ms meant) ran a 45-s loop as one sample, without a word."""
    ctrl = DisplacementController(ControllerSettings(ts_s=100.0), THETA0_44N)
    with pytest.raises(ValueError, match=r"sampling period 100.0 s is longer than the run \(duration_s = 45.0 s\): a "
                                         r"period in milliseconds\?"):
        run_closed_loop(Plant(PlantParams()), ctrl, None, duration_s=45.0)


def test_eq21_refuses_a_period_in_milliseconds_a_fractional_window_and_a_gap():
    """Each gave a number without a word: a period of 100 (ms meant) put the whole window on sample 0
    and returned |r(0) - l(0)| (35 mm for a 0.18-mm run), also from a run whose t_s is in ms; a window
    (100.5, 200) was cut to sample 100; a NaN reading made the mean NaN."""
    r = 35.0 + 30.0 * np.sin(2 * np.pi * 0.1 * 0.1 * np.arange(451))
    l = r + 0.1
    run = {"t_s": 0.1 * np.arange(451), "r_mm": r, "l_mm": l}
    assert eq21_error_mm(run) == eq21_error_mm(r, l)
    with pytest.raises(ValueError, match=r"ts_s = 100 s is outside the 0.001..10 s .* a period in milliseconds\?"):
        eq21_error_mm(r, l, ts_s=100)
    with pytest.raises(ValueError, match=r"the run's sampling period \(from its t_s\) = 100.0 s is outside .* "
                                         r"milliseconds\? .*\(t_s in seconds from the start, or give ts_s\)"):
        eq21_error_mm(run | {"t_s": 1e3 * run["t_s"]})
    with pytest.raises(TypeError, match=r"window \(100.5, 200\): a sample number must be an integer, got float 100.5"):
        eq21_error_mm(r, l, window=(100.5, 200))
    assert eq21_error_mm(r, l, window=(np.int64(101), 401)) == eq21_error_mm(r, l)
    assert eq21_error_mm(r, l, window=(101.0, np.float64(401.0))) == eq21_error_mm(r, l)  # whole numbers as floats
    gap = l.copy()
    gap[150] = np.nan
    with pytest.raises(ValueError, match=r"l_mm\[150\] = nan is not finite: Eq. \(21\)'s mean over samples 101..401"):
        eq21_error_mm(r, gap)
    assert eq21_error_mm(r, gap, window=(151, 401)) == pytest.approx(0.1, abs=1e-12)  # outside the window: no matter


def _parts(ts_s: float = 0.1):
    from fmu_controller.displacement_control import ControllerSettings, DisplacementController
    from fmu_controller.preliminary_model import THETA0_44N
    from fmu_plant import Plant

    return Plant(seed=0), DisplacementController(ControllerSettings(method="mpc_servo", ts_s=ts_s), THETA0_44N)


def test_the_loop_takes_a_reference_in_any_form_the_api_does():
    """A function of time, samples and None run the same loop as the equivalent reference objects."""
    from fmu_controller.reference import ArrayReference, FunctionReference, SineReference
    from tapmuscle.closed_loop import run_closed_loop

    step = np.repeat([30.0, 45.0], 15)
    for given, same in ((None, SineReference()), (step, ArrayReference(step)),
                        (lambda t: 30.0 + 5.0 * (t > 1.0), FunctionReference(lambda t: 30.0 + 5.0 * (t > 1.0)))):
        a = run_closed_loop(*_parts(), given, duration_s=3.0)
        b = run_closed_loop(*_parts(), same, duration_s=3.0)
        assert np.array_equal(a["r_mm"], b["r_mm"]) and np.array_equal(a["u_v"], b["u_v"])


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(reference=None, duration_s=float("nan")), ValueError, r"duration_s must be a finite number > 0 \[s\], got nan"),
    (dict(reference=None, duration_s=-1.0), ValueError, r"duration_s must be a finite number > 0 \[s\], got -1.0"),
    (dict(reference="sine", duration_s=3.0), TypeError, r"reference must be a function r\(t\) \[mm\], .* got str 'sine'"),
    (dict(reference=np.ones((3, 2)), duration_s=3.0), ValueError, r"values_mm must be a non-empty 1-D array, got shape \(3, 2\)"),
    (dict(reference=lambda t: np.array([35.0]), duration_s=3.0), ValueError,
     r"r\(t = 0 s\) returned an array of shape \(1,\), not one number"),
    (dict(reference=lambda t: None, duration_s=3.0), ValueError, r"r\(t = 0 s\) = None is not a number"),
])
def test_bad_loop_input_is_named_before_the_loop_runs(kwargs, error, match):
    from tapmuscle.closed_loop import run_closed_loop

    with pytest.raises(error, match=match):
        run_closed_loop(*_parts(), **kwargs)


def test_a_reference_on_another_grid_than_the_controllers_is_refused():
    """The controller's model and horizons are for its own Ts: a reference sampled at another period
    would run the loop on the wrong grid without a word."""
    from fmu_controller.reference import SineReference
    from tapmuscle.closed_loop import run_closed_loop

    with pytest.raises(ValueError, match=r"reference's ts_s = 0.05 s differs from the loop's ts_s = 0.1 s"):
        run_closed_loop(*_parts(), SineReference(ts_s=0.05), duration_s=3.0)
    plant, controller = _parts()
    with pytest.raises(TypeError, match=r"plant must be a Plant .* got PlantParams"):
        run_closed_loop(plant.params, controller, None, duration_s=3.0)
    with pytest.raises(TypeError, match=r"controller must be a DisplacementController .* got ControllerSettings"):
        run_closed_loop(plant, controller.settings, None, duration_s=3.0)


def test_eq21_at_another_period_scores_the_same_seconds():
    """At 0.05 s the samples 101..401 are 5.05..20.05 s, start-up included: with ``ts_s`` the default
    window is Eq. (21)'s 10.1..40.1 s (samples 202..802), the same seconds as at 0.1 s; at 0.1 s it is
    the paper's 101..401. The chatter figure's window follows its ts_s the same way."""
    from tapmuscle.closed_loop import eq21_window

    assert eq21_window(0.1) == EQ21_WINDOW and eq21_window(0.05) == (202, 802) and eq21_window(0.2) == (50, 200)
    t = np.arange(1001) * 0.05
    err = np.where(t < 10.0, 30.0, 0.5)  # a 30-mm start-up, then 0.5 mm
    r, l = np.zeros_like(t), err
    assert eq21_error_mm(r, l, ts_s=0.05) == 0.5
    assert eq21_error_mm(r, l) > 10.0  # samples 101..401: the paper's numbering, whatever the period
    assert eq21_error_mm(r, l, ts_s=0.1) == eq21_error_mm(r, l)
    with pytest.raises(ValueError, match=r"needs samples k = 0..802 \(803 samples\), the run has 401"):
        eq21_error_mm(r[:401], l[:401], ts_s=0.05)
    with pytest.raises(ValueError, match="not both"):
        eq21_error_mm(r, l, (0, 10), ts_s=0.05)
    # a whole run places the window by its own period; a short run without ts_s is told to give one
    run = {"t_s": t, "r_mm": r, "l_mm": l}
    assert eq21_error_mm(run) == 0.5 and eq21_error_mm(run, window=(101, 401)) == eq21_error_mm(r, l)
    with pytest.raises(ValueError, match=r"the run has 301; a run at another period than 0.1 s: give ts_s"):
        eq21_error_mm(r[::2][:301], l[::2][:301])
    with pytest.raises(ValueError, match=r"alone, or the arrays r_mm and l_mm; the run has no t_s"):
        eq21_error_mm({"r_mm": r, "l_mm": l})
    with pytest.raises(ValueError, match=r"alone"):
        eq21_error_mm(run, l)
    with pytest.raises(ValueError, match=r"needs the displacement l_mm"):
        eq21_error_mm(r)
    with pytest.raises(ValueError, match="ts_s must be a positive finite sampling period"):
        eq21_window(0.0)
    u = 5.0 + 3.0 * np.sin(2 * np.pi * 0.1 * t)
    u[t < 10.0] += np.where(np.arange((t < 10.0).sum()) % 2, 1.0, -1.0)  # chatter in the start-up only
    assert abs(command_tv_excess(u, 0.1, ts_s=0.05)) < 0.01
    assert command_tv_excess(u, 0.1, ts_s=0.05, window=(101, 401)) > 1.0


def test_a_law_holding_the_valve_against_the_error_is_warned_of_after_the_run():
    """A fixed method on theta0 with a negative b1 holds the valve at 0 V for the whole run while l stays
    35 mm below r: the run warns as the FMU logs it, at the caller's line, naming theta0's b1; the same
    loop on THETA0_44N does not."""
    import warnings

    import tapmuscle as tm

    theta = list(tm.THETA0_44N)
    theta[2] = -0.8
    with pytest.warns(tm.ClosedLoopWarning, match=r"^t = 10 s: the command has sat at the valve's 0 V for 10 s while the "
                                            r"reading l = -?[\d.]+ mm stays [\d.]+ mm below the reference r = [\d.]+ mm, "
                                            r"where the other way would close the gap: theta0\.b1 = -0\.8 < 0 inverts "
                                            r"the law") as caught:
        run = tm.simulate_closed_loop("mpc_servo", None, theta0=theta, duration_s=45.0)
    assert run["u_v"].max() < 1e-9 and caught[0].filename == __file__  # the QP's bound, to rounding
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tm.simulate_closed_loop("mpc_servo", None, duration_s=45.0)


def test_a_glitch_in_the_readings_is_warned_of_after_the_run():
    """run_closed_loop says after the run how many readings the glitch guard held, and when the first was."""
    import pytest

    import tapmuscle as tm

    class GlitchingPlant(tm.Plant):
        """The rig whose encoder reads 60 mm high at every 50th sample from t = 10 s."""

        def step(self, u_v, dt_s):
            m = super().step(u_v, dt_s)
            k = round(m.t_s / dt_s)
            return m._replace(l_mm=m.l_mm + 60.0) if k >= 100 and k % 50 == 0 else m

    ctrl = tm.DisplacementController(tm.ControllerSettings(method="ampc_servo"), tm.THETA0_44N)
    with pytest.warns(RuntimeWarning, match=r"^5 readings \(the first at t = 10 s\) were further from the last one used .* 400 x 0\.1 mm"):
        tm.run_closed_loop(GlitchingPlant(seed=0), ctrl, tm.SineReference(), duration_s=30.0)


def test_stale_repeats_of_the_reading_are_warned_of_after_the_run():
    """A data acquisition that delivers its last sample again at the sine's fastest points (t = 30.0 s
    and 35.0 s, the muscle moving 1.9 mm a sample): run_closed_loop says how many readings were taken
    for stale samples, and when the first was."""
    import pytest

    import tapmuscle as tm

    class RepeatingPlant(tm.Plant):
        last = None

        def step(self, u_v, dt_s):
            m = super().step(u_v, dt_s)
            k = round(m.t_s / dt_s)
            fed = m._replace(l_mm=self.last) if k in (300, 350) else m
            self.last = fed.l_mm
            return fed

    ctrl = tm.DisplacementController(tm.ControllerSettings(method="ampc_servo"), tm.THETA0_44N)
    with pytest.warns(RuntimeWarning, match=r"^2 readings \(the first at t = 30 s\) repeated the last one to the bit .*"
                                            r"stale samples of the data acquisition") as said:
        tm.run_closed_loop(RepeatingPlant(seed=0), ctrl, tm.SineReference(), duration_s=40.0)
    assert not [w for w in said if "muscle's own" in str(w.message)]  # the reading after each back on the track


def test_readings_held_that_the_reading_after_found_the_muscles_own_are_said_so_after_the_run():
    """The supply falling by 0.2 MPa at once at t = 24 s and back at 40 s (a sag without ramps): the
    muscle leaves its model's track by 15 mm within a sample, the spike guard holds those readings, and
    the warning after the run says which the reading after found the muscle's own."""
    import pytest

    import tapmuscle as tm

    rig = tm.PlantParams().with_values(**{"supply_variation.sag_mpa": 0.2, "supply_variation.start_s": 24.0,
                                          "supply_variation.ramp_s": 0.0, "supply_variation.end_s": 40.0})
    ctrl = tm.DisplacementController(tm.ControllerSettings(method="ampc_servo"), tm.THETA0_44N)
    with pytest.warns(RuntimeWarning, match=r"^2 readings \(the first at t = 24\.1 s\) were further from the one-step "
                                            r"prediction .*; the reading after showed 2 of them \(t = 24\.1, 40\.1 s\) "
                                            r"the muscle's own"):
        tm.run_closed_loop(tm.Plant(rig, seed=0), ctrl, tm.SineReference(), duration_s=60.0)


def test_a_stuck_reading_is_warned_of_after_the_run():
    """run_closed_loop says after the run where the readings stopped changing while the valve went end
    to end (the encoder frozen from t = 20 s), with the reading and how long it had not changed."""
    import pytest

    import tapmuscle as tm

    class FrozenEncoderPlant(tm.Plant):
        """The rig whose encoder holds its reading from t = 20 s."""

        frozen = None

        def step(self, u_v, dt_s):
            m = super().step(u_v, dt_s)
            if m.t_s >= 20.0 - 1e-9:
                self.frozen = m.l_mm if self.frozen is None else self.frozen
                return m._replace(l_mm=self.frozen)
            return m

    plant = FrozenEncoderPlant(seed=0)
    ctrl = tm.DisplacementController(tm.ControllerSettings(method="ampc_servo"), tm.THETA0_44N)
    with pytest.warns(RuntimeWarning, match=r"^t = 2\d\.?\d* s: the reading l = [\d.]+ mm has not changed at all for "
                                            r"[\d.]+ s while the command sat at each of the valve's limits for 2 s or "
                                            r"more.*the sensor is stuck") as caught:
        run = tm.run_closed_loop(plant, ctrl, tm.SineReference(), duration_s=40.0)
    said = [w for w in caught if "has not changed at all" in str(w.message)]
    assert len(said) == 1 and f"l = {plant.frozen:g} mm" in str(said[0].message)
    assert np.all(run["l_mm"][200:] == plant.frozen)


def test_the_python_loop_tells_what_the_controller_fmu_logs():
    """A rig with a 0.2-s transport delay and a law that compensates none (input_delay_samples = 0):
    the loop swings limit to limit and the first 30 s show the delay. run_closed_loop warns of both,
    word for word as the controller FMU logs them on the same rig (the FMU's law is the direct loop's
    bit for bit), and the delay named is the rig's."""
    import pytest

    import tapmuscle as tm
    from fmu_controller.controller_slave import AMPCController
    from pythonfmu.enums import Fmi2Status

    rig = tm.PlantParams().with_values(**{"delay.delay_s": 0.2})
    settings = tm.ControllerSettings(method="ampc_servo", input_delay_samples=0)
    with pytest.warns(RuntimeWarning) as caught:
        tm.run_closed_loop(tm.Plant(rig, seed=0), tm.DisplacementController(settings, tm.THETA0_44N), None,
                           duration_s=40.0)
    said = [str(w.message) for w in caught if "limit cycle" in str(w.message) or "input delay of" in str(w.message)]
    slave = AMPCController(instance_name="delayed")
    slave._int_par["input_delay_samples"] = 0
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    plant = tm.Plant(rig, seed=0)
    for k in range(401):
        slave.l = plant.measurement.l_mm
        assert slave.do_step(k * 0.1, 0.1)
        plant.step(slave.u, 0.1)
    logged = [m.msg for m in slave.log_queue if m.status == Fmi2Status.warning
              and ("limit cycle" in m.msg or "input delay of" in m.msg)]
    assert said == logged and len(said) == 2
    assert "a limit cycle (input_delay_samples = 0)" in said[0]
    assert said[1].startswith("t = 30 s: the measurements show an input delay of 2 samples, not the 0 set")


def test_the_run_holds_the_muscles_displacement_beside_the_reading():
    """Under a sensor drift of 1 mm/min the loop tracks the reading (Eq. (21) on l_mm small) while the
    muscle itself drifts away from the reference: l_true_mm shows it, the drift's offset to 0.05 mm."""
    import tapmuscle as tm

    rig = tm.PlantParams().with_values(**{"sensor_drift.rate_mm_per_min": 1.0})
    run = tm.simulate_closed_loop("ampc_servo", None, duration_s=60.0, params=rig)
    late = slice(500, 601)
    assert tm.eq21_error_mm(run) < 0.3
    drift = run["l_mm"][late] - run["l_true_mm"][late]
    assert np.all(np.abs(drift - run["t_s"][late] / 60.0) < 0.05)
    clean = tm.simulate_closed_loop("ampc_servo", None, duration_s=10.0)
    assert np.max(np.abs(clean["l_mm"] - clean["l_true_mm"])) < 0.06  # noise 0.01 mm and the 0.01-mm steps
