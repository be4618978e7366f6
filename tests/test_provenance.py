"""The software versions written into tapmuscle's JSON documents (tapmuscle/provenance.py)."""

import json
import platform
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import osqp
import scipy

import tapmuscle
from fmu_plant.rosenbrock import COMPILED
from tapmuscle.provenance import NUMERICS_PACKAGES, cpu_features, package_version, software, source_revision


def test_software_names_the_releases_that_run_here():
    found = software()
    expected = {"tapmuscle", "python", *NUMERICS_PACKAGES, "matplotlib", "machine", "cpu_features", "compiled_substep"}
    # "source" where tapmuscle is imported from a git checkout (this one's editable install)
    assert set(found) - {"source"} == expected
    assert ("source" in found) == (Path(tapmuscle.__file__).resolve().parents[1] / ".git").exists()
    import matplotlib

    assert found["matplotlib"] == matplotlib.__version__
    # the imported modules' own versions: the distributions found are the ones that compute
    assert (found["tapmuscle"], found["numpy"], found["scipy"], found["osqp"]) == \
        (tapmuscle.__version__, np.__version__, scipy.__version__, osqp.__version__)
    assert found["python"] == platform.python_version()
    assert found["machine"] == f"{platform.system()} {platform.machine()}"
    assert found["compiled_substep"] == ("yes" if COMPILED else "no")
    json.dumps(found, allow_nan=False)  # plain strings, for every document


def test_a_package_that_is_not_installed_is_said_so():
    assert package_version("tapmuscle-no-such-distribution") == "not installed"



def test_the_one_line_form_names_every_release_and_takes_a_documents():
    from tapmuscle.provenance import software_text

    # as read back from a document of an earlier release: no matplotlib, CPU features or source
    found = {k: v for k, v in software().items() if k not in ("matplotlib", "cpu_features", "source")} \
        | {"numpy": "1.26.0", "osqp": "1.1.2"}
    line = software_text(found, more=["libpython shared"])
    assert line.startswith(f"tapmuscle {found['tapmuscle']} (Python {found['python']}; numpy 1.26.0, scipy ")
    assert ", osqp 1.1.2, pythonfmu " in line and line.endswith(f"; {found['machine']}; compiled sub-step "
                                                                f"{found['compiled_substep']}; libpython shared)")
    # today's: the commit it ran from and the CPU's SIMD levels too
    line = software_text(found | {"cpu_features": "X86_V3", "source": "0123456789ab with changes"})
    assert line.startswith(f"tapmuscle {found['tapmuscle']} from 0123456789ab with changes (Python ")
    assert f"; {found['machine']} (X86_V3); compiled sub-step" in line


def test_the_cpu_features_are_numpys_dispatch_levels_left_on(monkeypatch):
    """The SIMD level that changes a chaotic loop's last bits: numpy's own record, fewer levels with
    NPY_DISABLE_CPU_FEATURES (as .ci/run's second pass), in a child (numpy reads it at import)."""
    import sys

    here = cpu_features()
    assert here != "unknown" and here.replace(" ", "").replace("_", "").isalnum()
    if here == "baseline":
        return
    child = subprocess.run([sys.executable, "-c", "from tapmuscle.provenance import cpu_features; print(cpu_features())"],
                           env={**__import__("os").environ, "NPY_DISABLE_CPU_FEATURES": here}, capture_output=True,
                           text=True, check=True)
    assert child.stdout.strip() == "baseline"


@pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")
def test_a_checkouts_commit_and_its_changes_are_named(tmp_path, monkeypatch):
    """A copy of the package in a new git repository: its commit, "with changes" once a tracked file
    changes (an untracked one does not count); no source outside a checkout."""
    import tapmuscle.provenance as provenance

    pkg = tmp_path / "repo" / "tapmuscle"
    pkg.mkdir(parents=True)
    shutil.copy(provenance.__file__, pkg / "provenance.py")
    monkeypatch.setattr(provenance, "__file__", str(pkg / "provenance.py"))
    assert source_revision() is None
    git = ["git", "-C", str(tmp_path / "repo"), "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    subprocess.run(git + ["init", "-q"], check=True)
    subprocess.run(git + ["add", "."], check=True)
    subprocess.run(git + ["commit", "-q", "-m", "c"], check=True)
    head = subprocess.run(git + ["rev-parse", "--short=12", "HEAD"], capture_output=True, text=True).stdout.strip()
    (pkg / "new.py").write_text("untracked\n")
    assert source_revision() == head and len(head) == 12
    (pkg / "provenance.py").write_text("changed\n")
    assert source_revision() == f"{head} with changes"
    assert software()["source"] == f"{head} with changes"
    # a git hook that runs tapmuscle exports another repository's GIT_DIR: this checkout is still named
    other = tmp_path / "other"
    subprocess.run(["git", "init", "-q", str(other)], check=True)
    monkeypatch.setenv("GIT_DIR", str(other / ".git"))
    assert source_revision() == f"{head} with changes"


@pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")
def test_a_package_folder_that_another_repository_does_not_track_names_no_commit(tmp_path, monkeypatch):
    """``pip install --target`` into a project of one's own, or a copied folder: the project's repository
    holds the folder without tracking it, and its commit is not tapmuscle's."""
    import tapmuscle.provenance as provenance

    pkg = tmp_path / "project" / "tapmuscle"
    pkg.mkdir(parents=True)
    shutil.copy(provenance.__file__, pkg / "provenance.py")
    monkeypatch.setattr(provenance, "__file__", str(pkg / "provenance.py"))
    git = ["git", "-C", str(tmp_path / "project"), "-c", "user.name=t", "-c", "user.email=t@t", "-c",
           "commit.gpgsign=false"]
    subprocess.run(git + ["init", "-q"], check=True)
    (tmp_path / "project" / "mine.txt").write_text("the project's own\n")
    subprocess.run(git + ["add", "mine.txt"], check=True)
    subprocess.run(git + ["commit", "-q", "-m", "c"], check=True)
    assert source_revision() is None


def test_a_document_written_by_a_command_names_the_command(tmp_path):
    """The console script's arguments beside the software, quoted for a shell; a call of the API
    writes none."""
    from tapmuscle.cli.main import main
    from tapmuscle.provenance import invoked_as, produced_by

    assert "command" not in produced_by()
    with invoked_as(["paper", "--out", "my out"]):
        assert produced_by() == {"software": software(), "command": "tapmuscle paper --out 'my out'"}
    assert "command" not in produced_by()
    rec = tmp_path / "rec 1.csv"
    assert main(["record", "--input", "sine:bias=5,amp=3,freq=0.1", "--duration", "30",
                 "--out", str(rec), "--quiet"]) == 0
    out = tmp_path / "id.json"
    assert main(["identify", str(rec), "--json", str(out), "--quiet"]) == 0
    doc = json.loads(out.read_text())
    assert doc["command"] == f"tapmuscle identify '{rec}' --json {out} --quiet" and doc["software"] == software()


def test_the_code_digest_follows_the_sources_not_the_folder_they_are_in(tmp_path):
    """The same sources elsewhere (a wheel's site-packages, another checkout) give the same digest; one
    changed character in one module gives another, though the version is the same."""
    import os
    import sys

    from tapmuscle.provenance import CODE_PACKAGES, code_digest

    root = Path(tapmuscle.__file__).resolve().parents[1]
    copy = tmp_path / "site-packages"
    for name in CODE_PACKAGES:
        shutil.copytree(root / name, copy / name, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    probe = ["-c", "import tapmuscle, tapmuscle.provenance as p; print(p.code_digest(), tapmuscle.__file__)"]

    def digest_there() -> list[str]:
        env = dict(os.environ, PYTHONPATH=str(copy), PYTHONDONTWRITEBYTECODE="1")
        return subprocess.run([sys.executable, *probe], capture_output=True, text=True, env=env, check=True,
                              cwd=tmp_path).stdout.split()

    digest, where = digest_there()
    assert Path(where).is_relative_to(copy) and digest == code_digest()
    expect = copy / "tapmuscle" / "cosim" / "expect.py"
    expect.write_text(expect.read_text() + "\n")
    assert digest_there()[0] != digest
