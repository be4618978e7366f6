"""The training / held-out split's balance (tapmuscle/diagnosis/residual_analysis.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tapmuscle.diagnosis import diagnose
from tapmuscle.diagnosis.demo import DEMO_MODEL
from tapmuscle.diagnosis.residual_analysis import (BLOCK_CHOICES, SPLIT_BALANCE, balanced_block_s, direction_imbalance,
                                                   held_command, regime_summary)
from tapmuscle.diagnosis.simulation import Simulator
from scipy import stats

TS = 0.1


def _t(duration_s: float) -> np.ndarray:
    return np.arange(0.0, duration_s + 0.5 * TS, TS)


def test_a_sine_locked_to_the_split_is_rising_in_training_and_falling_held_out():
    t = _t(180.0)
    # period twice the block, minimum at each even block's start: the training blocks see it rise only
    locked = 5.0 - 3.0 * np.cos(2 * math.pi * t / 20.0)
    assert direction_imbalance(locked, TS, 10.0) > 0.99
    # a full period in every block: both parts see the same motion
    assert direction_imbalance(5.0 + 3.0 * np.sin(2 * math.pi * t / 10.0), TS, 10.0) < 0.01
    # the same sine a quarter period later: each block a half rise and a half fall (up to the one
    # sample at each block's edge that falls to the other part: about pi / 100 of 100-sample blocks)
    assert direction_imbalance(5.0 + 3.0 * np.sin(2 * math.pi * t / 20.0), TS, 10.0) < 0.05


def test_the_balanced_block_length_is_the_preferred_one_unless_a_continuous_command_is_locked_to_it():
    t = _t(180.0)
    locked = 5.0 - 3.0 * np.cos(2 * math.pi * t / 20.0)
    b = balanced_block_s(locked, TS, 10.0)
    assert b != 10.0 and any(math.isclose(b, 10.0 * k) for k in BLOCK_CHOICES)
    assert direction_imbalance(locked, TS, b) <= SPLIT_BALANCE
    # the first balanced choice in the documented order: every earlier one is unbalanced
    earlier = [10.0 * k for k in BLOCK_CHOICES[:BLOCK_CHOICES.index(round(b / 10.0, 6))]]
    assert all(direction_imbalance(locked, TS, e) > SPLIT_BALANCE for e in earlier)
    assert balanced_block_s(5.0 + 3.0 * np.sin(2 * math.pi * t / 10.0), TS, 10.0) == 10.0
    # no longer than the recording allows
    assert balanced_block_s(locked, TS, 10.0, longest_s=9.5) <= 9.5


def test_a_held_command_keeps_the_preferred_blocks_however_its_jumps_fall():
    t = _t(180.0)
    # steps that rise in every training block and fall in every held-out one
    steps = np.where((t // 10.0) % 2 == 0, 3.0 + (t % 10.0 // 2.0), 7.0 - (t % 10.0 // 2.0))
    assert held_command(steps)
    assert direction_imbalance(steps, TS, 10.0) > SPLIT_BALANCE
    assert balanced_block_s(steps, TS, 10.0) == 10.0


def test_diagnose_reports_the_block_length_it_chose_and_keeps_one_it_is_given():
    t = _t(120.0)
    u = 5.0 - 2.0 * np.cos(2 * math.pi * t / 20.0)
    y = Simulator(u, TS).run(DEMO_MODEL)[0] + np.random.default_rng(3).normal(0.0, 0.01, len(t))
    d = diagnose(t, u, y, DEMO_MODEL, candidates=[], calibration=None)
    assert d.block_s == balanced_block_s(u, TS, 10.0, longest_s=30.0) != 10.0
    assert d.to_json()["split"]["block_s"] == d.block_s
    assert diagnose(t, u, y, DEMO_MODEL, candidates=[], calibration=None, block_s=10.0).block_s == 10.0
    with pytest.raises(ValueError, match=r"block_s \(--block\) = 40.0 s"):
        diagnose(t, u, y, DEMO_MODEL, candidates=[], calibration=None, block_s=40.0)


def test_the_regimes_of_another_models_output_are_worded_in_its_name_and_unit():
    """A residual while a speed omega [rad/s] rises: its words, not the muscle's."""
    ts = 0.05
    t = np.arange(0, 60, ts)
    omega = 50 + 40 * np.sin(2 * np.pi * 0.05 * t)
    energy = np.where(np.gradient(omega) > 0, 1.0, 0.01)
    text, table = regime_summary(energy, omega, ts, output=("omega", "rad/s"))
    assert "while omega is rising" in text
    assert set(table["direction"]) == {"rising", "falling", "steady"}
    assert all(k.endswith(" rad/s/s)") for k in table["speed"]) and all(k.endswith(" rad/s)") for k in table["displacement"])
    assert not any(word in text for word in ("contracting", "extending", "mm", "displacement"))
    muscle, _ = regime_summary(energy, omega, ts)
    assert "while contracting" in muscle


@pytest.mark.parametrize("seed", range(5))
def test_a_constant_offset_is_structure_though_white_about_its_mean(seed):
    """The whiteness test removes the mean; an offset of a few noise levels is still a mismatch (an encoder
    zeroed elsewhere), and one below the materiality factor, or none, is not."""
    from tapmuscle.diagnosis.residual_analysis import is_structured, mean_test

    e = np.random.default_rng(seed).normal(0.0, 0.01, 2401)
    assert not is_structured(e, sensor_noise_mm=0.01)[0]
    structured, numbers = is_structured(e + 0.03, sensor_noise_mm=0.01)
    assert structured and numbers["ljung_box_p"] > 1e-3 and numbers["mean_p"] < 1e-12
    assert numbers["mean_mm"] == pytest.approx(0.03, abs=0.001)
    # significant (t about 24) but its RMS within 1.5 noise levels: immaterial
    assert mean_test(e + 0.005) < 1e-3 and not is_structured(e + 0.005, sensor_noise_mm=0.01)[0]
    assert mean_test(np.zeros(10)) == 1.0 and mean_test(np.full(10, 2.0)) == 0.0


def test_regime_ranges_read_as_numbers():
    """A displacement range from -0.3 mm read "low (-0-54 mm)": a bound that rounds to zero is 0, and a
    negative one is joined with "to"."""
    from tapmuscle.diagnosis.residual_analysis import regime_summary

    def displacement_regimes(l_mm):
        return list(regime_summary(np.ones(len(l_mm)), l_mm, 0.1)[1]["displacement"])

    assert displacement_regimes(np.linspace(-0.3, 80.0, 600))[0].startswith("low (0-")
    assert displacement_regimes(np.linspace(-5.0, 60.0, 600)) == ["low (-5 to 17 mm)", "middle (17-38 mm)",
                                                                 "high (38-60 mm)"]


def test_a_pressure_column_in_another_unit_is_not_labelled_mpa():
    """A supply logged in kPa (250 where 0.25 MPa) read "high (254.1-300.000 MPa)"; recording_checks
    notes the unit, the regimes keep the numbers as logged."""
    from tapmuscle.diagnosis.residual_analysis import regime_summary

    t = np.arange(600) * 0.1
    l_mm = 20.0 + 10.0 * np.sin(0.5 * t)
    for scale, unit in ((1.0, "MPa"), (1000.0, "as logged, not MPa")):
        p = scale * (0.2 + 0.1 * np.sin(0.3 * t))
        names = list(regime_summary(np.ones(600), l_mm, 0.1, p)[1]["pressure"])
        assert all(name.endswith(f" {unit})") for name in names), names
    assert names[2] == "high (254.1-300 as logged, not MPa)"


def test_mean_test_is_the_one_sample_t_test():
    """Two-sided, as its docstring says: scipy's one-sample t test."""
    from tapmuscle.diagnosis.residual_analysis import mean_test
    rng = np.random.default_rng(1)
    for n, shift in ((10, 0.3), (300, 0.05), (2400, 0.0)):
        e = rng.normal(shift, 1.0, n)
        assert mean_test(e) == pytest.approx(stats.ttest_1samp(e, 0.0).pvalue, rel=1e-9)
