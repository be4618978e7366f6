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



def test_the_one_line_form_names_every_release_and_takes_a_documents():
    from tapmuscle.provenance import software_text

    found = software() | {"numpy": "1.26.0", "osqp": "1.1.2"}  # as read back from an older document
    line = software_text(found, more=["libpython shared"])
    assert line.startswith(f"tapmuscle {found['tapmuscle']} (Python {found['python']}; numpy 1.26.0, scipy ")
    assert ", osqp 1.1.2, pythonfmu " in line and line.endswith(f"; {found['machine']}; compiled sub-step "
                                                                f"{found['compiled_substep']}; libpython shared)")
