"""Plant parameter files: a folder, a diagnosis report or a missing file where a plant file is expected is named."""

import json

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
    with pytest.raises(PlantSourceError, match=r"--plant .*diag: a folder, not a MusclePlant \.fmu or a plant \.json"):
        load_plant(report.parent)
    with pytest.raises(PlantSourceError, match="no such file"):
        load_plant(tmp_path / "nowhere.json")
