"""The ``tapmuscle`` command itself (tapmuscle/cli/main.py): what it says about its versions."""

import platform
import re
import subprocess
import sys
import sysconfig

import numpy as np
import pytest
import scipy

import tapmuscle
from fmu_plant.rosenbrock import COMPILED
from tapmuscle.cli.main import main
from conftest import UTF8_PATHS


def test_version_names_tapmuscle_python_the_numerics_and_the_sub_step(capsys):
    from tapmuscle.cosim.master import formats_fmu_messages

    with pytest.raises(SystemExit) as ended:
        main(["--version"])
    assert ended.value.code == 0
    out, err = capsys.readouterr()
    assert err == ""
    found = re.fullmatch(r"tapmuscle (\S+)( from [^()]+)? \(Python (\S+); numpy (\S+), "
                         r"scipy (\S+), osqp \S+, pythonfmu \S+, "
                         r"fmpy \S+, matplotlib \S+; (\S+ \S+) \(([A-Z0-9_ ]+|baseline)\); compiled sub-step (yes|no); "
                         r"C FMU messages formatted (yes|no)"
                         r"(; libpython shared|; libpython static: FMUs for "
                         r"Python hosts only)?\)\n", out)
    assert found, out
    shared = bool(sysconfig.get_config_var("Py_ENABLE_SHARED"))
    libpython = None if not sys.platform.startswith("linux") else \
        "; libpython shared" if shared else "; libpython static: FMUs for Python hosts only"
    from tapmuscle.provenance import cpu_features, source_revision

    source = source_revision()
    assert found.groups() == (tapmuscle.__version__, None if source is None else f" from {source}",
                              platform.python_version(), np.__version__, scipy.__version__,
                              f"{platform.system()} {platform.machine()}", cpu_features(),
                              "yes" if COMPILED else "no", "yes" if formats_fmu_messages() else "no", libpython)


def test_version_from_the_installed_command_needs_no_subcommand():
    done = subprocess.run([sys.executable, "-m", "tapmuscle", "--version"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and re.match(rf"tapmuscle {re.escape(tapmuscle.__version__)}( from [^(]+)? \(Python ",
                                             done.stdout), done


def test_a_closed_pipe_is_not_reported_as_bad_input(tmp_path):
    """``tapmuscle record ... | head -0``: the reader is gone when the summary line is printed. The file
    is written; the exit is 141 (a closed pipe), quietly, not 'error: [Errno 32] Broken pipe' and 2."""
    import subprocess
    import sys

    import os

    out = tmp_path / "rec.csv"
    # as a user's shell starts it: stdout block-buffered (PYTHONUNBUFFERED unset), so that the line
    # meets the closed pipe only at the flush on the way out
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    proc = subprocess.Popen([sys.executable, "-m", "tapmuscle", "record", "--input", "const:value=5",
                             "--duration", "2", "--out", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    proc.stdout.close()  # the reader goes away before anything is printed
    stderr = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.wait(timeout=120) == 141, stderr
    assert stderr == "" and out.is_file()


@pytest.mark.skipif(not UTF8_PATHS, reason="a folder named in Greek and Japanese needs UTF-8 file names")
@pytest.mark.parametrize("encoding", ["cp1252", "cp1252:surrogateescape"])
def test_an_output_named_beyond_the_consoles_encoding_is_printed_escaped_not_an_error(tmp_path, encoding):
    """A Windows console, or its output redirected, is cp1252: a folder named "Δp" or "日本" cannot be
    printed in it, and the command must not end with "error: 'charmap' codec can't encode" and status 2 after
    writing every file. It prints such characters as escapes, as Python's stderr does."""
    import os

    out = tmp_path / "Δp 日本" / "rec.csv"
    env = {**os.environ, "PYTHONIOENCODING": encoding}  # a redirected output's under Wine: surrogateescape
    done = subprocess.run([sys.executable, "-m", "tapmuscle", "record", "--input", "const:value=5", "--duration", "2",
                           "--out", str(out), "--quiet"], capture_output=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr.decode("cp1252")
    assert f"wrote {tmp_path}{os.sep}\\u0394p \\u65e5\\u672c{os.sep}rec.csv (".encode("cp1252") in done.stdout
    assert out.is_file()


def test_a_file_names_undecodable_bytes_are_still_written_as_those_bytes():
    """Where the output had surrogateescape (a POSIX locale that is not UTF-8), a file name's bytes
    that the locale cannot decode are written back as they were; what the encoding lacks is escaped."""
    import importlib

    escaping = importlib.import_module("tapmuscle.cli.main")._ESCAPING
    assert "run\udcff Δp".encode("latin-1", errors=escaping) == b"run\xff \\u0394p"


def test_a_recording_without_a_plot_does_not_load_matplotlib(tmp_path):
    """Where HOME is not writable (a distribution's build, a CI box), importing matplotlib writes
    'mkdir -p failed ... created a temporary cache directory' to stderr: `tapmuscle record` without
    --plot must not import it, or its stderr is not empty there (the test above fails alone)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "MPLCONFIGDIR"}
    env["HOME"] = str(tmp_path / "nonexistent")
    probe = ("import sys; from tapmuscle.cli.main import main; "
             f"code = main(['record', '--input', 'const:value=5', '--duration', '2', '--out', {str(tmp_path / 'r.csv')!r}, "
             "'--quiet']); print(code, 'matplotlib' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=120)
    assert done.stdout.split()[-2:] == ["0", "False"] and done.stderr == "", (done.stdout, done.stderr)


@pytest.mark.parametrize("argv, command, unknown", [
    (["build", "--out", "fmus", "--quiet"], "build", "--quiet"),  # it shows no progress
    (["build", "--out", "fmus", "--bogus", "1"], "build", "--bogus 1"),
])
def test_an_argument_a_command_does_not_take_is_refused_by_that_command(capsys, monkeypatch, tmp_path, argv, command, unknown):
    """Not by ``tapmuscle``, whose help does not list the command's options."""
    monkeypatch.chdir(tmp_path)  # its relative outputs: a source tree may be read-only
    with pytest.raises(SystemExit) as ended:
        main(argv)
    assert ended.value.code == 2
    assert capsys.readouterr().err == (f"tapmuscle {command}: error: unrecognized arguments: {unknown} "
                                       f"(see tapmuscle {command} --help)\n")


@pytest.mark.parametrize("argv, unknown", [
    (["--quiet", "record", "--input", "const:value=5", "--duration", "1", "--out", "o.csv"], "--quiet"),
    (["--bogus", "identify", "rec.csv", "--json", "id.json"], "--bogus"),
    (["--bogus", "identify", "rec.csv", "--json", "id.json", "--quiet"], "--bogus"),  # the one before first
])
def test_an_argument_before_the_command_is_tapmuscles_to_refuse(capsys, monkeypatch, tmp_path, argv, unknown):
    """record takes --quiet after its name; given before it, it is tapmuscle's unknown argument."""
    monkeypatch.chdir(tmp_path)  # its relative outputs: a source tree may be read-only
    with pytest.raises(SystemExit) as ended:
        main(argv)
    assert ended.value.code == 2
    assert capsys.readouterr().err == f"tapmuscle: error: unrecognized arguments: {unknown} (see tapmuscle --help)\n"


def test_an_interrupt_while_the_command_line_is_read_is_said_in_one_line(monkeypatch, capsys):
    """Ctrl-C in the first second of a command (its subcommands' modules being imported to build the
    parser) must not end in a KeyboardInterrupt traceback: it gives the 'interrupted' line and 130, as a later Ctrl-C does."""
    import importlib

    cli = importlib.import_module("tapmuscle.cli.main")  # the module (tapmuscle.cli.main is also its function)

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["record", "--input", "const:value=5", "--duration", "2", "--out", "never.csv"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "tapmuscle: interrupted before anything ran; nothing is written"


def test_a_simulating_command_says_when_the_compiled_sub_step_is_missing(monkeypatch, tmp_path, capsys):
    """Installed where no C compiler is, the commands run several times slower, which must not go without a word
    (not with tapmuscle --version as the only place that says so)."""
    import fmu_plant.rosenbrock as rosenbrock

    args = ["record", "--input", "const:value=5", "--duration", "1", "--out", str(tmp_path / "r.csv")]
    monkeypatch.delenv("TAPMUSCLE_PURE_PYTHON", raising=False)
    monkeypatch.setattr(rosenbrock, "COMPILED", False)
    monkeypatch.setattr(rosenbrock, "COMPILED_FOR_ANOTHER_PYTHON", None)
    assert main(args) == 0
    err = capsys.readouterr().err
    assert err.count("note: the plant's compiled integrator sub-step is not installed (no C compiler") == 1
    assert "a plant step about 8 times slower" in err and "; install gcc and reinstall tapmuscle to have it" in err
    # the compiler a user of another system installs
    from tapmuscle.cli.main import _c_compiler

    for platform_name, compiler in (("win32", "Microsoft's C++ Build Tools"), ("darwin", "Xcode's command line tools")):
        monkeypatch.setattr(sys, "platform", platform_name)
        assert _c_compiler().startswith(compiler)
    monkeypatch.undo()
    monkeypatch.delenv("TAPMUSCLE_PURE_PYTHON", raising=False)
    for quiet, compiled, pure in ((True, False, "0"), (False, True, "0"), (False, False, "1")):
        monkeypatch.setattr(rosenbrock, "COMPILED", compiled)
        monkeypatch.setenv("TAPMUSCLE_PURE_PYTHON", pure)
        assert main(args + (["--quiet"] if quiet else [])) == 0
        assert "compiled integrator sub-step" not in capsys.readouterr().err
