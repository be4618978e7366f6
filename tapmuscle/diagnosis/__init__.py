"""Mismatch diagnosis: where a simulation and a rig recording differ, how much of it recalibrating the
nominal constants explains, which physics the simulation left out, a fitted model of it, and the fit
it wins on held-out data; an ``ambiguous`` verdict with a discriminating experiment where the data
cannot tell explanations apart (docs/diagnosis.md).

Pure numerics, apart from :mod:`tapmuscle.diagnosis.report` (files and figures) and :mod:`tapmuscle.diagnosis.plant_source`
(reading a plant parameter file or a MusclePlant FMU). The physics of the candidate effects lives in
the plant (``fmu_plant/effect_library.py``), so the plant FMU can switch them on by parameters;
this package fits them.
"""

from tapmuscle.diagnosis.candidates import CANDIDATES, Candidate
from tapmuscle.diagnosis.calibration import NOMINAL_PARAMETERS, Calibration, calibrate
from tapmuscle.diagnosis.diagnose import VERDICTS, Alternative, Diagnosis, Finding, diagnose
from tapmuscle.diagnosis.experiment_design import Experiment, design_input

__all__ = ["diagnose", "Diagnosis", "Finding", "Alternative", "VERDICTS", "Candidate", "CANDIDATES", "calibrate",
           "Calibration", "NOMINAL_PARAMETERS", "design_input", "Experiment"]
