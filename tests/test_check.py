"""`tapmuscle check`: the project's CI scenario tests on the paper scenarios, JUnit XML, failures."""

import json
import xml.etree.ElementTree as ET

import pytest

from tapmuscle.cosim import PAPER_SCENARIOS, load_scenario
from tapmuscle.cli.main import main


@pytest.mark.slow
def test_paper_scenarios_meet_their_expectations(built_fmus, tmp_path, capsys):
    """The CI scenario tests: every paper scenario within its [expect] bounds, reported as JUnit XML."""
    junit = tmp_path / "reports" / "scenarios.xml"
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    code = main(["check", str(PAPER_SCENARIOS), "--junit", str(junit), "--fmu-dir", fmu_dir, "--quiet"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "12 scenarios: 12 passed, 0 failed, 0 errors" in out
    root = ET.parse(junit).getroot()
    assert root.tag == "testsuites" and root.get("tests") == "12" and root.get("failures") == "0"
    cases = root.findall("testsuite/testcase")
    assert sorted(c.get("name") for c in cases) == sorted(p.stem for p in PAPER_SCENARIOS.glob("*.toml"))
    for case in cases:
        assert case.find("failure") is None and case.find("error") is None
        bound = load_scenario(PAPER_SCENARIOS / f"{case.get('name')}.toml").expect.bounds[0]
        text = case.find("system-out").text
        mae = float(text.split("mae_mm = ")[1].split()[0])
        assert bound.metric == "mae_mm" and 0.0 < mae <= bound.hi
        assert f"mae_mm <= {bound.hi:g}: " in text and "u_max_v <= 10: " in text


def test_a_missed_expectation_fails_the_check(built_fmus, tmp_path, capsys):
    folder = tmp_path / "cases"
    folder.mkdir()
    (folder / "tight.toml").write_text('duration_s = 12.0\nevaluation_samples = [20, 120]\n'
                                       '[expect]\nmae_mm_max = 0.01\nu_within = [0, 10]\n')
    (folder / "loose.toml").write_text('duration_s = 12.0\nevaluation_samples = [20, 120]\n'
                                       '[expect]\nmae_mm_max = 5.0\n')
    (folder / "broken.toml").write_text('duration_s = 12.0\nevaluation_samples = [20, 120]\n'
                                        '[controller]\nparameters = { "servo.Hu" = 9 }\n[expect]\nmae_mm_max = 5.0\n')
    (folder / "plain.toml").write_text('duration_s = 12.0\n')  # no [expect]: skipped
    junit = tmp_path / "report.xml"
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    kept = tmp_path / "kept"
    assert main(["check", str(folder), "--junit", str(junit), "--fmu-dir", fmu_dir, "--quiet", "--out", str(kept)]) == 1
    out, err = capsys.readouterr()
    assert "3 scenarios with expectations (1 files without [expect] skipped)" in out
    # --out: what did not pass is run again and kept as `tapmuscle run` writes it, the same run
    assert sorted(str(p.relative_to(kept)) for p in kept.glob("*/*")) == ["tight/tight"]
    assert [p.name for p in kept.iterdir()] == ["tight"]  # "nothing written" for broken: not an empty folder
    assert f"wrote {kept / 'tight' / 'tight'} (fail: " in out
    assert "broken: the run failed again, nothing written:" in err and "servo.Hu must be <= servo.Hp" in err
    mae = json.loads((kept / "tight" / "tight" / "summary.json").read_text())["mae_mm"]
    assert {p.name for p in (kept / "tight" / "tight").iterdir()} >= {"result.csv", "summary.json", "tracking.png"}
    assert "3 scenarios: 1 passed, 1 failed, 1 errors" in out and "1 bound met" in out
    root = ET.parse(junit).getroot()
    assert (root.get("tests"), root.get("failures"), root.get("errors")) == ("3", "1", "1")
    tight = next(c for c in root.iter("testcase") if c.get("name") == "tight")
    failure = tight.find("failure")
    assert failure is not None and failure.get("message").startswith(f"mae_mm = {mae:g} > 0.01 (mae_mm_max)")
    broken = next(c for c in root.iter("testcase") if c.get("name") == "broken")
    assert "servo.Hu must be <= servo.Hp" in broken.find("error").get("message")


def test_check_reports_bad_files_and_empty_folders(tmp_path, capsys):
    (tmp_path / "bad.toml").write_text('duration_s = 12.0\n[expect]\nmae_mm_maximum = 1\n')
    assert main(["check", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "bad.toml") in err and "expect.mae_mm_maximum" in err
    (tmp_path / "bad.toml").write_text('duration_s = 12.0\n')
    assert main(["check", str(tmp_path)]) == 2
    assert "no scenario with an [expect] table" in capsys.readouterr().err
    assert main(["check", str(tmp_path / "missing")]) == 2
    assert "no such file or folder" in capsys.readouterr().err


def test_bad_files_are_all_named_and_reach_the_junit_report(tmp_path, capsys):
    """A CI looks for the failure in its test view: every file that cannot be read is an error there,
    and nothing runs (as pytest does with a collection error)."""
    folder = tmp_path / "cases"
    folder.mkdir()
    (folder / "a_bad.toml").write_text('duration_s = 12.0\n[expect]\nmae_mm_maximum = 1\n')
    (folder / "b_good.toml").write_text('duration_s = 12.0\n[expect]\nmae_mm_max = 5.0\n')
    (folder / "c_bad.toml").write_text('duration_s = = 12.0\n')
    junit = tmp_path / "report.xml"
    junit.write_text("an earlier report")
    assert main(["check", str(folder), str(tmp_path / "missing"), "--junit", str(junit), "--quiet"]) == 2
    err = capsys.readouterr().err
    for name in ("a_bad.toml", "c_bad.toml", "missing"):
        assert str(tmp_path / "cases" / name) in err or str(tmp_path / name) in err, err
    assert "3 files could not be read; nothing was run" in err
    root = ET.parse(junit).getroot()
    assert (root.get("tests"), root.get("failures"), root.get("errors")) == ("3", "0", "3")
    errors = {c.get("name"): c.find("error") for c in root.iter("testcase")}
    assert sorted(errors) == ["a_bad.toml", "c_bad.toml", "missing"]
    assert "expect.mae_mm_maximum" in errors["a_bad.toml"].get("message")
    assert errors["c_bad.toml"].get("type") == "ScenarioError" and str(folder / "c_bad.toml") in errors["c_bad.toml"].text
    # a folder without expectations gets a report too: no tests, and the exit code says why
    empty = tmp_path / "plain"
    empty.mkdir()
    (empty / "plain.toml").write_text('duration_s = 12.0\n')
    assert main(["check", str(empty), "--junit", str(junit)]) == 2
    assert ET.parse(junit).getroot().get("tests") == "0"



def test_every_bad_fmu_parameter_of_every_file_is_named_before_anything_runs(built_fmus, tmp_path, capsys):
    """Parameters checked against the FMUs' model descriptions: all of a file's bad ones in one message,
    every file with one named, each an error case of its own file in the JUnit report."""
    folder = tmp_path / "cases"
    folder.mkdir()
    head = 'duration_s = 12.0\n[expect]\nmae_mm_max = 5.0\n'
    (folder / "a.toml").write_text(head + '[controller]\nparameters = { "servo.Rr" = 15.0, "u_max" = 12.0 }\n'
                                   '[plant]\nparameters = { "friction.rate_gain" = -1.0 }\n')
    (folder / "b.toml").write_text(head + '[controller]\nparameters = { "u_min" = -1.0 }\n')
    (folder / "c.toml").write_text(head)
    junit = tmp_path / "report.xml"
    fmu_dir = str(built_fmus["MusclePlant"].parent)
    assert main(["check", str(folder), "--junit", str(junit), "--fmu-dir", fmu_dir, "--quiet"]) == 2
    err = capsys.readouterr().err
    for said in ("'controller.parameters.servo.Rr': not a parameter", "'controller.parameters.u_max': 12.0 is outside",
                 "'plant.parameters.friction.rate_gain': -1.0 is outside", "'controller.parameters.u_min': -1.0 is outside",
                 "2 files set FMU parameters wrongly; nothing was run"):
        assert said in err, err
    errors = {c.get("name"): c.find("error") for c in ET.parse(junit).getroot().iter("testcase")}
    assert sorted(errors) == ["a.toml", "b.toml"]
    assert "friction.rate_gain" in errors["a.toml"].get("message") and "u_min" in errors["b.toml"].get("message")

@pytest.mark.slow
def test_the_long_run_scenario_meets_its_expectation(built_fmus, capsys):
    """The 24-hour soak's CI scenario test: 30 min of AMPC-servo through the FMUs with the long-run
    estimator, load and supply stepping, within its bound over the last 10 minutes."""
    from tapmuscle.cosim import PAPER_SCENARIOS

    folder = PAPER_SCENARIOS.parent / "long_run"
    code = main(["check", str(folder), "--fmu-dir", str(built_fmus["MusclePlant"].parent), "--quiet"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "1 scenarios: 1 passed, 0 failed, 0 errors" in out, out


def test_a_junit_class_is_the_files_folder_dotted_without_the_root(tmp_path, monkeypatch):
    """A CI's test view groups cases by class: `scenarios.paper`, relative to the working folder; an
    absolute path elsewhere keeps its folders without the root (no `/.tmp...`)."""
    from tapmuscle.cosim.check import CollectionError, junit_xml

    monkeypatch.chdir(tmp_path)
    files = [str(tmp_path / "scenarios" / "paper" / "a.toml"), "/elsewhere/rig/b.toml", "c.toml"]
    root = ET.fromstring(junit_xml([], errors=[CollectionError(f, "bad") for f in files]))
    assert [c.get("classname") for c in root.iter("testcase")] == ["scenarios.paper", "elsewhere.rig", "scenarios"]


def test_cases_of_one_name_in_two_files_are_told_apart_in_the_table():
    from tapmuscle.cosim import parse_scenario
    from tapmuscle.cosim.check import CheckCase, CheckResult, result_table
    from tapmuscle.cosim.distributed_sweep import RunResult
    from tapmuscle.cosim.expect import Outcome

    scenario = parse_scenario({"duration_s": 2.0}, source="x")
    results = [CheckResult(CheckCase(file, name, scenario), RunResult("0", "ok", {"mae_mm": 0.5}), Outcome((), ("b",)))
               for file, name in (("a/rig.toml", "rig"), ("b/rig.toml", "rig"), ("c.toml", "other"))]
    lines = result_table(results).splitlines()
    assert "rig (a/rig.toml)" in lines[1] and "rig (b/rig.toml)" in lines[2]
    assert lines[3].split()[1] == "other"  # a name of its own stands alone


def test_a_junit_report_stays_readable_with_control_characters_and_tells_shared_names_apart(tmp_path, monkeypatch):
    """An FMU's coloured warning (ESC, BEL, a NUL) and a name with a control character are shown as
    escapes, not written raw (which made the whole file unreadable to a CI's parser); two files of one
    folder with a case of one name get their file beside it (a CI keys history on class + name)."""
    from tapmuscle.cosim import parse_scenario
    from tapmuscle.cosim.check import CheckCase, CheckResult, junit_xml
    from tapmuscle.cosim.distributed_sweep import RunResult
    from tapmuscle.cosim.expect import Outcome

    monkeypatch.chdir(tmp_path)
    scenario = parse_scenario({"duration_s": 2.0}, source="x")
    warned = RunResult("0", "ok", {"mae_mm": 0.5}, fmu_warnings=("\x1b[31mhot\x1b[0m\x07 and\x00 more",))
    results = [CheckResult(CheckCase(file, name, scenario), run, Outcome((), ("b",)))
               for file, name, run in (("s/a.toml", "same", warned), ("s/b.toml", "same", warned),
                                       ("s/c.toml", "bell\x07", RunResult("1", "ok", {"mae_mm": 0.5})))]
    path = tmp_path / "report.xml"
    path.write_text(junit_xml(results), encoding="utf-8")
    root = ET.parse(path).getroot()
    cases = list(root.iter("testcase"))
    assert [(c.get("classname"), c.get("name")) for c in cases] == [("s", "same (a.toml)"), ("s", "same (b.toml)"),
                                                                     ("s", "bell\\x07")]
    assert cases[0].find("system-err").text == "FMU warning: \\x1b[31mhot\\x1b[0m\\x07 and\\x00 more"


def test_the_table_keeps_its_columns_for_a_long_method_name():
    """A controller of one's own is method own:<its file's stem>, longer than the paper's names: the
    mae_mm column stays one column under its heading."""
    from dataclasses import replace

    from tapmuscle.cosim import parse_scenario
    from tapmuscle.cosim.check import CheckCase, CheckResult, result_table
    from tapmuscle.cosim.distributed_sweep import RunResult
    from tapmuscle.cosim.expect import Outcome

    scenario = parse_scenario({"duration_s": 2.0}, source="x")
    results = [CheckResult(CheckCase("a.toml", "a", replace(scenario, method=method)),
                           RunResult("0", "ok", {"mae_mm": 0.5}), Outcome((), ("b",)))
               for method in ("ampc_servo", "own:MuscleLib.Controllers.PI")]
    lines = result_table(results).splitlines()
    column = lines[0].index("mae_mm")
    assert all(line[column:column + 6].strip() in ("mae_mm", "0.500") for line in lines[:3])


def test_a_check_that_an_fmu_crashes_leaves_a_report_naming_the_case(built_fmus, tmp_path):
    """A controller FMU of one's own that segfaults in a step takes the check's process with it
    (--workers 0, the default); the JUnit report, written as runs finish, names the case it was
    running as the one that did not finish, the case after it as not started, and keeps the one that
    passed."""
    import subprocess
    import sys
    import xml.etree.ElementTree as ET

    from own_controller_fmus import EXAMPLES, build_pi, build_pi_variant

    build_pi_variant(tmp_path, "crashing_pi", do="import ctypes\nctypes.string_at(0)  # a C FMU's bad pointer")
    build_pi(tmp_path / "good")
    text = (EXAMPLES / "own_controller.toml").read_text().replace("duration_s = 45.0", "duration_s = 5.0").replace(
        "steps = [ { t_s = 30.0, load_n = 68.0 } ]", "")
    (tmp_path / "a_good.toml").write_text(text.replace('fmu = "PIController.fmu"', 'fmu = "good/PIController.fmu"')
                                          .replace('name = "own_controller_pi"', 'name = "a_good"'))
    (tmp_path / "b_crash.toml").write_text(text.replace('name = "own_controller_pi"', 'name = "b_crash"'))
    (tmp_path / "c_after.toml").write_text(text.replace('fmu = "PIController.fmu"', 'fmu = "good/PIController.fmu"')
                                           .replace('name = "own_controller_pi"', 'name = "c_after"'))
    junit = tmp_path / "report.xml"
    proc = subprocess.run([sys.executable, "-m", "tapmuscle", "check", str(tmp_path / "a_good.toml"),
                           str(tmp_path / "b_crash.toml"), str(tmp_path / "c_after.toml"), "--junit", str(junit), "--fmu-dir",
                           str(built_fmus["MusclePlant"].parent), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode < 0, (proc.returncode, proc.stderr)  # killed by the signal
    cases = {case.get("name"): case for case in ET.parse(junit).getroot().iter("testcase")}
    assert len(cases) == 3
    good, crashed, after = cases["a_good"], cases["b_crash"], cases["c_after"]
    assert good.find("failure") is None and good.find("error") is None
    assert "did not finish: the check ended while it ran this case" in crashed.find("error").text
    assert "did not finish: not started, the check ended in an earlier case" in after.find("error").text


@pytest.mark.parametrize("name, folder", [("..", "case"), (".", "case"), ("...", "case"), ("../../etc", ".._.._etc"),
                                          ("a/../b", "a_.._b"), ("Rig A, 44 N", "Rig_A_44_N"), ("", "case")])
def test_a_kept_runs_folder_stays_under_out_whatever_the_cases_name(name, folder):
    """A case (or a file ``...toml``) named so that its folder would be ``..`` would have its kept run
    replace what is above ``--out``: each name is one folder name under it."""
    from tapmuscle.cli.sweep import _component

    assert _component(name, "case") == folder
