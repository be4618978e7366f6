"""tapmuscle.io.json_file: JSON text every reader takes, and files read with errors that name them."""

import json
import math

import pytest

from tapmuscle.io.json_file import json_text, read_json


def test_non_finite_numbers_are_named_strings_anywhere_and_everything_else_is_kept():
    doc = {"box": {"a1": -math.inf, "b1": math.inf}, "fits": [1.5, math.nan, (2, -math.inf)], "n": 3, "ok": True,
           "none": None, "text": "inf"}
    text = json_text(doc, indent=1)
    assert text.endswith("}\n")
    back = json.loads(text, parse_constant=lambda name: pytest.fail(f"not strict JSON: {name}"))
    assert back == {"box": {"a1": "-inf", "b1": "inf"}, "fits": [1.5, "nan", [2, "-inf"]], "n": 3, "ok": True,
                    "none": None, "text": "inf"}
    assert float(back["box"]["a1"]) == -math.inf  # Python reads them back with float()


def test_a_file_that_is_not_json_is_named_with_its_line(tmp_path):
    path = tmp_path / "x.json"
    path.write_text('{\n  "a": Infinity,\n  "b": ]\n}')
    with pytest.raises(ValueError, match=r"x.json: not valid JSON \(line 3, column 8\)"):
        read_json(path, ValueError, where=str(path), missing="no file")


def test_a_key_given_twice_in_one_object_is_named_not_lost(tmp_path):
    """A plant file with its friction group written twice ran with the second's values only, the first's
    base_n dropped without a word; the same key in two different objects is fine."""
    from tapmuscle.io.plant_file import PlantFileError, read_plant_file

    path = tmp_path / "plant.json"
    path.write_text('{"plant": {"friction": {"base_n": 9.4}, "valve": {"cv_max": 1.3}, "friction": {"per_mpa_n": 31}}}')
    with pytest.raises(PlantFileError, match=rf"{path}.*key 'friction' is given twice in one object; JSON keeps only "
                                             r"the last"):
        read_plant_file(path)
    ok = tmp_path / "ok.json"
    ok.write_text('{"a": {"x": 1}, "b": {"x": 2}}')
    assert read_json(ok, ValueError, where="ok", missing="none") == {"a": {"x": 1}, "b": {"x": 2}}
