"""What tests/test_windows_host.py asks of the FMUs in a Python host: run by a Windows Python (under
Wine) and by this machine's Python, the same script, so the two answers can be compared.

    python fmu_checks.py FMU_DIR OUT.json                    the plant alone, the closed loop (fmpy, libcosim,
                                                             and FMU_DIR/TapLoop.fmu, a container, if there)
    python fmu_checks.py FMU_DIR OUT.json non-ascii-folder   the plant unpacked into "Jürgen 日本 ..."
    python fmu_checks.py FMU_DIR OUT.json osqp               the controller in a Python that lacks osqp

fmpy's ``FMU2Slave`` (the FMI calls themselves, stable across fmpy releases) and, for a third-party
master, libcosimpy; the output is JSON, written at the end.
"""

import json
import math
import os
import sys
import tempfile

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

TS_S = 0.1


def _slave(fmu: str, name: str, messages: list, logging_on: bool = True, folder: str | None = None):
    md = read_model_description(fmu)
    where = extract(fmu, unzipdir=folder)

    def logger(env, instance, status, category, message):
        messages.append((int(status), (category or b"").decode("utf-8", "replace"),
                         (message or b"").decode("utf-8", "replace")))

    s = FMU2Slave(guid=md.guid, unzipDirectory=where, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    s.instantiate(loggingOn=logging_on, callbacks=_callbacks(logger))
    return s, {v.name: v.valueReference for v in md.modelVariables}


def _callbacks(logger):
    from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                           fmi2CallbackLoggerTYPE)
    from fmpy import calloc, free

    c = fmi2CallbackFunctions()
    c.logger = fmi2CallbackLoggerTYPE(logger)
    c.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    c.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    _KEEP.append(c)
    return c


_KEEP: list = []  # the ctypes callbacks live as long as the process


def _start(*slaves) -> None:
    for s in slaves:
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.exitInitializationMode()


def plant_alone(fmu: str, folder: str | None = None) -> dict:
    """The plant at u = 5 V for 10 s: its encoder reading and (unquantised) pressure at the end."""
    messages: list = []
    p, vr = _slave(fmu, "plant", messages, folder=folder)
    _start(p)
    p.setReal([vr["u"]], [5.0])
    for k in range(100):
        p.doStep(k * TS_S, TS_S)
    l_mm, p_mpa = p.getReal([vr["l"], vr["p"]])
    p.terminate()
    p.freeInstance()
    return {"l_mm": l_mm, "p_mpa": p_mpa, "folder": folder or ""}


def closed_loop(fmus: dict, parallel: bool, duration_s: float = 60.0) -> dict:
    """The plant and the controller (its built-in 35 + 30 sin(2 pi 0.1 t) mm) at h = Ts: sequential
    (controller, then plant) or parallel (both on the previous outputs, as libcosim and Ecos step)."""
    messages: list = []
    p, pv = _slave(fmus["MusclePlant"], "plant", messages)
    c, cv = _slave(fmus["AMPCController"], "ctrl", messages)
    _start(p, c)
    l_mm = p.getReal([pv["l"]])[0]
    u_v = c.getReal([cv["u"]])[0]
    t, rows = 0.0, []
    for k in range(int(round(duration_s / TS_S))):
        l_k = l_mm  # the l(k) the controller takes with r(k), Eq. (21)
        if parallel:
            c.setReal([cv["l"]], [l_mm])
            p.setReal([pv["u"]], [u_v])
            c.doStep(t, TS_S)
            p.doStep(t, TS_S)
            u_v, l_mm = c.getReal([cv["u"]])[0], p.getReal([pv["l"]])[0]
        else:
            c.setReal([cv["l"]], [l_mm])
            c.doStep(t, TS_S)
            u_v = c.getReal([cv["u"]])[0]
            p.setReal([pv["u"]], [u_v])
            p.doStep(t, TS_S)
            l_mm = p.getReal([pv["l"]])[0]
        t = (k + 1) * TS_S
        rows.append((t - TS_S, l_k, u_v, c.getReal([cv["r_k"]])[0]))
    for s in (c, p):
        s.terminate()
        s.freeInstance()
    after = [abs(r - l) for t_s, l, _u, r in rows if t_s >= 20.0 - 1e-9]
    return {"mae_20_60_mm": sum(after) / len(after), "u_min_v": min(r[2] for r in rows),
            "u_max_v": max(r[2] for r in rows), "finite": all(math.isfinite(x) for r in rows for x in r),
            "l_mm": [r[1] for r in rows]}


def libcosim_loop(fmus: dict, duration_s: float = 60.0) -> dict:
    """The closed loop in libcosim (``libcosimpy``: the Open Simulation Platform's C++ master, which steps
    the FMUs in parallel), h = Ts, the controller's defaults."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    ex = CosimExecution.from_step_size(step_size=int(round(TS_S * 1e9)))
    observer = CosimObserver.create_last_value()
    ex.add_observer(observer)
    index, vr = {}, {}
    for name, fmu in (("plant", fmus["MusclePlant"]), ("ctrl", fmus["AMPCController"])):
        index[name] = ex.add_local_slave(CosimLocalSlave(fmu_path=fmu, instance_name=name))
        vr[name] = {v.name.decode(): v.reference for v in ex.slave_variables(index[name])}
    ex.connect_real_variables(index["plant"], vr["plant"]["l"], index["ctrl"], vr["ctrl"]["l"])
    ex.connect_real_variables(index["ctrl"], vr["ctrl"]["u"], index["plant"], vr["plant"]["u"])

    def real(name: str, var: str) -> float:
        return observer.last_real_values(index[name], [vr[name][var]])[0]

    rows, l_k = [], 0.0
    for k in range(int(round(duration_s / TS_S))):
        if not ex.step(1):
            return {"stepped": k}
        # the controller took l(k) (the plant's output before this step) with r(k)
        rows.append((k * TS_S, l_k, real("plant", "u"), real("ctrl", "r_k")))
        l_k = real("plant", "l")
    after = [abs(r - l) for t_s, l, _u, r in rows if t_s >= 20.0 - 1e-9]
    return {"stepped": len(rows), "mae_20_60_mm": sum(after) / len(after),
            "u_min_v": min(r[2] for r in rows), "u_max_v": max(r[2] for r in rows)}


class _Missing:
    """An import hook: ``name`` is not installed, as in a tool's own Python environment."""

    def __init__(self, name: str) -> None:
        self.name = name

    def find_spec(self, fullname, path=None, target=None):
        if fullname == self.name or fullname.startswith(self.name + "."):
            raise ModuleNotFoundError(f"No module named '{fullname}'", name=fullname)
        return None


def missing_package(fmu: str, package: str) -> dict:
    """The controller where ``package`` cannot be imported, with logging off (fmpy's default)."""
    sys.meta_path.insert(0, _Missing(package))
    messages: list = []
    out: dict = {"instantiated": False}
    try:
        c, cv = _slave(fmu, "ctrl", messages, logging_on=False)
        out["instantiated"] = True
        try:
            _start(c)
            c.doStep(0.0, TS_S)
            out["step"] = "ok"
        except FMICallException as e:  # a status above Warning
            out["step"] = f"{type(e).__name__}: {e}"
        c.freeInstance()
    except Exception as e:  # noqa: BLE001 - fmpy raises a bare Exception for a NULL instance
        out["instantiate_error"] = f"{type(e).__name__}: {e}"
    out["messages"] = messages
    return out


def container_loop(fmu: str, duration_s: float = 60.0) -> dict:
    """The closed loop as one FMU made by fmu-manipulation-toolbox's ``fmucontainer`` (its C++ container
    steps the two FMUs in parallel in one thread), run by fmpy, h = Ts, the controller's defaults."""
    from fmpy import simulate_fmu

    res = simulate_fmu(fmu, stop_time=duration_s, output_interval=TS_S, output=["l", "u"])
    rows = [(float(t), float(l_mm), float(u_v)) for t, l_mm, u_v in zip(res["time"], res["l"], res["u"])]
    after = [abs(35.0 + 30.0 * math.sin(2 * math.pi * 0.1 * t) - l_mm) for t, l_mm, _u in rows if t >= 20.0 - 1e-9]
    return {"mae_20_60_mm": sum(after) / len(after), "u_min_v": min(r[2] for r in rows),
            "u_max_v": max(r[2] for r in rows), "finite": all(math.isfinite(x) for r in rows for x in r)}


def main(argv: list[str]) -> None:
    fmu_dir, out = argv[1], argv[2]
    fmus = {n: os.path.join(fmu_dir, n + ".fmu") for n in ("MusclePlant", "AMPCController")}
    if len(argv) > 3 and argv[3] == "non-ascii-folder":
        odd = tempfile.mkdtemp(prefix="J\u00fcrgen \u65e5\u672c ")  # a user folder as Windows users have them
        result = {"plant": plant_alone(fmus["MusclePlant"], os.path.join(odd, "MusclePlant"))}
    elif len(argv) > 3:
        result = {"missing": missing_package(fmus["AMPCController"], argv[3])}
    else:
        result = {"platform": sys.platform, "plant": plant_alone(fmus["MusclePlant"]),
                  "sequential": closed_loop(fmus, parallel=False), "parallel": closed_loop(fmus, parallel=True),
                  "libcosim": libcosim_loop(fmus)}
        if os.path.isfile(os.path.join(fmu_dir, "TapLoop.fmu")):
            result["container"] = container_loop(os.path.join(fmu_dir, "TapLoop.fmu"))
    with open(out, "w", encoding="utf-8") as f:
        json.dump(result, f)


if __name__ == "__main__":
    main(sys.argv)
