"""Atomic outputs (tapmuscle/io/atomic.py): whole or nothing, and the user's umask."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

import matplotlib.pyplot as plt
import pytest

from tapmuscle.io.atomic import atomic_path, staged_folder, probe_output_folder
from tapmuscle.io.recording import atomic_write_text
from tapmuscle.plots.figures import save_figure


@pytest.fixture
def umask():
    old = os.umask(0o022)
    os.umask(old)

    def set_mask(mask: int) -> None:
        os.umask(mask)
    yield set_mask
    os.umask(old)


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_outputs_get_the_users_umask(tmp_path, umask, mask, mode):
    umask(mask)
    atomic_write_text(tmp_path / "a.json", "{}\n")
    fig = plt.figure()
    save_figure(fig, tmp_path / "b.png")
    for name in ("a.json", "b.png"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == mode, name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.png"]  # no temporary left


def test_a_failure_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["out.csv"]


def test_a_directory_as_target_is_refused_by_name(tmp_path):
    (tmp_path / "out").mkdir()
    with pytest.raises(IsADirectoryError, match="out is a directory"):
        atomic_write_text(tmp_path / "out", "x")
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_a_full_disk_names_what_was_being_written_and_keeps_the_old(tmp_path, monkeypatch):
    """A write that fails for want of room raises an OSError that names no file (``[Errno 28] No
    space left on device``): the file, or the output folder of a staged run, is named; the old
    content stays and nothing temporary is left."""
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(OSError, match=r"\[Errno 28\] No space left on device: '.*out\.csv'") as caught:
        with atomic_path(target):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as a write() on a full disk
    assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(target)
    assert target.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["out.csv"]
    out = tmp_path / "run"
    for inside, shown in ((False, out), (True, out / "fig" / "a.png")):  # not the hidden staging folder
        with pytest.raises(OSError, match="No space left on device") as caught:
            with staged_folder(out) as tmp:
                (tmp / "result.csv").write_text("half")
                if inside:
                    with atomic_path(tmp / "fig" / "a.png"):
                        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        assert caught.value.filename == str(shown)
        assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["out.csv"]
    # a full disk elsewhere (an FMU's extraction folder) keeps its own name; a file in the staging folder
    # named by its absolute path, for an output folder given relative, is named in the output folder
    monkeypatch.chdir(tmp_path)
    for raised, shown in (("/elsewhere/x.so", "/elsewhere/x.so"), (None, "rel")):
        with pytest.raises(OSError, match="No space left on device") as caught:
            with staged_folder("rel") as tmp:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC),
                              raised or os.path.abspath(os.path.join(tmp, "a.csv")))
        assert caught.value.filename == (shown if raised else os.path.join("rel", "a.csv"))
    with pytest.raises(FileNotFoundError, match="elsewhere") as other:  # an error naming its own file is kept
        with atomic_path(target):
            raise FileNotFoundError(errno.ENOENT, "no such file", "elsewhere")
    assert other.value.filename == "elsewhere"


def _run_into(out, files, fail=False, owned=None):
    with staged_folder(out, owned=owned) as tmp:
        for name, text in files.items():
            atomic_write_text(tmp / name, text)
        if fail:
            raise RuntimeError("a figure failed")


def test_a_staged_folder_appears_whole_or_not_at_all(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        _run_into(out, {"a.json": "1"}, fail=True, owned=("*.json",))
    assert not out.exists() and list(tmp_path.iterdir()) == []
    _run_into(out, {"a.json": "1", "b.png": "x"}, owned=("*.json", "*.png"))
    with pytest.raises(RuntimeError):
        _run_into(out, {"a.json": "2"}, fail=True, owned=("*.json", "*.png"))
    assert (out / "a.json").read_text() == "1" and (out / "b.png").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging folder left


def test_a_ctrl_c_in_the_staging_folders_removal_leaves_no_folder(tmp_path, monkeypatch, python_sigint_handler):
    """A Ctrl-C held down: the first interrupt stops the run, the next lands in the removal of the
    staging folder (here sent from inside it), which is finished; the first is what the caller gets."""
    import shutil
    import signal

    from tapmuscle.io import atomic

    real = shutil.rmtree

    def interrupted(path, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)  # Python runs the handler before the next line
        real(path, *args, **kwargs)

    monkeypatch.setattr(atomic.shutil, "rmtree", interrupted)
    out = tmp_path / "out"
    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt) as stopped:
        with staged_folder(out, owned=("*.json",)) as tmp:
            (tmp / "a.json").write_text("1")
            raise KeyboardInterrupt("the run's")
    assert str(stopped.value) == "the run's" and list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGINT) is handler


def test_a_staged_folder_removes_what_the_earlier_run_owned_and_keeps_the_rest(tmp_path):
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.png": "x", "exp_2.csv": "e"}, owned=("*.json", "*.png", "exp*.csv"))
    (out / "notes.txt").write_text("mine")
    _run_into(out, {"a.json": "2"}, owned=("*.json", "*.png", "exp*.csv"))
    assert sorted(p.name for p in out.iterdir()) == ["a.json", "notes.txt"]
    assert (out / "a.json").read_text() == "2"


def test_a_directory_in_a_files_place_fails_before_anything_changes(tmp_path):
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1"}, owned=("*.json", "*.md"))
    (out / "report.md").mkdir()
    with pytest.raises(IsADirectoryError, match="report.md is a directory"):
        _run_into(out, {"a.json": "2", "report.md": "r"}, owned=("*.json", "*.md"))
    assert (out / "a.json").read_text() == "1"


def test_without_owned_patterns_the_folder_is_replaced_whole(tmp_path):
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.json": "1"})
    _run_into(out, {"a.json": "2"})
    assert sorted(p.name for p in out.iterdir()) == ["a.json"]
    with pytest.raises(NotADirectoryError, match="is a file"):
        _run_into(out / "a.json", {"x": "1"})


def _held_open(monkeypatch, *held: Path, staged: str | None = None) -> None:
    """Renames as Windows does them while another program (a spreadsheet, an image viewer) holds the
    files ``held`` open: such a file can be neither moved nor replaced, nor a folder holding it
    (``_target`` cannot see it: the file is writable). ``staged``: a staged file of that name cannot
    be moved either."""
    from tapmuscle.io import atomic

    real_replace, real_rename = os.replace, os.rename
    inodes = {os.stat(p).st_ino for p in held}

    def is_held(path) -> bool:
        return os.path.lexists(path) and os.stat(path).st_ino in inodes

    def replace(src, dst, **kw):
        if is_held(src) or is_held(dst) or (staged is not None and os.path.basename(src) == staged
                                            and os.path.basename(os.path.dirname(src)).startswith(".out.")):
            raise PermissionError(errno.EACCES, "Access is denied", os.fspath(src), None, os.fspath(dst))
        return real_replace(src, dst, **kw)

    def rename(src, dst, **kw):
        if os.path.isdir(src) and any(is_held(os.path.join(src, name)) for name in os.listdir(src)):
            raise PermissionError(errno.EACCES, "Access is denied", os.fspath(src), None, os.fspath(dst))
        return real_rename(src, dst, **kw)

    monkeypatch.setattr(atomic.os, "replace", replace)
    monkeypatch.setattr(atomic.os, "rename", rename)


OWNED = ("*.json", "*.png", "exp*.csv")


@pytest.mark.parametrize("held", ["b.png", "exp_2.csv", "a.json"])
def test_a_file_held_open_leaves_the_earlier_run_whole_and_is_named(tmp_path, monkeypatch, held):
    """On Windows a file another program holds open can be neither replaced nor moved, and nothing
    tells before the rename: the files moved until then go back, so the folder holds the earlier
    run whole (a figure of each run, a summary of the other, before), not a mix of two."""
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.png": "x", "exp_2.csv": "e"}, owned=OWNED)
    (out / "notes.txt").write_text("mine")
    _held_open(monkeypatch, out / held)
    with pytest.raises(PermissionError, match=rf"{out / held} could not be replaced \(Access is denied; on Windows a "
                                              rf"file that another program holds open.*close it and run again; {out} "
                                              "is left as it was"):
        _run_into(out, {"a.json": "2", "b.png": "y", "c.png": "new"}, owned=OWNED)
    assert {p.name: p.read_text() for p in out.iterdir()} == {"a.json": "1", "b.png": "x", "exp_2.csv": "e",
                                                               "notes.txt": "mine"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging or set-aside folder left


def test_a_new_file_failing_half_way_puts_back_the_files_already_replaced(tmp_path, monkeypatch):
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.png": "x"}, owned=OWNED)
    _held_open(monkeypatch, staged="c.png")  # the files are renamed in name order: a, b, then c fails
    with pytest.raises(PermissionError, match="c.png could not be replaced"):
        _run_into(out, {"a.json": "2", "b.png": "y", "c.png": "new"}, owned=OWNED)
    assert {p.name: p.read_text() for p in out.iterdir()} == {"a.json": "1", "b.png": "x"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_folder_replaced_whole_while_a_file_in_it_is_held_open_is_kept(tmp_path, monkeypatch):
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1"})
    _held_open(monkeypatch, out / "a.json")
    with pytest.raises(PermissionError, match=f"{out} could not be replaced .*close it and run again"):
        _run_into(out, {"a.json": "2"})
    assert (out / "a.json").read_text() == "1" and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.mark.parametrize("owned", [OWNED, None])
def test_a_ctrl_c_while_the_files_are_put_in_place_is_raised_once_they_are(tmp_path, monkeypatch, owned,
                                                                          python_sigint_handler):
    """An interrupt between moving a file aside and recording it would lose the file: Ctrl-C is held
    until the run's files are in place (or the earlier ones back), then raised."""
    import signal

    from tapmuscle.io import atomic

    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.png": "x"}, owned=owned)
    real_replace, real_rename = os.replace, os.rename

    def replace(src, dst, **kw):
        real_replace(src, dst, **kw)
        if Path(src) == out / "a.json":  # moved aside
            os.kill(os.getpid(), signal.SIGINT)

    def rename(src, dst, **kw):
        real_rename(src, dst, **kw)
        if Path(src) == out:  # the whole folder moved aside
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(atomic.os, "replace", replace)
    monkeypatch.setattr(atomic.os, "rename", rename)
    with pytest.raises(KeyboardInterrupt):
        _run_into(out, {"a.json": "2", "b.png": "y"}, owned=owned)
    monkeypatch.undo()
    assert {p.name: p.read_text() for p in out.iterdir()} == {"a.json": "2", "b.png": "y"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing set aside or staged is left


def test_an_earlier_file_that_cannot_be_put_back_is_kept_and_named(tmp_path, monkeypatch):
    from tapmuscle.io import atomic

    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.png": "x"}, owned=OWNED)
    real = os.replace

    def replace(src, dst, **kw):  # the run's b.png refused, then a.json's earlier version too
        if Path(dst) == out / "b.png" and ".replaced." not in str(src) \
                or Path(dst) == out / "a.json" and ".replaced." in str(src):
            raise PermissionError(errno.EACCES, "Access is denied")
        return real(src, dst, **kw)

    monkeypatch.setattr(atomic.os, "replace", replace)
    with pytest.raises(OSError, match=rf"{out / 'b.png'} could not be replaced \(.*\), and putting back the "
                                      rf"earlier outputs failed: {out / 'a.json'} is the new run's or missing "
                                      r"\(Access is denied\); its earlier version is .*\.out\.replaced\.\w+/0$") as err:
        _run_into(out, {"a.json": "2", "b.png": "y"}, owned=OWNED)
    monkeypatch.undo()
    kept = Path(str(err.value).rsplit(" ", 1)[1])
    assert kept.read_text() == "1" and (out / "b.png").read_text() == "x" and (out / "a.json").read_text() == "2"


def test_a_link_to_a_file_the_run_no_longer_writes_keeps_its_target(tmp_path):
    """``x.png`` a link to ``b.png``, which this run does not write: the run's x.png goes into b.png,
    which therefore is not removed as stale (that left the link dangling)."""
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.png": "old"}, owned=OWNED)
    (out / "x.png").symlink_to("b.png")
    _run_into(out, {"x.png": "new"}, owned=OWNED)
    assert (out / "x.png").is_symlink() and (out / "x.png").read_text() == "new"
    assert sorted(p.name for p in out.iterdir()) == ["b.png", "x.png"]


def test_a_single_file_held_open_is_named_and_kept(tmp_path, monkeypatch):
    held = tmp_path / "rec.csv"
    held.write_text("old")
    _held_open(monkeypatch, held)
    with pytest.raises(PermissionError, match=rf"{held} could not be replaced \(Access is denied; on Windows .*"
                                              rf"close it and run again; {held} is left as it was"):
        atomic_write_text(held, "new")
    assert held.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv"]


def _not_writable(monkeypatch, *paths) -> None:
    """chmod 0444; under root, which may write any file, ``os.access`` answers as for another user."""
    for p in paths:
        p.chmod(0o444)
    if os.geteuid() == 0:
        real = os.access
        denied = {os.path.realpath(p) for p in paths}
        monkeypatch.setattr(os, "access", lambda p, mode, **kw: (not mode & os.W_OK or os.path.realpath(p) not in denied)
                            and real(p, mode, **kw))


def test_a_write_leaves_what_open_would_an_existing_files_mode_and_a_links_target(tmp_path):
    """As ``open(path, "w")``: an existing file keeps its mode (0640 stays 0640), and a symbolic link is
    followed: its target gets the content, the link stays a link."""
    kept = tmp_path / "kept.csv"
    kept.write_text("old")
    kept.chmod(0o640)
    atomic_write_text(kept, "new")
    assert kept.read_text() == "new" and stat.S_IMODE(kept.stat().st_mode) == 0o640
    (tmp_path / "elsewhere").mkdir()
    real = tmp_path / "elsewhere" / "real.csv"
    real.write_text("old")
    link = tmp_path / "link.csv"
    link.symlink_to(real)
    atomic_write_text(link, "new")
    assert link.is_symlink() and real.read_text() == "new"
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1"}, owned=("*.json",))
    (out / "a.json").unlink()
    (out / "a.json").symlink_to(real)
    _run_into(out, {"a.json": "2"}, owned=("*.json",))
    assert (out / "a.json").is_symlink() and real.read_text() == "2"
    assert sorted(p.name for p in (tmp_path / "elsewhere").iterdir()) == ["real.csv"]  # no temporary left


def test_a_read_only_file_is_refused_before_the_work_and_kept(tmp_path, monkeypatch):
    ro = tmp_path / "ro.csv"
    ro.write_text("keep")
    out = tmp_path / "out"
    _run_into(out, {"a.json": "1", "b.json": "1"}, owned=("*.json",))
    _not_writable(monkeypatch, ro, out / "b.json")
    ran = []
    with pytest.raises(PermissionError, match="ro.csv is read-only: not replaced"):
        with atomic_path(ro) as tmp:
            ran.append(tmp)
    assert ran == [] and ro.read_text() == "keep" and stat.S_IMODE(ro.stat().st_mode) == 0o444
    with pytest.raises(PermissionError, match="b.json is read-only"):
        _run_into(out, {"a.json": "2", "b.json": "2"}, owned=("*.json",))
    assert (out / "a.json").read_text() == "1" and (out / "b.json").read_text() == "1"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "ro.csv"]


@pytest.fixture
def unwritable_folder(tmp_path):
    """A folder nothing can be written into: mode 0555, or immutable under root (whom modes do not stop)."""
    import shutil
    import subprocess

    folder = tmp_path / "locked"
    (folder / "out").mkdir(parents=True)
    if os.geteuid() != 0:
        folder.chmod(0o555)
        (folder / "out").chmod(0o555)
        yield folder
        (folder / "out").chmod(0o755)
        folder.chmod(0o755)
        return
    if shutil.which("chattr") is None:
        pytest.skip("chattr (e2fsprogs) not found: root writes any folder without it")
    if subprocess.run(["chattr", "+i", str(folder / "out"), str(folder)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i is not permitted here (no CAP_LINUX_IMMUTABLE): root writes any folder")
    try:
        yield folder
    finally:
        subprocess.run(["chattr", "-i", str(folder / "out"), str(folder)], check=True)


def test_an_output_folder_that_cannot_be_written_is_named_before_the_work(unwritable_folder, monkeypatch):
    """A diagnosis of a long recording must not run for minutes to fail on its last rename, naming a
    hidden staging folder."""
    from tapmuscle.diagnosis import report

    with pytest.raises(PermissionError, match=r"locked/out: the outputs cannot be written there \(.+\); choose another"):
        probe_output_folder(unwritable_folder / "out")
    with pytest.raises(PermissionError, match=r"locked/new: the outputs cannot be written there"):
        probe_output_folder(unwritable_folder / "new")

    def no_work(*args, **kwargs):
        raise AssertionError("the diagnosis ran")

    monkeypatch.setattr(report, "diagnose", no_work)
    monkeypatch.setattr(report, "read_recording", lambda path: None)
    monkeypatch.setattr(report, "load_plant", lambda path: (None, "file"))
    with pytest.raises(PermissionError, match="locked/out: the outputs cannot be written there"):
        report.diagnose_files("rec.csv", "plant.json", unwritable_folder / "out")
    assert [p.name for p in unwritable_folder.iterdir()] == ["out"] and not any((unwritable_folder / "out").iterdir())


def test_a_name_the_file_system_encoding_could_not_decode_is_written_as_its_bytes(tmp_path):
    """Under an ASCII locale with PYTHONUTF8=0 a folder "rig ü" reads as "rig \\udcc3\\udcbc": a
    recording's header naming it failed with "surrogates not allowed" after the whole run."""
    name = b"rig \xc3\xbc".decode("ascii", "surrogateescape")
    atomic_write_text(tmp_path / "r.csv", f"# source: {name}/s.toml\n")
    assert (tmp_path / "r.csv").read_bytes() == "# source: rig ü/s.toml\n".encode()


needs_root = pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0,
                                reason="a link of another user's is made with lchown, as root")


def _their_link(link, target):
    """A link to ``target`` that another user (nobody, uid 65534) made, in a folder others may write."""
    os.symlink(target, link)
    os.lchown(link, 65534, 65534)
    return link


@needs_root
def test_an_output_is_not_written_through_a_link_another_user_made(tmp_path):
    """In a shared folder another user links the output's name to this user's file, or the output
    folder's name to this user's folder, or a folder on the way: nothing is written or replaced
    there; the link is named with its owner. A link of this user's own is still followed."""
    from tapmuscle.io.atomic import atomic_path, staged_folder

    mine = tmp_path / "home"
    mine.mkdir()
    (mine / "precious.txt").write_text("mine")
    (mine / "thesis").mkdir()
    (mine / "thesis" / "thesis.tex").write_text("mine")
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o777)
    _their_link(shared / "rec.csv", mine / "precious.txt")
    with pytest.raises(PermissionError, match=r"rec.csv is a link that another user \(uid 65534\) made"):
        with atomic_path(shared / "rec.csv") as tmp:
            tmp.write_text("output")
    _their_link(shared / "diag", mine / "thesis")
    for owned in (None, ("report.md",)):
        with pytest.raises(PermissionError, match=r"diag is a link that another user \(uid 65534\) made"):
            with staged_folder(shared / "diag", owned=owned) as tmp:
                (tmp / "report.md").write_text("output")
    (shared / "run").mkdir()
    _their_link(shared / "run" / "summary.json", mine / "precious.txt")
    with pytest.raises(PermissionError, match=r"summary.json is a link that another user \(uid 65534\) made"):
        with staged_folder(shared / "run", owned=("summary.json",)) as tmp:
            (tmp / "summary.json").write_text("output")
    _their_link(shared / "via", mine)  # a folder on the way
    with pytest.raises(PermissionError, match=r"via is a link that another user \(uid 65534\) made"):
        with atomic_path(shared / "via" / "new.csv") as tmp:
            tmp.write_text("output")
    assert (mine / "precious.txt").read_text() == "mine" and not (mine / "new.csv").exists()
    assert sorted(p.name for p in (mine / "thesis").iterdir()) == ["thesis.tex"]
    # a colleague's link in a folder of theirs no one else may write (a volume of the host user's
    # mounted in a container run as root) is theirs to make: followed
    colleague = tmp_path / "colleague"
    colleague.mkdir(mode=0o755)
    os.chown(colleague, 65534, 65534)
    _their_link(colleague / "results", mine / "thesis")
    with atomic_path(colleague / "results" / "new.csv") as tmp:
        tmp.write_text("output")
    assert (mine / "thesis" / "new.csv").read_text() == "output"
    # nor in one of theirs that their group may write (every folder of a user's under a umask of 002)
    os.chmod(colleague, 0o775)
    with atomic_path(colleague / "results" / "group.csv") as tmp:
        tmp.write_text("output")
    assert (mine / "thesis" / "group.csv").is_file()
    # this user's own link is theirs to follow
    os.symlink(mine / "precious.txt", shared / "own.csv")
    with atomic_path(shared / "own.csv") as tmp:
        tmp.write_text("output")
    assert (mine / "precious.txt").read_text() == "output" and (shared / "own.csv").is_symlink()


def test_the_path_followed_is_the_one_the_kernel_resolves(tmp_path):
    """On trees of this user's own links (absolute, relative, chains, targets with ``..``, dangling) and
    paths with ``..`` after a link, :func:`followed` is ``os.path.realpath``: the path checked is the
    path written. Seeded; also deep paths with no link (no limit on a path's parts, only on links)."""
    import errno
    import random

    from tapmuscle.io.atomic import followed

    rng = random.Random(3)
    root = tmp_path / "tree"
    folders = [root]
    root.mkdir()
    for i in range(12):
        folder = rng.choice(folders) / f"d{i}"
        folder.mkdir()
        folders.append(folder)
    links = []
    for i in range(25):
        where = rng.choice(folders)
        target = rng.choice(folders + links + [root / "missing"]) if links else rng.choice(folders)
        text = os.path.relpath(target, where) if rng.random() < 0.5 else str(target)
        if rng.random() < 0.2:
            text = os.path.join(text, "..")
        link = where / f"l{i}"
        os.symlink(text, link)
        links.append(link)
    queries = []
    for _ in range(300):
        parts = [str(rng.choice(folders + links))]
        for _ in range(rng.randint(0, 3)):
            parts.append(rng.choice(["..", ".", "x.csv", f"l{rng.randrange(25)}", f"d{rng.randrange(12)}"]))
        queries.append(os.path.join(*parts))
    for query in queries:
        try:
            expected = os.path.realpath(query, strict=False)
        except OSError:
            continue
        try:
            got = followed(query)
        except OSError as exc:  # a loop of links: the kernel refuses it too
            assert exc.errno == errno.ELOOP, (query, exc)
            continue
        assert str(got) == expected, query
    deep = tmp_path.joinpath(*["a"] * 300, "x.csv")
    assert followed(deep) == deep
