"""What produced a result: the software versions written into the JSON documents tapmuscle leaves.

A closed loop whose valve command saturates is chaotic: another numpy, scipy or osqp release, or
another CPU's SIMD kernels, changes the last bits of a step and, through the loop, an Eq. (21) error in
its second or third digit (docs/control.md). ``summary.json``, ``paper.json``, ``diagnosis.json``, an
identification file and a demonstration's ``scores.json`` therefore carry a ``"software"`` object
(:func:`software`), so that two results can be told apart by what made them before their numbers are.
``tapmuscle --version`` prints the same.
"""

from __future__ import annotations

import platform
from importlib import metadata
from typing import Sequence

__all__ = ["NUMERICS_PACKAGES", "package_version", "software", "software_text"]

#: The packages whose release can change a result's last bits (the FMUs run in pythonfmu, the
#: co-simulation in fmpy).
NUMERICS_PACKAGES = ("numpy", "scipy", "osqp", "pythonfmu", "fmpy")


def package_version(name: str) -> str:
    """The installed release of distribution ``name``, or ``"not installed"``."""
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not installed"


def software() -> dict[str, str]:
    """The versions that produce a result here.

    Returns
    -------
    dict
        ``tapmuscle`` and each of :data:`NUMERICS_PACKAGES` (the installed releases), ``python``,
        ``machine`` (operating system and processor architecture, as ``Linux x86_64``) and
        ``compiled_substep`` (``"yes"`` where the plant's Rosenbrock sub-step runs compiled, ``"no"``
        where in Python: the same bits, only slower, docs/plant.md).
    """
    from fmu_plant.rosenbrock import COMPILED

    return {"tapmuscle": package_version("tapmuscle"), "python": platform.python_version(),
            **{name: package_version(name) for name in NUMERICS_PACKAGES},
            "machine": f"{platform.system()} {platform.machine()}", "compiled_substep": "yes" if COMPILED else "no"}


def software_text(found: dict[str, str] | None = None, more: Sequence[str] = ()) -> str:
    """:func:`software` (or ``found``, such a dict read from a document) in one line, as ``tapmuscle
    --version`` (with ``more``, further facts in the parentheses) and a sweep's ``summary.md`` say it."""
    found = software() if found is None else found
    facts = [f"Python {found['python']}", ", ".join(f"{name} {found[name]}" for name in NUMERICS_PACKAGES),
             found["machine"], f"compiled sub-step {found['compiled_substep']}", *more]
    return f"tapmuscle {found['tapmuscle']} ({'; '.join(facts)})"
