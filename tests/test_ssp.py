"""TapMuscleLoop.ssp (``tapmuscle build --ssp``): valid SSP 1.0, and it runs in three SSP tools: libcosim's SSP
loader, fmpy's SSP runner, and fmu-manipulation-toolbox's container built from it (Ecos: tests/test_ecos.py)."""

import zipfile

import numpy as np
import pytest
from fmpy.ssp.ssd import read_ssd

from build_scripts.ssp import SSP_NAME, write_ssp
from fmu_container import build_container_from_ssp
from tapmuscle.cli.main import main
from tracking import tracking_error_mm


@pytest.fixture(scope="module")
def ssp(built_fmus, tmp_path_factory):
    return write_ssp(built_fmus, tmp_path_factory.mktemp("ssp"))


def test_the_archive_validates_and_fmpy_reads_it(ssp):
    """write_ssp validates the SSD and SSV files against the SSP 1.0 schemas; fmpy's reader (which
    validates again) sees both components and the two connections."""
    ssd = read_ssd(str(ssp))
    assert sorted(e.name for e in ssd.system.elements) == ["controller", "plant"]
    conns = {(c.startElement, c.startConnector, c.endElement, c.endConnector) for c in ssd.system.connections}
    assert conns == {("plant", "l", "controller", "l"), ("controller", "u", "plant", "u")}
    names = zipfile.ZipFile(ssp).namelist()
    assert {"SystemStructure.ssd", "resources/MusclePlant.fmu", "resources/AMPCController.fmu",
            "resources/load_44N.ssv", "resources/load_68N.ssv", "resources/parallel_master.ssv"} <= set(names)
    assert 'value="68.0"' in zipfile.ZipFile(ssp).read("resources/load_68N.ssv").decode()


def _open_in_libcosim(path) -> tuple:
    """libcosim's SSP loader on ``path`` (a parallel master) with a last-value observer: the execution,
    the observer, each component's slave index and its value references by name."""
    libcosim = pytest.importorskip("libcosimpy.CosimExecution")
    from libcosimpy.CosimObserver import CosimObserver

    ex = libcosim.CosimExecution.from_ssp_file(ssp_path=str(path), step_size=100_000_000)
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    idx = {s.name.decode(): s.index for s in ex.slave_infos()}
    refs = {name: {v.name.decode(): v.reference for v in ex.slave_variables(i)} for name, i in idx.items()}
    return ex, obs, idx, refs


def test_libcosim_runs_the_ssp_and_tracks(ssp):
    """libcosim's SSP loader (a parallel master): the bound sets apply (load 44 N, the controller's
    one-sample delay compensation), and the loop tracks the built-in sine as in docs/fmu.md."""
    ex, obs, idx, refs = _open_in_libcosim(ssp)
    pv = refs["plant"]
    rows = []
    for _ in range(300):
        assert ex.step(1)
        rows.append(obs.last_real_values(idx["plant"], [pv["l"], pv["load_force"], pv["u"]]))
    a = np.array(rows)
    t = (np.arange(len(a)) + 1) * 0.1
    err = tracking_error_mm(t, a[:, 0])
    assert np.all(a[:, 1] == 44.0) and a[:, 2].min() >= 0.0 and a[:, 2].max() <= 10.0
    assert err < 0.25, err  # measured 0.138 mm; without the bound compensation: about 3 mm


def test_a_load_set_bound_in_the_ssd_reaches_the_plant_which_declares_no_load_connector(ssp, tmp_path):
    """docs/fmu.md: for 68 N, bind ``load_68N.ssv`` to the plant in the SSD instead; libcosim applies
    a set's values by variable name, so the plant's ``load_force`` needs no connector."""
    edited = tmp_path / "TapMuscleLoop_68N.ssp"
    with zipfile.ZipFile(ssp) as src, zipfile.ZipFile(edited, "w") as dst:
        for name in src.namelist():
            data = src.read(name)
            if name == "SystemStructure.ssd":
                assert data.count(b"resources/load_44N.ssv") == 1
                data = data.replace(b"resources/load_44N.ssv", b"resources/load_68N.ssv")
            dst.writestr(name, data)
    ex, obs, idx, refs = _open_in_libcosim(edited)
    pv = refs["plant"]
    assert ex.step(3)
    assert obs.last_real_values(idx["plant"], [pv["load_force"]]) == [68.0]


def test_fmpys_ssp_runner_runs_the_ssp_and_tracks(ssp):
    """fmpy's own SSP runner (``fmpy.ssp.simulation.simulate_ssp``: each component stepped on the
    others' previous outputs, the SSD's parameter bindings not applied, so the plant's load stays at its
    start value, 44 N, and the controller detects the delay itself) tracks as libcosim does. It wires
    an input connector without a connection to the source of the connection found before it: with the
    plant's load and supply pressure declared, the supply pressure took the command in volts and
    the run stopped at 1.1 s on the plant's refusal; the SSD declares only the connected inputs."""
    from fmpy.ssp.simulation import simulate_ssp

    res = simulate_ssp(str(ssp), stop_time=30.0, step_size=0.1)
    assert len(res) == 300
    assert np.array_equal(res["controller.l"], res["plant.l"]) and np.array_equal(res["plant.u"], res["controller.u"])
    assert res["plant.u"].min() >= 0.0 and res["plant.u"].max() <= 10.0
    err = tracking_error_mm(res["time"] + 0.1, res["plant.l"])  # a row holds the outputs at the step's end
    assert err < 0.25, err  # measured 0.137 mm


def test_fmu_manipulation_toolbox_makes_one_fmu_of_the_ssp_that_tracks(ssp, tmp_path):
    """``fmucontainer -container TapMuscleLoop.ssp:0.1`` (an SSP tool of the test extra) builds the loop
    as one FMU, parallel mode, without the parameter bindings (the FMUs' defaults: 44 N, the
    controller's delay detection); in fmpy it tracks as the other parallel masters."""
    pytest.importorskip("fmu_manipulation_toolbox", reason="fmu-manipulation-toolbox (test extra) is not installed")
    from fmpy import simulate_fmu

    loop = build_container_from_ssp(ssp, tmp_path)
    res = simulate_fmu(str(loop), stop_time=30.0, step_size=0.1, output_interval=0.1)
    assert len(res) == 301 and "muscleplant.l" in res.dtype.names, res.dtype.names
    err = tracking_error_mm(res["time"], res["muscleplant.l"])
    assert err < 0.25, err  # measured 0.137 mm


def test_every_input_connector_of_the_ssd_is_connected(ssp):
    ssd = read_ssd(str(ssp))
    ends = {(c.endElement, c.endConnector) for c in ssd.system.connections}
    inputs = {(e.name, c.name) for e in ssd.system.elements for c in e.connectors if c.kind == "input"}
    assert inputs == ends == {("plant", "u"), ("controller", "l")}


#: A rig whose constants are off and whose command reaches the valve 0.2 s late (two samples at Ts = 0.1 s)
RIG = {"valve.cv_max": 1.3, "muscle.rubber_stiffness_n_per_mm": 1.38, "friction.base_n": 9.3, "delay.delay_s": 0.2}


def _run_libcosim(path, seconds: float = 60.0) -> tuple[np.ndarray, dict[str, float], int]:
    """libcosim's SSP loader on ``path``: l [mm] each step, the plant's parameters read back by name,
    the controller's input_delay_samples."""
    ex, obs, idx, refs = _open_in_libcosim(path)
    pv, cv = refs["plant"], refs["controller"]
    ls = []
    for _ in range(round(seconds / 0.1)):
        assert ex.step(1)
        ls.append(obs.last_real_values(idx["plant"], [pv["l"]])[0])
    names = [n for n in pv if "." in n]
    values = dict(zip(names, obs.last_real_values(idx["plant"], [pv[n] for n in names])))
    return np.array(ls), values, obs.last_integer_values(idx["controller"], [cv["input_delay_samples"]])[0]


def test_a_rigs_plant_file_binds_its_values_and_its_delay_in_the_ssp(built_fmus, tmp_path):
    """A digital twin in an SSP tool: the plant file's every parameter reaches the plant as written,
    the controller's set adds the rig's two samples of transport delay to the parallel master's one,
    and that compensation is what makes the twin's loop track (measured 0.52 mm against 5.61 with the
    parallel master's sample alone, a limit cycle)."""
    from fmu_plant import PlantParams

    rig = PlantParams().with_values(**RIG)
    (tmp_path / "twin").mkdir()
    twin = write_ssp(built_fmus, tmp_path / "twin", rig=rig.dotted(), rig_delay_samples=2)
    names = zipfile.ZipFile(twin).namelist()
    assert {"resources/rig.ssv", "resources/rig_controller.ssv", "resources/load_44N.ssv"} <= set(names)
    bound = [b.source for e in read_ssd(str(twin)).system.elements for b in e.parameterBindings]
    assert sorted(bound) == ["resources/rig.ssv", "resources/rig_controller.ssv"]
    l_twin, read_back, delay = _run_libcosim(twin)
    assert read_back == {k: float(v) for k, v in rig.dotted().items()}  # all 59, as Reals
    assert delay == 3
    (tmp_path / "uncompensated").mkdir()
    late = write_ssp(built_fmus, tmp_path / "uncompensated", rig=rig.dotted(), rig_delay_samples=0)
    l_late, _, delay_late = _run_libcosim(late)
    assert delay_late == 1
    t = (np.arange(len(l_twin)) + 1) * 0.1
    err, err_late = tracking_error_mm(t, l_twin), tracking_error_mm(t, l_late)
    assert err < 2.5 and err < 0.5 * err_late, (err, err_late)


def test_build_cli_refuses_a_rigs_delay_beyond_the_controllers_reach_before_building(tmp_path, capsys, monkeypatch):
    """The plant's delay (at most 2 s, 20 samples at Ts = 0.1 s) and the parallel master's sample fit
    the controller's 25 today; a change of either bound is refused rather than written as an SSP
    whose controller refuses its parameter."""
    import fmu_controller.prediction as prediction
    import tapmuscle as tm
    from fmu_plant import PlantParams

    plant_file = tmp_path / "calibrated_plant.json"
    tm.write_plant_file(plant_file, PlantParams().with_values(**RIG))
    monkeypatch.setattr(prediction, "MAX_INPUT_DELAY_SAMPLES", 2)
    assert main(["build", "--out", str(tmp_path / "out"), "--ssp", "--params", str(plant_file)]) == 2
    assert (f"--params {plant_file}: a transport delay of 0.2 s is 2 samples at Ts = 0.1 s, and with the parallel "
            "master's one more than the controller compensates (input_delay_samples up to 2)") in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_build_cli_binds_a_rigs_plant_file_and_refuses_it_without_ssp(tmp_path, capsys):
    import tapmuscle as tm
    from fmu_plant import PlantParams

    plant_file = tmp_path / "calibrated_plant.json"
    tm.write_plant_file(plant_file, PlantParams().with_values(**RIG | {"delay.delay_s": 0.15}))
    assert main(["build", "--out", str(tmp_path / "alone"), "--params", str(plant_file)]) == 2
    assert "--params puts a rig's plant file into TapMuscleLoop.ssp: give --ssp with it" in capsys.readouterr().err
    assert not (tmp_path / "alone").exists()  # refused before anything was built
    assert main(["build", "--out", str(tmp_path), "--ssp", "--params", str(plant_file)]) == 0
    out = capsys.readouterr().out
    # 1.5 samples: the longer of 1 and 2, as the diagnosis advises, and the parallel master's one
    assert "the controller's input_delay_samples = 3: 2 for the rig's transport delay of 0.15 s at Ts = 0.1 s" in out
    with zipfile.ZipFile(tmp_path / SSP_NAME) as z:
        assert '<ssv:Integer value="3" />' in z.read("resources/rig_controller.ssv").decode()
        assert '<ssv:Parameter name="valve.cv_max">\n      <ssv:Real value="1.3" />' in z.read("resources/rig.ssv").decode()


@pytest.mark.slow
def test_build_cli_writes_the_ssp(tmp_path, capsys):
    assert main(["build", "--out", str(tmp_path), "--ssp"]) == 0
    assert (tmp_path / SSP_NAME).is_file() and f"wrote {tmp_path / SSP_NAME}" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["AMPCController.fmu", "MusclePlant.fmu", SSP_NAME]
