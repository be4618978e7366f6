"""`tapmuscle build`: both FMUs, reproducibly, and a content-derived GUID."""

import zipfile

import pytest

from build_scripts.build_fmus import FMUS, build_fmus
from build_scripts.model_description import finish_model_description
from tapmuscle.cli.main import main


@pytest.mark.slow
def test_build_writes_both_fmus_byte_identical_to_an_earlier_build(built_fmus, tmp_path, capsys):
    out = tmp_path / "again"
    assert main(["build", "--out", str(out)]) == 0
    assert "AMPCController.fmu" in capsys.readouterr().out
    for name in FMUS:
        assert (out / f"{name}.fmu").read_bytes() == built_fmus[name].read_bytes(), name
    assert not list(out.glob(".*partial*"))


def test_guid_follows_the_content(built_fmus):
    guids = {}
    for name, path in built_fmus.items():
        with zipfile.ZipFile(path) as z:
            md = z.read("modelDescription.xml").decode()
            assert "generationDateAndTime" not in md
            guids[name] = md.split('guid="')[1].split('"')[0]
            assert all(i.date_time == (1980, 1, 1, 0, 0, 0) for i in z.infolist())
            assert "resources/controller_slave.py" in z.namelist() or name == "MusclePlant"
    assert len(set(guids.values())) == 2


def test_unknown_fmu_name_and_unit_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown FMU 'Pump'"):
        build_fmus(tmp_path, ("Pump",))
    xml = ('<fmiModelDescription fmiVersion="2.0" guid="x"><CoSimulation modelIdentifier="m"/><ModelVariables>'
           '<ScalarVariable name="q" valueReference="0" causality="output"><Real/></ScalarVariable>'
           '</ModelVariables><ModelStructure/></fmiModelDescription>')
    with pytest.raises(ValueError, match="unit 'furlong' has no entry"):
        finish_model_description(xml, {"q": {"unit": "furlong"}}, guid="g")
    with pytest.raises(ValueError, match="variable 'q' has no metadata"):
        finish_model_description(xml, {}, guid="g")


@pytest.mark.parametrize("name", ["MusclePlant", "AMPCController"])
def test_instantiating_again_and_again_defines_no_new_slave_class(built_fmus, name):
    """pythonfmu executes the entry script at every fmi2Instantiate (build_scripts.build_fmus): 60
    instantiate/free cycles in this process leave no new slave class behind (with the whole class in
    the entry script each cycle left one, about 50 kB for the controller) and the entry module keeps
    working (its dict would be freed by pythonfmu's extra release, and the 2nd instantiation fail)."""
    import gc

    from tapmuscle.cosim.master import FmuInstance

    role = "plant" if name == "MusclePlant" else "controller"

    def cycle(i):
        inst = FmuInstance(built_fmus[name], f"cycle{i}", role=role)
        inst.start()
        inst.fmu.doStep(0.0, 0.1)
        inst.free()

    def classes():
        gc.collect()
        return sum(1 for o in gc.get_objects() if isinstance(o, type) and o.__name__ == name)

    cycle(0)
    before = classes()
    for i in range(1, 61):
        cycle(i)
    assert classes() == before


def test_the_fmus_carry_python_sources_only(built_fmus):
    # The plant's compiled sub-step is built for one interpreter (setup.py); the FMUs run the Python
    # one (the same bits), and rosenbrock.py loads a compiled one only from beside itself.
    for name, path in built_fmus.items():
        with zipfile.ZipFile(path) as z:
            resources = [n for n in z.namelist() if n.startswith("resources/")]
        assert name != "MusclePlant" or "resources/fmu_plant/rosenbrock.py" in resources
        assert not [n for n in resources if n.endswith((".so", ".pyd", ".c"))], name
