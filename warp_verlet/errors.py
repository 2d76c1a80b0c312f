"""The project's exception types. Each carries one message meant for the user, not a traceback."""

from __future__ import annotations


class WarpVerletError(Exception):
    """Base class of every error this package raises on purpose."""


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


class OutputError(WarpVerletError):
    """The output path cannot be written."""
