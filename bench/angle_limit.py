"""How closely the angle limit holds on a long chain: the worst joint angle over a run of the 40-link rope of
scenes/rope.toml with ``max_bend_angle``, against the sweeps per substep.

Joints that share particles are projected one colour after another, so a tight limit along a chain converges
as stiff sticks do, by Gauss-Seidel: the overshoot falls with the sweeps.

    python -m bench.angle_limit [--frames 120] [--out bench/results/angle_limit.md]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from warp_verlet.constraints.angle_limit import grid_joints
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator


def rope(limit: float | None, iterations: int) -> dict:
    cloth = {"name": "rope", "resolution": [1, 40], "size": [0.0, 2.0], "origin": [0.0, 2.0, 0.0],
             "orientation": "horizontal", "mass": 0.5, "pins": [0], "sticks": ["structural"]}
    if limit is not None:
        cloth["max_bend_angle"] = limit
    return {"simulation": {"fps": 60, "substeps": 8, "iterations": iterations, "damping": 0.48}, "cloth": [cloth]}


def worst_angle(limit: float | None, iterations: int, frames: int) -> tuple[float, float]:
    """(worst joint angle in degrees over the frames, milliseconds per frame)."""
    sim = Simulator(parse_scene(rope(limit, iterations)), "cpu", threads=1)
    joints = grid_joints(1, 40)
    worst, start = 0.0, time.perf_counter()
    for _ in range(frames):
        sim.step_frame()
        p = sim.positions().astype(np.float64)
        u, v = p[joints[:, 1]] - p[joints[:, 0]], p[joints[:, 2]] - p[joints[:, 1]]
        cosine = (u * v).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        worst = max(worst, float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))).max()))
    return worst, 1e3 * (time.perf_counter() - start) / frames


def cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    rows = ["| max_bend_angle | sweeps | worst joint angle | overshoot | ms/frame (1 CPU thread, with the check) |",
            "|---|---|---|---|---|"]
    for limit in (None, 5.0, 10.0, 30.0):
        for iterations in (16, 32, 64):
            worst, ms = worst_angle(limit, iterations, args.frames)
            over = "–" if limit is None else f"{100 * max(worst - limit, 0.0) / limit:.1f}%"
            rows.append(f"| {'none' if limit is None else limit} | {iterations} | {worst:.3f}° | {over} | {ms:.2f} |")
    text = (f"# The angle limit on the 40-link rope ({args.frames} frames at 60 fps, 8 substeps)\n\n"
            f"Machine: {cpu_name()}, {os.cpu_count()} cores, Python {platform.python_version()}. "
            f"Command: `python -m bench.angle_limit --frames {args.frames}`.\n\n" + "\n".join(rows) + "\n")
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text)


if __name__ == "__main__":
    main()
