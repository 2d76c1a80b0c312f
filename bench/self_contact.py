"""Self-collision's cost and how well it holds: a cloth folded in half and dropped on the ground, with and without
``self_collision``.

    python -m bench.self_contact [--sizes 64 128] [--frames 60] [--substeps 8] [--iterations 8]
                                 [--strides 1 2] [--device cpu] [--out bench/results]
    python -m bench.self_contact --device cuda --sizes 256 1024 --substeps 32
    python -m bench.self_contact --peer [...]   # beside NVIDIA Newton, when installed (bench/newton_self_contact.py)

--out writes self_contact.md and self_contact.csv there; bench/results/self_contact.md keeps a reading of the
measured run above its table, to carry over when the run is repeated.

The cloth: n x n particles, a 1 m square of 0.3 kg, structural + shear + bend sticks (bend compliance 1 m/N),
laid horizontal, folded in half between its two middle columns (the right half over the left, round a half circle,
1.5 thicknesses above it), 0.1 m above a ground plane (friction 0.5), released at rest: the upper layer lands on
the lower one at about 1.4 m/s, so nearly every particle is in contact from then on (about 0.15 s in). 60 fps,
--substeps substeps and --iterations sweeps, damping 0.5 /s; the thickness is the default, 0.8 x the spacing
1 / (n - 1) m. Keep a particle's move per substep (about 1.4 m/s x dt) under half the thickness: 8 substeps do
up to 128 x 128, 1024 x 1024 needs about 32. On the CPU, one thread (``Simulator(..., threads=1)``).
--strides runs the contact once per ``self_collision_stride``: with a stride k, every k-th particle along the rows
and columns collides, at the default thickness of its spacing, 0.8 k / (n - 1) m, and the fold's gap is 1.5 of
that thickness.

Columns: ms/frame (the median frame's wall time over --frames frames, frame 1 excluded as the warm-up; the
median, since other work on a shared machine slows some frames), the same with self-collision as a multiple of
without, and the worst penetration over the run, 1 - (least distance between two particles that were not rest
neighbours) / thickness, taken at the end of every frame (after timing it) by a hash-grid query on the device
(0: no pair closer than the thickness; 1: two particles at one point); with a stride, over the colliding particles
at their thickness. The run without self-collision shows how far the same cloth passes through itself.
"approach": the fastest relative move per substep of colliding particles near each other, over the thickness, as
``warp-verlet run`` reads it for its summary's warning (warp_verlet/apps/contact_speed.py), which it gives above 0.5.

--peer adds NVIDIA Newton's rows for the same scene (bench/newton_self_contact.py, which lists what differs):
newton-vbd (SolverVBD, its particle self-contact off and on) and newton-style3d (SolverStyle3D, its collision
handler's self-contact off and on), measured the same way, with a "simulator" column and a "graph" column (whether
a frame ran as one captured graph: warp-verlet captures on the CPU too, but not a CUDA frame with self-collision;
Newton's rows capture on CUDA only). Without Newton it prints "Newton not installed: skipped" and the table
has warp-verlet's rows alone.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.apps.contact_speed import ContactSpeedWatch
from warp_verlet.constraints.self_contact import DEFAULT_FRACTION, REST_EXCLUSION, colliding_particles
from warp_verlet.core.simulator import Simulator
from warp_verlet.input.scene import parse_scene

from . import newton_self_contact
from .common import arg_parser, machine, quiet_warp, timed_frames, write_table

STEM = "self_contact"
SIZE, MASS, HEIGHT = 1.0, 0.3, 0.1  # m, kg, m above the ground


def folded_scene(n: int, self_collision: bool, frames: int, substeps: int, iterations: int, stride: int = 1):
    cloth = {"name": "sheet", "resolution": [n, n], "size": [SIZE, SIZE], "origin": [-0.5, HEIGHT, -0.5],
             "orientation": "horizontal", "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 1.0},
             "mass": MASS, "self_collision": self_collision}
    if self_collision and stride > 1:
        cloth["self_collision_stride"] = stride
    ground = {"type": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0], "friction_coefficient": 0.5}
    return parse_scene({"simulation": {"fps": 60, "frames": frames, "substeps": substeps, "iterations": iterations,
                                       "damping": 0.5}, "cloth": [cloth], "collider": [ground]}, file="<bench>")


def folded(rest: np.ndarray, spacing: float, thickness: float) -> np.ndarray:
    """The rest sheet (a grid ``spacing`` m apart) folded in half between its two middle columns, the right half
    laid over the left a gap of 1.5 thicknesses above it, round a half circle (the sticks keep about their
    lengths)."""
    x = rest.astype(np.float64).copy()
    crease = 0.5 * (x[:, 0].min() + x[:, 0].max()) - 0.5 * spacing
    radius = 0.75 * thickness
    over = x[:, 0] > crease
    along = x[over, 0] - crease
    angle = np.minimum(along, np.pi * radius) / radius
    x[over, 0] = crease + radius * np.sin(angle) - np.maximum(along - np.pi * radius, 0.0)
    x[over, 1] += radius * (1.0 - np.cos(angle))
    return x


@wp.kernel
def least_gap(grid: wp.uint64, x: wp.array(dtype=wp.vec3), rest: wp.array(dtype=wp.vec3), thickness: float,
              exclusion: float, out: wp.array(dtype=float)):
    """The least distance / thickness over pairs closer than the thickness that were not rest neighbours
    (atomic min: the minimum does not depend on the order)."""
    i = wp.tid()
    query = wp.hash_grid_query(grid, x[i], thickness)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        if j != i and wp.length(rest[i] - rest[j]) >= exclusion * thickness:
            d = wp.length(x[i] - x[j])
            if d < thickness:
                wp.atomic_min(out, 0, d / thickness)


class PointsGapMeter:
    """The worst penetration of given positions, measured on ``device``; ``rest``: the particles' rest positions,
    in the order the positions come in."""

    def __init__(self, rest: np.ndarray, thickness: float, device):
        self.device, self.thickness = wp.get_device(device), thickness
        self.grid = wp.HashGrid(128, 128, 128, device=self.device)
        self.points = wp.empty(len(rest), dtype=wp.vec3, device=self.device)
        self.rest = wp.array(np.asarray(rest, dtype=np.float32), dtype=wp.vec3, device=self.device)
        self.out = wp.empty(1, dtype=float, device=self.device)

    def penetration_of(self, positions: np.ndarray) -> float:
        self.points.assign(np.asarray(positions, dtype=np.float32))  # float32 or float64 positions alike
        self.grid.build(self.points, self.thickness)
        self.out.fill_(1.0)
        wp.launch(least_gap, len(self.points), inputs=[wp.uint64(self.grid.id), self.points, self.rest, self.thickness,
                                                       REST_EXCLUSION, self.out], device=self.device)
        return 1.0 - float(self.out.numpy()[0])


class GapMeter(PointsGapMeter):
    """The worst penetration at a frame end, measured on the simulator's device."""

    def __init__(self, sim: Simulator, thickness: float):
        super().__init__(sim.model.rest_positions, thickness, sim.device)
        self.sim = sim

    def penetration(self) -> float:
        return self.penetration_of(self.sim.positions())


def run(n: int, self_collision: bool, frames: int, substeps: int, iterations: int, device: str,
        stride: int = 1) -> dict:
    """One drop, timed, with the worst penetration at the frame ends: of every particle at the thickness, or with
    a stride of the colliding particles at theirs (the particles between them are not spheres of it)."""
    scene = folded_scene(n, self_collision, frames, substeps, iterations, stride)
    thickness = DEFAULT_FRACTION * stride * SIZE / (n - 1)
    start = time.perf_counter()
    sim = Simulator(scene, device, threads=1)
    build = time.perf_counter() - start
    sim.state.set_positions(folded(sim.model.rest_positions, SIZE / (n - 1), thickness))
    colliding = colliding_particles(scene.cloths[0])  # the scene's order, which a grid's device order is
    meter = PointsGapMeter(sim.model.rest_positions[colliding], thickness, sim.device)
    readings = []
    watch = ContactSpeedWatch(scene, sim.model, gate=0.0)  # every frame's moves, not only those past 0.5
    watch.observe(0, sim.positions(), substeps)

    def after_frame():
        points = sim.positions()
        readings.append(meter.penetration_of(points[colliding]))
        watch.observe(len(readings), points, substeps)

    times = timed_frames(sim, frames, after_frame)
    worst = max([0.0, *readings])
    return {"n": n, "self_collision": "on" if self_collision else "off", "particles": n * n,
            "stride": stride if self_collision else "", "thickness mm": round(1e3 * thickness, 3),
            "ms/frame": round(1e3 * statistics.median(times[1:]), 3), "worst penetration": round(worst, 4),
            "approach": round(watch.worst / watch.thickness, 3) if watch.active else "",
            "build s": round(build, 2), "graph": sim.replays_frames}


def main(argv: list[str] | None = None) -> int:
    parser = arg_parser("bench.self_contact", __doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128], help="particles along each side")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=8, help="sweeps per substep")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--out", type=Path, default=None, help="directory for self_contact.md and .csv")
    parser.add_argument("--strides", type=int, nargs="+", default=[1],
                        help="self_collision_stride values to run with contact on (1: every particle collides)")
    parser.add_argument("--peer", action="store_true",
                        help="also run NVIDIA Newton's VBD and Style3D solvers on the scene, when Newton is installed")
    args = parser.parse_args(argv)
    if any(n < 4 for n in args.sizes) or args.frames < 2:
        parser.error("each size needs 4 particles a side or more, and --frames at least 2")
    quiet_warp()
    if args.peer and not newton_self_contact.available():
        print(newton_self_contact.SKIP_MESSAGE)
        args.peer = False
    if any(k < 1 for k in args.strides):
        parser.error("each stride needs to be 1 or more")
    rows = []
    for n in args.sizes:
        without = run(n, False, args.frames, args.substeps, args.iterations, args.device)
        runs = [without] + [run(n, True, args.frames, args.substeps, args.iterations, args.device, k)
                            for k in args.strides if k < n]
        for row in runs:
            row["x without"] = round(row["ms/frame"] / without["ms/frame"], 2)
            rows.append({"simulator": "warp-verlet", **row})
        if args.peer:
            rows += newton_self_contact.peer_rows(n, args.frames, args.substeps, args.iterations, args.device)
    where = machine(args.device)
    command = ["bench.self_contact", *(sys.argv[1:] if argv is None else argv)]
    on = "one CPU thread" if wp.get_device(args.device).is_cpu else str(where)
    title = (f"Self-collision: a folded 1 m cloth dropped on the ground, {args.frames} frames at 60 fps, "
             f"{args.substeps} substeps, {args.iterations} sweeps, {on}\n\n" + "\n".join(where.lines(command)))
    columns = ["n", "particles", "self_collision", "stride", "thickness mm", "ms/frame", "x without",
               "worst penetration", "approach", "build s"]
    if args.peer:
        columns = ["simulator", *columns, "graph"]
    write_table([{k: row.get(k, "") for k in columns} for row in rows], args.out, STEM, title, columns)
    return 0


if __name__ == "__main__":
    sys.exit(main())
