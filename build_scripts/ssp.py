"""``TapMuscleLoop.ssp``: both FMUs as one closed loop for SSP tools (System Structure and
Parameterization 1.0).

The archive holds ``SystemStructure.ssd`` and ``resources/``: the two FMUs, one parameter-value file
per load (``load_44N.ssv``, ``load_68N.ssv``: the plant's hanging load, the paper's two) and
``parallel_master.ssv`` (the controller's ``input_delay_samples = 1``). The system connects plant
``l`` -> controller ``l`` and controller ``u`` -> plant ``u`` (docs/fmu.md), binds the 44 N set to the
plant and the parallel-master set to the controller (component-level bindings, which libcosim reads),
and carries the default experiment (0..60 s); SSP tools step it at Ts = 0.1 s. The SSD and
the SSV files are checked against the SSP 1.0 schemas that fmpy ships before the archive is written.

SSP tools (libcosim, Ecos, OMSimulator) step the components in parallel, which applies the
controller's command one step late, hence ``input_delay_samples = 1`` (docs/fmu.md, "Parallel
masters"); in a sequential master unbind it (or set it to 0).

A rig's plant file (``tapmuscle build --ssp --params FILE``: a digital twin of that rig) adds
``rig.ssv``, every parameter of the file, bound to the plant in the 44-N set's place, and a set of
the same name for the controller, ``rig_controller.ssv``, whose ``input_delay_samples`` is the
parallel master's sample plus the file's transport delay in samples (bound to the controller in the
parallel-master set's place): libcosim applies every bound set, Ecos the sets of the name its
``init(parameter_set=...)`` gives, so ``"rig"`` gives both components theirs.
"""

from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from typing import Mapping

__all__ = ["SSP_NAME", "LOADS_N", "RIG_SET", "ssd_text", "ssv_files", "write_ssp"]

SSP_NAME = "TapMuscleLoop.ssp"
#: The parameter sets written: hanging load [N] (paper, Table 1).
LOADS_N = (44.0, 68.0)
#: The name of the parameter sets of a rig's plant file (module docstring).
RIG_SET = "rig"
#: The sample a parallel master adds to the loop (docs/fmu.md, "Parallel masters").
PARALLEL_MASTER_SAMPLES = 1

_NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
       "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
       "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues"}
for _prefix, _uri in _NS.items():
    ET.register_namespace(_prefix, _uri)

#: Components: name in the system -> (FMU, connectors as (name, kind)). Every input connector is
#: connected: fmpy's SSP runner (``fmpy.ssp.simulation.simulate_ssp``) wires an unconnected one to the
#: source of the connection found before it (the plant's load and supply pressure to the command in
#: volts, the controller's reference to the displacement). The plant's other inputs keep their start
#: values or take the bound parameter set's (``load_force``), which the SSP tools apply by variable name.
_COMPONENTS = {
    "plant": ("MusclePlant", (("u", "input"), ("l", "output"), ("p", "output"))),
    "controller": ("AMPCController", (("l", "input"), ("u", "output"), ("r_k", "output"),
                                      ("input_delay_samples", "parameter"))),
}
_INTEGERS = {"input_delay_samples"}
_CONNECTIONS = (("plant", "l", "controller", "l"), ("controller", "u", "plant", "u"))


def _q(prefix: str, tag: str) -> str:
    return f"{{{_NS[prefix]}}}{tag}"


def _parameter_set(name: str, values: Mapping[str, float | int]) -> str:
    """An SSV parameter set; an int value is an Integer parameter, a float a Real one."""
    root = ET.Element(_q("ssv", "ParameterSet"), {"version": "1.0", "name": name})
    params = ET.SubElement(root, _q("ssv", "Parameters"))
    for pname, value in values.items():
        p = ET.SubElement(params, _q("ssv", "Parameter"), {"name": pname})
        if isinstance(value, int):
            ET.SubElement(p, _q("ssv", "Integer"), {"value": str(value)})
        else:
            ET.SubElement(p, _q("ssv", "Real"), {"value": repr(float(value))})
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def ssv_files(rig: Mapping[str, float] | None = None, rig_delay_samples: int = 0) -> dict[str, str]:
    """``resources/<file>.ssv`` -> text: the plant's load sets and the controller's parallel-master
    set; with ``rig`` (MusclePlant parameter name -> value, a plant file's), the rig's two sets too,
    the controller's compensating ``rig_delay_samples`` (the rig's transport delay in samples of the
    controller's Ts) beside the parallel master's sample."""
    files = {f"resources/load_{load:g}N.ssv": _parameter_set(f"load_{load:g}N", {"load_force": float(load)})
             for load in LOADS_N}
    # SSP tools step the components in parallel: the controller compensates that sample of delay
    files["resources/parallel_master.ssv"] = _parameter_set("parallel_master",
                                                            {"input_delay_samples": PARALLEL_MASTER_SAMPLES})
    if rig is not None:
        # every plant parameter is a Real (an int from a JSON file would be written as an Integer)
        files[f"resources/{RIG_SET}.ssv"] = _parameter_set(RIG_SET, {k: float(v) for k, v in rig.items()})
        files[f"resources/{RIG_SET}_controller.ssv"] = _parameter_set(
            RIG_SET, {"input_delay_samples": PARALLEL_MASTER_SAMPLES + int(rig_delay_samples)})
    return files


def _bindings(rig: bool) -> dict[str, str]:
    """Which parameter set each component binds (component-level bindings, as libcosim reads them)."""
    if rig:
        return {"plant": f"resources/{RIG_SET}.ssv", "controller": f"resources/{RIG_SET}_controller.ssv"}
    return {"plant": f"resources/load_{LOADS_N[0]:g}N.ssv", "controller": "resources/parallel_master.ssv"}


def ssd_text(stop_time_s: float = 60.0, *, rig: bool = False) -> str:
    """The system structure: both components with their parameter sets bound (the rig's with
    ``rig``), the two connections, the default experiment."""
    root = ET.Element(_q("ssd", "SystemStructureDescription"), {"version": "1.0", "name": "TapMuscleLoop"})
    system = ET.SubElement(root, _q("ssd", "System"), {
        "name": "TapMuscleLoop",
        "description": "tap-water McKibben muscle (MusclePlant) under AMPC displacement control (AMPCController)"})
    elements = ET.SubElement(system, _q("ssd", "Elements"))
    for name, (fmu, connectors) in _COMPONENTS.items():
        comp = ET.SubElement(elements, _q("ssd", "Component"), {
            "name": name, "type": "application/x-fmu-sharedlibrary", "source": f"resources/{fmu}.fmu"})
        cons = ET.SubElement(comp, _q("ssd", "Connectors"))
        for cname, kind in connectors:
            c = ET.SubElement(cons, _q("ssd", "Connector"), {"name": cname, "kind": kind})
            ET.SubElement(c, _q("ssc", "Integer" if cname in _INTEGERS else "Real"))
        bindings = ET.SubElement(comp, _q("ssd", "ParameterBindings"))
        ET.SubElement(bindings, _q("ssd", "ParameterBinding"),
                      {"type": "application/x-ssp-parameter-set", "source": _bindings(rig)[name]})
    conns = ET.SubElement(system, _q("ssd", "Connections"))
    for a, ca, b, cb in _CONNECTIONS:
        ET.SubElement(conns, _q("ssd", "Connection"),
                      {"startElement": a, "startConnector": ca, "endElement": b, "endConnector": cb})
    ET.SubElement(root, _q("ssd", "DefaultExperiment"), {"startTime": "0.0", "stopTime": repr(float(stop_time_s))})
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _validate(text: str, schema_file: str, what: str) -> None:
    """Against fmpy's copy of the SSP 1.0 schema (lxml); ValueError naming the file and the problem."""
    import fmpy
    from lxml import etree

    schema = etree.XMLSchema(file=os.path.join(os.path.dirname(fmpy.__file__), "ssp", "schema", schema_file))
    doc = etree.fromstring(text.encode("utf-8"))
    if not schema.validate(doc):
        raise ValueError(f"{what} does not validate against {schema_file}: {schema.error_log.last_error}")


def write_ssp(fmus: Mapping[str, str | Path], out: str | Path, *, rig: Mapping[str, float] | None = None,
              rig_delay_samples: int = 0) -> Path:
    """Write ``out/TapMuscleLoop.ssp`` from the built FMUs ``{"MusclePlant": path, "AMPCController": path}``
    (atomically: a temporary file renamed into place).

    Parameters
    ----------
    fmus : mapping
        The two FMUs' files.
    out : path
        The folder.
    rig : mapping, optional
        A rig's plant parameters (MusclePlant parameter name -> value, ``PlantParams.dotted()``),
        written as the ``rig`` sets and bound in place of the 44-N and parallel-master sets (module
        docstring).
    rig_delay_samples : int
        The rig's transport delay in samples of the controller's Ts, which the controller's ``rig``
        set compensates beside the parallel master's sample.
    """
    out = Path(out)
    ssd = ssd_text(rig=rig is not None)
    _validate(ssd, "SystemStructureDescription.xsd", "SystemStructure.ssd")
    ssvs = ssv_files(rig, rig_delay_samples)
    for name, text in ssvs.items():
        _validate(text, "SystemStructureParameterValues.xsd", name)
    target = out / SSP_NAME
    fd, tmp = tempfile.mkstemp(prefix=".TapMuscleLoop.", suffix=".ssp", dir=out)
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("SystemStructure.ssd", ssd)
            for name, text in ssvs.items():
                z.writestr(name, text)
            for fmu in ("MusclePlant", "AMPCController"):
                z.write(fmus[fmu], f"resources/{fmu}.fmu")
        mask = os.umask(0o022)  # the mode open() would give: mkstemp's 0600 would survive the rename
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
