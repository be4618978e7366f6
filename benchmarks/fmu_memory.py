"""Memory per instantiate/free cycle of each FMU in one host process (fmpy).

A host that instantiates and frees an FMU again and again (a sweep worker, a test runner) keeps what
each cycle leaves behind. Per FMU: ``--cycles`` cycles of instantiate, initialise, one step,
terminate, free, through the project's fmpy host; the resident set size (psutil) after every quarter; printed: the growth per cycle
over the second half, after the allocator has warmed up. Measured here: about 1.7 kB per cycle for
the plant and 2.2 kB for the controller (docs/fmu.md); before the entry script was an import of the slave class (build_scripts.build_fmus),
51 kB (controller) and 16 kB (plant).

    python benchmarks/fmu_memory.py [--cycles 800]      # needs psutil (with the dist or test extra)
"""

from __future__ import annotations

import argparse
import gc
import os

import psutil

from build_scripts.build_fmus import FMUS, cached_fmus
from tapmuscle.cosim.master import FmuInstance


def growth_per_cycle_kb(path: str, role: str, cycles: int) -> tuple[float, list[tuple[int, float]]]:
    """RSS growth per cycle over the second half [kB] and the RSS after each quarter [MiB]; each cycle
    through the project's own host (:class:`tapmuscle.cosim.master.FmuInstance`, as sweeps use it)."""
    process = psutil.Process(os.getpid())
    marks = []
    for i in range(cycles + 1):
        if i % (cycles // 4) == 0:
            gc.collect()
            marks.append((i, process.memory_info().rss))
        if i == cycles:
            break
        inst = FmuInstance(path, f"cycle{i}", role=role)
        inst.start()
        inst.fmu.doStep(0.0, 0.1)
        inst.free()
    (i0, r0), (i1, r1) = marks[2], marks[-1]
    return (r1 - r0) / (i1 - i0) / 1024, [(i, r / 2**20) for i, r in marks]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=800, help="instantiate/free cycles per FMU (default 800)")
    args = parser.parse_args()
    if args.cycles < 8:
        parser.error(f"--cycles must be at least 8, got {args.cycles}")
    fmus = cached_fmus()
    for name in FMUS:
        role = "plant" if name == "MusclePlant" else "controller"
        slope, marks = growth_per_cycle_kb(str(fmus[name]), role, args.cycles)
        print(f"{name:<15} {slope:6.1f} kB per cycle over the second half   RSS "
              + ", ".join(f"{r:.1f} MiB after {i}" for i, r in marks), flush=True)


if __name__ == "__main__":
    main()
