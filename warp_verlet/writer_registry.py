"""The output formats a run can write, keyed by file suffix, and what a writer must provide.

Every check of an output path asks this table: the scene's ``output.path`` (scene.py), a run's output
(output_file.CacheOutput), a sweep's ``format`` (sweep/sweep_file.py); and ``runner.open_writer``, which a
live session's save goes through too, opens the writer of the output's suffix. A format is named here as
``"module:attribute"`` and imported only when a run writes to it, so this module imports neither pxr nor warp:
loading a scene and ``validate`` read it.

A new format is one module holding an object that satisfies :class:`CacheFormat`, and one line in
``_register_builtin_formats``. :func:`register_format` adds one at run time (a plug-in, a test), which every
check above then accepts.

The override layer (``output.kind = "override"``) is not a format of its own: it is the USD writer opened with
the asset it overrides. It writes the same files (a USD layer, the same suffixes) through the same stage,
saves, time samples, torn faces and size estimate; only where the points go differs (``over``s at the asset's
prims instead of new prims). A separate registration would need a second key besides the suffix, and would
share all of that code anyway. A format says whether it can write one (``overrides``), so that an override to a
format that has none is refused by name.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Callable, Protocol, Sequence, runtime_checkable

from .errors import ArgumentError, OutputError


@runtime_checkable
class CacheWriter(Protocol):
    """An open point cache: what runner.py, live_session.py, background_writer.py and output_file.py use of it.

    Frames arrive one at a time with increasing frame numbers, from ``start_frame`` on. Every ``save_every``
    frames the file on disk becomes a valid cache of the frames written so far; before each save the writer
    calls the request's ``before_save(writer)``, which may raise (the disk is full) to refuse it, after which
    the writer saves nothing more, so that what is on disk stays the last good save. ``close`` (and leaving
    the ``with`` block, even on an exception) saves the frames not yet saved, unless a save was refused, and
    releases the file. The writer writes only the path it was opened on (the run's partial file:
    output_file.py renames it over the output when the run succeeds), so a failed run never touches the
    previous output.
    """

    path: Path
    start_frame: int
    save_every: int
    frames_written: int  # frames given to write_frame
    saved_frames: int  # frames on disk (output_file.OutputReport names them after a failure)
    saved_frame: int | None  # the last frame on disk; None before the first

    def write_frame(self, frame: int, points: Sequence[Any], moving_centres: Any = None,
                    hidden_faces: Sequence[Any] | None = None) -> None:
        """One frame: ``points``, one float32 (N, 3) array per shape, in the request's shape order;
        ``moving_centres``, one row per moving sphere, in collider order; ``hidden_faces``, per shape the torn
        faces (indices into its faces) or None where unchanged or not tearing."""

    def close(self) -> None:
        """Save what is not saved yet and release the file; calling it again does nothing."""

    def __enter__(self) -> CacheWriter: ...

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...


@dataclass(frozen=True)
class CacheRequest:
    """What a run asks of its cache, whatever its format."""

    shapes: Sequence[Any]  # usd_writer.CachedShape per cloth: name, faces, UVs, point count, tears
    fps: float
    colliders: Sequence[Any] = ()  # usd_writer.CachedSphere / CachedPlane
    up_axis: str = "Y"
    meters_per_unit: float = 1.0
    save_every: int = 10
    start_frame: int = 0
    metadata: dict[str, str] = field(default_factory=dict)  # generator, scene, device
    torn_faces: str = "holes"  # "holes" or "remove" (usd_writer.py says what each shows)
    override_asset: Path | None = None  # an override layer: the asset whose prims it overrides
    before_save: Callable[[CacheWriter], None] | None = None  # output_file.CacheOutput.before_save


class CacheFormat(Protocol):
    """One output format: opens its writer, estimates its size, and checks a finished cache."""

    name: str  # as an error names it ("USD point cache")
    overrides: bool  # can write an override layer (output.kind = "override")

    def open(self, path: Path, request: CacheRequest) -> CacheWriter:
        """The writer of a new cache at ``path`` (replacing any file there)."""

    def estimate(self, request: CacheRequest, path: Path) -> Any:
        """The cache's expected size (output_file.CacheEstimate), which the free-space checks use, or None
        when the format cannot say (the run then starts without them)."""

    def problems(self, path: Path, frames: int) -> list[str]:
        """Why ``path`` is not a complete cache of frames 0 .. ``frames`` (empty when it is): a resumed sweep
        runs a variant again unless its cache passes."""


_formats: dict[str, CacheFormat | str] = {}  # suffix -> the format, or "module:attribute" until first used
_overrides: dict[str, bool] = {}


def register_format(suffixes: str | Sequence[str], cache_format: CacheFormat | str, overrides: bool = False,
                    replace: bool = False) -> None:
    """Write files ending in ``suffixes`` (".npz", or several) with ``cache_format``: the object, or
    ``"module:attribute"`` to import when first used. A suffix already registered is refused unless
    ``replace``."""
    suffixes = (suffixes,) if isinstance(suffixes, str) else tuple(suffixes)
    for suffix in suffixes:
        if not (isinstance(suffix, str) and len(suffix) > 1 and suffix.startswith(".") and "." not in suffix[1:]
                and "/" not in suffix and suffix == suffix.strip()):
            raise ArgumentError(f"a format's suffix is one dot and a name, like '.npz'; got {suffix!r}")
        if suffix in _formats and not replace:
            raise ArgumentError(f"the suffix {suffix} is already registered (to {_describe(_formats[suffix])}); "
                                "pass replace=True to replace it")
    for suffix in suffixes:
        _formats[suffix] = cache_format
        _overrides[suffix] = bool(overrides)


def unregister_format(suffixes: str | Sequence[str]) -> None:
    """Forget ``suffixes``; one that is not registered is ignored."""
    for suffix in (suffixes,) if isinstance(suffixes, str) else suffixes:
        _formats.pop(suffix, None)
        _overrides.pop(suffix, None)


def output_suffixes() -> tuple[str, ...]:
    """Every suffix an output may end in, in the order registered."""
    return tuple(_formats)


def suffixes_text() -> str:
    """The suffixes as an error lists them: ".usd, .usda, .usdc"."""
    return ", ".join(output_suffixes())


def is_output_suffix(suffix: str) -> bool:
    return suffix in _formats


def writes_overrides(suffix: str) -> bool:
    """Whether the format of ``suffix`` can write an override layer."""
    return _overrides.get(suffix, False)


def format_for(path: str | Path, override: bool = False) -> CacheFormat:
    """The format that writes ``path``, by its suffix (imported on first use). OutputError names every
    registered suffix when ``path``'s is none of them, and refuses an override layer to a format without one."""
    path = Path(path)
    cache_format = _formats.get(path.suffix)
    if cache_format is None:
        raise OutputError(f"cannot write {path}: the file name must end in {suffixes_text()}")
    if isinstance(cache_format, str):
        reference = cache_format
        module, _, attribute = reference.partition(":")
        cache_format = getattr(importlib.import_module(module), attribute)
        for suffix, registered in _formats.items():  # every suffix of that format: imported once
            if registered == reference:
                _formats[suffix] = cache_format
    if override and not writes_overrides(path.suffix):
        overriding = ", ".join(s for s in _formats if _overrides[s])
        raise OutputError(f"cannot write {path}: an override layer (output.kind = \"override\") is written by "
                          f"{overriding or 'no registered format'}; {cache_format.name} files "
                          f"({path.suffix}) have none")
    return cache_format


def _describe(cache_format: CacheFormat | str) -> str:
    return cache_format if isinstance(cache_format, str) else getattr(cache_format, "name", repr(cache_format))


# The files USD writes: a crate (.usdc), text (.usda), or either (.usd, crate when written).
USD_SUFFIXES = (".usd", ".usda", ".usdc")


def _register_builtin_formats() -> None:
    # One line per format: its suffixes, where it lives, whether it writes override layers.
    register_format(USD_SUFFIXES, "warp_verlet.output.usd_writer:USD_POINT_CACHE", overrides=True)


_register_builtin_formats()
