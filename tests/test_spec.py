"""Scenario and sweep files as read (tapmuscle/cosim/spec.py): what a file from elsewhere can make
the reader do; the scenario schema's own tests are in tests/test_scenarios.py."""

import pytest


def test_a_file_nested_too_deep_to_read_is_named_not_a_traceback(tmp_path):
    """tomllib recurses once per level of nesting: 100,000 nested arrays ended in a RecursionError."""
    from tapmuscle.cosim.spec import ScenarioError, load_scenario

    path = tmp_path / "deep.toml"
    path.write_text("x = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ScenarioError, match=r"deep.toml: not a scenario file: its arrays or tables are nested too deep"):
        load_scenario(path)
