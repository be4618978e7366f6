"""The Python API at the package root: every public name documented, and docs/python-api.md runs.

Like python-control's docstring test: each public function's (and class constructor's) parameters
must appear in its numpydoc ``Parameters`` section (or, for a dataclass field, in its attribute
docstring or field metadata: ``description``, or ``doc`` as the plant's parameter groups keep it);
an undocumented argument fails here. The same holds for every function and class that the
``__all__`` of a module of tapmuscle/, fmu_plant/ and fmu_controller/ names.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

import tapmuscle as tm
from fmu_controller.rls import TABLE2_LOWER

ROOT = Path(__file__).resolve().parents[1]


def _documented_names(doc: str | None) -> set[str]:
    """Names listed in the numpydoc Parameters / Attributes / Other Parameters sections."""
    doc = inspect.cleandoc(doc or "")
    names: set[str] = set()
    for section in re.split(r"\n(?=[A-Z][A-Za-z ]+\n-{3,}\n)", doc):
        head = section.split("\n", 1)[0].strip()
        if head not in ("Parameters", "Attributes", "Other Parameters", "Keyword Arguments"):
            continue
        for line in section.split("\n")[2:]:
            if line and not line.startswith(" "):
                for part in line.split(":")[0].split(","):
                    names.add(part.strip().lstrip("*"))
    return names


def _attribute_docstrings(cls: type) -> set[str]:
    """Fields of ``cls`` followed by a string literal (attribute docstrings), through its bases."""
    out: set[str] = set()
    for klass in cls.__mro__:
        if klass is object:
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):
            continue
        body = tree.body[0].body
        for stmt, nxt in zip(body, body[1:]):
            if (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)
                    and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
                    and isinstance(nxt.value.value, str)):
                out.add(stmt.target.id)
    return out


def undocumented(obj) -> list[str]:
    """Parameters of ``obj`` (a function, or a class's constructor) that its documentation omits."""
    if inspect.isclass(obj) and getattr(obj, "_is_protocol", False):
        # a protocol is not constructed: what it asks for is its methods, documented with it
        documented = _documented_names(obj.__doc__)
        return [f"{name}({p})" for name, method in vars(obj).items() if inspect.isfunction(method)
                and not name.startswith("_")
                for p in inspect.signature(method).parameters
                if p not in ("self", "cls") and p not in documented | _documented_names(method.__doc__)]
    if inspect.isclass(obj):
        if dataclasses.is_dataclass(obj):
            documented = _documented_names(obj.__doc__) | _attribute_docstrings(obj)
            return [f.name for f in dataclasses.fields(obj) if f.init and not f.name.startswith("_")
                    and f.name not in documented and not (f.metadata.get("description") or f.metadata.get("doc"))]
        sig = inspect.signature(obj.__init__)
        documented = _documented_names(obj.__doc__) | _documented_names(obj.__init__.__doc__)
    else:
        sig = inspect.signature(obj)
        documented = _documented_names(obj.__doc__)
    return [p for p in sig.parameters if p not in ("self", "cls") and p not in documented]


# exceptions take Exception's arguments; their docstring says when they are raised
PUBLIC = [n for n in tm.__all__ if callable(getattr(tm, n))
          and not (inspect.isclass(getattr(tm, n)) and issubclass(getattr(tm, n), BaseException))]


@pytest.mark.parametrize("name", PUBLIC)
def test_every_public_parameter_is_documented(name):
    obj = getattr(tm, name)
    assert obj.__doc__ and obj.__doc__.strip(), f"tm.{name} has no docstring"
    missing = undocumented(obj)
    assert not missing, f"tm.{name}: parameters not in its docstring: {missing}"


def test_the_check_fails_on_an_undocumented_argument():
    def documented(a: int, b: int) -> int:
        """Add.

        Parameters
        ----------
        a, b : int
            Terms.
        """
        return a + b

    def half(a: int, b: int) -> int:
        """Add.

        Parameters
        ----------
        a : int
            A term.
        """
        return a + b

    @dataclasses.dataclass
    class Settings:
        """Settings."""

        gain: float = 1.0
        """Gain [-]."""
        horizon: int = 5

    assert undocumented(documented) == []
    assert undocumented(half) == ["b"]
    assert undocumented(Settings) == ["horizon"]


#: Packages whose modules' ``__all__`` is checked (not fmi_slave/, build_scripts/, tests/).
CHECKED_PACKAGES = ("tapmuscle", "fmu_plant", "fmu_controller")


def _modules_with_all() -> list[str]:
    """Modules of :data:`CHECKED_PACKAGES` whose source sets ``__all__`` (found in the source: a
    ``__main__`` is not imported, it would run the command line)."""
    names = []
    for package in CHECKED_PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if path.name == "__main__.py":
                continue
            tree = ast.parse(path.read_text(encoding="utf-8"))
            targets = [t for s in tree.body if isinstance(s, (ast.Assign, ast.AnnAssign))
                       for t in (s.targets if isinstance(s, ast.Assign) else [s.target])]
            if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
                parts = path.relative_to(ROOT).with_suffix("").parts
                names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


def exported_definitions() -> list[tuple[str, str]]:
    """``(module, name)`` of each function and class that a module's ``__all__`` names and the module
    defines. Left out: constants, re-exports (checked where they are defined), exceptions (they take
    Exception's arguments; their docstring says when they are raised) and classes without a
    constructor of their own (``__init__`` is object's, so ``undocumented`` would see its
    ``*args, **kwargs``: a NamedTuple, a tuple subclass made by ``__new__``, an abstract base)."""
    out = []
    for module_name in _modules_with_all():
        module = importlib.import_module(module_name)
        for name in module.__all__:
            obj = getattr(module, name)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)) or obj.__module__ != module_name:
                continue
            if inspect.isclass(obj) and (issubclass(obj, BaseException) or obj.__init__ is object.__init__):
                continue
            out.append((module_name, name))
    return out


EXPORTED = exported_definitions()


def test_the_exported_definitions_are_collected():
    assert len(EXPORTED) > 50, EXPORTED


@pytest.mark.parametrize(("module_name", "name"), EXPORTED, ids=[f"{m}.{n}" for m, n in EXPORTED])
def test_every_exported_parameter_of_every_module_is_documented(module_name, name):
    obj = getattr(importlib.import_module(module_name), name)
    assert obj.__doc__ and obj.__doc__.strip(), f"{module_name}.{name} has no docstring"
    missing = undocumented(obj)
    assert not missing, f"{module_name}.{name}: parameters not in its docstring: {missing}"


def test_import_is_lazy_and_names_resolve():
    assert set(tm.__all__) <= set(dir(tm))
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        tm.nonexistent  # noqa: B018
    # docs/python-api.md: the base of every bad-input error, and a ValueError
    from tapmuscle.cosim.spec import ScenarioError
    from tapmuscle.diagnosis.plant_source import PlantSourceError
    from tapmuscle.io.plant_file import PlantFileError
    from tapmuscle.io.recording import RecordingError

    assert issubclass(tm.TapmuscleError, ValueError)
    for error in (tm.UsageError, ScenarioError, PlantFileError, PlantSourceError, RecordingError):
        assert issubclass(error, tm.TapmuscleError), error


def test_a_notebooks_tab_completion_and_help_show_the_api_alone():
    """dir(tm) offered the package's own imports (annotations, Any, importlib) beside the API, and
    help(tm.diagnose) / Shift-Tab wrote out every default candidate and constant, functions and
    paragraphs of physics (9,464 characters of signature): the defaults show as their names."""
    import inspect
    import types

    assert [n for n in dir(tm) if not n.startswith("_") and n not in tm.__all__
            and not isinstance(getattr(tm, n), types.ModuleType)] == []  # its submodules, once imported
    signatures = {name: str(inspect.signature(getattr(tm, name))) for name in tm.__all__
                  if inspect.isfunction(getattr(tm, name))}
    assert max(map(len, signatures.values())) < 1500, {n: len(s) for n, s in signatures.items() if len(s) >= 1500}
    assert "candidates: 'Sequence[Candidate | str]' = CANDIDATES (" in signatures["diagnose"]
    assert "= NOMINAL_PARAMETERS (12)" in signatures["diagnose"]


def test_a_result_shown_in_a_notebook_leaves_its_arrays_out():
    """A Diagnosis displayed in a cell wrote out every array (13 kB), an IdentificationReport its whole
    theta history, a sweep every run's scenario (225 kB for 200 runs): no public result's repr shows an
    array field but the identified theta, and a sweep counts its runs."""
    import dataclasses
    import typing

    from tapmuscle.cosim.sweep import load_sweep

    for name in tm.__all__:
        cls = getattr(tm, name)
        if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
            continue
        hints = typing.get_type_hints(cls)
        shown = [f.name for f in dataclasses.fields(cls) if f.repr and "ndarray" in str(hints[f.name])]
        assert shown == (["theta"] if name == "IdentificationReport" else []), (name, shown)  # Eq. (1)'s 15 numbers
    sweep = load_sweep(ROOT / "scenarios" / "sweeps" / "robustness_mc.toml")
    assert len(repr(sweep)) < 1000 and f"runs=<{len(sweep.runs)} runs>" in repr(sweep)
    t = np.arange(3001) * 0.1
    recording = tm.Recording(columns={"t_s": t, "u_v": np.zeros_like(t), "l_mm": np.zeros_like(t)}, metadata={"rig": "A"})
    assert repr(recording) == "Recording(3001 samples, 300 s, columns t_s, u_v, l_mm, metadata={'rig': 'A'})"


def test_a_warning_points_at_the_callers_line():
    """The braid-lock note pointed at tapmuscle/api.py (a notebook showed the package's line, and hid the
    warning when the cell ran again) and spelt the parameter "Load_n": it points at the line that
    called the API, naming load_n as it is."""
    with pytest.warns(RuntimeWarning) as caught:
        tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=2.0, load_n=30.0)
    (w,) = [w for w in caught if "braid lock" in str(w.message)]
    assert w.filename == __file__ and str(w.message).startswith("load_n = 30 N is below the braid lock's")


def test_a_light_load_warning_has_its_own_category_and_suspects_kilograms():
    """A loop over light loads (a parameter estimation) warns once per load: its category silences it
    alone. 4.5 "N" is the paper's 44 N given as a mass: the note says so; 30 N is not suspected."""
    import warnings

    with pytest.warns(tm.LightLoadWarning) as caught:
        tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=2.0, load_n=4.5)
    (w,) = caught
    assert issubclass(w.category, RuntimeWarning)
    assert "if 4.5 is a mass in kg, its weight is 44.1 N: the load is a force in N" in str(w.message)
    with pytest.warns(tm.LightLoadWarning) as caught:
        tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=2.0, load_n=30.0)
    assert "kg" not in str(caught[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", tm.LightLoadWarning)
        for load in (36.0, 38.0, 39.9):
            tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=2.0, load_n=load)


@pytest.mark.parametrize("command, at", [(np.full(50, 5000.0), "u(t = 0 s) = 5000 V"),  # mV
                                         (lambda t: 50.0 if t >= 2.0 else 5.0, "u(t = 2 s) = 50 V")])  # %
def test_a_command_outside_what_the_plant_takes_is_refused_naming_its_time(command, at):
    """The plant FMU takes -1..11 V and ``tapmuscle record`` refuses what lies outside; tm.simulate ran
    a command of 5000 (mV) saturated at 10 V without a word."""
    with pytest.raises(ValueError, match=re.escape(at) + r" is outside the -1..11 V the plant takes .*mV or %\?"):
        tm.simulate(command, duration_s=4.0)
    assert tm.simulate(np.full(50, 10.5))["u_v"][0] == 10.5  # within a volt beyond: clipped by the amplifier


def test_a_scenario_shortened_in_code_is_refused_before_its_run():
    """dataclasses.replace(scenario, duration_s=20.0) ran the whole co-simulation and then failed on
    Eq. (21)'s window: the replaced scenario is refused at once, naming evaluation_samples."""
    import dataclasses

    from tapmuscle.cosim.spec import ScenarioError

    scenario = tm.load_scenario(ROOT / "scenarios" / "paper" / "ampc_servo_44N_0.1Hz.toml")
    with pytest.raises(ScenarioError, match=r"evaluation_samples = \(101, 401\) is not within the run's samples "
                                            r"k = 0 \.\. 200 \(20 s at step 0\.1 s\)"):
        dataclasses.replace(scenario, duration_s=20.0)
    assert dataclasses.replace(scenario, duration_s=20.0, evaluation_samples=(0, 200)).n_samples == 201


def _examples() -> list[tuple[str, str]]:
    """The ``python`` code blocks of docs/python-api.md, with the heading each stands under."""
    out: list[tuple[str, str]] = []
    heading, code = "", None
    for line in (ROOT / "docs" / "python-api.md").read_text().splitlines():
        if code is not None:
            if line.startswith("```"):
                out.append((heading, "\n".join(code)))
                code = None
            else:
                code.append(line)
        elif line.startswith("```python"):
            code = []
        elif line.startswith("#"):
            heading = line.lstrip("# ").strip()
    return out


@pytest.mark.slow
def test_the_documented_examples_run(tmp_path, monkeypatch):
    """Every example of docs/python-api.md, in order, in one namespace (later ones use earlier results);
    each states what it shows with ``assert``."""
    monkeypatch.chdir(tmp_path)
    examples = _examples()
    assert len(examples) >= 6
    namespace: dict = {"np": np}
    for heading, code in examples:
        try:
            exec(compile(code, f"docs/python-api.md ({heading})", "exec"), namespace)  # noqa: S102
        except Exception as exc:  # noqa: BLE001 - name the failing example
            pytest.fail(f"docs/python-api.md, example under '{heading}': {type(exc).__name__}: {exc}")


_PAPER_SCENARIO = tm.PAPER_SCENARIOS / "ampc_servo_44N_0.1Hz.toml"
SWEEP_FILE = ROOT / "scenarios" / "sweeps" / "paper_grid.toml"


def _RANDOM_RUN():
    """A 60-s open-loop record's command [V] and displacement [mm] at 0.1 s (601 samples)."""
    cols = tm.simulate("random:lo=2,hi=8,seed=3", duration_s=60.0)
    return cols["u_v"], cols["l_mm"]


@pytest.mark.parametrize("call, error, match", [
    (lambda: tm.Plant(seed=None), ValueError, r"seed = None must be an integer"),
    (lambda: tm.simulate("const:value=5", duration_s=2.0, seed=None), ValueError, r"seed = None must be an integer"),
    (lambda: tm.simulate(np.array([5.0])), ValueError, r"command has 1 sample; give at least 2 samples, or duration_s"),
    (lambda: tm.diagnose(np.arange(10.0), np.ones(10), np.ones(10), "MusclePlant.fmu"), TypeError,
     r"model must be a PlantParams .* got str 'MusclePlant.fmu'"),
    (lambda: tm.cosimulate(_PAPER_SCENARIO, out="x", figure_format="jpg"), ValueError,
     r"figure_format must be one of png, pdf, svg, got 'jpg'"),
    (lambda: tm.cosimulate(_PAPER_SCENARIO, fmus=["MusclePlant.fmu", "AMPCController.fmu"]), TypeError,
     r"fmus must be a mapping .* got a list"),
    (lambda: tm.cosimulate(_PAPER_SCENARIO, fmus={"MusclePlant": "MusclePlant.fmu"}), ValueError,
     r"fmus has no 'AMPCController' .*given: 'MusclePlant'"),
    (lambda: tm.cosimulate(_PAPER_SCENARIO, fmus={"MusclePlantt": "a.fmu", "AMPCController": "b.fmu"}), ValueError,
     r"fmus takes the keys 'MusclePlant' and 'AMPCController' \(the FMUs' roles\), got 'MusclePlantt' \(did you "
     r"mean 'MusclePlant'\?\)"),
    (lambda: tm.cosimulate(_PAPER_SCENARIO, fmus={"MusclePlant": "nope.fmu", "AMPCController": "no.fmu"}), ValueError,
     r"fmus names no FMU file for AMPCController: no.fmu; MusclePlant: nope.fmu"),
    (lambda: tm.sweep(SWEEP_FILE, "o", fmus=["MusclePlant.fmu", "AMPCController.fmu"]), TypeError,
     r"fmus must be a mapping .* got a list"),
    (lambda: tm.sweep(SWEEP_FILE, "o", fmus={"MusclePlant": "MusclePlant.fmu"}), ValueError, r"fmus has no 'AMPCController'"),
    (lambda: tm.sweep(SWEEP_FILE, "o", client="tcp://127.0.0.1:1"), ValueError,
     r"client must be a running distributed.Client, got 'tcp://127.0.0.1:1' \(for a scheduler's address"),
    (lambda: tm.sweep(SWEEP_FILE, SWEEP_FILE), ValueError, r"out must be a folder to write into, .* \(an existing file\)"),
    (lambda: tm.sweep(123, "o"), TypeError, r"sweep must be a sweep file's path or a Sweep, got a int"),
    (lambda: tm.simulate_closed_loop(42, None, duration_s=1.0), TypeError, r"unknown method 42; expected one of"),
    (lambda: tm.simulate_closed_loop("ampc", None, duration_s=1.0), ValueError, r"unknown method 'ampc'; expected"),
    (lambda: tm.simulate("const:value=5", duration_s=2.0, load_n="68"), TypeError, r"load_n must be a number of newtons"),
    (lambda: tm.identify(np.ones(50), np.ones(50), ts_s="0.1"), TypeError, r"ts_s must be a number of seconds, got str"),
    # a plant file is read by its reader, as a recording or an identification is
    (lambda: tm.simulate("const:value=5", duration_s=2.0, params="calibrated_plant.json"), TypeError,
     r"params must be a PlantParams, got str 'calibrated_plant.json': a plant parameter file is read by "
     r"tm.read_plant_file\(path\)"),
    (lambda: tm.simulate_closed_loop("mpc_ucp", None, duration_s=2.0, params=Path("calibrated_plant.json")), TypeError,
     r"params must be a PlantParams, got \w+Path .*tm.read_plant_file\(path\)"),
    (lambda: tm.simulate("const:value=5", duration_s=2.0, params={"plant": {}}), TypeError,
     r"params must be a PlantParams, got dict \{'plant': \{\}\}$"),
    # a notebook user's calls that met a numpy or pathlib error naming nothing, or a period in ms let through
    (lambda: tm.identify(*_RANDOM_RUN(), ts_s=100), ValueError,
     r"ts_s = 100(.0)? s is outside the 0.001..10 s of the muscle's sampling .* a period in milliseconds\?"),
    (lambda: tm.choose_input_delay(*(x[:, None] for x in _RANDOM_RUN()), ts_s=0.1), ValueError,
     r"u and l must be 1-D arrays of equal length, got shapes \(601, 1\) and \(601, 1\)"),
    (lambda: tm.choose_input_delay(*_RANDOM_RUN(), ts_s=100), ValueError, r"ts_s = 100(.0)? s is outside"),
    (lambda: tm.identify(*_RANDOM_RUN(), ts_s=0.0005), ValueError,
     r"ts_s = 0.0005 s is outside .* a data acquisition faster than the muscle needs\? Merge its samples"),
    (lambda: tm.identify(*_RANDOM_RUN(), ts_s=0.1, box={"a1": 1.0}), ValueError,
     r"box \(asymmetric model\): a1 must be a pair \(lower, upper\) of numbers, got 1.0"),
    (lambda: tm.score_model(tm.THETA0_44N, "asymetric", *_RANDOM_RUN()), ValueError,
     r"unknown model structure 'asymetric'; expected one of asymmetric, standard"),
    (lambda: tm.score_model(tm.THETA0_44N, 3, *_RANDOM_RUN()), TypeError, r"structure must be a ModelStructure"),
    (lambda: tm.DisplacementController(tm.ControllerSettings(), tm.THETA0_44N).step(np.array([0.5]), [35.0] * 9),
     TypeError, r"measured l_mm must be one number \[mm\], got ndarray array\(\[0.5\]\)"),
    (lambda: tm.LoopWatch(tm.ControllerSettings()), TypeError,
     r"LoopWatch watches a DisplacementController, got ControllerSettings"),
    (lambda: tm.decimated({"t_s": [0.0, 0.1]}, 2), TypeError, r"decimated takes a Recording .* got dict"),
    (lambda: tm.diagnose_files(tm.Recording({"t_s": [0.0, 0.1], "u_v": [1.0, 1.0], "l_mm": [0.0, 0.0]}),
                               "p.json", "out"), TypeError,
     r"diagnose_files: recording must be a path .* got Recording .*; tm.diagnose\(rec.t_s, rec.u_v, rec.l_mm"),
    (lambda: tm.diagnose_files("rig.csv", tm.PlantParams(), "out"), TypeError,
     r"diagnose_files: plant must be a path .* got PlantParams"),
    (lambda: tm.cosimulate({"plant": {}}), TypeError, r"scenario must be a scenario TOML file's path or a Scenario"),
])
def test_a_wrong_argument_is_named(call, error, match):
    with pytest.raises(error, match=match):
        call()


@pytest.mark.slow
def test_a_callers_numpy_error_handling_changes_no_result(built_fmus):
    """Careful notebooks set ``np.seterr(all="raise")``, and fmpy runs the FMUs in the caller's thread,
    under that setting. Where the numerics rely on IEEE arithmetic they say so themselves (the RLS's
    covariance loss), so the direct loop, an identification and a co-simulation through both FMUs give
    the default's results bit for bit."""
    from tapmuscle.cosim import PAPER_SCENARIOS

    scenario = tm.load_scenario(PAPER_SCENARIOS / "ampc_servo_44N_0.1Hz.toml")

    def runs() -> list[np.ndarray]:
        loop = tm.simulate_closed_loop("ampc_servo", None, duration_s=30.0, seed=3)
        rec = tm.simulate("random:lo=2,hi=8,hold_min=1,hold_max=4,seed=2", duration_s=60.0)
        fit = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1)
        co = tm.cosimulate(scenario, fmus=built_fmus)["columns"]
        return [loop["l_mm"], loop["u_v"], fit.theta_history, co["l_mm"], co["u_v"]]

    default = runs()
    with np.errstate(all="raise"):
        raised = runs()
    for a, b in zip(default, raised):
        assert np.array_equal(a, b)


def _short(path: Path, method: str):
    import dataclasses as dc

    sc = tm.load_scenario(path)
    return dc.replace(sc, name=f"short_{method}", duration_s=3.0, evaluation_samples=(5, 30), method=method)


@pytest.mark.slow
def test_an_output_folder_holds_one_run(built_fmus, tmp_path):
    """``cosimulate(out=DIR)`` (and ``tapmuscle run``) writes a run's files together: a second run into
    the same folder leaves none of the first run's files that it does not write (the adaptive
    controller's ``parameters.png`` after a fixed-predictor run), and keeps the user's own files."""
    out = tmp_path / "run"
    tm.cosimulate(_short(_PAPER_SCENARIO, "ampc_servo"), fmus=built_fmus, out=out)
    assert {p.name for p in out.iterdir()} == {"result.csv", "summary.json", "tracking.png",
                                               "prediction_error.png", "parameters.png"}
    (out / "notes.txt").write_text("mine")
    tm.cosimulate(_short(_PAPER_SCENARIO, "mpc_servo"), fmus=built_fmus, out=out)
    assert {p.name for p in out.iterdir()} == {"result.csv", "summary.json", "tracking.png",
                                               "prediction_error.png", "notes.txt"}
    assert '"method": "mpc_servo"' in (out / "summary.json").read_text()
    tm.cosimulate(_short(_PAPER_SCENARIO, "mpc_servo"), fmus=built_fmus, out=out, plots=False)
    assert {p.name for p in out.iterdir()} == {"result.csv", "summary.json", "notes.txt"}
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # no staging folder left


def test_an_output_path_that_is_a_file_is_refused_before_the_run(built_fmus, tmp_path):
    (tmp_path / "taken").write_text("a file")
    with pytest.raises(NotADirectoryError, match="taken is a file, not a folder"):
        tm.cosimulate(_PAPER_SCENARIO, fmus=built_fmus, out=tmp_path / "taken")
    assert (tmp_path / "taken").read_text() == "a file"


def test_theta0_is_taken_in_both_forms_an_identification_gives():
    """``identify`` and ``simulate_closed_loop`` both take ``report.theta`` (an array in the model's
    order) and ``report.theta_dict`` (by name), with the same result."""
    rec = tm.simulate("random:lo=2,hi=8,hold_min=1,hold_max=4,seed=2", duration_s=40.0)
    fit = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1)
    by_order = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1, theta0=fit.theta)
    by_name = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1, theta0=fit.theta_dict)
    assert np.array_equal(by_order.theta, by_name.theta)
    named = dict(zip(tm.ASYMMETRIC.names, tm.THETA0_44N))
    a = tm.simulate_closed_loop("mpc_servo", None, duration_s=3.0, theta0=named)
    b = tm.simulate_closed_loop("mpc_servo", None, duration_s=3.0, theta0=np.array(tm.THETA0_44N))
    assert np.array_equal(a["u_v"], b["u_v"])
    with pytest.raises(ValueError, match=r"theta0 names 14 of the 15 parameters; missing: xi32"):
        tm.simulate_closed_loop("mpc_servo", None, duration_s=3.0,
                                theta0={n: v for n, v in named.items() if n != "xi32"})
    with pytest.raises(TypeError, match=r"theta0 must be a mapping .* got str"):
        tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1, theta0="THETA0_44N")


def test_tm_identifys_result_is_a_theta0_with_its_period_box_and_delay():
    """The report ``tm.identify`` returns, given as ``theta0``, brings its period (a bare ``theta`` has
    none and runs at the default 0.1 s), its box and its delay, checked as an identification file is:
    a period that disagrees, the standard model, a recording not in mm are said as for a file."""
    rec = tm.simulate("random:lo=2,hi=8,hold_min=0.5,hold_max=3,seed=1", duration_s=60.0, ts_s=0.05)
    fit = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.05, input_delay_samples=1)
    run = tm.simulate_closed_loop("ampc_servo", None, duration_s=2.0, theta0=fit, watch=False)
    assert run["t_s"][1] == pytest.approx(0.05)
    settings = tm.ControllerSettings(method="ampc_servo", ts_s=0.05, box_lower=fit.box_lower, box_upper=fit.box_upper,
                                     input_delay_samples=1)
    same = tm.simulate_closed_loop("ampc_servo", None, duration_s=2.0, theta0=fit.theta, settings=settings, watch=False)
    assert np.array_equal(run["u_v"], same["u_v"])
    with pytest.raises(ValueError, match=r"theta0 \(tm.identify's result\): identified at ts_s = 0.05 s, the "
                                         r"controller samples at 0.1 s"):
        tm.simulate_closed_loop("mpc_servo", None, duration_s=2.0, ts_s=0.1, theta0=fit)
    # at 0.1 s the report's box is Table 2's, taken along: the same run as with that box set
    rec = tm.simulate("random:lo=2,hi=8,hold_min=0.5,hold_max=3,seed=1", duration_s=150.0)
    fit = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1)
    assert fit.box_lower == dict(TABLE2_LOWER)
    wide = {"a1": -5.0, "a2": -5.0, "b1": 0.01}
    boxed = tm.simulate_closed_loop("ampc_servo", None, duration_s=12.0, theta0=fit, watch=False,
                                    settings=tm.ControllerSettings(method="ampc_servo", box_lower=fit.box_lower,
                                                                   box_upper=fit.box_upper))
    assert np.array_equal(tm.simulate_closed_loop("ampc_servo", None, duration_s=12.0, theta0=fit, watch=False)["u_v"],
                          boxed["u_v"])
    other = tm.simulate_closed_loop("ampc_servo", None, duration_s=12.0, theta0=fit.theta, watch=False,
                                    settings=tm.ControllerSettings(method="ampc_servo", box_lower=wide, box_upper={}))
    assert not np.array_equal(other["u_v"], boxed["u_v"])  # the box matters to this run
    standard = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1, model="standard")
    with pytest.raises(ValueError, match=r"theta0 \(tm.identify's result\): key 'model' is 'standard'; the "
                                         r"controllers use the asymmetric model"):
        tm.simulate_closed_loop("mpc_servo", None, duration_s=2.0, theta0=standard)
    metres = tm.identify(rec["u_v"], rec["l_mm"] / 1000.0, ts_s=0.1)
    # the report says it itself, as the command line does
    assert [n for n in metres.notes if "metres?" in n] == [
        "identified on a recording whose largest displacement is under about 1.9 (scaling.l_scale = 0.001: metres?); "
        "the controllers need Eq. (1) in mm and V, as their readings l and command u are: identify on the recording "
        "in mm and V"]
    assert not [n for n in fit.notes if "identified on a recording" in n]
    with pytest.warns(UserWarning, match=r"theta0 \(tm.identify's result\): identified on a recording whose "
                                         r"largest displacement is under about 1.9"):
        tm.simulate_closed_loop("mpc_servo", None, duration_s=2.0, theta0=metres, watch=False)


def test_another_sampling_period_needs_its_own_predictor():
    """THETA0_44N is a 0.1-s model: at 0.2 s it gives 13 mm of error, so the default is refused there;
    a theta0 given is the caller's (identified at that period, say)."""
    with pytest.raises(ValueError, match=r"ts_s = 0.2 s needs a theta0 identified at that period: the default "
                                         r"THETA0_44N is the paper's, identified at Ts = 0.1 s"):
        tm.simulate_closed_loop("mpc_ucp", None, duration_s=3.0, ts_s=0.2)
    run = tm.simulate_closed_loop("mpc_ucp", None, duration_s=3.0, ts_s=0.2, theta0=tm.THETA0_44N)
    assert len(run["t_s"]) == 16
    assert len(tm.simulate_closed_loop("mpc_ucp", None, duration_s=30 * 0.10000001, ts_s=0.10000001)["t_s"]) == 31
    # off 0.1 s the default settings have no box (Table 2's is for 0.1 s, as tm.identify applies none
    # there): a theta0 identified at 0.2 s with b1 below Table 2's 0.607 starts an adaptive controller
    from fmu_controller.hysteresis_model import ASYMMETRIC

    theta = dict(zip(ASYMMETRIC.names, tm.THETA0_44N))
    run = tm.simulate_closed_loop("ampc_servo", None, duration_s=3.0, ts_s=0.2, theta0=theta | {"b1": 0.3})
    assert len(run["t_s"]) == 16
    # a period in milliseconds is refused as tapmuscle record --ts refuses it (else it would run 2 samples)
    for call in (lambda: tm.simulate_closed_loop("mpc_ucp", None, ts_s=50.0, theta0=tm.THETA0_44N),
                 lambda: tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=100.0, ts_s=50.0)):
        with pytest.raises(ValueError, match=r"ts_s = 50.0 s is outside the 0.001..10 s .*milliseconds"):
            call()


def test_every_bad_input_error_is_a_tapmuscle_error():
    """``except tm.TapmuscleError`` catches every error class the package defines for bad input (the
    ``ValueError`` kinds): a recording's sampling, a signal map, a foreign FMU, a scenario, a plant file."""
    import importlib
    import pkgutil

    found = {}
    for info in pkgutil.walk_packages(tm.__path__, "tapmuscle."):
        if ".foreign_fmus." in info.name or info.name.endswith("__main__"):
            continue  # FMU sources (built, not imported) and entry points
        module = importlib.import_module(info.name)
        for obj in vars(module).values():
            if (inspect.isclass(obj) and issubclass(obj, ValueError) and obj.__module__ == info.name
                    and not obj.__name__.startswith("_")):
                found[f"{info.name}.{obj.__name__}"] = obj
    assert {"tapmuscle.io.sampling.SamplingError", "tapmuscle.diagnosis.signal_map.SignalMapError",
            "tapmuscle.io.recording.RecordingError"} <= set(found)
    assert [name for name, cls in found.items() if not issubclass(cls, tm.TapmuscleError)] == []


@pytest.mark.parametrize("command, match", [
    (lambda t: np.array([5.0]), r"u\(t = 0 s\) returned an array of shape \(1,\), not one command \[V\]"),
    (lambda t: None, r"u\(t = 0 s\) = None is not a number \[V\]"),
])
def test_a_command_function_that_returns_no_number_is_named(command, match):
    with pytest.raises(ValueError, match=match):
        tm.simulate(command, duration_s=1.0)


def test_simulate_replays_a_recording_as_the_command_line_does(tmp_path):
    """``csv:PATH`` in Python: the recording's commands sample by sample from its first sample (its
    times here start at 1000 s: the run held one command), over its whole length unless told, and a
    run at another period or past its end is refused."""
    from tapmuscle.io.recording import Recording, write_recording

    u = np.round(np.repeat([3.0, 7.0, 5.0, 6.5], 50), 6)
    path = tmp_path / "late.csv"
    write_recording(path, Recording({"t_s": 1000.0 + 0.1 * np.arange(u.size), "u_v": u, "l_mm": 0 * u}))
    assert np.array_equal(tm.simulate(f"csv:{path}", duration_s=10.0)["u_v"], u[:101])
    rec = tm.simulate(f"csv:{path}")
    assert np.array_equal(rec["u_v"], u) and rec["t_s"][-1] == pytest.approx(19.9)
    with pytest.raises(ValueError, match=r"the run's duration 30 s \(301 samples\) is longer than .*late\.csv's 19\.9 s"):
        tm.simulate(f"csv:{path}", duration_s=30.0)
    with pytest.raises(ValueError, match=r"late\.csv is sampled every 0\.1 s, the run every 0\.05 s"):
        tm.simulate(f"csv:{path}", duration_s=10.0, ts_s=0.05)


def test_an_effect_of_ones_own_runs_in_simulate_and_the_closed_loop():
    """tm.simulate and tm.simulate_closed_loop took no effect of one's own (TypeError: unexpected
    keyword 'effects'); they take one, or several, as Plant does, and a non-Effect is a TypeError."""
    from fmu_plant import Effect

    class HalfSupply(Effect):
        name = "half_supply"

        def supply_pressure(self, t_s, p_mpa):
            return 0.5 * p_mpa

    plain = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=20.0)
    halved = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=20.0, effects=HalfSupply())
    assert plain["l_mm"].max() - halved["l_mm"].max() > 5.0  # half the supply: much less contraction
    loop = tm.simulate_closed_loop("mpc_ucp", None, duration_s=20.0, effects=[HalfSupply()])
    assert np.all(np.isfinite(loop["l_mm"]))
    with pytest.raises(TypeError, match=r"effects must be Effect instances \(subclasses of fmu_plant\.Effect\), got dict"):
        tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=2.0, effects=[{"supply": 0.5}])


@pytest.mark.parametrize("run", [lambda: tm.simulate("const:value=5", duration_s=2.05),
                                 lambda: tm.simulate_closed_loop("ampc_servo", None, duration_s=45.05)])
def test_a_duration_between_two_samples_is_refused_naming_the_nearest(run):
    """45.05 s at Ts = 0.1 s ran 45.0 s without a word (a scenario file refused it already)."""
    with pytest.raises(ValueError, match=r"duration_s = \d+\.05 s is not a whole number of sampling periods ts_s = "
                                         r"0.1 s \(\d+\.5\); the nearest: (2 and 2.1|45 and 45.1) s"):
        run()
