"""Complete pythonfmu's modelDescription.xml: units, ranges, dependencies, a stable GUID.

pythonfmu 0.7 writes variables with name, causality, variability, description and start only, lists
every output in ``ModelStructure/Outputs`` without ``dependencies`` (which FMI 2.0 reads as "depends
on every input": hosts then report an algebraic loop between two FMUs that have none, PythonFMU#258),
and stamps a fresh GUID (``uuid1``) and the current time on every build. :func:`finish_model_description`
fixes all of that from the slave's :attr:`fmi_slave.SafeSlave.variable_meta`:

* ``UnitDefinitions`` with SI base-unit exponents for each unit used, ``unit``/``min``/``max``/
  ``nominal`` on Real variables, ``min``/``max`` on Integers;
* no ``Enumeration`` variables: choices are Integers whose description lists the codes, because
  libcosim ignores Enumeration parameters and its SSP loader aborts on them;
* ``Outputs`` with explicit ``dependencies`` (ours: none) and ``InitialUnknowns`` for the outputs
  computed at initialisation, with the parameters they are computed from;
* ``canGetAndSetFMUstate``/``canSerializeFMUstate`` true (the slaves keep all dynamic state);
* the model ``version`` and ``generationTool`` name the tapmuscle release (and ``generationTool`` the
  digest of the code the FMU carries);
* structured names that form a tree (:func:`refuse_parent_names`: no variable is another's parent);
* no ``generationDateAndTime``, and a GUID derived from a hash of the FMU's content, so the same
  sources give the same FMU byte for byte.
"""

from __future__ import annotations

import math
import uuid
import xml.etree.ElementTree as ET
from typing import Any, Iterable, Mapping

__all__ = ["UNITS", "UNIT_ALIASES", "finish_model_description", "content_guid"]

#: Unit name -> (SI base-unit exponents, factor): value in base units = factor * value.
UNITS: dict[str, tuple[dict[str, int], float]] = {
    "mm": ({"m": 1}, 1e-3),
    "V": ({"kg": 1, "m": 2, "s": -3, "A": -1}, 1.0),
    "N": ({"kg": 1, "m": 1, "s": -2}, 1.0),
    "MPa": ({"kg": 1, "m": -1, "s": -2}, 1e6),
    "s": ({"s": 1}, 1.0),
    "Hz": ({"s": -1}, 1.0),
    "kg": ({"kg": 1}, 1.0),
    "deg": ({"rad": 1}, math.pi / 180.0),
    "N/mm": ({"kg": 1, "s": -2}, 1e3),
    "N.s/mm": ({"kg": 1, "s": -1}, 1e3),
    "N/MPa": ({"m": 2}, 1e-6),
    "mm/s": ({"m": 1, "s": -1}, 1e-3),
    "mm/min": ({"m": 1, "s": -1}, 1e-3 / 60.0),
    "m3/MPa": ({"kg": -1, "m": 4, "s": 2}, 1e-6),
    # The valve's flow coefficient Cv (US gal/min at 1 psi drop): not an SI quantity, declared without
    # a base unit as FMI allows.
    "USgpm/psi0.5": ({}, 1.0),
}

#: How the plant's parameter docs write units -> the FMI unit name ("" = dimensionless, no unit).
UNIT_ALIASES: dict[str, str] = {"MPa(G)": "MPa", "N s/mm": "N.s/mm", "m^3/MPa": "m3/MPa",
                                "US gpm/psi^0.5": "USgpm/psi0.5", "-": "", "": ""}


def _unit(name: str) -> str:
    unit = UNIT_ALIASES.get(name, name)
    if unit and unit not in UNITS:
        raise ValueError(f"unit {name!r} has no entry in build_scripts.model_description.UNITS")
    return unit


def content_guid(digest: bytes) -> str:
    """A GUID (UUID version 5 form) from a content hash."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "tapmuscle:" + digest.hex()))


def refuse_parent_names(names: Iterable[str]) -> None:
    """ValueError naming a variable whose name is also the parent of another's (``load`` beside
    ``load.load_n``, or ``v`` beside ``v[1]``).

    Under the structured naming convention (FMI 2.0, section 2.2.9) the names form a tree, which
    Modelica importers map to a hierarchy of records: one node cannot be both a variable and a record.
    Quoted names (``'a.b'``) are not split; the FMUs declare none.
    """
    names = set(names)
    for name in sorted(names):
        if name.startswith("'"):
            continue
        for i, char in enumerate(name):
            if char in ".[" and name[:i] in names:
                raise ValueError(f"variable {name[:i]!r} is also the parent of {name!r} under the structured "
                                 "naming convention: rename one of them")


def finish_model_description(xml_text: str, meta: Mapping[str, Mapping[str, Any]], *, guid: str,
                             version: str | None = None, sources: str | None = None) -> str:
    """Return the completed modelDescription.xml (see module docstring).

    Parameters
    ----------
    xml_text : str
        pythonfmu's modelDescription.xml.
    meta : mapping
        ``SafeSlave.variable_meta`` of the slave: name -> unit, min, max, nominal, depends_on.
    guid : str
        The GUID to write.
    version : str, optional
        tapmuscle's version: the model's ``version`` attribute, and ``generationTool`` becomes
        ``tapmuscle <version> (PythonFMU <its version>)``, so a tool's FMU browser says which
        release built the FMU.
    sources : str, optional
        The digest of the code the FMU carries (its private package's): ``generationTool`` names it
        too, ``tapmuscle <version>, sources <digest> (PythonFMU ...)``, which tells two builds of one
        release apart (the version stays until a release).
    """
    root = ET.fromstring(xml_text)
    root.set("guid", guid)
    if version is not None:
        root.set("version", version)
        built = f", sources {sources}" if sources else ""
        root.set("generationTool", f"tapmuscle {version}{built} ({root.get('generationTool', 'PythonFMU')})")
    root.attrib.pop("generationDateAndTime", None)
    cs = root.find("CoSimulation")
    cs.set("canGetAndSetFMUstate", "true")
    cs.set("canSerializeFMUstate", "true")

    variables = root.find("ModelVariables")
    index: dict[str, int] = {}
    units_used: list[str] = []
    for i, sv in enumerate(variables.findall("ScalarVariable"), start=1):
        name = sv.get("name")
        index[name] = i
        m = meta.get(name)
        if m is None:
            raise ValueError(f"variable {name!r} has no metadata (register it through SafeSlave)")
        typed = sv[0]
        unit = _unit(m.get("unit", ""))
        if unit and typed.tag == "Real":
            typed.set("unit", unit)
            if unit not in units_used:
                units_used.append(unit)
        for key in ("min", "max", "nominal"):
            value = m.get(key)
            if value is None or (key == "nominal" and typed.tag != "Real"):
                continue
            if typed.tag == "Integer":
                typed.set(key, str(int(value)))
            else:
                typed.set(key, repr(float(value)))

    if root.get("variableNamingConvention") == "structured":
        refuse_parent_names(index)

    if units_used:
        defs = ET.Element("UnitDefinitions")
        for unit in units_used:
            u = ET.SubElement(defs, "Unit", name=unit)
            exponents, factor = UNITS[unit]
            if exponents:
                attrs = {k: str(v) for k, v in exponents.items()}
                if factor != 1.0:
                    attrs["factor"] = repr(factor)
                ET.SubElement(u, "BaseUnit", attrs)
        root.insert(list(root).index(cs) + 1, defs)

    structure = root.find("ModelStructure")
    for child in list(structure):
        structure.remove(child)
    outputs = [sv for sv in variables.findall("ScalarVariable") if sv.get("causality") == "output"]
    if outputs:
        node = ET.SubElement(structure, "Outputs")
        initial = ET.Element("InitialUnknowns")
        for sv in outputs:
            name = sv.get("name")
            deps = " ".join(str(index[d]) for d in meta[name].get("depends_on", ()))
            ET.SubElement(node, "Unknown", index=str(index[name]), dependencies=deps)
            if sv.get("initial") in ("approx", "calculated"):
                # at initialisation: the parameters it is computed from (FMI 2.0 lists knowns there)
                known = meta[name].get("initial_depends_on", meta[name].get("depends_on", ()))
                ET.SubElement(initial, "Unknown", index=str(index[name]),
                              dependencies=" ".join(str(index[d]) for d in sorted(known, key=index.get)))
        if len(initial):
            structure.append(initial)
    ET.indent(root, space="\t")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
