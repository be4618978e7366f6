"""`tapmuscle build`: both FMUs, reproducibly, and a content-derived GUID."""

import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest
import pythonfmu

import tapmuscle
from build_scripts.build_fmus import FMUS, build_fmus, private_package
from build_scripts.model_description import finish_model_description
from build_scripts.native_host import fmi_export, machine_name, python_machine
from tapmuscle.cli.main import main


@pytest.mark.slow
def test_build_writes_both_fmus_byte_identical_to_an_earlier_build(built_fmus, tmp_path, capsys):
    out = tmp_path / "again"
    assert main(["build", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "AMPCController.fmu" in printed
    # which library runs the slave in the linux64 binary, for which machine
    library = "pythonfmu's" if fmi_export() == "pythonfmu" else "the project's"
    assert f"MusclePlant.fmu (linux64 for {machine_name(python_machine())}: {library} FMI" in printed
    for name in FMUS:
        assert (out / f"{name}.fmu").read_bytes() == built_fmus[name].read_bytes(), name
    assert not list(out.glob(".*partial*"))


def test_the_build_says_when_its_fmus_run_in_python_hosts_only(tmp_path):
    # built by a Python without a shared libpython (tests/test_c_host.py builds and runs one)
    from build_scripts.native_host import CONFIG_NAME
    from tapmuscle.cli.main import _linux64_note

    notes = {}
    for hosts_only in (False, True):
        fmu = tmp_path / f"{hosts_only}.fmu"
        with zipfile.ZipFile(fmu, "w") as z:
            z.writestr(f"resources/{CONFIG_NAME}", f'{{"fmi_export": "pythonfmu", "python_hosts_only": {str(hosts_only).lower()}}}')
        notes[hosts_only] = _linux64_note(fmu)
    assert notes[False] == f" (linux64 for {machine_name(python_machine())}: pythonfmu's FMI library)"
    assert notes[True] == notes[False][:-1] + "; Python hosts only: the building Python has no shared libpython)"


@pytest.mark.slow
def test_warnings_made_errors_stop_no_run_for_a_tool_other_hosts_need(tmp_path):
    """Under PYTHONWARNINGS=error a missing MinGW-w64 (most Linux machines) must not stop tapmuscle run and
    paper with exit 1 while building their own FMUs, which fmpy (a Python host) runs whatever the win64
    binary; tapmuscle build, which writes FMUs to take to other hosts, still says what it left out."""
    env = {**os.environ, "PYTHONWARNINGS": "error", "XDG_CACHE_HOME": str(tmp_path / "cache"),
           "CC_WIN64": str(tmp_path / "no-mingw-gcc")}
    scenario = Path(tapmuscle.__file__).resolve().parents[1] / "scenarios" / "examples" / "load_step.toml"
    run = subprocess.run([sys.executable, "-m", "tapmuscle", "run", str(scenario), "--out", str(tmp_path / "run"),
                          "--quiet"], env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert "NativeHostWarning" not in run.stderr and (tmp_path / "run" / "summary.json").is_file()
    build = subprocess.run([sys.executable, "-m", "tapmuscle", "build", "--out", str(tmp_path / "fmus")], env=env,
                           capture_output=True, text=True, timeout=600)
    assert build.returncode == 1 and "NativeHostWarning" in build.stderr and "MinGW-w64" in build.stderr


def test_guid_follows_the_content(built_fmus):
    guids = {}
    for name, path in built_fmus.items():
        with zipfile.ZipFile(path) as z:
            md = z.read("modelDescription.xml").decode()
            assert "generationDateAndTime" not in md
            guids[name] = md.split('guid="')[1].split('"')[0]
            assert all(i.date_time == (1980, 1, 1, 0, 0, 0) for i in z.infolist())
            entry = z.read("resources/slavemodule.txt").decode().strip()
            assert f"resources/{entry}.py" in z.namelist() and entry.startswith(f"_tapmuscle_{name.lower()}_")
    assert len(set(guids.values())) == 2


def test_the_model_descriptions_name_the_release_that_built_them(built_fmus):
    """An FMI tool's FMU browser shows ``version`` and ``generationTool``: tapmuscle's release, the
    digest of the code the FMU carries (two builds of one release told apart: it names the FMU's
    private package), and the PythonFMU it runs on."""
    for name, path in built_fmus.items():
        with zipfile.ZipFile(path) as z:
            root = ET.fromstring(z.read("modelDescription.xml"))
            private = {n.split("/")[1] for n in z.namelist() if n.startswith("resources/_tapmuscle_")}
        assert root.get("version") == tapmuscle.__version__, name
        (package,) = {p for p in private if not p.endswith(".py")}
        assert root.get("generationTool") == (f"tapmuscle {tapmuscle.__version__}, sources {package.rsplit('_', 1)[1]} "
                                              f"(PythonFMU {pythonfmu.__version__})")



def test_outputs_computed_at_initialisation_have_no_start_and_list_their_parameters(built_fmus):
    """FMI 2.0, section 2.2.8: an output whose initial value the FMU computes is initial = calculated,
    without a start value, and an InitialUnknown whose dependencies are what it is computed from; the
    others (u, ...) have an exact start value and no InitialUnknown."""
    from fmpy import read_model_description

    from fmu_controller.hysteresis_model import ASYMMETRIC

    for name, calculated in (("MusclePlant", {"l", "p"}),
                             ("AMPCController", {"samples", "input_delay"} | {f"theta.{n}" for n in ASYMMETRIC.names})):
        md = read_model_description(str(built_fmus[name]))
        outputs = [v for v in md.modelVariables if v.causality == "output"]
        assert {v.name for v in outputs if v.initial == "calculated"} == calculated
        assert all(v.start is None for v in outputs if v.initial == "calculated")
        assert all(v.initial == "exact" and v.start is not None for v in outputs if v.name not in calculated)
        unknowns = {u.variable.name: {d.name for d in u.dependencies} for u in md.initialUnknowns}
        assert unknowns.keys() == calculated
        if name == "AMPCController":
            assert unknowns["theta.b1"] == {"theta0.b1"} and unknowns["samples"] == set()
        else:
            assert {"sensor_drift.offset_mm", "seed", "sensor.encoder_noise_std_mm"} <= unknowns["l"]
            assert not {"u", "load_force", "supply_pressure"} & unknowns["l"]  # at rest, whatever the inputs


def test_no_variable_of_either_fmu_is_the_parent_of_another(built_fmus):
    """Under the structured naming convention a Modelica importer maps ``load.load_n`` to a record
    ``load``: a variable ``load`` beside it cannot be mapped, so the build refuses such names."""
    from build_scripts.model_description import refuse_parent_names

    for name, path in built_fmus.items():
        with zipfile.ZipFile(path) as z:
            root = ET.fromstring(z.read("modelDescription.xml"))
        assert root.get("variableNamingConvention") == "structured"
        names = [v.get("name") for v in root.iter("ScalarVariable")]
        refuse_parent_names(names)
        if name == "MusclePlant":
            assert {"load_force", "load.load_n", "load.moving_mass_kg"} <= set(names)
    for names, parent, child in ((["u", "load", "load.load_n"], "load", "load.load_n"),
                                 (["v", "v[1]"], "v", "v[1]"), (["a.b", "a.b.c", "a"], "a", "a.b")):
        with pytest.raises(ValueError, match=rf"variable '{re.escape(parent)}' is also the parent of "
                                             rf"'{re.escape(child)}'"):
            refuse_parent_names(names)
    refuse_parent_names(["load_force", "load.load_n", "loads", "'load.x'", "load_x.y"])  # none a parent


@pytest.mark.parametrize("convention, refused", [("structured", True), ("flat", False)])
def test_the_build_refuses_a_variable_that_is_anothers_parent(convention, refused):
    """finish_model_description, which every build runs, applies the check under the structured
    naming convention (under the flat one a name is a plain string)."""
    xml = (f'<fmiModelDescription fmiVersion="2.0" guid="x" variableNamingConvention="{convention}">'
           '<CoSimulation modelIdentifier="m"/><ModelVariables>'
           '<ScalarVariable name="load" valueReference="0" causality="input"><Real start="44"/></ScalarVariable>'
           '<ScalarVariable name="load.load_n" valueReference="1" causality="parameter" variability="fixed">'
           '<Real start="44"/></ScalarVariable></ModelVariables><ModelStructure/></fmiModelDescription>')
    meta = {"load": {"unit": "N"}, "load.load_n": {"unit": "N"}}
    if refused:
        with pytest.raises(ValueError, match="variable 'load' is also the parent of 'load.load_n'"):
            finish_model_description(xml, meta, guid="g")
    else:
        assert 'name="load.load_n"' in finish_model_description(xml, meta, guid="g")


def test_unknown_fmu_name_and_unit_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown FMU 'Pump'"):
        build_fmus(tmp_path, ("Pump",))
    with pytest.raises(ValueError, match="unknown FMU 'Pump'"):  # one name, not its letters
        build_fmus(tmp_path / "new", "Pump")
    assert not (tmp_path / "new").exists()  # refused before anything is written
    (tmp_path / "taken").write_text("a file")
    with pytest.raises(NotADirectoryError, match="taken is a file, not a folder for the FMUs"):
        build_fmus(tmp_path / "taken")
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
    the entry script each cycle would leave one, about 50 kB for the controller) and the entry module keeps
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


def test_the_fmus_carry_python_sources_and_this_interpreters_compiled_sub_step(built_fmus):
    """The plant's compiled sub-step (setup.py) travels in the FMU for the building interpreter's exact
    ABI, the one the FMU's binary links; nothing else compiled, no C source."""
    from importlib.machinery import EXTENSION_SUFFIXES

    from fmu_plant.rosenbrock import COMPILED

    for name, path in built_fmus.items():
        with zipfile.ZipFile(path) as z:
            resources = [n for n in z.namelist() if n.startswith("resources/")]
        compiled = [n for n in resources if n.endswith((".so", ".pyd"))]
        if name == "MusclePlant":
            assert any(n.endswith("/fmu_plant/rosenbrock.py") for n in resources)
            expected = ["fmu_plant/_ros34pw2" + EXTENSION_SUFFIXES[0]] if COMPILED else []
            assert [n.split("/", 2)[2] for n in compiled] == expected
        else:
            assert not compiled, name
        assert not [n for n in resources if n.endswith(".c")], name


SUB_STEP = r"""
import sys
import fmpy
l = fmpy.simulate_fmu(sys.argv[1], stop_time=10.0, output_interval=0.1, start_values={"u": 5.0})["l"]
(r,) = [m for name, m in sys.modules.items() if name.endswith(".fmu_plant.rosenbrock")]
print(r.COMPILED, repr(float(l[-1])))
"""


def test_the_plant_fmu_runs_its_compiled_sub_step_and_the_python_one_gives_the_same_bits(built_fmus):
    from fmu_plant.rosenbrock import COMPILED

    if not COMPILED:
        pytest.skip("the compiled sub-step is not built here (no C compiler at install time)")
    env = {k: v for k, v in os.environ.items() if k != "TAPMUSCLE_PURE_PYTHON"}
    runs = {}
    for pure in ("0", "1"):
        proc = subprocess.run([sys.executable, "-c", SUB_STEP, str(built_fmus["MusclePlant"])], capture_output=True,
                              text=True, timeout=300, env={**env, "TAPMUSCLE_PURE_PYTHON": pure})
        assert proc.returncode == 0, proc.stderr[-2000:]
        runs[pure] = proc.stdout.split()[-2:]
    assert runs["0"][0] == "True" and runs["1"][0] == "False"
    assert runs["0"][1] == runs["1"][1] and float(runs["0"][1]) > 10.0  # the same bits (repr), a moved muscle


OWN_CODE = r"""
import sys
import fmpy
import fmu_plant.plant_slave  # the host's copy, as in tapmuscle's own master or a notebook
host = fmu_plant.__file__
l = fmpy.simulate_fmu(sys.argv[1], stop_time=0.2, output_interval=0.1, start_values={"u": 5.0})["l"]
import fmu_plant
print(float(l[0]), fmu_plant.__file__ == host, "fmu_plant" in sys.modules and "resources" not in fmu_plant.__file__)
"""


def test_an_fmu_runs_its_own_code_beside_the_hosts(built_fmus, tmp_path):
    """An FMU carries its code under a name of its build, so a host that has imported the project's
    packages (tapmuscle's master, a notebook) neither lends it its own copy nor gets the FMU's. Here
    the FMU's copy is changed after the build (its l reads 1000 mm high, as another version's code
    would differ): loaded in a process that imported fmu_plant, the FMU still runs its own copy, and
    the host's fmu_plant is still its own."""
    tree = tmp_path / "fmu"
    with zipfile.ZipFile(built_fmus["MusclePlant"]) as z:
        z.extractall(tree)
    (slave,) = tree.glob("resources/_tapmuscle_muscleplant_*/fmu_plant/plant_slave.py")
    text = slave.read_text()
    changed = text.replace("self.l, self.p = self._plant.measurement.l_mm,", "self.l, self.p = 1000.0 + self._plant.measurement.l_mm,", 1)
    assert changed != text
    slave.write_text(changed)
    patched = shutil.make_archive(str(tmp_path / "patched"), "zip", tree)
    proc = subprocess.run([sys.executable, "-c", OWN_CODE, patched], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    l0, same_host_module, not_the_fmus = proc.stdout.split()[-3:]
    assert float(l0) == 1000.0 and same_host_module == "True" and not_the_fmus == "True", proc.stdout


def test_the_private_package_name_follows_the_sources(tmp_path):
    (tmp_path / "a" / "fmu_plant").mkdir(parents=True)
    (tmp_path / "a" / "fmu_plant" / "x.py").write_text("A = 1\n")
    first = private_package("MusclePlant", tmp_path / "a")
    assert first == private_package("MusclePlant", tmp_path / "a") and first.startswith("_tapmuscle_muscleplant_")
    (tmp_path / "a" / "fmu_plant" / "x.py").write_text("A = 2\n")
    assert private_package("MusclePlant", tmp_path / "a") != first


def test_an_unwritable_cache_is_named_with_its_remedy(tmp_path, monkeypatch):
    """A cache folder that cannot be made (a read-only home in a container; here a file in the way)
    is named, with what to do; an empty XDG_CACHE_HOME means unset, not the current folder."""
    from build_scripts.build_fmus import cached_fmus

    (tmp_path / "file").write_text("")
    with pytest.raises(OSError, match=r"cannot write the FMU cache .*/file \(Not a directory\): set "
                                      r"XDG_CACHE_HOME to a writable folder \(or give run, sweep and check --fmu-dir"):
        cached_fmus(tmp_path / "file")
    monkeypatch.setenv("XDG_CACHE_HOME", "")
    monkeypatch.setenv("HOME", str(tmp_path / "file"))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OSError, match=r"cannot write the FMU cache .*file/\.cache/tapmuscle \(Not a directory\)"):
        cached_fmus()
    assert not (tmp_path / "tapmuscle").exists()


def test_a_cache_folder_of_another_users_is_named_with_its_remedy(tmp_path, monkeypatch):
    """A shared XDG_CACHE_HOME whose FMU folder another user made (umask 022): the folder is there, the
    build's first file in it is refused. Said as the unwritable cache is, not a bare Permission denied
    naming a hidden partial file (emulated: root may write anywhere)."""
    import errno

    import build_scripts.build_fmus as build

    def refused(folder, names):
        raise PermissionError(errno.EACCES, "Permission denied", str(folder / ".AMPCController.fmu.partial-1"))

    monkeypatch.setattr(build, "build_fmus", refused)
    with pytest.raises(OSError, match=r"cannot write the FMU cache .*/fmu-\w+ \(Permission denied\): set XDG_CACHE_HOME"):
        build.cached_fmus(tmp_path)


def test_no_home_folder_is_named_with_its_remedy(tmp_path, monkeypatch):
    """HOME unset and a user id without a passwd entry (a container run as an arbitrary user):
    `tapmuscle run` and `paper` must not end in pathlib's RuntimeError traceback; the CLI's error names what
    to set, and XDG_CACHE_HOME alone is enough."""
    import pwd

    from build_scripts.build_fmus import user_cache_root

    monkeypatch.delenv("HOME")
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)

    def no_entry(uid):
        raise KeyError(f"getpwuid(): uid not found: {uid}")

    monkeypatch.setattr(pwd, "getpwuid", no_entry)
    with pytest.raises(OSError, match=r"no home folder for the FMU cache \(HOME is unset and user id \d+ has no passwd "
                                      r"entry\): set XDG_CACHE_HOME \(or HOME\) to a writable folder"):
        user_cache_root()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert user_cache_root() == tmp_path / "tapmuscle"


def test_on_windows_the_fmu_cache_is_in_local_app_data_unless_xdg_cache_home_says_otherwise(tmp_path, monkeypatch):
    import sys

    from build_scripts.build_fmus import user_cache_root

    monkeypatch.setattr(sys, "platform", "win32")
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("LOCALAPPDATA", str(tmp_path / "Local"))
    assert user_cache_root() == tmp_path / "Local" / "tapmuscle"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert user_cache_root() == tmp_path / "xdg" / "tapmuscle"
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert user_cache_root() == tmp_path / "home" / ".cache" / "tapmuscle"  # LOCALAPPDATA is Windows'


def test_the_fmu_cache_keeps_the_recently_used_builds(tmp_path):
    """Each source state of a checkout gets a build in the cache: beyond CACHE_KEEP the least recently
    used ones go, but never the one just built nor one used within the hour (another process)."""
    import os
    import time

    from build_scripts.build_fmus import CACHE_IN_USE_S, CACHE_KEEP, _prune_cache

    now = time.time()
    ages_h = [0.1, 0.5, *range(2, 14)]  # hours since last use: two in use, twelve idle
    folders = []
    for i, age in enumerate(ages_h):
        d = tmp_path / f"fmu-{i:016x}"
        (d / "x").mkdir(parents=True)
        os.utime(d, (now - age * 3600, now - age * 3600))
        folders.append(d)
    (tmp_path / "extracted").mkdir()  # not a build: left alone
    just_built = folders[-1]  # the oldest time stamp, but the build this call made
    _prune_cache(tmp_path, just_built)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert "extracted" in left and just_built.name in left
    kept = [d for d in folders if d.exists()]
    assert kept == folders[:CACHE_KEEP] + [just_built]
    assert all(d.exists() for d, age in zip(folders, ages_h) if age * 3600 < CACHE_IN_USE_S)


def test_one_fmu_named_alone_is_built_alone(tmp_path):
    import tapmuscle as tm

    assert [p.name for p in tm.build_fmus(tmp_path, names="MusclePlant")] == ["MusclePlant.fmu"]
    assert [p.name for p in tmp_path.iterdir()] == ["MusclePlant.fmu"]


def test_the_build_copies_a_read_only_checkout_writable(tmp_path):
    """A checkout or install without write bits (a Nix store, a read-only CI workspace, chmod a-w):
    were the build's copies to keep its modes, rewriting their imports would fail with PermissionError for any
    user but root (tapmuscle run: "[Errno 13] Permission denied: .../fmi_slave/__init__.py"). The
    copies are the owner's to write; what is not shipped stays out."""
    import stat

    from build_scripts.build_fmus import _clean_copy

    src = tmp_path / "src"
    (src / "pkg").mkdir(parents=True)
    (src / "pkg" / "mod.py").write_text("X = 1\n")
    (src / "pkg" / "mod.pyc").write_text("")
    for path in (src / "pkg" / "mod.py", src / "pkg", src):
        path.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH | (0 if path.is_file() else 0o111))
    try:
        _clean_copy(src, tmp_path / "dst")
    finally:
        for path in (src, src / "pkg", src / "pkg" / "mod.py"):
            path.chmod(path.stat().st_mode | stat.S_IWUSR)
    copied = [tmp_path / "dst", tmp_path / "dst" / "pkg", tmp_path / "dst" / "pkg" / "mod.py"]
    assert all(p.stat().st_mode & stat.S_IWUSR for p in copied), [oct(p.stat().st_mode) for p in copied]
    assert not (tmp_path / "dst" / "pkg" / "mod.pyc").exists()


def test_an_interrupt_in_the_build_folders_removal_leaves_nothing_behind(monkeypatch):
    """Ctrl-C landing in the removal of a build's temporary folder must not leave 2 MB in $TMPDIR (one of five
    interrupts of tm.build_fmus in a notebook): the removal finishes, then the interrupt is raised."""
    import build_scripts.build_fmus as build

    real, calls = shutil.rmtree, []

    def interrupted_once(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 1:
            real(next(p for p in sorted(os.scandir(path), key=lambda e: e.name)).path)  # removed in part
            raise KeyboardInterrupt
        real(path, *args, **kwargs)

    monkeypatch.setattr(build.shutil, "rmtree", interrupted_once)
    with pytest.raises(KeyboardInterrupt):
        with build._build_folder() as folder:
            for name in ("a", "b"):
                (folder / name).mkdir()
                (folder / name / "f.bin").write_bytes(b"x" * 1000)
    assert len(calls) == 2 and not folder.exists()


@pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0, reason="another user's folder is made with chown, as root")
def test_fmus_another_user_could_have_put_in_the_cache_are_not_run(tmp_path, monkeypatch):
    """The cached FMUs are code run as this user. A cache folder of another user's (a shared
    XDG_CACHE_HOME) is refused, naming the remedy; one of this user's that others may write into is
    closed to them; an FMU file of another user's in it is built anew (the build is emulated)."""
    import build_scripts.build_fmus as build
    from build_scripts.own_folder import UntrustedFolderError

    built = []

    def fake_build(folder, names):
        for name in names:
            (folder / f"{name}.fmu").write_bytes(b"ours")
        built.extend(names)

    monkeypatch.setattr(build, "build_fmus", fake_build)
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    os.chown(theirs, 65534, 65534)
    with pytest.raises(UntrustedFolderError, match=rf"the FMU cache {theirs} belongs to another user \(uid 65534\): "
                                                   r"another user could put an FMU there .* Set XDG_CACHE_HOME"):
        build.cached_fmus(theirs)
    mine = tmp_path / "mine"
    paths = build.cached_fmus(mine)
    assert sorted(built) == sorted(build.FMUS) and (mine.stat().st_mode & 0o777) == 0o755
    os.chmod(mine, 0o777)
    os.chmod(paths["MusclePlant"].parent, 0o775)
    os.chown(paths["MusclePlant"], 65534, 65534)  # left there while the folder was open to others
    built.clear()
    assert build.cached_fmus(mine) == paths
    assert built == ["MusclePlant"] and paths["MusclePlant"].stat().st_uid == 0
    assert [p.stat().st_mode & 0o777 for p in (mine, paths["MusclePlant"].parent)] == [0o755, 0o755]


def test_a_cache_through_ones_own_link_or_on_a_read_only_mount_is_used(tmp_path, monkeypatch):
    """``~/.cache/tapmuscle`` linked by its user to a larger disk is followed; a cache folder open to
    others that cannot be closed is used where its mount is read-only (no one writes there) and
    refused where it is not (a file system without modes, where anyone may)."""
    import errno
    import types

    import build_scripts.build_fmus as build
    import build_scripts.own_folder as own
    from build_scripts.own_folder import UntrustedFolderError

    def fake_build(folder, names):
        for name in names:
            (folder / f"{name}.fmu").write_bytes(b"ours")

    monkeypatch.setattr(build, "build_fmus", fake_build)
    (tmp_path / "bigdisk").mkdir()
    (tmp_path / "cache").symlink_to(tmp_path / "bigdisk")
    paths = build.cached_fmus(tmp_path / "cache")
    assert all(p.read_bytes() == b"ours" for p in paths.values()) and any((tmp_path / "bigdisk").iterdir())
    os.chmod(tmp_path / "bigdisk", 0o777)

    def refused(fd, mode):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(own.os, "fchmod", refused)
    for read_only, works in ((True, True), (False, False)):
        flags = types.SimpleNamespace(f_flag=os.ST_RDONLY if read_only else 0)
        monkeypatch.setattr(own.os, "fstatvfs", lambda fd, flags=flags: flags)
        if works:
            assert build.cached_fmus(tmp_path / "cache") == paths
        else:
            with pytest.raises(UntrustedFolderError, match=r"cannot be closed to other users \(Operation not permitted: "
                                                           r"a file system without permissions\?\)"):
                build.cached_fmus(tmp_path / "cache")
