"""Atomic outputs (tapmuscle/io/atomic.py): whole or nothing, and the user's umask."""

from __future__ import annotations

import os
import stat

import matplotlib.pyplot as plt
import pytest

from tapmuscle.io.atomic import atomic_path, staged_folder
from tapmuscle.io.recording import atomic_write_text
from tapmuscle.plots.figures import save_figure


@pytest.fixture
def umask():
    old = os.umask(0o022)
    os.umask(old)

    def set_mask(mask: int) -> None:
        os.umask(mask)
    yield set_mask
    os.umask(old)


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_outputs_get_the_users_umask(tmp_path, umask, mask, mode):
    umask(mask)
    atomic_write_text(tmp_path / "a.json", "{}\n")
    fig = plt.figure()
    save_figure(fig, tmp_path / "b.png")
    for name in ("a.json", "b.png"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == mode, name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.png"]  # no temporary left


def test_a_failure_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["out.csv"]


def test_a_directory_as_target_is_refused_by_name(tmp_path):
    (tmp_path / "out").mkdir()
    with pytest.raises(IsADirectoryError, match="out is a directory"):
        atomic_write_text(tmp_path / "out", "x")
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def _run_into(out, files, fail=False, owned=None):
    with staged_folder(out, owned=owned) as tmp:
        for name, text in files.items():
            atomic_write_text(tmp / name, text)
        if fail:
            raise RuntimeError("a figure failed")


def test_a_staged_folder_appears_whole_or_not_at_all(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        _run_into(out, {"a.json": "1"}, fail=True, owned=("*.json",))
    assert not out.exists() and list(tmp_path.iterdir()) == []
    _run_into(out, {"a.json": "1", "b.png": "x"}, owned=("*.json", "*.png"))
    with pytest.raises(RuntimeError):
        _run_into(out, {"a.json": "2"}, fail=True, owned=("*.json", "*.png"))
    assert (out / "a.json").read_text() == "1" and (out / "b.png").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging folder left


def test_a_staged_folder_removes_what_the_earlier_run_owned_and_keeps_the_rest(tmp_path):
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.png": "x", "exp_2.csv": "e"}, owned=("*.json", "*.png", "exp*.csv"))
    (out / "notes.txt").write_text("mine")
    _run_into(out, {"a.json": "2"}, owned=("*.json", "*.png", "exp*.csv"))
    assert sorted(p.name for p in out.iterdir()) == ["a.json", "notes.txt"]
    assert (out / "a.json").read_text() == "2"


def test_a_directory_in_a_files_place_fails_before_anything_changes(tmp_path):
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1"}, owned=("*.json", "*.md"))
    (out / "report.md").mkdir()
    with pytest.raises(IsADirectoryError, match="report.md is a directory"):
        _run_into(out, {"a.json": "2", "report.md": "r"}, owned=("*.json", "*.md"))
    assert (out / "a.json").read_text() == "1"


def test_without_owned_patterns_the_folder_is_replaced_whole(tmp_path):
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.json": "1"})
    _run_into(out, {"a.json": "2"})
    assert sorted(p.name for p in out.iterdir()) == ["a.json"]
    with pytest.raises(NotADirectoryError, match="is a file"):
        _run_into(out / "a.json", {"x": "1"})
