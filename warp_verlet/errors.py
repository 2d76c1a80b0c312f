"""The project's exception types. Each carries one message meant for the user, not a traceback.

Every error this package raises on purpose derives from :class:`WarpVerletError`. Where Python has a natural
base as well, the error derives from both, so that ``except ValueError`` keeps working: a bad argument to a
function of the API is an :class:`ArgumentError` (a ValueError too), a call at the wrong time (writing to a
closed cache) a :class:`StateError` (a RuntimeError too).
"""

from __future__ import annotations

import re
from contextlib import contextmanager


class WarpVerletError(Exception):
    """Base class of every error this package raises on purpose."""


class ArgumentError(WarpVerletError, ValueError):
    """A function of the API was given an argument it cannot use."""


class StickFormRefused(ArgumentError):
    """The form of the sticks asked for (``Simulator(sticks=...)``: "implicit", "tiled", "clustered") cannot take
    this scene; the message names the form and the reason."""


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


# USD's C++ namespace, spelled into the names in some of its messages ("pxrInternal_v0_26_11__pxrReserved__::").
_USD_NAMESPACE = re.compile(r"\bpxrInternal_v\w*?__pxrReserved__::")
# USD's C++ location, as its default diagnostic output and Tf.ErrorException spell it.
_USD_LOCATION = re.compile(r"(?:Error|Warning|Status)?\s*in '?[\w:<>~]+'? at line \d+ (?:in file|of) \S+\s*(?::|--)\s*")
# What USD appends to a diagnostic about a stage it was opening (the stage again, with its memory address), the
# in-memory session layer it names beside a file ("@anon:0x55f5...:scene-session.usda@"), and the "skipping" of
# a layer it went on without (a refused asset is not gone on with).
_USD_CONTEXT = re.compile(r"\s*\(instantiating stage on stage @[^@]*@ <0x[0-9a-fA-F]+>\)|,?@anon:0x[0-9a-fA-F]+:[^@]*@"
                          r"|;\s*skipping\.?")


def plain_usd_text(text: str) -> str:
    """A message of USD's without its C++ namespace, function names, source files, line numbers and addresses."""
    text = _USD_CONTEXT.sub("", _USD_LOCATION.sub("", _USD_NAMESPACE.sub("", str(text))))
    return text.strip().strip("'").strip()


def usd_cause(exc: BaseException) -> str:
    """The plain cause of a USD error (``pxr.Tf.ErrorException``), without USD's C++ function names, source
    files and line numbers: the commentary of each Tf error it carries, joined by "; ". Needs no pxr import."""
    parts = [plain_usd_text(getattr(arg, "commentary", "") or "") for arg in getattr(exc, "args", ())]
    parts = [p for p in parts if p]
    if parts:
        return "; ".join(dict.fromkeys(parts))  # in order, each once
    text = str(exc).strip()
    # "Error in 'f' at line N in file F : 'cause'": keep the causes.
    quoted = [plain_usd_text(chunk.rsplit(" : ", 1)[-1]) for chunk in text.split("\n") if chunk.strip()]
    return "; ".join(q for q in quoted if q) or plain_usd_text(text)


@contextmanager
def usd_diagnostics():
    """While open, USD's warnings and status messages are collected (into the list it yields, as their plain
    commentary) instead of printed: USD prints them with its C++ function, source file and line, which mean
    nothing to a user. Errors still raise (pxr.Tf.ErrorException). Imports pxr when entered."""
    from pxr import UsdUtils

    delegate = UsdUtils.CoalescingDiagnosticDelegate()
    collected: list[str] = []
    try:
        yield collected
    finally:
        collected.extend(plain_usd_text(d.commentary) for d in delegate.TakeUncoalescedDiagnostics())
        del delegate  # unregisters it: USD prints its diagnostics again
