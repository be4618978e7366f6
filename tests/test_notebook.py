"""docs/notebooks/ run in a real Jupyter kernel (nbclient, ipykernel): tapmuscle called from a notebook
keeps the notebook's inline figures, spawns its worker processes, runs the FMUs in the kernel's process
(twice, as a re-run cell does), and gives the documented results."""

from __future__ import annotations

import re
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parent.parent / "docs" / "notebooks" / "tapmuscle_in_a_notebook.ipynb"


def _text(cell) -> str:
    return "".join(o.get("text", "") for o in cell.outputs if o.output_type == "stream")


def _images(cell) -> int:
    return sum("image/png" in o.get("data", {}) for o in cell.outputs)


@pytest.mark.slow
def test_the_notebook_runs_in_a_jupyter_kernel_with_its_figures_inline(tmp_path):
    nb = nbformat.read(NOTEBOOK, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(not c.outputs for c in code), "commit the notebook without outputs"
    # raises CellExecutionError, naming the cell, on any error
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    rig, diagnosis, files, loop, fmus, own = code[1:]
    assert _images(rig) == 1  # the user's own plot, inline
    m = re.search(r"mismatch \['transport_delay'\] delay ([0-9.]+) s fit ([0-9.]+) %", _text(diagnosis))
    assert m, _text(diagnosis)  # workers=2: spawned from the kernel
    assert abs(float(m.group(1)) - 0.3) < 0.05 and float(m.group(2)) > 95.0
    assert "mismatch ['transport_delay']" in _text(files) and _images(files) == 1  # the report's overlay.png
    assert (tmp_path / "diagnosis_out" / "overlay.png").is_file()
    # after tapmuscle drew its figures, the user's plot still shows inline, on the inline backend
    assert _images(loop) == 1
    backend = _text(loop).split()[-1]  # the cell's last line: plt.get_backend()
    assert "inline" in backend, backend  # "module://matplotlib_inline.backend_inline"; IPython 9 names it "inline"
    eq21 = float(re.search(r"Eq\. \(21\) error ([0-9.]+) mm", _text(loop)).group(1))
    assert eq21 < 0.5  # the AMPC-servo tracks the 60-mm sine (0.084 mm at 44 N, 0.1 Hz: docs/control.md, Table 7)
    # the FMUs loaded into the kernel's process, twice: the direct loop bit for bit (a contract: one process)
    runs = re.findall(r"FMUs, run (\d): Eq\. \(21\) error ([0-9.]+) mm, the direct loop's bit for bit: (\w+)", _text(fmus))
    assert [(n, same) for n, _, same in runs] == [("1", "True"), ("2", "True")], _text(fmus)
    # a law of one's own in the methods' loop: scored beside AMPC-servo, its delayed loop's limit cycle told
    m = re.search(r"PI: Eq\. \(21\) error ([0-9.]+) mm, AMPC-servo ([0-9.]+) mm", _text(own))
    assert m and float(m.group(1)) < 1.0 and float(m.group(2)) < 0.5, _text(own)  # 0.41 and 0.084 mm measured
    late = re.search(r"PI under a 0\.1-s delay: ([0-9.]+) mm; the watch: (.*)", _text(own))
    assert late and float(late.group(1)) > 3.0 and "a limit cycle" in late.group(2), _text(own)
    assert _images(own) == 1
