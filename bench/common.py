"""Helpers shared by the benchmark scripts: scene construction, timing and table output."""

from __future__ import annotations

import csv
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.scene import parse_scene


def hanging_cloth(n: int, substeps: int = 4, iterations: int = 8, solver: str = "coloured", frames: int = 60):
    """The benchmark scene: an n x n, 1 m cloth pinned at its top corners, all three stick families."""
    return parse_scene({
        "simulation": {"fps": 60, "frames": frames, "substeps": substeps, "iterations": iterations,
                       "drag": 0.999, "solver": solver},
        "cloth": [{"name": "sheet", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 1.0, 0.0],
                   "mass": 0.2, "pins": ["top-left", "top-right"],
                   "sticks": {"structural": 1.0, "shear": 1.0, "bend": 0.5}}],
    }, file=f"<hanging cloth {n}x{n}>")


def time_frames(sim, frames: int, repeats: int) -> list[float]:
    """Seconds per frame for ``repeats`` batches of ``frames`` frames, synchronised around each batch."""
    out = []
    for _ in range(repeats):
        wp.synchronize_device(sim.device)
        start = time.perf_counter()
        for _ in range(frames):
            sim.step_frame()
        wp.synchronize_device(sim.device)
        out.append((time.perf_counter() - start) / frames)
    return out


def median_spread(values: list[float]) -> tuple[float, float]:
    """Median and half the range, as a fraction of the median."""
    med = statistics.median(values)
    return med, (max(values) - min(values)) / (2 * med) if med else 0.0


def machine(device) -> str:
    if device.is_cuda:
        return f"{device.name} (CUDA), Warp {wp.__version__}"
    return f"CPU {platform.processor() or platform.machine()}, Warp {wp.__version__}"


def copy_bandwidth(device, mib: int = 1024, repeats: int = 20) -> float:
    """Device-to-device copy rate in GB/s, counting bytes read plus bytes written."""
    n = mib * (1 << 20) // 4
    src = wp.array(np.random.default_rng(0).random(n, dtype=np.float32), device=device)
    dst = wp.empty_like(src)
    wp.copy(dst, src)
    wp.synchronize_device(device)
    start = time.perf_counter()
    for _ in range(repeats):
        wp.copy(dst, src)
    wp.synchronize_device(device)
    return 2 * src.capacity * repeats / (time.perf_counter() - start) / 1e9


def write_table(rows: list[dict], out_dir: Path | None, stem: str, title: str) -> str:
    """Print a markdown table and, with ``out_dir``, write it as .md and .csv."""
    keys = list(rows[0])
    lines = [f"### {title}", "", "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(str(r[k]) for k in keys) + " |" for r in rows]
    text = "\n".join(lines) + "\n"
    print(text)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / f"{stem}.md").write_text(text)
        with open(out_dir / f"{stem}.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=keys)
            writer.writeheader()
            writer.writerows(rows)
    return text


# ---------------------------------------------------------------- additions for work_precision / cpu_reference

def quiet_warp() -> None:
    """Silence Warp's banner and module-load lines: ``config.quiet`` up to Warp 1.x, ``log_level`` after."""
    wp.config.quiet = True
    if hasattr(wp.config, "log_level") and hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (Linux), else what the platform module says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_lines(command: list[str] | None = None) -> list[str]:
    """Markdown bullet lines describing where and how a CPU benchmark ran."""
    import os
    import shlex
    import sys
    from datetime import datetime

    try:
        load = " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        load = "n/a"
    lines = [
        f"- CPU: {cpu_model()}, {os.cpu_count()} logical CPUs; Warp runs one CPU launch on one thread, "
        "warp_verlet cuts each colour over its relaxation threads",
        f"- load average (1 / 5 / 15 min) at the end: {load}",
        f"- Warp {wp.__version__}, numpy {np.__version__}, Python {platform.python_version()}, {platform.system()}",
        f"- date: {datetime.now().isoformat(timespec='seconds')}",
    ]
    if command is not None:
        lines.append(f"- command: `{shlex.join([Path(sys.executable).name] + command)}`")
    return lines
