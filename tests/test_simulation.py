"""The diagnosis's simulator (tapmuscle/diagnosis/simulation.py): a run the plant cannot integrate."""

from __future__ import annotations

import numpy as np
import pytest

from fmu_plant import PlantParams
from tapmuscle.diagnosis.fit_problem import SimulationError as FitProblemSimulationError
from tapmuscle.diagnosis.simulation import SimulationError, Simulator


def test_parameters_the_plant_cannot_integrate_are_a_failed_simulation_naming_them():
    """A plant integration that breaks down is a failed simulation, which the fits step around (as an
    FMU error), not an exception that ends the diagnosis."""
    sim = Simulator(np.full(50, 5.0), 0.1)
    with pytest.raises(SimulationError, match=r"the plant with muscle\.rest_length_mm=1e-12: .*too many sub-steps"):
        sim.run(PlantParams().with_values(**{"muscle.rest_length_mm": 1e-12}))
    assert FitProblemSimulationError is SimulationError  # the one the fits catch
    assert sim.run(PlantParams())[0].shape == (50,) and sim.runs == 1  # the failed run is not counted
