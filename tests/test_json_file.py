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
