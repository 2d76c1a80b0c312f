"""The project's exception types. Each carries one message meant for the user, not a traceback.

Every error this package raises on purpose derives from :class:`WarpVerletError`. Where Python has a natural
base as well, the error derives from both, so that ``except ValueError`` keeps working: a bad argument to a
function of the API is an :class:`ArgumentError` (a ValueError too), a call at the wrong time (writing to a
closed cache) a :class:`StateError` (a RuntimeError too).
"""

from __future__ import annotations


class WarpVerletError(Exception):
    """Base class of every error this package raises on purpose."""


class ArgumentError(WarpVerletError, ValueError):
    """A function of the API was given an argument it cannot use."""


class StateError(WarpVerletError, RuntimeError):
    """An object was used when it cannot be (for example a point cache after it was closed)."""


class SceneError(WarpVerletError):
    """A scene file is unreadable or invalid.

    The message names the file, the key (as a dotted path, e.g. ``cloth[0].mass``) and what was expected.
    """

    def __init__(self, file: str, key: str | None, problem: str):
        self.file = file
        self.key = key
        self.problem = problem
        where = f"{file}: {key}" if key else file
        super().__init__(f"{where}: {problem}")


class DivergenceError(WarpVerletError):
    """The simulation produced a non-finite or out-of-bounds position."""

    def __init__(self, frame: int, cloth: str, particle: int, value, reason: str):
        self.frame = frame
        self.cloth = cloth
        self.particle = particle
        super().__init__(
            f"simulation diverged at frame {frame}: cloth '{cloth}' particle {particle} "
            f"is at {tuple(float(v) for v in value)} ({reason})"
        )


class ServerError(WarpVerletError):
    """A browser view's web server cannot start as asked: a port in use, a host that cannot be bound, viser
    not installed (a bad argument: exit code 2)."""


class OutputError(WarpVerletError):
    """The output path cannot be written."""


class OutputBusyError(OutputError):
    """Another run is writing the same output now (it holds the output's lock)."""


class DiskFullError(OutputError):
    """The disk holding the output has not enough free space for the cache (or for its next save)."""


def usd_cause(exc: BaseException) -> str:
    """The plain cause of a USD error (``pxr.Tf.ErrorException``), without USD's C++ function names, source
    files and line numbers: the commentary of each Tf error it carries, joined by "; ". Needs no pxr import."""
    parts = [str(getattr(arg, "commentary", "") or "").strip() for arg in getattr(exc, "args", ())]
    parts = [p for p in parts if p]
    if parts:
        return "; ".join(dict.fromkeys(parts))  # in order, each once
    text = str(exc).strip()
    # "Error in 'f' at line N in file F : 'cause'": keep the causes.
    quoted = [chunk.rsplit(" : ", 1)[-1].strip().strip("'") for chunk in text.split("\n") if chunk.strip()]
    return "; ".join(q for q in quoted if q) or text
