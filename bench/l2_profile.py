"""Frames for Nsight Compute to profile: the benchmark's hanging sheet with tethers, kernel by kernel (no graph).

    ncu --cache-control none --replay-mode application --kernel-name regex:relax ... \\
        python3 -m bench.l2_profile --size 1024 --budget 4x8 --sticks auto

``--cache-control none`` keeps what earlier kernels left in L2 (Nsight Compute flushes it before each profiled
kernel by default, which would hide the reuse between a sweep's colours), and application replay runs the whole
program again for each pass, so each pass sees the L2 as the frame leaves it. bench/gpu_l2_profile.sh runs it.
"""

from __future__ import annotations

import sys

import warp as wp

from warp_verlet.core.simulator import Simulator

from .common import arg_parser, quiet_warp
from .implicit_grid import sheet


def main(argv=None) -> int:
    p = arg_parser("bench.l2_profile", __doc__)
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--budget", default="4x8")
    p.add_argument("--sticks", default="auto", choices=("explicit", "auto", "implicit", "tiled"))
    p.add_argument("--frames", type=int, default=3)
    p.add_argument("--device", default="cuda")
    args = p.parse_args(argv)
    quiet_warp()
    substeps, iterations = (int(v) for v in args.budget.split("x"))
    sim = Simulator(sheet(args.size, substeps, iterations), args.device, use_graph=False, sticks=args.sticks)
    for _ in range(args.frames):
        sim.step_frame()
    wp.synchronize_device(sim.device)
    print(f"{args.size}^2 {args.budget} {args.sticks}: constraint sets {sim.constraint_sets}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
