"""The master's logger for FMUs whose messages are printf formats with arguments (C exports): the
values are formatted in, each message reaches its own instance's sink, and pythonfmu's FMUs keep
the plain-text logger (a '%' in their text is no format)."""

from __future__ import annotations

import ctypes
import os

import pytest

from tapmuscle.cosim import master

pytestmark = pytest.mark.skipif(
    master._formatting_logger() is None and not os.environ.get("TAPMUSCLE_REQUIRE_COMPILED"),
    reason="tapmuscle.cosim._fmi_log is not compiled (python setup.py build_ext --inplace)")


def _call(name: bytes, status: int, fmt: bytes, *args) -> None:
    """The compiled logger called as an FMU calls it: fmi2CallbackLogger with variadic arguments."""
    types = [ctypes.c_double if isinstance(a, float) else ctypes.c_int if isinstance(a, int) else ctypes.c_char_p
             for a in args]
    prototype = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                                 ctypes.c_char_p, *types)
    prototype(master._formatting_logger().address())(None, name, status, b"logStatusWarning", fmt, *args)


def test_a_messages_arguments_are_formatted_into_it_and_routed_by_instance():
    sink: list[str] = []
    master._LOG_SINKS["ctl#1"] = sink
    try:
        _call(b"ctl#1", 1, b"PI.T = %g s is small (%.0f%% of the default), in %s", 0.002, 2.0, b"PI")
        _call(b"ctl#1", 3, b"Tf = %g must be >= 0 (%d of %d)", -1.5, 3, 4)
        _call(b"ctl#1", 1, b"[ctl#1] 100%% plain")  # an instance's name leading its text is left out
    finally:
        del master._LOG_SINKS["ctl#1"]
    assert sink == ["[WARNING] PI.T = 0.002 s is small (2% of the default), in PI",
                    "[ERROR] Tf = -1.5 must be >= 0 (3 of 4)", "[WARNING] 100% plain"]


def test_a_message_longer_than_16_kb_is_cut_not_overrun(capsys):
    sink: list[str] = []
    master._LOG_SINKS["long#1"] = sink
    try:
        _call(b"long#1", 1, b"%s", b"x" * 40000)
    finally:
        del master._LOG_SINKS["long#1"]
    assert sink == ["[WARNING] " + "x" * 16383]


def test_pythonfmus_fmus_keep_the_plain_logger_and_other_fmus_get_the_formatting_one(built_fmus, tmp_path, monkeypatch):
    from tapmuscle.diagnosis.foreign_fmus import build_dc_motor_fmu

    def address(callbacks):
        return ctypes.cast(callbacks.logger, ctypes.c_void_p).value

    ours = master.unpack(built_fmus["MusclePlant"])
    assert master._sends_plain_text(ours)
    assert address(master._callbacks(formatted=True)) == master._formatting_logger().address()
    assert address(master._callbacks(formatted=False)) != master._formatting_logger().address()
    try:
        motor = master.unpack(build_dc_motor_fmu(tmp_path))
    except Exception as exc:  # noqa: BLE001 - no gcc: the plain-text rule alone is checked
        pytest.skip(f"the C demo FMU cannot be built here: {exc}")
    assert not master._sends_plain_text(motor)
    # an FMU that sends its text as the format (a '%' in it, which FMI forbids): every FMU's as plain text
    monkeypatch.setenv(master.FMU_LOG_ENV, "plain")
    assert master._sends_plain_text(motor) and not master._made_by_pythonfmu(motor)


def test_a_format_that_would_write_through_an_argument_is_shown_not_formatted():
    sink: list[str] = []
    master._LOG_SINKS["n#1"] = sink
    try:
        _call(b"n#1", 1, b"wrote %n bytes, %5.2lln more")
    finally:
        del master._LOG_SINKS["n#1"]
    assert sink == ["[WARNING] wrote %n bytes, %5.2lln more"]


def test_a_ctrl_c_taken_inside_the_logger_is_raised_once_the_fmi_call_returns(python_sigint_handler):
    """Python may run its SIGINT handler while the logger's target runs, inside an FMI call; the
    KeyboardInterrupt is not lost there (printed as unraisable): it is raised after the call."""
    def interrupted(*_args):
        raise KeyboardInterrupt

    from tapmuscle.cosim import _fmi_log

    call = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                            ctypes.c_char_p)(_fmi_log.address())
    _fmi_log.set_target(interrupted)
    try:
        with pytest.raises(KeyboardInterrupt):
            call(None, b"x#1", 1, b"logStatusWarning", b"a message")
            for _ in range(1000):  # the interrupt is checked between bytecodes
                pass
    finally:
        _fmi_log.set_target(master._log_formatted)
