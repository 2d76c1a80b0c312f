"""A sweep's summary: ``sweep.csv`` and ``sweep.md``, one row per variant, rewritten whole and atomically as
results come in. Each file starts as only this sweep's summary does (:func:`summary_markers`), which is how a
resumed sweep knows it may replace them (running.py).
"""

from __future__ import annotations

import csv
import io
import json
import os
import time
from pathlib import Path
from typing import Any

from .sweep_file import Sweep

# Statuses of a summary row. Only "ok" is ever skipped by a resumed sweep.
STATUSES = ("ok", "diverged", "failed", "killed", "interrupted", "pending")

COLUMNS_BEFORE = ["index", "name"]
COLUMNS_AFTER = ["status", "wall_s", "task_s", "frames", "stretch_rms", "stretch_max", "torn", "device", "host",
                 "resumed", "retries", "retry_reason", "error", "output", "hash"]


def summary_columns(sweep: Sweep) -> list[str]:
    return COLUMNS_BEFORE + sweep.parameter_names + (["sample"] if sweep.random_axes else []) + COLUMNS_AFTER


def atomic_write(path: Path, data: str | bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


class Summary:
    """sweep.csv and sweep.md, rewritten whole and atomically (at most every ``interval`` s, and at the end)."""

    def __init__(self, sweep: Sweep, out: Path, rows: list[dict], backend_text: str, parallel: str,
                 interval: float = 1.0):
        self.sweep, self.out, self.rows = sweep, out, rows
        self.backend_text, self.parallel, self.interval = backend_text, parallel, interval
        self.columns = summary_columns(sweep)
        self.last = 0.0

    def update(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self.last < self.interval:
            return
        self.last = now
        atomic_write(self.out / "sweep.csv", self.csv_text())
        atomic_write(self.out / "sweep.md", self.md_text())

    def csv_text(self) -> str:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=self.columns, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        for r in self.rows:
            writer.writerow({k: _cell(r.get(k)) for k in self.columns})
        return buf.getvalue()

    def md_text(self) -> str:
        counts = {s: sum(1 for r in self.rows if r["status"] == s) for s in STATUSES}
        tally = ", ".join(f"{n} {s}" for s, n in counts.items() if n)
        sweep = self.sweep
        lines = [f"# Sweep {Path(sweep.file).name}", "",
                 f"- sweep file: `{sweep.file}`; base scene: `{sweep.base}`",
                 f"- {len(self.rows)} variants: {tally}",
                 f"- backend: {self.backend_text}",
                 f"- timings: {self.parallel}",
                 "- wall_s: the run's simulation and writing time (`RunSummary.wall_seconds`); task_s: the whole "
                 "variant in its worker, building the simulator and loading kernels included",
                 "- stretch: |D - L| / L over structural sticks at the last frame; torn: sticks torn by the end "
                 "(empty where no cloth can tear)",
                 "- retries: how often a variant was run again because its worker process died (retry_reason: how), "
                 "whatever its status then", ""]
        retried = [r["name"] for r in self.rows if r.get("retries")]
        if retried:
            lines.insert(4, f"- run again after their worker died: {len(retried)} variant(s), "
                         + ", ".join(retried[:20]) + (", ..." if len(retried) > 20 else ""))
        if sweep.random_axes:
            lines.insert(3, f"- random sampler: seed {sweep.seed}, {sweep.samples} samples")
        cols = self.columns
        lines.append("| " + " | ".join(cols) + " |")
        lines.append("|" + "---|" * len(cols))
        for r in self.rows:
            lines.append("| " + " | ".join(_cell(r.get(k), md=True) for k in cols) + " |")
        return "\n".join(lines) + "\n"


def _cell(value: Any, md: bool = False) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple, dict)):
        value = json.dumps(value)
    value = str(value)
    if md:
        value = value.replace("|", "/").replace("\n", " ")
    return value


def summary_markers(sweep: Sweep) -> dict[str, bytes]:
    """How each summary file of this sweep starts (running.py's docstring says why)."""
    empty = Summary(sweep, Path("."), [], "", "")
    md_head = empty.md_text().split("`", 1)[0] + "`"  # "# Sweep NAME", "", "- sweep file: `" (then its path)
    return {"sweep.csv": empty.csv_text().encode(), "sweep.md": md_head.encode()}
