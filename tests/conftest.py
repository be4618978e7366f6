"""Shared fixtures and markers.

The FMUs are built once per test session (about 3 s). Every test that uses them is marked ``fmu``
here, so ``pytest -m "not fmu"`` runs the pure numerics without building anything; ``pytest -m "not
slow"`` is the quick run (under 30 s here). The other markers
(``slow``, ``dask``, ``c_host``) are set in the test modules; all four are registered in
``pyproject.toml``.
"""

import pytest


@pytest.fixture(scope="session")
def built_fmus(tmp_path_factory):
    """``{"MusclePlant": path, "AMPCController": path}`` built from this checkout."""
    from build_scripts.build_fmus import FMUS, build_fmus

    out = tmp_path_factory.mktemp("fmus")
    paths = build_fmus(out)
    return {name: path for name, path in zip(FMUS, paths)}


#: fixtures that make every test using them ``fmu`` or ``slow`` (the ``paper`` fixture of
#: tests/test_paper.py runs section 4's grid, about 5 s)
_FIXTURE_MARKS = {"built_fmus": "fmu", "paper": "slow"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        for fixture, mark in _FIXTURE_MARKS.items():
            if fixture in getattr(item, "fixturenames", ()):
                item.add_marker(getattr(pytest.mark, mark))
