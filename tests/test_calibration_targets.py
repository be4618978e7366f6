"""The simulated rig's calibration targets: `tapmuscle record` makes the recordings, the targets are measured from the CSVs."""

import pytest

from tapmuscle.paper.rig_targets import TARGET_RECORDINGS, check_targets
from tapmuscle.cli.main import main
from tapmuscle.io.recording import read_recording


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    folder = tmp_path_factory.mktemp("calibration")
    out = {}
    for name, (load, spec, duration) in TARGET_RECORDINGS.items():
        path = folder / f"{name}.csv"
        assert main(["record", "--load", str(load), "--input", spec, "--duration", str(duration),
                     "--ts", "0.1", "--seed", "0", "--out", str(path), "--quiet"]) == 0
        rec = read_recording(path)
        out[name] = (rec.t_s, rec.u_v, rec.l_mm)
    return out


@pytest.fixture(scope="module")
def checks(recordings):
    return {c.name: c for c in check_targets(recordings)}


def test_every_target_is_measured(checks):
    assert len(checks) == 15


@pytest.mark.parametrize("index", range(15))
def test_calibration_target(checks, index):
    check = list(checks.values())[index]
    assert check.ok, f"{check.name} = {check.value:.3f}, want {check.bound}"
