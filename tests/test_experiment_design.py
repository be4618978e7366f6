"""The discriminating experiment (tapmuscle/diagnosis/experiment_design.py): an input within 0..10 V whose
predictions under two explanations differ, written as a `record --input csv:` file."""

from __future__ import annotations

import numpy as np
import pytest

from tapmuscle.diagnosis.experiment_design import design_input, separation, write_experiment
from tapmuscle.diagnosis.simulation import Simulator
from fmu_plant import PlantParams
from tapmuscle.io.signals import parse_input_spec

A = PlantParams()
B = PlantParams().with_values(**{"delay.delay_s": 0.15})


def test_separation_is_the_smallest_pairwise_distance():
    y = [np.zeros(4), np.ones(4), np.full(4, 3.0)]
    assert separation(y) == pytest.approx(2.0)  # |0 - 1| over 4 samples
    assert separation(y[:1]) == 0.0


@pytest.mark.slow
def test_designed_input_separates_two_explanations_better_than_the_paper_sine(tmp_path):
    exp = design_input({"none": A, "transport_delay": B}, ts_s=0.1, duration_s=60.0, noise_mm=0.013, seed=0)
    assert exp.t_s[-1] == pytest.approx(60.0) and len(exp.u_v) == 601
    assert np.all((exp.u_v >= 0.0) & (exp.u_v <= 10.0))
    # the predictions it reports are the plants' own
    sim = Simulator(exp.u_v, 0.1)
    assert exp.predictions["transport_delay"] == pytest.approx(sim.run(B)[0], abs=1e-12)
    # better than the identification sine 5 + 3 sin(2 pi 0.1 t) of the same length
    u_sine = 5.0 + 3.0 * np.sin(2 * np.pi * 0.1 * exp.t_s)
    s = Simulator(u_sine, 0.1)
    assert exp.separation_sigma * 0.013 >= separation([s.run(A)[0], s.run(B)[0]])
    assert exp.separation_sigma > 10.0

    path = tmp_path / "discriminating_input.csv"
    write_experiment(exp, path, alternatives=["none", "transport_delay"], ts_s=0.1)
    replay = parse_input_spec(f"csv:{path}")
    assert [replay(t) for t in exp.t_s[:50]] == pytest.approx(exp.u_v[:50], abs=1e-6)
    # its times as a reader writes them: 0.3, not 0.30000000000000004
    rows = [line.split(",")[0] for line in path.read_text().splitlines() if line[:1].isdigit()]
    assert [float(r) for r in rows[:4]] == [0.0, 0.1, 0.2, 0.3] and rows[3] == "0.3" and float(rows[-1]) == 60.0


def test_design_input_refuses_fewer_than_two_alternatives():
    with pytest.raises(ValueError, match="at least two"):
        design_input({"a": A}, ts_s=0.1)
    with pytest.raises(ValueError, match="samples"):
        design_input({"a": A, "b": B}, ts_s=0.1, duration_s=0.5)


@pytest.mark.slow
def test_the_design_is_the_same_with_worker_processes():
    """The library scored in two processes (the local search stays in this one): the same input."""
    from tapmuscle.diagnosis.simulation import worker_pool

    alts = {"none": A, "transport_delay": B}
    serial = design_input(alts, ts_s=0.1, duration_s=30.0, noise_mm=0.013, seed=1, local_steps=6)
    with worker_pool(2) as pool:
        parallel = design_input(alts, ts_s=0.1, duration_s=30.0, noise_mm=0.013, seed=1, local_steps=6,
                                executor=pool)
    assert np.array_equal(serial.u_v, parallel.u_v) and serial.separation_sigma == parallel.separation_sigma
    assert serial.evaluations == parallel.evaluations


def test_the_design_stays_within_the_commands_it_is_given():
    """Beyond the recording's commands the alternatives are extrapolations: a valve band at 8.3-8.9 V
    that a recording over 2-7 V never reached is no evidence, and the design must not look for it
    there (it would find it: the default span reaches it)."""
    band = A.with_values(**{"dead_zone.center_v": 8.6, "dead_zone.width_v": 0.6})
    alts = {"none": A, "valve_dead_zone": band}
    for seed in (0, 1, 2):
        exp = design_input(alts, ts_s=0.1, duration_s=30.0, noise_mm=0.013, seed=seed, local_steps=10,
                           u_span_v=(2.0, 7.0))
        assert 2.0 <= exp.u_v.min() and exp.u_v.max() <= 7.0, seed  # library and local search alike
        assert exp.separation_sigma < 1.0, seed  # never enters the band: the same prediction to noise
    wide = design_input(alts, ts_s=0.1, duration_s=30.0, noise_mm=0.013, seed=0, local_steps=10)
    assert 1.0 <= wide.u_v.min() and wide.u_v.max() <= 9.0 and wide.separation_sigma > 10.0
    with pytest.raises(ValueError, match="u_span_v"):
        design_input(alts, ts_s=0.1, u_span_v=(3.0, 10.5))
    with pytest.raises(ValueError, match="u_span_v"):
        design_input(alts, ts_s=0.1, u_span_v=(6.0, 4.0))


def test_the_local_search_keeps_the_command_moving():
    """A 3-N load mismatch separates best with the command low: the sine's local search walks to the
    span's lower edge, where its amplitude once shrank to 0.01-0.03 V, nearly a constant command (the
    diagnosis refuses a constant one). It keeps at least 0.2 V there."""
    heavier = A.with_values(**{"load_mismatch.extra_n": 3.0})
    for seed in (0, 1, 2):
        exp = design_input({"none": A, "load_mismatch": heavier}, ts_s=0.1, duration_s=20.0, noise_mm=0.013,
                           seed=seed, local_steps=30, u_span_v=(5.0, 6.0))
        assert 5.0 <= exp.u_v.min() and exp.u_v.max() <= 6.0, seed
        assert np.ptp(exp.u_v) > 0.3, (seed, exp.description)  # a 0.2-V sine sampled at 0.1 s
