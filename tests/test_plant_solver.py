"""The plant's numerics: ROS34PW2 coefficients, analytic Jacobian, accuracy against a fine reference,
step-size memory and noise blocks in the saved state, the number of sub-steps it takes, and bounded
work with parameters the tolerances cannot be met with."""

import cmath
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fmu_plant
from fmu_plant import Plant, PlantParams
from fmu_plant.parameters import SolverParams
from fmu_plant.rosenbrock import _A, _E, _GC, _M, _ROS_GAMMA, COMPILED, _sum, adaptive_steps, build_model
from fmu_plant.sensors import read_encoder_mm, read_pressure_mpa

QUIET = PlantParams().with_values(**{"sensor.encoder_noise_std_mm": 0.0, "sensor.pressure_noise_std_mpa": 0.0})


def sine(t):
    return 5 + 3 * math.sin(2 * math.pi * 0.1 * t)


def stability_function(zeta):
    """``y1 / y0`` of the transformed scheme on ``y' = lambda y`` with ``zeta = h lambda`` and exact J."""
    g = _ROS_GAMMA * zeta
    u = []
    for i in range(4):
        y = 1.0 + sum(_A[i][j] * u[j] for j in range(i))
        u.append((g * y + sum(_GC[i][j] * u[j] for j in range(i))) / (1.0 - g))
    return 1.0 + sum(m * ui for m, ui in zip(_M, u)), sum(e * ui for e, ui in zip(_E, u))


def test_ros34pw2_is_third_order_l_stable_and_stiffly_accurate():
    # order 3: R(z) - exp(z) = O(z^4); halving z divides the defect by ~16
    d1 = abs(stability_function(0.02)[0] - cmath.exp(0.02))
    d2 = abs(stability_function(0.01)[0] - cmath.exp(0.01))
    assert 12.0 < d1 / d2 < 20.0 and d1 < 1e-7
    # the embedded solution is 2nd order: its difference is O(z^3)
    e1, e2 = abs(stability_function(0.02)[1]), abs(stability_function(0.01)[1])
    assert 6.0 < e1 / e2 < 10.0
    # L-stable: stiff modes are damped out, also oscillatory ones (the hydraulic spring-mass pair)
    assert abs(stability_function(-1e8)[0]) < 1e-6
    assert abs(stability_function(-1e6 + 1e6j)[0]) < 1e-5
    assert all(abs(stability_function(complex(-x, y))[0]) <= 1.0 for x in (0.1, 1, 10, 100) for y in (0, 1, 10, 100))
    # stiffly accurate: the new state is the last stage plus its increment (weights = last row of A, 1)
    assert np.allclose(_M, [*_A[3][:3], 1.0], rtol=0, atol=1e-14)


def test_the_coefficients_sum_left_to_right_as_on_every_python_version():
    """The transformed coefficients come from plain left-to-right float sums: Python 3.12's built-in
    ``sum`` compensates rounding (1e16 + 1 - 1e16 = 1), which would move every plant output by a last bit
    against Python 3.11 and turn an extreme-parameter run that fails on one into one that ends."""
    assert _sum([1e16, 1.0, -1e16]) == 0.0 and _sum([]) == 0.0 and math.copysign(1.0, _sum([-0.0])) == 1.0
    rng = np.random.default_rng(7)
    for _ in range(200):
        terms = (rng.standard_normal(rng.integers(1, 6)) * 10.0 ** rng.integers(-8, 9, 1)).tolist()
        total = 0.0
        for t in terms:
            total = total + t
        assert _sum(iter(terms)) == total


def test_jacobian_matches_finite_differences():
    rhs, jacobian, *_ = build_model(PlantParams())
    rng = np.random.default_rng(0)
    cols = {"p": 1, "l": 2, "v": 3, "z": 4}
    entries = ["pp", "pv", "pl", "vp", "vl", "vv", "vz", "zp", "zv", "zz"]
    worst = 0.0
    for _ in range(300):
        s = [rng.uniform(0, 1), rng.uniform(0.005, 0.3), rng.uniform(1, 140),
             rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 200), rng.uniform(-60, 60)]
        args = (0.25, 44.0, 1e3 / (44.0 / 9.80665 + 0.3))
        out = jacobian(*s, *args)
        assert np.allclose(out[:4], rhs(*s, *args), rtol=1e-14, atol=0)
        for k, name in enumerate(entries):
            row, col = "plvz".index(name[0]), cols[name[1]]
            eps = 1e-7 * max(1.0, abs(s[col]))
            hi, lo = list(s), list(s)
            hi[col] += eps
            lo[col] -= eps
            fd = (rhs(*hi, *args)[row] - rhs(*lo, *args)[row]) / (2 * eps)
            worst = max(worst, abs(fd - out[4 + k]) / (1.0 + abs(fd)))
    assert worst < 1e-4, worst


def _rk4_reference(prm, command, load_n, duration_s, h=5e-4, ts=0.1):
    """The rig's equations (``Plant.derivatives``) by classical RK4 at a fine fixed step: true ``l`` every ``ts``."""
    plant = Plant(prm)
    s = [0.0] * 5
    ps = prm.supply.supply_pressure_mpa
    n = int(round(ts / h))
    out = []
    for k in range(int(round(duration_s / ts))):
        u = command(k * ts)
        for _ in range(n):
            k1 = plant.derivatives(s, u, ps, load_n)
            k2 = plant.derivatives([a + 0.5 * h * b for a, b in zip(s, k1)], u, ps, load_n)
            k3 = plant.derivatives([a + 0.5 * h * b for a, b in zip(s, k2)], u, ps, load_n)
            k4 = plant.derivatives([a + h * b for a, b in zip(s, k3)], u, ps, load_n)
            s = [a + h / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4)]
            if s[2] < 0.0:
                s[2] = 0.0
                s[3] = max(s[3], 0.0)
        out.append(s[2])
    return np.array(out)


def _run(prm, command, load_n, duration_s, ts=0.1):
    plant = Plant(prm)
    plant.update(load_n=load_n)
    out = []
    for k in range(int(round(duration_s / ts))):
        plant.step(command(k * ts), ts)
        out.append(plant.l_mm)
    return np.array(out)


@pytest.mark.parametrize("load_n", [44.0, 68.0])
def test_trajectory_matches_a_fine_rk4_reference_on_the_identification_sine(load_n):
    ref = _rk4_reference(QUIET, sine, load_n, 15.0)
    got = _run(QUIET, sine, load_n, 15.0)
    assert np.ptp(ref) > 40.0  # a real swing, not a resting muscle
    assert np.max(np.abs(got - ref)) < 0.03


def test_saturated_commands_stay_accurate():
    """At 10 V the pressure sits within the valve's laminar band below the supply pressure, where the
    pressure relaxes at ~2500 1/s: an explicit RK4 at 2 ms is unstable there (l 2-4 mm too high)."""
    def command(t):
        return 10.0 if t < 4.0 else 0.0 if t < 8.0 else 6.0
    ref = _rk4_reference(QUIET, command, 44.0, 10.0)
    got = _run(QUIET, command, 44.0, 10.0)
    assert 97.0 < ref[39] < 99.0  # at 10 V
    assert np.max(np.abs(got - ref)) < 0.05


def test_step_size_memory_is_part_of_the_saved_state():
    a = Plant(seed=2)
    for k in range(150):
        a.step(sine(0.1 * k), 0.1)
    saved = a.get_state()
    assert saved["kink_scale_s"] != Plant(seed=2).get_state()["kink_scale_s"]  # it adapted
    b = Plant(seed=2)  # a fresh plant continues bit-identically from the saved state
    b.set_state(saved)
    for k in range(150, 250):
        ma, mb = a.step(sine(0.1 * k), 0.1), b.step(sine(0.1 * k), 0.1)
        assert ma == mb
    assert a.state == b.state


def test_sensor_noise_is_the_seeded_generators_sequence_and_survives_a_rewind():
    """Noise is drawn in blocks, but it is the same sequence sensors.py reads one value at a time."""
    plant = Plant(seed=4)
    sp = plant.params.sensor
    rng = np.random.default_rng(4)
    read_encoder_mm(sp, 0.0, rng), read_pressure_mpa(sp, 0.0, rng)  # the reading at reset
    other = Plant(seed=9)
    for k in range(300):
        m = plant.step(sine(0.1 * k), 0.1)
        assert (m.l_mm, m.p_mpa) == (read_encoder_mm(sp, plant.l_mm, rng), read_pressure_mpa(sp, plant.p_mpa, rng))
        if k == 100:  # mid-block (two normals per step, 64 per block)
            other.set_state(plant.get_state())
        elif k > 100:
            assert other.step(sine(0.1 * k), 0.1) == m
    assert np.std([Plant(seed=s).step(5.0, 0.1).l_mm for s in range(40)]) > 0.005  # the noise is on


@pytest.mark.parametrize("freq, most", [(0.1, 4.0), (0.2, 5.0)])
def test_a_communication_step_takes_few_sub_steps(freq, most):
    """The point of the implicit scheme: sub-steps of tens of ms instead of RK4's 50 x 2 ms."""
    plant = Plant(seed=0)
    attempts = []
    _, _, inner, _, _ = build_model(plant.params)

    def counting(*args):
        attempts.append(args[-1])
        return inner(*args)

    plant._advance_substeps = adaptive_steps(counting, plant.params)
    for k in range(600):
        plant.step(5 + 3 * math.sin(2 * math.pi * freq * 0.1 * k), 0.1)
    assert len(attempts) / 600 < most
    assert np.median(attempts) > 0.015  # [s]


def test_a_broken_down_integration_raises_instead_of_looping():
    plant = Plant(seed=0)
    plant.step(5.0, 0.1)
    plant.state = [0.5, math.nan, 10.0, 0.0, 0.0]  # as if the numbers had overflowed
    with pytest.raises(FloatingPointError, match="t = 0.1 s"):
        plant.step(5.0, 0.1)
    assert math.isnan(plant.state[1]) and plant.t_s == pytest.approx(0.1)  # the step did not happen


# ------------------------------------------------------------------------- extreme parameters
# In-range parameters the tolerances cannot be met with at min_substep_s. Unbounded, the step size would settle
# far below min_substep_s (1.3e-10 s with a presliding of 1e-9 mm) and a communication step would never
# end, in the API, the CLI and an FMU host alike. Such runs are checked in a subprocess with a
# timeout, so that a regression fails the test instead of hanging the suite.
EXTREME = {"presliding": {"friction.presliding_mm": 1e-9},
           "rest length": {"muscle.rest_length_mm": 1e-12},
           # sub-steps end on the delay's breakpoints: Plant.step restores the state itself
           "rest length, delayed": {"muscle.rest_length_mm": 1e-12, "delay.delay_s": 0.05}}

_RUN_EXTREME = r"""
import hashlib, json, math, sys
import numpy as np
from fmu_plant import Plant, PlantParams, rosenbrock
assert rosenbrock.COMPILED == (sys.argv[1] == "compiled"), (sys.argv[1], rosenbrock.COMPILED)
for name, values in json.loads(sys.argv[2]).items():
    plant = Plant(PlantParams().with_values(**values), seed=0)
    rows = []
    for k in range(50):
        before = (list(plant.state), plant.t_s, plant.get_state()["kink_scale_s"])
        try:
            m = plant.step(5.0 + 3.0 * math.sin(2 * math.pi * 0.2 * 0.1 * k), 0.1)
        except FloatingPointError as exc:
            # the documented failure: the state is that of the start of the step
            assert (list(plant.state), plant.t_s, plant.get_state()["kink_scale_s"]) == before
            print(f"{name}: FloatingPointError at step {k}: {exc}")
            break
        rows.append([m.l_mm, m.p_mpa, *plant.state])
    else:
        rows = np.array(rows)
        print(f"{name}: completed 5 s, finite {bool(np.isfinite(rows).all())}, "
              f"sha256 {hashlib.sha256(rows.tobytes()).hexdigest()}")
"""


def _isolated(code: str, *args: str, pure_python: bool = False, timeout: float = 60.0) -> str:
    """stdout of ``python -c code *args``, failing the test if it does not end within ``timeout`` [s].

    It runs in the folder that holds the ``fmu_plant`` these tests import (``python -c`` puts its
    working folder first on the path), so that it imports that copy: in an unpacked sdist with the
    package installed, the source folder's copy has no compiled sub-step.
    """
    env = {k: v for k, v in os.environ.items() if k != "TAPMUSCLE_PURE_PYTHON"}
    if pure_python:
        env["TAPMUSCLE_PURE_PYTHON"] = "1"
    try:
        done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                              timeout=timeout, env=env, cwd=Path(fmu_plant.__file__).parents[1])
    except subprocess.TimeoutExpired:
        pytest.fail(f"still running after {timeout} s: the sub-steps of a communication step never end")
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_extreme_parameters_end_in_bounded_time_in_python_and_compiled():
    paths = ["python", "compiled"] if COMPILED else ["python"]
    out = {path: _isolated(_RUN_EXTREME, path, json.dumps(EXTREME), pure_python=path == "python") for path in paths}
    lines = out["python"].splitlines()
    assert len(lines) == len(EXTREME), out["python"]
    # a sub-step of min_substep_s is accepted whatever its error: the presliding run ends (inaccurate)
    assert lines[0].startswith("presliding: completed 5 s, finite True"), lines[0]
    # a thousand of them in one communication step mean the tolerances cannot be met at all: the
    # documented error, at a time within the step that raised it (0.139 s; 0.068 s with the delay)
    for name, line in zip(list(EXTREME)[1:], lines[1:]):
        found = re.fullmatch(rf"{name}: FloatingPointError at step (\d+): plant integration failed at t = (\S+) s: "
                             r"too many sub-steps of solver\.min_substep_s = 1e-05 s over their error tolerances in "
                             r"one communication step \(1001\): stiff/extreme parameters\? \(a smaller "
                             r"min_substep_s may help\)", line)
        assert found, line
        k, t = int(found[1]), float(found[2])
        assert k < 2 and 0.1 * k <= t < 0.1 * (k + 1), line
    if COMPILED:
        assert out["compiled"] == out["python"]  # the same bits, the same message


def test_no_sub_step_is_shorter_than_min_substep_but_those_ending_a_communication_step():
    prm = PlantParams().with_values(**EXTREME["presliding"])
    plant = Plant(prm, seed=0)
    h_min = prm.solver.min_substep_s
    _, _, inner, _, _ = build_model(prm)
    attempts = []

    def counting(*args):
        attempts.append(args[-1])
        return inner(*args)

    plant._advance_substeps = adaptive_steps(counting, prm)
    short = []
    for k in range(30):  # 3 s: unbounded, the step size would long have left min_substep_s by then
        del attempts[:]
        plant.step(5.0 + 3.0 * math.sin(2 * math.pi * 0.2 * 0.1 * k), 0.1)
        short.append(sum(h < h_min for h in attempts))
        assert len(attempts) < 0.1 / h_min
    assert max(short) <= 2  # the last sub-step, or the halved rest
    assert all(math.isfinite(v) for v in plant.state)


def test_min_substep_longer_than_max_substep_is_refused():
    with pytest.raises(ValueError, match=r"solver\.min_substep_s \(0\.001\) must not exceed "
                                         r"max_substep_s \(0\.0001\)"):
        PlantParams().with_values(**{"solver.min_substep_s": 1e-3, "solver.max_substep_s": 1e-4})
    with pytest.raises(ValueError, match="min_substep_s"):
        SolverParams(min_substep_s=2e-5, max_substep_s=1e-5)
    fixed = PlantParams().with_values(**{"solver.min_substep_s": 1e-3, "solver.max_substep_s": 1e-3})
    assert Plant(fixed).step(6.0, 0.1).l_mm > 0.0  # equal: fixed sub-steps, allowed


_RUN_FMU = r"""
import math, sys
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
folder = extract(sys.argv[1], sys.argv[2])
vr = {v.name: v.valueReference for v in md.modelVariables}
for name, values in (("presliding", {"friction.presliding_mm": 1e-9}),
                     ("rest length", {"muscle.rest_length_mm": 1e-12}),
                     ("min > max", {"solver.min_substep_s": 1e-3, "solver.max_substep_s": 1e-4})):
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="i")
    f.instantiate(loggingOn=True)
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    for key, value in values.items():
        f.setReal([vr[key]], [value])
    print(f"RESULT {name}: exitInitializationMode status {f.exitInitializationMode()}", flush=True)
    try:
        for k in range(50):
            f.setReal([vr["u"]], [5.0 + 3.0 * math.sin(2 * math.pi * 0.2 * 0.1 * k)])
            f.doStep(k * 0.1, 0.1)
        print(f"RESULT {name}: 50 steps, l finite {math.isfinite(f.getReal([vr['l']])[0])}", flush=True)
    except FMICallException as exc:
        print(f"RESULT {name}: doStep at step {k}: {exc}", flush=True)
    f.terminate()
    f.freeInstance()
"""


def test_the_plant_fmu_ends_its_steps_with_extreme_parameters_and_refuses_min_above_max(built_fmus, tmp_path):
    out = _isolated(_RUN_FMU, str(built_fmus["MusclePlant"]), str(tmp_path), timeout=120.0)
    results = [line for line in out.splitlines() if line.startswith("RESULT ")]
    assert results == ["RESULT presliding: exitInitializationMode status 0",
                       "RESULT presliding: 50 steps, l finite True",
                       "RESULT rest length: exitInitializationMode status 0",
                       "RESULT rest length: doStep at step 1: fmi2DoStep failed with status 3 (error).",
                       "RESULT min > max: exitInitializationMode status 1",  # fmi2Warning, then errors
                       "RESULT min > max: doStep at step 0: fmi2DoStep failed with status 3 (error)."], out
    # the logged reasons
    assert "too many sub-steps of solver.min_substep_s = 1e-05 s" in out and "stiff/extreme parameters?" in out
    assert "Traceback" not in out and "internal error" not in out  # a documented failure, not a bug
    assert "solver.min_substep_s (0.001) must not exceed max_substep_s (0.0001)" in out  # the FMU's name


@pytest.mark.skipif(not COMPILED, reason="the Python sub-steps are interruptible anyway")
@pytest.mark.parametrize("with_cuts", [False, True])
def test_an_interrupt_stops_a_long_compiled_step_and_leaves_the_steps_start(with_cuts):
    """An hour's step at 10-us sub-steps takes minutes in the compiled loop: Ctrl-C (here a signal
    handler raising, as Python's SIGINT handler does) must end it, with the state of the step's start
    and the command before it, as after a breakdown."""
    import signal

    class Interrupted(KeyboardInterrupt):
        pass

    def interrupt(signum, frame):
        raise Interrupted

    values = {"solver.max_substep_s": 1e-5}
    if with_cuts:  # an effect's signal jumps within the step: the step is advanced in pieces
        values.update({"supply_variation.sag_mpa": 0.05, "supply_variation.start_s": 100.0})
    plant = Plant(PlantParams().with_values(**values), seed=1)
    plant.step(4.0, 0.5)
    before = json.dumps(plant.get_state())
    previous = signal.signal(signal.SIGALRM, interrupt)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.2)
        with pytest.raises(Interrupted):
            plant.step(7.0, 3600.0)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)
    assert json.dumps(plant.get_state()) == before  # nothing of the hour's step happened
    assert plant.step(7.0, 0.1).t_s == pytest.approx(0.6)


_COUNT_FORCED = r"""
import sys
from fmu_plant import Plant, PlantParams, rosenbrock
assert rosenbrock.COMPILED == (sys.argv[1] == "compiled"), (sys.argv[1], rosenbrock.COMPILED)
for pre in (1.5, 1e-7):
    plant = Plant(PlantParams().with_values(**{"friction.presliding_mm": pre}), seed=0)
    for k in range(100):
        plant.step(10.0 if k < 50 else 0.0, 0.1)
    print(pre, plant.forced_substeps, plant.accuracy_note() is None)
"""


def test_sub_steps_accepted_over_their_tolerances_are_counted_and_said():
    """A presliding length of 1e-7 mm (in range) is stiffer than solver.min_substep_s resolves: sub-steps
    of that length are accepted over their tolerances and the run completes 0.33 mm off (3e-8 mm: frozen at
    0 mm under a full supply), with no error. The plant counts them, the same in Python and compiled, and
    says what they mean; the nominal rig has none."""
    paths = ["python", "compiled"] if COMPILED else ["python"]
    out = {path: _isolated(_COUNT_FORCED, path, pure_python=path == "python") for path in paths}
    nominal, stiff = (line.split() for line in out["python"].splitlines())
    assert nominal == ["1.5", "0", "True"] and int(stiff[1]) > 0 and stiff[2] == "False", out
    if COMPILED:
        assert out["compiled"] == out["python"]
    plant = Plant(PlantParams().with_values(**{"friction.presliding_mm": 1e-7}), seed=0)
    plant.step_many([10.0] * 50 + [0.0] * 50, 0.1)
    assert plant.forced_substeps == int(stiff[1])  # step_many's loop counts them too
    assert plant.accuracy_note().startswith(f"the plant's integration accepted {stiff[1]} sub-steps of "
                                            "solver.min_substep_s = 1e-05 s over their error tolerances")
