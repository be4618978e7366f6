"""Shared fixtures and markers.

The FMUs are built once per test session (about 3 s). Every test that uses them is marked ``fmu``
here, so ``pytest -m "not fmu"`` runs the pure numerics without building anything; ``pytest -m "not
slow"`` is the quick run (about 1-2 min on two cores). The other markers
(``slow``, ``dask``, ``c_host``) are set in the test modules; all four are registered in
``pyproject.toml``.
"""

import os
import signal
import sys
import tempfile

import pytest

#: the SIGINT handler the test process started with (Python's; None: not installed from Python)
_SIGINT_AT_START = signal.getsignal(signal.SIGINT)


@pytest.fixture(scope="session", autouse=True)
def _temporary_directory_of_the_run(tmp_path_factory):
    """The temporary directory of this process and of every process it starts (subprocesses, Jupyter
    kernels, Dask workers) is a folder of pytest's base directory, which pytest keeps for the last 3
    runs only: what the hosts under test extract and leave there (fmpy's ``extract()`` without a
    folder, the SSP Ecos unpacks into ``ecos_ssp_<uuid>`` and keeps) does not pile up in the
    machine's ``/tmp``, run after run."""
    folder = tmp_path_factory.mktemp("TMPDIR", numbered=False)
    before = os.environ.get("TMPDIR"), tempfile.tempdir
    os.environ["TMPDIR"] = str(folder)
    tempfile.tempdir = None  # gettempdir() reads TMPDIR again
    yield folder
    if before[0] is None:
        os.environ.pop("TMPDIR", None)
    else:
        os.environ["TMPDIR"] = before[0]
    tempfile.tempdir = before[1]


@pytest.fixture(autouse=True)
def _sigint_handler_left_as_found(request):
    """Every test starts with the SIGINT handler this process started with, and a test that leaves it
    changed (or a fixture or thread that changed it before the test) is named in a warning. The
    next tests of the worker would otherwise run with Ctrl-C ignored, and those that raise a signal
    and expect KeyboardInterrupt would fail for a neighbour's reason (a library call that did so in a
    notebook would leave its user without Ctrl-C)."""
    import signal
    import threading
    import warnings

    if threading.current_thread() is not threading.main_thread() or _SIGINT_AT_START is None:
        yield
        return
    found = signal.getsignal(signal.SIGINT)
    if found is not _SIGINT_AT_START:
        signal.signal(signal.SIGINT, _SIGINT_AT_START)
        warnings.warn(f"SIGINT's handler was {found!r} when {request.node.nodeid} began (its fixtures set up, "
                      f"or an earlier test's leftovers): {_SIGINT_AT_START!r} put back", RuntimeWarning, stacklevel=1)
    yield
    after = signal.getsignal(signal.SIGINT)
    if after is not _SIGINT_AT_START:
        signal.signal(signal.SIGINT, _SIGINT_AT_START)
        warnings.warn(f"{request.node.nodeid} left SIGINT's handler {after!r}; {_SIGINT_AT_START!r} put back",
                      RuntimeWarning, stacklevel=1)


@pytest.fixture
def python_sigint_handler():
    """Python's own SIGINT handler (KeyboardInterrupt) for the test, the inherited disposition put
    back after: a test about what Ctrl-C does needs it, and a test run started with SIGINT ignored
    (nohup, a shell's background job, some CI runners) starts without it."""
    inherited = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, inherited)


@pytest.fixture(scope="session")
def built_fmus(tmp_path_factory):
    """``{"MusclePlant": path, "AMPCController": path}`` built from this checkout (what a tool missing
    for other hosts' binaries left out is not warned of: the tests of those hosts check it, and
    ``pytest -W error`` would fail every FMU test here)."""
    import warnings

    from build_scripts.build_fmus import FMUS, build_fmus
    from build_scripts.native_host import NativeHostWarning

    out = tmp_path_factory.mktemp("fmus")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NativeHostWarning)
        paths = build_fmus(out)
    return {name: path for name, path in zip(FMUS, paths)}


#: fixtures that make every test using them ``fmu`` or ``slow`` (the ``paper`` fixture of
#: tests/test_paper.py runs section 4's grid, about 5 s)
_FIXTURE_MARKS = {"built_fmus": "fmu", "paper": "slow"}


#: Whether file names with non-ASCII characters can be made here: under a Latin-1 locale Python
#: encodes paths in it, and a test's folder named "日本" cannot exist.
UTF8_PATHS = sys.getfilesystemencoding().lower().replace("-", "") == "utf8"


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """``-n N`` hands out the tests by work stealing (a long test does not hold back a worker's
    queue), unless ``--dist`` says otherwise. Set here rather than in addopts, where xdist's option
    would stop pytest without xdist (``-p no:xdist``, a bare ``pip install pytest``)."""
    if getattr(config.option, "numprocesses", None) and getattr(config.option, "dist", "no") == "no":
        config.option.dist = "worksteal"


def pytest_collection_modifyitems(config, items):
    for item in items:
        for fixture, mark in _FIXTURE_MARKS.items():
            if fixture in getattr(item, "fixturenames", ()):
                item.add_marker(getattr(pytest.mark, mark))
        if item.get_closest_marker("utf8_paths") is not None and not UTF8_PATHS:
            item.add_marker(pytest.mark.skip(reason=f"non-ASCII folder names under a {sys.getfilesystemencoding()} "
                                                    "file-system encoding (a UTF-8 locale runs it)"))
    # The slow tests first (stable otherwise): with `-n auto` the long diagnosis runs start early and the
    # quick tests fill the gaps, instead of a long one starting last while the other core idles.
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
