"""Scenario runs through the FMUs: scenario files (:mod:`.spec`), the co-simulation master
(:mod:`.master`), and the run with its outputs (:mod:`.run`). The paper's experiments ship as
scenario files in ``scenarios/paper/``."""

from importlib.resources import files
from pathlib import Path

from tapmuscle.cosim.master import co_simulate
from tapmuscle.cosim.run import run_scenario
from tapmuscle.cosim.spec import Scenario, ScenarioError, load_scenario, parse_scenario

__all__ = ["SCENARIO_FILES", "PAPER_SCENARIOS", "Scenario", "ScenarioError", "co_simulate", "load_scenario", "parse_scenario",
           "run_scenario"]

#: The scenario files shipped with tapmuscle (the repository's top-level ``scenarios/``).
SCENARIO_FILES = Path(str(files("tapmuscle.scenario_files")))
#: Folder of the paper's scenario files (section 4: ``<method>_<load>N_<freq>Hz.toml``).
PAPER_SCENARIOS = SCENARIO_FILES / "paper"
