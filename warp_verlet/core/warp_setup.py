"""Warp's start-up: a kernel cache it can write to, and no CUDA-driver warning on a CPU run.

Warp compiles kernels into a cache directory (``~/.cache/warp/<version>`` on Linux) and fails with a bare
``PermissionError`` when it cannot create it, for example when HOME is not writable. :func:`ensure_kernel_cache`
checks first: when the default is not writable it uses ``kernels`` in this user's private directory instead
(with a note; private_dir.py: created 0700, and refused when another user made it first, when it is a symlink
or open to others), and when an explicitly chosen one (``WARP_CACHE_PATH`` or
``warp.config.kernel_cache_dir``) is not writable it raises one clear :class:`WarpVerletError`.

On a machine without an NVIDIA driver, Warp's native library prints "Warp CUDA warning: Could not find or load
the NVIDIA CUDA driver" to the process's stderr when it starts. On a CPU run that is noise, and so it is in each
worker of a sweep: :func:`start_warp` filters that one line out (the command line shows it again with ``-v``).
On a run that asked for CUDA it is the reason the run cannot go on, and it becomes one ``note:`` line in the
project's words before the error that says no CUDA device is available.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path
from typing import Callable, Iterator

from ..errors import WarpVerletError
from ..private_dir import make_private_directory, user_directory

CUDA_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"


def _not_writable(path: Path) -> str | None:
    """None when files can be created in ``path`` (created if missing), else why not."""
    try:
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
        fd, name = tempfile.mkstemp(dir=path, prefix=".warp-verlet-probe-")
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


def _default_cache_dir(version: str) -> Path:
    """Where Warp puts its kernel cache when nobody chose: its own choice (appdirs) where it can be asked."""
    try:
        from warp._src.thirdparty import appdirs  # Warp's own choice of the user cache directory

        return Path(appdirs.user_cache_dir(appname="warp", appauthor="NVIDIA", version=version))
    except Exception:  # pragma: no cover - a Warp without that module: the XDG default
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        return Path(base) / "warp" / version


def fallback_cache_dir() -> Path:
    """Where kernels go when Warp's default cache is not writable: ``kernels`` in this user's private directory
    (private_dir.user_directory), which only this user can write, so that no other user can swap a compiled
    kernel this user's runs load."""
    return user_directory()[0] / "kernels"


def ensure_kernel_cache(note: Callable[[str], None] | None = None) -> None:
    """Make sure Warp can write its kernel cache before it starts (see the module's docstring)."""
    import warp as wp

    chosen = wp.config.kernel_cache_dir or os.environ.get("WARP_CACHE_PATH")
    if chosen:
        problem = _not_writable(Path(chosen))
        if problem is not None:
            how = "WARP_CACHE_PATH" if not wp.config.kernel_cache_dir else "warp.config.kernel_cache_dir"
            raise WarpVerletError(f"Warp's kernel cache directory {chosen} (from {how}) is not writable "
                                  f"({problem}): set {how} to a directory this user can write")
        return
    default = _default_cache_dir(wp.config.version)
    problem = _not_writable(default)
    if problem is None:
        return
    fallback = fallback_cache_dir()
    directory, below = user_directory()
    # Every directory from the system's one down to the fallback must be private; a fallback outside this user's
    # directory (fallback_cache_dir replaced) is checked from its own parent on.
    try:
        unusable = make_private_directory(fallback, below if fallback.is_relative_to(directory) else fallback.parent)
    except OSError as exc:
        unusable = exc.strerror or str(exc)
    unusable = unusable or _not_writable(fallback)
    if unusable is None:
        wp.config.kernel_cache_dir = str(fallback)
        if note is not None:
            note(f"Warp's kernel cache directory {default} is not writable ({problem}); compiled kernels go to "
                 f"{fallback} instead (set WARP_CACHE_PATH to choose another)")
        return
    raise WarpVerletError(f"Warp's kernel cache directory {default} is not writable ({problem}), nor is "
                          f"{fallback} usable ({unusable}): set WARP_CACHE_PATH to a directory this user can write")


@contextlib.contextmanager
def _native_stderr_without(text: str) -> Iterator[list[str]]:
    """Capture what native code writes to file descriptor 2 meanwhile, and pass it on without the lines that
    contain ``text``; the list it gives holds those lines once the block is over."""
    dropped: list[str] = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no usable fd 2: nothing to filter
        yield dropped
        return
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            yield dropped
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            kept = []
            for line in capture.read().decode("utf-8", "replace").splitlines(keepends=True):
                (dropped if text in line else kept).append(line)
            if kept:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()


def start_warp(verbose: bool = False, cpu: bool = False, note: Callable[[str], None] | None = None) -> None:
    """Initialise Warp for a run: quiet unless ``verbose`` (no banner, no per-module load times), a writable
    kernel cache, and no CUDA-driver warning unless ``verbose``: on a CPU run (``cpu``, or the default device,
    which falls back to the CPU) it is dropped, on a run that asked for CUDA it is said as a note."""
    import warp as wp

    if not verbose:
        wp.config.quiet = True
        wp.config.log_level = wp.LOG_WARNING
    ensure_kernel_cache(note)
    if verbose:
        wp.init()
        return
    with _native_stderr_without(CUDA_DRIVER_WARNING) as dropped:
        wp.init()
    if dropped and not cpu and note is not None:
        note("Warp could not find or load the NVIDIA CUDA driver, so no CUDA device can be used")
