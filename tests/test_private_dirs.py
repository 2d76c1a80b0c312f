"""Every private directory is private (private_dir.py), tried as two users: another user who makes the kernel-cache
fallback or the lock directory first, open to all, private to them, or as a symlink, gets it refused, and
nothing of this user's is written into it. Needs root to act as a second user (CI runs as root)."""

from __future__ import annotations

import os
import shutil
import stat
import tempfile
from pathlib import Path

import pytest

from warp_verlet.output import output_file

from warp_verlet.core import warp_setup
from warp_verlet.errors import OutputError, WarpVerletError

OTHER_UID = OTHER_GID = 65534  # "nobody"

needs_two_users = pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0,
                                     reason="acting as a second user needs root (os.setuid)")


def as_other_user(work) -> None:
    """Run ``work()`` in a forked child as the other user; fail here when it raised."""
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        code = 1
        try:
            os.setgid(OTHER_GID)
            os.setuid(OTHER_UID)
            work()
            code = 0
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0, "the other user's part failed"


@pytest.fixture
def shared_temp(monkeypatch):
    """A system temporary directory as /tmp is: everybody may create in it (sticky, 1777); no runtime
    directory, so the private directory goes there. In the real one (pytest's own are closed to others)."""
    temp = Path(tempfile.mkdtemp(prefix="warp-verlet-two-users-"))
    temp.chmod(0o1777)
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    yield temp
    shutil.rmtree(temp)


@pytest.fixture
def default_not_writable(shared_temp, monkeypatch):
    """Warp's own cache directory cannot be created (HOME's .cache is a file), and nothing else was chosen."""
    import warp as wp

    blocked = shared_temp / "file"
    blocked.write_text("HOME's .cache is a file here")
    monkeypatch.setattr(wp.config, "kernel_cache_dir", None)
    monkeypatch.delenv("WARP_CACHE_PATH", raising=False)
    monkeypatch.setattr(warp_setup, "_default_cache_dir", lambda version: blocked / "warp" / version)


def plant(path: Path, mode: int | None = None, link_to: Path | None = None):
    """The other user's part: make every missing directory of ``path`` first (with ``mode``), or make ``path``
    a symlink to a directory of theirs."""
    def work():
        if link_to is not None:
            link_to.mkdir(mode=0o777)
            os.chmod(link_to, 0o777)
            os.symlink(link_to, path)
            return
        os.makedirs(path)
        current = path
        while current != Path(tempfile.gettempdir()):
            os.chmod(current, mode)
            current = current.parent
    as_other_user(work)


def kernel_fallback_is_refused(trap: Path) -> str:
    """ensure_kernel_cache must refuse the fallback; Warp's directory stays unset and ``trap`` stays empty."""
    import warp as wp

    with pytest.raises(WarpVerletError) as caught:
        warp_setup.ensure_kernel_cache(lambda text: None)
    assert wp.config.kernel_cache_dir is None
    assert list(trap.iterdir()) == []
    return str(caught.value)


@needs_two_users
@pytest.mark.parametrize("mode", [0o777, 0o700], ids=["open-to-all", "private-to-them"])
def test_a_kernel_fallback_another_user_made_first_is_refused(shared_temp, default_not_writable, mode):
    fallback = warp_setup.fallback_cache_dir()
    plant(fallback, mode)
    message = kernel_fallback_is_refused(fallback)
    assert "is not a private directory of this user's (it belongs to another user (uid 65534))" in message
    assert message.endswith("set WARP_CACHE_PATH to a directory this user can write")


@needs_two_users
def test_a_kernel_fallback_that_is_another_users_symlink_is_refused(shared_temp, default_not_writable):
    fallback = warp_setup.fallback_cache_dir()
    first_missing = fallback
    while first_missing.parent != shared_temp:
        first_missing = first_missing.parent
    theirs = shared_temp / "theirs"
    plant(first_missing, link_to=theirs)
    message = kernel_fallback_is_refused(theirs)
    assert f"{first_missing} is not a private directory of this user's (it is a symlink)" in message


@needs_two_users
def test_a_fresh_kernel_fallback_is_private_and_closed_to_the_other_user(shared_temp, default_not_writable):
    import warp as wp

    notes = []
    warp_setup.ensure_kernel_cache(notes.append)
    fallback = warp_setup.fallback_cache_dir()
    assert wp.config.kernel_cache_dir == str(fallback) and len(notes) == 1
    current = fallback
    while current != shared_temp:  # every directory made on the way: this user's, mode 0700
        info = os.lstat(current)
        assert stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and stat.S_IMODE(info.st_mode) == 0o700
        current = current.parent

    def try_to_swap_a_kernel():
        try:
            (fallback / "kernel.o").write_bytes(b"not ours")
        except PermissionError:
            return
        raise AssertionError("the other user could write into the kernel cache")
    as_other_user(try_to_swap_a_kernel)
    assert list(fallback.iterdir()) == []


@needs_two_users
def test_a_lock_directory_another_user_made_first_is_refused(shared_temp):
    from warp_verlet.private_dir import user_directory

    directory = user_directory()[0]
    plant(directory, 0o700)
    with pytest.raises(OutputError, match=r"is not a private directory of this user's \(it belongs to another user"):
        output_file.lock_directory()
    assert list(directory.iterdir()) == []
