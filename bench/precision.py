"""Float32 against float64 positions: what float64 costs, and what it buys below the float32 floor on dt.

    python -m bench.precision [--device cpu] [--threads 1] [--sizes 64 256] [--frames 60] [--out DIR]

The cloth is bench.convergence's hanging cloth (1 m, pinned at two corners, structural + shear + bend, tethers
on, damping 0.24 /s, 60 fps). Two tables:

1. **cost**: ms/frame (mean of frames 2 .. 11; the first captures the frame) in float32 and in float64 at the
   same substeps x sweeps (S x K), for each grid size.
2. **reach** (the largest size): the RMS and max structural stretch at 1 s for float32 at budgets up to its
   floor (about 75 substeps per frame for this cloth) and float64 beyond it, with ms/frame.

With ``--out`` the tables also go to DIR/precision-cost.md and DIR/precision-reach.md (and .csv).
"""

from __future__ import annotations

import time
from pathlib import Path

import warp as wp

from bench.common import arg_parser, machine, quiet_warp, write_table
from bench.convergence import hanging
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator

COST_BUDGETS = ((4, 8), (16, 2))
REACH_BUDGETS = (("float32", 16, 2), ("float32", 64, 2), ("float32", 64, 4), ("float32", 75, 2),
                 ("float64", 64, 2), ("float64", 128, 1), ("float64", 128, 2), ("float64", 256, 1))


def run(n: int, precision: str, substeps: int, iterations: int, frames: int, device: str, threads: int | None) -> dict:
    data = hanging(n, substeps, iterations)
    data["cloth"][0]["tethers"] = True
    data["simulation"]["precision"] = precision
    sim = Simulator(parse_scene(data, file=f"<hanging {n}^2>"), device, threads=threads)
    sim.step_frame()  # the first frame runs the exact start and captures the rest
    wp.synchronize_device(sim.device)
    start = time.perf_counter()
    for _ in range(frames - 1):
        sim.step_frame()
    wp.synchronize_device(sim.device)
    ms = (time.perf_counter() - start) / (frames - 1) * 1e3
    stretch = sim.stretch()
    sim.close()
    return {"grid": f"{n}²", "precision": sim.precision, "S x K": f"{substeps} x {iterations}",
            "ms/frame": f"{ms:.1f}", "RMS stretch": f"{stretch.rms * 100:.4f}%", "max stretch": f"{stretch.max * 100:.3f}%",
            "_ms": ms}


def main(argv=None) -> int:
    parser = arg_parser("bench.precision", __doc__)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=1, help="CPU relaxation threads (default 1)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--frames", type=int, default=60, help="frames of the reach table (60: 1 s)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    quiet_warp()
    threads = args.threads if args.device == "cpu" else None
    where = machine(args.device)
    command = ["bench.precision", *(argv if argv is not None else __import__("sys").argv[1:])]

    cost = []
    for n in args.sizes:
        for s, k in COST_BUDGETS:
            pair = [run(n, p, s, k, 11, args.device, threads) for p in ("float32", "float64")]
            for row in pair:
                row["float64 / float32"] = f"{pair[1]['_ms'] / pair[0]['_ms']:.2f}"
            cost += pair
    columns = ["grid", "precision", "S x K", "ms/frame", "float64 / float32"]
    title = f"Cost of float64 positions, hanging cloth, {where}, threads {threads}\n\n" + "\n".join(where.lines(command))
    write_table([{k: r[k] for k in columns} for r in cost], args.out, "precision-cost", title, columns)

    n = max(args.sizes)
    reach = [run(n, p, s, k, args.frames, args.device, threads) for p, s, k in REACH_BUDGETS]
    columns = ["grid", "precision", "S x K", "ms/frame", "RMS stretch", "max stretch"]
    title = (f"Stretch at {args.frames / 60:g} s below the float32 floor (75 substeps per frame here), {n}² hanging "
             f"cloth with tethers, {where}, threads {threads}")
    write_table([{k: r[k] for k in columns} for r in reach], args.out, "precision-reach", title, columns)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
