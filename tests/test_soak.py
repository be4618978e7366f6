"""The soak run (tapmuscle.soak): its schedule keeps its promises, and the long-run estimator
(forgetting 0.999 with the covariance ceiling) passes every check over three simulated hours.
The 24-hour figures are benchmarks/soak.py's."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fmu_controller.displacement_control import ControllerSettings
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.hysteresis_model import ASYMMETRIC
from tapmuscle.plots.soak_figures import plot_soak
from tapmuscle.soak import SoakSettings, covariance_spectrum, run_soak, soak_schedule


def test_schedule_ranges_continuity_and_strata():
    s = SoakSettings(duration_s=7200.0, seed=3)
    sch = soak_schedule(s)
    n = int(round(s.duration_s / s.ts_s)) + 1
    assert len(sch.r_mm) == len(sch.load_n) == len(sch.supply_mpa) == n
    assert 35.0 - 30.0 - 1e-9 <= sch.r_mm.min() and sch.r_mm.max() <= 35.0 + 30.0 + 1e-9
    assert np.all((sch.load_n >= 30.0) & (sch.load_n <= 80.0))
    assert np.all((sch.supply_mpa >= 0.20 - 1e-12) & (sch.supply_mpa <= 0.30 + 1e-12))
    f_all = sch.frequency_hz[np.isfinite(sch.frequency_hz)]
    assert np.all((f_all >= 0.05) & (f_all <= 0.3))
    assert np.mean(np.isnan(sch.frequency_hz)) < 0.05  # the holds at 35 mm are short pauses
    assert np.all(sch.r_mm[np.isnan(sch.frequency_hz)] == 35.0)
    # continuous: no step larger than the fastest, deepest sine moves in one sample
    assert np.max(np.abs(np.diff(sch.r_mm))) <= 30.0 * 2 * math.pi * 0.3 * s.ts_s
    # every block holds a segment from each third of the frequency range
    per_block = int(round(s.block_s / s.ts_s))
    edges = np.linspace(0.05, 0.3, 4)
    for b in range((n - 1) // per_block):
        f = sch.frequency_hz[b * per_block:(b + 1) * per_block]
        f = np.unique(f[np.isfinite(f)])
        thirds = sorted(int(np.searchsorted(edges, x, side="right")) - 1 for x in f)
        assert thirds == [0, 1, 2], f"block {b}: frequencies {f}"
    # loads change and the supply drifts
    assert len(np.unique(sch.load_n)) >= 5 and np.ptp(sch.supply_mpa) > 0.01


@pytest.mark.parametrize("field, value", [("duration_s", 0.0), ("block_s", -1.0), ("load_n", (80.0, 30.0)),
                                          ("amplitude_pp_mm", (10.0, 90.0)), ("settle_s", 600.0)])
def test_settings_errors_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        SoakSettings(**{field: value})


def test_covariance_spectrum_detects_indefinite():
    P = np.diag([1e6, 1.0, 1e-12])
    ev, ev_s, pd = covariance_spectrum(P)
    assert pd and ev[0] == pytest.approx(1e-12) and np.allclose(ev_s, 1.0)
    Q = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues -1, 3
    assert not covariance_spectrum(Q)[2]


@pytest.mark.slow
def test_long_run_estimator_passes_three_hours(tmp_path):
    cs = ControllerSettings(method="ampc_servo", forgetting=0.999, covariance_ceiling=True)
    res = run_soak(SoakSettings(duration_s=3 * 3600.0, seed=1), theta0=THETA0_44N, controller=cs)
    checks = res.checks()
    failed = {k: v for k, v in checks.items() if not v["passed"]}
    assert not failed, failed  # the literal 2x rule too: the three hours of seed 1 have no hard block
    # the wall-clock criterion is reported with its figures but judged by benchmarks/soak.py only
    assert set(res.timing_checks()) == {"step_time_flat"} and "step_time_flat" not in checks
    # the ceiling holds: no covariance eigenvalue above P(0)'s largest, none lost
    assert res.p_eigenvalues[:, 1].max() <= max(cs.p0) * (1 + 1e-9)
    assert res.covariance_resets == 0
    # the first hour's error is that of a good loop (the paper's 45-s runs: 0.1-0.4 mm)
    assert checks["error_bounded"]["first_hour_mm"] < 0.3
    # the benchmark's figure from this result
    png = plot_soak({"long-run": res.figure_data()}, ASYMMETRIC.names, tmp_path / "soak.png",
                    theta_lower=np.full(15, -np.inf), theta_upper=np.full(15, np.inf))
    assert png.stat().st_size > 10_000
