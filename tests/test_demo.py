"""The concealed-effect proof's scores (``tapmuscle demo-mismatch --suite concealed``): counted from the
cases' results, written as strict JSON and as the table docs/diagnosis.md shows."""

from __future__ import annotations

import json

import pytest

from tapmuscle.diagnosis.demo import _scores, concealed_cases, scores_markdown

SHOWCASE = [{"top_finding": "supply_pressure_variation", "iou": 0.92},
            {"top_finding": "rate_dependent_hysteresis", "fit_before_percent": 90.8, "fit_after_percent": 97.1}]


def _case(effect: str, correct: bool, cost: float, gain: float, top: str | None = None) -> dict:
    return {"effect": effect, "correct": correct, "cost_points": cost, "gain_points": gain,
            "top_finding": top or (effect if correct else "unexplained")}


def test_the_scores_count_each_target_over_its_own_cases():
    concealed = [_case("backlash", True, 5.0, 4.0), _case("backlash", False, 5.0, 1.0),
                 _case("transport_delay", True, 0.1, 0.1), _case("transport_delay", False, 0.2, 0.0, "sensor_drift")]
    clean = [{"correct": True}, {"correct": True}, {"correct": False}]
    s = _scores(concealed, clean, SHOWCASE)
    assert s["correct_top_finding_percent"] == 50.0  # 2 of 4
    assert s["visible_cases"] == 2 and s["correct_top_finding_visible_percent"] == 50.0  # cost >= 0.3 points
    assert s["costly_cases"] == 2 and s["costly_with_gain_3_points_percent"] == 50.0
    assert abs(s["clean_no_significant_mismatch_percent"] - 200.0 / 3) < 1e-12
    assert s["per_effect"]["transport_delay"]["confused_with"] == {"sensor_drift": 1}
    md = scores_markdown(s)
    assert "**50.0 %** of 4 concealed-effect recordings" in md and "**66.7 %** of 3 clean recordings" in md
    assert "| `backlash` | 2 | 1 (50 %) | 2 | 1 | unexplained (1) |" in md


def test_a_run_without_clean_recordings_writes_strict_json_and_says_none_were_run():
    """``--clean-seeds 0`` (a run of one effect's rows): no rate over zero cases, no NaN in scores.json."""
    s = _scores([_case("supply_pressure_variation", True, 10.0, 9.0)], [], SHOWCASE)
    assert s["clean_cases"] == 0 and s["clean_no_significant_mismatch_percent"] is None
    json.dumps(s, allow_nan=False)  # raises on NaN or infinity
    md = scores_markdown(s)
    assert "no clean recordings (target >= 95 %)" in md and "nan" not in md
    assert "**100.0 %** of 1 concealed-effect recordings" in md


def test_a_run_of_some_rows_draws_the_same_cases_as_the_whole_suite():
    """``--effects`` / ``--excitations``: the sag row of the steps input is the whole suite's, case by case
    (same names, same magnitudes and windows), so a row re-run to look closer is the row that was scored."""
    whole = {c.name: c for c in concealed_cases(3)}
    part = concealed_cases(3, effects=("supply_pressure_variation",), excitations=("steps",))
    assert len(part) == 9 and len({c.name for c in part}) == 9
    for c in part:
        assert c.overrides == whole[c.name].overrides and c.true_window == whole[c.name].true_window


def test_an_unknown_effect_or_excitation_is_named():
    with pytest.raises(ValueError, match="unknown effect 'sag'"):
        concealed_cases(1, effects=("sag",))
    with pytest.raises(ValueError, match="unknown excitation 'chirp'"):
        concealed_cases(1, excitations=("sine", "chirp"))
