"""tapmuscle: simulate, identify and control a tap-water-driven McKibben muscle.

The Python API (docs/python-api.md)::

    import tapmuscle as tm
    rec = tm.simulate("sine:bias=5,amp=3,freq=0.1", duration_s=240.0)      # the rig, open loop
    report = tm.identify(rec["u_v"], rec["l_mm"], ts_s=0.1)                  # Eq. (1), Algorithm 1
    run = tm.simulate_closed_loop("ampc_servo", lambda t: 35 + 30 * np.sin(0.2 * np.pi * t), duration_s=45.0)
    tm.eq21_error_mm(run["r_mm"], run["l_mm"])                               # Eq. (21)

The names load on first use, so ``import tapmuscle`` (and the command line) stays fast. The layers
under the root, bottom to top: :mod:`tapmuscle.errors`, :mod:`tapmuscle.io`, :mod:`tapmuscle.plots`,
:mod:`tapmuscle.closed_loop`, :mod:`tapmuscle.cosim`, :mod:`tapmuscle.diagnosis`,
:mod:`tapmuscle.paper`, :mod:`tapmuscle.cli`; the numerics that ship inside the FMUs are the
top-level packages ``fmu_plant`` and ``fmu_controller``.
"""

# underscored: dir(tm) and a notebook's tab completion offer the API alone
import importlib as _importlib
from typing import Any as _Any

__version__ = "0.1.0"

#: public name -> (module, attribute)
_EXPORTS: dict[str, tuple[str, str]] = {
    # the simulated rig (section 2.4, Table 1)
    "Plant": ("fmu_plant", "Plant"),
    "PlantParams": ("fmu_plant", "PlantParams"),
    "LightLoadWarning": ("fmu_plant", "LightLoadWarning"),
    "read_plant_file": ("tapmuscle.io.plant_file", "read_plant_file"),
    "write_plant_file": ("tapmuscle.io.plant_file", "write_plant_file"),
    "simulate": ("tapmuscle.api", "simulate"),
    # identification of Eq. (1) (section 2.3, Algorithm 1, Table 4)
    "identify": ("fmu_controller.identification", "identify_record"),
    "IdentificationReport": ("fmu_controller.identification", "IdentificationReport"),
    "score_model": ("fmu_controller.identification", "score_model"),
    "choose_input_delay": ("fmu_controller.input_delay_choice", "choose_input_delay"),
    "ASYMMETRIC": ("fmu_controller.hysteresis_model", "ASYMMETRIC"),
    "STANDARD": ("fmu_controller.hysteresis_model", "STANDARD"),
    # control (section 3, Eqs. (3)-(5), (15)-(21))
    "METHODS": ("fmu_controller.displacement_control", "METHODS"),
    "ControllerSettings": ("fmu_controller.displacement_control", "ControllerSettings"),
    "ServoMPCSettings": ("fmu_controller.servo_settings", "ServoMPCSettings"),
    "UCPSettings": ("fmu_controller.ucp_mpc", "UCPSettings"),
    "DisplacementController": ("fmu_controller.displacement_control", "DisplacementController"),
    "LoopWatch": ("fmu_controller.loop_watch", "LoopWatch"),
    "THETA0_44N": ("fmu_controller.preliminary_model", "THETA0_44N"),
    "SineReference": ("fmu_controller.reference", "SineReference"),
    "ArrayReference": ("fmu_controller.reference", "ArrayReference"),
    "FunctionReference": ("fmu_controller.reference", "FunctionReference"),
    "simulate_closed_loop": ("tapmuscle.api", "simulate_closed_loop"),
    "run_closed_loop": ("tapmuscle.closed_loop", "run_closed_loop"),
    "eq21_error_mm": ("tapmuscle.tracking_metrics", "eq21_error_mm"),
    "ClosedLoopWarning": ("tapmuscle.closed_loop", "ClosedLoopWarning"),
    "ControlLaw": ("tapmuscle.own_law", "ControlLaw"),
    "ValveWatch": ("tapmuscle.own_law", "ValveWatch"),
    # FMUs and co-simulation
    "build_fmus": ("tapmuscle.api", "build_fmus"),
    "cosimulate": ("tapmuscle.api", "cosimulate"),
    "sweep": ("tapmuscle.api", "sweep"),
    "load_scenario": ("tapmuscle.cosim", "load_scenario"),
    "PAPER_SCENARIOS": ("tapmuscle.cosim", "PAPER_SCENARIOS"),
    # recordings
    "Recording": ("tapmuscle.io.recording", "Recording"),
    "read_recording": ("tapmuscle.io.recording", "read_recording"),
    "write_recording": ("tapmuscle.io.recording", "write_recording"),
    "decimated": ("tapmuscle.io.decimation", "decimated"),
    "read_rig_log": ("tapmuscle.api", "read_rig_log"),
    "rig_log_runs": ("tapmuscle.io.rig_log", "rig_log_runs"),
    "LogColumn": ("tapmuscle.io.rig_log", "LogColumn"),
    "read_identification": ("tapmuscle.io.identification_file", "read_identification"),
    "write_identification": ("tapmuscle.io.identification_file", "write_identification"),
    # mismatch diagnosis
    "diagnose": ("tapmuscle.diagnosis", "diagnose"),
    "Diagnosis": ("tapmuscle.diagnosis", "Diagnosis"),
    "diagnose_files": ("tapmuscle.diagnosis.report", "diagnose_files"),
    "diagnose_foreign": ("tapmuscle.diagnosis.foreign_diagnose", "diagnose_foreign"),
    "diagnose_foreign_outputs": ("tapmuscle.diagnosis.foreign_diagnose", "diagnose_foreign_outputs"),
    # progress reports of long calls (``progress=True``)
    "Progress": ("tapmuscle.progress", "Progress"),
    # errors
    "TapmuscleError": ("tapmuscle.errors", "TapmuscleError"),
    "UsageError": ("tapmuscle.errors", "UsageError"),
    "ClusterError": ("tapmuscle.cosim.distributed_sweep", "ClusterError"),
    "ClusterWarning": ("tapmuscle.cosim.distributed_sweep", "ClusterWarning"),
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> _Any:
    try:
        module, attribute = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'tapmuscle' has no attribute {name!r}") from None
    value = getattr(_importlib.import_module(module), attribute)
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
