"""The four controllers in closed loop: limits, constraint region, linearisation, state, errors."""

import copy
import json
import math
import pickle
import warnings

import numpy as np
import pytest

from fmu_controller.displacement_control import (AUTO_INPUT_DELAY_SAMPLES, B1_KEPT_FRACTION, DEFAULT_MAX_SPEED_MM_PER_S,
                                                 DEFAULT_PROBING_V, DEFAULT_STARTUP_S, HELD_READINGS_MAX,
                                                 HOLD_AFTER_SAMPLES, MAX_INPUT_DELAY_SAMPLES, METHODS, P0_TABLE5, P0_TABLE8,
                                                 DEFAULT_DELAY_MOVE_WEIGHT, STUCK_AT_LIMIT_S, ControllerSettings,
                                                 DisplacementController, held_reading_message,
                                                 real_move_message)
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.probing import probe_v
from fmu_controller.hysteresis_model import ASYMMETRIC, ModelState
from fmu_controller.reference import ArrayReference, SineReference
from fmu_controller.servo_settings import ServoMPCSettings
from fmu_controller.ucp_mpc import UCPSettings
from fmu_controller.rls import TABLE2_LOWER, TABLE2_UPPER
from fmu_plant import Plant, PlantParams
from tapmuscle.closed_loop import command_tv_excess, eq21_error_mm, run_closed_loop

from tapmuscle.paper.reproduce import preliminary_theta


@pytest.fixture(scope="module")
def theta0():
    """Section 4.2's fixed predictor, identified on the simulated rig."""
    return preliminary_theta(0, refine_hz=0.1)  # refined at the evaluation frequency: a well-fitted fixed model


def _same(a, b):
    """Deep equality of plain-data states that may hold numpy arrays."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float), equal_nan=True)
    if isinstance(a, (list, tuple)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b or (a != a and b != b)


@pytest.fixture(scope="module", params=METHODS)
def run(request, theta0):
    c = DisplacementController(ControllerSettings(method=request.param), theta0)
    return request.param, run_closed_loop(Plant(seed=0), c, SineReference(), duration_s=45.0)


def test_input_within_limits_and_everything_finite(run):
    method, cols = run
    assert cols["u_v"].min() >= 0.0 and cols["u_v"].max() <= 10.0, method
    for name, col in cols.items():
        assert np.all(np.isfinite(col)), (method, name)


def test_tracks_the_reference(run):
    method, cols = run
    bound = 0.5 if method.endswith("servo") else 2.0
    assert eq21_error_mm(cols["r_mm"], cols["l_mm"]) < bound


def test_adaptive_estimate_stays_in_the_table2_box(run):
    method, cols = run
    for name in ("a1", "a2", "b1"):
        values = cols[f"theta_{name}"]
        if method.startswith("ampc"):
            assert values.min() >= TABLE2_LOWER[name] - 1e-9 and values.max() <= TABLE2_UPPER[name] + 1e-9
            assert np.ptp(cols["theta_c2"]) > 0  # it does adapt
        else:
            assert np.ptp(values) == 0.0


def _model_plant_loop(theta0, method, n=300):
    """Closed loop on a 'plant' that is exactly the Eq. (1) model."""
    c = DisplacementController(ControllerSettings(method=method), theta0)
    ref = SineReference()
    plant = ModelState(ASYMMETRIC, l_init=(20.0, 20.0, 20.0), u_init=0.0)
    l = 20.0
    c.reset(l)
    err = []
    for k in range(n):
        step = c.step(l, ref.preview(k, 5))
        plant.apply(step.u_v)
        l = float(plant.phi() @ theta0)
        plant.observe(l, theta0)
        err.append(ref.at(k + 1) - l)
    return np.array(err)


def test_hysteresis_cancellation_linearises_an_exact_model(theta0):
    """Eq. (5) on a plant that is the model: the servo loop sees only Eq. (2) and tracks tightly."""
    err = _model_plant_loop(theta0, "mpc_servo")
    assert np.mean(np.abs(err[100:])) < 0.15


def test_get_set_state_replays_bit_identically(theta0):
    for method in METHODS:
        c = DisplacementController(ControllerSettings(method=method), theta0)
        ref = SineReference()
        rng = np.random.default_rng(1)
        l_seq = 35 + 20 * np.sin(np.arange(200) * 0.06) + rng.normal(0, 0.05, 200)
        for k in range(100):
            c.step(l_seq[k], ref.preview(k, 5))
        saved = c.get_state()
        a = [c.step(l_seq[k], ref.preview(k, 5)).u_v for k in range(100, 200)]
        c.set_state(saved)
        b = [c.step(l_seq[k], ref.preview(k, 5)).u_v for k in range(100, 200)]
        assert a == b, method


@pytest.mark.parametrize("how", [copy.copy, copy.deepcopy, lambda c: pickle.loads(pickle.dumps(c))],
                         ids=["copy", "deepcopy", "pickle"])
def test_a_copied_or_unpickled_controller_steps_on_alone_bit_for_bit(theta0, how):
    """Branching an experiment (or sending a controller to a worker process): the copy continues as
    the original would, and stepping it with other readings leaves the original alone (both hold an
    OSQP solver and an estimator's read-only box, which neither copy nor pickle could take)."""
    ref = SineReference()
    l_seq = 35 + 31 * np.sin(np.arange(260) * 0.063) + np.random.default_rng(4).normal(0, 0.05, 260)
    for method in METHODS:
        c = DisplacementController(ControllerSettings(method=method), theta0)
        for k in range(150):
            c.step(l_seq[k], ref.preview(k, 5))
        saved = c.get_state()
        d = how(c)
        assert d is not c and d.settings == c.settings and np.array_equal(d.theta0, c.theta0)
        other = [d.step(l_seq[k] + 3.0, ref.preview(k, 5)).u_v for k in range(150, 260)]  # the branch first
        alone = DisplacementController(ControllerSettings(method=method), theta0)
        alone.set_state(saved)
        expected = [alone.step(l_seq[k], ref.preview(k, 5)).u_v for k in range(150, 260)]
        assert [c.step(l_seq[k], ref.preview(k, 5)).u_v for k in range(150, 260)] == expected, method
        assert other != expected, method  # the branch was stepped with other readings


def test_state_survives_json_and_replays_bit_identically(theta0):
    """The FMU state is stored as JSON: get_state() must be plain data, and a controller restored from
    its JSON text continues exactly like the original (all four methods, through OSQP solves too)."""
    for method in METHODS:
        c = DisplacementController(ControllerSettings(method=method), theta0)
        ref = SineReference()
        l_seq = 35 + 31 * np.sin(np.arange(300) * 0.063) + np.random.default_rng(2).normal(0, 0.05, 300)
        for k in range(150):
            c.step(l_seq[k], ref.preview(k, 5))
        text = json.dumps(c.get_state(), allow_nan=True)
        a = [c.step(l_seq[k], ref.preview(k, 5)) for k in range(150, 300)]
        d = DisplacementController(ControllerSettings(method=method), theta0)
        d.set_state(json.loads(text))
        b = [d.step(l_seq[k], ref.preview(k, 5)) for k in range(150, 300)]
        assert [s.u_v for s in a] == [s.u_v for s in b], method
        assert all(np.array_equal(x.theta, y.theta) for x, y in zip(a, b)), method
        assert json.dumps(c.get_state()) == json.dumps(d.get_state()), method
        if method.endswith("servo"):  # the window reaches the valve limits: OSQP was used
            assert any(s.saturated for s in a), method


@pytest.mark.parametrize("l, preview, match", [(math.nan, [35.0] * 6, "l_mm"), (30.0, [35.0] * 3, "preview"),
                                               (30.0, [35.0, math.inf] + [35.0] * 4, "finite"),
                                               # a reading in micrometres: refused as the controller FMU refuses it
                                               (35000.0, [35.0] * 6, r"within -1000\.\.5000 mm .*got 35000\.0"),
                                               (-1000.5, [35.0] * 6, "l_mm")])
def test_bad_measurements_raise_and_leave_state(theta0, l, preview, match):
    c = DisplacementController(ControllerSettings(method="ampc_servo"), theta0)
    c.step(30.0, [35.0] * 6)
    before = c.get_state()
    with pytest.raises(ValueError, match=match):
        c.step(l, preview)
    assert _same(c.get_state(), before)


def test_bad_settings_and_theta(theta0):
    with pytest.raises(ValueError, match="method"):
        ControllerSettings(method="pid")
    with pytest.raises(ValueError, match="p0"):
        ControllerSettings(p0=(1.0,) * 3)
    bad = theta0.copy()
    bad[2] = 0.0
    with pytest.raises(ValueError, match="b1"):
        DisplacementController(ControllerSettings(), bad)
    for delay in (-2, MAX_INPUT_DELAY_SAMPLES + 1):
        with pytest.raises(ValueError, match=rf"input_delay_samples must be -1 \(detect\) or a number of samples "
                                             rf"0 \.\. {MAX_INPUT_DELAY_SAMPLES}, got {delay}"):
            ControllerSettings(input_delay_samples=delay)
    # the FMU's ranges: a forgetting factor that follows the noise, valve bounds the valve clips
    for forgetting in (0.3, 1.1, math.nan):
        with pytest.raises(ValueError, match=r"ControllerSettings\.forgetting must be"):
            ControllerSettings(forgetting=forgetting)
    for kwargs in (dict(servo=ServoMPCSettings(u_min_v=-5.0)), dict(servo=ServoMPCSettings(u_max_v=15.0)),
                   dict(ucp=UCPSettings(u_max_v=20.0))):
        (part, bounds), = kwargs.items()
        name = "u_min_v" if bounds.u_min_v < 0 else "u_max_v"
        with pytest.raises(ValueError, match=rf"ControllerSettings\.{part}\.{name} must be within the valve's range 0 \.\. 10 V"):
            ControllerSettings(**kwargs)


# ------------------------------------------------------------------ input delay
@pytest.mark.parametrize("delay", [1, 2, 3])
@pytest.mark.parametrize("method", METHODS)
def test_delay_compensation_on_the_model_gives_the_undelayed_commands(theta0, method, delay):
    """On a plant that is the Eq. (1) model, the predictions l(k+1|k) .. l(k+d|k) are exact: the
    controller with ``input_delay_samples = d`` must output at sample k the command the undelayed
    controller computes at k+d (after both have had 0 V on the valve over the first d samples), so
    the delayed loop is the undelayed one (with the same move weight R: ``delay_move_weight = 1``)."""
    # the paper's start: the start-up mode's lead-in counts its own samples, d apart in the two loops
    d = DisplacementController(ControllerSettings(method=method, input_delay_samples=delay, startup_s=0.0,
                                                  delay_move_weight=1.0), theta0)
    c = DisplacementController(ControllerSettings(method=method, startup_s=0.0), theta0)
    hp = d.settings.preview_samples
    assert hp == c.settings.preview_samples + delay
    ref = SineReference()
    plant = ModelState(ASYMMETRIC, l_init=(20.0, 20.0, 20.0), u_init=0.0)
    l = 20.0
    d.reset(l)
    c.reset(l)
    plant.observe(l, theta0)  # the controllers' reset observes l(0) on the same history
    in_flight, ahead, undelayed = [0.0] * delay, [], []
    for k in range(300):
        step = d.step(l, ref.preview(k, hp))
        if k < delay:  # the undelayed controller with 0 V on the valve over [t_k, t_k+1) as well
            xs = c.get_state().get("xs", 0.0)
            c.step(l, ref.preview(k, hp - delay))
            st = c.get_state()
            st["u_prev"], st["uc_prev"], st["model"]["u"] = 0.0, 0.0, 0.0
            if "xs" in st:  # x_s(k+1) integrated under that 0 V (the anti-windup hold judged the command c chose)
                st["xs"], st["limit_run"] = xs + float(ref.preview(k, 0)[0]) - l, 0
            c.set_state(st)
        else:
            undelayed.append(c.step(l, ref.preview(k, hp - delay)).u_v)
            ahead.append(in_flight[0])
        plant.apply(in_flight[0])
        in_flight = in_flight[1:] + [step.u_v]
        l = float(plant.phi() @ theta0)
        plant.observe(l, theta0)
    assert np.ptp(undelayed) > 5.0  # the commands move: the comparison is not between constants
    np.testing.assert_allclose(ahead, undelayed, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def delayed_runs(theta0):
    """AMPC-servo on the rig through a loop that applies each command one sample late."""
    out = {}
    for comp in (0, 1):
        c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=comp), theta0)
        out[comp] = run_closed_loop(Plant(seed=0), c, SineReference(), duration_s=45.0, loop_delay_samples=1)
    return out


def test_delay_compensation_restores_tracking_on_the_rig(delayed_runs):
    """A parallel master's one sample of delay makes the uncompensated loop oscillate (several mm);
    the compensated one, with its corrected one-step prediction, tracks within 0.25 mm (measured 2.44
    against 0.177 mm; the Eq. (21) window holds the end of the start-up mode's blend, docs/fmu.md), with
    the command inside 0..10 V and far less valve travel (55 against 785 V)."""
    plain, comp = delayed_runs[0], delayed_runs[1]
    e_plain = eq21_error_mm(plain["r_mm"], plain["l_mm"])
    e_comp = eq21_error_mm(comp["r_mm"], comp["l_mm"])
    assert e_plain > 2.0 and e_comp < 0.25 and e_plain > 5 * e_comp, (e_plain, e_comp)
    assert comp["u_v"].min() >= 0.0 and comp["u_v"].max() <= 10.0
    travel = {k: float(np.sum(np.abs(np.diff(r["u_v"][100:])))) for k, r in delayed_runs.items()}
    assert travel[1] < 0.15 * travel[0], travel


def test_the_delayed_loop_applies_the_previous_command(delayed_runs):
    comp = delayed_runs[1]
    assert comp["u_v"][0] == 0.0  # nothing computed before t_0 reaches the valve
    with pytest.raises(ValueError, match="loop_delay_samples"):
        run_closed_loop(Plant(seed=0), DisplacementController(ControllerSettings(), THETA0_44N), SineReference(),
                        duration_s=1.0, loop_delay_samples=2)


def test_delayed_state_replays_bit_identically(theta0):
    """The command in flight is part of the state: a rewind continues exactly."""
    for method in METHODS:
        c = DisplacementController(ControllerSettings(method=method, input_delay_samples=1), theta0)
        ref = SineReference()
        l_seq = 35 + 20 * np.sin(np.arange(200) * 0.06) + np.random.default_rng(1).normal(0, 0.05, 200)
        for k in range(100):
            c.step(l_seq[k], ref.preview(k, 6))
        saved = json.loads(json.dumps(c.get_state()))
        a = [c.step(l_seq[k], ref.preview(k, 6)).u_v for k in range(100, 200)]
        c.set_state(saved)
        b = [c.step(l_seq[k], ref.preview(k, 6)).u_v for k in range(100, 200)]
        assert a == b, method


@pytest.fixture(scope="module")
def transport_delay_runs(theta0):
    """AMPC-servo at 44 N on a rig whose valve acts on each command 0.2 s (two samples) late, with
    the law compensating 0, 1 and 2 samples and deciding it (-1)."""
    rig = PlantParams().with_values(**{"delay.delay_s": 0.2})
    out, decided = {}, {}
    for delay in (0, 1, 2, -1):
        c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=delay), theta0)
        out[delay] = run_closed_loop(Plant(rig, seed=0), c, SineReference(), duration_s=45.0, load_n=44.0)
        decided[delay] = c.input_delay_decision
    return out, decided


def test_a_rigs_transport_delay_is_compensated_when_set_or_decided(transport_delay_runs):
    """A transport delay of two samples: the law that compensates none or one oscillates with the
    valve slamming (Eq. (21) measured 7.3 and 5.3 mm, the valve at a limit 53 and 39 % of the time);
    with 2 it tracks (0.61 mm; 0.067 on the rig without the delay), and -1 decides 2 within its first
    5 s and restarts the estimator there, whose start-up mode the Eq. (21) window then holds (0.99 mm;
    after 30 s 0.34 against 0.46 with 2 set). A closed loop amplifies last bits: the bounds keep a
    factor of 2-3 from the measured figures."""
    runs, decided = transport_delay_runs
    e = {d: eq21_error_mm(r["r_mm"], r["l_mm"]) for d, r in runs.items()}
    assert e[2] < 1.2 and min(e[0], e[1]) > 3 * e[2], e
    assert decided == {0: 0, 1: 1, 2: 2, -1: 2}
    assert e[-1] < 0.5 * min(e[0], e[1]), e
    late = {d: float(np.mean(np.abs(r["r_mm"][300:] - r["l_mm"][300:]))) for d, r in runs.items()}
    assert late[-1] < 1.5 * late[2] + 0.1, late  # after the restart's start-up mode, as good as set
    for r in runs.values():
        assert r["u_v"].min() >= 0.0 and r["u_v"].max() <= 10.0


def test_a_transport_delay_longer_than_five_samples_is_compensated_when_set():
    """A rig logged at Ts = 0.02 s whose valve acts 0.15 s late (7.5 samples): AMPC-servo compensating
    5 samples (the model identified under D = 5) tracks 5.5 times worse over 20-40 s (1.47 mm, where
    delay_move_weight 4 slammed the valve: 3.1-3.2 mm, at a limit 21-22 % of the time; the loop under a
    wrong delay is chaotic, so the test asks for the contrast, not the size); with 8, round(0.15 /
    0.02), and the model identified under it, it tracks: 0.27 mm, and the set delay's check (over 30 s,
    1500 samples here) finds no better delay. servo.Hp = 12 spans 0.24 s, as Table 5's 5 samples do at Ts = 0.05 s, where this rig
    tracks with 3 samples set; 5 samples at 0.02 s span less than the delay (8.4 mm with 8 set)."""
    from dataclasses import replace

    from fmu_controller.identification import identify_record
    from tapmuscle.api import simulate

    ts = 0.02
    rig = PlantParams().with_values(**{"delay.delay_s": 0.15})
    record = simulate("random:lo=2,hi=8,seed=3", duration_s=120.0, ts_s=ts, params=rig, seed=0)
    runs, scored, evidence = {}, {}, {}
    for d in (5, 8):
        theta = identify_record(record["u_v"], record["l_mm"], ts_s=ts, input_delay_samples=d).theta
        settings = ControllerSettings(method="ampc_servo", ts_s=ts, input_delay_samples=d, box_lower={}, box_upper={},
                                      servo=replace(ControllerSettings().servo, hp=12))
        c = DisplacementController(settings, theta)
        runs[d] = run_closed_loop(Plant(rig, seed=0), c, SineReference(ts_s=ts), duration_s=40.1, load_n=44.0)
        scored[d] = len(c.get_state()["delay_scores"])
        assert c.delay_check_samples == 1500  # DELAY_CHECK_SAMPLES' 30 s at Ts = 0.1 s
        evidence[d] = c.delay_evidence
    late = {d: float(np.mean(np.abs(r["r_mm"][1000:] - r["l_mm"][1000:]))) for d, r in runs.items()}
    at_limit = {d: float(np.mean((r["u_v"][500:] <= 0.0) | (r["u_v"][500:] >= 10.0))) for d, r in runs.items()}
    assert late[8] < 1.0 and eq21_error_mm(runs[8]) < 1.0 and evidence[8] is None, (late, evidence)
    assert late[5] > 3.0 * late[8] and at_limit[8] < 0.05, (late, at_limit)
    assert scored == {5: 6, 8: 9}  # the set delay's check scores 0 .. max(5, d)


def test_the_adaptive_gain_keeps_its_sign_where_the_box_does_not_bound_it():
    """A 250-mm muscle at 25 N whose valve acts 0.15 s (3 samples) late, logged at Ts = 0.05 s, where C
    is unbounded by default, run under a wrong delay (1 set): the estimate of b1 crossed zero at 2.5 s
    and the inverted law held the valve at 10 V for good (39 mm over 20-60 s). With b1 kept at
    B1_KEPT_FRACTION of theta0's or more, the bound acts and the loop, still under the wrong delay,
    stays within the reference's range (4-6 mm on two BLAS paths)."""
    from fmu_controller.identification import identify_record
    from tapmuscle.api import simulate

    ts = 0.05
    rig = PlantParams().with_values(**{"muscle.rest_length_mm": 250.0, "delay.delay_s": 0.15,
                                       "muscle.braid_lock_force_n": 20.0, "load.load_n": 25.0})
    record = simulate("random:lo=2,hi=8,seed=3", duration_s=120.0, ts_s=ts, params=rig, seed=0)
    theta = identify_record(record["u_v"], record["l_mm"], ts_s=ts).theta
    c = DisplacementController(ControllerSettings(method="ampc_servo", ts_s=ts, input_delay_samples=1,
                                                  box_lower={}, box_upper={}), theta)
    run = run_closed_loop(Plant(rig, seed=0), c, lambda t: 30.0 + 20.0 * math.sin(2 * math.pi * 0.1 * t),
                          duration_s=60.0, load_n=25.0)
    kept = B1_KEPT_FRACTION * theta[2]
    assert theta[2] > 0.0 and run["theta_b1"].min() == pytest.approx(kept, rel=1e-9)  # the bound acted
    late = np.abs(run["r_mm"][400:] - run["l_mm"][400:])
    assert float(np.mean(late)) < 15.0 and float(np.mean(run["u_v"][400:] >= 10.0)) < 0.8


@pytest.mark.parametrize("b1", [0.805, -0.4])
def test_the_gain_bound_keeps_theta0_inside_and_zero_outside(b1):
    """Property of the box Algorithm 1 projects on: for any box that holds theta0 (or none), the b1
    interval still holds theta0's b1, excludes 0, and is the box's wherever the box is tighter."""
    from fmu_controller.displacement_control import _keep_gain_sign

    rng = np.random.default_rng(0)
    for _ in range(200):
        lo = {} if rng.random() < 0.3 else {"b1": b1 - abs(b1) * rng.uniform(0.0, 2.0)}
        hi = {} if rng.random() < 0.3 else {"b1": b1 + abs(b1) * rng.uniform(0.0, 2.0)}
        settings = ControllerSettings(box_lower=lo, box_upper=hi)
        lower, upper = _keep_gain_sign(settings, b1)
        low, high = lower.get("b1", -math.inf), upper.get("b1", math.inf)
        assert low <= b1 <= high and not low <= 0.0 <= high
        assert low >= lo.get("b1", -math.inf) and high <= hi.get("b1", math.inf)
        assert {**lower, **upper}.keys() >= {"b1"} and lower.get("b1") in (lo.get("b1"), B1_KEPT_FRACTION * b1, None)


@pytest.mark.parametrize("delay", [6, MAX_INPUT_DELAY_SAMPLES])
def test_a_long_set_delay_sizes_its_buffers_and_state_and_replays(theta0, delay):
    """Everything sized by the delay follows a set one up to the cap: the preview (Hp + d), the commands
    in flight, the scores of 0 .. d, the FMU state that round-trips through JSON; a rewind continues
    bit-identically."""
    c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=delay), theta0)
    n = c.settings.preview_samples
    assert n == c.settings.servo.hp + delay and c.largest_scored_delay == delay
    ref = SineReference()
    l_seq = 35 + 20 * np.sin(np.arange(200) * 0.06) + np.random.default_rng(1).normal(0, 0.05, 200)
    with pytest.raises(ValueError, match=rf"r\(k\)..r\(k\+{n}\), {n + 1} samples \(servo.hp = 5 \+ "
                                         rf"input_delay_samples = {delay}, \+ 1\), got {n} samples"):
        c.step(l_seq[0], ref.preview(0, n - 1))
    for k in range(100):
        c.step(l_seq[k], ref.preview(k, n))
    saved = json.loads(json.dumps(c.get_state()))
    assert len(saved["in_flight"]) == delay - 1 and len(saved["delay_scores"]) == len(saved["u_out"]) == delay + 1
    a = [c.step(l_seq[k], ref.preview(k, n)).u_v for k in range(100, 200)]
    c.set_state(saved)
    b = [c.step(l_seq[k], ref.preview(k, n)).u_v for k in range(100, 200)]
    assert a == b
    short = json.loads(json.dumps(saved))
    short["delay_scores"] = short["delay_scores"][:6]
    with pytest.raises(ValueError, match=rf"delay_scores \({delay + 1}, >= 0\)"):
        c.set_state(short)


def test_minus_one_and_a_short_set_delay_score_six_delays(theta0):
    """-1 scores (and may decide) 0..5 whatever the cap, and takes a preview of Hp + 5; a set delay of
    5 or less scores the same six: their cost and their state are those of a cap of 5."""
    for delay in (-1, 0, 1, 5):
        c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=delay), theta0)
        assert c.largest_scored_delay == AUTO_INPUT_DELAY_SAMPLES == 5
        assert len(c.get_state()["delay_scores"]) == 6 and len(c.get_state()["delay_models"]) == 6
    assert ControllerSettings(input_delay_samples=-1).preview_samples == ControllerSettings().servo.hp + 5


def test_a_fixed_predictor_made_under_the_delay_tracks_on_the_delayed_rig():
    """The fixed-predictor MPC-servo with the delay set keeps the paper's theta0, identified on the rig
    without the delay: on a 0.3-s delay it oscillates again (measured 11.2 mm). preliminary_theta with
    the delay identifies on the command the valve had and refines with the delay compensated: 1.2-3.9
    mm over identification seeds 0-4, noise seeds 0-1 and two floating-point paths (AVX-512 and
    OpenBLAS's Nehalem kernels; a refined fixed predictor is a snapshot of a chaotic adaptive loop);
    the clean rig's MPC-servo: 0.40."""
    rig = PlantParams().with_values(**{"delay.delay_s": 0.3})
    errors = {}
    for label, theta in (("paper", preliminary_theta(0, refine_hz=0.05)),
                         ("delayed", preliminary_theta(0, refine_hz=0.05, params=rig, input_delay_samples=3))):
        plant = Plant(rig, seed=0)
        plant.update(load_n=44.0)
        c = DisplacementController(ControllerSettings(method="mpc_servo", input_delay_samples=3), theta)
        r = run_closed_loop(plant, c, SineReference(), duration_s=45.0)
        errors[label] = eq21_error_mm(r["r_mm"], r["l_mm"])
    assert errors["delayed"] < 5.0 and errors["paper"] > 2 * errors["delayed"], errors
    with pytest.raises(ValueError, match="input_delay_samples must be a number of samples 0 .. 25, got 26"):
        preliminary_theta(0, input_delay_samples=26)


def test_a_delay_set_where_the_rig_has_none_keeps_the_prediction_through_the_commands_in_flight_bounded():
    """AMPC-servo told of 4 samples of delay on a rig without one: its estimate, made under the wrong
    delay, once predicted l(k+4|k) = 8e11 mm at 1.9 s through the bilinear hysteresis terms, and the
    cancellation offset H/b1 reached 1e285 V (numpy's overflow warning in the QP's cost). The
    predictions are clamped as Eq. (1)'s free run is, within 10 spans of the last displacements and
    the reference (about -600..700 mm here): H's bilinear terms then stay below ~1e6 (measured max
    |u_c| 3.1e5 V, a garbage cancellation at the wrong delay, but a number), and the valve's commands
    stay in 0..10 V."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=4), THETA0_44N)
        r = run_closed_loop(Plant(PlantParams(), seed=0), c, SineReference(), duration_s=10.0, load_n=44.0)
    assert np.abs(r["uc_v"]).max() < 1e7, np.abs(r["uc_v"]).max()
    assert r["u_v"].min() >= 0.0 and r["u_v"].max() <= 10.0


def test_the_servo_is_detuned_for_a_transport_delay_set_or_decided(theta0):
    """delay_move_weight (default 16) multiplies Table 5's R = 15 while the law runs for a delay of 2 or
    more: set, or decided by -1 (and back to 15 at a reset, whose law runs for 1 again); 0 and 1 keep
    R. On a rig with a 0.3-s delay, AMPC-servo with 3 set tracks better than with the factor 1
    (measured Eq. (21) 0.71 against 1.91 mm, 1.00 with 4; MPC-servo 1.71 against 8.51, 4.30 with 4)."""
    assert DEFAULT_DELAY_MOVE_WEIGHT == 16.0
    assert ControllerSettings().servo_for_delay(1).r == 15.0 and ControllerSettings().servo_for_delay(2).r == 240.0
    tup = ControllerSettings(servo=ServoMPCSettings(r=(1.0, 2.0, 3.0, 4.0, 5.0)), delay_move_weight=2.0)
    assert tup.servo_for_delay(5).r == (2.0, 4.0, 6.0, 8.0, 10.0) and tup.servo_for_delay(0).r == tup.servo.r
    for bad in (0.0, -1.0, 1001.0, math.nan):
        with pytest.raises(ValueError, match="delay_move_weight"):
            ControllerSettings(delay_move_weight=bad)
    rig = PlantParams().with_values(**{"delay.delay_s": 0.3})
    errors = {}
    for factor in (1.0, DEFAULT_DELAY_MOVE_WEIGHT):
        c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=3,
                                                      delay_move_weight=factor), theta0)
        assert c._servo.settings.r == 15.0 * factor
        r = run_closed_loop(Plant(rig, seed=0), c, SineReference(), duration_s=45.0, load_n=44.0)
        errors[factor] = eq21_error_mm(r["r_mm"], r["l_mm"])
    assert errors[DEFAULT_DELAY_MOVE_WEIGHT] < 0.8 * errors[1.0], errors
    c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=-1), theta0)
    assert c._servo.settings.r == 15.0
    run_closed_loop(Plant(rig, seed=1), c, SineReference(), duration_s=8.0, load_n=44.0)
    assert c.input_delay_decision == 3 and c._servo.settings.r == 240.0
    c.reset(0.0)
    assert c._servo.settings.r == 15.0


@pytest.mark.parametrize("delay_s, expected", [(0.0, 0), (0.1, 1), (0.2, 2), (0.3, 3), (0.4, 4)])
def test_minus_one_decides_the_transport_delay_in_samples(theta0, delay_s, expected):
    """-1 compares delays 0..5 and decides by its 50th sample on these rigs (a sequential loop, so a
    rig's delay of n samples is n samples of input delay)."""
    rig = PlantParams().with_values(**{"delay.delay_s": delay_s})
    c = DisplacementController(ControllerSettings(method="ampc_ucp", input_delay_samples=-1), theta0)
    run_closed_loop(Plant(rig, seed=1), c, SineReference(), duration_s=6.0, load_n=44.0)
    assert c.input_delay_decision == expected


@pytest.mark.parametrize("method", ["mpc_servo", "ampc_servo"])
def test_a_loop_chattering_with_a_period_of_samples_is_not_taken_for_a_transport_delay(method):
    """A rig whose command acts a quarter sample late (0.025 s: a parallel master sub-stepping at Ts/4)
    at 68 N, 0.2 Hz: the delayed law -1 starts with chatters with a period of 3 samples, so delay 3
    scores best with 1 and 2 far worse, and deciding 3 tracks 5-6 times worse than 0 set. The
    scores that a transport delay gives fall towards it from 1 sample on (a real 0.3 s delay still
    decides 3)."""
    def run(delay_s, input_delay):
        rig = PlantParams().with_values(**{"delay.delay_s": delay_s, "load.load_n": 68.0})
        c = DisplacementController(ControllerSettings(method=method, input_delay_samples=input_delay), THETA0_44N)
        out = run_closed_loop(Plant(rig, seed=0), c, SineReference(frequency_hz=0.2, amplitude_mm=25.0),
                              duration_s=40.0, watch=False)
        return c, float(np.mean(np.abs(out["r_mm"] - out["l_mm"])[out["t_s"] >= 20.0]))

    auto, mae_auto = run(0.025, -1)
    ms = np.array(auto._scores.ms)
    assert ms[3] < ms[0] < ms[1] < ms[2]  # the chatter's aliased delay scores best
    assert auto.input_delay_decision == 0
    assert mae_auto < 2.0 * run(0.025, 0)[1]  # deciding 3: 4.8 (MPC-servo) and 6 (AMPC-servo) times
    assert run(0.3, -1)[0].input_delay_decision == 3


@pytest.mark.parametrize("seed", [0, 1])
def test_a_delay_between_two_samples_is_decided_as_the_longer_for_the_servo_law(seed):
    """0.15 s at Ts = 0.1 s scores delays 1 and 2 within a few percent (DELAY_TIE_RATIO): the servo
    methods decide 2 (MPC-servo decided 1 and swung the valve limit to limit, 2.3-2.5 mm over 40-90 s;
    with 2, 0.53), the coincidence point keeps the better scored; a whole number of samples (0.2 s, or
    no delay in a parallel master) is decided as before."""
    def decided(method, delay_s, loop=0):
        rig = PlantParams().with_values(**{"delay.delay_s": delay_s})
        c = DisplacementController(ControllerSettings(method=method, input_delay_samples=-1), THETA0_44N)
        run = run_closed_loop(Plant(rig, seed=seed), c, SineReference(), duration_s=90.0 if method == "mpc_servo" else 6.0,
                              load_n=44.0, loop_delay_samples=loop, watch=False)
        return c.input_delay_decision, run

    (d, run) = decided("mpc_servo", 0.15)
    assert d == 2 and float(np.mean(np.abs(run["r_mm"] - run["l_mm"])[400:901])) < 1.0
    assert decided("ampc_servo", 0.15)[0] == 2 and decided("ampc_servo", 0.35)[0] == 4
    assert decided("mpc_ucp", 0.15)[0] == 1
    assert decided("ampc_servo", 0.2)[0] == 2 and decided("ampc_servo", 0.0, loop=1)[0] == 1


@pytest.mark.parametrize("settings", [dict(method="ampc_servo", input_delay_samples=3),
                                      dict(method="mpc_ucp", input_delay_samples=5),
                                      dict(method="ampc_servo", input_delay_samples=-1)])
def test_the_commands_in_flight_are_part_of_the_state(theta0, settings):
    """A rewind continues bit for bit with several commands in flight, and after -1 decided for a
    transport delay of 3 samples (the loop below applies each command 3 samples late)."""
    c = DisplacementController(ControllerSettings(**settings), theta0)
    plant, in_flight = Plant(PlantParams(), seed=2), [0.0] * 3
    hp = c.settings.preview_samples
    ref = SineReference()
    c.reset(plant.measurement.l_mm)
    ls, steps = [], []
    for k in range(160):
        l = plant.measurement.l_mm
        ls.append(l)
        if k == 100:
            saved = json.loads(json.dumps(c.get_state()))
        steps.append(c.step(l, ref.preview(k, hp)).u_v)
        plant.step(in_flight[0], 0.1)
        in_flight = in_flight[1:] + [steps[-1]]
    if settings["input_delay_samples"] == -1:
        assert c.input_delay_decision == 3
    c.set_state(saved)
    again = [c.step(ls[k], ref.preview(k, hp)).u_v for k in range(100, 160)]
    assert again == steps[100:]


@pytest.mark.parametrize("key, value", [("theta", [1.0] * 3), ("xs", math.inf), ("k", -1), ("u_next", math.nan),
                                        ("predicted", math.inf), ("held_in_a_row", -1), ("held_in_a_row", 9)])
def test_a_corrupted_state_is_refused_naming_the_field(theta0, key, value):
    c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=1), theta0)
    for k in range(5):
        c.step(30.0 + k, [35.0] * 7)
    good = c.get_state()
    with pytest.raises(ValueError, match=f"state field {key}"):
        c.set_state({**good, key: value})


# ------------------------------------------------------------------ valve chatter (hysteresis notch)
def _servo_runs(theta0, notch, load, f, seeds=(0, 1, 2)):
    p0 = P0_TABLE8 if f == 0.2 else P0_TABLE5
    out = []
    for seed in seeds:
        plant = Plant(seed=seed)
        plant.update(load_n=load)
        c = DisplacementController(ControllerSettings(method="mpc_servo", p0=p0, hysteresis_notch=notch), theta0)
        out.append(run_closed_loop(plant, c, SineReference(frequency_hz=f), duration_s=45.0))
    return out


@pytest.fixture(scope="module")
def paper_theta0():
    """The fixed predictor as `tapmuscle paper` identifies it (refined at 0.05 Hz)."""
    return preliminary_theta(0, refine_hz=0.05)


@pytest.mark.parametrize("load, f", [(44.0, 0.1), (44.0, 0.2), (68.0, 0.1), (68.0, 0.2)])
def test_mpc_servo_does_not_chatter_and_tracks_no_worse(paper_theta0, load, f):
    """The notch (default for MPC-servo) keeps the command's total variation within 10 % of a smooth
    command's in the Eq. (21) window, and Eq. (21) is no worse than with the paper's Eq. (5); the
    paper's Eq. (5) chatters in the same runs (measured 7-83 % above, seeds 0-4)."""
    notch, paper = _servo_runs(paper_theta0, None, load, f), _servo_runs(paper_theta0, False, load, f)
    for r in notch:
        assert command_tv_excess(r["u_v"], f) <= 0.10
    if load == 44.0:  # where the chatter is strongest: the paper's Eq. (5) is >= 19 % above in each run
        assert min(command_tv_excess(r["u_v"], f) for r in paper) >= 0.15
    e_notch = np.mean([eq21_error_mm(r["r_mm"], r["l_mm"]) for r in notch])
    e_paper = np.mean([eq21_error_mm(r["r_mm"], r["l_mm"]) for r in paper])
    # no worse, within 1 %: single runs of the chattering loop vary by up to 7 % between seeds
    assert e_notch <= 1.01 * e_paper, (e_notch, e_paper)


def test_the_notch_is_on_by_method_and_selectable(theta0):
    on = {m: DisplacementController(ControllerSettings(method=m), theta0)._notch for m in METHODS}
    assert on == {"mpc_ucp": False, "mpc_servo": True, "ampc_ucp": False, "ampc_servo": True}
    on = {m: DisplacementController(ControllerSettings(method=m, startup_s=0.0), theta0)._notch for m in METHODS}
    assert on == {"mpc_ucp": False, "mpc_servo": True, "ampc_ucp": False, "ampc_servo": False}
    assert DisplacementController(ControllerSettings(method="ampc_servo", hysteresis_notch=True), theta0)._notch
    assert not DisplacementController(ControllerSettings(method="mpc_servo", hysteresis_notch=False), theta0)._notch
    with pytest.raises(ValueError, match="hysteresis_notch"):
        ControllerSettings(hysteresis_notch=1)


def _step_run(target_mm, seed, **settings):
    ctrl = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=0, **settings),
                                  THETA0_44N)
    return run_closed_loop(Plant(PlantParams(), seed=seed), ctrl, lambda t: 35.0 if t < 20.0 else target_mm,
                           duration_s=30.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_notch_keeps_the_qp_input_sane_after_a_large_reference_step(seed):
    """AMPC-servo, 35 -> 90 mm at 20 s (reachable: tracked to 0.01 mm after): the estimate's jump at the
    step made the notch's predicted H(k+2|k) thousands of mm and u_c 2000-4000 V in every seed, the
    valve slamming shut for a sample. Bounded to NOTCH_RATE_FACTOR and NOTCH_FLOOR_MM, u_c stays
    within 31-36 V here; 100 V (ten valve spans) leaves room for another CPU's bits in this loop."""
    r = _step_run(90.0, seed)
    assert np.abs(r["uc_v"]).max() < 100.0
    assert np.abs(r["h_mm"]).max() < 50.0
    late = r["t_s"] >= 25.0
    assert np.mean(np.abs(r["r_mm"][late] - r["l_mm"][late])) < 0.05


@pytest.mark.parametrize("method, f", [("mpc_servo", 0.2), ("ampc_servo", 0.1)])
def test_the_notchs_bound_does_not_act_in_tracking(monkeypatch, method, f):
    """In the paper's sine tracking the predicted H moves under 0.5 mm per sample: the bound changes no
    bit of the run (the paper's tables are those of the notch without it)."""
    import fmu_controller.displacement_control as dc

    def run():
        c = DisplacementController(ControllerSettings(method=method, hysteresis_notch=True), THETA0_44N)
        return run_closed_loop(Plant(PlantParams(), seed=0), c, SineReference(frequency_hz=f), duration_s=60.0)

    bounded = run()
    monkeypatch.setattr(dc, "NOTCH_FLOOR_MM", 1e300)
    free = run()
    assert all(np.array_equal(bounded[k], free[k]) for k in ("u_v", "l_mm", "h_mm"))


# ------------------------------------------------------------------ start-up mode
def _reversals(u: np.ndarray) -> int:
    """Full-range command reversals: changes between 0 V and 10 V saturation (samples in between ignored)."""
    s = np.where(u <= 0.05, -1, np.where(u >= 9.95, 1, 0))
    s = s[s != 0]
    return int(np.count_nonzero(s[1:] != s[:-1]))


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("load, f", [(44.0, 0.1), (44.0, 0.2), (68.0, 0.1), (68.0, 0.2)])
def test_the_default_start_is_clean_for_every_method(paper_theta0, method, load, f):
    """From rest with the default start-up mode, noise seeds 0-3, 45 s: the displacement never exceeds
    the reference's 65-mm peak by more than 3 mm and the valve makes at most 2 full-range reversals
    (measured over seeds 0-15: at most 0.7 mm and 0 reversals). The paper's start breaks a limit in
    every run of every method but MPC-UCP (overshoot 11-31 mm, up to 10 reversals). Eq. (21) of the
    fixed-predictor MPCs is the paper start's within 2 % (their steady state does not depend on the
    start)."""
    for seed in range(4):
        runs = {}
        for startup in (DEFAULT_STARTUP_S, 0.0):
            plant = Plant(seed=seed)
            plant.update(load_n=load)
            # the paper's start: its controller from the first sample, Eq. (18) without the hold included
            cs = ControllerSettings(method=method, p0=P0_TABLE8 if f == 0.2 else P0_TABLE5, startup_s=startup,
                                    anti_windup=startup > 0)
            ctrl = DisplacementController(cs, paper_theta0)
            runs[startup] = run_closed_loop(plant, ctrl, SineReference(frequency_hz=f), duration_s=45.0)
            assert ctrl.startup_guarded_at is None  # the guard never fires on a sound theta0 (bits kept)
        r = runs[DEFAULT_STARTUP_S]
        assert np.max(r["l_mm"]) <= 65.0 + 3.0, (seed, np.max(r["l_mm"]))
        assert _reversals(r["u_v"]) <= 2
        assert r["u_v"].min() >= 0.0 and r["u_v"].max() <= 10.0
        paper = runs[0.0]
        if method != "mpc_ucp":  # the paper's start: what the mode removes
            assert np.max(paper["l_mm"]) > 65.0 + 3.0 or _reversals(paper["u_v"]) > 2
        if not method.startswith("ampc"):
            e0, e1 = (eq21_error_mm(x["r_mm"], x["l_mm"]) for x in (paper, r))
            assert e1 <= 1.02 * e0, (e1, e0)


def test_the_default_start_makes_adaptive_ucp_beat_fixed_ucp_at_both_loads(paper_theta0):
    """With the default start-up mode, AMPC-UCP beats MPC-UCP at 44 N (where the paper's start does
    not) and at 68 N, in every one of seeds 0-4 (measured over seeds 0-9: 0.28 vs 0.87 mm at 44 N,
    0.57 vs 1.34 mm at 68 N)."""
    for load in (44.0, 68.0):
        fixed, adaptive = [], []
        for seed in range(5):
            for method, out in (("mpc_ucp", fixed), ("ampc_ucp", adaptive)):
                plant = Plant(seed=seed)
                plant.update(load_n=load)
                c = DisplacementController(ControllerSettings(method=method), paper_theta0)
                r = run_closed_loop(plant, c, SineReference(frequency_hz=0.1), duration_s=45.0)
                out.append(eq21_error_mm(r["r_mm"], r["l_mm"]))
        assert max(adaptive) < min(fixed), (load, adaptive, fixed)
        assert np.mean(adaptive) < 0.8 * np.mean(fixed)


@pytest.mark.parametrize("load, f", [(44.0, 0.1), (44.0, 0.2), (68.0, 0.1), (68.0, 0.2)])
def test_default_adaptive_servo_against_the_papers(paper_theta0, load, f):
    """AMPC-servo with the defaults (start-up mode with its probing, 5-point notch) against the paper's
    controller (paper start, Eq. (5)), seeds 0-2: Eq. (21) lower in every cell (measured 0.084, 0.117,
    0.083, 0.122 mm against 0.137, 0.380, 0.131, 0.273), and the command's total variation in the
    Eq. (21) window at most 10 % above smooth (measured at most 5 % over seeds 0-9; without the probing
    14-26 % at 0.1 Hz, docs/control.md "Start-up")."""
    runs = {}
    for name, extra in (("default", {}), ("paper", {"startup_s": 0.0, "hysteresis_notch": False})):
        runs[name] = []
        for seed in range(3):
            plant = Plant(seed=seed)
            plant.update(load_n=load)
            cs = ControllerSettings(method="ampc_servo", p0=P0_TABLE8 if f == 0.2 else P0_TABLE5, **extra)
            runs[name].append(run_closed_loop(plant, DisplacementController(cs, paper_theta0),
                                              SineReference(frequency_hz=f), duration_s=45.0))
    e = {name: np.mean([eq21_error_mm(r["r_mm"], r["l_mm"]) for r in rs]) for name, rs in runs.items()}
    assert e["default"] < e["paper"], e
    for r in runs["default"]:
        assert command_tv_excess(r["u_v"], f) <= 0.10


@pytest.mark.parametrize("load", [44.0, 68.0])
def test_probing_keeps_the_servo_estimate_off_the_box(paper_theta0, load):
    """The mechanism of the probing signal: without it, AMPC-servo's gentle start leaves ``b1`` on C's
    lower bound by 40 s (measured within 0.001 of it, seeds 0-2, 0.1 Hz), the young model whose
    command ripples; with it ``b1`` stays clear of the bound (measured 0.66-0.78 against 0.607). It
    does so only with the regressor's hysteresis state computed by the law's parameters during the
    start-up: with section 2.3's, from the raw estimate, ``b1`` is within 0.01 of the bound despite
    the probe (benchmarks/startup_regressor.py), and this test fails."""
    lower = TABLE2_LOWER["b1"]
    for seed in range(3):
        b1 = {}
        for pv in (DEFAULT_PROBING_V, 0.0):
            plant = Plant(seed=seed)
            plant.update(load_n=load)
            c = DisplacementController(ControllerSettings(method="ampc_servo", probing_v=pv), paper_theta0)
            run_closed_loop(plant, c, SineReference(frequency_hz=0.1), duration_s=40.0)
            b1[pv] = float(c.theta[2])
        assert b1[0.0] <= lower + 0.005, b1
        assert b1[DEFAULT_PROBING_V] >= lower + 0.03, b1


def test_probing_is_only_in_the_adaptive_warm_up(theta0):
    """The probe reaches the valve only for the adaptive methods with the start-up mode, only while
    the law is on theta0 (0 < t < startup_s/2), and the command stays in 0..10 V: fed the same
    measurements, a controller with the probe and one without give identical commands for the fixed
    methods and for every method with ``startup_s = 0``."""
    ref = SineReference()
    meas = 35.0 + 30.0 * np.sin(2 * np.pi * 0.1 * 0.1 * np.arange(200)) * np.minimum(1.0, np.arange(200) / 30)
    for method in METHODS:
        for startup in (DEFAULT_STARTUP_S, 0.0):
            u = {}
            for pv in (DEFAULT_PROBING_V, 0.0):
                c = DisplacementController(ControllerSettings(method=method, startup_s=startup, probing_v=pv), theta0)
                c.reset(meas[0])
                u[pv] = np.array([c.step(l, ref.preview(k, c.settings.preview_samples)).u_v
                                  for k, l in enumerate(meas)])
                assert u[pv].min() >= 0.0 and u[pv].max() <= 10.0
            diff = np.abs(u[DEFAULT_PROBING_V] - u[0.0])
            if method.startswith("ampc") and startup > 0:
                warm = int(round(0.5 * startup / 0.1))
                assert diff[1:warm].max() > 0.25  # the probe is there (0.5 V, less where the valve clips)
                c = DisplacementController(ControllerSettings(method=method, startup_s=startup), theta0)
                for j in range(2 * warm):  # the probe added at sample j of the estimator's clock
                    c._k = j
                    assert c._probed(5.0) - 5.0 == (probe_v(j, DEFAULT_PROBING_V) if 0 < j < warm else 0.0)
            else:
                assert diff.max() == 0.0, method


def test_probing_is_validated():
    assert ControllerSettings().probing_v == DEFAULT_PROBING_V == 0.5
    for bad in (-0.1, math.nan, 2.6, True, "0.5"):
        with pytest.raises(TypeError if isinstance(bad, (bool, str)) else ValueError, match="probing_v"):
            ControllerSettings(probing_v=bad)
    assert ControllerSettings().probing_phase == 0 and ControllerSettings(probing_phase=np.int64(126)).probing_phase == 126
    for bad in (-1, 127, 1.0, True):
        with pytest.raises(TypeError if isinstance(bad, (bool, float)) else ValueError, match="probing_phase"):
            ControllerSettings(probing_phase=bad)


def test_the_probing_phase_shifts_the_probe_and_nothing_else(theta0):
    """The phase moves the probe along the sequence: fed the same measurements, controllers of phases
    0 and 111 command differently in the warm-up; without a probe (probing_v = 0) the phase changes
    nothing."""
    c0, c1 = (DisplacementController(ControllerSettings(method="ampc_servo", probing_phase=p), theta0) for p in (0, 111))
    c0._k = c1._k = 7
    assert c1._probed(5.0) - c0._probed(5.0) == probe_v(7, DEFAULT_PROBING_V, 111) - probe_v(7, DEFAULT_PROBING_V)
    ref = SineReference()
    meas = 35.0 + 30.0 * np.sin(2 * np.pi * 0.1 * 0.1 * np.arange(150)) * np.minimum(1.0, np.arange(150) / 30)
    u = []
    for c in (c0, c1):
        c.reset(meas[0])
        u.append(np.array([c.step(l, ref.preview(k, c.settings.preview_samples)).u_v for k, l in enumerate(meas)]))
    warm = int(round(0.5 * DEFAULT_STARTUP_S / 0.1))
    assert np.abs(u[1] - u[0])[1:warm].max() > 0.5  # the probes differ: +0.5 against -0.5 V on some bits
    quiet = []
    for p in (0, 111):
        c = DisplacementController(ControllerSettings(method="ampc_servo", probing_v=0.0, probing_phase=p), theta0)
        c.reset(meas[0])
        quiet.append([c.step(l, ref.preview(k, c.settings.preview_samples)).u_v for k, l in enumerate(meas)])
    assert quiet[0] == quiet[1]


def test_startup_mode_is_on_by_default_and_validated(theta0):
    assert ControllerSettings().startup_s == DEFAULT_STARTUP_S == 12.0
    for bad in (-1.0, math.nan, 601.0, True):
        with pytest.raises(TypeError if bad is True else ValueError, match="startup_s"):
            ControllerSettings(startup_s=bad)


@pytest.mark.parametrize("method", ["ampc_ucp", "ampc_servo"])
@pytest.mark.parametrize("saved_at", [20, 80])
def test_state_round_trip_during_the_startup_mode(paper_theta0, method, saved_at):
    """get_state/set_state (through JSON) in the middle of the default start-up mode's lead-in (2 s)
    and of its blending (8 s) continue bit for bit, the notch's past values included."""
    cs = ControllerSettings(method=method)
    ref = SineReference()
    a, b = DisplacementController(cs, paper_theta0), DisplacementController(cs, paper_theta0)
    plant = Plant(seed=1)
    l = plant.measurement.l_mm
    a.reset(l)
    for k in range(saved_at):
        u = a.step(l, ref.preview(k, a.settings.preview_samples)).u_v
        l = plant.step(u, 0.1).l_mm
    b.set_state(json.loads(json.dumps(a.get_state())))
    for k in range(saved_at, saved_at + 150):
        p = ref.preview(k, a.settings.preview_samples)
        sa, sb = a.step(l, p), b.step(l, p)
        assert sa.u_v == sb.u_v and np.array_equal(sa.theta, sb.theta)
        l = plant.step(sa.u_v, 0.1).l_mm


# ------------------------------------------------------------------ input delay detected (-1)
@pytest.mark.parametrize("method", METHODS)
def test_detected_delay_decides_for_the_undelayed_law_in_a_sequential_loop(theta0, method):
    """input_delay_samples = -1 with a sequential loop starts with the delayed law and decides for the
    undelayed one after the 5 s of scores it needs (0.1 Hz, 0.2 Hz with a load step). The fixed
    predictors then track as 0 (measured equal to 1e-3 mm over 20-45 s, seed 3); the adaptive ones
    restart their estimator at the decision (its first regressors held the command one sample off),
    which costs at most a third over 20-45 s (measured AMPC-UCP 0.318 against 0.237 mm, AMPC-servo
    0.085 against 0.064 mm at 0.1 Hz)."""
    for f, load_n in ((0.1, 44.0), (0.2, lambda t: 68.0 if t >= 20.0 else 44.0)):
        err = {}
        for d in (0, -1):
            c = DisplacementController(ControllerSettings(method=method, input_delay_samples=d), theta0)
            plant, ref = Plant(seed=3), SineReference(frequency_hz=f)
            hp = c.settings.preview_samples
            c.reset(plant.measurement.l_mm)
            meas, e, decided_at = plant.measurement, [], None
            for k in range(451):
                if callable(load_n):
                    plant.update(load_n=load_n(k * 0.1))
                u = c.step(meas.l_mm, ref.preview(k, hp)).u_v
                if decided_at is None and c.input_delay_decision is not None:
                    decided_at = k * 0.1
                if k >= 200:
                    e.append(abs(ref.at(k) - meas.l_mm))
                meas = plant.step(u, 0.1)
            assert c.input_delay_decision == 0 and not c.input_delay_detected
            assert decided_at <= 6.0, decided_at
            err[d] = float(np.mean(e))
        limit = 1.01 if not method.startswith("ampc") else 1.5
        assert err[-1] <= limit * err[0] + 1e-3, (f, err)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_detected_delay_switches_in_a_parallel_loop(theta0, method):
    """With each command applied one sample late (a parallel master at h = Ts), -1 keeps the delayed
    law it starts with, decided within 6 s; AMPC-servo then tracks as with 1 and far better than with
    0, judged on the mean |r - l| over 30-90 s of seeds 0-3."""
    errors: dict[int, list[float]] = {0: [], 1: [], -1: []}
    for seed in range(4 if method == "ampc_servo" else 1):
        for d in (0, 1, -1):
            c = DisplacementController(ControllerSettings(method=method, input_delay_samples=d), theta0)
            switched_at = None
            plant, ref = Plant(seed=seed), SineReference()
            hp = c.settings.preview_samples
            c.reset(plant.measurement.l_mm)
            meas, in_flight, err = plant.measurement, 0.0, []
            for k in range(900):
                u = c.step(meas.l_mm, ref.preview(k, hp)).u_v
                if d == -1 and switched_at is None and c.input_delay_detected:
                    switched_at = k * 0.1
                if k >= 300:
                    err.append(abs(ref.at(k) - meas.l_mm))
                u, in_flight = in_flight, u
                meas = plant.step(u, 0.1)
            errors[d].append(float(np.mean(err)))
            if d == -1:
                assert switched_at is not None and switched_at <= 6.0, switched_at
    if method == "ampc_servo":
        e = {d: float(np.mean(v)) for d, v in errors.items()}
        assert e[-1] <= 1.5 * e[1] and e[-1] < 0.5 * e[0], errors


@pytest.mark.parametrize("method", METHODS)
def test_detected_delay_in_a_parallel_loop_is_the_delayed_law_bit_for_bit(theta0, method):
    """-1 starts with the delayed law and, once the parallel hypothesis leads (from the 20th compared
    sample), uses the corrected prediction as 1 does from its 21st sample: in a parallel loop its
    commands are those of 1, bit for bit (the hypotheses' scores differ by a factor of 1.4 or more,
    far from a rounding tie)."""
    runs = []
    for d in (1, -1):
        c = DisplacementController(ControllerSettings(method=method, input_delay_samples=d), theta0)
        runs.append(run_closed_loop(Plant(seed=1), c, SineReference(frequency_hz=0.2), duration_s=30.0,
                                    loop_delay_samples=1))
        assert c.input_delay_detected
    assert np.array_equal(runs[0]["u_v"], runs[1]["u_v"])


@pytest.mark.parametrize("saved_at", [30, 120])
def test_detected_delay_state_round_trip(theta0, saved_at):
    """get_state/set_state while still deciding (3 s) and after deciding (12 s) continue bit for bit
    (the detection's scores, its two shadow models and the delay predictor included)."""
    cs = ControllerSettings(method="ampc_servo", input_delay_samples=-1)
    a, b = DisplacementController(cs, theta0), DisplacementController(cs, theta0)
    plant, ref = Plant(seed=2), SineReference()
    hp = cs.preview_samples
    a.reset(plant.measurement.l_mm)
    l, in_flight = plant.measurement.l_mm, 0.0
    for k in range(saved_at):
        u = a.step(l, ref.preview(k, hp)).u_v
        u, in_flight = in_flight, u
        l = plant.step(u, 0.1).l_mm
    assert a.input_delay_detected == (saved_at == 120)
    b.set_state(json.loads(json.dumps(a.get_state())))
    assert b.input_delay_detected == a.input_delay_detected
    for k in range(saved_at, 200):
        sa, sb = a.step(l, ref.preview(k, hp)), b.step(l, ref.preview(k, hp))
        assert sa.u_v == sb.u_v
        assert json.dumps(a.get_state()) == json.dumps(b.get_state()), k  # the whole state, every bit
        u, in_flight = in_flight, sa.u_v
        l = plant.step(u, 0.1).l_mm


@pytest.mark.parametrize("method", ["mpc_servo", "ampc_servo"])
@pytest.mark.parametrize("far_mm", [120.0, -20.0])
def test_the_servo_integrator_does_not_wind_up_on_a_reference_out_of_reach(method, far_mm):
    """A reference the muscle cannot follow (120 mm: the valve open at 10 V for seconds; -20 mm: closed
    at 0 V) for 20 s, then 40 mm: with the hold the loop is within 2 mm of 40 mm within 0.3-2.6 s of the
    step back, without it 6-11.5 s (x_s wound up to +-3400..3800 mm). Wherever the command has sat at a
    limit the error pushes it into for HOLD_AFTER_SAMPLES samples, x_s is held."""
    from tapmuscle import simulate_closed_loop

    settle = {}
    for hold in (True, False):
        run = simulate_closed_loop(method, lambda t: far_mm if t < 20.0 else 40.0, duration_s=45.0,
                                   settings=ControllerSettings(method=method, anti_windup=hold))
        t, l, u, xs = run["t_s"], run["l_mm"], run["u_v"], run["xs_mm"]
        off = (t >= 20.0) & (np.abs(l - 40.0) > 2.0)
        settle[hold] = t[off].max() - 20.0
        if hold:
            e = run["r_mm"] - l
            # after the start-up's reference lead-in (the law integrates the led-in reference there)
            pushed = (((u >= 10.0 - 1e-9) & (e > 0)) | ((u <= 1e-9) & (e < 0))) & (t >= DEFAULT_STARTUP_S)
            n = HOLD_AFTER_SAMPLES
            held = np.array([pushed[k - n + 1:k + 1].all() for k in range(n, len(t))])
            k = np.flatnonzero(held) + n
            assert len(k) > 10 and np.array_equal(xs[k], xs[k - 1])  # xs_mm[k] is x_s(k+1)
    assert settle[True] < 0.5 * settle[False], settle
    assert settle[True] < 4.0, settle


def test_anti_windup_is_validated():
    assert ControllerSettings().anti_windup is True
    with pytest.raises(ValueError, match="anti_windup"):
        ControllerSettings(anti_windup=1)


def test_numpy_numbers_of_any_width_are_taken_as_numbers(theta0):
    """What a notebook's arrays give (np.float32, np.int64) is a number; a bool or a string is a
    TypeError naming the field."""
    from fmu_controller.delay_predictor import DelayPredictor
    from fmu_controller.reference import ArrayReference
    from fmu_controller.servo_mpc import ServoMPCSettings

    cs = ControllerSettings(method="ampc_servo", ts_s=np.float32(0.1), startup_s=np.float32(12),
                            probing_v=np.float64(0.5), input_delay_samples=np.int64(0),
                            servo=ServoMPCSettings(hp=np.int64(5), hu=np.int32(5), u_max_v=np.float32(10)),
                            ucp=UCPSettings(hp=np.int16(2), u_min_v=np.int64(0)))
    assert type(cs.ts_s) is float and cs.ts_s == float(np.float32(0.1)) and type(cs.input_delay_samples) is int
    assert (cs.startup_s, cs.servo.hp, cs.ucp.hp, cs.ucp.u_min_v) == (12.0, 5, 2, 0.0)
    ref = SineReference(frequency_hz=np.float32(0.1), ts_s=np.float32(0.1))
    c = DisplacementController(cs, theta0)
    assert np.isfinite(c.step(0.0, ref.preview(0, cs.preview_samples)).u_v)
    assert ArrayReference(np.arange(5.0), ts_s=np.float64(0.1)).ts_s == 0.1
    assert DelayPredictor(forgetting=np.float32(0.5), p0=np.int64(2), warmup_samples=np.int64(3)).warmup_samples == 3
    for kwargs, name in [({"ts_s": True}, "ts_s"), ({"startup_s": "12"}, "startup_s"),
                         ({"input_delay_samples": 1.0}, "input_delay_samples")]:
        with pytest.raises(TypeError, match=name):
            ControllerSettings(**kwargs)
    with pytest.raises(TypeError, match="SineReference.ts_s"):
        SineReference(ts_s="0.1")


def test_the_parameters_a_step_hands_out_cannot_change_the_law(theta0):
    """A caller rescaling ``step.theta`` for a plot must not change the next commands (it shares the
    controller's array): it is read-only, for every method, before and after a state restore."""
    for method in METHODS:
        c = DisplacementController(ControllerSettings(method=method), theta0)
        ref = SineReference()
        for k in range(3):
            step = c.step(0.0, ref.preview(k, c.settings.preview_samples))
            with pytest.raises(ValueError, match="read-only"):
                step.theta[:] = step.theta * 1.05
        with pytest.raises(ValueError, match="read-only"):
            c.theta0[0] = 1.0
        saved = c.get_state()
        saved["theta"] = np.array(saved["theta"])
        c.set_state(saved)
        assert saved["theta"].flags.writeable  # the caller's array is left as it was
        with pytest.raises(ValueError, match="read-only"):
            c.step(0.0, ref.preview(3, c.settings.preview_samples)).theta[0] = 0.0


def test_a_finite_preview_whose_sum_overflows_is_finite(theta0):
    c = DisplacementController(ControllerSettings(method="mpc_ucp"), theta0)
    assert 0.0 <= c.step(0.0, [1e308] * (c.settings.preview_samples + 1)).u_v <= 10.0
    with pytest.raises(ValueError, match="must be finite"):
        c.step(0.0, [1e308, math.inf] + [0.0] * (c.settings.preview_samples - 1))


def test_an_adaptive_controller_starts_inside_its_constraint_region(theta0):
    """Algorithm 1 keeps the estimate in C: a theta0 outside it would stay in the law, outside C,
    through the start-up mode; a fixed-predictor MPC has no C."""
    outside = dict(zip(ASYMMETRIC.names, theta0)) | {"a1": 1.10, "b1": 0.30}
    with pytest.raises(ValueError, match=r"theta0's a1 = 1.1 lies outside the constraint region C, 1.208..1.26") as e:
        DisplacementController(ControllerSettings(method="ampc_servo"), outside)
    # Table 2's box, which holds at Ts = 0.1 s: a theta0 of another period is named as a cause (a
    # 0.05-s identification's theta passed alone was told only of the box)
    assert str(e.value).endswith("; or theta0 was identified at another sampling period than this controller's "
                                 "Ts = 0.1 s (an identification file carries its Ts and box: give the file, not its "
                                 "theta alone)")
    # at another Ts it is the box that is of another period, Table 2's default kept: said so, with the fix
    with pytest.raises(ValueError, match=r"; the box is Table 2's, which holds at Ts = 0.1 s, and this controller "
                                         r"samples at Ts = 0.05 s: give your identification's box \(box_lower/box_upper"):
        DisplacementController(ControllerSettings(method="ampc_servo", ts_s=0.05), outside)
    assert DisplacementController(ControllerSettings(method="ampc_servo", ts_s=0.05, box_lower={}, box_upper={}),
                                  outside).theta0[0] == 1.10
    DisplacementController(ControllerSettings(method="mpc_servo"), outside)
    wide = ControllerSettings(method="ampc_ucp", box_lower={"a1": 1.0, "a2": -0.4, "b1": 0.2})
    assert DisplacementController(wide, outside).theta0[0] == 1.10


def test_a_set_delay_is_checked_once_its_samples_are_scored(theta0):
    """``delay_checked`` turns true once the first ``delay_check_samples`` samples are scored under each
    delay, and only then may ``delay_evidence`` speak; with -1 (which decides) never."""
    from fmu_plant import Plant

    for delay in (0, -1):
        ctrl = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=delay), theta0)
        plant, ref = Plant(seed=0), SineReference()
        ctrl.reset(plant.measurement.l_mm)
        checked = []
        for k in range(ctrl.delay_check_samples + 5):
            checked.append(ctrl.delay_checked)
            plant.step(ctrl.step(plant.measurement.l_mm, ref.preview(k, ctrl.settings.preview_samples)).u_v, 0.1)
        checked.append(ctrl.delay_checked)
        if delay == -1:
            assert not any(checked)
        else:
            first = checked.index(True)
            assert ctrl.delay_check_samples <= first <= ctrl.delay_check_samples + 5 and all(checked[first:])
            assert ctrl.delay_evidence is None  # the nominal rig in a sequential loop: 0 is right


def test_the_constraint_region_is_checked_when_the_settings_are_made(theta0):
    """A bound on one side only is a half-open C (it raised a bare KeyError: 'b1'); an inverted box,
    an unknown name or a NaN is refused by ControllerSettings, naming it (an inverted one was
    reported as theta0 lying outside C)."""
    lower_only = ControllerSettings(method="ampc_servo", box_lower={"b1": 0.01}, box_upper={})
    lo, hi = lower_only.constraint_region()
    assert lo[ASYMMETRIC.index("b1")] == 0.01 and np.isinf(hi).all() and np.isneginf(np.delete(lo, 2)).all()
    far = dict(zip(ASYMMETRIC.names, theta0)) | {"b1": 5.0}
    assert DisplacementController(lower_only, far).theta0[2] == 5.0
    with pytest.raises(ValueError, match=r"theta0's b1 = 0.005 lies outside the constraint region C, 0.01..inf") as e:
        DisplacementController(lower_only, far | {"b1": 0.005})
    assert "another sampling period" not in str(e.value)  # a box of one's own: its period is one's own
    for lower, upper, message in (({"b1": 1.0}, {"b1": 0.1}, r"box_lower\['b1'\]=1.0 > box_upper\['b1'\]=0.1"),
                                  ({"b2": 1.0}, {}, "box_lower names unknown parameter 'b2'"),
                                  ({"b1": math.nan}, {}, r"box_lower\['b1'\] must not be NaN"),
                                  ([0.0] * 15, [1.0] * 15, "must be mappings of parameter name to bound")):
        with pytest.raises(ValueError, match=message):
            ControllerSettings(method="ampc_servo", box_lower=lower, box_upper=upper)


@pytest.fixture(scope="module")
def open_loop_theta_03mpa():
    """theta0 identified open loop (``tm.identify`` on a 240-s sine) on a 0.3-MPa rig at 30 N, and
    that rig: a poor fixed law for the start-up mode's warm-up."""
    from fmu_controller.identification import identify_record as identify
    from tapmuscle.api import simulate

    rig = PlantParams().with_values(**{"supply.supply_pressure_mpa": 0.3})
    rec = simulate("sine:bias=5,amp=3,freq=0.1", duration_s=240.0, ts_s=0.1, load_n=30.0, params=rig, seed=0)
    return identify(rec["u_v"], rec["l_mm"], ts_s=0.1).theta, rig


@pytest.fixture
def unbounded_notch(monkeypatch):
    """The notch's predictions without their bound: a law that slams the valve in the warm-up on the
    open-loop theta0 below (the bound alone tames that one:
    test_the_notchs_bound_tames_an_open_loop_theta0_without_the_guard), for the guard to act on."""
    import fmu_controller.displacement_control as dc

    monkeypatch.setattr(dc, "NOTCH_FLOOR_MM", 1e300)


def test_the_notchs_bound_tames_an_open_loop_theta0_without_the_guard(open_loop_theta_03mpa):
    """On the open-loop theta0 of a 0.3-MPa rig the warm-up's notch predicted H of thousands of mm and
    slammed the valve (21 full-range jumps in 12 s, Eq. (21) 6.65 mm without the guard); with the
    bound, 2 jumps and 0.24 mm (seeds 0-2: 0.241-0.256), and the guard has nothing to fire on."""
    theta, rig = open_loop_theta_03mpa
    plant = Plant(rig, seed=0)
    plant.update(load_n=30.0)
    ctrl = DisplacementController(ControllerSettings(method="ampc_servo", startup_guard=False, input_delay_samples=0),
                                  theta)
    run = run_closed_loop(plant, ctrl, SineReference(frequency_hz=0.1), duration_s=45.0)
    assert eq21_error_mm(run["r_mm"], run["l_mm"]) < 0.5 and np.abs(run["h_mm"]).max() < 200.0
    assert np.count_nonzero(np.abs(np.diff(run["u_v"][:120])) > 9.0) <= 4


@pytest.mark.parametrize("input_delay", [0, -1])
def test_the_startup_guard_hands_a_slamming_law_to_the_estimate(open_loop_theta_03mpa, unbounded_notch, input_delay):
    """With an open-loop theta0 of a 0.3-MPa rig and the notch unbounded, AMPC-servo's warm-up on
    theta0 slammed the valve end to end and the cancelled H grew to thousands of mm: Eq. (21) 6.65 mm
    (12.5 with -1). The guard hands the law to the estimate after GUARD_JUMPS full-range jumps
    (measured 0.29 mm; with -1, whose guard starts over at the delay's decision, 0.25-0.81 mm by the
    BLAS's last bits: OpenBLAS 0.3.30 or 0.3.31, Nehalem or Haswell kernels)."""
    theta, rig = open_loop_theta_03mpa
    errors, fired = {}, {}
    for guard in (True, False):
        plant = Plant(rig, seed=0)
        plant.update(load_n=30.0)
        ctrl = DisplacementController(ControllerSettings(method="ampc_servo", startup_guard=guard,
                                                         input_delay_samples=input_delay), theta)
        run = run_closed_loop(plant, ctrl, SineReference(frequency_hz=0.1), duration_s=45.0)
        errors[guard], fired[guard] = eq21_error_mm(run["r_mm"], run["l_mm"]), ctrl.startup_guarded_at
        assert np.all(np.isfinite(run["u_v"])) and run["u_v"].min() >= 0.0 and run["u_v"].max() <= 10.0
    assert fired[False] is None
    if input_delay == 0:  # with -1 the guard starts over when the delay is decided (at 5 s), unfired since
        assert fired[True] is not None and 30 <= fired[True] <= 60  # t = 3-6 s
    assert errors[True] < 1.5 and errors[False] > 3.0 and errors[True] < 0.25 * errors[False], errors


def test_the_startup_guard_is_validated_and_kept_in_the_state(theta0):
    """A setting of True/False only; the jumps counted and the firing sample go through
    get_state/set_state (a rewind continues bit for bit)."""
    with pytest.raises(ValueError, match="startup_guard must be True or False"):
        ControllerSettings(startup_guard=1)
    c = DisplacementController(ControllerSettings(method="ampc_servo"), theta0)
    c.reset(0.0)
    slam = [0.0, 60.0, 0.0, 60.0, 0.0, 60.0, 0.0, 60.0]  # readings that make the warm-up law jump
    for k, l in enumerate(slam):
        c.step(l, [30.0] * c.settings.preview_samples + [30.0])
    saved = c.get_state()
    twin = DisplacementController(ControllerSettings(method="ampc_servo"), theta0)
    twin.set_state(saved)
    assert twin.startup_guarded_at == c.startup_guarded_at and twin.get_state()["guard"] == saved["guard"]
    for l in (10.0, 20.0, 30.0):
        a, b = c.step(l, [30.0] * 7), twin.step(l, [30.0] * 7)
        assert a.u_v == b.u_v and np.array_equal(a.theta, b.theta)
    for bad in ([-1, None], [0, 10 ** 6], [1.5, None]):
        with pytest.raises(ValueError, match="state field guard"):
            twin.set_state(saved | {"guard": bad})


def test_the_step_that_fires_the_guard_ran_on_theta0(open_loop_theta_03mpa, unbounded_notch):
    """law_on_theta0 (which the FMU's divergence warning reads) is True for the step at which the guard
    fires (its command came from theta0) and False from the next: the warning blamed the estimate."""
    theta, rig = open_loop_theta_03mpa
    plant = Plant(rig, seed=0)
    plant.update(load_n=30.0)
    ctrl = DisplacementController(ControllerSettings(method="ampc_servo"), theta)
    ref = SineReference(frequency_hz=0.1)
    ctrl.reset(plant.measurement.l_mm)
    meas = plant.measurement
    for k in range(200):
        u = ctrl.step(meas.l_mm, ref.preview(k, ctrl.settings.preview_samples)).u_v
        if k < 60:  # the warm-up (T/2 = 6 s), where the guard fires on this rig (t = 3-6 s)
            assert ctrl.law_on_theta0 is (ctrl.startup_guarded_at in (None, k))
        if ctrl.startup_guarded_at is not None and k > ctrl.startup_guarded_at:
            break
        meas = plant.step(u, 0.1)
    assert ctrl.startup_guarded_at is not None and not ctrl.law_on_theta0


def test_the_delay_evidence_of_a_set_delay():
    """With input_delay_samples set, delay_evidence is None before DELAY_CHECK_SAMPLES samples are scored
    and with -1; then the delay DELAY_RATIO times better than the set one and the ratio of their mean
    squares, inf where the better one predicts without error."""
    from fmu_controller.displacement_control import DELAY_CHECK_SAMPLES, DELAY_RATIO

    c = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=0), THETA0_44N)
    c.reset(0.0)
    assert c.delay_evidence is None
    c._scores.compared = DELAY_CHECK_SAMPLES
    c._scores.ms = [1.0, 0.5, 2.0, 2.0, 2.0, 2.0]
    assert c.delay_evidence == (1, 2.0)
    c._scores.ms = [1.0, 1.0 / DELAY_RATIO, 2.0, 2.0, 2.0, 2.0]  # not better by the ratio
    assert c.delay_evidence is None
    c._scores.ms = [1.0, 0.0, 2.0, 2.0, 2.0, 2.0]
    assert c.delay_evidence == (1, math.inf)
    auto = DisplacementController(ControllerSettings(method="ampc_servo", input_delay_samples=-1), THETA0_44N)
    auto.reset(0.0)
    auto._scores.compared = DELAY_CHECK_SAMPLES
    assert auto.delay_evidence is None


# ------------------------------------------------------------------ glitch guard
def _spiked_run(theta0, method, spike_mm, *, guard=True, k_spike=300, width=1, n=601, seed=0, save_at=None,
                real=None):
    """A loop on the simulated rig whose readings are ``spike_mm`` off for ``width`` samples from
    ``k_spike``: the real displacement, the commands and the samples the guard held (``real``: a list
    given the samples that found the one held before the muscle's own)."""
    plant = Plant(seed=seed)
    s = ControllerSettings(method=method, max_speed_mm_per_s=DEFAULT_MAX_SPEED_MM_PER_S if guard else 0.0)
    c = DisplacementController(s, theta0)
    ref = SineReference()
    l = plant.measurement.l_mm
    c.reset(l)
    ls, us, held, saved = [], [], [], None
    for k in range(n):
        if k == save_at:
            saved = c.get_state()
        step = c.step(l + (spike_mm if k_spike <= k < k_spike + width else 0.0), ref.preview(k, s.preview_samples))
        if c.reading_held is not None:
            held.append(k)
        if real is not None and c.held_reading_real is not None:
            real.append(k)
        ls.append(l)
        us.append(step.u_v)
        plant.step(step.u_v, s.ts_s)
        l = plant.measurement.l_mm
    return np.array(ls), np.array(us), held, saved, c


@pytest.mark.parametrize("method", ["ampc_servo", "ampc_ucp", "mpc_servo"])
def test_a_reading_50_mm_off_for_one_sample_is_held_and_the_loop_does_not_notice(theta0, method):
    """Without the guard the valve goes to a limit and the muscle really moves 15 mm or more in a sample;
    with it the sample's reading is replaced by the prediction, and the real motion and commands stay
    within what the undisturbed loop does."""
    ls0, us0, held0, _, _ = _spiked_run(theta0, method, 0.0)
    ls, us, held, _, _ = _spiked_run(theta0, method, 50.0)
    lsx, usx, heldx, _, _ = _spiked_run(theta0, method, 50.0, guard=False)
    assert held0 == [] and held == [300] and heldx == []
    window = slice(299, 320)
    assert np.max(np.abs(np.diff(lsx[window]))) > 10.0  # the unguarded loop jumps
    assert np.max(np.abs(np.diff(ls[window]))) < np.max(np.abs(np.diff(ls0[window]))) + 1.0
    assert np.max(np.abs(us[300:310] - us0[300:310])) < 1.0
    # 10-30 s after it the guarded loop tracks as the undisturbed one (within 20 %), the unguarded adaptive ones not
    ref = np.array([SineReference().at(k) for k in range(len(ls))])
    after = slice(400, 600)
    e0, e, ex = (float(np.mean(np.abs(ref - x)[after])) for x in (ls0, ls, lsx))
    assert e <= 1.2 * e0 + 0.005
    if method.startswith("ampc"):
        assert ex > 2.0 * e0


def test_a_lasting_offset_is_taken_as_the_new_level_after_three_held_readings(theta0):
    """An encoder re-zeroed by +60 mm is not a glitch: three readings are held, the fourth is used, and
    the controller follows the readings from then on (every later one is used)."""
    _, _, held, _, c = _spiked_run(theta0, "ampc_servo", 60.0, width=10_000)
    assert held == [300, 301, 302] and HELD_READINGS_MAX == 3


def test_the_guard_is_off_at_zero_and_validated(theta0):
    assert ControllerSettings().max_speed_mm_per_s == DEFAULT_MAX_SPEED_MM_PER_S == 400.0
    for bad in (-1.0, math.inf, math.nan, "fast"):
        with pytest.raises((ValueError, TypeError), match="max_speed_mm_per_s"):
            ControllerSettings(max_speed_mm_per_s=bad)
    # the paper's run never comes near the bound: every reading used, bit for bit the run without the guard
    _, us, held, _, _ = _spiked_run(theta0, "ampc_servo", 0.0)
    _, us_off, _, _, _ = _spiked_run(theta0, "ampc_servo", 0.0, guard=False)
    assert held == [] and np.array_equal(us, us_off)


def test_a_state_saved_while_readings_are_held_replays_bit_identically(theta0):
    """The count of readings held in a row is part of the state: restored mid-hold, the controller
    holds the same readings and gives the same commands."""
    plant_ls, us, held, saved, c = _spiked_run(theta0, "ampc_servo", 60.0, width=10_000, save_at=301)
    assert saved["held_in_a_row"] == 1
    c2 = DisplacementController(c.settings, theta0)
    c2.reset(0.0)
    c2.set_state(saved)
    ref = SineReference()
    again = [c2.step(plant_ls[k] + 60.0, ref.preview(k, c.settings.preview_samples)).u_v for k in range(301, 320)]
    assert again == us[301:320].tolist()


@pytest.mark.parametrize("jump_mm, held", [(39.0, False), (41.0, True)])
def test_the_glitch_guard_bound_is_max_speed_times_ts(jump_mm, held):
    """The bound is max_speed_mm_per_s x ts_s (40 mm at the defaults), and a held reading is replaced by
    the one-step prediction made at the sample before."""
    from fmu_controller.displacement_control import ControllerSettings, DisplacementController
    from fmu_controller.reference import SineReference
    from fmu_controller.preliminary_model import THETA0_44N
    s = ControllerSettings(method="mpc_servo")          # 400 mm/s x 0.1 s = 40 mm
    c = DisplacementController(s, THETA0_44N)
    ref = SineReference()
    c.reset(20.0)
    for k in range(50):
        prediction = c.step(20.0, ref.preview(k, s.preview_samples)).predicted_next_mm
    c.step(20.0 + jump_mm, ref.preview(50, s.preview_samples))
    assert (c.reading_held is not None) == held
    if held:
        reading, used, last = c.reading_held
        assert reading == 20.0 + jump_mm and last == 20.0 and used == prediction


# ------------------------------------------------------------------ stuck reading
def _frozen_run(method, *, freeze_at=200, n=500, params=None, reference=None, save_at=None, **settings):
    """A loop on the simulated rig whose readings stop changing from sample ``freeze_at`` on (None:
    never): the samples where ``reading_stuck`` was set with what it said, the commands, and the
    controller's state saved before sample ``save_at``."""
    plant = Plant(params, seed=0)
    s = ControllerSettings(method=method, **settings)
    c = DisplacementController(s, THETA0_44N)
    ref = SineReference() if reference is None else reference
    l = plant.measurement.l_mm
    c.reset(l)
    told, us, readings, saved = [], [], [], None
    for k in range(n):
        if k == save_at:
            saved = c.get_state()
        reading = readings[freeze_at] if freeze_at is not None and k > freeze_at else l
        readings.append(reading)
        step = c.step(reading, ref.preview(k, s.preview_samples))
        if c.reading_stuck is not None:
            told.append((k, c.reading_stuck))
        us.append(step.u_v)
        plant.step(step.u_v, s.ts_s)
        l = plant.measurement.l_mm
    return told, np.array(us), readings, saved, c


@pytest.mark.parametrize("method", METHODS)
def test_a_reading_that_stops_changing_is_told_once_as_stuck(method):
    """Readings frozen at t = 20 s under the paper's sine: every controller's valve goes end to end
    (the error never closes) and the muscle swings over its whole range unseen; once the command has
    sat at each limit for STUCK_AT_LIMIT_S within the unchanged stretch, reading_stuck says the reading
    and how long it has not changed, once."""
    told, us, readings, _, _ = _frozen_run(method)
    (k, (reading, unchanged_s)), = told
    assert reading == readings[200]
    assert unchanged_s == pytest.approx((k - 200) * 0.1)
    # each limit for 2 s or more: at least 4 s after the freeze; the sine's 5-s half periods bound it
    assert 2 * STUCK_AT_LIMIT_S <= unchanged_s <= 12.0
    assert np.mean((us[200:] <= 1e-9) | (us[200:] >= 10.0 - 1e-9)) > 0.6


@pytest.mark.parametrize("method", ["ampc_servo", "mpc_ucp"])
@pytest.mark.parametrize("case", ["out_of_reach", "below_rest", "delay_0.3_s", "backlash_2_mm", "68_N_steps"])
def test_a_muscle_that_really_stays_still_is_not_stuck(method, case):
    """No stuck reading where the muscle really does not move under a command held at a limit, with an
    encoder without noise (a still muscle reads the same to the bit): a reference beyond full
    contraction (10 V for 40 s at the end stop), one below the rest length (0 V at rest), a 0.3-s
    transport delay and a 2-mm backlash in the encoder (readings that lag the valve), steps at 68 N."""
    quiet = {"sensor.encoder_noise_std_mm": 0.0}
    params, reference = PlantParams().with_values(**quiet), None
    if case == "out_of_reach":
        reference = ArrayReference(np.full(700, 150.0))
    elif case == "below_rest":
        reference = ArrayReference(np.full(700, -20.0))
    elif case == "delay_0.3_s":
        params = params.with_values(**{"delay.delay_s": 0.3})
    elif case == "backlash_2_mm":
        params = params.with_values(**{"backlash.slack_mm": 2.0})
    else:
        params = params.with_values(**{"load.load_n": 68.0})
        reference = ArrayReference(np.repeat([10.0, 80.0, 0.0, 60.0, 150.0, 20.0, 20.0], 100))
    told, us, readings, _, _ = _frozen_run(method, freeze_at=None, n=600, params=params, reference=reference)
    assert told == []
    if case == "out_of_reach":  # the case is what it says: the valve held open, the reading unchanged
        assert np.all(us[200:] >= 10.0 - 1e-9) and len(set(readings[300:])) == 1
    if case == "below_rest":
        assert np.all(us[100:] <= 1e-9) and len(set(readings[100:])) == 1


def test_a_state_saved_in_a_stuck_stretch_tells_it_at_the_same_sample():
    """The stretch of unchanged readings is part of the state: restored within it, the controller tells
    the stuck reading at the same sample; a state saved without it starts a new stretch; a stretch no
    controller could have saved is refused by name."""
    told, us, readings, saved, c = _frozen_run("ampc_servo", save_at=230)
    assert saved["still"][0] == readings[200] and saved["still"][1] == 29
    c2 = DisplacementController(c.settings, THETA0_44N)
    c2.reset(0.0)
    c2.set_state(saved)
    again, ref = [], SineReference()
    for k in range(230, 500):
        u = c2.step(readings[k], ref.preview(k, c.settings.preview_samples)).u_v
        assert u == us[k]
        if c2.reading_stuck is not None:
            again.append((k, c2.reading_stuck))
    assert again == told
    old = {key: value for key, value in saved.items() if key != "still"}
    c2.set_state(old)
    assert c2.get_state()["still"][1:] == [0, 0, 0, False]
    for bad in ([math.nan, 3, 2, 2, False], [1e9, 3, 1, 1, False], [20.0, -1, 0, 0, False], [20.0, 3, 1, 1, "no"],
                [20.0, 3.5, 1, 1, False], [20.0, 3, 1], "still"):
        with pytest.raises(ValueError, match="state field still"):
            c2.set_state({**saved, "still": bad})
    c2.set_state({**saved, "still": [math.nan, 0, 0, 0, False]})  # before the first step


def test_the_start_on_a_delayed_rig_overshoots_on_a_theta0_made_without_the_delay():
    """A 0.3-s transport delay, 3 samples set: on THETA0_44N (identified without the delay) the start
    overshoots the reference by about 30 mm at the end of its lead-in; on a theta0 identified under
    the delay (docs/control.md, "Transport delay") by a few mm, and the loop tracks better after it."""
    rig = PlantParams().with_values(**{"delay.delay_s": 0.3})
    settings = ControllerSettings(method="ampc_servo", input_delay_samples=3)

    def run(theta):
        cols = run_closed_loop(Plant(rig, seed=0), DisplacementController(settings, theta), None, duration_s=45.0,
                               watch=False)
        return float(np.max(cols["l_mm"] - cols["r_mm"])), eq21_error_mm(cols)

    (excess0, eq21_0), (excess, eq21) = run(THETA0_44N), run(preliminary_theta(0, refine_hz=0.1, params=rig,
                                                                                  input_delay_samples=3))
    assert excess0 > 20.0 and excess < 8.0
    assert eq21 < eq21_0


def test_a_stuck_reading_is_told_at_the_coincidence_points_own_valve_limits():
    """AMPC-UCP keeping the valve within 1..8 V (UCPSettings' bounds, not the servo's 0..10 V): a reading
    frozen at 20 s is told as with the full range (the watch looked at the servo's limits, which this
    law never reaches, and said nothing)."""
    told, us, _, _, _ = _frozen_run("ampc_ucp", ucp=UCPSettings(u_min_v=1.0, u_max_v=8.0))
    assert np.mean((us[200:] <= 1.0 + 1e-9) | (us[200:] >= 8.0 - 1e-9)) > 0.6 and us.max() <= 8.0
    (k, _), = told
    assert 240 <= k <= 320


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("spike_mm", [-30.0, 12.0])
def test_a_spike_under_the_speed_bound_is_held_as_a_spike(theta0, method, spike_mm):
    """A potentiometer's one-sample spike of 12 or 30 mm is within the 40 mm the muscle could move in a
    sample, which the max_speed bound lets through (a 30-mm one, used, moves the muscle by 30-40 mm).
    From 5 s after the start-up on it is further from the one-step prediction than SPIKE_MM and
    SPIKE_SPREAD times the usual error: held once as a spike, the real motion stays within 0.5 mm of
    the undisturbed loop's."""
    from fmu_controller.displacement_control import SPIKE_MM

    ls0, us0, _, _, _ = _spiked_run(theta0, method, 0.0)
    real = []
    ls, us, held, _, c = _spiked_run(theta0, method, spike_mm, real=real)
    assert held == [300] and abs(spike_mm) > SPIKE_MM  # a spike the max_speed bound lets through
    assert real == []  # the next reading back on the model's track: the sensor's spike
    # one of two samples: its second lies by the first and passes, and the verdict says the fault lasted
    real = []
    _, _, held, _, c = _spiked_run(theta0, method, spike_mm, width=2, n=302, real=real)
    assert held == [300] and real == [301] and c.held_reading_real[0] == "spike"
    assert "or the sensor's fault lasts (a spike or repeat of two samples or more)" in real_move_message(*c.held_reading_real)
    assert np.max(np.abs(ls - ls0)) < 0.5
    # in the start-up and the 5 s after it (the estimate still learning) a spike is used; a 39-mm one at
    # 2.4 s, the muscle rising, leaves the next reading more than 40 mm from it: that reading, within
    # reach of the one before the spike, is used too, not held as if the spike were the level
    ls0, _, _, _, _ = _spiked_run(theta0, method, 0.0, n=40)
    assert abs(ls0[25] - (ls0[24] - 39.0)) > DEFAULT_MAX_SPEED_MM_PER_S * 0.1
    _, _, held_early, _, _ = _spiked_run(theta0, method, -39.0, k_spike=24, n=40)
    assert held_early == []


def test_the_spike_guard_holds_nothing_in_the_papers_runs_and_its_state_restores(theta0):
    """No reading of the paper's runs (every method, 45 s) nor of staircases stepping every 5 s by 15-30
    mm (steps under the muscle's 20 mm a sample among them) is held; the guard's state is part of the
    controller's, and a state saved without it starts it anew."""
    for method in METHODS:
        _, _, held, _, _ = _spiked_run(theta0, method, 0.0, n=451)
        assert held == [], method
    for step_mm in (15.0, 19.0, 20.0, 30.0):
        ref = np.repeat([30.0, 30.0 + step_mm] * 5, 50)
        for method in METHODS:
            c = DisplacementController(ControllerSettings(method=method), theta0)
            plant = Plant(seed=1)
            c.reset(plant.measurement.l_mm)
            held = []
            for k in range(len(ref) - c.settings.preview_samples):
                step = c.step(plant.measurement.l_mm, ref[k:k + c.settings.preview_samples + 1])
                if c.reading_held is not None:
                    held.append(k)
                plant.step(step.u_v, 0.1)
            assert held == [], (step_mm, method, held)
            assert c.get_state()["spike"][0] > 0.0
    plant_ls, us, held, saved, c = _spiked_run(theta0, "ampc_servo", -30.0, save_at=290)
    c2 = DisplacementController(c.settings, theta0)
    c2.reset(0.0)
    c2.set_state(saved)
    ref = SineReference()
    again = [c2.step(plant_ls[k] + (-30.0 if k == 300 else 0.0), ref.preview(k, c.settings.preview_samples)).u_v
             for k in range(290, 320)]
    assert again == us[290:320].tolist() and held == [300]
    c2.set_state({k: v for k, v in saved.items() if k != "spike"})
    assert _same(c2.get_state()["spike"], [math.nan, math.nan, 0, math.nan, math.nan])
    for bad in ([-1.0, 0.0, 0, 0.0, 0.0], [0.1, 0.1, 0, math.inf, 0.0], [0.1, 0.1, 1.5, 0.0, 0.0], [0.1, 0.1, 0, 0.0]):
        with pytest.raises(ValueError, match="state field spike"):
            c2.set_state({**saved, "spike": bad})


def _stale_run(theta0, method, stale=(), *, guard=True, n=601, params=None, reference=None, record=None, real=None):
    """A loop on the simulated rig in which the readings of the samples ``stale`` repeat the reading fed
    before (a data acquisition that delivered its last value again): the real displacement, the
    samples whose reading was held, and the controller (``record``: a dict given the readings fed,
    the commands and the controller's state before each sample; ``real``: a list given the samples
    that found the one held before the muscle's own)."""
    plant = Plant(params or PlantParams(), seed=0)
    s = ControllerSettings(method=method, max_speed_mm_per_s=DEFAULT_MAX_SPEED_MM_PER_S if guard else 0.0)
    c = DisplacementController(s, theta0)
    preview = reference or SineReference().preview
    l = plant.measurement.l_mm
    c.reset(l)
    ls, held, fed = [], [], None
    for k in range(n):
        fed = fed if k in stale and fed is not None else l
        if record is not None:
            record.setdefault("states", []).append(c.get_state())
        step = c.step(fed, preview(k, s.preview_samples))
        if record is not None:
            record.setdefault("fed", []).append(fed)
            record.setdefault("u", []).append(step.u_v)
        if c.reading_held is not None:
            held.append(k)
        if real is not None and c.held_reading_real is not None:
            real.append(k)
        ls.append(l)
        plant.step(step.u_v, s.ts_s)
        l = plant.measurement.l_mm
    return np.array(ls), held, c


@pytest.mark.parametrize("method", METHODS)
def test_a_reading_repeated_by_a_stale_acquisition_where_the_muscle_moves_is_replaced_by_the_prediction(theta0, method):
    """One repeat at the sine's fastest point (1.9 mm a sample): the law would push the valve for a move
    that happened, and the muscle ends 1.8-2.5 mm off its undisturbed path; the repeat is taken for a
    stale sample and the prediction used (0.03-0.46 mm measured). Repeats in a row: the first only
    (a muscle that stopped reads the same again), and the message says what was seen."""
    base, held0, _ = _stale_run(theta0, method)
    real = []
    ls, held, c = _stale_run(theta0, method, {300}, real=real)
    unguarded, held_x, _ = _stale_run(theta0, method, {300}, guard=False)
    assert held0 == [] and held == [300] and held_x == [] and real == []
    assert np.max(np.abs(ls - base)) < 0.6 and np.max(np.abs(unguarded - base)) > 1.5
    _, held, _ = _stale_run(theta0, method, set(range(300, 305)), n=305)
    assert held == [300]
    _, _, c = _stale_run(theta0, method, {300}, n=301)
    reading, used, last = c.reading_held
    assert reading == last and abs(used - reading) > 1.0
    told = held_reading_message(c.settings, reading, used, last, None)
    assert told.startswith(f"the reading l = {reading:g} mm repeats the last one to the bit while the one-step "
                           f"prediction has the muscle move {abs(used - last):.3g} mm") and "stale sample" in told


def test_a_muscle_stopped_short_by_backlash_is_not_taken_for_a_stale_reading():
    """0.8 mm of backlash: at a reversal the encoder stands still while the slack is taken up, and
    AMPC-servo's prediction overran it by 0.53 mm at 27.8 s (noise seed 1), 3.5 times its mean error (a
    threshold of 0.5 mm and 3 times held that reading and told a stale sample of the data acquisition)."""
    rig = PlantParams().with_values(**{"backlash.slack_mm": 0.8})
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        run_closed_loop(Plant(rig, seed=1), DisplacementController(ControllerSettings(method="ampc_servo"), THETA0_44N),
                        SineReference(), duration_s=60.0)
    assert not [w for w in said if "repeated the last one" in str(w.message)]


def test_a_controller_restored_before_a_stale_repeat_holds_it_and_commands_as_the_first_bit_for_bit(theta0):
    """The repeat guard keeps no state of its own beyond the controller's (the last reading, the spike
    guard's mean error and wait): restored at 29.5 s, fed the same readings, it holds the same repeat
    and gives the same commands to the bit."""
    record = {}
    _, held, c = _stale_run(theta0, "ampc_servo", {300}, n=320, record=record)
    assert held == [300]
    c2 = DisplacementController(c.settings, theta0)
    c2.reset(0.0)
    c2.set_state(record["states"][295])
    again, held2, ref = [], [], SineReference()
    for k in range(295, 320):
        again.append(c2.step(record["fed"][k], ref.preview(k, c.settings.preview_samples)).u_v)
        if c2.reading_held is not None:
            held2.append(k)
    assert held2 == [300] and again == record["u"][295:320]


@pytest.mark.parametrize("method", METHODS)
def test_the_repeat_guard_holds_no_reading_of_a_muscle_that_really_stops(theta0, method):
    """Readings that repeat because the muscle stands still: at its end stop under a reference out of its
    reach, at rest under 0 mm, read without encoder noise, or by a 0.1-mm encoder; a rig whose
    constants are 10-18 % off on a staircase (a muscle held by friction after a step stops short of
    the prediction). None is held."""
    exact = PlantParams().with_values(**{"sensor.encoder_noise_std_mm": 0.0, "sensor.encoder_resolution_mm": 0.0})
    coarse = PlantParams().with_values(**{"sensor.encoder_resolution_mm": 0.1})
    off = PlantParams().with_values(**{"muscle.rubber_stiffness_n_per_mm": 0.87 * PlantParams().muscle.rubber_stiffness_n_per_mm,
                                       "muscle.radius_mm": 0.86 * PlantParams().muscle.radius_mm,
                                       "friction.base_n": 1.11 * PlantParams().friction.base_n})
    far = lambda k, n: np.full(n + 1, 200.0)  # noqa: E731
    rest = lambda k, n: np.zeros(n + 1)  # noqa: E731
    stair = lambda k, n: np.array([30.0 + 20.0 * (((k + i) // 50) % 2) for i in range(n + 1)])  # noqa: E731
    for params, reference in ((None, far), (None, rest), (exact, None), (exact, far), (coarse, None), (off, stair)):
        _, held, _ = _stale_run(theta0, method, params=params, reference=reference)
        assert held == [], (params, reference)


@pytest.mark.parametrize("method", METHODS)
def test_a_sensor_spiking_every_two_seconds_is_guarded_no_worse_than_unguarded(theta0, method):
    """30-mm spikes every 2 s from 6 s on (benchmarks/frequent_spikes.py): counted whole in the guard's
    mean error they raised its limit beyond 30 mm (AMPC-servo held none: 2.7 mm mean |r - l|), and the
    real readings after a spike used were held as glitches (the fixed predictors did worse guarded than
    unguarded, 3.1 against 1.7 mm and 5.4 against 4.3). Guarded, every method tracks at least as well as
    unguarded, and the servo laws and AMPC-UCP, which hold the spikes, at least a third better."""
    def run(guard):
        s = ControllerSettings(method=method, max_speed_mm_per_s=DEFAULT_MAX_SPEED_MM_PER_S if guard else 0.0)
        c, plant, ref = DisplacementController(s, theta0), Plant(seed=0), SineReference()
        c.reset(plant.measurement.l_mm)
        errors, held = [], 0
        for k in range(901):
            l = plant.measurement.l_mm
            if k > 60 and k % 20 == 0:
                l = l - 30.0 if l > 32.0 else l + 30.0
            step = c.step(l, ref.preview(k, s.preview_samples))
            held += c.reading_held is not None
            if k >= 300:
                errors.append(abs(ref.at(k) - plant.l_mm))
            plant.step(step.u_v, s.ts_s)
        return float(np.mean(errors)), held

    (guarded, held), (unguarded, _) = run(True), run(False)
    assert guarded <= unguarded + 0.05
    if method != "mpc_ucp":  # its law answers each spike used in the start-up so hard that the guard keeps waiting
        assert held >= 20 and guarded < 0.67 * unguarded


@pytest.mark.parametrize("method", METHODS)
def test_a_supply_lost_and_back_is_told_the_muscles_own_move_by_the_reading_after(theta0, method):
    """The tap shut at 30 s (0.25 -> 0 MPa) and opened again at 40 s: the muscle drains, or fills, and
    leaves its model's track by 15 mm within a sample. One sample cannot tell that from a sensor's
    spike, and the guard holds it; the reading after stays by the held one, far from the prediction,
    and tells it the muscle's own, for every hold; after it the guards wait, so that the drained
    muscle's standstill is not held as stale samples."""
    plant = Plant(seed=0)
    c = DisplacementController(ControllerSettings(method=method), theta0)
    ref = SineReference()
    c.reset(plant.measurement.l_mm)
    held, real = [], []
    for k in range(600):
        if k in (300, 400):
            plant.update(supply_pressure_mpa=0.0 if k == 300 else 0.25)
        step = c.step(plant.measurement.l_mm, ref.preview(k, c.settings.preview_samples))
        if c.reading_held is not None:
            held.append(k)
        if c.held_reading_real is not None:
            kind, held_mm, reading, predicted = c.held_reading_real
            assert abs(reading - held_mm) < abs(reading - predicted) and abs(reading - predicted) > 1.0
            real.append(k)
        plant.step(step.u_v, 0.1)
    assert 301 in held and held and [k + 1 for k in held] == real


@pytest.mark.parametrize("method", ["mpc_servo", "ampc_servo"])
def test_a_glitch_beyond_the_bound_during_a_fast_move_is_held(theta0, method):
    """Steps 30 <-> 70 mm: at the fastest sample of the move (10-13 mm a sample) a reading 50-55 mm behind
    the motion is beyond the 40-mm bound from the last reading but within it of the one before. The
    last reading was its prediction's, no spike: the glitch is held, and the muscle stays within a
    few millimetres of its undisturbed run."""
    ref = np.repeat([30.0, 70.0, 30.0, 70.0], 100)

    def run(glitch_k: int, glitch_mm: float):
        c = DisplacementController(ControllerSettings(method=method), theta0)
        p = Plant(seed=0)
        c.reset(p.measurement.l_mm)
        ls, held = [], []
        for k in range(300):
            step = c.step(p.measurement.l_mm + (glitch_mm if k == glitch_k else 0.0),
                          ref[k:k + c.settings.preview_samples + 1])
            if c.reading_held is not None:
                held.append(k)
            ls.append(p.l_mm)
            p.step(step.u_v, 0.1)
        return np.array(ls), held

    base, _ = run(-1, 0.0)
    d = np.diff(base[195:215])
    k = 195 + int(np.argmax(np.abs(d))) + 1
    move, bound = base[k] - base[k - 1], DEFAULT_MAX_SPEED_MM_PER_S * 0.1
    # between the bound from the last reading and the bound from the one before (50-55 mm)
    glitch = -np.sign(move) * (bound + 0.5 * (abs(move) + abs(base[k] - base[k - 2])))
    assert abs(move) > 8.0 and abs(base[k] + glitch - base[k - 1]) > bound >= abs(base[k] + glitch - base[k - 2])
    ls, held = run(k, glitch)
    assert held == [k]
    assert np.max(np.abs(ls - base)) < 9.0


def test_the_coincidence_points_own_valve_limits_bound_the_probe(theta0):
    """The start-up probe and the guard's jumps are judged against the method's own limits: AMPC-UCP
    with ucp.u_max_v = 4 V must not send more (the probe clipped to the servo's 10 V gives 4.5 V on 22
    of its first 60 samples)."""
    settings = ControllerSettings(method="ampc_ucp", ucp=UCPSettings(u_max_v=4.0))
    run = run_closed_loop(Plant(seed=0), DisplacementController(settings, theta0), SineReference(), duration_s=12.0,
                          watch=False)
    assert run["u_v"].max() <= 4.0 and np.sum(run["u_v"] == 4.0) > 10  # at its limit, and not beyond


def test_minus_one_takes_a_delay_of_two_or_more_only_where_the_scores_fall_to_it_from_zero(theta0):
    """A transport delay's scores fall from 0 through 1 to it. Where 1 scores worse than 0 and a longer
    delay best, the loop repeats its command (a chatter of that period): on a rig with constants off,
    a valve band and a drift, MPC-UCP at 68 N, 0.1 Hz decided 2 there (scores 1.31, 1.86, 1.0 times the
    best for 0, 1, 2) and tracked to 1.60 mm against 1.18 with 0, the rig having no delay (a rig owner's
    study, 2026-12-06); on 256 nominal runs (4 methods, 44/68 N, 0.1/0.2 Hz, delays 0-0.35 s, sequential
    and parallel) no decision moved."""
    c = DisplacementController(ControllerSettings(method="mpc_ucp", input_delay_samples=-1), theta0)
    c._scores.ms = [1.31, 1.86, 1.0, 1.39, 1.24, 1.42]
    assert list(c._scores.valley_beyond_one()) == []
    c._scores.ms = [1.54, 1.21, 1.0, 1.36, 2.04, 2.69]  # a rig's 0.21-s delay
    assert list(c._scores.valley_beyond_one()) == [2]
    rig = PlantParams().with_values(**{
        "friction.asymmetry": 0.369248, "valve.cv_max": 1.281181, "load.moving_mass_kg": 0.338404,
        "muscle.braid_angle_deg": 19.752245, "valve.spool_time_constant_s": 0.027425,
        "friction.presliding_mm": 1.61815, "sensor_drift.offset_mm": -1.404, "sensor_drift.rate_mm_per_min": 2.825,
        "dead_zone.center_v": 3.868, "dead_zone.width_v": 1.238, "load.load_n": 68.0})
    ctrl = DisplacementController(ControllerSettings(method="mpc_ucp", input_delay_samples=-1), theta0)
    run_closed_loop(Plant(rig, seed=4), ctrl, SineReference(frequency_hz=0.1), duration_s=10.0, watch=False)
    assert ctrl.input_delay_decision == 0


def test_minus_one_takes_a_delay_outside_the_valley_that_explains_the_data_twice_as_well(theta0):
    """A rig's 0.4-s delay under MPC-UCP at 68 N, 0.2 Hz scores 5.31, 3.67, 4.77, 2.86, 1, 3.0 times the
    best for 0..5: the walk stops at 1 (the bump at 2), but 4 explains the data 3.7 times better than 0
    and 1 (DELAY_CLEAR_RATIO): decided 4, tracking to 3.8 mm where 1 limit-cycled at 11 mm."""
    rig = PlantParams().with_values(**{"delay.delay_s": 0.4, "load.load_n": 68.0})
    ctrl = DisplacementController(ControllerSettings(method="mpc_ucp", input_delay_samples=-1), theta0)
    run_closed_loop(Plant(rig, seed=0), ctrl, SineReference(frequency_hz=0.2), duration_s=10.0, watch=False)
    assert ctrl.input_delay_decision == 4
