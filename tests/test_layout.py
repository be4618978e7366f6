"""The package layout shows its layers, and data flows one way.

What ships inside the FMUs (``fmu_plant``, ``fmu_controller``, ``fmi_slave``) and the FMU build
(``build_scripts``) never import :mod:`tapmuscle`. Inside :mod:`tapmuscle` the layers are, bottom
to top: ``errors``, ``provenance``, ``interrupts``, ``progress``, ``io``, ``plots``, ``own_law``, ``closed_loop``, ``soak``,
``cosim``, ``diagnosis``, ``paper``, ``cli``, and the package root (the Python API face). A module may import its own layer and the
layers below it, never one above: the test reads every import statement, including those inside
functions. The plant's and the controller's packages ship in different FMUs and import neither each
other nor, outside their slave modules, anything of FMI.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest
from fmpy_helpers import host_lines

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ["tapmuscle.errors", "tapmuscle.provenance", "tapmuscle.interrupts", "tapmuscle.progress", "tapmuscle.tracking_metrics",
          "tapmuscle.io",
          "tapmuscle.plots", "tapmuscle.own_law",
          "tapmuscle.closed_loop", "tapmuscle.soak",
          "tapmuscle.cosim",
          "tapmuscle.diagnosis", "tapmuscle.paper", "tapmuscle.cli", "tapmuscle"]
FOUNDATION = ["fmu_plant", "fmu_controller", "fmi_slave", "build_scripts"]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, source: str | None = None) -> list[tuple[int, str]]:
    """Every module ``path`` imports (absolute names), with the line."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8") if source is None else source, str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((node.lineno, mod))
            # ``from pkg import sub`` imports the submodule when there is one
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names
                    if (ROOT / mod.replace(".", "/") / f"{a.name}.py").exists()
                    or (ROOT / mod.replace(".", "/") / a.name / "__init__.py").exists()]
    return out


def _layer(module: str) -> int | None:
    """Index in LAYERS of the layer ``module`` belongs to (longest prefix), None outside tapmuscle."""
    best = None
    for i, layer in enumerate(LAYERS):
        if module == layer or module.startswith(layer + "."):
            if best is None or len(layer) > len(LAYERS[best]):
                best = i
    return best


def _sources(*tops: str) -> list[Path]:
    return sorted(p for top in tops for p in (ROOT / top).rglob("*.py"))


@pytest.mark.parametrize("path", _sources("tapmuscle"), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_import_points_to_a_higher_layer(path):
    own = _layer(_module_name(path))
    assert own is not None
    upward = [f"line {line}: {mod} ({LAYERS[_layer(mod)]} is above {LAYERS[own]})"
              for line, mod in _imports(path) if _layer(mod) is not None and _layer(mod) > own]
    assert not upward, f"{path.relative_to(ROOT)} imports upward: " + "; ".join(upward)


@pytest.mark.parametrize("path", _sources(*FOUNDATION), ids=lambda p: str(p.relative_to(ROOT)))
def test_fmu_contents_and_the_build_never_import_tapmuscle(path):
    bad = [f"line {line}: {mod}" for line, mod in _imports(path) if _layer(mod) is not None]
    assert not bad, f"{path.relative_to(ROOT)} imports tapmuscle: " + "; ".join(bad)


#: The FMI shell of each FMU package: the only modules there that may know of FMI (pythonfmu, the
#: project's slave base fmi_slave); the numerics beside them know nothing of FMUs.
FMI_SHELLS = {"fmu_plant.plant_slave", "fmu_controller.controller_slave"}


@pytest.mark.parametrize("path", _sources("fmu_plant", "fmu_controller"), ids=lambda p: str(p.relative_to(ROOT)))
def test_each_fmus_numerics_stand_alone_and_know_nothing_of_fmi(path):
    """The plant's and the controller's packages ship in different FMUs: neither imports the other, and
    outside their slave modules neither imports pythonfmu, fmi_slave, fmpy or the build."""
    name = _module_name(path)
    own, other = ("fmu_plant", "fmu_controller") if name.startswith("fmu_plant") else ("fmu_controller", "fmu_plant")
    fmi = ("pythonfmu", "fmi_slave", "fmpy", "build_scripts")
    bad = [f"line {line}: {mod}" for line, mod in _imports(path)
           if mod == other or mod.startswith(other + ".")
           or (name not in FMI_SHELLS and any(mod == f or mod.startswith(f + ".") for f in fmi))]
    assert not bad, f"{path.relative_to(ROOT)} imports beyond its own numerics: " + "; ".join(bad)


@pytest.mark.parametrize("module", ["tapmuscle.cosim.master", "tapmuscle.cosim.spec", "tapmuscle.cosim.expect"])
def test_running_fmus_loads_none_of_the_controllers_numerics(module):
    """The co-simulation master, a scenario's reading and its metrics drive and score FMUs: a process
    that only does that (a foreign FMU's master, a Dask worker, a host under valgrind) loads neither the
    controllers (osqp, scipy.sparse) nor the direct closed loop, which the FMU carries in its own copy."""
    code = (f"import sys, {module}\n"
            "print(sorted(m for m in ('osqp', 'scipy', 'fmu_controller.displacement_control', 'tapmuscle.closed_loop')"
            " if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "[]", f"import {module} loaded {done.stdout.strip()}"


def test_the_checker_sees_upward_imports_in_every_form():
    # a module of the io layer importing the command line, absolutely, relatively, inside a function
    fake = ROOT / "tapmuscle" / "io" / "fake.py"
    source = "import numpy\nfrom tapmuscle.cli import main\ndef f():\n    from ..cli.sweep import register\n"
    found = _imports(fake, source)
    assert (2, "tapmuscle.cli") in found and (4, "tapmuscle.cli.sweep") in found
    assert all(_layer(m) > _layer("tapmuscle.io.fake") for _, m in found if _layer(m) is not None)
    assert _layer("tapmuscle") == len(LAYERS) - 1 and _layer("tapmuscle_other") is None


def test_every_package_folder_is_installed():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {_module_name(p) for top in [*FOUNDATION, "tapmuscle"] for p in (ROOT / top).rglob("__init__.py")}
    assert found - listed == set(), "package folders missing from pyproject.toml's packages"
    assert "tapmuscle.scenario_files" in listed and (ROOT / "scenarios" / "paper").is_dir()


def test_only_what_ships_in_the_fmus_is_a_top_level_package():
    tops = {p.parent.name for p in ROOT.glob("*/__init__.py")}
    # scenarios/ is the scenario files' folder (installed as tapmuscle.scenario_files), not a package
    assert tops == {*FOUNDATION, "tapmuscle", "scenarios"}
    assert not list((ROOT / "scenarios").glob("*.py"))[1:], "scenarios/ holds scenario files, not code"


def test_a_checkout_imported_without_its_install_finds_its_scenario_files():
    """With the checkout first on sys.path and no ``tapmuscle.scenario_files`` package (a non-editable
    install beside ``python -m pytest``, or ``sys.path.insert(0, checkout)`` in a notebook), the
    scenario files are the checkout's ``scenarios/``."""
    code = textwrap.dedent("""
        import importlib.abc, sys
        class NoDataPackage(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name == "tapmuscle.scenario_files":
                    raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        sys.meta_path.insert(0, NoDataPackage())
        from tapmuscle.cosim import PAPER_SCENARIOS, SCENARIO_FILES
        print(SCENARIO_FILES, len(list(PAPER_SCENARIOS.glob("*.toml"))))
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    folder, n_paper = host_lines(done.stdout)[-1].rsplit(maxsplit=1)  # the checkout's path may hold spaces
    assert Path(folder) == ROOT / "scenarios" and int(n_paper) >= 10
