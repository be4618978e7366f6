"""Calibration before accusation (tapmuscle/diagnosis/calibration.py): the MAP least-squares solver, the
identifiability rule and the recovery of a rig's constants from a recording."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tapmuscle.diagnosis.calibration import (NOMINAL_PARAMETERS, FittedParameter, NominalParameter, calibrate,
                                   effective_sigma, fit_covariance, fit_parameters, fitted_intervals)
from tapmuscle.diagnosis.demo import record
from tapmuscle.diagnosis.residual_analysis import fit_percent, interleaved_split, is_structured
from tapmuscle.diagnosis.simulation import Simulator
from fmu_plant import PlantParams

NOMINAL = PlantParams()
KEYS = ("friction.base_n", "friction.per_mpa_n", "muscle.damping_n_s_per_mm")


def _linear_residual(a: np.ndarray, b: np.ndarray):
    """A residual linear in the three KEYS (relative to nominal): r = b - A d, d_j = theta_j / nominal_j - 1."""
    nom = np.array([NOMINAL.dotted()[k] for k in KEYS])

    def residual(p: PlantParams) -> np.ndarray:
        d = np.array([p.dotted()[k] for k in KEYS]) / nom - 1.0
        return b - a @ d
    return residual


def test_map_fit_of_a_linear_problem_equals_the_closed_form():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(200, 3))
    truth = np.array([0.1, -0.15, 0.05])
    b = a @ truth + 0.01 * rng.normal(size=200)
    sigma = 0.01
    coords = [FittedParameter(k, NOMINAL.dotted()[k], 0.2 * NOMINAL.dotted()[k], True, *PlantParams.bounds(k)) for k in KEYS]
    fit = fit_parameters(_linear_residual(a, b), NOMINAL, coords, sigma)
    # closed form in scaled coordinates x = d / 0.2: minimise |b - 0.2 A x|^2 + sigma^2 |x|^2
    m = 0.2 * a
    x = np.linalg.solve(m.T @ m + sigma ** 2 * np.eye(3), m.T @ b)
    assert fit.x == pytest.approx(x, abs=1e-4)
    # the secant/forward-difference Jacobian of a linear residual is exact
    assert fit.jacobian == pytest.approx(-m, rel=1e-6, abs=1e-9)


def test_a_point_the_model_refuses_is_never_simulated_and_the_fit_ends_at_a_valid_one():
    """Bounds are per coordinate, but an input map's outputs must not decrease: a fit of two outputs
    pulled across each other (knot 1 towards 8 V, knot 2 towards 5 V) must not raise; the residual
    is only ever asked for maps the plant accepts, and the fit ends at one."""
    keys = ("input_map.knot1_out_v", "input_map.knot2_out_v")
    asked = []

    def residual(p: PlantParams) -> np.ndarray:
        asked.append(p)
        return np.array([p.input_map.knot1_out_v - 8.0, p.input_map.knot2_out_v - 5.0])
    coords = [FittedParameter(k, NOMINAL.dotted()[k], 0.2, False, *PlantParams.bounds(k)) for k in keys]
    fit = fit_parameters(residual, NOMINAL, coords, 0.01, max_iterations=40)
    assert asked and all(p.input_map.knot1_out_v <= p.input_map.knot2_out_v for p in asked)
    k1, k2 = fit.values["input_map.knot1_out_v"], fit.values["input_map.knot2_out_v"]
    assert k1 <= k2
    NOMINAL.with_values(**fit.values)  # a map the plant accepts
    # and it moved towards the targets as far as the order lets it: better than the start
    start = residual(NOMINAL)
    assert float(np.sum(fit.residual ** 2)) < float(np.sum(start ** 2))


def test_two_constants_that_only_act_as_their_sum_are_not_identifiable():
    rng = np.random.default_rng(1)
    a1 = rng.normal(size=300)
    a = np.column_stack([a1, a1, rng.normal(size=300)])  # the first two trade off exactly
    b = a @ np.array([0.1, 0.1, -0.1]) + 0.01 * rng.normal(size=300)
    params = [NominalParameter(k, "-") for k in KEYS]
    cal = calibrate(_linear_residual(a, b), NOMINAL, NOMINAL, 0.01, parameters=params, robust=False)
    ident = {r.parameter: r.identifiable for r in cal.rows}
    assert ident == {KEYS[0]: False, KEYS[1]: False, KEYS[2]: True}
    rows = {r.parameter: r for r in cal.rows}
    # left nominal, with the prior's interval; the identifiable one recovered within its interval
    assert rows[KEYS[0]].estimate == NOMINAL.dotted()[KEYS[0]]
    assert rows[KEYS[0]].ci95[1] - rows[KEYS[0]].ci95[0] == pytest.approx(2 * 1.96 * 0.2 * NOMINAL.dotted()[KEYS[0]])
    true3 = 0.9 * NOMINAL.dotted()[KEYS[2]]
    assert rows[KEYS[2]].ci95[0] <= true3 <= rows[KEYS[2]].ci95[1]
    assert cal.changed == {KEYS[2]: rows[KEYS[2]].estimate}


def test_the_map_estimate_with_every_constant_free_is_kept_beside_the_calibrated_plant():
    """Putting back the constants that are not identifiable one by one can undo a fit: two that act
    only as their sum, both 10 % off, go back to nominal and leave their sum's error in the residual.
    The MAP estimate with every constant free (``map_params``) still fits it to the noise; with every
    constant identifiable there is nothing put back, and it is None."""
    rng = np.random.default_rng(1)
    a1 = rng.normal(size=300)
    a = np.column_stack([a1, a1, rng.normal(size=300)])
    b = a @ np.array([0.1, 0.1, -0.1]) + 0.01 * rng.normal(size=300)
    params = [NominalParameter(k, "-") for k in KEYS]
    residual = _linear_residual(a, b)
    cal = calibrate(residual, NOMINAL, NOMINAL, 0.01, parameters=params, robust=False)
    assert cal.map_params is not None
    free = {k: cal.map_params.dotted()[k] / NOMINAL.dotted()[k] - 1.0 for k in KEYS}
    assert free[KEYS[0]] + free[KEYS[1]] == pytest.approx(0.2, abs=2e-3)
    assert free[KEYS[2]] == pytest.approx(-0.1, abs=2e-3)
    sse_free, sse_cal = (float(np.sum(residual(p) ** 2)) for p in (cal.map_params, cal.params))
    assert sse_free < 1.5 * 300 * 0.01 ** 2 < sse_cal
    # independent columns: every constant identifiable, nothing put back
    a = rng.normal(size=(300, 3))
    b = a @ np.array([0.1, 0.1, -0.1]) + 0.01 * rng.normal(size=300)
    cal = calibrate(_linear_residual(a, b), NOMINAL, NOMINAL, 0.01, parameters=params, robust=False)
    assert all(r.identifiable for r in cal.rows) and cal.map_params is None


def test_an_interval_covers_the_truth_when_a_constant_it_trades_with_is_left_nominal():
    """The third constant acts as 2 % of the first's column: it is not identifiable and goes back to
    nominal, and the first absorbs its error. Over rigs whose third constant is drawn from its prior
    (20 % sd), the first's 95 % interval must still cover the truth about 95 % of the time (the
    prior's variance carried in); the data-only interval covered it in 16 of these 60."""
    rng = np.random.default_rng(7)
    n, sigma = 300, 0.01
    a0, a1 = rng.normal(size=n), rng.normal(size=n)
    a = np.column_stack([a0, a1, 0.02 * a0 + 0.002 * rng.normal(size=n)])
    params = [NominalParameter(k, "-") for k in KEYS]
    nom0 = NOMINAL.dotted()[KEYS[0]]
    covered, widths = 0, []
    draws = 60
    for _ in range(draws):
        d = np.array([0.1, -0.1, 0.2 * rng.normal()])
        b = a @ d + sigma * rng.normal(size=n)
        cal = calibrate(_linear_residual(a, b), NOMINAL, NOMINAL, sigma, parameters=params, robust=False)
        rows = {r.parameter: r for r in cal.rows}
        assert rows[KEYS[0]].identifiable and not rows[KEYS[2]].identifiable
        lo, hi = rows[KEYS[0]].ci95
        covered += lo <= (1.0 + d[0]) * nom0 <= hi
        widths.append((hi - lo) / nom0)
    # binomial(60, 0.95): 51 or more with probability 0.997
    assert covered >= 51, f"{covered} of {draws} intervals cover the truth"
    # and the widening is what the left-out constant's prior gives, not a blanket inflation:
    # 0.02 x 20 % = 0.4 % sd of the first constant, against about 0.06 % from the noise
    assert np.median(widths) == pytest.approx(2 * 1.96 * math.hypot(0.02 * 0.2, sigma / np.linalg.norm(a0)), rel=0.1)


def test_an_effect_s_interval_covers_the_truth_when_it_trades_with_a_constant():
    """An effect parameter (flat within its bounds) fitted jointly with a constant whose column it
    nearly repeats: its 95 % interval from the joint covariance covers the truth about 95 % of the
    time over noise draws, where the interval with the constant held (the effect's column alone)
    is several times too narrow."""
    rng = np.random.default_rng(11)
    n, sigma = 300, 0.01
    a0 = rng.normal(size=n)
    a1 = 0.95 * a0 + 0.3 * rng.normal(size=n)
    nom = NOMINAL.dotted()["friction.base_n"]
    coords = [FittedParameter("friction.base_n", nom, 0.2 * nom, True, *PlantParams.bounds("friction.base_n")),
              FittedParameter("load_mismatch.extra_n", 0.0, 2.0, False, *PlantParams.bounds("load_mismatch.extra_n"))]
    truth = {"friction.base_n": 1.1 * nom, "load_mismatch.extra_n": 3.0}
    x_true = np.array([(truth[c.key] - c.center) / c.scale for c in coords])
    joint = alone = 0
    draws = 60
    for _ in range(draws):
        b = a0 * x_true[0] + a1 * x_true[1] + sigma * rng.normal(size=n)

        def residual(p: PlantParams) -> np.ndarray:
            x = [(p.value(c.key) - c.center) / c.scale for c in coords]
            return b - a0 * x[0] - a1 * x[1]
        f = fit_parameters(residual, NOMINAL, coords, sigma)
        lo, hi = fitted_intervals(coords, f.values, fit_covariance(f.jacobian, f.residual, sigma))["load_mismatch.extra_n"]
        joint += lo <= truth["load_mismatch.extra_n"] <= hi
        lo1, hi1 = fitted_intervals(coords[1:], f.values, fit_covariance(f.jacobian[:, 1:], f.residual, sigma))[
            "load_mismatch.extra_n"]
        alone += lo1 <= truth["load_mismatch.extra_n"] <= hi1
        # the joint interval is wider by the trade: 1 / sqrt(1 - rho^2) with rho the columns' correlation
        rho = np.corrcoef(a0, a1)[0, 1]
        assert (hi - lo) / (hi1 - lo1) == pytest.approx(1.0 / math.sqrt(1.0 - rho ** 2), rel=0.02)
    # binomial(60, 0.95): 51 or more with probability 0.997
    assert joint >= 51, f"{joint} of {draws} joint intervals cover the truth"
    assert alone <= 40, f"{alone} of {draws} intervals with the constant held cover the truth"


def test_an_effect_s_interval_stays_within_its_bounds():
    """A play [mm] cannot be negative: an interval from a flat residual reaching below 0 is clipped."""
    coords = [FittedParameter("backlash.slack_mm", 0.0, 0.5, False, *PlantParams.bounds("backlash.slack_mm"))]
    lo_b, hi_b = PlantParams.bounds("backlash.slack_mm")
    ci = fitted_intervals(coords, {"backlash.slack_mm": 0.1}, np.array([[1.0]]))["backlash.slack_mm"]
    assert ci == (max(lo_b, 0.1 - 1.96 * 0.5), min(hi_b, 0.1 + 1.96 * 0.5)) and ci[0] >= 0.0


def test_effective_sigma_inflates_for_autocorrelation():
    rng = np.random.default_rng(2)
    white = rng.normal(size=5000)
    assert effective_sigma(white) == pytest.approx(1.0, rel=0.05)
    ar = np.zeros(5000)
    for k in range(1, 5000):
        ar[k] = 0.8 * ar[k - 1] + white[k]
    # AR(1) with rho 0.8: variance factor (1 + rho) / (1 - rho) = 9 on the standard deviation of the series
    assert effective_sigma(ar) == pytest.approx(np.std(ar) * 3.0, rel=0.1)


def test_every_nominal_parameter_is_a_plant_field_with_a_positive_nominal():
    for p in NOMINAL_PARAMETERS:
        lo, hi = PlantParams.bounds(p.key)
        v = NOMINAL.dotted()[p.key]
        assert lo <= v <= hi and v > 0, p.key


@pytest.mark.slow
def test_calibration_recovers_a_rig_whose_constants_are_off():
    """Stiffness +15 %, base friction -20 %, valve Cv -10 % (no left-out physics): the calibrated plant
    brings the held-out residual down to the noise."""
    rig = NOMINAL.with_values(**{"muscle.rubber_stiffness_n_per_mm": 1.38, "friction.base_n": 6.4, "valve.cv_max": 1.35})
    cols = record(rig, "steps", 3, duration_s=150)
    y, ts = cols["l_mm"], 0.1
    sim = Simulator(cols["u_v"], ts)
    train, test = interleaved_split(len(y), ts, 10.0)
    n_fit = 1201
    m = train[:n_fit]

    def residual(p):
        return (y[:n_fit] - sim.run(p, stop=n_fit)[0])[m]
    cal = calibrate(residual, NOMINAL, NOMINAL, 0.013)
    y_cal = sim.run(cal.params)[0]
    assert fit_percent(y, sim.run(NOMINAL)[0], test) < 90.0
    assert fit_percent(y, y_cal, test) > 99.5
    assert not is_structured(y - y_cal, sensor_noise_mm=math.sqrt(0.01 ** 2 + 0.01 ** 2 / 12))[0]
    est = {r.parameter: r for r in cal.rows}
    # the valve's flow coefficient is pinned by the step responses' speed
    assert est["valve.cv_max"].identifiable
    assert est["valve.cv_max"].estimate == pytest.approx(1.35, rel=0.05)


@pytest.mark.slow
def test_run_many_is_run_for_each_in_processes_too():
    """Simulator.run_many: each run's displacement, in order, the same bit for bit with an executor."""
    from fmu_plant import PlantParams
    from tapmuscle.diagnosis.simulation import Simulator, worker_pool

    u = 5.0 + 2.0 * np.sin(2 * np.pi * 0.1 * 0.1 * np.arange(201))
    ps = [PlantParams().with_values(**{"load.load_n": w}) for w in (40.0, 60.0, 80.0)]
    sim = Simulator(u, 0.1)
    one = [sim.run(p, stop=150)[0] for p in ps]
    assert all(np.array_equal(a, b) for a, b in zip(one, sim.run_many(ps, stop=150)))
    with worker_pool(2) as pool:
        sim.executor = pool
        many = sim.run_many(ps, stop=150)
        sim.executor = None
    assert all(np.array_equal(a, b) for a, b in zip(one, many)) and sim.runs == 9
    assert not np.array_equal(one[0], one[2])  # different loads: a comparison of different runs


def test_an_interval_stays_within_the_parameters_bounds():
    """A structured residual (10 mm RMS, autocorrelated) inflates the level behind an identifiable
    constant's interval; the flow coefficient's must still not reach below 0 or above the
    datasheet's 1.6 (its bounds), and a constant whose interval fits inside them keeps it whole."""
    from tapmuscle.diagnosis.calibration import calibration_rows

    n = 400
    t = np.arange(n)
    residual = 10.0 * np.sin(2 * np.pi * t / 200.0)  # slow: lag-1 autocorrelation near 1
    keys = ("valve.cv_max", "friction.base_n")
    jac = np.column_stack([0.05 * np.cos(0.3 * t), 50.0 * np.sin(0.7 * t)])
    params = [NominalParameter(k, "-") for k in keys]
    nominal = PlantParams()
    rows = {r.parameter: r for r in calibration_rows(params, nominal, nominal, list(keys), jac, residual, 0.01,
                                                     [0.1, 0.1])}
    lo, hi = PlantParams.bounds("valve.cv_max")
    cv = rows["valve.cv_max"].ci95
    assert cv[0] == lo and cv[1] == hi  # clipped at both ends: unclipped it would be about 1.5 +- 12
    base = rows["friction.base_n"].ci95
    assert 0.0 < base[0] < 8.0 < base[1] < 16.0  # narrow enough to stay whole
    assert base[1] - 8.0 == pytest.approx(8.0 - base[0])
    # identifiable, yet its interval is wider than the prior's (+-1.96 x 0.3): the report says so
    assert rows["valve.cv_max"].wider_than_prior and "trades with them" in rows["valve.cv_max"].identifiable_text()
    assert rows["valve.cv_max"].to_json()["wider_than_prior"] is True
    assert not rows["friction.base_n"].wider_than_prior and rows["friction.base_n"].identifiable_text() == "yes"


@pytest.mark.slow
def test_a_left_out_valve_band_cannot_push_a_constant_beyond_its_prior_bound():
    """A 1.2-V valve band left out of the model pulls the constants far from nominal (the calibration
    takes up the stall it cannot model); none goes beyond PRIOR_BOUND_SDS prior sds, the band pulls
    at least one constant to that bound (the bound is what holds it), and the rows say which."""
    from tapmuscle.diagnosis.calibration import AT_BOUND_SDS, PRIOR_BOUND_SDS, nominal_coords

    rig = NOMINAL.with_values(**{"dead_zone.center_v": 5.0, "dead_zone.width_v": 1.2})
    cols = record(rig, "sine", 4, duration_s=120)
    y, ts = cols["l_mm"], 0.1
    sim = Simulator(cols["u_v"], ts)
    train, _ = interleaved_split(len(y), ts, 10.0)

    def residual(p):
        return (y - sim.run(p)[0])[train]
    cal = calibrate(residual, NOMINAL, NOMINAL, 0.013)
    coords = {c.key: c for c in nominal_coords(NOMINAL)}
    sds = {k: (cal.params.value(k) - c.center) / c.scale for k, c in coords.items()}
    assert all(abs(x) <= PRIOR_BOUND_SDS + 1e-6 for x in sds.values()), sds
    assert max(abs(x) for x in sds.values()) > PRIOR_BOUND_SDS - 0.05, sds
    # the report flags exactly the identifiable constants the bound holds
    rows = {r.parameter: r for r in cal.rows}
    held = {k for k, c in coords.items() if rows[k].identifiable
            and min(cal.params.value(k) - c.lo, c.hi - cal.params.value(k)) <= AT_BOUND_SDS * c.scale}
    assert held and {k for k, r in rows.items() if r.at_bound} == held
    assert all(r.to_json()["at_bound"] == r.at_bound for r in rows.values())
    assert rows[next(iter(held))].identifiable_text().startswith("yes, at its bound")


def test_any_constant_of_the_rig_may_be_named_for_calibration():
    """The catalogue's twelve by their own entries; any other constant with its unit and the same
    prior; an effect's, a sensor's or the solver's parameter, or an unknown one, refused by name."""
    from tapmuscle.diagnosis.calibration import nominal_parameter

    assert nominal_parameter("valve.cv_max") is NOMINAL_PARAMETERS[0]
    load = nominal_parameter("load.load_n")
    assert (load.key, load.unit, load.prior_rel) == ("load.load_n", "N", NOMINAL_PARAMETERS[0].prior_rel)
    assert nominal_parameter("supply.supply_pressure_mpa").unit == "MPa(G)"  # gauge, as the FMU declares it
    for key, message in [("backlash.slack_mm", r"'backlash.slack_mm' is a parameter of an effect \(backlash\)"),
                         ("sensor.encoder_resolution_mm", r"without sensor noise and quantisation"),
                         ("solver.max_substep_s", r"the solver's settings are numerical"),
                         ("load.mass_kg", r"unknown nominal parameter 'load.mass_kg' \(unknown plant parameter "
                                          r"'load.mass_kg'; load has: load_n"),
                         ("load", r"unknown nominal parameter 'load' .*the default ones: valve.cv_max, ")]:
        with pytest.raises(ValueError, match=message):
            nominal_parameter(key)


def test_a_rigs_supply_load_and_friction_are_recalibrated_when_named():
    """A rig whose supply is 10 % low, load and friction 10 % high: named by key, the three are
    recalibrated to within 1 % (the 180-s recording's noise, 0.01-mm encoder, leaves about 0.1 %)."""
    import tapmuscle as tm

    truth = {"friction.base_n": 1.1 * NOMINAL.friction.base_n, "supply.supply_pressure_mpa": 0.9 * 0.25,
             "load.load_n": 1.1 * 44.0}
    rig = tm.simulate("random:lo=2,hi=8,hold_min=2,hold_max=6,seed=3", duration_s=180.0,
                      params=NOMINAL.with_values(**truth), seed=7)
    d = tm.diagnose(rig["t_s"], rig["u_v"], rig["l_mm"], NOMINAL, calibration=list(truth), candidates=[])
    for key, value in truth.items():
        assert d.calibrated.value(key) == pytest.approx(value, rel=0.01), key
    assert d.verdict == "calibration_only" and d.fit_after_percent > 99.0
