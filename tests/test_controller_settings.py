"""ControllerSettings: each setting refused outside its range, naming it, and taken at its bounds."""

from __future__ import annotations

import math

import pytest

from fmu_controller.controller_settings import (MAX_DELAY_MOVE_WEIGHT, MAX_PROBING_V, MAX_STARTUP_S, MIN_FORGETTING,
                                                ControllerSettings)
from fmu_controller.prediction import MAX_INPUT_DELAY_SAMPLES
from fmu_controller.probing import MLS_LENGTH
from fmu_controller.servo_settings import MAX_WEIGHT, ServoMPCSettings

#: (setting, values taken at its bounds, values refused just beyond them)
RANGES = [
    ("ts_s", (1e-6, 10.0), (0.0, -0.1, math.nan, math.inf)),
    ("startup_s", (0.0, MAX_STARTUP_S), (-1e-9, MAX_STARTUP_S * (1 + 1e-9), math.nan)),
    ("probing_v", (0.0, MAX_PROBING_V), (-1e-9, MAX_PROBING_V + 1e-9, math.nan)),
    ("probing_phase", (0, MLS_LENGTH - 1), (-1, MLS_LENGTH)),
    ("forgetting", (MIN_FORGETTING, 1.0), (MIN_FORGETTING - 1e-9, 1.0 + 1e-12, math.nan)),
    ("max_speed_mm_per_s", (0.0, 1e6), (-1e-9, math.inf, math.nan)),
    ("delay_move_weight", (1e-9, MAX_DELAY_MOVE_WEIGHT), (0.0, MAX_DELAY_MOVE_WEIGHT * (1 + 1e-9), math.nan)),
    ("input_delay_samples", (-1, 0, MAX_INPUT_DELAY_SAMPLES), (-2, MAX_INPUT_DELAY_SAMPLES + 1)),
]


@pytest.mark.parametrize("name, taken, refused", RANGES, ids=[r[0] for r in RANGES])
def test_each_setting_is_refused_beyond_its_range_naming_it_and_taken_at_its_bounds(name, taken, refused):
    # the UCP method: a servo law's move weight under a delay has its own check (below)
    for value in taken:
        assert getattr(ControllerSettings(method="ampc_ucp", **{name: value}), name) == value
    for value in refused:
        with pytest.raises(ValueError, match=rf"ControllerSettings\.{name} must"):
            ControllerSettings(method="ampc_ucp", **{name: value})


@pytest.mark.parametrize("name", ["startup_guard", "anti_windup", "delay_correction", "hysteresis_notch"])
def test_a_switch_is_true_or_false(name):
    with pytest.raises(ValueError, match=rf"ControllerSettings\.{name} must be"):
        ControllerSettings(**{name: 1})


def test_a_move_weight_the_delayed_law_would_scale_past_the_qp_range_is_refused_up_front():
    """servo_for_delay runs a delay of 2 or more with R x delay_move_weight: an R within its own range
    (3e5 <= MAX_WEIGHT) times the default 16 failed the decision of -1 mid-run; it is refused when the
    settings are made, where a delay of 2 or more is possible and the method is a servo one."""
    servo = ServoMPCSettings(r=3e5)
    for delay in (-1, 2, 5):
        with pytest.raises(ValueError, match=r"servo.r x ControllerSettings.delay_move_weight = 300000 x 16, the move "
                                             r"weight of the law for a delay of 2 samples or more, is not one: r must be "
                                             r"<= 1e\+06, got 4800000.0 \(with this delay_move_weight, servo.r may be at "
                                             r"most 62500\)"):
            ControllerSettings(method="ampc_servo", servo=servo, input_delay_samples=delay)
    # the largest servo.r named is itself allowed (rounded down, not to the nearest)
    for w in (1.5, 6.0, 7.0):
        with pytest.raises(ValueError, match="servo.r may be at most") as refused:
            ControllerSettings(method="ampc_servo", servo=ServoMPCSettings(r=MAX_WEIGHT), delay_move_weight=w,
                               input_delay_samples=-1)
        most = float(str(refused.value).rsplit("at most ", 1)[1].rstrip(")"))
        ControllerSettings(method="ampc_servo", servo=ServoMPCSettings(r=most), delay_move_weight=w, input_delay_samples=-1)
    # a product that rounds to 0 is not a move weight either (R > 0), nor is a per-step one too large
    with pytest.raises(ValueError, match=r"= 1e-300 x 1e-30, .* is not one: r must be > 0"):
        ControllerSettings(method="ampc_servo", servo=ServoMPCSettings(r=1e-300), delay_move_weight=1e-30,
                           input_delay_samples=-1)
    with pytest.raises(ValueError, match=r"= 400000 x 16, .* is not one: r must be <= 1e\+06 elementwise"):
        ControllerSettings(method="mpc_servo", servo=ServoMPCSettings(hu=2, r=(1.0, 4e5)), input_delay_samples=2)
    # no delay of 2 or more (0, 1), no servo law (UCP), or a product within the range: accepted
    for settings in (dict(method="ampc_servo", input_delay_samples=0), dict(method="mpc_servo", input_delay_samples=1),
                     dict(method="ampc_ucp", input_delay_samples=-1)):
        ControllerSettings(servo=servo, **settings)
    s = ControllerSettings(method="ampc_servo", servo=servo, input_delay_samples=-1, delay_move_weight=3.0)
    assert s.servo_for_delay(2).r == 9e5 <= MAX_WEIGHT
