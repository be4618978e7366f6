"""The FMU files a sweep ships to its workers (tapmuscle/cosim/distributed_sweep.py): each worker
writes them into a folder of the temporary directory whose name is predictable, so that folder must
be the user's own and closed to others before an FMU there is trusted."""

from __future__ import annotations

import getpass
import hashlib
import os
import stat
import sys

import pytest

from tapmuscle.cosim import distributed_sweep
from tapmuscle.cosim.distributed_sweep import FmuFiles

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX owners and modes; Windows' TEMP is per user")

CONTENT = b"PK\x03\x04 an FMU's bytes"
DIGEST = hashlib.sha256(CONTENT).hexdigest()


@pytest.fixture
def files(tmp_path, monkeypatch):
    """The FMU files of a sweep, and the folder they go to under a temporary directory of the test's."""
    monkeypatch.setattr(distributed_sweep.tempfile, "gettempdir", lambda: str(tmp_path))
    monkeypatch.setattr(distributed_sweep, "_WRITTEN", {})
    return FmuFiles({DIGEST: CONTENT}, {DIGEST: "MusclePlant.fmu"}), tmp_path / f"tapmuscle-fmus-{getpass.getuser()}"


def test_the_files_go_into_a_folder_only_this_user_may_enter(files):
    shipped, root = files
    path = shipped.path(DIGEST, use_local=False)
    assert path == root / DIGEST / "MusclePlant.fmu" and path.read_bytes() == CONTENT
    for folder in (root, root / DIGEST):
        st = os.lstat(folder)
        assert stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and st.st_mode & 0o077 == 0, oct(st.st_mode)
    # an earlier release's folders, made with the umask's mode (0775 under a umask of 002): closed to others
    for folder in (root, root / DIGEST):
        os.chmod(folder, 0o775)
    distributed_sweep._WRITTEN.clear()
    assert shipped.path(DIGEST, use_local=False).read_bytes() == CONTENT
    assert [os.lstat(folder).st_mode & 0o777 for folder in (root, root / DIGEST)] == [0o700, 0o700]


@pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0, reason="another user's link is made with lchown, as root")
def test_a_folder_another_user_could_redirect_is_refused(files, tmp_path):
    """Another local user who put a link in the folder's place, or in place of an FMU's own folder,
    could swap the checked FMU for one whose code runs as this user: refused, naming the folder and
    what to do, and nothing is written where the link points. A link of this user's own is followed."""
    shipped, root = files
    elsewhere = tmp_path / "theirs"
    elsewhere.mkdir()
    root.symlink_to(elsewhere)
    os.lchown(root, 65534, 65534)
    with pytest.raises(PermissionError, match=rf"FMU folder {root} is a link another user \(uid 65534\) made: .* "
                                              r"set TMPDIR to a folder of your own"):
        shipped.path(DIGEST, use_local=False)
    root.unlink()
    root.mkdir(mode=0o700)
    (root / DIGEST).symlink_to(elsewhere)
    os.lchown(root / DIGEST, 65534, 65534)
    with pytest.raises(PermissionError, match=rf"{root / DIGEST} is a link another user"):
        shipped.path(DIGEST, use_local=False)
    assert list(elsewhere.iterdir()) == []
    (root / DIGEST).unlink()
    (root / DIGEST).symlink_to(elsewhere)  # this user's own
    assert shipped.path(DIGEST, use_local=False).read_bytes() == CONTENT and (elsewhere / "MusclePlant.fmu").is_file()


@pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0, reason="giving a folder to another user needs root")
def test_a_folder_of_another_users_is_refused(files):
    shipped, root = files
    root.mkdir(mode=0o700)
    os.chown(root, 65534, -1)  # nobody's
    with pytest.raises(PermissionError, match=rf"{root} belongs to another user \(uid 65534\)"):
        shipped.path(DIGEST, use_local=False)


@pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0, reason="giving a file to another user needs root")
def test_an_fmu_file_another_user_left_is_replaced_by_ones_own(files):
    """The right bytes, but another user's file (left while the folder was open to others): replaced,
    so that no one else can write to the file that runs."""
    shipped, root = files
    (root / DIGEST).mkdir(parents=True, mode=0o700)
    theirs = root / DIGEST / "MusclePlant.fmu"
    theirs.write_bytes(CONTENT)
    os.chown(theirs, 65534, -1)
    path = shipped.path(DIGEST, use_local=False)
    assert path == theirs and path.read_bytes() == CONTENT and path.stat().st_uid == os.getuid()


def test_a_link_left_in_place_of_an_fmu_is_removed_not_written_through(files, tmp_path):
    """A link in the FMU's place (to a file of this user's), left while the folder was open to
    others: the link goes, the FMU is written as a file, the linked file is untouched."""
    shipped, root = files
    (root / DIGEST).mkdir(parents=True, mode=0o700)
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    (root / DIGEST / "MusclePlant.fmu").symlink_to(notes)
    path = shipped.path(DIGEST, use_local=False)
    assert not path.is_symlink() and path.read_bytes() == CONTENT and notes.read_text() == "mine"
