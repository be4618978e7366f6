"""The paper's experiments (section 4) on the simulated rig: ``tapmuscle paper``.

1. Preliminary identification (section 4.2's fixed predictor): the asymmetric Eq. (1) model,
   identified by the constrained RLS on the 0.1 Hz identification input at 44 N (240 s), then refined
   in closed loop (:func:`preliminary_theta`), with noise seed ``--id-seed`` (default: the first noise seed).
2. Closed loop through the FMUs (MusclePlant and AMPCController co-simulated in fmpy by
   :mod:`tapmuscle.cosim.master`; the scenario files are ``scenarios/paper/<run>.toml``), Ts = 0.1 s,
   r = 35 + 30 sin(2 pi f t) mm, 45 s per run, evaluated by Eq. (21) over 10.1-40.1 s (samples 101..401): the four methods
   at 44 N and 68 N with f = 0.1 Hz (Tables 6, 7), and MPC/AMPC with servo mechanism at f = 0.2 Hz
   (Table 9, with Table 8's P(0)); each cell the mean over three noise seeds. The FMU loop gives the
   direct Python loop's numbers bit for bit (tests/test_scenarios.py).
3. Outputs: ``paper.json`` (Tables 6, 7, 9), ``tables.csv`` (the same cells, one row each, with
   their spread over the seeds and the paper's value), one CSV per run and seed in ``runs/``
   (``NAME.csv`` the first seed's, the one the figures show, ``NAME_seedS.csv`` each other's),
   tracking and prediction-error figures like Figs. 8-19 (PNG, PDF or SVG), all put in place together
   once all are written (:data:`PAPER_FILES`), and the tables printed beside the paper's.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence, TextIO, TypeVar

import numpy as np

from fmu_controller.argument_checks import real_number
from fmu_controller.displacement_control import P0_TABLE5, ControllerSettings, DisplacementController
from fmu_controller.hysteresis_model import ASYMMETRIC
from fmu_controller.identification import identify_record
from fmu_controller.prediction import checked_input_delay
from fmu_controller.reference import SineReference
from fmu_plant import Plant, PlantParams
from fmu_plant.open_loop import run_open_loop
from fmu_plant.seed import SEED_MAX

from tapmuscle.closed_loop import EQ21_WINDOW_S, eq21_error_mm, run_closed_loop
from tapmuscle.plots.figure_formats import FIGURE_FORMATS, checked_figure_format
from tapmuscle.plots.figures import plot_prediction_errors, plot_tracking
from tapmuscle.io.atomic import staged_folder
from tapmuscle.io.json_file import json_text
from tapmuscle.io.recording import Recording, atomic_write_text, write_recording
from tapmuscle.io.signals import parse_input_spec
from tapmuscle.provenance import produced_by

__all__ = ["PaperRun", "PAPER_FILES", "PAPER_RUNS", "PAPER_TABLES", "paper_findings", "paper_tables",
           "preliminary_theta", "run_paper", "tables_csv_text", "TABLE_COLUMNS", "checked_seeds"]


#: The paper's measured Eq. (21) errors [mm]: table -> load -> method.
PAPER_TABLES = {
    "table6": {"44": {"mpc_servo": 0.33, "mpc_ucp": 1.27}, "68": {"mpc_servo": 0.33, "mpc_ucp": 2.25}},
    "table7": {"44": {"ampc_servo": 0.28, "ampc_ucp": 1.07}, "68": {"ampc_servo": 0.29, "ampc_ucp": 1.40}},
    "table9": {"44": {"ampc_servo": 0.67, "mpc_servo": 0.80}, "68": {"ampc_servo": 0.68, "mpc_servo": 0.91}},
}

DURATION_S = 45.0

T = TypeVar("T")


@dataclass(frozen=True)
class PaperRun:
    """One closed-loop experiment of section 4.

    Parameters
    ----------
    method : str
        The controller's method (``mpc_ucp``, ``mpc_servo``, ``ampc_ucp``, ``ampc_servo``).
    load_n : float
        The hanging load [N] (section 4.1: 44 or 68).
    frequency_hz : float
        The sine reference's frequency [Hz] (0.1 or 0.2).
    """

    method: str
    load_n: float
    frequency_hz: float

    @property
    def name(self) -> str:
        return f"{self.method}_{self.load_n:g}N_{self.frequency_hz:g}Hz"


PAPER_RUNS: tuple[PaperRun, ...] = tuple(
    [PaperRun(m, load, 0.1) for load in (44.0, 68.0) for m in ("mpc_ucp", "mpc_servo", "ampc_ucp", "ampc_servo")]
    + [PaperRun(m, load, 0.2) for load in (44.0, 68.0) for m in ("mpc_servo", "ampc_servo")])

#: (table, frequency, methods compared, figure numbers of tracking and prediction error)
_TABLES = (("table6", 0.1, ("mpc_servo", "mpc_ucp"), {44: (8, 9), 68: (10, 11)}),
           ("table7", 0.1, ("ampc_servo", "ampc_ucp"), {44: (12, 13), 68: (14, 15)}),
           ("table9", 0.2, ("ampc_servo", "mpc_servo"), {44: (16, 17), 68: (18, 19)}))


def _figure_names(fmt: str) -> list[tuple[str, int, str, str]]:
    """``(table, load, tracking figure, prediction-error figure)``: the file names of each table's figures."""
    return [(table, load, f"fig{figs[load][0]:02d}_tracking_{load}N_{freq:g}Hz.{fmt}",
             f"fig{figs[load][1]:02d}_prediction_error_{load}N_{freq:g}Hz.{fmt}")
            for table, freq, _, figs in _TABLES for load in (44, 68)]


def _run_file(run: PaperRun, seed: int, first: bool) -> str:
    """A run's CSV in the output folder: the first seed's (the figures') ``runs/NAME.csv``."""
    return f"runs/{run.name}.csv" if first else f"runs/{run.name}_seed{seed}.csv"


#: What ``tapmuscle paper`` writes into its folder, by name (a run's CSV of any seed, a figure in any
#: format): an earlier run's files of these names are replaced or removed; other files are left alone.
PAPER_FILES: tuple[str | re.Pattern[str], ...] = (
    ("paper.json", "tables.csv")
    + tuple(name for r in PAPER_RUNS for name in (f"runs/{r.name}.csv",
                                                  re.compile(rf"runs/{re.escape(r.name)}_seed(0|[1-9][0-9]*)\.csv")))
    + tuple(name for fmt in FIGURE_FORMATS for _, _, *names in _figure_names(fmt) for name in names))


def preliminary_theta(seed: int = 0, refine_hz: float = 0.05, *, params: PlantParams | None = None,
                      load_n: float | None = None, ts_s: float = 0.1, input_delay_samples: int = 0,
                      refine_offset_mm: float = 35.0, refine_amplitude_mm: float = 30.0) -> np.ndarray:
    """Section 4.2's fixed predictor, "obtained by a preliminary identification under 44 N".

    The paper does not say on which data. We identify in two stages, both at 44 N:

    1. open loop: Eq. (1) by the constrained RLS on 5 + 3 sin(2 pi 0.1 t) V (Fig. 3's input) for
       240 s (our choice: the paper gives no length, only that the estimate settles and the box
       acts after 120 s);
    2. closed loop: 120 s of AMPC with servo mechanism tracking the sine ``refine_offset_mm +
       refine_amplitude_mm sin(2 pi refine_hz t)`` (the paper's 35 + 30 mm at ``tapmuscle paper``'s
       0.05 Hz, docs/control.md says why), started from stage 1, with its own
       noise seed (``seed + 1000``); the estimate at the end is frozen. The experiment is fixed: the
       paper's AMPC-servo with the paper's start, Eq. (5) and Eq. (18), whatever the controller's
       defaults.

    Stage 1 alone fits the open-loop data well (docs/identification.md) but its polynomial and
    A-terms give the hysteresis cancellation H(k) large, nearly cancelling velocity gains; the fixed
    servo loop then oscillates at the Nyquist rate (measured: 3.7 mm Eq. (21) error at 44 N).
    Stage 2 gives the estimate the closed loop sees. docs/control.md has the numbers.

    Parameters
    ----------
    seed : int
        Noise seed of stage 1 (stage 2: ``seed + 1000``).
    refine_hz : float
        Frequency [Hz] of stage 2's sine reference.
    params : PlantParams, optional
        Another simulated rig to make the fixed predictor of (default: the calibrated rig).
    load_n : float, optional
        Its load [N] (default: that of ``params``, 44 N).
    ts_s : float
        The sampling period [s] of both stages: the controller's. Off 0.1 s both run without a box
        (Table 2 is for 0.1 s, as :func:`~fmu_controller.identification.identify_record` decides).
    refine_offset_mm, refine_amplitude_mm : float
        Stage 2's sine [mm]: the range the fixed predictor will hold over (it holds where it was
        identified, docs/control.md "MPC-servo outside its predictor's range"). The paper's 35 and 30
        span 5..65 mm of the simulated rig's 98 mm at 10 V; for a rig of another reach, the same
        fractions of it (0.36 and 0.30 times the reach): on 10 simulated rigs of 28-163 mm, fixed
        MPC-servo on that predictor tracked the same fractions to 0.06-0.19 mm, where the paper's
        35 + 30 mm gave up to 1.2 mm (docs/control.md, "A theta0 for another rig").
    input_delay_samples : int
        The controller's input delay d (a rig's transport delay, docs/control.md "Transport delay"):
        stage 1 identifies Eq. (1) on the command the valve had, ``u(k-d)``, and stage 2 runs with the
        delay compensated, so that the fixed predictor describes what the delayed law predicts with.
        (With the predictor of the rig without the delay, MPC-servo on a 0.3-s delay: 11.2 mm; with this
        one 1.2-3.9 mm, by the identification seed and the floating-point path.)

    Returns
    -------
    ndarray
        The 15 parameters of Eq. (1) in :data:`~fmu_controller.hysteresis_model.ASYMMETRIC`'s order.
    """
    rig = PlantParams() if params is None else params
    # checked before the stages run
    reference = SineReference(offset_mm=real_number(refine_offset_mm, what="refine_offset_mm"),
                              amplitude_mm=real_number(refine_amplitude_mm, what="refine_amplitude_mm"),
                              frequency_hz=refine_hz, ts_s=ts_s)
    if load_n is not None:
        rig = rig.with_values(**{"load.load_n": float(load_n)})
    d = checked_input_delay(input_delay_samples)  # before the open-loop run
    rec = run_open_loop(Plant(rig, seed=seed), parse_input_spec("sine:bias=5,amp=3,freq=0.1"),
                        duration_s=240.0, ts_s=ts_s)
    report = identify_record(rec["u_v"], rec["l_mm"], ts_s=ts_s, model="asymmetric", input_delay_samples=d)
    settings = ControllerSettings(method="ampc_servo", ts_s=ts_s, p0=P0_TABLE5, startup_s=0.0,
                                  hysteresis_notch=False, anti_windup=False, input_delay_samples=d,
                                  box_lower=report.box_lower, box_upper=report.box_upper)
    refine = DisplacementController(settings, report.theta)
    # a loop run for its final estimate, not its tracking: unwatched
    cols = run_closed_loop(Plant(rig, seed=seed + 1000), refine, reference, duration_s=120.0, watch=False)
    return np.array([cols[f"theta_{n}"][-1] for n in ASYMMETRIC.names])


def checked_seeds(seeds: tuple[int, ...]) -> tuple[int, ...]:
    """``seeds``, once they name at least one noise seed, each an integer in 0 .. 2**64 - 1 (the plant's
    seeds) and none twice (a repeat would weigh that noise realisation twice in a cell's mean).

    Parameters
    ----------
    seeds : tuple of int
        The plant's noise seeds.

    Raises
    ------
    ValueError
        No seed, one out of range or not an integer, or one given more than once (named).
    """
    if not seeds:
        raise ValueError("seeds must name at least one noise seed")
    bad = [s for s in seeds if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or not 0 <= s <= SEED_MAX]
    if bad:  # before the identification and the first runs, not at that seed's first run
        raise ValueError(f"seeds must be integers in 0 .. 2**64 - 1 = {SEED_MAX}, got {bad[0]!r} in {tuple(seeds)}")
    repeated = sorted({s for s in seeds if list(seeds).count(s) > 1})
    if repeated:
        raise ValueError(f"seeds must differ (a repeat would count that noise realisation twice in the mean), got "
                         f"{', '.join(map(str, repeated))} more than once in {tuple(seeds)}")
    return seeds


def run_paper(out: Path, *, seeds: tuple[int, ...] = (0, 1, 2), id_seed: int | None = None,
              refine_hz: float = 0.05, fmus: Mapping[str, Path] | None = None, stream: TextIO = sys.stdout,
              progress: Callable[[int, int], None] | None = None, faithful_eq5: bool = False,
              faithful_start: bool = False, figure_format: str = "png") -> dict:
    """Run every experiment of section 4 and write the outputs into ``out`` (see module docstring).

    Each table cell is the mean Eq. (21) error over the noise ``seeds`` (the per-seed values are in
    ``paper.json`` and ``tables.csv``): single runs of the unique-coincidence-point controllers differ
    by up to 0.3 mm between noise realisations, more than some of the differences the paper reports.
    The fixed predictor is identified once and given to the controller FMU as its ``theta0.*``
    parameters.

    Parameters
    ----------
    out : path
        The output folder; files of other names in it are left alone.
    seeds : tuple of int
        The noise seeds, each once; a run's CSV is written for each, the figures show the first's.
    id_seed : int, optional
        Noise seed of the preliminary identification (default: the first of ``seeds``). Another one
        is another identification experiment, which shows how much the tables owe to that one
        experiment (docs/control.md).
    refine_hz : float
        Frequency [Hz] of the identification's closed-loop stage (:func:`preliminary_theta`).
    fmus : mapping, optional
        ``{"MusclePlant": path, "AMPCController": path}``; default the FMUs built from this checkout
        (:func:`build_scripts.build_fmus.cached_fmus`).
    stream : text stream
        Where the runs' lines and the tables are printed.
    progress : callable, optional
        ``progress(done, total)`` after each run.
    faithful_eq5 : bool
        Cancel ``H(k)`` in both servo methods as the paper's Eq. (5) does (the controller FMU's
        ``hysteresis_notch = 0``); by default the FMU's own setting applies, which removes MPC-servo's
        valve chatter (docs/control.md, "Chatter").
    faithful_start : bool
        Start every controller as the paper does (the FMU's ``startup_s = 0``: the full reference and
        the raw estimate from the first sample), with the integrator of Eq. (18) as written
        (``anti_windup = 0``); by default the FMU's start-up mode applies (docs/control.md,
        "Start-up"). Both flags together run the paper's controllers exactly.
    figure_format : {"png", "pdf", "svg"}
        The figures' format (:data:`FIGURE_FORMATS`).

    Returns
    -------
    dict
        The document written as ``paper.json``.

    Raises
    ------
    ValueError
        No seed, a seed given twice, or a figure format not in :data:`FIGURE_FORMATS`.
    """
    from build_scripts.build_fmus import cached_fmus
    from tapmuscle.cosim import PAPER_SCENARIOS, co_simulate, load_scenario
    from tapmuscle.cosim.master import sample_columns

    checked_seeds(seeds)
    checked_figure_format(figure_format)
    out = Path(out)
    total, done = len(PAPER_RUNS) * len(seeds), 0
    if progress is not None:
        progress(0, total)  # from the start: the FMU build and the identification come first
    fmus = dict(fmus) if fmus is not None else cached_fmus()
    if id_seed is None:
        id_seed = seeds[0]
    theta0 = preliminary_theta(id_seed, refine_hz)
    theta_params = {f"theta0.{n}": float(v) for n, v in zip(ASYMMETRIC.names, theta0)}
    if faithful_eq5:
        theta_params["hysteresis_notch"] = 0
    if faithful_start:
        theta_params["startup_s"] = 0.0
        theta_params["anti_windup"] = 0
    # every output at once: an interrupted or failed run leaves the folder as it was, never half of two runs
    with staged_folder(out, owned=PAPER_FILES) as tmp:
        results: dict[str, dict] = {}
        for run in PAPER_RUNS:
            scenario = load_scenario(PAPER_SCENARIOS / f"{run.name}.toml")
            errors, first = [], None
            for i, seed in enumerate(seeds):
                # the notch and the anti-windup are the servo law's: not set on the UCP methods, which
                # would warn of parameters they do not use
                given = {k: v for k, v in theta_params.items()
                         if run.method.endswith("servo") or k not in ("hysteresis_notch", "anti_windup")}
                cols = sample_columns(co_simulate(dataclasses.replace(scenario, seed=seed), fmus,
                                                  controller_parameters=given))
                errors.append(eq21_error_mm(cols["r_mm"], cols["l_mm"], scenario.evaluation_samples))
                if first is None:
                    first = cols
                # this run's own error: the table's cell is the mean over the seeds
                meta = {"ts_s": "0.1", "load_n": f"{run.load_n:g}", "seed": str(seed), "method": run.method,
                        "reference": f"35 + 30 sin(2 pi {run.frequency_hz:g} t) mm",
                        "eq21_error_mm": f"{errors[-1]:.4f}",
                        "eq21_window_s": f"{EQ21_WINDOW_S[0]:g}-{EQ21_WINDOW_S[1]:g}",
                        "source": f"tapmuscle paper (simulated rig, FMU co-simulation of scenarios/paper/{run.name}.toml)"}
                write_recording(tmp / _run_file(run, seed, i == 0), Recording(cols, meta))
                done += 1
                if progress is not None:
                    progress(done, total)
            err = float(np.mean(errors))
            results[run.name] = {"run": run, "cols": first, "error": err, "errors": errors}
            print(f"  {run.name:<24} Eq. (21) error {err:6.3f} mm (seeds {', '.join(f'{e:.3f}' for e in errors)}), "
                  f"u in [{first['u_v'].min():.2f}, {first['u_v'].max():.2f}] V", file=stream)

        tables = paper_tables({name: r["error"] for name, r in results.items()})
        per_seed = paper_tables({name: r["errors"] for name, r in results.items()})
        cols_by_table = paper_tables({name: r["cols"] for name, r in results.items()})
        # the figures of the two modes differ: each says its own
        mode = ", ".join([("the paper's start" if faithful_start else "start-up mode"),
                          ("Eq. (5) as printed" if faithful_eq5 else "notch")])
        frequency = {table: freq for table, freq, _, _ in _TABLES}
        numbers = {table: figs for table, _, _, figs in _TABLES}
        for table, load, tracking, prediction in _figure_names(figure_format):
            runs = cols_by_table[table][str(load)]
            fig_t, fig_p = numbers[table][load]
            where = f"{load} N, {frequency[table]:g} Hz (seed {seeds[0]}; {mode})"
            plot_tracking(runs, tmp / tracking, window_s=EQ21_WINDOW_S, title=f"Fig. {fig_t}: tracking, {where}")
            plot_prediction_errors(runs, tmp / prediction, window_s=EQ21_WINDOW_S,
                                   title=f"Fig. {fig_p}: prediction error, {where}")
        document = {**tables, "per_seed": per_seed, "seeds": list(seeds), "id_seed": id_seed,
                    "findings": paper_findings(tables), "paper": PAPER_TABLES,
                    "theta0": ASYMMETRIC.to_dict(theta0),
                    "hysteresis_notch": "off (the paper's Eq. (5))" if faithful_eq5 else "the FMU's default",
                    "start": "the paper's (startup_s = 0)" if faithful_start else "the FMU's start-up mode (its default startup_s)",
                    "eq21_window_s": list(EQ21_WINDOW_S), **produced_by()}
        atomic_write_text(tmp / "paper.json", json_text(document, indent=2))
        atomic_write_text(tmp / "tables.csv", tables_csv_text(per_seed))
    print_tables(tables, stream)
    return document


def paper_tables(values: Mapping[str, T]) -> dict[str, dict[str, dict[str, T]]]:
    """Per-run ``values`` (keyed by :attr:`PaperRun.name`) arranged as Tables 6, 7 and 9:
    ``table -> load ("44", "68") -> method``, the shape of ``paper.json``.

    Parameters
    ----------
    values : mapping of str to object
        A value per run, keyed by :attr:`PaperRun.name`.
    """
    return {table: {str(load): {m: values[PaperRun(m, float(load), freq).name] for m in methods} for load in (44, 68)}
            for table, freq, methods, _ in _TABLES}


def paper_findings(tables: Mapping[str, Mapping[str, Mapping[str, float]]]) -> dict[str, bool]:
    """The reproduction targets on Tables 6, 7 and 9 (``paper.json``'s shape), each true where it holds.

    The paper's findings (sections 4.2-4.4): servo beats UCP, fixed and adaptive; the fixed UCP degrades
    with load (by more than 0.2 mm: its predictor is a 44 N model); AMPC-UCP beats MPC-UCP;
    AMPC-servo <= MPC-servo at 0.1 Hz and < at 0.2 Hz; and the AMPC-servo error targets,
    <= 0.30 mm at 0.1 Hz and <= 0.70 mm at 0.2 Hz.

    The numbers are ours, set against the paper's: the error targets lie just above its AMPC-servo
    rows (Table 7: 0.28 and 0.29 mm; Table 9: 0.67 and 0.68 mm), and the load's 0.2 mm is a fifth of
    the fixed UCP's degradation in Table 6 (1.27 -> 2.25 mm). Sections 4.2-4.3's "more than 0.94"
    and "more than 0.04" are the tables' smaller gaps (Table 6's UCP-servo gap is 0.94 at 44 N and
    1.92 at 68 N; Table 7's AMPC-servo against Table 6's MPC-servo 0.05 at 44 N, 0.04 at 68 N); the
    Conclusion's "more than 0.84" matches no gap of the tables, and its "0.05" only the 44-N one.
    Only the findings' directions are checked.

    Parameters
    ----------
    tables : mapping
        Eq. (21) errors [mm] as ``table -> load -> method`` (:func:`paper_tables`' shape) for
        ``table6``, ``table7`` and ``table9``.
    """
    t6, t7, t9 = tables["table6"], tables["table7"], tables["table9"]
    out: dict[str, bool] = {}
    for load in ("44", "68"):
        out[f"servo beats UCP, fixed, {load} N"] = t6[load]["mpc_servo"] < t6[load]["mpc_ucp"]
        out[f"servo beats UCP, adaptive, {load} N"] = t7[load]["ampc_servo"] < t7[load]["ampc_ucp"]
        out[f"AMPC-UCP beats MPC-UCP, {load} N"] = t7[load]["ampc_ucp"] < t6[load]["mpc_ucp"]
        out[f"AMPC-servo <= MPC-servo at 0.1 Hz, {load} N"] = t7[load]["ampc_servo"] <= t6[load]["mpc_servo"]
        out[f"AMPC-servo < MPC-servo at 0.2 Hz, {load} N"] = t9[load]["ampc_servo"] < t9[load]["mpc_servo"]
        out[f"AMPC-servo <= 0.30 mm at 0.1 Hz, {load} N"] = t7[load]["ampc_servo"] <= 0.30
        out[f"AMPC-servo <= 0.70 mm at 0.2 Hz, {load} N"] = t9[load]["ampc_servo"] <= 0.70
    out["fixed UCP degrades with load"] = t6["68"]["mpc_ucp"] > t6["44"]["mpc_ucp"] + 0.2
    return out


#: The columns of ``tables.csv`` (:func:`tables_csv_text`).
TABLE_COLUMNS = ("table", "load_n", "frequency_hz", "method", "eq21_error_mm", "sd_mm", "min_mm", "max_mm", "seeds",
                 "paper_eq21_error_mm", "window_from_s", "window_to_s")


def tables_csv_text(per_seed: Mapping[str, Mapping[str, Mapping[str, Sequence[float]]]]) -> str:
    """Tables 6, 7 and 9 as CSV text, one row per cell (``tables.csv``).

    Parameters
    ----------
    per_seed : mapping
        ``table -> load ("44", "68") -> method -> [Eq. (21) error of each seed, mm]`` (``paper.json``'s
        ``per_seed``).

    Returns
    -------
    str
        A header of :data:`TABLE_COLUMNS`, then per cell: the mean error over the seeds (the table's
        number), the seeds' sample standard deviation (empty with one seed), least and largest, how
        many seeds, the paper's value, and the window Eq. (21) averages |r - l| over [s]. Errors
        [mm] to 4 decimals: the simulation's noise floor is far above 1e-4 mm.
    """
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(TABLE_COLUMNS)
    for table, freq, methods, _ in _TABLES:
        for load in ("44", "68"):
            for m in methods:
                e = np.asarray(per_seed[table][load][m], dtype=float)
                sd = f"{np.std(e, ddof=1):.4f}" if e.size > 1 else ""
                writer.writerow([table, load, f"{freq:g}", m, f"{np.mean(e):.4f}", sd, f"{e.min():.4f}",
                                 f"{e.max():.4f}", e.size, f"{PAPER_TABLES[table][load][m]:g}",
                                 f"{EQ21_WINDOW_S[0]:g}", f"{EQ21_WINDOW_S[1]:g}"])
    return text.getvalue()


def print_tables(tables: dict, stream: TextIO = sys.stdout) -> None:
    """Tables 6, 7 and 9: our Eq. (21) errors beside the paper's [mm]."""
    titles = {"table6": "Table 6 (0.1 Hz, fixed predictor)", "table7": "Table 7 (0.1 Hz, adaptive)",
              "table9": "Table 9 (0.2 Hz, servo mechanism)"}
    for table, freq, methods, _ in _TABLES:
        print(f"\n{titles[table]}: Eq. (21) error [mm], simulated (paper)", file=stream)
        print(f"{'load':>6}  " + "  ".join(f"{m:>20}" for m in methods), file=stream)
        for load in ("44", "68"):
            cells = [f"{tables[table][load][m]:9.3f} ({PAPER_TABLES[table][load][m]:5.2f})" for m in methods]
            print(f"{load + ' N':>6}  " + "  ".join(f"{c:>20}" for c in cells), file=stream)
    findings = paper_findings(tables)
    print(f"\nThe paper's findings: {sum(findings.values())} of {len(findings)} hold (docs/control.md)", file=stream)
    for name, holds in findings.items():
        print(f"  {'holds' if holds else 'DOES NOT HOLD':>13}  {name}", file=stream)
