"""The model family's answers to the search (tapmuscle/diagnosis/model_space.py): the effect a first
reading evidences on its own."""

from __future__ import annotations

import numpy as np
import pytest

from tapmuscle.diagnosis.model_space import MUSCLE, ModelSpace
from tapmuscle.diagnosis.recording_checks import AT_REST_MM, DRAINED_MPA

REST = np.zeros(5)


@pytest.mark.parametrize("l0", [0.0, 0.01, -AT_REST_MM, AT_REST_MM])
def test_a_first_reading_at_rest_evidences_nothing(l0):
    y = REST + l0
    assert MUSCLE.first_reading(y, REST, None) is None
    assert MUSCLE.first_reading(y, REST, np.zeros(5)) is None


@pytest.mark.parametrize("l0", [0.51, -0.6, 12.5, -37.0])
def test_a_drained_first_reading_away_from_rest_is_the_encoders_offset(l0):
    y = REST + l0
    for p in (None, np.full(5, DRAINED_MPA)):
        assert MUSCLE.first_reading(y, REST, p) == ("sensor_drift", {"sensor_drift.offset_mm": l0})
    # measured against the model's own first output, whatever it is
    name, start = MUSCLE.first_reading(y + 2.0, REST + 2.0, None)
    assert name == "sensor_drift" and start["sensor_drift.offset_mm"] == pytest.approx(l0, abs=1e-12)


def test_an_offset_beyond_its_bounds_starts_at_the_bound():
    lo, hi = MUSCLE.bounds("sensor_drift.offset_mm")
    assert MUSCLE.first_reading(REST + 2 * hi, REST, None)[1] == {"sensor_drift.offset_mm": hi}
    assert MUSCLE.first_reading(REST + 2 * lo, REST, None)[1] == {"sensor_drift.offset_mm": lo}


def test_a_pressurised_first_reading_is_a_recording_started_mid_run_not_an_offset():
    y = REST + 12.5
    assert MUSCLE.first_reading(y, REST, np.full(5, DRAINED_MPA * 1.01)) is None
    assert MUSCLE.first_reading(y, REST, np.full(5, 0.15)) is None


def test_another_model_family_has_no_first_reading_rule():
    class Other(ModelSpace):
        def bounds(self, key):
            return (-1.0, 1.0)

        def off_values(self, keys):
            return dict.fromkeys(keys, 0.0)
    assert Other().first_reading(REST + 12.5, REST, None) is None


def test_a_recording_starts_mid_run_when_its_first_pressure_is_above_a_drained_muscles():
    y = REST + 80.0
    assert MUSCLE.starts_mid_run(y, np.full(5, DRAINED_MPA * 1.01))
    assert not MUSCLE.starts_mid_run(y, np.full(5, DRAINED_MPA))
    assert not MUSCLE.starts_mid_run(y, None)  # without a pressure: an offset or a mid-run start (first_reading)
    assert not MUSCLE.starts_mid_run(REST, np.zeros(5))


def test_the_supply_offsets_off_value_is_the_nominal_models_pressure_not_the_default_plants():
    """Switched off (the backward step, the discriminating experiment's plant), the supply offset gives
    back the plant file's supply pressure, here 0.3 MPa; every other effect is off as before."""
    from fmu_plant import PlantParams

    from tapmuscle.diagnosis.model_space import JOINT_STARTS, MuscleSpace

    at_03 = PlantParams().with_values(**{"supply.supply_pressure_mpa": 0.3, "load_mismatch.extra_n": 5.0})
    keys = ["supply.supply_pressure_mpa", "load_mismatch.extra_n", "friction.rate_gain", "delay.delay_s"]
    assert MuscleSpace(at_03).off_values(keys) == {"supply.supply_pressure_mpa": 0.3, "load_mismatch.extra_n": 0.0,
                                                   "friction.rate_gain": 0.8, "delay.delay_s": 0.0}
    assert MUSCLE.off_values(keys) == {"supply.supply_pressure_mpa": 0.25, "load_mismatch.extra_n": 0.0,
                                       "friction.rate_gain": 0.8, "delay.delay_s": 0.0}
    # the joint re-fit's further starts lie either side of the plant file's pressure; the others are shared
    starts = [st["supply.supply_pressure_mpa"] for st in MuscleSpace(at_03).joint_starts["supply_pressure_offset"]]
    assert min(starts) < 0.3 < max(starts) and all(0.2 <= p <= 0.4 for p in starts)
    assert {k: v for k, v in MuscleSpace(at_03).joint_starts.items() if k != "supply_pressure_offset"} == JOINT_STARTS


def test_the_rate_dependences_off_value_is_the_nominal_models_gain():
    """Every plant has a rate dependence (the default 0.8): switched off at 0, the backward step and the
    discriminating experiment's plant took it away, and an experiment between a rate dependence and an
    input map then named the rate dependence (0.85) on a rig whose truth was the map. Off is the plant
    file's gain: 0.8 for the default plant, 0 for the demos' model calibrated without it; and the
    finding's words state the gain against the model's."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.candidates import CANDIDATES
    from tapmuscle.diagnosis.demo import DEMO_MODEL
    from tapmuscle.diagnosis.model_space import MuscleSpace

    assert MuscleSpace(PlantParams()).off_values(["friction.rate_gain"]) == {"friction.rate_gain": 0.8}
    assert MuscleSpace(DEMO_MODEL).off_values(["friction.rate_gain"]) == {"friction.rate_gain": 0.0}
    rate = next(c for c in CANDIDATES if c.name == "rate_dependent_hysteresis")
    said = rate.words({"friction.rate_gain": 1.2}, PlantParams())
    assert said.endswith("(1 + 1.20 |v| / v_ref) fits the recording, against the model's 0.80"), said

