"""The diagnosis's files (tapmuscle/diagnosis/report.py): what the recording's header says is used, a
command outside 0..10 V is diagnosed, and an output folder holds one diagnosis whole."""

from __future__ import annotations

import json
import numpy as np
import pytest

from fmu_plant import PlantParams
from tapmuscle.cli.main import main
from tapmuscle.diagnosis.demo import DEMO_MODEL, record
from tapmuscle.diagnosis.report import OUTPUT_FILES, diagnose_files
from tapmuscle.io.plant_file import plant_file_text
from tapmuscle.io.recording import Recording, RecordingError, write_recording

pytestmark = pytest.mark.slow


def _files(tmp_path, rig: PlantParams, *, drop=(), metadata=None, shift_v=0.0):
    """A 60-s step recording of ``rig`` without the columns ``drop``, its command shifted by
    ``shift_v``, and the nominal plant file."""
    cols = record(rig, "steps", 3, duration_s=60.0)
    cols = {k: v for k, v in cols.items() if k not in drop} | {"u_v": cols["u_v"] + shift_v}
    rec = tmp_path / "rec.csv"
    write_recording(rec, Recording(cols, {"ts_s": "0.1"} | (metadata or {})))
    plant = tmp_path / "plant.json"
    plant.write_text(plant_file_text(DEMO_MODEL, "nominal"))
    return rec, plant


def test_the_load_of_the_header_is_used_without_a_load_column(tmp_path):
    """A rig at 68 N recorded without its load column but with '# load_n: 68': the plant at 68 N is
    the rig, so nothing is found (read at the default 44 N, a 24-N load mismatch would be)."""
    rig = DEMO_MODEL.with_values(**{"load.load_n": 68.0})
    rec, plant = _files(tmp_path, rig, drop=("load_n",), metadata={"load_n": "68"})
    d, doc = diagnose_files(rec, plant, tmp_path / "out", plots=False)
    assert np.all(d.load_n == 68.0) and doc["notes"] == [
        "The recording's load is 68 N, the plant's 44 N: the diagnosis re-simulated the recording's, and the "
        "calibrated plant's load.load_n is 68 N"]
    assert doc["verdict"] == "no_significant_mismatch" and doc["fit_after_percent"] > 99.0
    # the calibrated plant file is the rig: at the recording's load, which its note says
    cal = json.loads((tmp_path / "out" / "calibrated_plant.json").read_text())
    assert cal["plant"]["load"]["load_n"] == 68.0 and cal["note"].endswith("at the recording's load (68 N)")


def test_a_recording_without_its_load_says_which_load_was_assumed(tmp_path):
    rec, plant = _files(tmp_path, DEMO_MODEL, drop=("load_n",))
    d, doc = diagnose_files(rec, plant, tmp_path / "out", plots=False)
    assert d.load_n is None and doc["verdict"] == "no_significant_mismatch"
    assert doc["notes"] == ["The recording gives no load (no load_n column, no '# load_n:' line): the plant's 44 N is "
                            "assumed (a rig at another load shows as load_mismatch, or, where the recalibrated "
                            "constants take it up, in them: give the rig's load to tell)"]
    assert "## Notes" in (tmp_path / "out" / "report.md").read_text()


def test_samples_put_back_by_the_import_are_said(tmp_path):
    rec, plant = _files(tmp_path, DEMO_MODEL)
    from tapmuscle.io.recording import read_recording
    r = read_recording(rec)
    filled = np.zeros(len(r))
    filled[[250, 400, 401]] = 1.0  # what tapmuscle import --fill-gaps marks
    write_recording(rec, Recording(r.columns | {"filled": filled}, r.metadata))
    d, doc = diagnose_files(rec, plant, tmp_path / "out", plots=False)
    assert doc["notes"] == ["3 samples were put back by interpolation (column filled, from t = 25 s): left out of the "
                            "fits and the held-out tests; the command there was not logged, so a gap of more than a "
                            "few samples may leave an unexplained window after it"]
    assert doc["split"]["left_out_samples"] == 3


@pytest.mark.parametrize("meta, match", [({"load_n": "heavy"}, "'# load_n: heavy' is not a number"),
                                         ({"ts_s": "0.2"}, "'# ts_s: 0.2' contradicts the t_s column")])
def test_a_header_that_is_wrong_is_named_with_the_file(tmp_path, meta, match):
    rec, plant = _files(tmp_path, DEMO_MODEL, drop=("load_n",), metadata=meta)
    with pytest.raises(RecordingError, match=rf"rec\.csv(, line \d+)?: header {match}"):
        diagnose_files(rec, plant, tmp_path / "out", plots=False)
    assert not (tmp_path / "out").exists()


def test_commands_below_0_v_are_diagnosed_not_refused_by_a_band_search(tmp_path):
    """The amplifier takes -2.5 V off the command (the plant accepts -1..11 V, the valve saturates):
    the band searches stay within the band's bounds, and the input map explains the offset."""
    rec, plant = _files(tmp_path, DEMO_MODEL, shift_v=-2.5)
    d, doc = diagnose_files(rec, plant, tmp_path / "out", plots=False)
    assert float(np.min(d.u_v)) < 0.0
    assert doc["verdict"] == "mismatch" and "input_map" in d.named and doc["fit_after_percent"] > 95.0


def test_a_diagnosis_replaces_the_files_of_the_one_before_in_its_folder(tmp_path):
    rec, plant = _files(tmp_path, DEMO_MODEL)
    out = tmp_path / "out"
    diagnose_files(rec, plant, out, plots=True)
    (out / "discriminating_input_2.csv").write_text("an earlier diagnosis's experiment\n")
    (out / "discriminate_plant_12.json").write_text("an earlier diagnosis's plant\n")
    # the user's, beside them: a note, and a name a diagnosis never writes (the experiment's recording)
    (out / "notes.txt").write_text("the user's\n")
    (out / "discriminating_input_run.csv").write_text("the user's recording of the experiment\n")
    diagnose_files(rec, plant, out, plots=False)
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES[:3] + ("notes.txt", "discriminating_input_run.csv"))
    assert ".png" not in (out / "report.md").read_text()
    (out / "report.md").unlink()
    (out / "report.md").mkdir()  # a file that cannot be written: nothing of this diagnosis appears
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    with pytest.raises(IsADirectoryError, match="report.md is a directory"):
        diagnose_files(rec, plant, out, plots=False)
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "plant.json", "rec.csv"]


def test_asking_for_the_pressure_without_a_pressure_column_is_said(tmp_path, capsys):
    rec, plant = _files(tmp_path, DEMO_MODEL, drop=("p_mpa",))
    assert main(["diagnose", "--recording", str(rec), "--plant", str(plant), "--out", str(tmp_path / "out"),
                 "--use-pressure", "--no-plots", "--quiet", "--workers", "1"]) == 0
    assert "--use-pressure: the recording has no usable p_mpa column" in capsys.readouterr().out


def test_a_value_that_is_not_finite_goes_to_the_json_as_null_by_its_path():
    """Strict JSON has no NaN: one left in a diagnosis must not end the run in a crash after the
    search (the files lost); it is written as null, and write_outputs names its path in the notes."""
    import json
    import math

    from tapmuscle.diagnosis.report import finite_json, json_text

    doc = {"fit": math.nan, "ok": 1.5, "n": 3, "text": "nan", "findings": [{"gain": math.inf, "p": [0.1, -math.inf]}],
           "pair": (2.0, np.float64("nan"))}
    clean, paths = finite_json(doc)
    assert paths == [".fit", ".findings[0].gain", ".findings[0].p[1]", ".pair[1]"]
    assert clean == {"fit": None, "ok": 1.5, "n": 3, "text": "nan", "findings": [{"gain": None, "p": [0.1, None]}],
                     "pair": [2.0, None]}
    json.dumps(clean, allow_nan=False)
    assert finite_json({"a": [1.0, {"b": 2.0}]}) == ({"a": [1.0, {"b": 2.0}]}, [])
    written = json.loads(json_text({"fit": math.nan, "notes": ["before"]}))
    assert written == {"fit": None, "notes": ["before", "not a finite number, written as null: .fit"]}


def _calibration_only(rms_mm: float, noise_mm: float, whiteness_p: float, nominal: float, estimate: float):
    from types import SimpleNamespace

    row = SimpleNamespace(parameter="supply.compliance_m3_per_mpa", nominal=nominal, estimate=estimate,
                          identifiable=True, at_bound=False)
    return SimpleNamespace(verdict="calibration_only", calibration=SimpleNamespace(rows=[row]), named=[], ambiguous=[],
                           fit_before_percent=80.0, fit_calibrated_percent=99.9, unexplained=None, unit="mm",
                           tests_after=_tests(rms_mm, noise_mm, whiteness_p))


def _tests(rms_mm: float, noise_mm: float, whiteness_p: float, structured: bool = False) -> dict:
    """A residual test's numbers (``is_structured``'s and ``whiteness_p``), its mean zero (p = 0.5)."""
    return {"rms_mm": rms_mm, "noise_reference_mm": noise_mm, "white_noise_mm": noise_mm, "whiteness_p": whiteness_p,
            "ljung_box_p": whiteness_p, "mean_p": 0.5, "structured": structured}


def test_the_summary_says_why_a_residual_counts_as_unstructured():
    """Not white at p = 1e-209 but within the noise: "at the noise level", never "white"; a constant of
    1e-5 that moved by 1e-11 is listed as changed."""
    from tapmuscle.diagnosis.report import summary_lines

    lines = summary_lines(_calibration_only(0.0145, 0.0104, 1.9e-209, 1.2e-5, 1.2e-5 + 3e-11))
    assert "residual at the noise level: RMS 0.0145 mm against 0.0104 mm of noise, < 1.5 x" in lines[1]
    assert "white" not in lines[1].split("whiteness p")[0]
    assert "supply.compliance_m3_per_mpa 1.2e-05 -> 1.2e-05" in lines[0]
    assert "residual white" in summary_lines(_calibration_only(0.03, 0.0104, 0.2, 1.0, 1.0))[1]
    assert "none changed" in summary_lines(_calibration_only(0.03, 0.0104, 0.2, 1.0, 1.0))[0]


def test_the_summary_lists_the_first_located_windows_and_counts_the_rest():
    """A delay on a 4-h recording is located in hundreds of windows: the console line names the first
    ten and how many more diagnosis.json holds, not all of them (a 5.6-kB line); a few are all named."""
    from types import SimpleNamespace

    from tapmuscle.diagnosis.report import SUMMARY_WINDOWS, summary_lines

    def finding_line(n_windows):
        located = [(30.0 * k, 30.0 * k + 5.0) for k in range(n_windows)]
        finding = SimpleNamespace(effect="transport_delay", fit_gain_points=9.11, located=located,
                                  explanation="the valve acts 300 ms after the command", regime="while contracting",
                                  parameters={"delay.delay_s": 0.3})
        d = SimpleNamespace(verdict="mismatch", calibration=None, named=["transport_delay"], ambiguous=[],
                            fit_before_percent=84.15, fit_after_percent=99.94, unexplained=None, unit="mm",
                            findings=[finding], ts_s=0.1)
        lines = summary_lines(d)
        assert lines[-1].startswith("  for control: set the controller's input_delay_samples = 3 at Ts = 0.1 s")
        return lines[-2]

    assert SUMMARY_WINDOWS == 10
    long = finding_line(399)
    assert "located 0-5 s, 30-35 s, " in long and "270-275 s, ... +389 more in diagnosis.json; while contracting" in long
    assert "300-305 s" not in long and len(long) < 300
    short = finding_line(10)
    assert "located 0-5 s, " in short and "270-275 s; while contracting" in short and "more" not in short
    assert "located nowhere in particular;" in finding_line(0)


def test_no_significant_mismatch_says_white_only_of_a_white_residual():
    """A re-diagnosis with the calibrated plant left RMS 0.0130 mm against 0.0104 mm of noise, not
    white at p = 1.5e-264: "no significant mismatch" for being within the noise, not "the residual
    is white noise"; a structured residual below a finding's materiality (no calibration) is said as
    such; a white one is white."""
    from types import SimpleNamespace

    from tapmuscle.diagnosis.report import summary_lines

    def line(tests):
        return summary_lines(SimpleNamespace(verdict="no_significant_mismatch", tests_before=tests, unit="mm",
                                             fit_before_percent=99.95))[0]

    small = line(_tests(0.0130, 0.0104, 1.5e-264))
    assert small.startswith("no significant mismatch: residual at the noise level: RMS 0.0130 mm against 0.0104 mm "
                            "of noise, < 1.5 x (whiteness p = 1.5e-264)") and "white" not in small.split("whiteness")[0]
    assert line(_tests(0.0105, 0.0105, 0.42)).startswith("no significant mismatch: residual white (whiteness p = 0.42, "
                                                         "RMS 0.0105 mm, noise 0.0105 mm); held-out fit 99.95 %")
    below = line(_tests(0.025, 0.0104, 1e-30, structured=True))
    assert "structured residual below the materiality level" in below and "< 3 x" in below


def test_the_residual_figure_shows_the_final_residual_on_its_own_scale(tmp_path, monkeypatch):
    """residual.png: the residuals before above; below, the final one alone with the band of twice the
    noise level, so that a remainder of hundredths of a millimetre is seen beside millimetres."""
    import tapmuscle.diagnosis.report as report

    rig = DEMO_MODEL.with_values(**{"delay.delay_s": 0.2})
    rec, plant = _files(tmp_path, rig)
    drawn = {}
    monkeypatch.setattr(report, "save_figure", lambda fig, path: drawn.setdefault(path.name, fig))
    d, _ = diagnose_files(rec, plant, tmp_path / "out")
    fig = drawn["residual.png"]
    top, zoom = fig.axes
    final = d.y_mm - d.y_after_mm
    assert np.array_equal(zoom.lines[0].get_ydata(), final)
    assert len(top.lines) >= 2 and np.ptp(top.lines[0].get_ydata()) > 10 * np.ptp(final)
    noise = d.tests_after["noise_reference_mm"]
    (band,) = [p for p in zoom.patches if (p.get_label() or "").startswith("+-2 x the noise level")]
    # a Rectangle (matplotlib >= 3.9) or a Polygon, in data coordinates along y
    lo, hi = ((band.get_y(), band.get_y() + band.get_height()) if hasattr(band, "get_height")
              else (band.get_xy()[:, 1].min(), band.get_xy()[:, 1].max()))
    assert np.isclose(lo, -2 * noise) and np.isclose(hi, 2 * noise)


@pytest.mark.parametrize("rig, calibration, says", [
    ({"delay.delay_s": 0.2}, "default", "with the constants tapmuscle diagnose recalibrated and the effects it fitted to"),
    ({"delay.delay_s": 0.2}, None, "with the effects tapmuscle diagnose fitted to"),
    ({"friction.base_n": 5.0}, "default", "with the constants tapmuscle diagnose recalibrated to"),
    ({}, None, "as given: tapmuscle diagnose recalibrated and fitted nothing on")])
def test_the_calibrated_plant_files_note_says_what_was_fitted(tmp_path, rig, calibration, says):
    import json

    rec, plant = _files(tmp_path, DEMO_MODEL.with_values(**rig))
    options = {} if calibration == "default" else {"calibration": None}
    diagnose_files(rec, plant, tmp_path / "out", plots=False, **options)
    note = json.loads((tmp_path / "out" / "calibrated_plant.json").read_text())["note"]
    assert note == f"{plant} {says} {rec}"


def test_a_calibration_that_lowers_the_held_out_fit_is_said_to():
    """A first calibration that fits the held-out blocks worse than the nominal plant (65.7 -> 60.7 %
    on a rig with a band and a drift, before the effects took it to 99.9 %) would read as a calibration gone
    wrong: the line says why it can be lower; a higher one gets no such words."""
    import dataclasses

    from tapmuscle.diagnosis import diagnose
    from tapmuscle.diagnosis.report import summary_lines

    cols = record(DEMO_MODEL.with_values(**{"delay.delay_s": 0.3}), "steps", 3, duration_s=60.0)
    d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL, calibration=["valve.cv_max"],
                 candidates=["transport_delay"])
    assert d.calibration is not None and d.verdict == "mismatch"
    lower = dataclasses.replace(d, fit_calibrated_percent=d.fit_before_percent - 5.0)
    higher = dataclasses.replace(d, fit_calibrated_percent=d.fit_before_percent + 5.0)
    said_lower, said_higher = (next(x for x in summary_lines(case) if x.startswith("calibration:"))
                               for case in (lower, higher))
    assert "without any effect (lower: the constants fitted to the training blocks without the effects below do " \
           "not carry to the held-out ones); constants" in said_lower
    assert "without any effect; constants" in said_higher
