"""Throughput of the full simulator on a hanging cloth, with the error each figure bought.

    python -m bench.throughput --device cpu --sizes 64 128 256
    python -m bench.throughput --device cuda --sizes 64 256 1024 2048 --out bench/results/h100
    python -m bench.throughput --device cpu --sizes 64 --colliders --tear 1.5   # every stage present
    python -m bench.throughput --device cpu --sizes 256 --threads 1             # one core only

Each grid simulates the same 60 frames (1 s at 60 fps, 4 substeps x 8 iterations). Frames 1-2 are a
warm-up that keeps compilation and graph capture out; frames 3-60 are timed in ``--repeats`` equal batches
and the median batch gives ms per frame (the spread is half the range). Reported beside it: stick
projections per second, colour count, device memory per particle and per stick, and the error that speed
bought: RMS and max relative stretch |D - L|/L over structural sticks at frame 60. On the CPU the
relaxation runs on ``--threads`` threads (default: the simulator's own choice from the cores and the grid
size; the "threads" column says what it used).

A second table breaks a frame down by stage (integrate, relax, collide, tear, USD write): each stage of
the simulator's ``stages()`` is run on its own for 12 substeps with a device synchronisation around it (so
on CUDA these are launch-by-launch figures, without graph replay), scaled to one frame. A stage the scene
does not have is never run and shows 0. ``USD write`` is the host copy plus one ``write_frame`` into a
temporary .usdc. "relax GB/s" is the bytes the relaxation must move (RELAX_BYTES_PER_PROJECTION per stick
projection) over its measured time; on CUDA it is also given as a share of the card's device-to-device
copy rate, measured in the same run.
"""

from __future__ import annotations

import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import warp as wp

from warp_verlet.colliders.plane import PlaneCollider
from warp_verlet.colliders.sphere import SphereCollider
from warp_verlet.core.simulator import Simulator

from .common import (arg_parser, copy_bandwidth, device_arrays, hanging_cloth, machine, median_spread, quiet_warp,
                     time_frames, write_table)


FRAMES, WARM_UP = 60, 2
STAGES = ("integrate", "relax", "collide", "tear", "USD write")
STAGE_SUBSTEPS = 12
# Bytes one stick projection must move in relax_colour: its ends (vec2i), rest and weight, both inverse
# masses, and both positions read and written. Caches can only lower the real traffic (neighbouring sticks
# share particles), so bytes / time is a lower bound on the bandwidth the kernel reaches.
RELAX_BYTES_PER_PROJECTION = 8 + 4 + 4 + 2 * 4 + 2 * 12 + 2 * 12


def bench_scene(n: int, substeps: int, iterations: int, colliders: bool, tear: float | None):
    """The hanging cloth, optionally with a ball it drapes over and a ground plane, and a tear threshold."""
    scene = hanging_cloth(n, substeps, iterations)
    if colliders:
        scene = replace(scene, colliders=(
            SphereCollider("ball", 0.15, ((0.0, (0.0, 0.5, 0.1)),), thickness=0.005, friction_coefficient=0.3),
            PlaneCollider("ground", (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), friction_coefficient=0.5),
        ))
    if tear is not None:
        scene = replace(scene, cloths=tuple(replace(c, tear_threshold=tear) for c in scene.cloths))
    return scene


def stage_breakdown(sim: Simulator) -> dict[str, float]:
    """ms per frame spent in each stage, run one stage at a time (see the module docstring)."""
    from warp_verlet.output.usd_writer import CachedShape, PointCacheWriter

    seconds = dict.fromkeys(STAGES, 0.0)
    dt = sim.settings.dt
    with wp.ScopedDevice(sim.device):
        for _ in range(STAGE_SUBSTEPS):
            for name, run in sim.stages():
                wp.synchronize_device(sim.device)
                start = time.perf_counter()
                run(dt)
                wp.synchronize_device(sim.device)
                seconds[name] += time.perf_counter() - start
    per_frame = {k: v / STAGE_SUBSTEPS * sim.settings.substeps for k, v in seconds.items()}
    shapes = [CachedShape(s.name, s.topology.faces, s.topology.uvs, s.count) for s in sim.model.cloths]
    with tempfile.TemporaryDirectory() as tmp:
        with PointCacheWriter(Path(tmp) / "stage.usdc", shapes, fps=sim.settings.fps, save_every=10**9) as writer:
            writes = 3
            start = time.perf_counter()
            for frame in range(writes):
                writer.write_frame(frame, sim.model.split(sim.positions()))
            per_frame["USD write"] = (time.perf_counter() - start) / writes
    return {k: round(v * 1e3, 3) for k, v in per_frame.items()}


def array_bytes(sim: Simulator) -> tuple[int, int]:
    """Device bytes held in per-particle arrays (tethers count as per-particle: one row per tethered particle)
    and in all other arrays (the per-stick ones, and a few bytes of colliders and counters): the Model's, its
    colliders', the State's and the solver's scratch (common.device_arrays; each array once)."""
    m = sim.model
    arrays = device_arrays(sim).values()
    rows = {m.particle_count, m.particle_count + 1, sim.solver.req.tethered or m.particle_count}
    particle = sum(a.capacity for a in arrays if a.shape[0] in rows)
    return particle, sum(a.capacity for a in arrays) - particle


def measure(n: int, device: str, repeats: int, use_graph: bool, substeps: int, iterations: int,
            colliders: bool = False, tear: float | None = None, copy_gbs: float | None = None,
            threads: int | None = None) -> tuple[dict, dict]:
    scene = bench_scene(n, substeps, iterations, colliders, tear)
    sim = Simulator(scene, device, use_graph=use_graph, threads=threads)
    sim.step_frame()  # warm-up: compiles kernels, initialises the Verlet state
    sim.step_frame()  # on CUDA: captures the frame graph
    batch = (FRAMES - WARM_UP) // repeats
    per_frame, spread = median_spread(time_frames(sim, batch, repeats))
    for _ in range(FRAMES - WARM_UP - batch * repeats):
        sim.step_frame()  # so that the error is always read at frame 60
    projections = sim.model.stick_count * substeps * iterations
    stretch = sim.stretch()
    particle_bytes, stick_bytes = array_bytes(sim)
    row = {
        "grid": f"{n}x{n}",
        "particles": sim.model.particle_count,
        "sticks": sim.model.stick_count,
        "colours": sim.model.colour_count,
        "threads": sim.threads,
        "ms/frame": f"{per_frame * 1e3:.3f}",
        "spread": f"±{spread * 100:.1f}%",
        "Mproj/s": f"{projections / per_frame / 1e6:.1f}",
        "ns/proj": f"{per_frame / projections * 1e9:.2f}",
        "bytes/particle": f"{(particle_bytes + stick_bytes) / sim.model.particle_count:.0f}",
        "B/particle arrays": f"{particle_bytes / sim.model.particle_count:.0f}",
        "B/stick arrays": f"{stick_bytes / max(sim.model.stick_count, 1):.0f}",
        "stretch rms": f"{stretch.rms:.2e}",
        "stretch max": f"{stretch.max:.2e}",
        "frames timed": batch * repeats,
    }
    if tear is not None:
        row["torn"] = sim.torn_count()
    stages = {"grid": f"{n}x{n}", **stage_breakdown(sim)}
    relax_gbs = projections * RELAX_BYTES_PER_PROJECTION / (stages["relax"] * 1e-3) / 1e9 if stages["relax"] else 0.0
    stages["relax GB/s"] = f"{relax_gbs:.0f}"
    if copy_gbs:
        stages["of copy"] = f"{relax_gbs / copy_gbs * 100:.0f}%"
    return row, stages


def launch_bound_below(rows: list[dict]) -> str:
    """The smallest grid whose cost per projection is within 1.5x of the best: below it, launch overhead
    (a fixed cost per launch) dominates; from it on, the work does."""
    best = min(float(r["ns/proj"]) for r in rows)
    for r in rows:
        if float(r["ns/proj"]) <= 1.5 * best:
            return (f"launch overhead stops dominating at {r['grid']} ({r['ns/proj']} ns per projection, "
                    f"best {best:.2f})")
    return ""


def main(argv=None) -> int:
    p = arg_parser("bench.throughput", __doc__)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128, 256])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--substeps", type=int, default=4)
    p.add_argument("--iterations", type=int, default=8)
    p.add_argument("--no-graph", action="store_true", help="launch kernels one by one, no graph/capture replay")
    p.add_argument("--threads", type=int, default=None, help="CPU relaxation threads (default: automatic)")
    p.add_argument("--colliders", action="store_true", help="add a ball and a ground plane to the scene")
    p.add_argument("--tear", type=float, default=None, metavar="RATIO", help="give the cloth this tear_threshold")
    p.add_argument("--out", type=Path, default=None, help="write throughput.md/.csv here")
    args = p.parse_args(argv)
    quiet_warp()
    device = wp.get_device(args.device)
    copy_gbs = copy_bandwidth(device) if device.is_cuda else None
    rows, stage_rows = [], []
    for n in args.sizes:
        row, stages = measure(n, str(device), args.repeats, not args.no_graph, args.substeps, args.iterations,
                              args.colliders, args.tear, copy_gbs, args.threads)
        rows.append(row)
        stage_rows.append(stages)
        print(row, flush=True)
    extras = (" + ball and ground" if args.colliders else "") + (f", tear_threshold {args.tear}" if args.tear else "")
    title = (f"Hanging cloth{extras} at 1 s, {args.substeps} substeps x {args.iterations} iterations, coloured "
             f"Gauss-Seidel{', no graph capture' if args.no_graph else ''}: {machine(device)}")
    if copy_gbs:
        title += f"; device copy {copy_gbs:.0f} GB/s (read + write)"
    stem = "throughput" + ("-nograph" if args.no_graph else "") + (f"-{args.threads}thread" if args.threads else "")
    stem += ("-colliders" if args.colliders else "") + ("-tear" if args.tear else "")
    write_table(rows, args.out, stem, title)
    if len(rows) > 1:
        print(launch_bound_below(rows) + "\n")
    write_table(stage_rows, args.out, stem + "-stages", "ms per frame by stage, each stage run on its own "
                f"({STAGE_SUBSTEPS} substeps, synchronised); relax GB/s counts {RELAX_BYTES_PER_PROJECTION} B "
                "per stick projection")
    return 0


if __name__ == "__main__":
    sys.exit(main())
