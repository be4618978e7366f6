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
    # an earlier release's folder (mode 0755 from the umask): nobody else can write into it
    os.chmod(root, 0o755)
    distributed_sweep._WRITTEN.clear()
    assert shipped.path(DIGEST, use_local=False).read_bytes() == CONTENT


def test_a_folder_another_user_could_write_into_or_redirect_is_refused(files, tmp_path):
    """Another local user who made the folder open to all, or put a link in its place or in place of
    an FMU's own folder, could swap the checked FMU for one whose code runs as this user: refused,
    naming the folder, and nothing is written there."""
    shipped, root = files
    root.mkdir(mode=0o777)
    os.chmod(root, 0o777)
    with pytest.raises(PermissionError, match=rf"FMU folder {root} may be written by other users: .* TMPDIR"):
        shipped.path(DIGEST, use_local=False)
    assert list(root.iterdir()) == []
    root.rmdir()
    elsewhere = tmp_path / "theirs"
    elsewhere.mkdir()
    root.symlink_to(elsewhere)
    with pytest.raises(PermissionError, match=rf"{root} is a link"):
        shipped.path(DIGEST, use_local=False)
    root.unlink()
    root.mkdir(mode=0o700)
    (root / DIGEST).symlink_to(elsewhere)
    with pytest.raises(PermissionError, match=rf"{root / DIGEST} is a link"):
        shipped.path(DIGEST, use_local=False)
    assert list(elsewhere.iterdir()) == []


@pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0, reason="giving a folder to another user needs root")
def test_a_folder_of_another_users_is_refused(files):
    shipped, root = files
    root.mkdir(mode=0o700)
    os.chown(root, 65534, -1)  # nobody's
    with pytest.raises(PermissionError, match=rf"{root} belongs to another user \(uid 65534\)"):
        shipped.path(DIGEST, use_local=False)
