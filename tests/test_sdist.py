"""The source distribution (``python -m build --sdist``): every file git tracks but the CI scripts.

A packager builds the wheel from the sdist and runs the tests there (conda-forge's recipes do), so a
test module without its ``conftest.py``, its C hosts or its data files, or a docs figure the README
links to, is a broken release. check-manifest builds the sdist from the tracked files and compares the
two lists; it runs with this environment's setuptools (the test extra pins the build's), offline.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def test_the_sdist_holds_every_tracked_file_but_the_ci_scripts():
    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        pytest.skip(f"{ROOT} is not a git checkout (an unpacked sdist?): no list of tracked files to compare with")
    proc = subprocess.run([sys.executable, "-m", "check_manifest", "--no-build-isolation", str(ROOT)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "lists of files in version control and sdist match" in proc.stdout, proc.stdout
