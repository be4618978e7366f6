"""Mismatch diagnosis: where a simulation and a rig recording differ, which physics the simulation left
out, a fitted model of it, and the fit it wins on held-out data (issue 6, docs/diagnosis.md).

Pure numerics, apart from :mod:`diagnosis.report` (files and figures) and :mod:`diagnosis.plant_source`
(reading a plant parameter file or a MusclePlant FMU). The physics of the candidate effects lives in
the plant (``fmu_plant/effect_library.py``), so the plant FMU can switch them on by parameters;
this package fits them.
"""

from .candidates import CANDIDATES, Candidate
from .diagnose import Diagnosis, Finding, diagnose

__all__ = ["diagnose", "Diagnosis", "Finding", "Candidate", "CANDIDATES"]
