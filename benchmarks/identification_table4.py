"""Table-4-style comparison of the asymmetric and standard Bouc-Wen models on the simulated rig.

Run: ``python benchmarks/identification_table4.py [OUT_DIR]`` (default ``out/identification``).
Records (with ``tapmuscle record``) the paper's identification input u = 5 + 3 sin(2 pi 0.1 t) V at
44 N and 68 N: 240 s for identification (seed 0) and a fresh 120 s for validation (seed 1), Ts 0.1 s,
encoder noise and quantisation on. Identifies both models with the constrained RLS (Table 2 box from
120 s) and prints the validation fits beside the paper's Table 4; also the unconstrained estimate's
linear part (against the Table 2 box the rig was calibrated to). Writes Fig. 4 / Fig. 5 style PNGs into OUT_DIR.

The paper's Table 4 gives only three numbers for the proposed model under four columns; they are read
as the 1-, 3- and 5-step fits, the free run being the text's "higher than 90 [%]"
(docs/identification.md, "Reading Table 4").
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from fmu_controller.identification import identify_record, score_model
from tapmuscle.cli.main import main as tapmuscle
from tapmuscle.plots.figures import plot_loop_comparison, plot_model_vs_measured
from tapmuscle.io.recording import read_recording

PAPER_TABLE4 = {"asymmetric": ("99.6", "98.3", "96.8", "> 90"), "standard": ("99.5", "97.4", "93.9", "81.9")}


def main(out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    ok = True
    for load in (44, 68):
        recs = {}
        for kind, duration, seed in (("train", 240, 0), ("val", 120, 1)):
            path = out / f"{kind}_{load}N.csv"
            tapmuscle(["record", "--load", str(load), "--input", "sine:bias=5,amp=3,freq=0.1", "--duration",
                       str(duration), "--seed", str(seed), "--out", str(path), "--quiet"])
            recs[kind] = read_recording(path)
        tr, va = recs["train"], recs["val"]
        print(f"\n=== load {load} N: validation fits [%] (identification 240 s seed 0, validation 120 s seed 1)")
        print(f"{'model':<11} {'1-step':>7} {'3-step':>7} {'5-step':>7} {'free run':>9}   paper Table 4 (44 N)")
        sims = {}
        for model in ("asymmetric", "standard"):
            t0 = time.perf_counter()
            rep = identify_record(tr.u_v, tr.l_mm, ts_s=tr.ts_s, model=model)
            dt = time.perf_counter() - t0
            fit = score_model(rep.theta, rep.structure, va.u_v, va.l_mm)
            p = fit.percent
            flag = " (diverged)" if fit.free_run_diverged else ""
            paper = " / ".join(PAPER_TABLE4[model])
            print(f"{model:<11} {p['1']:7.1f} {p['3']:7.1f} {p['5']:7.1f} {p['sim']:9.1f}{flag:11} {paper}"
                  f"   [identify {dt:.2f} s]")
            th = rep.theta_dict
            print(f"{'':11} constrained: a1={th['a1']:.3f} a2={th['a2']:.3f} b1={th['b1']:.3f} "
                  f"(a1+a2={th['a1'] + th['a2']:.3f})")
            sims[f"{model} ({'free run diverged' if fit.free_run_diverged else format(p['sim'], '.1f') + ' %'})"] = fit.simulated_mm
            if model == "asymmetric":
                ok &= p["1"] >= 99 and p["5"] >= 95 and p["sim"] >= (90 if load == 44 else 85)
        free = identify_record(tr.u_v, tr.l_mm, ts_s=tr.ts_s, box=None)
        th = free.theta_dict
        s = th["a1"] + th["a2"]
        print(f"unconstrained asymmetric: a1+a2={s:.3f} b1={th['b1']:.3f} mm/V "
              f"(the Table 2 box: 0.87..0.98 and 0.6..1.2); a1+A1={free.identifiable['a1+A1']:.3f}, "
              f"a2-A1={free.identifiable['a2-A1']:.3f}")
        plot_model_vs_measured(va.t_s, va.u_v, va.l_mm, sims, out / f"fig4_models_{load}N.png",
                               title=f"free run of both models against the validation record, {load} N (cf. Fig. 4)")
        plot_loop_comparison(va.u_v, va.l_mm, sims, out / f"fig5_loops_{load}N.png", skip=len(va.t_s) // 4,
                             title=f"hysteresis loops, {load} N, 0.1 Hz (cf. Fig. 5)")
    print(f"\nfigures in {out}/")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("out/identification")))
