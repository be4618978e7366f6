"""The four controllers with a noisier sensor than the paper's encoder, and what a user can do about it.

Run: ``python benchmarks/noisy_sensor.py [--seeds 3]`` (about 10 s).
The paper's rig at 44 N and its 35 + 30 sin(2 pi 0.1 t) mm, 90 s from rest, with the encoder's
0.01 mm of white noise or a potentiometer's 0.2 and 0.5 mm (``sensor.encoder_noise_std_mm``; 0.1-mm
resolution for those), ``THETA0_44N``. Variants: the defaults; the servo's move weight R at 60 and 240
(Table 5: 15); the reading blended with the controller's own one-step prediction before each step,
``l_used = l(k|k-1) + K (l - l(k|k-1))`` with K = 0.5 (a fixed-gain observer in the user's loop).
Printed per method, noise and variant, means over the noise seeds: Eq. (21) against the muscle's
true displacement (what the reading hides) and the command's total variation over 15-90 s [V].
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

import tapmuscle as tm

NOISES_MM = (0.01, 0.2, 0.5)
VARIANTS = {"defaults": {}, "servo.R = 60": {"r": 60.0}, "servo.R = 240": {"r": 240.0}, "blend K = 0.5": {"k": 0.5}}


def run(method: str, noise_mm: float, seed: int, *, r: float | None = None, k: float | None = None) -> tuple[float, float]:
    """Eq. (21) against the true displacement [mm] and the command's total variation over 15-90 s [V]."""
    params = tm.PlantParams().with_values(**{"sensor.encoder_noise_std_mm": noise_mm,
                                             "sensor.encoder_resolution_mm": 0.1 if noise_mm > 0.01 else 0.01})
    settings = tm.ControllerSettings(method=method, **({} if r is None else {"servo": tm.ServoMPCSettings(r=r)}))
    plant = tm.Plant(params, seed=seed)
    ctrl = tm.DisplacementController(settings, tm.THETA0_44N)
    ref = tm.SineReference()
    n = 901
    ctrl.reset(plant.measurement.l_mm)
    predicted = math.nan
    r_mm, l_true, u_v = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        l = plant.measurement.l_mm
        if k is not None and math.isfinite(predicted):
            l = predicted + k * (l - predicted)
        step = ctrl.step(l, ref.preview(i, settings.preview_samples))
        predicted = step.predicted_next_mm
        r_mm[i], l_true[i], u_v[i] = ref.at(i), plant.l_mm, step.u_v
        if i + 1 < n:
            plant.step(step.u_v, 0.1)
    return tm.eq21_error_mm(r_mm, l_true), float(np.sum(np.abs(np.diff(u_v[150:]))))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="noise seeds 0..N-1 (default 3)")
    args = ap.parse_args(argv)
    print(f"{'method':11s} {'noise [mm]':>10s}  " + "  ".join(f"{v:>20s}" for v in VARIANTS))
    print(f"{'':11s} {'':>10s}  " + "  ".join(f"{'Eq.21 [mm] / TV [V]':>20s}" for _ in VARIANTS))
    for method in tm.METHODS:
        for noise in NOISES_MM:
            cells = []
            for kw in VARIANTS.values():
                if "r" in kw and not method.endswith("servo"):
                    cells.append(f"{'-':>20s}")
                    continue
                res = np.array([run(method, noise, seed, **kw) for seed in range(args.seeds)])
                cells.append(f"{res[:, 0].mean():11.3f} / {res[:, 1].mean():6.0f}")
            print(f"{method:11s} {noise:10g}  " + "  ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
