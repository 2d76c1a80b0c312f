"""GPU time per kernel of one frame, stick arrays against implicit grid sticks (Warp's CUDA activity timing).

    python -m bench.kernel_times --device cuda --size 1024 --budget 4x8

The benchmark's hanging sheet with tethers (bench.implicit_grid), launched kernel by kernel (no graph), after two
warm-up frames; prints each kernel's total GPU time in the frame, its launches, and the frame's sum.
"""

from __future__ import annotations

import sys
from collections import defaultdict

import warp as wp

from warp_verlet.core.simulator import Simulator

from .common import arg_parser, quiet_warp
from .implicit_grid import sheet


def kernel_times(size: int, substeps: int, iterations: int, device: str, sticks: str):
    sim = Simulator(sheet(size, substeps, iterations), device, use_graph=False, sticks=sticks)
    for _ in range(2):
        sim.step_frame()
    wp.synchronize_device(sim.device)
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
    sim.step_frame()
    results = wp.timing_end()
    total: dict[str, list] = defaultdict(lambda: [0.0, 0])
    for r in results:
        name = r.name.split("(")[0].replace("forward kernel ", "")
        total[name][0] += r.elapsed
        total[name][1] += 1
    first = [(r.name.split("(")[0].replace("forward kernel ", ""), r.elapsed) for r in results[:16]]
    return {k: (v[0], v[1]) for k, v in total.items()}, first


def main(argv=None) -> int:
    p = arg_parser("bench.kernel_times", __doc__)
    p.add_argument("--device", default="cuda")
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--budget", default="4x8")
    p.add_argument("--block-dims", type=int, nargs="*", default=[],
                   help="also time the implicit sticks ('auto') with these threads per block (sticks.GRID_BLOCK_DIM)")
    args = p.parse_args(argv)
    quiet_warp()
    substeps, iterations = (int(v) for v in args.budget.split("x"))
    from warp_verlet.constraints import sticks

    chosen = sticks.GRID_BLOCK_DIM
    for block in args.block_dims:
        sticks.GRID_BLOCK_DIM = block
        times, _ = kernel_times(args.size, substeps, iterations, args.device, "auto")
        colour = [k for k in times if k.startswith("relax_grid_colour")]
        if colour:  # CUDA only: the CPU has no activity timing
            ms, n = times[colour[0]]
            print(f"{args.size}^2 {args.budget} auto, {block} threads per block: a colour {ms / n * 1e3:.1f} us")
    sticks.GRID_BLOCK_DIM = chosen  # the table below is of the block size the simulator uses
    for form in ("explicit", "auto", "implicit", "tiled"):
        times, first = kernel_times(args.size, substeps, iterations, args.device, form)
        print(f"{args.size}^2 {args.budget} {form}: {sum(t for t, _ in times.values()):.3f} ms of kernels per frame")
        for name, (ms, n) in sorted(times.items(), key=lambda kv: -kv[1][0]):
            print(f"  {name:60s} {ms:8.3f} ms  {n:5d} launches  {ms / n * 1e3:8.1f} us each")
        print("  the first launches, in order: " + ", ".join(f"{n} {t * 1e3:.0f} us" for n, t in first))
    return 0


if __name__ == "__main__":
    sys.exit(main())
