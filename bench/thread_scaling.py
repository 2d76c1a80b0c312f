"""How the CPU relaxation scales with threads: ms/frame of the full simulator against the thread count.

    python -m bench.thread_scaling [--sizes 128 256 1024] [--threads 1 2 4 8 16] [--out bench/results/...]

The hanging cloth of bench.throughput (structural + shear + bend, 4 substeps x 8 iterations), for each
solver, grid size and thread count: 2 warm-up frames, then the median of ``--repeats`` timed batches. Every
threaded run's final positions are compared with the 1-thread run's (they must be bit-identical). The
"auto" column is what the simulator picks by itself (warp_verlet/core/cpu_team.py ``auto_threads``); the table
is what that choice is tuned from. Writes thread_scaling.md/.csv under ``--out``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from warp_verlet.core.cpu_team import usable_cores
from warp_verlet.core.simulator import Simulator

from .common import arg_parser, hanging_cloth, machine, median_spread, quiet_warp, time_frames, write_table


def measure(scene, threads: int, frames: int, repeats: int) -> tuple[float, np.ndarray]:
    sim = Simulator(scene, "cpu", threads=threads)
    sim.step_frame()
    sim.step_frame()
    per_frame, _ = median_spread(time_frames(sim, frames, repeats))
    return per_frame, sim.positions()


def main(argv=None) -> int:
    p = arg_parser("bench.thread_scaling", __doc__)
    p.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512])
    p.add_argument("--threads", type=int, nargs="+", default=None, help="default: 1, 2, 4, ... up to the cores")
    p.add_argument("--solvers", nargs="+", choices=["coloured", "jacobi"], default=["coloured", "jacobi"])
    p.add_argument("--frames", type=int, default=3, help="frames per timed batch")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    quiet_warp()
    cores = usable_cores()
    counts = args.threads or sorted({1, cores, *(2**k for k in range(1, 8) if 2**k < cores)})
    rows = []
    for solver in args.solvers:
        for n in args.sizes:
            scene = hanging_cloth(n, 4, 8, solver)
            auto = Simulator(scene, "cpu").threads
            one, reference = None, None
            row = {"relaxation": solver, "grid": f"{n}x{n}", "auto": auto}
            for t in counts:
                per_frame, points = measure(scene, t, args.frames, args.repeats)
                if t == 1:
                    one, reference = per_frame, points
                elif reference is not None and not np.array_equal(points, reference):
                    print(f"error: {t} threads changed the result ({solver}, {n}^2)", file=sys.stderr)
                    return 1
                row[f"{t}T ms"] = f"{per_frame * 1e3:.1f}"
                if one:
                    row[f"{t}T x"] = f"{one / per_frame:.2f}"
            rows.append(row)
            print(row, flush=True)
    command = ["bench.thread_scaling", *(argv if argv is not None else sys.argv[1:])]
    title = "CPU relaxation threads: ms/frame and speed-up over 1 thread, hanging cloth 4 x 8"
    write_table(rows, args.out, "thread_scaling", title + "\n\n" + "\n".join(machine("cpu").lines(command)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
