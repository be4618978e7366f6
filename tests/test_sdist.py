"""The source distribution (``python -m build --sdist``): every file git tracks but the CI scripts.

A packager builds the wheel from the sdist and runs the tests there (conda-forge's recipes do), so a
test module without its ``conftest.py``, its C hosts or its data files, or a docs figure the README
links to, is a broken release. check-manifest builds the sdist from the tracked files and compares the
two lists; it runs with this environment's setuptools (the test extra pins the build's), offline.
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def _tracked_copy(folder: Path) -> Path:
    """The tracked files of the checkout, as they are in the working tree, and its ``.git``, copied into
    ``folder``: check-manifest builds a first sdist where it is run, writing ``tapmuscle.egg-info`` there,
    and the tests write only under pytest's temporary folders (the tree may be read-only)."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for name in filter(None, listed.split(b"\0")):
        source, target = ROOT / os.fsdecode(name), folder / os.fsdecode(name)
        if source.is_file():  # a tracked file deleted from the tree is check-manifest's to name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    shutil.copytree(ROOT / ".git", folder / ".git", symlinks=True)
    return folder


def test_the_sdist_holds_every_tracked_file_but_the_ci_scripts(tmp_path):
    if not (ROOT / ".git").is_dir() or shutil.which("git") is None:
        pytest.skip(f"{ROOT} is not a git checkout (an unpacked sdist, a worktree?): no tracked files to compare with")
    proc = subprocess.run([sys.executable, "-m", "check_manifest", "--no-build-isolation", str(_tracked_copy(tmp_path / "src"))],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "lists of files in version control and sdist match" in proc.stdout, proc.stdout


def test_the_citation_file_names_the_packages_version():
    """CITATION.cff's version is the release's: a citation of another version points a reader at
    other code (the file is YAML; its one ``version:`` line is read without a YAML parser)."""
    import re
    import tomllib

    root = Path(__file__).resolve().parents[1]
    version = tomllib.loads((root / "pyproject.toml").read_text())["project"]["version"]
    cited = re.findall(r'^version:\s*"?([^"\n]+)"?\s*$', (root / "CITATION.cff").read_text(), flags=re.M)
    assert cited == [version]
