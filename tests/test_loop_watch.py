"""The closed loop's supervision (fmu_controller.loop_watch): what it tells, once, and its state."""

import re
from pathlib import Path

import numpy as np
import pytest

import tapmuscle as tm
from fmu_controller.loop_watch import LoopWatch

ROOT = Path(__file__).resolve().parents[1]


def _delayed_loop(n, *, save_at=None, restore=None):
    """AMPC-servo with input_delay_samples = 0 on a rig with a 0.2-s transport delay, watched: the
    messages told and the watch's state before sample ``save_at``; ``restore``: (k, state) to set the
    watch to at sample k, the run before it not watched."""
    rig = tm.PlantParams().with_values(**{"delay.delay_s": 0.2})
    ctrl = tm.DisplacementController(tm.ControllerSettings(input_delay_samples=0), tm.THETA0_44N)
    plant = tm.Plant(rig, seed=0)
    ref = tm.SineReference()
    watch = LoopWatch(ctrl)
    ctrl.reset(plant.measurement.l_mm)
    told, saved, u_prev = [], None, 0.0
    for k in range(n):
        if k == save_at:
            saved = watch.get_state()
        if restore is not None and k == restore[0]:
            watch.set_state(restore[1])
        l, preview = plant.measurement.l_mm, ref.preview(k, ctrl.settings.preview_samples)
        step = ctrl.step(l, preview)
        if restore is None or k >= restore[0]:  # before it, the restored watch has seen nothing
            told += watch.observe(k, k * 0.1, l, preview[0], step, u_prev)
        u_prev = step.u_v
        plant.step(step.u_v, 0.1)
    return told, saved


def test_each_kind_is_told_once_and_a_restored_watch_tells_the_same():
    """Over 60 s the limit cycle and the contradicted delay are told once each (the cycle keeps going);
    a watch restored from a state saved at 12 s tells what the uninterrupted one tells from there; a
    state of a build that watched less (five fields) starts the later watches anew."""
    told, saved = _delayed_loop(601, save_at=120)
    kinds = [m for m in told if "a limit cycle" in m], [m for m in told if "the measurements show an input delay" in m]
    assert [len(k) for k in kinds] == [1, 1], told
    assert all(re.match(r"t = \d+(\.\d+)? s: ", m) for m in told)
    again, _ = _delayed_loop(601, restore=(120, saved))
    assert again == [m for m in told if float(m.split()[2]) >= 12.0]
    # unrestored, the watch that saw nothing before 12 s tells the limit cycle later, or not at all
    fresh, _ = _delayed_loop(601, restore=(120, LoopWatch(tm.DisplacementController(tm.ControllerSettings(),
                                                                                   tm.THETA0_44N)).get_state()))
    assert fresh != again
    watch = LoopWatch(tm.DisplacementController(tm.ControllerSettings(), tm.THETA0_44N))
    watch.set_state(saved[:5])
    assert watch.get_state()[5:] == [0, pytest.approx(np.nan, nan_ok=True), 0, pytest.approx(np.nan, nan_ok=True),
                                     True]


def test_the_real_time_loop_of_the_docs_runs_and_tells_a_stuck_sensor():
    """docs/control.md's loop of one's own ("In a real-time loop"), run on the simulated rig whose
    encoder freezes at 20 s (no sleeping): the watch's message reaches the log it names, once."""
    text = (ROOT / "docs" / "control.md").read_text()
    block = next(b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "tm.LoopWatch(ctrl)" in b)
    plant = tm.Plant(seed=0)
    frozen: list[float] = []
    logged: list[str] = []

    def read_encoder_mm():
        if plant.t_s >= 20.0 - 1e-9:
            frozen[:] = frozen or [plant.measurement.l_mm]
            return frozen[0]
        return plant.measurement.l_mm

    class NoSleep:
        monotonic = staticmethod(lambda: 0.0)
        sleep = staticmethod(lambda s: None)

    namespace = {"read_encoder_mm": read_encoder_mm, "write_valve_v": lambda u: plant.step(u, 0.1),
                 "log_warning": logged.append}
    code = block.replace("import time\n", "")
    exec(compile(code, "docs/control.md", "exec"), {**namespace, "time": NoSleep})
    assert len(logged) == 1 and "has not changed at all" in logged[0] and "the sensor is stuck" in logged[0]


def test_a_limit_cycle_after_minus_one_decided_does_not_send_the_user_back_to_minus_one():
    """-1 decides once and for good; a rig's delay between two samples (or an encoder offset) can make
    it a sample off, and the loop then swings: the message names the decision and the neighbours to
    try, not "-1 decides it", which would send the user back to what went wrong."""
    import dataclasses

    class Decided(tm.DisplacementController):
        input_delay_decision = 2
        in_startup = False
        samples_since_start = 10_000

    ctrl = Decided(tm.ControllerSettings(input_delay_samples=-1), tm.THETA0_44N)
    ctrl.reset(30.0)
    step = ctrl.step(30.0, tm.SineReference().preview(0, ctrl.settings.preview_samples))
    watch = LoopWatch(ctrl)
    told = []
    for k in range(1, 40):  # limit to limit every 2 samples through 5 V: a swing each time, no jump
        u = (0.0, 5.0, 10.0, 5.0)[k % 4]
        told += watch.observe(k, k * 0.1, 30.0, 35.0, dataclasses.replace(step, u_v=u), 5.0)
    (msg,) = told
    assert "a limit cycle (input_delay_samples = -1, decided 2)" in msg
    assert "-1 decided 2 for good" in msg and "try 3 or 1 set" in msg and "-1 decides it" not in msg


def test_a_valve_pinned_at_one_limit_under_a_reading_that_never_changes_names_a_stuck_sensor():
    """A reading frozen at 20 s as the reference steps from 40 to 60 mm: the command sits at 10 V for good (one
    limit: reading_stuck, which needs both, cannot tell it); the pinned-valve warning then adds a stuck
    sensor to its causes. A reference out of the muscle's reach with a noisy encoder, whose reading
    moves at the end stop, is told without it; a restored pinned stretch keeps what it saw."""
    def pinned(after_mm, freeze_at, n=500, restore_at=None):
        plant = tm.Plant(seed=0)
        ctrl = tm.DisplacementController(tm.ControllerSettings(), tm.THETA0_44N)
        watch = LoopWatch(ctrl)
        ctrl.reset(plant.measurement.l_mm)
        told, frozen, u_prev, saved = [], None, 0.0, None
        for k in range(n):
            l = plant.measurement.l_mm
            if freeze_at is not None and k >= freeze_at:
                frozen = l if frozen is None else frozen
                l = frozen
            if k == restore_at:  # the watch saved and restored mid-stretch
                saved = watch.get_state()
                watch = LoopWatch(ctrl)
                watch.set_state(saved)
            r = 40.0 if k < 200 else after_mm
            step = ctrl.step(l, [r] * (ctrl.settings.preview_samples + 1))
            told += [m for m in watch.observe(k, k * 0.1, l, r, step, u_prev) if "pushes it further" in m]
            u_prev = step.u_v
            plant.step(step.u_v, 0.1)
        return told

    (msg,) = pinned(60.0, 200)
    assert msg.endswith("or the sensor is stuck (l has not changed at all in that time)")
    assert pinned(60.0, 200, restore_at=250) == [msg]
    (reach,) = pinned(150.0, None)
    assert "stuck" not in reach and "out of the rig's reach" in reach


def test_a_theta0_that_runs_away_is_told_from_its_identification_to_the_first_sample_and_the_held_valve():
    """On a rig at 0.15 MPa, Table 2's box gives a model that fits one step ahead (98.6 %) and runs away
    on its own outputs: identify notes it. MPC-UCP on it is told at t = 0 that theta0 runs away, and the
    valve it then holds shut is blamed on that, not on the sign of b1 (0.607 > 0). An adaptive law is
    told what it does with such a theta0; the paper's theta0 runs away under neither law's commands."""
    rig = tm.PlantParams().with_values(**{"supply.supply_pressure_mpa": 0.15})
    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=240.0, params=rig, seed=0)
    report = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1)
    assert report.fit.free_run_diverged and report.fit.percent["1"] > 95.0
    assert any(re.match(r"the free run diverged: .* held in a box C that does not hold this rig \(without it, --box "
                        r"none or box=None, the free run (diverges as well|fits -?[\d.]+ %), with b1 = [-\d.e]+ mm/V",
                        n) for n in report.notes), report.notes
    nominal = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=240.0, seed=0)
    assert not any("free run diverged" in n for n in tm.identify(nominal["u_v"], nominal["l_mm"], ts_s=0.1).notes)

    with pytest.warns(RuntimeWarning) as told:
        run = tm.simulate_closed_loop("mpc_ucp", None, duration_s=12.0, theta0=report.theta, params=rig)
    said = [str(w.message) for w in told]
    assert said[0].startswith("t = 0 s: theta0 runs away: from rest, with the command held at 2 V for 30 s, its free "
                              "run of Eq. (1) leaves -1000..1100 mm") and "the fixed law predicts with it" in said[0]
    held = [m for m in said if "other way would close the gap" in m]
    assert len(held) == 1 and "theta0 runs away" in held[0] and "wrong way round for this rig" not in held[0]
    assert np.all(run["u_v"][20:] == 0.0)  # what it tells of: the valve held shut below the reference

    steeper = np.array(tm.THETA0_44N)
    steeper[0] += 0.1  # a1 1.308: runs away at 2 V
    unboxed = tm.ControllerSettings(method="ampc_servo", box_lower={}, box_upper={})
    ctrl = tm.DisplacementController(unboxed, steeper)
    ctrl.reset(0.0)
    first = LoopWatch(ctrl).observe(0, 0.0, 0.0, 35.0, ctrl.step(0.0, [35.0] * 6), 0.0)
    assert len(first) == 1 and first[0].endswith("the start-up mode's law runs on it for up to "
                                                 f"{unboxed.startup_s:g} s and the adaptive estimate starts from it")
    for method in tm.METHODS:
        assert LoopWatch(tm.DisplacementController(tm.ControllerSettings(method=method), tm.THETA0_44N)).runaway(
            tm.THETA0_44N) is None
