"""The Python API's own functions: one call for each of the things the command line does.

The package root (``import tapmuscle as tm``) re-exports these with the numerics they are made of
(:class:`~fmu_plant.Plant`, :class:`~fmu_controller.displacement_control.DisplacementController`,
:func:`~fmu_controller.identification.identify_record` as ``tm.identify``, ...). Each function here
is a thin composition of the layers below; nothing here writes a file unless asked to.
"""

from __future__ import annotations

import math
import numbers
import os
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from fmu_controller.argument_checks import sampling_period
from fmu_controller.displacement_control import METHODS, ControllerSettings, DisplacementController
from fmu_controller.preliminary_model import THETA0_44N
from fmu_controller.identification import PAPER_TS_S, IdentificationReport
from fmu_controller.prediction import MAX_INPUT_DELAY_SAMPLES
from fmu_plant import Effect, Plant, PlantParams
from fmu_plant.open_loop import run_open_loop
from tapmuscle.closed_loop import run_closed_loop
from tapmuscle.own_law import ControlLaw, as_law, law_name, law_period
from tapmuscle.progress import reporter
from tapmuscle.io.identification_file import IdentifiedModel, identified_model
from tapmuscle.io.recording import Recording, RecordingError
from tapmuscle.io.signals import Replay, parse_input_spec
from tapmuscle.plots.figure_formats import checked_figure_format

__all__ = ["simulate", "simulate_closed_loop", "cosimulate", "sweep", "build_fmus", "read_rig_log"]


def _plant(params: PlantParams | None, load_n: float | None, seed: int, effects: Sequence[Effect] | Effect = ()) -> Plant:
    """The rig at ``load_n`` with ``effects`` of the caller's own; :class:`Plant` checks ``seed`` (unsigned
    64-bit) and ``effects``."""
    if params is not None and not isinstance(params, PlantParams):
        # a file is read by its reader, as a recording or an identification is: the numerics take objects
        hint = (": a plant parameter file is read by tm.read_plant_file(path)"
                if isinstance(params, (str, os.PathLike)) else "")
        raise TypeError(f"params must be a PlantParams, got {type(params).__name__} {params!r:.60}{hint}")
    p = PlantParams() if params is None else params
    if load_n is not None and (isinstance(load_n, bool) or not isinstance(load_n, numbers.Real)):
        raise TypeError(f"load_n must be a number of newtons (or a function of time, closed loop), got "
                        f"{type(load_n).__name__} {load_n!r}")
    if load_n is not None and isinstance(p, PlantParams):
        p = p.with_values(**{"load.load_n": float(load_n)})
    return Plant(p, seed=seed, effects=effects)


def _check_positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def _check_period(ts_s: float) -> float:
    """A sampling period [s] the rig is simulated at: within ``tapmuscle record --ts``'s 1 ms..10 s
    (50 is milliseconds meant)."""
    _check_positive("ts_s", ts_s)
    return sampling_period(ts_s)


def simulate(command: Callable[[float], float] | Sequence[float] | np.ndarray | str, *,
             duration_s: float | None = None, ts_s: float = 0.1, load_n: float | None = None,
             params: PlantParams | None = None, seed: int = 0,
             effects: Sequence[Effect] | Effect = ()) -> dict[str, np.ndarray]:
    """Run the simulated rig open loop from rest (what ``tapmuscle record`` records).

    Parameters
    ----------
    command : callable, array_like or str
        The valve command [V]: ``u(t)`` of the time [s]; or one value per sample ``u(k)``, held over
        ``[t_k, t_k+1)`` (the last one held to the end); or a ``tapmuscle record --input`` spec such as
        ``"sine:bias=5,amp=3,freq=0.1"`` (docs/recordings.md). The valve takes 0..10 V. A
        ``csv:PATH`` spec replays a recording sample by sample, at its own period and for at most its
        length (another ``ts_s``, or a longer ``duration_s``, is refused).
    duration_s : float, optional
        Length of the run [s]; required for a callable or a spec other than ``csv:``, default
        ``(len - 1) ts_s`` for samples and the recording's length for ``csv:``.
    ts_s : float
        Sampling period [s] (paper: 0.1).
    load_n : float, optional
        Hanging load [N] (section 4.1: 44 or 68); default that of ``params`` (44 N).
    params : PlantParams, optional
        The rig's parameters (default: the calibrated rig of docs/plant.md); a plant parameter file
        (``calibrated_plant.json``) is read by :func:`~tapmuscle.io.plant_file.read_plant_file`.
    seed : int
        Seed of the encoder noise.
    effects : Effect or sequence of Effect
        Physics of your own (:class:`fmu_plant.Effect` subclasses, docs/plant.md "Effects of your
        own") beside the effects ``params`` switch on. They act in this process only: a plant FMU,
        ``tapmuscle record`` and the diagnosis know the parameters' effects alone.

    Returns
    -------
    dict of ndarray
        ``t_s`` [s], ``u_v`` [V], ``l_mm`` [mm] (encoder reading at ``t_k``), ``p_mpa`` [MPa],
        ``load_n`` [N], one row per sample (``round(duration_s / ts_s) + 1`` rows).

    Examples
    --------
    >>> import tapmuscle as tm
    >>> rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=20.0)
    >>> rec["l_mm"].shape
    (201,)
    """
    ts = _check_period(ts_s)
    if isinstance(command, str):
        signal = parse_input_spec(command, run_duration_s=duration_s, run_ts_s=ts)
        if duration_s is None and isinstance(signal, Replay):  # a recording replayed whole
            duration_s = signal.duration_s
    elif callable(command):
        signal = command
    else:
        u = np.asarray(command, dtype=float)
        if u.ndim != 1 or u.size == 0:
            raise ValueError(f"command samples must be a non-empty 1-D array, got shape {u.shape}")
        bad = np.nonzero(~np.isfinite(u))[0]
        if bad.size:
            raise ValueError(f"command[{int(bad[0])}] = {float(u[bad[0]])!r} is not finite")
        if duration_s is None:
            if u.size < 2:
                raise ValueError(f"command has {u.size} sample; give at least 2 samples, or duration_s")
            duration_s = (u.size - 1) * ts

        def signal(t: float) -> float:
            return float(u[min(int(round(t / ts)), u.size - 1)])
    if duration_s is None:
        raise ValueError("duration_s is required when the command is a function or a spec")
    return run_open_loop(_plant(params, load_n, seed, effects), signal, duration_s=_check_positive("duration_s", duration_s),
                         ts_s=ts)


def simulate_closed_loop(method: str | ControlLaw = "ampc_servo", reference: Any = None, *, duration_s: float = 45.0,
                ts_s: float | None = None, load_n: float | Callable[[float], float] | None = None,
                params: PlantParams | None = None, theta0: Sequence[float] | Mapping[str, float] | None = None,
                settings: ControllerSettings | None = None, seed: int = 0,
                loop_delay_samples: int = 0, effects: Sequence[Effect] | Effect = (),
                progress: bool | Callable[[int, int], None] | None = None,
                watch: bool = True, preview_samples: int | None = None) -> dict[str, np.ndarray]:
    """Track a reference with one of the paper's four controllers on the simulated rig (no FMU).

    The loop of :func:`tapmuscle.closed_loop.run_closed_loop`: at ``t_k`` the controller reads
    ``l(k)``, sees the preview ``r(k..k+Hp)`` and sets ``u(k)``, held until ``t_k+1``. It gives the
    co-simulated FMUs' numbers bit for bit (docs/fmu.md).

    Parameters
    ----------
    method : {"mpc_ucp", "mpc_servo", "ampc_ucp", "ampc_servo"} or ControlLaw
        MPC with unique coincidence point (Eqs. (11)-(14)) or with servo mechanism (Eqs. (15)-(20)), with a
        fixed predictor (MPC) or adapted online by Algorithm 1 (AMPC). Or a law of your own, an object
        with ``step(l_mm, preview_mm)`` returning the valve command [V]
        (:class:`tapmuscle.own_law.ControlLaw`; ``theta0`` and ``settings`` are then not taken), or
        a function ``u = f(l_mm, preview_mm)``, run on the same rig and loop at ``ts_s`` (default
        its own ``ts_s`` attribute; given both, they must agree).
    reference : callable, array_like, Reference or None
        ``r(t)`` [mm] of the time [s]; or one value per sample ``r(k)`` [mm] (the last held beyond
        its end, also in the preview); or a :class:`~fmu_controller.reference.SineReference`,
        :class:`~fmu_controller.reference.ArrayReference` or
        :class:`~fmu_controller.reference.FunctionReference`. Default: the paper's
        ``35 + 30 sin(2 pi 0.1 t)`` mm (section 4.1).
    duration_s : float
        Length of the run [s]. The default 45 s holds Eq. (21)'s window (10-40 s; the paper does not
        give its runs' length).
    ts_s : float, optional
        Sampling period [s]; default that of ``settings``, of an ``IdentifiedModel`` ``theta0`` or of a
        law of your own (its ``ts_s`` attribute), else the paper's 0.1.
    load_n : float or callable, optional
        Hanging load [N], constant or ``load(t)``; default that of ``params`` (44 N).
    params : PlantParams, optional
        The simulated rig (default: the calibrated rig of docs/plant.md); a plant parameter file is
        read by :func:`~tapmuscle.io.plant_file.read_plant_file`.
    theta0 : sequence of 15 floats, mapping, IdentifiedModel or IdentificationReport, optional
        The predictor's initial (for MPC: fixed) Eq. (1) parameters, in the asymmetric model's order
        (``tm.identify(...).theta``) or all 15 by name (its ``theta_dict``); or, better, what
        :func:`~tapmuscle.io.identification_file.read_identification` read or ``tm.identify``
        returned (its period checked against ``ts_s`` and taken where ``ts_s`` is not given, its box
        and a transport delay it was identified under the default settings', the delay with
        ``loop_delay_samples`` added; given ``settings``, theirs apply: a bare ``theta`` carries no
        period, and runs at 0.1 s unless ``ts_s`` says otherwise); default the 44 N
        preliminary identification :data:`~fmu_controller.preliminary_model.THETA0_44N` (section 4.2),
        identified at Ts = 0.1 s: another ``ts_s`` needs a ``theta0`` identified at it; for another
        ``params`` it is the paper's rig's still, which fixed MPC-UCP on rigs of other reach tracks with
        offsets of 2-6 mm (``tapmuscle.paper.preliminary_theta(params=...)`` makes the rig's own;
        docs/control.md, "A theta0 for another rig").
    settings : ControllerSettings, optional
        Full controller settings (horizons, weights, P(0), box); its ``method`` and ``ts_s`` must
        agree with ``method`` and ``ts_s``. Default: the paper's (Table 5), as the controller FMU's,
        with the box C of an ``IdentifiedModel`` ``theta0``, else Table 2's at Ts = 0.1 s and none at
        another ``ts_s`` (as :func:`identify` does).
    seed : int
        Seed of the encoder noise.
    loop_delay_samples : {0, 1}
        1: each command acts one sample late, as in a parallel co-simulation master at h = Ts.
    effects : Effect or sequence of Effect
        Physics of your own on the simulated rig, as :func:`simulate` takes them (this process only).
    progress : bool or callable, optional
        ``progress(done, total)`` about every 1 % of the run; True: a report on stderr
        (:class:`tapmuscle.progress.Progress`).
    watch : bool, default True
        Warn after the run of what the controller FMU would log of it (a limit cycle, a set input
        delay the first 30 s contradict, a stuck reading, ...: :func:`run_closed_loop`); for a law of
        your own, of what needs no model (:class:`tapmuscle.own_law.ValveWatch`); False: not.
    preview_samples : int, optional
        A law of your own's preview ``r(k..k+n)``: ``n`` (default its ``preview_samples`` attribute,
        else 5, Table 5's servo horizon); the paper's controllers take theirs from ``settings``.

    Returns
    -------
    dict of ndarray
        ``t_s, r_mm, l_mm, u_v, p_mpa, load_n, l_pred_mm, pred_error_mm, uc_v, h_mm, xs_mm`` and
        ``theta_<name>`` for Eq. (1)'s 15 parameters; one row per sample (a law of your own's: ``t_s,
        r_mm, l_mm, l_true_mm, u_v, p_mpa, load_n``). Score with
        :func:`tapmuscle.tracking_metrics.eq21_error_mm` (Eq. (21)).

    Examples
    --------
    >>> import tapmuscle as tm
    >>> run = tm.simulate_closed_loop("ampc_servo", lambda t: 40.0 + 10.0 * (t > 5.0), duration_s=20.0)
    >>> bool(abs(run["l_mm"][-1] - 50.0) < 2.0)
    True
    """
    if not isinstance(method, str) and (callable(method) or callable(getattr(method, "step", None))):
        method = as_law(method)
        ts = _check_period(law_period(method, PAPER_TS_S if ts_s is None and getattr(method, "ts_s", None) is None
                                      else ts_s))
        if theta0 is not None or settings is not None:
            raise ValueError(f"theta0 and settings set the paper's controllers; the law {law_name(method)} of "
                             "your own takes neither (give it its own parameters)")
        plant = _plant(params, None if callable(load_n) else load_n, seed, effects)
        return run_closed_loop(plant, method, reference, duration_s=duration_s, ts_s=ts,
                               load_n=load_n if callable(load_n) else None, loop_delay_samples=loop_delay_samples,
                               progress=reporter(progress, "simulate_closed_loop"), watch=watch,
                               preview_samples=preview_samples)
    if not isinstance(method, str) or method not in METHODS:
        kind = ValueError if isinstance(method, str) else TypeError  # a value of the wrong kind (python-api.md)
        raise kind(f"unknown method {method!r}; expected one of {', '.join(METHODS)}, or a law of your own "
                   "with a step(l_mm, preview_mm) method (tapmuscle.own_law.ControlLaw) or a function u = "
                   "f(l_mm, preview_mm)")
    if isinstance(theta0, IdentificationReport):  # tm.identify's result: its period, box and delay go with it
        theta0 = identified_model(theta0.to_dict(), "theta0 (tm.identify's result)")  # checked as a file is
    if ts_s is None:
        ts_s = (settings.ts_s if isinstance(settings, ControllerSettings)
                else theta0.ts_s if isinstance(theta0, IdentifiedModel) else PAPER_TS_S)
    ts = _check_period(ts_s)
    box: dict[str, Any] = {}
    if isinstance(theta0, IdentifiedModel):  # read_identification's: its period, its box and its delay
        theta0.check_period(ts)
        box = {"box_lower": theta0.box_lower, "box_upper": theta0.box_upper}
        if theta0.input_delay_samples:
            # the rig's delay and, in a loop run as a parallel master does, its sample on top
            delay = theta0.input_delay_samples + (loop_delay_samples == 1)
            if delay > MAX_INPUT_DELAY_SAMPLES and settings is None:
                raise ValueError(f"{theta0.path}: identified under a transport delay of {theta0.input_delay_samples} "
                                 f"samples, and loop_delay_samples = 1 adds one: {delay} samples, beyond the "
                                 f"{MAX_INPUT_DELAY_SAMPLES} the controller compensates (input_delay_samples); run "
                                 "the loop with loop_delay_samples = 0, or identify at a longer Ts")
            box["input_delay_samples"] = delay
        theta0 = theta0.theta
    elif abs(ts - PAPER_TS_S) > 1e-3 * PAPER_TS_S:
        # Table 2's box holds for Ts = 0.1 s; elsewhere none, as tm.identify applies none there
        box = {"box_lower": {}, "box_upper": {}}
    if settings is None:
        settings = ControllerSettings(method=method, ts_s=ts, **box)
    elif not isinstance(settings, ControllerSettings):
        raise ValueError(f"settings must be a ControllerSettings, got {type(settings).__name__}")
    elif settings.method != method or abs(settings.ts_s - ts) > 1e-12 * ts:
        raise ValueError(f"settings.method = {settings.method!r}, settings.ts_s = {settings.ts_s!r} s disagree "
                         f"with method = {method!r}, ts_s = {ts!r} s")
    if theta0 is None and abs(ts - PAPER_TS_S) > 1e-3 * PAPER_TS_S:
        # a discrete model's parameters belong to its sampling period (the 0.1-s predictor at 0.2 s:
        # 13 mm of error and the valve slamming)
        raise ValueError(f"ts_s = {ts:g} s needs a theta0 identified at that period: the default THETA0_44N is "
                         f"the paper's, identified at Ts = {PAPER_TS_S:g} s (tm.identify(..., ts_s={ts:g}) gives one)")
    plant = _plant(params, None if callable(load_n) else load_n, seed, effects)
    controller = DisplacementController(settings, THETA0_44N if theta0 is None else theta0)
    return run_closed_loop(plant, controller, reference, duration_s=duration_s,
                           load_n=load_n if callable(load_n) else None, loop_delay_samples=loop_delay_samples,
                           progress=reporter(progress, "simulate_closed_loop"), watch=watch,
                           preview_samples=preview_samples)


def read_rig_log(path: str | os.PathLike, *, time: Any = None, u: Any, l: Any,  # noqa: E741
                 p: Any = None, load: Any = None, load_n: float | None = None, delimiter: str | None = None,
                 decimal: str | None = None, fill_gaps_s: float = 0.0, skip_lines: int = 0,
                 encoding: str = "utf-8-sig", run: int | None = None, ambient_kpa: float | None = None,
                 ts_s: float | None = None, decimate: int = 1, checks: bool = True) -> Recording:
    """Read a rig's log as a recording and check it as ``tapmuscle import`` does (docs/recordings.md).

    The log is read by :func:`tapmuscle.io.rig_log.read_rig_log` (any column names, the units given
    or the log's own, separator and decimal mark detected), then checked as the diagnosis would
    check it (:func:`tapmuscle.diagnosis.rig_log_checks.checked_rig_log`): a period, command,
    displacement or pressure that no muscle recording has is refused, naming the line, the column and
    the unit that would read it as one (``u='valve:%'``: a command in percent given as volts). What
    may be wrong but is not refused (a start away from rest, a span unlike the nominal model's, a
    sensor's jump or clipping) is warned of (``UserWarning``).

    Parameters
    ----------
    path : path
        The log file.
    time, u, l : LogColumn or str
        The columns of the time [s], the valve command [V] and the displacement [mm], as
        ``"NAME"`` or ``"NAME:UNIT"`` (units: ``tapmuscle.io.rig_log.UNITS``); ``time`` may be left
        out with ``ts_s``.
    p, load : LogColumn or str, optional
        The muscle pressure [MPa] and load [N] columns.
    load_n : float, optional
        The hanging load [N] when it is not a column.
    delimiter, decimal : str, optional
        Field separator and decimal mark (default: detected).
    fill_gaps_s : float
        Put back the samples a logger dropped in gaps of up to this many seconds (default 0: refused).
    skip_lines : int
        Lines before the header to skip.
    encoding : str
        The file's text encoding (default UTF-8).
    run : int, optional
        Which run (1 = the first) of a log a restarted logger wrote on.
    ambient_kpa : float, optional
        The ambient pressure [kPa] an absolute pressure unit is read against.
    ts_s : float, optional
        The sampling period [s] of a log without a time column, or with a sample counter for one.
    decimate : int
        Merge every ``decimate`` samples into one before the checks (a log taken faster than the
        muscle needs: 1 kHz with 20 gives 0.02 s; :func:`tapmuscle.io.decimation.decimated`).
    checks : bool
        False takes a log the checks refuse as it is, with a warning of what they found (another
        rig's units, for identification).

    Returns
    -------
    Recording
        As :func:`tapmuscle.io.rig_log.read_rig_log` returns it (merged, with ``decimate``).

    Raises
    ------
    tapmuscle.io.recording.RecordingError
        The log cannot be read as given, or (``checks``) holds values no muscle recording has.
    """
    from fmu_plant.user_warning import warn_at_caller
    from tapmuscle.diagnosis.rig_log_checks import PYTHON, LogOptions, checked_rig_log

    if isinstance(decimate, bool) or not isinstance(decimate, (int, np.integer)) or decimate < 1:
        raise RecordingError(f"{path}: decimate = {decimate!r} must be an integer >= 1 (samples merged into one)")
    checked = checked_rig_log(LogOptions(str(path), time=time, u=u, l=l, p=p, load=load, load_n=load_n,
                                         delimiter=delimiter, decimal=decimal, fill_gaps_s=fill_gaps_s,
                                         skip_lines=skip_lines, encoding=encoding, ambient_kpa=ambient_kpa,
                                         ts_s=ts_s, decimate=int(decimate), checks=bool(checks)), run, PYTHON)
    for finding in checked.findings:
        warn_at_caller(finding if str(path) in finding else f"{path}: {finding}", UserWarning)
    return checked.recording


def build_fmus(out: str | Path, names: str | Sequence[str] | None = None) -> list[Path]:
    """Build ``MusclePlant.fmu`` and ``AMPCController.fmu`` (FMI 2.0 co-simulation), reproducibly.

    Parameters
    ----------
    out : path
        Folder to write the FMUs into (created if missing).
    names : str or sequence of str, optional
        One of ``"MusclePlant"``, ``"AMPCController"`` or a subset of both; default both.

    Returns
    -------
    list of Path
        The FMU files, in the order of ``names``.
    """
    from build_scripts.build_fmus import build_fmus as _build

    return _build(out, names)


def _fmus_argument(fmus: Any, scenarios: list) -> dict[str, Path]:
    """The ``fmus`` argument of :func:`cosimulate` and :func:`sweep` checked: a mapping (default the FMUs
    built from this installation) with an existing FMU file for each role a scenario names no file for."""
    from build_scripts.build_fmus import FMUS, cached_fmus

    if fmus is not None and not isinstance(fmus, Mapping):
        raise TypeError(f"fmus must be a mapping {{'MusclePlant': path, 'AMPCController': path}}, got a "
                        f"{type(fmus).__name__}")
    given = {name: Path(path) for name, path in fmus.items()} if fmus is not None else cached_fmus()
    needed = {name for sc in scenarios for name, own in (("MusclePlant", sc.plant.path),
                                                          ("AMPCController", sc.controller.path)) if not own}
    unknown = sorted(set(given) - set(FMUS))
    if unknown:  # a misspelt role would otherwise read as the right one missing
        import difflib

        close = {k: difflib.get_close_matches(k, list(FMUS), n=1, cutoff=0.6) for k in unknown}
        raise ValueError(f"fmus takes the keys {' and '.join(map(repr, FMUS))} (the FMUs' roles), got "
                         + ", ".join(f"{k!r}" + (f" (did you mean {close[k][0]!r}?)" if close[k] else "") for k in unknown))
    missing = sorted(needed - set(given))
    if missing:
        raise ValueError(f"fmus has no {' and no '.join(repr(m) for m in missing)} (and the scenario names no "
                         f"path for it); given: {', '.join(map(repr, given)) or 'none'}")
    absent = [f"{name}: {given[name]}" for name in sorted(needed) if not given[name].is_file()]
    if absent:
        raise ValueError(f"fmus names no FMU file for {'; '.join(absent)} (tm.build_fmus(folder) writes them)")
    return given


def sweep(sweep: Any, out: str | Path, *, fmus: Mapping[str, str | Path] | None = None, client: Any = None,
          workers: int = 0, plots: bool = True, progress: bool | Callable[[int, int, str], None] | None = None,
          figure_format: str = "png") -> Any:
    """Run a sweep's runs not yet finished in ``out`` and write its summary (what ``tapmuscle sweep`` does).

    Parameters
    ----------
    sweep : path or Sweep
        A sweep TOML file (docs/sweeps.md; e.g. ``scenarios/sweeps/paper_grid.toml``) or a parsed
        :class:`~tapmuscle.cosim.sweep.Sweep`.
    out : path
        The output folder: ``results.csv`` (one row per run, appended as runs finish: a rerun goes on
        where one stopped), ``summary.md`` and the PNGs.
    fmus : mapping, optional
        ``{"MusclePlant": path, "AMPCController": path}``; default the FMUs built from this installation.
    client : distributed.Client, optional
        Run on this Dask client's cluster (a notebook's own; its workers are checked first, and it is left
        open and usable). Default: ``workers``.
    workers : int
        Without ``client``: 0 runs every run in this process; N > 0 on a local cluster of N worker
        processes, closed at the end.
    plots : bool
        Draw the figures.
    progress : bool or callable, optional
        ``progress(done, total, detail)`` after each run; True: a report on stderr
        (:class:`tapmuscle.progress.Progress`).
    figure_format : {"png", "pdf", "svg"}
        The figures' format (PDF and SVG, vector, for a publication).

    Returns
    -------
    SweepReport
        Runs in total, already done, run now, failed, missing their expectations, and every run's row.

    Raises
    ------
    ScenarioError
        A bad sweep file or parameter (named), or ``out`` holding another sweep's results.
    ClusterError
        None of ``client``'s workers can run tapmuscle (each named, with what it lacks; one that cannot
        beside others that can gets no run, warned of as a ``ClusterWarning``), a local cluster's
        processes did not start (a script calling this outside ``if __name__ == "__main__":``), or the
        cluster was lost mid-sweep (its scheduler, or every worker for a minute): the finished runs
        are kept in ``results.csv``, and calling again goes on.
    """
    from contextlib import ExitStack

    from tapmuscle.cosim.distributed_sweep import DaskExecutor, check_workers, dask_client, run_serial
    from tapmuscle.cosim.sweep import Sweep, load_sweep
    from tapmuscle.cosim.sweep_run import run_sweep

    progress = reporter(progress, "sweep")
    if not isinstance(sweep, (str, Path, Sweep)):
        raise TypeError(f"sweep must be a sweep file's path or a Sweep, got a {type(sweep).__name__}")
    if not isinstance(out, (str, Path)) or Path(out).exists() and not Path(out).is_dir():
        raise ValueError(f"out must be a folder to write into, got {out!r}"
                         + (" (an existing file)" if isinstance(out, (str, Path)) else ""))
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ValueError(f"workers must be an integer >= 0, got {workers!r}")
    if client is not None and (not callable(getattr(client, "run", None)) or getattr(client, "status", "running")
                               in ("closing", "closed")):
        raise ValueError(f"client must be a running distributed.Client, got {client!r}"
                         + (" (for a scheduler's address: distributed.Client(address))" if isinstance(client, str) else ""))
    sw = sweep if isinstance(sweep, Sweep) else load_sweep(sweep)
    given = _fmus_argument(fmus, [run.scenario for run in sw.runs])
    with ExitStack() as stack:
        if client is not None:
            execute = DaskExecutor(client, refused=check_workers(client))
        elif workers:
            execute = DaskExecutor(stack.enter_context(dask_client(workers)), one_run_per_thread=True)
        else:
            execute = run_serial
        return run_sweep(sw, out, given, execute, plots=plots, progress=progress, figure_format=figure_format)


def cosimulate(scenario: Any, *, fmus: Mapping[str, str | Path] | None = None, out: str | Path | None = None,
               plots: bool = True, figure_format: str = "png") -> dict[str, Any]:
    """Co-simulate a scenario through the two FMUs in fmpy (what ``tapmuscle run`` does).

    Parameters
    ----------
    scenario : path or Scenario
        A scenario TOML file (docs/fmu.md; e.g. one of :data:`tapmuscle.cosim.PAPER_SCENARIOS`) or a
        parsed :class:`~tapmuscle.cosim.spec.Scenario`.
    fmus : mapping, optional
        ``{"MusclePlant": path, "AMPCController": path}``; default the FMUs built from this
        installation (cached while the sources are unchanged).
    out : path, optional
        If given, also write ``result.csv``, ``summary.json`` and the figures there, as ``tapmuscle run``.
    plots : bool
        With ``out``: write the figures.
    figure_format : {"png", "pdf", "svg"}
        With ``out``: the figures' format (PDF and SVG, vector, for a publication).

    Returns
    -------
    dict
        ``columns`` (one array per recorded variable, one row per sample: ``t_s, r_mm, l_mm, u_v``
        and the controller's diagnostics, which a controller FMU of one's own has none of),
        ``mae_mm`` (Eq. (21) over the scenario's evaluation window [mm]) and ``summary`` (what
        ``summary.json`` holds: every metric, the FMUs, the scenario).
    """
    from tapmuscle.cosim import load_scenario
    from tapmuscle.cosim.master import co_simulate, sample_columns
    from tapmuscle.cosim.run import run_scenario, summarise
    from tapmuscle.cosim.spec import Scenario

    if not isinstance(scenario, (Scenario, str, os.PathLike)):
        raise TypeError(f"scenario must be a scenario TOML file's path or a Scenario (tm.load_scenario(path)), got "
                        f"{type(scenario).__name__} {scenario!r:.60}")
    checked_figure_format(figure_format)
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    given = _fmus_argument(fmus, [sc])
    if out is not None:
        summary = run_scenario(sc, out, given, plots=plots, figure_format=figure_format)
        cols = summary.pop("cols")
    else:
        # the scenario's own FMU paths win, as in tapmuscle run
        used = {"MusclePlant": Path(sc.plant.path or given["MusclePlant"]),
                "AMPCController": Path(sc.controller.path or given["AMPCController"])}
        cols = co_simulate(sc, used)
        summary = summarise(sc, cols, used)
    return {"columns": sample_columns(cols), "mae_mm": summary["mae_mm"],
            "summary": summary}
