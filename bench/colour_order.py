"""The order in which a sweep projects a grid's stick classes: the longest first (topology.SWEEP_ORDER: bend, shear,
structural) against the classes' own order (topology.CLASS_ORDER: structural, shear, bend).

    python -m bench.colour_order --device cpu --out bench/results/colour_order

Both orders run the same launches, so they cost the same; what differs is the error each leaves. For each scene,
grid and budget S x K (substeps x sweeps), both orders run from the same start: the hanging sheet with tethers
(bench.implicit_grid's, read at 1 s) and the drape (bench.convergence's: no pins, onto a ball and the ground, read
at 1.5 s). Each row gives ms/frame (bench.implicit_grid.timed: the median of three batches of frames 3-60) and the
RMS and max structural stretch at the end, and the RMS stretch of the shear sticks (the bend sticks measure
bending, which a drape should have).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from warp_verlet.core.simulator import Simulator
from warp_verlet.geometry import topology
from warp_verlet.geometry.mesh_cloth import SHEAR
from warp_verlet.input.scene import parse_scene

from .common import arg_parser, machine, quiet_warp, write_table
from .convergence import drape
from .implicit_grid import FRAMES, sheet, timed

ORDERS = {"longest first": topology.SWEEP_ORDER, "classes' order": topology.CLASS_ORDER}
SCENE_FRAMES = {"hanging": FRAMES, "drape": 90}


def scene_of(name: str, n: int, substeps: int, iterations: int):
    if name == "hanging":
        return sheet(n, substeps, iterations)
    return parse_scene(drape(n, substeps, iterations), file="<drape>")


def shear_rms(sim: Simulator) -> float:
    """RMS of |D - L| / L over the shear sticks (0 where there are none)."""
    m = sim.model
    shear = m.host_family == SHEAR
    if not shear.any():
        return 0.0
    s, rest = m.host_sticks[shear], m.host_rest[shear].astype(np.float64)
    p = m.to_device_order(sim.positions()).astype(np.float64)
    stretch = np.linalg.norm(p[s[:, 1]] - p[s[:, 0]], axis=1) / rest - 1.0
    return float(np.sqrt(np.mean(stretch ** 2)))


def run(device: str, scene_name: str, n: int, substeps: int, iterations: int, repeats: int) -> list[dict]:
    rows = []
    for label, order in ORDERS.items():
        topology.SWEEP_ORDER = order
        try:
            sim = Simulator(scene_of(scene_name, n, substeps, iterations), device)
            per_frame, spread = timed(sim, repeats)
            for _ in range(SCENE_FRAMES[scene_name] - FRAMES):
                sim.step_frame()
            stretch = sim.stretch()
        finally:
            topology.SWEEP_ORDER = ORDERS["longest first"]
        rows.append({"scene": scene_name, "grid": f"{n}x{n}", "S x K": f"{substeps} x {iterations}",
                     "order": label, "ms/frame": f"{per_frame * 1e3:.3f}", "spread": f"±{spread:.1%}",
                     "structural rms": f"{stretch.rms:.4%}", "structural max": f"{stretch.max:.3%}",
                     "shear rms": f"{shear_rms(sim):.4%}"})
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    p = arg_parser("bench.colour_order", __doc__)
    p.add_argument("--device", default=None)
    p.add_argument("--scenes", nargs="+", choices=list(SCENE_FRAMES), default=list(SCENE_FRAMES))
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    p.add_argument("--budgets", nargs="+", default=["4x8", "64x1"], help="S x K: substeps x sweeps")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", type=Path, default=None, help="write colour-order.md and .csv here")
    args = p.parse_args(argv)
    quiet_warp()
    try:
        budgets = [tuple(int(v) for v in b.split("x")) for b in args.budgets]
    except ValueError:
        p.error(f"--budgets takes SxK pairs such as 4x8, got {args.budgets}")
    rows = [row for scene_name in args.scenes for n in args.sizes for s, k in budgets
            for row in run(args.device, scene_name, n, s, k, args.repeats)]
    command = (f"python -m bench.colour_order --device {args.device or 'cpu'} --scenes {' '.join(args.scenes)} "
               f"--sizes {' '.join(map(str, args.sizes))} --budgets {' '.join(args.budgets)}")
    write_table(rows, args.out, "colour-order", f"Sweep order of a grid's stick classes, longest first against the "
                f"classes' own order: {machine(args.device)}\n\ncommand: `{command}`")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
