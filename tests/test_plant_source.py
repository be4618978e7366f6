"""tapmuscle.diagnosis.plant_source: a MusclePlant FMU run as the diagnosis runs it."""

import numpy as np
import pytest

from fmu_plant import Plant, PlantParams
from tapmuscle.diagnosis.plant_source import simulate_plant_fmu


@pytest.mark.parametrize("load_column", [False, True])
def test_a_plant_files_load_and_supply_reach_the_fmu_without_a_load_column(built_fmus, load_column):
    """The FMU's inputs set the load and the supply pressure; a 68-N, 0.2-MPa plant file diagnosed on a
    recording without a load column runs at 68 N and 0.2 MPa (as the direct plant), not at the inputs'
    start values (44 N, 0.25 MPa)."""
    params = PlantParams().with_values(**{"load.load_n": 68.0, "supply.supply_pressure_mpa": 0.2})
    u = np.full(60, 6.0)
    load = np.full(60, 68.0) if load_column else None
    got = simulate_plant_fmu(built_fmus["MusclePlant"], params.dotted(), u, 0.1, load_n=load)
    plant = Plant(params, seed=0)
    want = [plant.measurement.l_mm] + [plant.step(float(x), 0.1).l_mm for x in u[:-1]]
    np.testing.assert_array_equal(got, want)  # the FMU is the direct plant bit for bit (one process)
    nominal = Plant(PlantParams(), seed=0)
    other = [nominal.measurement.l_mm] + [nominal.step(float(x), 0.1).l_mm for x in u[:-1]]
    assert np.max(np.abs(np.asarray(want) - other)) > 5.0  # 44 N / 0.25 MPa would be another run
