"""What writing the USD cache costs, and how much of it the background writer hides.

    python -m bench.overlap --device cpu --sizes 64 128 256
    python -m bench.overlap --device cuda --sizes 256 1024 --out bench/results/h200

For each hanging-cloth grid (4 substeps x 8 iterations, --frames frames), three wall times per frame:

- simulation only: step the frame, copy the positions to the host, run the divergence check (what a run
  does besides writing);
- sequential: ``run_scene(overlap=False)``, each frame written before the next is simulated;
- overlapped: ``run_scene()``, frames written on a background thread while the next one is simulated.

"hidden" is the share of the writing time that overlap removes: (sequential - overlapped) / (sequential -
simulation only). Each figure is the median of --repeats runs, after a warm-up run that compiles the
kernels. The cache goes to a temporary directory.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import warp as wp

from warp_verlet.apps.runner import run_scene
from warp_verlet.core.simulator import Simulator

from .common import arg_parser, hanging_cloth, machine, quiet_warp, write_table


def simulate_only(scene, device: str) -> float:
    sim = Simulator(scene, device)
    start = time.perf_counter()
    for _ in range(scene.simulation.frames):
        sim.step_frame()
        sim.positions()
        sim.diverged_particle()
    return time.perf_counter() - start


def written(scene, device: str, overlap: bool) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        return run_scene(scene, Path(tmp) / "cache.usdc", device=device, overlap=overlap).wall_seconds


def measure(n: int, device: str, frames: int, repeats: int) -> dict:
    scene = hanging_cloth(n, frames=frames)
    written(scene, device, True)  # warm-up: kernel compilation, first graph capture
    per_frame = {}
    for name, run in (("simulation only", lambda: simulate_only(scene, device)),
                      ("sequential", lambda: written(scene, device, False)),
                      ("overlapped", lambda: written(scene, device, True))):
        per_frame[name] = statistics.median(run() for _ in range(repeats)) / frames
    writing = per_frame["sequential"] - per_frame["simulation only"]
    hidden = (per_frame["sequential"] - per_frame["overlapped"]) / writing if writing > 0 else float("nan")
    return {"grid": f"{n}x{n}", **{f"{k} ms/frame": f"{v * 1e3:.2f}" for k, v in per_frame.items()},
            "write ms/frame": f"{writing * 1e3:.2f}", "hidden": f"{hidden * 100:.0f}%"}


def main(argv=None) -> int:
    p = arg_parser("bench.overlap", __doc__)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", type=Path, default=None, help="write overlap.md/.csv here")
    args = p.parse_args(argv)
    quiet_warp()
    device = wp.get_device(args.device)
    rows = [measure(n, str(device), args.frames, args.repeats) for n in args.sizes]
    title = (f"USD writing overlapped with simulation, hanging cloth, 4 substeps x 8 iterations, {args.frames} frames: "
             f"{machine(device)}")
    write_table(rows, args.out, "overlap", title)
    return 0


if __name__ == "__main__":
    sys.exit(main())
