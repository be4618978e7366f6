"""Scenario runs through the FMUs: scenario files (:mod:`.spec`), the co-simulation master
(:mod:`.master`), and the run with its outputs (:mod:`.run`). The paper's experiments ship as
scenario files in ``scenarios/paper/``."""

from pathlib import Path

from .master import co_simulate
from .run import run_scenario
from .spec import Scenario, ScenarioError, load_scenario, parse_scenario

__all__ = ["PAPER_SCENARIOS", "Scenario", "ScenarioError", "co_simulate", "load_scenario", "parse_scenario",
           "run_scenario"]

#: Folder of the paper's scenario files (section 4: ``<method>_<load>N_<freq>Hz.toml``).
PAPER_SCENARIOS = Path(__file__).resolve().parent / "paper"
