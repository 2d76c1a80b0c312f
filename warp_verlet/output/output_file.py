"""Where a run's point cache goes, and what becomes of it when the run does not finish.

A run never writes its output path directly:

* **Atomic output.** It writes ``NAME.partial.EXT`` next to the output and renames it over ``NAME.EXT`` only
  when the run succeeds (``os.replace``: one atomic step on one file system). A run that fails, diverges, is
  interrupted or killed leaves its frames in ``NAME.partial.EXT`` and any previous ``NAME.EXT`` exactly as it
  was. The next run to that output replaces the partial file (with a note), and removes the temporary files
  USD had open when a run was killed in the middle of a save (``NAME.partial.XXXXXX``).
* **One writer per output.** It holds an exclusive lock (filelock) from before the simulator is built until the
  cache is in place: a second run of this user's to the same output is refused at once (:class:`OutputBusyError`).
  The lock file is not beside the output, where it would litter the user's directory: it lives in a private
  directory of the user's (:func:`lock_directory`), named after the output's directory (device and inode, so
  that every path to it, through symlinks or bind mounts, finds the same lock) and its file name. It stays
  there, empty: removing a lock file while another run opens it would let two runs hold "the" lock.
* **Disk space.** It estimates the cache's size (:func:`estimate_cache`) and refuses to start when the disk
  cannot hold it. Before every save it checks the free space again, with the estimate refined from the sizes
  the saves so far actually took, and stops with the frames saved so far (:class:`DiskFullError`) rather than
  let USD write into a full disk, where it crashes.
* **Paths.** The output is resolved (symlinks followed: the file the link points to is replaced, the link
  stays) and refused when it, its partial file or its lock is the scene file or any other input.

This module imports neither warp nor pxr.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence

from ..errors import DiskFullError, OutputBusyError, OutputError
from ..private_dir import make_private_directory, user_directory
from ..writer_registry import is_output_suffix, suffixes_text


class OutputNameError(OutputError):
    """The output path is refused for its name alone (no registered format's suffix, a partial file's name, or
    an input file): a bad argument, which nothing on the disk would change (the command line exits 2 for it)."""

PARTIAL = ".partial"  # NAME.usdc -> NAME.partial.usdc
# Kept free besides what a save is expected to write: other programs write to the same disk, and the estimate
# of a save is an estimate.
RESERVE_BYTES = 256 * 1024
SAVE_MARGIN = 1.25  # a save is allowed when the free space exceeds its predicted size x this, plus the reserve
# Crate (.usdc) files are appended to at every save, and each save also writes again the time codes and value
# offsets of every time-sampled attribute: about this many bytes per sample already on disk, per attribute.
# Measured with usd-core 26.11 (a 40-point rope, 2000 frames, save_every = 10: 5.89 MB, where the points
# alone are 0.96 MB).
CRATE_BYTES_PER_SAMPLE_PER_SAVE = 12
# Bytes per value: a crate file stores float32 as is and compresses integer arrays (to well under 2 bytes an
# index for a grid); a text file (.usda) spells every number out, up to about 12 characters for a float with
# its separator (a point is "(-0.12345678, 1.2345678, 0.5), "; the shipped scenes average under 10).
CRATE_FLOAT, CRATE_INT = 4, 2
TEXT_FLOAT, TEXT_INT = 12, 8
HEADER_BYTES = 4096  # stage metadata, prim specs, an empty crate's tables


@dataclass(frozen=True)
class CacheEstimate:
    """The expected size of a point cache."""

    static_bytes: int  # the file after its first save: metadata, topology, UVs, colliders
    frame_bytes: int  # what one frame adds (points and extent of every shape, moving spheres)
    sampled: int  # attributes sampled every frame (points and extent per shape, translate per moving sphere)
    text: bool  # .usda: every save writes the whole file again, to a temporary file beside it

    def overhead(self, frames_from: int, frames_to: int, save_every: int) -> int:
        """What the crate format's saves add beyond the frames' own data, from ``frames_from`` frames on disk
        to ``frames_to``, one save every ``save_every`` frames. 0 for text files, which are rewritten whole."""
        if self.text or frames_to <= frames_from:
            return 0
        saves = math.ceil((frames_to - frames_from) / save_every)
        # Save k writes again the samples of every frame on disk by then: frames_from + k * save_every.
        samples = saves * frames_from + save_every * saves * (saves + 1) // 2
        return CRATE_BYTES_PER_SAMPLE_PER_SAVE * self.sampled * min(samples, saves * frames_to)

    def total(self, frames: int, save_every: int) -> int:
        """The final file of ``frames`` frames (frame 0, the rest pose, included)."""
        return self.static_bytes + frames * self.frame_bytes + self.overhead(0, frames, save_every)

    def peak(self, frames: int, save_every: int) -> int:
        """The most disk the cache takes while it is written: a text file's last save writes the new file
        beside the old one."""
        final = self.total(frames, save_every)
        return 2 * final if self.text else final


def estimate_cache(shapes: Sequence, colliders: Sequence = (), text: bool = False) -> CacheEstimate:
    """The size of a cache of ``shapes`` (usd_writer.CachedShape: point_count, faces, is_rope, tears) and
    ``colliders`` (CachedSphere with ``moving``, CachedPlane)."""
    f, i = (TEXT_FLOAT, TEXT_INT) if text else (CRATE_FLOAT, CRATE_INT)
    static = HEADER_BYTES
    frame = 0
    sampled = 0
    for shape in shapes:
        n = int(shape.point_count)
        if shape.is_rope:
            static += 256
        else:
            faces = shape.faces
            static += 2 * f * n + i * (len(faces.counts) + len(faces.indices))  # UVs, counts, indices
            if shape.tears:
                static += 64
        frame += 3 * f * n + 6 * f + 32  # points, extent, the sample's time and offsets
        sampled += 2
    for collider in colliders:
        size = getattr(collider, "cache_bytes", None)  # a kind whose prim grows with its geometry says how much
        static += size(f, i) if size is not None else 512
        if getattr(collider, "moving", False):
            frame += 3 * f + 32
            sampled += 1
    return CacheEstimate(static_bytes=static, frame_bytes=frame, sampled=sampled, text=text)


@dataclass(frozen=True)
class OutputReport:
    """What became of a run's output when the run did not finish; attached to the exception that ended the
    run as its ``output_report`` attribute (see :func:`output_report`)."""

    output: Path  # as given
    partial: Path | None  # the file holding the frames saved, or None when no frame was saved
    frames: tuple[int, int] | None  # first and last frame in ``partial``
    previous: bool  # the output existed before the run, and is as it was

    def describe(self) -> str:
        kept = f"{self.output} is as it was before this run" if self.previous else f"{self.output} was not written"
        if self.partial is None or self.frames is None:
            return f"nothing was written; {kept}"
        first, last = self.frames
        frames = f"frame {first} is" if first == last else f"frames {first} to {last} are"
        return f"{frames} in {self.partial}; {kept}"


def output_report(exc: BaseException) -> OutputReport | None:
    """The report a failed run attached to ``exc``, or None (the run failed before its output was opened)."""
    report = getattr(exc, "output_report", None)
    return report if isinstance(report, OutputReport) else None


def partial_path(path: Path) -> Path:
    """``NAME.partial.EXT`` beside ``NAME.EXT``."""
    return path.with_name(f"{path.stem}{PARTIAL}{path.suffix}")


def input_files(scene) -> list[Path]:
    """The files a scene reads: the scene file itself and every path-valued field of its cloths and colliders
    (mesh files, override layers, and every layer a USD mesh composes, recursively: the mesh's
    ``SourceMesh.dependencies``), so that the output can never overwrite one of them."""
    found = []
    source = Path(scene.source)
    if source.is_file():
        found.append(source)

    def visit(value) -> None:
        if isinstance(value, (str, bytes)):
            return
        if isinstance(value, os.PathLike):
            found.append(Path(value))
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            for field in dataclasses.fields(value):
                visit(getattr(value, field.name))
        elif isinstance(value, (tuple, list)):
            for item in value:
                visit(item)
        elif isinstance(value, dict):
            for item in value.values():
                visit(item)

    for item in (*scene.cloths, *scene.colliders):
        visit(item)
    return found


def lock_directory() -> Path:
    """Where this user's output locks live: this user's private directory (private_dir.user_directory,
    ``$XDG_RUNTIME_DIR/warp-verlet`` or ``<temp dir>/warp-verlet-<user>``), created 0700. One that is a symlink,
    another user's or open to others is refused: another user could otherwise hold or swap the locks."""
    directory, below = user_directory()
    try:
        problem = make_private_directory(directory, below)
    except OSError as exc:
        raise OutputError(f"cannot create the output lock directory {directory}: {exc.strerror or exc}") from None
    if problem is not None:
        raise OutputError(f"cannot use the output lock directory {directory}: {problem}; remove it, or set "
                          "XDG_RUNTIME_DIR")
    return directory


def lock_path(output: Path) -> Path:
    """The lock file of a (resolved) output path, whose directory exists: in :func:`lock_directory`, named by
    the directory's device and inode and the file's name, readable name first."""
    parent = os.stat(output.parent)
    key = hashlib.sha256(f"{parent.st_dev}:{parent.st_ino}:{output.name}".encode()).hexdigest()[:32]
    return lock_directory() / f"{output.name[:100]}.{key}.lock"


def _same_file(a: Path, b: Path) -> bool:
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)  # a hard link, or a path through a bind mount
    except OSError:
        return False


def _size(n: float) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if abs(n) >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} bytes"


def free_bytes(directory: Path) -> int:
    """Bytes that this process may still write to the file system holding ``directory``."""
    return int(shutil.disk_usage(directory).free)


def check_output_names(path: Path, what: str = "") -> None:
    """Refuse, as a bad argument, an output whose file names are longer than its file system allows (255 bytes
    on most): the operating system's 'File name too long' would otherwise surface as a traceback from the first
    look at the path, or fail the run after it simulated. The names a run writes are the output's, its partial
    file's (NAME.partial.EXT) and USD's temporary file for that (NAME.partial.XXXXXX, renamed once saved), the
    longest. ``what`` names where the path came from."""
    partial = partial_path(Path(path))
    refuse_long_names(Path(path), (Path(path).name, partial.name, f"{partial.stem}.XXXXXX"), what)


def refuse_long_names(path: Path, names, what: str = "") -> None:
    """OutputNameError when a directory on the way to ``path``, or one of ``names`` (the files written in its
    directory on the way to ``path``), is a longer name than the file system allows, or the whole path longer
    than the system's path limit (PATH_MAX)."""
    path = Path(path)
    directory = Path(os.path.abspath(path.parent))
    existing = next(p for p in (directory, *directory.parents) if os.path.isdir(p))  # the root at least
    try:
        longest_name, longest_path = (os.pathconf(existing, "PC_NAME_MAX"), os.pathconf(existing, "PC_PATH_MAX"))
    except (OSError, ValueError):  # no limit to ask for: Linux's
        longest_name, longest_path = 255, 4096

    def refuse(problem: str) -> OutputNameError:
        shown = str(path) if len(str(path)) <= 120 else f"{str(path)[:56]}...{str(path)[-56:]}"
        return OutputNameError(f"cannot write {shown}{what}: {problem}; choose a shorter path")

    for part in directory.parts[1:]:
        if len(os.fsencode(part)) > longest_name:
            raise refuse(f"the directory name {part[:24]}... is {len(os.fsencode(part))} bytes, more than the "
                         f"{longest_name} its file system allows")
    for name in names:
        size = len(os.fsencode(name))
        if size > longest_name:
            raise refuse(f"the file name is too long: it is written through {name[:24]}...{name[-16:]}, {size} "
                         f"bytes, more than the {longest_name} its file system allows")
        full = len(os.fsencode(str(directory / name)))
        if full >= longest_path:  # PATH_MAX counts the terminating NUL
            raise refuse(f"the path is too long: {full} bytes with {name[:24]}..., more than the "
                         f"{longest_path - 1} this system allows")


class CacheOutput:
    """One run's output: checks the path, holds the lock, watches the free space, puts the cache in place.

    Use it as a context manager around everything the run does. The cache is written to :attr:`partial`
    (give :meth:`before_save` to the writer, and :meth:`check_space` the estimate first); :meth:`commit` puts
    it in place once the writer is closed. Leaving the block with an exception keeps the frames saved in the
    partial file (or removes it when it holds none), attaches an :class:`OutputReport` to the exception and
    releases the lock.
    """

    def __init__(self, path: str | os.PathLike[str], inputs: Iterable[Path] = (),
                 note: Callable[[str], None] | None = None):
        self.given = Path(path)
        self.path = Path(os.path.realpath(self.given))  # follows symlinks: the file they point to is written
        self.partial = partial_path(self.path)
        self.lock_path: Path | None = None  # chosen on entry (lock_path()), once the directory is known to exist
        # The partial file as the user will look for it: beside the output as given, unless that is a symlink.
        beside = self.given.with_name(self.partial.name)
        self.partial_shown = beside if _same_file(beside.parent, self.partial.parent) else self.partial
        self.notes: list[str] = []
        self._note = note
        self._lock = None
        self._writer = None
        self._estimate: CacheEstimate | None = None
        self._frames = 0
        self._save_every = 1
        self._last_check: tuple[int, int, int] | None = None  # file size, frames pending, frames written
        self._frame_bytes: float | None = None  # refined from the saves
        self._first_size = 0  # the file after its first save (the static part)
        self.previous = False
        self.committed = False
        self._check_path(list(inputs))

    # ------------------------------------------------------------------ checks before anything is written
    def _fail(self, problem: str) -> OutputError:
        return OutputError(f"cannot write {self.given}: {problem}")

    def _refuse_name(self, problem: str) -> OutputNameError:
        return OutputNameError(f"cannot write {self.given}: {problem}")

    def _check_path(self, inputs: list[Path]) -> None:
        check_output_names(self.given)
        path, given = self.path, self.given
        for source in inputs:
            for candidate, what in ((path, "the output"), (self.partial, f"its partial file {self.partial.name}")):
                if _same_file(candidate, source):
                    link = f" ({given} is a symlink to it)" if given.is_symlink() else ""
                    raise self._refuse_name(f"{what} would overwrite the input file {source}{link}; choose "
                                            "another output path")
        if not is_output_suffix(path.suffix):  # the suffixes of writer_registry's formats
            raise self._refuse_name(f"the file name must end in {suffixes_text()}"
                                    + (f" (it is a symlink to {path})" if given.is_symlink() else ""))
        if path.stem.endswith(PARTIAL):
            raise self._refuse_name(f"names ending in {PARTIAL}{path.suffix} are kept for the frames of runs that "
                                    "did not finish; choose another name")
        parent = path.parent
        if not parent.is_dir():
            raise self._fail(f"directory {given.parent} does not exist")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise self._fail(f"directory {given.parent} is not writable")
        for candidate in (path, self.partial):
            if candidate.is_dir():
                raise self._fail(f"{candidate} is a directory")
            if candidate.exists() and not candidate.is_file():
                raise self._fail(f"{candidate} is not a regular file")

    # ------------------------------------------------------------------ the lock
    def __enter__(self) -> CacheOutput:
        from filelock import FileLock, Timeout  # imported here: `validate` never needs it

        try:
            self.lock_path = lock_path(self.path)
        except FileNotFoundError:  # the directory went away since the checks
            raise self._fail(f"directory {self.given.parent} does not exist") from None
        lock = FileLock(str(self.lock_path), timeout=0)
        try:
            lock.acquire(timeout=0)
        except Timeout:
            # filelock also times out when it cannot create the lock file at all (a read-only or special
            # directory): say that instead of "busy".
            try:
                os.close(os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644))
            except OSError as exc:
                raise self._fail(f"cannot create its lock file {self.lock_path}: "
                                 f"{exc.strerror or exc}") from None
            raise OutputBusyError(f"cannot write {self.given}: another run is writing it now (it holds the lock "
                                  f"{self.lock_path}); wait for that run to finish, or choose another output "
                                  "path") from None
        except OSError as exc:
            raise self._fail(f"cannot create its lock file {self.lock_path}: "
                             f"{exc.strerror or exc}") from None
        self._lock = lock
        try:
            self.previous = self.path.exists()
            self._clear_leftovers()
        except BaseException:
            lock.release()
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc is not None and not self.committed:
                report = self._keep_partial()
                if output_report(exc) is None:
                    try:
                        exc.output_report = report
                    except AttributeError:  # pragma: no cover - an exception type with __slots__
                        pass
        finally:
            self._remove_usd_temps()
            if self._lock is not None:
                self._lock.release()
                self._lock = None

    def _say(self, text: str) -> None:
        self.notes.append(text)
        if self._note is not None:
            self._note(text)

    def _usd_temps(self) -> list[Path]:
        """Temporary files USD writes a save to before renaming it over the partial file: NAME.partial.XXXXXX
        (mkstemp's six characters), empty or starting as a USD file does; anything else is left alone."""
        pattern = re.compile(re.escape(self.partial.stem) + r"\.[A-Za-z0-9_]{6}")
        try:
            names = os.listdir(self.partial.parent)
        except OSError:
            return []
        temps = [self.partial.parent / n for n in names if pattern.fullmatch(n)]
        return [t for t in temps if _looks_like_usd(t)]

    def _remove_usd_temps(self) -> list[Path]:
        removed = []
        for temp in self._usd_temps():
            try:
                temp.unlink()
                removed.append(temp)
            except OSError:
                pass
        return removed

    def _clear_leftovers(self) -> None:
        """What an earlier run to this output left when it was killed (we hold the lock, so no run is writing
        these now): USD's temporary files are removed, and the partial file is about to be replaced."""
        for temp in self._remove_usd_temps():
            self._say(f"removed {temp}, a temporary file left by an earlier run that was killed during a save")
        if self.partial.exists():
            self._say(f"{self.partial_shown} holds the frames of an earlier run that did not finish; this run "
                      "replaces it")

    # ------------------------------------------------------------------ disk space
    def check_space(self, estimate: CacheEstimate | None, frames: int, save_every: int) -> None:
        """Refuse the run up front when the disk cannot hold the whole cache of ``frames`` frames (frame 0
        included). ``estimate`` None (a format that cannot estimate its size) checks nothing, here or before
        the saves."""
        self._estimate, self._frames, self._save_every = estimate, int(frames), max(1, int(save_every))
        need = estimate.peak(self._frames, self._save_every) if estimate is not None else 0
        free = free_bytes(self.path.parent)
        if estimate is not None and need + RESERVE_BYTES > free:
            raise DiskFullError(f"cannot write {self.given}: the cache needs about {_size(need)} and the disk "
                                f"holding {self.given.parent} has {_size(free)} free (nothing was written)")
        if self.partial.exists():  # an earlier run's frames (noted on entry): from here on the file is this run's
            self.partial.unlink()

    def before_save(self, writer) -> None:
        """Called by the writer before each save (``writer.frames_written``, ``writer.saved_frames``): raise
        DiskFullError, before USD writes anything, when the save or, judged by the saves so far, the rest of
        the cache cannot fit."""
        self._writer = writer
        estimate = self._estimate
        if estimate is None:  # check_space was not called: nothing to compare with
            return
        size = self.partial.stat().st_size if self.partial.exists() else 0
        written, pending = writer.frames_written, writer.frames_written - writer.saved_frames
        if self._last_check is not None:
            last_size, last_pending, last_written = self._last_check
            if last_written == 0 and last_pending == 0:
                self._first_size = size  # the first save held the topology only
            elif last_pending > 0 and size > last_size:
                data = size - last_size - estimate.overhead(last_written - last_pending, last_written, last_pending)
                if estimate.text:  # the whole file was written again: what the frames on disk take
                    data = size - self._first_size
                    last_pending = last_written
                self._frame_bytes = max(data / last_pending, 1.0)
        frame_bytes = self._frame_bytes if self._frame_bytes is not None else estimate.frame_bytes
        saved = written - pending
        if written == 0:
            save = estimate.static_bytes
        elif estimate.text:
            save = size + pending * frame_bytes  # the new file, written beside the old one
        else:
            save = pending * frame_bytes + estimate.overhead(saved, written, max(pending, 1))
        free = free_bytes(self.partial.parent)
        if save * SAVE_MARGIN + RESERVE_BYTES > free:
            what = "the cache's first save" if written == 0 else f"saving the next {pending} frame(s)"
            raise self._full(writer, f"{what} needs about {_size(save)} and the disk has {_size(free)} free")
        if self._frame_bytes is not None:  # the estimate is now measured: will the rest fit?
            rest = self._frames - written
            final = size + (written - saved + rest) * frame_bytes
            if estimate.text:
                need = 2 * final - size
            else:
                need = final - size + estimate.overhead(saved, self._frames, self._save_every)
            if need + RESERVE_BYTES > free:
                raise self._full(writer, f"the whole cache needs about {_size(need)} more (measured from the "
                                 f"frames saved so far) and the disk has {_size(free)} free")
        self._last_check = (size, pending, written)

    def _full(self, writer, problem: str) -> DiskFullError:
        return DiskFullError(f"not enough disk space for {self.given}: {problem}; stopped before USD could "
                             "write into a full disk")

    # ------------------------------------------------------------------ the end of a run
    def commit(self) -> None:
        """Put the finished cache in place: the partial file is renamed over the output in one step."""
        try:
            _fsync(self.partial)
            os.replace(self.partial, self.path)
            _fsync(self.path.parent)
        except OSError as exc:
            raise self._fail(f"cannot rename {self.partial} to it: {exc.strerror or exc}") from None
        self.committed = True

    def _keep_partial(self) -> OutputReport:
        """After a failure: keep the partial file when it holds frames, else remove it."""
        writer = self._writer  # set by the first save: from then on the partial file is this run's
        frames = None
        if writer is not None and writer.saved_frames > 0 and self.partial.exists():
            frames = (writer.start_frame, writer.saved_frame)
        elif writer is not None and self.partial.exists():
            try:
                self.partial.unlink()  # this run's topology and no frame: nothing worth keeping
            except OSError:
                pass
        return OutputReport(output=self.given, partial=self.partial_shown if frames else None, frames=frames,
                            previous=self.previous)


def _looks_like_usd(path: Path) -> bool:
    """Empty, or starting with a crate file's or a text layer's signature."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return False
    return head == b"" or head.startswith((b"PXR-USDC", b"#usda"))


def _fsync(path: Path) -> None:
    """Flush a file (or a directory's entries) to the disk, where the platform allows it."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
