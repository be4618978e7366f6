"""How often ``tapmuscle identify --input-delay-samples auto`` chooses a rig's transport delay.

Run: ``python benchmarks/input_delay_choice.py [--off-nominal 30] [--constraint-start S]`` (about 5 s,
plus 0.2 s per off-nominal rig). Simulated rigs with a transport delay of 0, 0.1, 0.2, 0.3 and 0.4 s
(``delay.delay_s``) at 44 N; per rig and command a 120-s record (noise seed 0), the identification
options the CLI's defaults (Algorithm 1's box from 120 s, which the choice moves to half the record)
or ``--constraint-start``. Commands: random (two seeds), steps among five levels, a chirp, and a 0.1-Hz
sine, which :func:`~fmu_controller.input_delay_choice.choose_input_delay` refuses; its line shows the D
the best fit would have given. ``--off-nominal N`` adds N rigs drawn as docs/diagnosis.md's field
generator does (3-6 constants off by 5-20 %, load 30-80 N, a delay of 0-0.4 s to the hundredth, so
mostly between two samples, where either counts as right) under a random command. Printed: the 1-step
fit on the record under each D = 0..5, the D chosen and the rig's, the lead where it is thin, and the
count of right choices.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from fmu_controller.input_delay_choice import (THIN_MARGIN_PERCENT, ToneCommandError, choose_input_delay,
                                               fits_by_delay)
from fmu_plant.parameters import PlantParams
from tapmuscle.api import simulate
from tapmuscle.diagnosis.field_cases import draw_parameter_errors, off_nominal

TS_S = 0.1
DURATION_S = 120.0
COMMANDS = ("random:lo=2,hi=8,seed=3", "random:lo=2,hi=8,seed=7", "steps:levels=3/7/5/6/4,period=8",
            "chirp:f0=0.01,f1=0.5", "sine:bias=5,amp=3,freq=0.1")


def one(params: PlantParams, command: str, delay_s: float, label: str, options: dict) -> bool | None:
    """Print one rig's choice; True/False whether it is the rig's delay (a delay between two samples:
    either), None where refused."""
    steps = delay_s / TS_S
    truth = {math.floor(steps + 1e-9), math.ceil(steps - 1e-9)}
    rec = simulate(command, duration_s=DURATION_S, ts_s=TS_S, params=params, seed=0)
    try:
        choice = choose_input_delay(rec["u_v"], rec["l_mm"], ts_s=TS_S, **options)
        fits, chosen = list(choice.fits_percent), choice.input_delay_samples
        note = f"  thin lead {choice.margin_percent:.3f} %" if choice.margin_percent < THIN_MARGIN_PERCENT else ""
    except ToneCommandError:
        fits = fits_by_delay(rec["u_v"], rec["l_mm"], ts_s=TS_S, **options)[0]
        chosen, note = int(np.argmax(fits)), "  refused (a sine); the best fit's D shown"
    right = chosen in truth
    print(f"{label:<46} rig D {'/'.join(map(str, sorted(truth))):3s} chosen {chosen} {'ok  ' if right else 'MISS'} "
          + " ".join(f"{f:6.2f}" for f in fits) + note, flush=True)
    return None if "refused" in note else right


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--off-nominal", type=int, default=0, help="field rigs with constants off (default 0)")
    ap.add_argument("--constraint-start", type=float, default=None,
                    help="Algorithm 1's box from this time [s] (default: the CLI's, 120)")
    args = ap.parse_args()
    options = {} if args.constraint_start is None else {"constraint_start_s": args.constraint_start}
    print(f"{'rig and command':<46} {'':22} 1-step fit on the record [%] under D = 0 .. 5")
    right = total = 0
    for delay_s in (0.0, 0.1, 0.2, 0.3, 0.4):
        params = PlantParams().with_values(**{"delay.delay_s": delay_s})
        for command in COMMANDS:
            got = one(params, command, delay_s, f"{delay_s:.1f} s, {command}", options)
            if got is not None:
                right, total = right + got, total + 1
    print(f"nominal rigs: the rig's delay chosen in {right} of {total} (sine commands refused)")
    if args.off_nominal:
        right = 0
        for i in range(args.off_nominal):
            rng = np.random.default_rng(3000 + i)
            load = float(rng.uniform(30.0, 80.0))
            delay_s = round(float(rng.uniform(0.0, 0.4)), 2)
            errors = draw_parameter_errors(rng, PlantParams().with_values(**{"load.load_n": load}))
            params = off_nominal(PlantParams(), errors).with_values(**{"delay.delay_s": delay_s,
                                                                       "load.load_n": load})
            label = f"field rig {i} ({len(errors)} constants off, {load:.0f} N), {delay_s:.2f} s"
            right += bool(one(params, f"random:lo=2,hi=8,seed={10 + i}", delay_s, label, options))
        print(f"off-nominal rigs: the rig's delay chosen in {right} of {args.off_nominal}")


if __name__ == "__main__":
    main()
