"""Throughput of the full simulator on a hanging cloth, with the error each figure bought.

    python bench/throughput.py --device cpu --sizes 64 128 256
    python bench/throughput.py --device cuda --sizes 64 256 1024 2048 --out bench/results/h100

For each grid: ms per frame (4 substeps x 8 iterations, after a warm-up frame that keeps compilation out;
median of repeated batches, with the spread), stick projections per second, colour count, device memory
per particle, and the constraint error reached: RMS and max relative stretch |D - L|/L over structural
sticks at the end of the timed frames.
"""

from __future__ import annotations

import argparse
import sys
from datetime import date
from pathlib import Path

import warp as wp

sys.path.insert(0, str(Path(__file__).parent))
from common import copy_bandwidth, device_bytes, hanging_cloth, machine, median_spread, time_frames, write_table  # noqa: E402

from warp_verlet.simulator import Simulator  # noqa: E402


def measure(n: int, device: str, frames: int, repeats: int, use_graph: bool, substeps: int, iterations: int) -> dict:
    scene = hanging_cloth(n, substeps, iterations)
    sim = Simulator(scene, device, use_graph=use_graph)
    sim.step_frame()  # warm-up: compiles kernels, initialises the Verlet state
    sim.step_frame()  # on CUDA: captures the frame graph
    per_frame, spread = median_spread(time_frames(sim, frames, repeats))
    projections = sim.model.stick_count * substeps * iterations
    stretch = sim.stretch()
    return {
        "grid": f"{n}x{n}",
        "particles": sim.model.particle_count,
        "sticks": sim.model.stick_count,
        "colours": sim.model.colour_count,
        "ms/frame": f"{per_frame * 1e3:.3f}",
        "spread": f"±{spread * 100:.1f}%",
        "Mproj/s": f"{projections / per_frame / 1e6:.1f}",
        "bytes/particle": f"{device_bytes(sim) / sim.model.particle_count:.0f}",
        "stretch rms": f"{stretch.rms:.2e}",
        "stretch max": f"{stretch.max:.2e}",
        "frames timed": frames * repeats,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128, 256])
    p.add_argument("--frames", type=int, default=None, help="frames per timed batch (default: by size)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--substeps", type=int, default=4)
    p.add_argument("--iterations", type=int, default=8)
    p.add_argument("--no-graph", action="store_true", help="CUDA: launch kernels one by one, no graph replay")
    p.add_argument("--out", type=Path, default=None, help="write throughput.md/.csv here")
    args = p.parse_args(argv)
    wp.config.quiet = True
    device = wp.get_device(args.device) if args.device else wp.get_device()
    rows = []
    for n in args.sizes:
        frames = args.frames or max(2, min(60, int(2_000_000 / (n * n)) if device.is_cpu else 60))
        rows.append(measure(n, str(device), frames, args.repeats, not args.no_graph, args.substeps, args.iterations))
        print(rows[-1], flush=True)
    title = (f"Hanging cloth, {args.substeps} substeps x {args.iterations} iterations, coloured Gauss-Seidel"
             f"{'' if device.is_cpu or not args.no_graph else ', no graph capture'}: {machine(device)}, {date.today()}")
    if device.is_cuda:
        title += f"; device copy {copy_bandwidth(device):.0f} GB/s (read + write)"
    write_table(rows, args.out, "throughput" + ("-nograph" if args.no_graph and device.is_cuda else ""), title)
    return 0


if __name__ == "__main__":
    sys.exit(main())
