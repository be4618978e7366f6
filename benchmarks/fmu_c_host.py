"""The closed loop in a host with no Python in its process: the project's C host and libcosim.

* C host: ``tests/c_host/fmi_host.c`` (gcc, dlopen RTLD_LOCAL), ``closed`` mode, plant and AMPC-servo
  controller at h = Ts = 0.1 s, run in a plain environment as a user's C master would be. The stepping
  time is the host's own (a monotonic clock around its loop, printed to stderr as "fmi_host: stepping
  loop: N steps in S s"): the process's start-up, Python's and the FMUs' instantiation, varies by more
  than the loop costs (three runs' process times less a 10-step run's gave 3644x, 460x and 763x).
* libcosim (``libcosimpy``, if installed): the same loop in a parallel master; its worker threads are
  not Python threads either.
* With ``--windows DIR``: the same C host cross-compiled with MinGW-w64 and run under Wine, with the
  Windows Python that ``tests/windows_host/prepare_python.py DIR`` prepared (python3.dll on its PATH),
  on the FMUs' win64 binaries. Wine is not Windows: the figure compares builds of the shim, not
  operating systems.

Goal: >= 300x real time in the C host. Best of ``--repeat`` runs (the machine may be shared). Then the
fmpy figures of today, those of ``python benchmarks/fmu_cosim.py`` (goals FMU/direct <= 1.3, >= 500x),
so that the C host's work is seen not to slow the Python hosts (``--no-fmpy`` skips them).

    python benchmarks/fmu_c_host.py [--steps 2400] [--repeat 3] [--windows DIR]
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import fmpy
from fmpy import extract, read_model_description

from build_scripts.build_fmus import cached_fmus

HOST_SOURCE = Path(__file__).resolve().parents[1] / "tests" / "c_host" / "fmi_host.c"
TS_S = 0.1
#: The line fmi_host prints to stderr after its open or closed loop.
LOOP_LINE = re.compile(r"^fmi_host: stepping loop: (\d+) steps in ([0-9.eE+-]+) s\r?$", re.MULTILINE)


def stepping_seconds(stderr: str, steps: int) -> float:
    """The duration of the host's loop of ``steps`` steps, as the host measured it."""
    found = LOOP_LINE.findall(stderr)
    if len(found) != 1 or int(found[0][0]) != steps:
        raise SystemExit(f"fmi_host printed no stepping time for {steps} steps:\n{stderr[-2000:]}")
    return float(found[0][1])


def _host(folder: Path, windows: bool = False) -> Path:
    compiler = "x86_64-w64-mingw32-gcc" if windows else "gcc"
    cc = shutil.which(compiler)
    if not cc:
        raise SystemExit(f"{compiler} is needed to build the C host")
    exe = folder / ("fmi_host.exe" if windows else "fmi_host")
    libs = [] if windows else ["-ldl", "-lm"]
    subprocess.run([cc, "-std=c99", "-O2", "-I", str(Path(fmpy.__file__).parent / "c-code"), "-o", str(exe),
                    str(HOST_SOURCE), *libs], check=True)
    return exe


def _windows_path(path: Path) -> str:
    return "Z:" + str(path)  # Wine maps the root of this machine to Z: (the C host takes / in paths)


def _args(fmus: dict[str, Path], folder: Path, windows: bool = False) -> list[str]:
    out = []
    for key, name, roles in (("P", "MusclePlant", {"u": "u", "l": "l"}), ("C", "AMPCController", {"l": "l", "u": "u"})):
        md = read_model_description(str(fmus[name]))
        unzipped = extract(str(fmus[name]), unzipdir=str(folder / name))
        vr = {v.name: v.valueReference for v in md.modelVariables}
        where = _windows_path(Path(unzipped)) if windows else unzipped
        out += [f"{key}.dir={where}", f"{key}.id={md.coSimulation.modelIdentifier}", f"{key}.guid={md.guid}"]
        out += [f"{key}.{role}={vr[var]}" for role, var in roles.items()]
    return out


def _wine_command(python_dir: Path) -> tuple[list[str], dict]:
    """Wine and the environment that runs a Windows C host with ``python_dir``'s python3.dll on PATH."""
    wine = shutil.which("wine64") or shutil.which("wine") or "/usr/lib/wine/wine64"
    exe = python_dir / "python" / "python.exe"
    if not Path(wine).is_file() or not exe.is_file():
        raise SystemExit(f"--windows needs Wine and a prepared Windows Python in {python_dir} "
                         f"(python tests/windows_host/prepare_python.py {python_dir})")
    env = {"PATH": "/usr/bin:/bin", "HOME": tempfile.gettempdir(), "LANG": "C.UTF-8", "WINEDEBUG": "-all",
           "WINEPREFIX": str(python_dir / "wineprefix"), "WINEPATH": "Z:" + str(exe.parent).replace("/", "\\")}
    return [wine], env


def c_host_seconds(exe: Path, args: list[str], steps: int, wine: tuple[list[str], dict] | None = None) -> float:
    """The stepping time of one run of the C host's closed loop (its own clock, start-up left out)."""
    env = {"PATH": "/usr/bin:/bin", "HOME": tempfile.gettempdir(), "LANG": "C.UTF-8"}
    prefix: list[str] = []
    if wine:
        prefix, env = wine
    proc = subprocess.run([*prefix, str(exe), "closed", *args, f"steps={steps}"], capture_output=True, text=True,
                          env=env)
    if proc.returncode != 0:
        raise SystemExit(f"fmi_host failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return stepping_seconds(proc.stderr, steps)


def loop_seconds(run, steps: int, repeat: int) -> float:
    """The best of ``repeat`` runs' stepping times (the machine may be shared)."""
    return min(run(steps) for _ in range(repeat))


def libcosim_seconds(fmus: dict[str, Path], steps: int) -> float | None:
    try:
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimSlave import CosimLocalSlave
    except ImportError:
        return None
    log_output_level(CosimLogLevel.WARNING)  # not its FMI Library's debug lines (about 75 per FMU loaded)
    ex = CosimExecution.from_step_size(step_size=int(round(TS_S * 1e9)))
    p = ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmus["MusclePlant"]), instance_name="plant"))
    c = ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmus["AMPCController"]), instance_name="ctrl"))
    pv = {v.name.decode(): v.reference for v in ex.slave_variables(p)}
    cv = {v.name.decode(): v.reference for v in ex.slave_variables(c)}
    ex.connect_real_variables(p, pv["l"], c, cv["l"])
    ex.connect_real_variables(c, cv["u"], p, pv["u"])
    ex.step(1)  # initialisation
    t0 = time.perf_counter()
    ex.step(steps)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2400)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-fmpy", action="store_true", help="skip the fmpy figures of benchmarks/fmu_cosim.py")
    ap.add_argument("--windows", type=Path, metavar="DIR",
                    help="also the Windows C host under Wine, with the Windows Python prepared in DIR")
    args = ap.parse_args()
    fmus = cached_fmus()
    simulated = args.steps * TS_S
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        exe = _host(folder)
        host_args = _args(fmus, folder)
        loop = loop_seconds(lambda steps: c_host_seconds(exe, host_args, steps), args.steps, args.repeat)
        print(f"C host, closed loop, {args.steps} steps of {TS_S} s: {loop:.3f} s, real-time factor "
              f"{simulated / loop:.0f}x (goal >= 300x)")
        if args.windows:
            wine = _wine_command(args.windows.resolve())
            win_exe, win_args = _host(folder, windows=True), _args(fmus, folder, windows=True)
            loop = loop_seconds(lambda steps: c_host_seconds(win_exe, win_args, steps, wine), args.steps, args.repeat)
            print(f"Windows C host under Wine, closed loop, {args.steps} steps: {loop:.3f} s, real-time factor "
                  f"{simulated / loop:.0f}x")
        lc = [libcosim_seconds(fmus, args.steps) for _ in range(args.repeat)]
        if lc[0] is None:
            print("libcosim: libcosimpy not installed")
        else:
            print(f"libcosim, closed loop (parallel), {args.steps} steps: {min(lc):.3f} s, real-time factor "
                  f"{simulated / min(lc):.0f}x")
    if not args.no_fmpy:
        print("fmpy (benchmarks/fmu_cosim.py):")
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from fmu_cosim import report

        report(7)


if __name__ == "__main__":
    main()
