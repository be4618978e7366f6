"""The hostile-input corpus (tests/hostile/cases.toml): every case exits 2 with one line naming the
offending file, flag, key or value; no traceback, no output, nothing left behind."""

from __future__ import annotations

import re
import shutil
import tomllib
from pathlib import Path

import pytest

from tapmuscle.cli.main import main

HOSTILE = Path(__file__).resolve().parent / "hostile"
CASES = tomllib.loads((HOSTILE / "cases.toml").read_text())["case"]


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_hostile_input_gets_one_line_and_leaves_nothing(case, tmp_path, monkeypatch, capsys, request):
    work = tmp_path / "work"
    # the folder the outputs would go to is the test's, whatever the checkout's modes (read-only: a
    # copy2 would lend them)
    shutil.copytree(HOSTILE, work, copy_function=shutil.copyfile)
    work.chmod(0o755)
    monkeypatch.chdir(work)
    before = sorted(p.name for p in work.iterdir())
    argv = list(case["argv"])
    if argv[0] == "run" and "--fmu-dir" not in argv:  # the session's FMUs, not a build into the user's cache
        argv += ["--fmu-dir", str(request.getfixturevalue("built_fmus")["MusclePlant"].parent)]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    err = capsys.readouterr().err.strip()
    assert code == case.get("exit", 2), err
    assert "Traceback" not in err and len(err.splitlines()) == 1 and len(err) <= 300, err
    assert re.search(case["error"], err), err
    if "out" in case:
        assert not (work / case["out"]).exists()
    assert sorted(p.name for p in work.iterdir()) == before  # no output, no temporary file


def test_the_corpus_covers_every_command():
    commands = {c["argv"][0] for c in CASES}
    assert commands >= {"record", "identify", "diagnose", "demo-mismatch", "run", "sweep", "paper"}
