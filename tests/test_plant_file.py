"""Plant parameter files: a folder, a diagnosis report or a missing file where a plant file is expected is named."""

import json
import re

import pytest

from tapmuscle.diagnosis.plant_source import PlantSourceError, load_plant
from tapmuscle.io.plant_file import PlantFileError, plant_file_text, read_plant_file
from fmu_plant import PlantParams


def test_a_plant_file_reads_back_what_was_written(tmp_path):
    path = tmp_path / "plant.json"
    params = PlantParams().with_values(**{"delay.delay_s": 0.3})
    path.write_text(plant_file_text(params, "test"))
    assert read_plant_file(path, "--params") == params and load_plant(path) == (params, "json")


def test_the_wrong_file_where_a_plant_file_is_expected_is_named(tmp_path):
    report = tmp_path / "diag" / "diagnosis.json"
    report.parent.mkdir()
    report.write_text(json.dumps({"verdict": "mismatch", "findings": [], "fit_before_percent": 80.0}))
    with pytest.raises(PlantFileError, match=r"--params .*diagnosis\.json: a diagnosis report, not a plant parameter "
                                             r"file \(the calibrated plant is .*diag/calibrated_plant\.json\)"):
        read_plant_file(report, "--params")
    # what diagnose --plant writes for a plant FMU of one's own (its keys as in foreign_diagnose)
    foreign = tmp_path / "calibrated_parameters.json"
    foreign.write_text(json.dumps({"fmu": "MyMuscle.fmu", "recording": "rig.csv", "parameters": {"K": 13.9},
                                   "boundary_effects": {}, "note": "set 'parameters' on the FMU"}))
    with pytest.raises(PlantFileError, match=r"calibrated_parameters\.json: the calibration of a plant FMU of one's "
                                             r"own \(MyMuscle\.fmu\), not a MusclePlant parameter file"):
        read_plant_file(foreign, "--params")
    with pytest.raises(PlantSourceError, match=r"--plant .*diag: a folder, not a MusclePlant \.fmu or a plant \.json"):
        load_plant(report.parent)
    with pytest.raises(PlantSourceError, match="no such file"):
        load_plant(tmp_path / "nowhere.json")


@pytest.fixture(scope="module")
def real_report(tmp_path_factory):
    """A report as ``tapmuscle diagnose`` writes it: its "plant" names the plant file it diagnosed."""
    from tapmuscle.cli.main import main

    folder = tmp_path_factory.mktemp("real")
    (folder / "nominal.json").write_text('{"plant": {}}')
    assert main(["record", "--input", "sine:bias=5,amp=3,freq=0.1", "--duration", "60", "--out",
                 str(folder / "r.csv"), "--quiet"]) == 0
    assert main(["diagnose", "--recording", str(folder / "r.csv"), "--plant", str(folder / "nominal.json"),
                 "--out", str(folder / "diag"), "--quiet", "--no-plots"]) == 0
    report = folder / "diag" / "diagnosis.json"
    assert json.loads(report.read_text())["plant"] == str(folder / "nominal.json")  # the plant file as given
    return report


def test_a_real_diagnosis_report_where_a_plant_file_is_expected_is_named(real_report, capsys):
    from tapmuscle.cli.main import main

    message = (r"diagnosis\.json: a diagnosis report, not a plant parameter file \(the calibrated plant is "
               r".*diag/calibrated_plant\.json; the plant it diagnosed is .*real\d*/nominal\.json\)")
    with pytest.raises(PlantFileError, match=r"--params .*" + message):
        read_plant_file(real_report, "--params")
    assert main(["record", "--input", "const:value=5", "--duration", "1", "--out", str(real_report.parent / "x.csv"),
                 "--params", str(real_report)]) == 2
    assert re.search(r"tapmuscle record: error: --params .*" + message, capsys.readouterr().err)
    assert main(["diagnose", "--recording", str(real_report.parent.parent / "r.csv"), "--plant", str(real_report),
                 "--out", str(real_report.parent.parent / "again"), "--quiet"]) == 2
    assert re.search(r"tapmuscle diagnose: error: --plant .*" + message, capsys.readouterr().err)
    # the calibrated plant beside it is the plant file meant
    assert read_plant_file(real_report.with_name("calibrated_plant.json")) == PlantParams()


def test_the_public_api_reads_and_writes_plant_files_with_their_effects(tmp_path):
    import tapmuscle as tm
    from fmu_plant import Plant

    rig = tm.PlantParams().with_values(**{"delay.delay_s": 0.3, "friction.base_n": 7.0})
    tm.write_plant_file(tmp_path / "rig.json", rig, note="a rig with a delay")
    doc = json.loads((tmp_path / "rig.json").read_text())
    assert doc["note"] == "a rig with a delay" and doc["plant"]["delay"]["delay_s"] == 0.3
    back = tm.read_plant_file(tmp_path / "rig.json")
    assert back == rig and [type(e).__name__ for e in Plant(back).effects] == [type(e).__name__ for e in Plant(rig).effects]
    assert Plant(back).effects  # the delay the file switches on
    # a file holds what differs from the nominal plant; {"plant": {}} is the nominal plant
    (tmp_path / "nominal.json").write_text('{"plant": {}}')
    assert tm.read_plant_file(tmp_path / "nominal.json") == tm.PlantParams()
    (tmp_path / "some.json").write_text('{"plant": {"load": {"load_n": 68}}}')
    assert tm.read_plant_file(tmp_path / "some.json") == tm.PlantParams().with_values(**{"load.load_n": 68})
    with pytest.raises(PlantFileError, match=r"^.*nowhere\.json'?: no such file|no such file .*nowhere\.json"):
        tm.read_plant_file(tmp_path / "nowhere.json")
    with pytest.raises(TypeError, match=r"params must be a PlantParams, got dict"):
        tm.write_plant_file(tmp_path / "bad.json", rig.to_dict())
    assert not (tmp_path / "bad.json").exists()
    # the whole document is not a mapping of groups: said, with where the groups are
    with pytest.raises(ValueError, match=r"a plant parameter file's whole document: its groups are in its 'plant' mapping"):
        tm.PlantParams.from_dict(doc)
    assert tm.PlantParams.from_dict(doc["plant"]) == rig


def test_a_path_given_to_the_plant_names_the_reader(tmp_path):
    import tapmuscle as tm

    with pytest.raises(TypeError, match=r"params must be a PlantParams, got PosixPath: a plant parameter file is "
                                        r"read by tm.read_plant_file\(path\)"):
        tm.Plant(tmp_path / "calibrated_plant.json")


def test_a_value_in_another_unit_is_named_by_its_key_and_unit(tmp_path):
    """A file's out-of-range value is named by the file's key, not the Python class
    (SupplyParams.supply_pressure_mpa), and lengths in metres (rest length 0.4, radius 0.01) or an
    encoder step in micrometres, which would simulate without a word, are warned of with the likely
    unit."""
    path = tmp_path / "rig.json"
    path.write_text(json.dumps({"plant": {"supply": {"supply_pressure_mpa": 250}}}))
    with pytest.raises(PlantFileError, match=r"rig\.json: supply\.supply_pressure_mpa must be <= 1\.0, got 250"):
        read_plant_file(path)
    for group, key, value, said in (("muscle", "rest_length_mm", 0.4, "under 10 mm.*metres or centimetres"),
                                    ("muscle", "radius_mm", 0.01, "under 1 mm.*metres or centimetres"),
                                    ("sensor", "encoder_resolution_mm", 10.0, "over 1 mm.*micrometres")):
        path.write_text(json.dumps({"plant": {group: {key: value}}}))
        with pytest.warns(UserWarning, match=rf"rig\.json: {group}\.{key} = {value:g} mm is {said}") as caught:
            params = read_plant_file(path)
        assert params.value(f"{group}.{key}") == value and caught[0].filename == __file__
    path.write_text(json.dumps({"plant": {"muscle": {"rest_length_mm": 250.0, "radius_mm": 8.0}}}))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_plant_file(path)
