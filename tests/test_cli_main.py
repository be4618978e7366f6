"""The ``tapmuscle`` command itself (tapmuscle/cli/main.py): what it says about its versions."""

import platform
import re
import subprocess
import sys
import sysconfig

import numpy as np
import pytest
import scipy

import tapmuscle
from fmu_plant.rosenbrock import COMPILED
from tapmuscle.cli.main import main


def test_version_names_tapmuscle_python_the_numerics_and_the_sub_step(capsys):
    with pytest.raises(SystemExit) as ended:
        main(["--version"])
    assert ended.value.code == 0
    out, err = capsys.readouterr()
    assert err == ""
    found = re.fullmatch(r"tapmuscle (\S+) \(Python (\S+); numpy (\S+), scipy (\S+), osqp \S+, pythonfmu \S+, "
                         r"fmpy \S+; compiled sub-step (yes|no)(; libpython shared|; libpython static: FMUs for "
                         r"Python hosts only)?\)\n", out)
    assert found, out
    shared = bool(sysconfig.get_config_var("Py_ENABLE_SHARED"))
    libpython = None if not sys.platform.startswith("linux") else \
        "; libpython shared" if shared else "; libpython static: FMUs for Python hosts only"
    assert found.groups() == (tapmuscle.__version__, platform.python_version(), np.__version__, scipy.__version__,
                              "yes" if COMPILED else "no", libpython)


def test_version_from_the_installed_command_needs_no_subcommand():
    done = subprocess.run([sys.executable, "-m", "tapmuscle", "--version"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith(f"tapmuscle {tapmuscle.__version__} (Python "), done
