"""What the benchmark scripts share: scenes, the device arrays a simulator holds, timing, the machine
description and the table writer."""

from __future__ import annotations

import argparse
import csv
import math
import os
import platform
import shlex
import statistics
import sys
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
import numpy as np
import warp as wp

from warp_verlet.input.scene import Scene, parse_scene


def arg_parser(module: str, doc: str) -> argparse.ArgumentParser:
    """The command line of ``python -m module``: the usage line names that command, --help shows ``doc`` as written."""
    return argparse.ArgumentParser(prog=f"python -m {module}", description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def add_compliance_arg(p: argparse.ArgumentParser) -> None:
    """``--compliance FAMILY=M_PER_N ...``: soft stick families (read back with ``compliance_of``)."""
    p.add_argument("--compliance", nargs="+", default=[], metavar="FAMILY=M_PER_N",
                   help="soft stick families in every variant, e.g. bend=1.0 (default: all rigid)")


def compliance_of(p: argparse.ArgumentParser, values: list[str]) -> dict[str, float]:
    """The families' compliances (m/N) given by ``--compliance``; a malformed entry is the parser's error."""
    try:
        return {family: float(value) for family, value in (c.split("=") for c in values)}
    except ValueError:
        p.error("--compliance: give FAMILY=M_PER_N, e.g. bend=1.0")


def quiet_warp() -> None:
    """Silence Warp's banner and module-load lines: ``config.quiet`` up to Warp 1.x, ``log_level`` after."""
    wp.config.quiet = True
    if hasattr(wp.config, "log_level") and hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING


# ---------------------------------------------------------------- scenes

HANGING_FAMILIES = ["structural", "shear", "bend"]
"""The benchmark cloth's stick families, all rigid (the kernel the C and numpy references implement)."""

HANGING_DAMPING = -math.log(0.999) * 240.0
"""1/s: the benchmark cloth's old drag 0.999 per substep at its 240 substeps per second (60 fps x 4), so that
at 4 substeps it keeps the same velocity per substep as before (about 0.24 /s; now the same per second at any
substeps)."""


def damping_for_drag(drag: float, dt: float) -> float:
    """The damping rate (1/s) that keeps ``drag`` of the velocity per step of ``dt`` s, as the old per-substep
    ``drag`` did: exp(-damping dt) = drag to float64 rounding, so the float32 the kernel sees is the same
    (tests/test_golden.py). 0 for drag 1."""
    return -math.log(drag) / dt if drag != 1.0 else 0.0


def scene(simulation: dict, cloths: dict | list, colliders: list | None = None, name: str = "<bench>") -> Scene:
    """A scene from the tables of a scene file (``cloths`` one [[cloth]] table or a list of them); 60 fps and
    4 substeps unless ``simulation`` says otherwise. ``name`` stands for the file in error messages."""
    return parse_scene({"simulation": {"fps": 60, "substeps": 4, **simulation},
                        "cloth": cloths if isinstance(cloths, list) else [cloths],
                        "collider": colliders or []}, file=name)


def hanging_sheet(n: int, **cloth) -> dict:
    """The [[cloth]] table of the benchmark cloth: n x n particles, 1 m, 0.2 kg, pinned at its top corners, all
    three stick families rigid, no tethers (which the C, numpy and Newton peers do not have; bench.convergence
    measures them); keyword arguments override its entries."""
    return {"name": "sheet", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 1.0, 0.0], "mass": 0.2,
            "pins": ["top-left", "top-right"], "sticks": list(HANGING_FAMILIES), "tethers": False, **cloth}


def hanging_cloth(n: int, substeps: int = 4, iterations: int = 8, solver: str = "coloured", frames: int = 60) -> Scene:
    """The benchmark scene: the hanging sheet, vertical, damping HANGING_DAMPING."""
    return scene({"frames": frames, "substeps": substeps, "iterations": iterations, "damping": HANGING_DAMPING,
                  "relaxation": solver}, hanging_sheet(n), name=f"<hanging cloth {n}x{n}>")


def cloth_size(scene: Scene) -> float:
    """The largest ``size`` entry of any cloth (m): what position errors are divided by."""
    return max(max(c.size) for c in scene.cloths)


# ---------------------------------------------------------------- the simulator's arrays

def device_arrays(sim) -> dict[int, wp.array]:
    """Every device array a ``Simulator`` holds, by address: the Model's, its colliders', the State's
    (``state.arrays()``) and the solver's scratch (allocated when the solver first binds a state, so ask after a
    step). An array two of them share (the coloured solver's tear ends are its stick ends) is there once."""
    def arrays_of(obj) -> list[wp.array]:
        return [a for a in vars(obj).values() if isinstance(a, wp.array)]

    found = arrays_of(sim.model) + arrays_of(sim.model.colliders) + list(sim.state.arrays().values())
    for data in sim.model.constraints.values():  # each constraint kind's build, and what its lists hold (levels)
        found += arrays_of(data)
        found += [a for part in vars(data).values() if isinstance(part, list) for item in part
                  if hasattr(item, "__dict__") for a in arrays_of(item)]
    for held in sim.solver._scratch.values():  # scratch arrays, and a stage's working set (the global correction)
        if isinstance(held, wp.array):
            found.append(held)
            continue
        found += arrays_of(held)
        for part in (p for p in vars(held).values() if isinstance(p, list)):  # its sums, its levels' arrays
            found += [a for a in part if isinstance(a, wp.array)]
            found += [a for item in part if hasattr(item, "__dict__") and not isinstance(item, wp.array)
                      for a in arrays_of(item)]
    return {a.ptr: a for a in found}


# ---------------------------------------------------------------- timing

def timed_frames(sim, frames: int, after=None) -> list[float]:
    """Seconds each of ``frames`` ``sim.step_frame()`` calls took, synchronised with its device, calling ``after()``
    after each frame, outside the timing (a measurement of the frame just stepped)."""
    out = []
    for _ in range(frames):
        wp.synchronize_device(sim.device)
        begin = time.perf_counter()
        sim.step_frame()
        wp.synchronize_device(sim.device)
        out.append(time.perf_counter() - begin)
        if after is not None:
            after()
    return out


def time_frames(stepper, frames: int, repeats: int, warm_up: int = 0) -> list[float]:
    """Seconds per frame of ``repeats`` batches of ``frames`` ``stepper.step_frame()`` calls, after ``warm_up``
    untimed frames; each batch is synchronised with the stepper's Warp device when it has one."""
    device = getattr(stepper, "device", None)
    for _ in range(warm_up):
        stepper.step_frame()
    out = []
    for _ in range(repeats):
        if device is not None:
            wp.synchronize_device(device)
        start = time.perf_counter()
        for _ in range(frames):
            stepper.step_frame()
        if device is not None:
            wp.synchronize_device(device)
        out.append((time.perf_counter() - start) / frames)
    return out


def captured(work, device, times: int = 32):
    """A CUDA graph of ``times`` calls of ``work()`` on ``device``, captured without running them."""
    with wp.ScopedCapture(device=device) as capture:
        for _ in range(times):
            work()
    return capture.graph


def graph_median_ms(graph, repeats: int = 7) -> float:
    """The median of ``repeats`` replays of a captured CUDA ``graph``, in milliseconds, each between two CUDA
    events on the current stream."""
    times = []
    for _ in range(repeats):
        begin, end = wp.Event(enable_timing=True), wp.Event(enable_timing=True)
        wp.record_event(begin)
        wp.capture_launch(graph)
        wp.record_event(end)
        wp.synchronize()
        times.append(wp.get_event_elapsed_time(begin, end))
    return float(statistics.median(times))


def median_spread(values: list[float]) -> tuple[float, float]:
    """Median and half the range, as a fraction of the median."""
    med = statistics.median(values)
    return med, (max(values) - min(values)) / (2 * med) if med else 0.0


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


# ---------------------------------------------------------------- the machine

def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (Linux), else what the platform module says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


@dataclass(frozen=True)
class Machine:
    """Where a benchmark ran: ``str()`` gives one line for a table title, ``lines()`` markdown bullets."""
    gpu: str | None  # the CUDA device's name, None on the CPU
    cpu: str
    cpus: int | None
    load: str
    versions: str
    when: datetime

    def __str__(self) -> str:
        where = f"{self.gpu} (CUDA)" if self.gpu else f"CPU {self.cpu}, {self.cpus} logical CPUs"
        return f"{where}, Warp {wp.__version__}, {self.when.date()}"

    def lines(self, command: list[str] | None = None) -> list[str]:
        """Bullets; with ``command`` (the module and its arguments) the command line, run with ``python -m``."""
        if self.gpu:
            where = f"- GPU: {self.gpu} (CUDA); host CPU: {self.cpu}, {self.cpus} logical CPUs"
        else:
            where = (f"- CPU: {self.cpu}, {self.cpus} logical CPUs; Warp runs one CPU launch on one thread, "
                     "warp_verlet cuts each colour over its relaxation threads")
        lines = [where, f"- load average (1 / 5 / 15 min) at the end: {self.load}", f"- {self.versions}",
                 f"- date: {self.when.isoformat(timespec='seconds')}"]
        if command is not None:
            lines.append(f"- command: `{shlex.join([Path(sys.executable).name, '-m', *command])}`")
        return lines


def machine(device=None) -> Machine:
    """The machine, now: CPU model and logical CPUs, the CUDA device's name when ``device`` is one (default:
    Warp's default device), load average, Warp / numpy / Python versions and the date."""
    d = wp.get_device(device)
    try:
        load = " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        load = "n/a"
    versions = (f"Warp {wp.__version__}, numpy {np.__version__}, Python {platform.python_version()}, "
                f"{platform.system()}")
    return Machine(d.name if d.is_cuda else None, cpu_model(), os.cpu_count(), load, versions, datetime.now())


# ---------------------------------------------------------------- tables

def markdown_table(rows: list[dict], columns: list[str] | None = None) -> str:
    """A markdown table of ``rows`` (dicts), one column per key of the first row unless ``columns`` is given;
    a "|" in a cell becomes "/". Its lines, without a newline after the last."""
    keys = columns or list(rows[0])
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(str(r[k]).replace("|", "/") for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def write_csv(path: Path, rows: list[dict], columns: list[str] | None = None) -> Path:
    """``rows`` as CSV with a header line, one column per key of the first row unless ``columns`` is given."""
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns or list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path


def write_table(rows: list[dict], out_dir: Path | None, stem: str, title: str,
                columns: list[str] | None = None) -> str:
    """Print ``### title`` and the markdown table of ``rows``; with ``out_dir``, also write that text to
    ``stem``.md and the rows to ``stem``.csv. The title may run over several paragraphs."""
    text = f"### {title}\n\n{markdown_table(rows, columns)}\n"
    print(text)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / f"{stem}.md").write_text(text)
        write_csv(out_dir / f"{stem}.csv", rows, columns)
    return text
