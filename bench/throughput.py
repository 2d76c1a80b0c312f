"""Throughput of the full simulator on a hanging cloth, with the error each figure bought.

    python bench/throughput.py --device cpu --sizes 64 128 256
    python bench/throughput.py --device cuda --sizes 64 256 1024 2048 --out bench/results/h100

Each grid simulates the same 60 frames (1 s at 60 fps, 4 substeps x 8 iterations). Frames 1-2 are a
warm-up that keeps compilation and graph capture out; frames 3-60 are timed in ``--repeats`` equal batches
and the median batch gives ms per frame (the spread is half the range). Reported beside it: stick
projections per second, colour count, device memory per particle, and the error that speed bought: RMS
and max relative stretch |D - L|/L over structural sticks at frame 60.
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


FRAMES, WARM_UP = 60, 2


def measure(n: int, device: str, repeats: int, use_graph: bool, substeps: int, iterations: int) -> dict:
    scene = hanging_cloth(n, substeps, iterations)
    sim = Simulator(scene, device, use_graph=use_graph)
    sim.step_frame()  # warm-up: compiles kernels, initialises the Verlet state
    sim.step_frame()  # on CUDA: captures the frame graph
    batch = (FRAMES - WARM_UP) // repeats
    per_frame, spread = median_spread(time_frames(sim, batch, repeats))
    for _ in range(FRAMES - WARM_UP - batch * repeats):
        sim.step_frame()  # so that the error is always read at frame 60
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
        "frames timed": batch * repeats,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128, 256])
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
        rows.append(measure(n, str(device), args.repeats, not args.no_graph, args.substeps, args.iterations))
        print(rows[-1], flush=True)
    title = (f"Hanging cloth at 1 s, {args.substeps} substeps x {args.iterations} iterations, coloured Gauss-Seidel"
             f"{'' if device.is_cpu or not args.no_graph else ', no graph capture'}: {machine(device)}, {date.today()}")
    if device.is_cuda:
        title += f"; device copy {copy_bandwidth(device):.0f} GB/s (read + write)"
    write_table(rows, args.out, "throughput" + ("-nograph" if args.no_graph and device.is_cuda else ""), title)
    return 0


if __name__ == "__main__":
    sys.exit(main())
