"""Running a sweep: each variant not already done, on a backend (sweep_backends.py), with resume.

Running (``run_sweep``): each variant writes ``<output>/<name>.<format>`` and a sidecar ``<name>.json`` with its
parameter hash, the SHA-256 of its cache and its result row; ``sweep.csv`` and ``sweep.md`` list every variant. A
re-run skips the variants whose sidecar says ok with the same hash and whose cache is the one the sidecar names (its
SHA-256: a cache copied in from another variant is run again) and validates with the expected frames. The hash is of
the variant's whole scene document, frames included, so a run with another ``--frames`` runs every variant again.
The backends that run the variants are in ``sweep_backends.py``; the summary files are summary.py's.

The output directory is the sweep's own while it runs:

* **One sweep per output directory.** A sweep holds an exclusive lock on its output directory (filelock, in this
  user's private lock directory, as a run holds one on its output file: output_file.py) until its summary is
  written; a second sweep into the same directory, by whatever path, is refused at once (:class:`OutputBusyError`).
* **No file of the user's is overwritten.** An output directory that holds the sweep file is refused. ``sweep.csv``
  and ``sweep.md`` are replaced only when they are this sweep's summary, written by an earlier run of it: the csv's
  header row is this sweep's columns, the markdown's first line is ``# Sweep <sweep file's name>`` followed by its
  ``- sweep file:`` line. Any other file by those names is refused (:class:`OutputError`); move it away, or choose
  another output directory.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ...errors import OutputBusyError, OutputError, WarpVerletError
from ...writer_registry import format_for
from .summary import COLUMNS_AFTER, Summary, atomic_write, summary_markers
from .sweep_file import Sweep, Variant


def run_variant(task: dict, slot) -> dict:
    """Run one variant (in a worker process or a Ray task): the result row's measured fields. A divergence or
    another error the simulator raises on purpose is a row too ("diverged", "failed"); anything else raises."""
    import socket

    from ...errors import DivergenceError

    from ..sweep_backends import quiet_warp

    started = time.perf_counter()
    quiet_warp(getattr(slot, "verbose", False), slot.device)
    from ..runner import run_scene

    output = Path(task["output"])
    shipped = None
    if not getattr(slot, "local", True):  # a node that does not see the driver's disk: write here, send it back
        import tempfile

        shipped = Path(tempfile.mkdtemp(prefix="warp-verlet-sweep-"))
        output = shipped / output.name
    row: dict = {"device": slot.device, "host": socket.gethostname()}
    threads = slot.threads if slot.device == "cpu" else None
    written = output
    try:
        summary = run_scene(task["scene"], output=output, device=slot.device, threads=threads)
        row.update(status="ok", wall_s=summary.wall_seconds, frames=summary.frames, stretch_rms=summary.stretch_rms,
                   stretch_max=summary.stretch_max, torn=summary.torn, device=summary.device)
    except DivergenceError as exc:
        row.update(status="diverged", error=str(exc), frames=exc.frame - 1)
        written = _frames_kept(exc, output)
    except WarpVerletError as exc:
        row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
        written = _frames_kept(exc, output)
    if written != output:  # a run that did not finish keeps its frames in NAME.partial.EXT (output_file.py)
        row["output"] = str(Path(task["output"]).with_name(written.name))
    row["task_s"] = time.perf_counter() - started
    if shipped is not None:
        if written.exists():
            row["_files"] = {written.name: written.read_bytes()}
        import shutil

        shutil.rmtree(shipped, ignore_errors=True)
    return row


def _beside(bar, file):
    """A context in which a line printed to ``file`` does not break the progress bar (None: no bar)."""
    import contextlib

    return bar.external_write_mode(file=file) if bar is not None else contextlib.nullcontext()


def _frames_kept(exc: BaseException, output: Path) -> Path:
    """Where a failed run left its frames: its partial file, or ``output`` itself when it wrote none."""
    from ...output.output_file import output_report

    report = output_report(exc)
    return report.partial if report is not None and report.partial is not None else output


def cache_problems(path: Path, frames: int) -> list[str]:
    """Why the cache at ``path`` is not a complete cache of ``frames`` frames (empty when it is), as the format
    of its suffix judges it (writer_registry.CacheFormat.problems: for USD, usd_writer.complete_cache_problems)."""
    return format_for(path).problems(path, frames)



@dataclass
class SweepResult:
    rows: list[dict]
    ran: list[int] = field(default_factory=list)  # variant indices run this time, sorted
    resumed: list[int] = field(default_factory=list)  # skipped: done by an earlier run
    interrupted: bool = False
    elapsed: float = 0.0
    csv: Path | None = None
    md: Path | None = None

    def count(self, status: str) -> int:
        return sum(1 for r in self.rows if r["status"] == status)

    @property
    def failed(self) -> list[int]:
        return [r["index"] for r in self.rows if r["status"] not in ("ok",)]


def _base_row(sweep: Sweep, variant: Variant, output: Path) -> dict:
    row = {"index": variant.index, "name": variant.name, **variant.params, "status": "pending",
           "output": str(output), "hash": variant.hash, "resumed": False, "retries": 0}
    if sweep.random_axes:
        row["sample"] = variant.sample
    return row


def cache_path(sweep: Sweep, variant: Variant, out: Path | None = None) -> Path:
    return (out or sweep.output) / f"{variant.name}.{sweep.format}"


MAX_SIDECAR_BYTES = 2**20  # a sidecar holds one row (well under 10 kB): a larger file is not one of ours


def file_sha256(path: Path) -> str | None:
    """The SHA-256 of a file's bytes, read in chunks (a cache may be GBs), or None when it cannot be read."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            while chunk := f.read(2**20):
                digest.update(chunk)
    except OSError:
        return None
    return digest.hexdigest()


def done_row(sweep: Sweep, variant: Variant, out: Path) -> dict | None:
    """The row of a variant an earlier run finished, when its sidecar says ok with this parameter hash, its cache
    is the file the sidecar recorded (SHA-256) and validates with the expected frames; otherwise None (it runs
    again)."""
    sidecar = out / f"{variant.name}.json"
    try:
        with open(sidecar, "rb") as f:
            saved = json.loads(f.read(MAX_SIDECAR_BYTES + 1))
    except (OSError, ValueError):  # a truncated, oversized or foreign file is no sidecar of ours
        return None
    if not isinstance(saved, dict) or saved.get("hash") != variant.hash or saved.get("status") != "ok":
        return None
    cache = cache_path(sweep, variant, out)
    if saved.get("cache_sha256") is None or saved.get("cache_sha256") != file_sha256(cache):
        return None
    if cache_problems(cache, variant.scene.simulation.frames):
        return None
    row = _base_row(sweep, variant, cache_path(sweep, variant, out))
    row.update({k: saved.get(k) for k in COLUMNS_AFTER if k in saved and k not in ("output", "resumed", "hash")})
    row["resumed"] = True
    return row


def run_sweep(sweep: Sweep, backend, out: Path | None = None, resume: bool = True, progress: bool = True,
              log: Callable[[str], None] | None = None, summary_interval: float = 1.0) -> SweepResult:
    """Run every variant not already done on ``backend`` (sweep_backends), writing each cache, its sidecar and the
    summary as results come in. Ctrl-C stops the backend, marks what did not finish "interrupted", writes the
    summary and re-raises KeyboardInterrupt."""
    out = Path(out) if out is not None else sweep.output
    _refuse_the_sweep_files_directory(sweep, out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the sweep's output directory {out}: {exc.strerror or exc}") from None
    lock = _lock_output_directory(out)
    try:
        _refuse_foreign_summaries(sweep, out)
        return _run_sweep(sweep, backend, out, resume, progress, log, summary_interval)
    finally:
        lock.release()


SWEEP_LOCK_NAME = "sweep-output-directory"  # no run's output has this name: a run's ends in a format's suffix


def _lock_output_directory(out: Path):
    """The held lock of a sweep's output directory (filelock, in output_file.lock_directory, named by the
    directory's device and inode, so every path to it finds the same lock), or OutputBusyError at once."""
    from filelock import FileLock, Timeout

    from ...output.output_file import lock_path

    path = lock_path(Path(os.path.realpath(out)) / SWEEP_LOCK_NAME)
    lock = FileLock(str(path), timeout=0)
    try:
        lock.acquire(timeout=0)
    except Timeout:
        raise OutputBusyError(f"cannot run the sweep into {out}: another sweep is writing that directory now (it "
                              f"holds the lock {path}); wait for it to finish, or choose another output directory"
                              ) from None
    except OSError as exc:
        raise OutputError(f"cannot create the lock of the sweep's output directory {out}, {path}: "
                          f"{exc.strerror or exc}") from None
    return lock


def _refuse_the_sweep_files_directory(sweep: Sweep, out: Path) -> None:
    from ...output.output_file import OutputNameError

    try:
        holds = os.path.samefile(out, Path(sweep.file).parent)
    except OSError:  # the output directory does not exist yet: it holds nothing
        return
    if holds:
        raise OutputNameError(f"{sweep.file}: the output directory {out} is the sweep file's own directory, where "
                              "the summary and the caches could overwrite it or its scene: choose another output "
                              "directory ([sweep] output, or --output)")



def _refuse_foreign_summaries(sweep: Sweep, out: Path) -> None:
    """Refuse to run when ``sweep.csv`` or ``sweep.md`` in ``out`` is not this sweep's summary."""
    for name, marker in summary_markers(sweep).items():
        path = out / name
        try:
            info = os.lstat(path)
        except FileNotFoundError:
            continue
        except OSError as exc:
            raise OutputError(f"cannot check {path}: {exc.strerror or exc}") from None
        ours = False
        if stat.S_ISREG(info.st_mode):
            try:
                with open(path, "rb") as f:
                    ours = f.read(len(marker)) == marker
            except OSError:
                pass
        if not ours:
            raise OutputError(f"{path} is not a summary of {sweep.file} (this sweep writes its summary there and "
                              "would overwrite it): move it away, or choose another output directory "
                              "([sweep] output, or --output)")


def _run_sweep(sweep: Sweep, backend, out: Path, resume: bool, progress: bool, log: Callable[[str], None] | None,
               summary_interval: float) -> SweepResult:
    started = time.perf_counter()
    rows: list[dict] = []
    todo = []
    result = SweepResult(rows=rows)
    for v in sweep.variants:
        row = done_row(sweep, v, out) if resume else None
        if row is None:
            row = _base_row(sweep, v, cache_path(sweep, v, out))
            todo.append(v)
            (out / f"{v.name}.json").unlink(missing_ok=True)  # a stale sidecar never vouches for a new cache
        else:
            result.resumed.append(v.index)
        rows.append(row)
    summary = Summary(sweep, out, rows, backend.description, backend.timing_note, summary_interval)
    result.csv, result.md = out / "sweep.csv", out / "sweep.md"
    summary.update(force=True)
    if log and result.resumed:
        log(f"resuming: {len(result.resumed)} of {len(rows)} variants already done in {out}")

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(rows), initial=len(result.resumed), unit="variant", desc="sweep", file=sys.stderr,
                   dynamic_ncols=True)
    by_index = {v.index: v for v in todo}
    tasks = [(v.index, {"scene": v.scene, "output": str(cache_path(sweep, v, out)), "name": v.name}) for v in todo]
    outcomes = backend.run(run_variant, tasks)
    try:
        for outcome in outcomes:
            v = by_index[outcome.key]
            row = rows[v.index]
            if outcome.status == "done":
                value = dict(outcome.value)
                for name, data in value.pop("_files", {}).items():
                    atomic_write(out / name, data)
                row.update(value)
            else:
                row.update(status=outcome.status, error=outcome.error)
            retries = getattr(outcome, "retries", 0)
            row.update(retries=retries, retry_reason=getattr(outcome, "retry_reason", None))
            if retries and log:
                # Said on the console as it happens, beside the summary's columns: the variant's worker died.
                with _beside(bar, sys.stderr):
                    log(f"variant {v.name}: {row['retry_reason']}; retried: {row['status']}")
            if not Path(row["output"]).exists():
                row["output"] = ""  # nothing was written (a failure before the first frame)
            result.ran.append(v.index)
            # The cache's digest ties the sidecar to this cache: a cache swapped in later is not vouched for.
            digest = file_sha256(Path(row["output"])) if row["status"] == "ok" else None
            atomic_write(out / f"{v.name}.json", json.dumps(
                {"hash": v.hash, "params": v.params, "cache_sha256": digest,
                 **{k: row.get(k) for k in COLUMNS_AFTER}}, indent=1, default=repr))
            summary.update()
            if bar is not None:
                bar.update(1)
                if row["status"] != "ok":
                    bar.set_postfix_str(f"{len(result.failed)} not ok", refresh=False)
    except KeyboardInterrupt:
        outcomes.close()  # stops the backend's workers
        result.interrupted = True
        from ...output.output_file import partial_path

        for row in rows:
            if row["status"] == "pending":
                # Its frames so far, if any, are in the partial file (output_file.py); the cache was not written.
                partial = partial_path(Path(row["output"]))
                row.update(status="interrupted", error="the sweep was interrupted before this variant finished",
                           output=str(partial) if partial.exists() else "")
        raise
    finally:
        if bar is not None:
            bar.close()
        result.elapsed = time.perf_counter() - started
        result.ran.sort()
        summary.update(force=True)
    return result
