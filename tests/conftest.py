"""Shared fixtures: the FMUs are built once per test session (about 3 s)."""

import pytest


@pytest.fixture(scope="session")
def built_fmus(tmp_path_factory):
    """``{"MusclePlant": path, "AMPCController": path}`` built from this checkout."""
    from build_scripts.build_fmus import FMUS, build_fmus

    out = tmp_path_factory.mktemp("fmus")
    paths = build_fmus(out)
    return {name: path for name, path in zip(FMUS, paths)}
