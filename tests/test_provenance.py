"""The software versions written into tapmuscle's JSON documents (tapmuscle/provenance.py)."""

import json
import platform

import numpy as np
import osqp
import scipy

import tapmuscle
from fmu_plant.rosenbrock import COMPILED
from tapmuscle.provenance import NUMERICS_PACKAGES, package_version, software


def test_software_names_the_releases_that_run_here():
    found = software()
    assert set(found) == {"tapmuscle", "python", *NUMERICS_PACKAGES, "machine", "compiled_substep"}
    # the imported modules' own versions: the distributions found are the ones that compute
    assert (found["tapmuscle"], found["numpy"], found["scipy"], found["osqp"]) == \
        (tapmuscle.__version__, np.__version__, scipy.__version__, osqp.__version__)
    assert found["python"] == platform.python_version()
    assert found["machine"] == f"{platform.system()} {platform.machine()}"
    assert found["compiled_substep"] == ("yes" if COMPILED else "no")
    json.dumps(found, allow_nan=False)  # plain strings, for every document


def test_a_package_that_is_not_installed_is_said_so():
    assert package_version("tapmuscle-no-such-distribution") == "not installed"

