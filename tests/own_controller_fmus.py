"""Controller FMUs of one's own for the tests: the shipped example PI (scenarios/examples/pi_controller.py)
built with pythonfmu as its docstring says, or a variant of it that misbehaves in a step."""

from __future__ import annotations

import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "scenarios" / "examples"
PI_SCRIPT = EXAMPLES / "pi_controller.py"
_DO_STEP = "    def do_step(self, current_time: float, step_size: float) -> bool:\n"


def build_pi(dest: Path, *, script: Path = PI_SCRIPT) -> Path:
    """``script`` (default the example PI) built into the folder ``dest`` by pythonfmu; the builder's
    changes to ``sys.path`` and ``sys.modules`` undone, so the test process imports its own modules."""
    from pythonfmu.builder import FmuBuilder

    dest.mkdir(parents=True, exist_ok=True)
    saved = list(sys.path)
    try:
        return Path(FmuBuilder.build_FMU(script, dest=dest))
    finally:
        sys.path[:] = saved
        sys.modules.pop(script.stem, None)


def build_pi_variant(dest: Path, name: str, *, from_s: float = 1.0, do: str = "", methods: str = "") -> Path:
    """The example PI with ``do`` (Python statements, one per line) run at the start of each step from
    ``from_s`` [s] on, and ``methods`` (method definitions at the class's indentation) added to its
    class, saved as ``name``.py and built into ``dest``. The FMU keeps the example's model name,
    PIController."""
    text = PI_SCRIPT.read_text()
    if do:
        body = "".join(f"            {line}\n" for line in do.splitlines())
        text = text.replace(_DO_STEP, f"{_DO_STEP}        if current_time >= {from_s!r}:\n{body}")
    if methods:
        text = text.replace(_DO_STEP, f"{methods.rstrip()}\n\n{_DO_STEP}")
    script = dest / f"{name}.py"
    dest.mkdir(parents=True, exist_ok=True)
    script.write_text(text)
    return build_pi(dest, script=script)
