"""This user's private directories: where the output locks and, when Warp's own cache is not writable, the
compiled kernels go.

A directory in a place other users can write to (the system's temporary directory) can be made by another user
first, under the name this user will look for. One that another user owns, can write to or has made a symlink
could let them hold or swap this user's locks, or replace a compiled kernel this user's next run loads and
executes. So every directory on the way is created with mode 0700 and then checked (not followed) with
``lstat``: a directory, this user's, and closed to others; anything else is refused, never repaired or used.

This module imports neither warp nor pxr.
"""

from __future__ import annotations

import os
import re
import stat
import tempfile
from pathlib import Path


def user_directory() -> tuple[Path, Path]:
    """This user's private directory, and the directory it lies in (which the system provides):
    ``$XDG_RUNTIME_DIR/warp-verlet`` (the per-user runtime directory, private and emptied at logout), else
    ``<temp dir>/warp-verlet-<user>``."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return Path(runtime) / "warp-verlet", Path(runtime)
    user = str(os.getuid()) if hasattr(os, "getuid") else re.sub(r"\W", "_", os.environ.get("USERNAME", "user"))
    temp = Path(tempfile.gettempdir())
    return temp / f"warp-verlet-{user}", temp


def not_private(info: os.stat_result) -> str | None:
    """Why a directory with this ``lstat`` is not a private directory of this user's, or None when it is."""
    if stat.S_ISLNK(info.st_mode):
        return "it is a symlink"
    if not stat.S_ISDIR(info.st_mode):
        return "it is not a directory"
    if hasattr(os, "getuid") and info.st_uid != os.getuid():
        return f"it belongs to another user (uid {info.st_uid})"
    if info.st_mode & 0o077:
        return f"it is open to other users (mode {stat.S_IMODE(info.st_mode):o})"
    return None


def make_private_directory(directory: Path, below: Path) -> str | None:
    """Create ``directory`` and every directory between ``below`` (which the system provides; created when
    missing, not checked) and it, each with mode 0700, and check each (see the module's docstring). None when
    all of them are this user's private directories, else what is wrong, naming the directory. Raises the
    OSError of a directory that cannot be created."""
    directory, below = Path(directory), Path(below)
    parts = directory.relative_to(below).parts  # ValueError when it is not inside: a caller's mistake
    below.mkdir(mode=0o700, parents=True, exist_ok=True)
    current = below
    for part in parts:
        current = current / part
        try:
            current.mkdir(mode=0o700)
        except FileExistsError:
            pass  # checked below, whoever made it
        problem = not_private(os.lstat(current))
        if problem is not None:
            return f"{current} is not a private directory of this user's ({problem})"
    return None
