"""What the sweep tests share: tiny base scenes and sweep files, reading a cache back with pxr, and task functions
for the backends that the spawned workers import from here (tests/ is on sys.path, and spawn passes sys.path on)."""

from __future__ import annotations

import csv
import os
import signal
from pathlib import Path

import numpy as np

# A 4 x 4 cloth, pinned at two corners, 3 frames: a variant runs in well under a second once Warp has loaded.
BASE_SCENE = """\
[simulation]
frames = 3
substeps = 2
iterations = 2

[[cloth]]
name = "sheet"
resolution = [4, 4]
size = [1.0, 1.0]
origin = [-0.5, 1.0, 0.0]
orientation = "horizontal"  # level, so that it swings down: hung where it hangs, its tethers hold it still
pins = ["top-left", "top-right"]
"""

# Unpinned, so that a huge gravity makes it diverge (a pinned cloth's tethers would hold it).
FALLING_SCENE = """\
[simulation]
frames = 3
substeps = 1
iterations = 1

[[cloth]]
name = "sheet"
resolution = [3, 3]
size = [1.0, 1.0]
origin = [-0.5, 1.0, 0.0]
"""

# 2 x 2: the resolution tells the variants' caches apart by point count, the substeps change the stretch.
GRID_SWEEP = """\
[sweep]
scene = "base.toml"
output = "{out}"

[axes]
"cloth.0.resolution" = [[4, 4], [5, 3]]
simulation.substeps = [1, 2]
"""

# Gravity -1e30 m/s^2 sends the unpinned cloth past position_bound in the first frame.
DIVERGING_SWEEP = """\
[sweep]
scene = "falling.toml"
output = "{out}"

[axes]
"simulation.gravity" = [[0.0, -9.81, 0.0], [0.0, -1.0e30, 0.0], [0.0, -5.0, 0.0]]
"""


def write_sweep(tmp_path: Path, sweep: str = GRID_SWEEP, name: str = "sweep.toml", out: str = "out") -> Path:
    (tmp_path / "base.toml").write_text(BASE_SCENE)
    (tmp_path / "falling.toml").write_text(FALLING_SCENE)
    path = tmp_path / name
    path.write_text(sweep.format(out=str(tmp_path / out)))
    return path


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def read_cache(path: Path) -> dict:
    """The cache's frame range, and each frame's points of its one cloth, as float64 (frames + 1, N, 3)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    mesh = next(UsdGeom.PointBased(p) for p in stage.Traverse() if p.IsA(UsdGeom.PointBased))
    attr = mesh.GetPointsAttr()
    times = attr.GetTimeSamples()
    points = np.stack([np.asarray(attr.Get(t), dtype=np.float64) for t in times])
    return {"start": stage.GetStartTimeCode(), "end": stage.GetEndTimeCode(), "times": list(times), "points": points}


def structural_stretch(points: np.ndarray, rows: int, cols: int) -> tuple[float, float]:
    """RMS and max |D - L| / L over the grid's structural sticks at the last frame, with L from frame 0 (the rest
    pose): recomputed from the cache alone, independently of the simulator."""
    ids = np.arange(rows * cols).reshape(rows, cols)
    a = np.concatenate([ids[:, :-1].ravel(), ids[:-1, :].ravel()])
    b = np.concatenate([ids[:, 1:].ravel(), ids[1:, :].ravel()])
    rest = np.linalg.norm(points[0, a] - points[0, b], axis=1)
    now = np.linalg.norm(points[-1, a] - points[-1, b], axis=1)
    s = np.abs(now - rest) / rest
    return float(np.sqrt(np.mean(s * s))), float(s.max())


# ---------------------------------------------------------------------------------------------- backend tasks

def square(payload, slot):
    """A task: the payload squared, with the slot's device, and this process's id."""
    return {"value": payload * payload, "device": slot.device, "pid": os.getpid()}


def square_or_die(payload, slot):
    """A task whose payload 13 kills its own worker process, as the out-of-memory killer would."""
    if payload == 13:
        os.kill(os.getpid(), signal.SIGKILL)
    if payload == 7:
        raise ValueError("seven is refused")
    return square(payload, slot)


def square_unless_killed(payload: dict, slot):
    """A task: ``value`` squared, after waiting for every file in ``wait_for`` to exist and then ``sleep`` seconds.
    ``die``: "always" kills its own worker process (SIGKILL, as the out-of-memory killer would); a path kills it the
    first time only (when that file is not there yet: it is created first), so that the retry succeeds.
    ``started`` and ``finished``: files created first of all and last of all (what another task's ``wait_for``
    waits for); ``first``: a file created on the first run, so that a second run waits for nothing."""
    import time

    if payload.get("started"):
        Path(payload["started"]).touch()
    die = payload.get("die")
    if die == "always" or (die is not None and not os.path.exists(die)):
        if die != "always":
            Path(die).touch()
        os.kill(os.getpid(), signal.SIGKILL)
    first = payload.get("first")  # a file: when it is there already, this is a second run, which waits for nothing
    if first is None or not os.path.exists(first):
        if first is not None:
            Path(first).touch()
        deadline = time.monotonic() + 120
        while not all(os.path.exists(f) for f in payload.get("wait_for", ())) and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(payload.get("sleep", 0.0))
    if payload.get("finished"):
        Path(payload["finished"]).touch()
    return square(payload["value"], slot)
