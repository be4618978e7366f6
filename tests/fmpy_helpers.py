"""Opening the project's FMUs in fmpy for tests: one place for the FMI start-up sequence."""

from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

#: What fmpy prints to stdout when it imports its FMI modules on a machine its logging helper is not
#: built for (fmpy 0.3's wheel has it for x86-64 Linux only: aarch64 prints it twice).
FMPY_IMPORT_NOTICE = "Failed to add logger proxy function."


def host_lines(stdout: str) -> list[str]:
    """The lines an fmpy child process printed itself: ``stdout`` without fmpy's import notice."""
    return [line for line in stdout.splitlines() if not line.startswith(FMPY_IMPORT_NOTICE)]


def open_fmu(path):
    """``(path, model description, extracted folder, {name: value reference})``."""
    md = read_model_description(str(path))
    return path, md, extract(str(path)), {v.name: v.valueReference for v in md.modelVariables}


def instantiate(fmu, name="i", reals=None, ints=None, *, rejected=False):
    """An initialised FMU2Slave of ``fmu`` (from :func:`open_fmu`) with parameters/inputs set.

    ``rejected``: the parameters are bad, so ``fmi2ExitInitializationMode`` must return fmi2Warning
    with the reason (not fmi2Error: libcosim would terminate), and every later step fmi2Error."""
    path, md, folder, vr = fmu
    f = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    f.instantiate(loggingOn=True)
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    for key, value in (reals or {}).items():
        f.setReal([vr[key]], [value])
    for key, value in (ints or {}).items():
        f.setInteger([vr[key]], [value])
    status = f.exitInitializationMode()
    assert status == (1 if rejected else 0), f"fmi2ExitInitializationMode returned status {status}"
    return f
