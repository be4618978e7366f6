"""Time of reading a long rig log (``tapmuscle import``) and the recording it becomes.

Run: ``python benchmarks/import_time.py [--lines N] [--repeats R]``. Writes a log as a PC logger does
(';' separated, time in ms, command in %, position in um, pressure in kPa, two text columns; default
1e6 lines: 17 minutes at 1 kHz) to a temporary folder, then times :func:`tapmuscle.read_rig_log`,
:func:`tapmuscle.write_recording` and :func:`tapmuscle.read_recording` on it. The machine may be
shared, so each figure is the best (lowest) of the repeats. Prints seconds and microseconds per line,
and the process's peak resident memory at the end.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import tapmuscle as tm


def write_log(path: Path, lines: int) -> None:
    """A 1-kHz logger's file of ``lines`` samples."""
    t = np.arange(lines) * 1e-3
    with open(path, "w") as f:
        f.write("time_ms;cmd_pct;pos_um;p_kPa;status;comment\n")
        for k in range(lines):
            f.write(f"{t[k] * 1e3:.0f};{50 + 20 * np.sin(t[k]):.3f};{30000 + 5000 * np.sin(t[k]):.2f};"
                    f"{150 + 20 * np.sin(t[k]):.2f};OK;run\n")


def best(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return min(times), out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        log, out = Path(tmp) / "log.csv", Path(tmp) / "recording.csv"
        print(f"writing a {args.lines}-line log ...", flush=True)
        write_log(log, args.lines)
        read_s, rec = best(lambda: tm.read_rig_log(log, time="time_ms:ms", u="cmd_pct:%", l="pos_um:um",
                                                   p="p_kPa:kPa"), args.repeats)
        write_s, _ = best(lambda: tm.write_recording(out, rec), args.repeats)
        back_s, _ = best(lambda: tm.read_recording(out), args.repeats)
        print(f"{'read_rig_log':16s} {read_s:6.2f} s  {1e6 * read_s / args.lines:5.2f} us/line  ({log.stat().st_size / 1e6:.0f} MB)")
        print(f"{'write_recording':16s} {write_s:6.2f} s  {1e6 * write_s / args.lines:5.2f} us/line")
        print(f"{'read_recording':16s} {back_s:6.2f} s  {1e6 * back_s / args.lines:5.2f} us/line  ({out.stat().st_size / 1e6:.0f} MB)")
    print(f"peak resident memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
