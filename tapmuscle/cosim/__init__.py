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


def _scenario_files() -> Path:
    """The installed data package ``tapmuscle.scenario_files``; in a source tree imported without
    installing it (the checkout first on ``sys.path``: ``python -m pytest`` or a notebook beside a
    non-editable install, ``sys.path.insert(0, checkout)``), the checkout's ``scenarios/``."""
    try:
        return Path(str(files("tapmuscle.scenario_files")))
    except ModuleNotFoundError:
        checkout = Path(__file__).resolve().parents[2] / "scenarios"
        if (checkout / "paper").is_dir():
            return checkout
        raise ModuleNotFoundError("tapmuscle's scenario files are missing: the package 'tapmuscle.scenario_files' "
                                  f"is not installed and {checkout} is not a tapmuscle checkout's scenarios/ "
                                  "folder; reinstall tapmuscle (pip install tapmuscle)") from None


#: The scenario files shipped with tapmuscle (the repository's top-level ``scenarios/``).
SCENARIO_FILES = _scenario_files()
#: Folder of the paper's scenario files (section 4: ``<method>_<load>N_<freq>Hz.toml``).
PAPER_SCENARIOS = SCENARIO_FILES / "paper"
