"""`tapmuscle paper` reproduces the paper's findings (Tables 6, 7, 9)."""

import json
from pathlib import Path

import numpy as np
import pytest
from computed_once import computed_once

from fmu_controller.displacement_control import P0_TABLE5, ControllerSettings, DisplacementController
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.identification import score_model
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.reference import FunctionReference, SineReference
from fmu_controller.rls import TABLE2_LOWER
from fmu_plant import Plant, PlantParams
from fmu_plant.open_loop import run_open_loop
from tapmuscle.cosim import PAPER_SCENARIOS, load_scenario
from tapmuscle.cli.main import main
from tapmuscle.closed_loop import eq21_error_mm, run_closed_loop
from tapmuscle.paper.reproduce import PAPER_RUNS, paper_findings, paper_tables, preliminary_theta
from tapmuscle.io.recording import read_recording
from tapmuscle.io.signals import parse_input_spec
from tapmuscle.provenance import software


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    """`tapmuscle paper`'s folder (the tests copy what they change) and its paper.json."""

    def make(out: Path) -> str:
        assert main(["paper", "--out", str(out), "--quiet"]) == 0
        return str(out)

    out = Path(computed_once(tmp_path_factory, "paper", make))
    return out, json.loads((out / "paper.json").read_text())


@pytest.mark.slow
def test_outputs(paper):
    out, doc = paper
    frequency = {"table6": 0.1, "table7": 0.1, "table9": 0.2}
    per_seed = {(m, float(load), frequency[t]): errs for t, by_load in doc["per_seed"].items()
                for load, cells in by_load.items() for m, errs in cells.items()}
    for run in PAPER_RUNS:
        # every seed's run, each with its own Eq. (21) error; the table's cell is their mean
        errors = []
        for seed, name in zip((0, 1, 2), (f"{run.name}.csv", f"{run.name}_seed1.csv", f"{run.name}_seed2.csv")):
            rec = read_recording(out / "runs" / name)
            assert {"t_s", "r_mm", "l_mm", "u_v", "l_pred_mm", "theta_b1"} <= set(rec.columns)
            assert rec.u_v.min() >= 0.0 and rec.u_v.max() <= 10.0
            assert rec.metadata["seed"] == str(seed) and rec.metadata["eq21_window_s"] == "10.1-40.1"
            assert float(rec.metadata["eq21_error_mm"]) == pytest.approx(
                eq21_error_mm(rec.columns["r_mm"], rec.columns["l_mm"], (101, 401)), abs=5e-5)
            errors.append(float(rec.metadata["eq21_error_mm"]))
        assert errors == pytest.approx(per_seed[run.method, run.load_n, run.frequency_hz], abs=5e-5)
    # tables.csv: one row per cell, the mean of paper.json's and the seeds' spread, beside the paper's
    import csv

    from tapmuscle.paper.reproduce import PAPER_TABLES, TABLE_COLUMNS

    with open(out / "tables.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == TABLE_COLUMNS and len(rows) == 12
    for row in rows:
        seeds = doc["per_seed"][row["table"]][row["load_n"]][row["method"]]
        assert float(row["eq21_error_mm"]) == pytest.approx(doc[row["table"]][row["load_n"]][row["method"]], abs=5e-5)
        assert float(row["sd_mm"]) == pytest.approx(np.std(seeds, ddof=1), abs=5e-5) and row["seeds"] == "3"
        assert float(row["min_mm"]) <= float(row["eq21_error_mm"]) <= float(row["max_mm"])
        assert float(row["paper_eq21_error_mm"]) == PAPER_TABLES[row["table"]][row["load_n"]][row["method"]]
        assert (row["window_from_s"], row["window_to_s"]) == ("10.1", "40.1")
    assert set(doc["table6"]["44"]) == {"mpc_servo", "mpc_ucp"}
    assert set(doc["table7"]["68"]) == {"ampc_servo", "ampc_ucp"}
    assert set(doc["table9"]["44"]) == {"ampc_servo", "mpc_servo"}
    assert len(list(out.glob("fig*_tracking_*.png"))) == 6 and len(list(out.glob("fig*_prediction_error_*.png"))) == 6
    assert doc["software"] == software()


@pytest.mark.slow
def test_an_interrupted_rerun_leaves_the_earlier_outputs_whole(paper, tmp_path):
    """Ctrl-C half-way through a rerun into the same folder: every file is the earlier run's (no CSV of
    the new seed beside figures of the old one), and no staging folder is left."""
    import hashlib
    import shutil

    from tapmuscle.paper.reproduce import run_paper

    out = tmp_path / "paper"
    shutil.copytree(paper[0], out)
    before = {p.relative_to(out): hashlib.sha256(p.read_bytes()).hexdigest() for p in out.rglob("*") if p.is_file()}

    def interrupt(done, total):
        if done == 3:
            raise KeyboardInterrupt

    with open(tmp_path / "log.txt", "w") as log, pytest.raises(KeyboardInterrupt):
        run_paper(out, seeds=(7,), progress=interrupt, stream=log)
    after = {p.relative_to(out): hashlib.sha256(p.read_bytes()).hexdigest() for p in out.rglob("*") if p.is_file()}
    assert after == before and len(before) >= 25
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.txt", "paper"]


@pytest.mark.slow
def test_a_rerun_keeps_files_of_ones_own_and_replaces_every_earlier_output(paper, tmp_path):
    """Into a folder of an earlier run with three seeds and PNGs, with files of one's own in it (a run
    CSV of another controller in runs/, a figure named like the paper's): one seed, SVG. The earlier
    seeds' CSVs and the PNGs go, the user's files stay as they were."""
    import shutil

    from tapmuscle.paper.reproduce import run_paper

    out = tmp_path / "paper"
    shutil.copytree(paper[0], out)
    mine = {out / "runs" / "my_pi_controller.csv": "t_s,u_v,l_mm\n0,1,2\n", out / "fig08_tracking_mine.png": "mine",
            out / "runs" / "ampc_servo_44N_0.1Hz_with_delay.csv": "mine", out / "notes.txt": "mine"}
    # named like an earlier seed's run, but not one: notes, a file manager's copy, a backup
    mine |= {out / "runs" / f"mpc_ucp_44N_0.1Hz_seed{tail}.csv": "mine" for tail in ("1_notes", "2 copy", "0.bak", "01")}
    for path, text in mine.items():
        path.write_text(text)
    with open(tmp_path / "log.txt", "w") as log:
        run_paper(out, seeds=(4,), figure_format="svg", stream=log)
    assert {p: p.read_text() for p in mine} == mine
    left = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()} - {
        p.relative_to(out).as_posix() for p in mine}
    expected = ({"paper.json", "tables.csv"} | {f"runs/{r.name}.csv" for r in PAPER_RUNS}
                | {p.with_suffix(".svg").name for p in paper[0].glob("fig*.png")})
    assert left == expected and len(expected) == 2 + 12 + 12
    assert read_recording(out / "runs" / "mpc_ucp_44N_0.1Hz.csv").metadata["seed"] == "4"
    assert json.loads((out / "paper.json").read_text())["seeds"] == [4]


@pytest.mark.parametrize("load", ["44", "68"])
def test_servo_beats_unique_coincidence_point(paper, load):
    _, d = paper
    assert d["table6"][load]["mpc_servo"] < d["table6"][load]["mpc_ucp"]
    assert d["table7"][load]["ampc_servo"] < d["table7"][load]["ampc_ucp"]


def test_fixed_ucp_degrades_with_load(paper):
    _, d = paper
    assert d["table6"]["68"]["mpc_ucp"] > d["table6"]["44"]["mpc_ucp"] + 0.2


def test_adaptive_ucp_beats_fixed_ucp_at_68n(paper):
    _, d = paper
    assert d["table7"]["68"]["ampc_ucp"] < d["table6"]["68"]["mpc_ucp"]


def test_adaptive_ucp_beats_fixed_ucp_at_44n(paper):
    """With the start-up mode (the default). With the paper's start it does not: at 44 N Algorithm 1's
    Table 2 box (a1 + a2 >= 0.874) is active at every sample and leaves a larger predictor bias than
    the fixed 44 N model (test_why_the_44n_ucp_cell_fails, docs/control.md)."""
    _, d = paper
    assert d["table7"]["44"]["ampc_ucp"] < d["table6"]["44"]["mpc_ucp"]


def _ucp_44n(method, forgetting=1.0, box_lower=None, theta0=THETA0_44N, seed=0):
    plant = Plant(PlantParams(), seed=seed)
    box = {} if box_lower is None else {"box_lower": dict(TABLE2_LOWER, **box_lower)}
    ctrl = DisplacementController(ControllerSettings(method=method, forgetting=forgetting, startup_s=0.0, **box), theta0)
    cols = run_closed_loop(plant, ctrl, SineReference(frequency_hz=0.1), duration_s=40.0)
    window = slice(101, 402)
    track, pred = cols["r_mm"][window] - cols["l_mm"][window], cols["pred_error_mm"][window]
    return ctrl, float(np.mean(np.abs(track))), float(np.mean(track)), float(np.mean(pred))


def test_why_the_44n_ucp_cell_fails():
    """docs/control.md's account of the cell above, each claim checked on the direct loop (seed 0)."""
    _, fixed_mae, fixed_track, fixed_pred = _ucp_44n("mpc_ucp")
    ctrl, mae, track, pred = _ucp_44n("ampc_ucp")
    for t, e in ((fixed_track, fixed_pred), (track, pred)):  # UCP error ~ 2.3 x the predictor's bias
        assert 2.0 < t / -e < 2.6
    assert pred < fixed_pred - 0.2 and mae > fixed_mae  # adaptation worsens the bias at 44 N
    # Algorithm 1 projects at every sample once a1, a2 sit on the Table 2 corner
    assert ctrl._rls.n_projections >= 300 and tuple(ctrl.theta[:2]) == (1.208, -0.334)
    # the cause: that corner (a1 + a2 >= 0.874). Without either lower bound the projections are rare,
    # the bias is the fixed model's and AMPC-UCP wins (not the paper's C; scenarios/sweeps/ucp_box.toml)
    for relaxed in ({"a1": -10.0}, {"a2": -10.0}):
        ctrl, relaxed_mae, _, relaxed_pred = _ucp_44n("ampc_ucp", box_lower=relaxed)
        assert ctrl._rls.n_projections < 150 and abs(relaxed_pred - fixed_pred) < 0.1
        assert relaxed_mae < fixed_mae - 0.1
    _, forgetting_mae, _, _ = _ucp_44n("ampc_ucp", forgetting=0.98)  # not the paper's Eq. (4)
    assert forgetting_mae < fixed_mae - 0.2


@pytest.mark.parametrize("id_seed", [1, 2])
def test_without_the_a2_bound_adaptation_gains_at_44n_for_other_identifications(id_seed):
    """Another preliminary identification experiment (its own noise): without Table 2's lower bound of
    a2, AMPC-UCP beats MPC-UCP at 44 N (mean of noise seeds 0-2), as with the shipped one."""
    theta0 = preliminary_theta(id_seed, refine_hz=0.05)

    def mae(method, box_lower=None):
        return np.mean([_ucp_44n(method, theta0=theta0, box_lower=box_lower, seed=seed)[1] for seed in (0, 1, 2)])

    assert mae("ampc_ucp", {"a2": -10.0}) < mae("mpc_ucp") - 0.05


def _direct_tables(theta0, seeds=(0, 1, 2)):
    """Tables 6, 7, 9 as `tapmuscle paper --paper-eq5 --paper-start` computes them from
    scenarios/paper/*.toml, on the direct loop (equal to the FMU loop, tests/test_scenarios.py), for a
    given fixed predictor: the paper's controllers, MPC-servo with the paper's Eq. (5), all with the
    paper's start and Eq. (18) without the anti-windup hold. (With the hysteresis notch, MPC-servo
    ties AMPC-servo at 68 N, 0.1 Hz for two of these identifications, within 0.006 mm either way:
    docs/control.md, "Chatter".)"""
    errors = {}
    for run in PAPER_RUNS:
        parameters = load_scenario(PAPER_SCENARIOS / f"{run.name}.toml").controller.parameters  # P0: Table 8 at 0.2 Hz
        p0 = tuple(parameters.get(f"P0.{n}", P0_TABLE5[i]) for i, n in enumerate(ASYMMETRIC.names))
        runs = []
        for seed in seeds:
            ctrl = DisplacementController(ControllerSettings(method=run.method, p0=p0, hysteresis_notch=False,
                                                          startup_s=0.0, anti_windup=False), theta0)
            cols = run_closed_loop(Plant(PlantParams(), seed=seed), ctrl, SineReference(frequency_hz=run.frequency_hz),
                                   duration_s=45.0, load_n=run.load_n)
            runs.append(eq21_error_mm(cols["r_mm"], cols["l_mm"]))
        errors[run.name] = float(np.mean(runs))
    return paper_tables(errors)


def test_findings_of_the_shipped_tables(paper):
    _, d = paper
    assert d["findings"] == paper_findings(d)
    assert [name for name, holds in d["findings"].items() if not holds] == []  # with the start-up mode


@pytest.mark.slow
@pytest.mark.parametrize("id_seed", [1, 2, 3, 4, 5])
def test_every_other_finding_holds_for_other_preliminary_identifications(id_seed):
    """docs/control.md's six-identification table: only the 44 N UCP cell depends on the one
    preliminary identification experiment (it holds for id seed 3 alone)."""
    findings = paper_findings(_direct_tables(preliminary_theta(id_seed, refine_hz=0.05)))
    failing = [name for name, holds in findings.items() if not holds]
    assert failing == ([] if id_seed == 3 else ["AMPC-UCP beats MPC-UCP, 44 N"])


@pytest.mark.parametrize("load", ["44", "68"])
def test_adaptive_servo_no_worse_at_01hz_and_better_at_02hz(paper, load):
    _, d = paper
    assert d["table7"][load]["ampc_servo"] <= d["table6"][load]["mpc_servo"]
    assert d["table9"][load]["ampc_servo"] < d["table9"][load]["mpc_servo"]


@pytest.mark.parametrize("load", ["44", "68"])
def test_adaptive_servo_error_targets(paper, load):
    _, d = paper
    assert d["table7"][load]["ampc_servo"] <= 0.30
    assert d["table9"][load]["ampc_servo"] <= 0.70


def test_bad_seeds(tmp_path, capsys):
    assert main(["paper", "--out", str(tmp_path / "p"), "--seeds", "a,b"]) == 2
    said = capsys.readouterr()
    assert "--seeds" in said.err and said.out == ""  # refused before the banner
    # a repeated seed would weigh one noise realisation twice in a cell's mean
    assert main(["paper", "--out", str(tmp_path / "p"), "--seeds", "0,1,0"]) == 2
    said = capsys.readouterr()
    assert "--seeds must differ" in said.err and "0 more than once in (0, 1, 0) (--seeds 0,1,0)" in said.err
    assert said.out == ""
    from tapmuscle.paper.reproduce import run_paper

    with pytest.raises(ValueError, match=r"seeds must differ \(a repeat would count that noise realisation twice in "
                                         r"the mean\), got 3 more than once"):
        run_paper(tmp_path / "p", seeds=(3, 3))
    with pytest.raises(ValueError, match=r"seeds must be integers in 0 .. 2\*\*64 - 1 = 18446744073709551615, got -1 "
                                         r"in \(0, -1\)"):
        run_paper(tmp_path / "p", seeds=(0, -1))
    assert main(["paper", "--out", str(tmp_path / "p"), "--seeds", "0,18446744073709551616"]) == 2
    assert "--seeds must be integers in 0 .. 2**64 - 1" in capsys.readouterr().err
    with pytest.raises(ValueError, match="figure_format must be one of png, pdf, svg, got 'eps'"):
        run_paper(tmp_path / "p", seeds=(3,), figure_format="eps")
    with pytest.raises(SystemExit) as exit_:  # refused by argparse, before anything runs
        main(["paper", "--out", str(tmp_path / "p"), "--id-seed", "-1"])
    assert exit_.value.code == 2 and "--id-seed must be within 0..18446744073709551615" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()


def test_the_fixed_predictor_is_identified_with_the_first_noise_seed_by_default(paper):
    _, d = paper
    assert d["seeds"] == [0, 1, 2] and d["id_seed"] == 0


def test_fmu_default_theta0_predicts_this_plant_as_well_as_its_preliminary_identification(paper):
    """THETA0_44N (the controller FMU's default theta0) must be regenerated when the plant changes.

    The preliminary identification ends in a closed loop, so its estimate is not a reproducible
    number: another noise seed moves single parameters by up to 10x their size (seeds 0-3), and
    another CPU's rounding does the same. What it must reproduce is the predictor: on open-loop
    data of this plant the stored theta predicts 1, 3 and 5 steps ahead within 2 points of the
    estimate identified now (noise seeds 0-3 spread by <= 1.0 point; b1 10 % off costs 2.4) and
    runs free within 15 points (seeds spread by 10.6).
    """
    _, d = paper
    fresh = np.array([d["theta0"][n] for n in ASYMMETRIC.names])
    rec = run_open_loop(Plant(PlantParams(), seed=77), parse_input_spec("sine:bias=5,amp=3.5,freq=0.07"),
                        duration_s=120.0, ts_s=0.1)
    stored = score_model(np.array(THETA0_44N), ASYMMETRIC, rec["u_v"], rec["l_mm"])
    now = score_model(fresh, ASYMMETRIC, rec["u_v"], rec["l_mm"])
    assert not stored.free_run_diverged and now.percent["1"] > 90.0
    for horizon in ("1", "3", "5"):
        assert stored.percent[horizon] >= now.percent[horizon] - 2.0, (horizon, stored.percent, now.percent)
    assert stored.percent["sim"] >= now.percent["sim"] - 15.0, (stored.percent, now.percent)


def test_the_fixed_predictor_of_another_rig_and_period():
    """preliminary_theta on another simulated rig (0.3 MPa, 30 N) at Ts = 0.05 s: the fixed MPC-servo
    tracks as on the paper's rig (measured 0.110 mm), where its open-loop stage alone oscillates
    (measured 12.3 mm); its defaults are the paper's experiment, bit for bit."""
    import tapmuscle as tm
    from fmu_controller.identification import identify_record

    rig = PlantParams().with_values(**{"supply.supply_pressure_mpa": 0.3})
    theta = preliminary_theta(params=rig, load_n=30.0, ts_s=0.05)
    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=240.0, ts_s=0.05, load_n=30.0, params=rig)
    open_loop = identify_record(rec["u_v"], rec["l_mm"], ts_s=0.05).theta
    errors = {}
    for name, t in (("refined", theta), ("open loop", open_loop)):
        run = tm.simulate_closed_loop("mpc_servo", None, ts_s=0.05, duration_s=45.0, load_n=30.0, params=rig, theta0=t)
        errors[name] = tm.eq21_error_mm(run["r_mm"], run["l_mm"], ts_s=0.05)
    assert errors["refined"] < 0.3 and errors["open loop"] > 2.0, errors
    default = preliminary_theta(0, 0.05)
    assert np.array_equal(default, preliminary_theta(0, 0.05, params=PlantParams(), load_n=44.0, ts_s=0.1))
    assert np.max(np.abs(default - np.array(THETA0_44N))) < 0.01  # the shipped table, up to the CPU's rounding


def test_a_fixed_predictor_refined_over_a_rigs_own_range_tracks_there():
    """A 600-mm muscle at 0.4 MPa and 20 N reaches 163 mm at 10 V. Refined over the paper's 35 +- 30 mm,
    the fixed predictor leaves MPC-UCP 31 mm and MPC-servo 1.2 mm from a sine over the same fractions of
    this rig's reach (59 +- 49 mm); refined over that sine (refine_offset_mm, refine_amplitude_mm),
    0.73 and 0.16 mm. A refinement reference that is not a number is refused before the stages run."""
    rig = PlantParams().with_values(**{"muscle.rest_length_mm": 600.0, "supply.supply_pressure_mpa": 0.4,
                                       "load.load_n": 20.0, "muscle.braid_lock_force_n": 15.0})
    offset, amplitude = 0.36 * 163.0, 0.30 * 163.0
    ref = SineReference(offset_mm=offset, amplitude_mm=amplitude)
    errors = {}
    for label, kw in (("paper's", {}), ("rig's", {"refine_offset_mm": offset, "refine_amplitude_mm": amplitude})):
        theta = preliminary_theta(0, params=rig, **kw)
        for method in ("mpc_ucp", "mpc_servo"):
            ctrl = DisplacementController(ControllerSettings(method=method), theta)
            run = run_closed_loop(Plant(rig, seed=0), ctrl, ref, duration_s=60.0, watch=False)
            errors[label, method] = float(np.mean(np.abs(run["r_mm"] - run["l_mm"])[50:]))
    assert errors["rig's", "mpc_ucp"] < 1.5 < 10.0 < errors["paper's", "mpc_ucp"], errors
    assert errors["rig's", "mpc_servo"] < 0.4 < 0.8 < errors["paper's", "mpc_servo"], errors
    with pytest.raises(ValueError, match="refine_amplitude_mm must be finite, got nan"):
        preliminary_theta(0, refine_amplitude_mm=float("nan"))


def _paper_controller_error(method, reference, load_n, seed=0):
    """Eq. (21) [mm] of the paper's controller (its start, Eq. (18) and Eq. (5) as printed, Table 5's
    P(0)) with THETA0_44N on the direct loop."""
    settings = ControllerSettings(method=method, p0=P0_TABLE5, startup_s=0.0, anti_windup=False,
                                  hysteresis_notch=False)
    plant = Plant(PlantParams().with_values(**{"load.load_n": load_n}), seed=seed)
    cols = run_closed_loop(plant, DisplacementController(settings, THETA0_44N), reference, duration_s=45.0, watch=False)
    return eq21_error_mm(cols)


@pytest.mark.parametrize("load_n", [44.0, 68.0])
def test_the_servo_findings_and_the_fixed_cells_do_not_depend_on_the_references_phase(load_n):
    """Section 4.1 gives no phase; the shipped sine starts at its mean (docs/control.md, "The reference's
    phase is a decision"). Started at its bottom, the servo methods still beat the UCP ones and the
    adaptive servo the fixed one, and the fixed predictors' cells stay put: their steady state does not
    remember the start (measured moves up to 0.007 mm; the bound leaves room for another CPU's rounding,
    which moves these cells by up to 0.008 mm)."""
    omega = 2.0 * np.pi * 0.1
    from_bottom = FunctionReference(lambda t: 35.0 - 30.0 * np.cos(omega * t), 0.1)
    err = {m: _paper_controller_error(m, from_bottom, load_n) for m in ("mpc_ucp", "mpc_servo", "ampc_ucp", "ampc_servo")}
    assert err["ampc_servo"] < err["mpc_servo"] < min(err["mpc_ucp"], err["ampc_ucp"])
    assert err["ampc_servo"] < err["ampc_ucp"]
    for method in ("mpc_ucp", "mpc_servo"):
        assert abs(err[method] - _paper_controller_error(method, SineReference(), load_n)) < 0.03
