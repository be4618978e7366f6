"""What produced a result: the software versions written into the JSON documents tapmuscle leaves.

A closed loop whose valve command saturates is chaotic: another numpy, scipy or osqp release, or
another CPU's SIMD kernels, changes the last bits of a step and, through the loop, an Eq. (21) error in
its second or third digit (docs/control.md). ``summary.json``, ``paper.json``, ``diagnosis.json``, an
identification file and a demonstration's ``scores.json`` therefore carry a ``"software"`` object
(:func:`software`), so that two results can be told apart by what made them before their numbers are.
``tapmuscle --version`` prints the same. Run from a git checkout (an editable install), it also
names the commit and whether the checkout had changes; a command of the console script is written
beside it as ``"command"`` (:func:`produced_by`, :func:`invoked_as`).
"""

from __future__ import annotations

import contextvars
import hashlib
import os
import platform
import shlex
import shutil
import subprocess
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path
from typing import Iterator, Sequence

__all__ = ["NUMERICS_PACKAGES", "CODE_PACKAGES", "package_version", "software", "software_text", "cpu_features",
           "source_revision", "code_digest", "produced_by", "invoked_as"]

#: The packages whose release can change a result's last bits (the FMUs run in pythonfmu, the
#: co-simulation in fmpy).
NUMERICS_PACKAGES = ("numpy", "scipy", "osqp", "pythonfmu", "fmpy")


#: The packages of tapmuscle's own code (the distribution's top-level packages).
CODE_PACKAGES = ("tapmuscle", "fmu_plant", "fmu_controller", "fmi_slave", "build_scripts")


def package_version(name: str) -> str:
    """The installed release of distribution ``name``, or ``"not installed"``.

    Parameters
    ----------
    name : str
        A distribution's name (e.g. ``"numpy"``).
    """
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not installed"


def cpu_features() -> str:
    """The SIMD levels numpy dispatches to on this CPU (``"X86_V3"``: AVX2; ``"X86_V3 X86_V4 ..."``:
    AVX-512; with ``NPY_DISABLE_CPU_FEATURES`` those left on): the floating-point path that changes
    a chaotic closed loop's last bits (docs/control.md); ``"baseline"`` when none beyond numpy's
    baseline, ``"unknown"`` where numpy does not say."""
    try:
        try:
            from numpy._core import _multiarray_umath as umath
        except ImportError:  # numpy 1.x
            from numpy.core import _multiarray_umath as umath  # type: ignore[no-redef]
        enabled = [name for name in umath.__cpu_dispatch__ if umath.__cpu_features__.get(name)]
    except (ImportError, AttributeError):
        return "unknown"
    return " ".join(enabled) or "baseline"


def source_revision() -> str | None:
    """The git commit tapmuscle runs from, ``"<12 hex digits>"`` or ``"<...> with changes"`` (files
    tracked by git modified; untracked ones do not count), where the package is imported from a git
    checkout of its own (an editable install); None where it is not (an installed wheel, or a
    ``tapmuscle`` folder some other repository holds without tracking it), and a reason where git
    cannot tell (``"a git checkout, git not found"``; git refusing a checkout another user owns)."""
    root = Path(__file__).resolve().parent.parent
    if not (root / ".git").exists():
        return None
    git = shutil.which("git")
    if git is None:
        return "a git checkout, git not found to name its commit"
    # this checkout's git, whatever a git hook running tapmuscle exported (GIT_DIR names another
    # repository); no optional locks: a commit the user makes meanwhile must not find the index taken
    env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_")}

    def git_says(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([git, "--no-optional-locks", "-C", str(root), *args], capture_output=True, text=True,
                              timeout=10, env=env)

    try:
        head = git_says("rev-parse", "--show-toplevel", "HEAD")
        tracked = git_says("ls-files", "--error-unmatch", "--", "tapmuscle/provenance.py")
        status = git_says("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"a git checkout, git failed: {exc}"
    if head.returncode or status.returncode:
        why = (head.stderr or status.stderr).strip().splitlines()
        # without parentheses: tapmuscle --version puts its facts in parentheses after it
        return f"a git checkout, git says: {why[0] if why else 'failed'}".replace("(", "").replace(")", "")
    top, commit = head.stdout.split()[:2]
    if Path(top).resolve() != root or tracked.returncode:  # another repository's folder holds it
        return None
    return commit[:12] + (" with changes" if status.stdout.strip() else "")


def code_digest() -> str:
    """A digest (12 hex digits) of the Python sources of :data:`CODE_PACKAGES` as imported here: one
    number for the code a process runs, whether installed from a wheel or from a checkout, which the
    version does not give (every commit of a release has its version). Compiled extensions are left
    out (each machine builds its own).

    Raises
    ------
    ImportError
        One of the packages cannot be imported.
    """
    import importlib

    h = hashlib.sha256()
    for name in CODE_PACKAGES:
        folder = Path(importlib.import_module(name).__file__).parent
        for f in sorted(folder.rglob("*.py"), key=lambda f: f.relative_to(folder).as_posix()):
            if "__pycache__" not in f.parts:
                h.update(f"{name}/{f.relative_to(folder).as_posix()}".encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:12]


def software() -> dict[str, str]:
    """The versions that produce a result here.

    Returns
    -------
    dict
        ``tapmuscle`` and each of :data:`NUMERICS_PACKAGES` (the installed releases), ``matplotlib``
        (the figures'), ``python``, ``machine`` (operating system and processor architecture, as
        ``Linux x86_64``), ``cpu_features`` (:func:`cpu_features`), ``compiled_substep`` (``"yes"``
        where the plant's Rosenbrock sub-step runs compiled, ``"no"`` where in Python: the same bits,
        only slower, docs/plant.md) and, run from a git checkout, ``source``
        (:func:`source_revision`).
    """
    from fmu_plant.rosenbrock import COMPILED

    found = {"tapmuscle": package_version("tapmuscle"), "python": platform.python_version(),
             **{name: package_version(name) for name in NUMERICS_PACKAGES}, "matplotlib": package_version("matplotlib"),
             "machine": f"{platform.system()} {platform.machine()}", "cpu_features": cpu_features(),
             "compiled_substep": "yes" if COMPILED else "no"}
    revision = source_revision()
    return found if revision is None else found | {"source": revision}


#: The command line of the console script running now (:func:`invoked_as`); None in a program's or a
#: notebook's call of the API.
_COMMAND: contextvars.ContextVar[str | None] = contextvars.ContextVar("tapmuscle_command", default=None)


@contextmanager
def invoked_as(argv: Sequence[str]) -> Iterator[None]:
    """Within the block, :func:`produced_by` names the command ``tapmuscle ARGV...`` (the console
    script's arguments), quoted so that it can be pasted into a shell.

    Parameters
    ----------
    argv : sequence of str
        The console script's arguments, without the program name.
    """
    token = _COMMAND.set(shlex.join(["tapmuscle", *argv]))
    try:
        yield
    finally:
        _COMMAND.reset(token)


def produced_by() -> dict[str, object]:
    """What a JSON document records of what made it: ``{"software": software()}``, with
    ``"command"``, the command line, when the console script made it (:func:`invoked_as`)."""
    command = _COMMAND.get()
    return {"software": software()} | ({} if command is None else {"command": command})


def software_text(found: dict[str, str] | None = None, more: Sequence[str] = ()) -> str:
    """:func:`software` (or ``found``, such a dict read from a document) in one line, as ``tapmuscle
    --version`` (with ``more``, further facts in the parentheses) and a sweep's ``summary.md`` say it.

    Parameters
    ----------
    found : dict of str to str, optional
        What :func:`software` returned, e.g. as read from a document; None (default):
        :func:`software` now.
    more : sequence of str, optional
        Further facts, added inside the parentheses.
    """
    found = software() if found is None else found
    # a document of an earlier release has no CPU features or source
    packages = [*NUMERICS_PACKAGES, *(["matplotlib"] if "matplotlib" in found else [])]
    facts = [f"Python {found['python']}", ", ".join(f"{name} {found[name]}" for name in packages),
             found["machine"] + (f" ({found['cpu_features']})" if "cpu_features" in found else ""),
             f"compiled sub-step {found['compiled_substep']}", *more]
    source = f" from {found['source']}" if "source" in found else ""
    return f"tapmuscle {found['tapmuscle']}{source} ({'; '.join(facts)})"
