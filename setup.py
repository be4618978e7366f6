"""The one compiled part: the plant's integrator sub-step (fmu_plant/_ros34pw2.c), optional.

Everything else is in pyproject.toml. Without a C compiler the install still succeeds and the plant
runs its Python sub-step, which gives the same bits (fmu_plant/rosenbrock.py), only slower.
"""

import sys

from setuptools import Extension, setup

# Same bits as Python's float arithmetic: no fused multiply-add contraction, no reassociation.
FLAGS = ["/fp:precise"] if sys.platform == "win32" else ["-O2", "-ffp-contract=off", "-fno-fast-math"]

setup(ext_modules=[Extension("fmu_plant._ros34pw2", ["fmu_plant/_ros34pw2.c"], extra_compile_args=FLAGS,
                             optional=True)])
