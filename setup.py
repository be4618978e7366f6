"""The compiled parts, both optional: the plant's integrator sub-step (fmu_plant/_ros34pw2.c) and the
master's logger for FMUs whose messages carry printf arguments (tapmuscle/cosim/_fmi_log.c).

Everything else is in pyproject.toml. Without a C compiler the install still succeeds: the plant
runs its Python sub-step, which gives the same bits (fmu_plant/rosenbrock.py), only slower, and such
an FMU's messages are shown as their formats.
"""

import sys

from setuptools import Extension, setup

# Same bits as Python's float arithmetic: no fused multiply-add contraction, no reassociation.
FLAGS = ["/fp:precise"] if sys.platform == "win32" else ["-O2", "-ffp-contract=off", "-fno-fast-math"]

setup(ext_modules=[Extension("fmu_plant._ros34pw2", ["fmu_plant/_ros34pw2.c"], extra_compile_args=FLAGS,
                             optional=True),
                   Extension("tapmuscle.cosim._fmi_log", ["tapmuscle/cosim/_fmi_log.c"], optional=True)])
