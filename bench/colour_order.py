"""The order in which a sweep projects a grid's stick families: the error each order leaves at the same cost.

    python -m bench.colour_order --device cpu --out bench/results/colour_order/cpu
    python -m bench.colour_order --device cpu --scenes --shipped drape ball_through_net --orders all

A grid's colours come one family after another, in topology.SWEEP_ORDER (structural, shear, bend). Any other order
of the three families runs the same launches, so it costs the same; what differs is the stretch it leaves. Each
scene runs once per order, from the same start:

- ``--scenes``: the hanging sheet with tethers (bench.implicit_grid's, rigid bend sticks, read at 1 s) and the drape
  (bench.convergence's: no pins, onto a ball and the ground, read at 1.5 s), at each of ``--sizes`` and
  ``--budgets`` (S x K, substeps x sweeps), timed as bench.implicit_grid times (the median of three batches of
  frames 3-60);
- ``--shipped``: scenes/NAME.toml with its own settings to its last frame (tearing as the runner tears), timed
  whole.

Each row gives the time, the RMS and max structural stretch at the end, and the RMS stretch of the shear sticks
(the bend sticks measure bending).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from warp_verlet.core.simulator import Simulator
from warp_verlet.geometry import topology
from warp_verlet.geometry.mesh_cloth import SHEAR
from warp_verlet.input.scene import load_scene, parse_scene

from .common import arg_parser, machine, quiet_warp, write_table
from .convergence import drape
from .implicit_grid import FRAMES, sheet, timed

S, SH, B = ((topology.STRUCT_H, topology.STRUCT_V), (topology.SHEAR_DIAG, topology.SHEAR_ANTI),
            (topology.BEND_H, topology.BEND_V))
ORDERS = {"structural, shear, bend": S + SH + B, "bend, shear, structural": B + SH + S,
          "shear, bend, structural": SH + B + S, "bend, structural, shear": B + S + SH,
          "shear, structural, bend": SH + S + B, "structural, bend, shear": S + B + SH}
"""Every order of the three families, each family's two directions kept together."""
TWO = ("structural, shear, bend", "bend, shear, structural")
BENCH_FRAMES = {"hanging": FRAMES, "drape": 90}
SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"


def shear_rms(sim: Simulator) -> float:
    """RMS of |D - L| / L over the shear sticks that are not torn (0 where there are none)."""
    m = sim.model
    shear = m.host_family == SHEAR
    if m.tears:
        shear &= ~sim.torn_sticks()
    if not shear.any():
        return 0.0
    s, rest = m.host_sticks[shear], m.host_rest[shear].astype(np.float64)
    p = m.to_device_order(sim.positions()).astype(np.float64)
    stretch = np.linalg.norm(p[s[:, 1]] - p[s[:, 0]], axis=1) / rest - 1.0
    return float(np.sqrt(np.mean(stretch ** 2)))


def in_order(order: tuple, run):
    """``run()`` with topology.SWEEP_ORDER set to ``order``, put back after."""
    before = topology.SWEEP_ORDER
    topology.SWEEP_ORDER = order
    try:
        return run()
    finally:
        topology.SWEEP_ORDER = before


def bench_row(device, name: str, n: int, substeps: int, iterations: int, repeats: int) -> dict:
    if name == "hanging":
        sim = Simulator(sheet(n, substeps, iterations), device)
    else:
        sim = Simulator(parse_scene(drape(n, substeps, iterations), file="<drape>"), device)
    per_frame, spread = timed(sim, repeats)
    for _ in range(BENCH_FRAMES[name] - FRAMES):
        sim.step_frame()
    stretch = sim.stretch()
    return {"scene": name, "grid": f"{n}x{n}", "S x K": f"{substeps} x {iterations}", "time": f"{per_frame * 1e3:.3f}",
            "time unit": "ms/frame", "spread": f"±{spread:.1%}", "structural rms": f"{stretch.rms:.4%}",
            "structural max": f"{stretch.max:.3%}", "shear rms": f"{shear_rms(sim):.4%}", "torn": 0}


def shipped_row(device, name: str) -> dict:
    path = SCENES_DIR / f"{name}.toml"
    scene = load_scene(path)
    sim = Simulator(scene, device)
    torn, start = 0, time.perf_counter()
    for _ in range(scene.simulation.frames):
        sim.step_frame()
        if scene.tears and sim.torn_count() != torn:
            torn = sim.torn_count()
            sim.sync_tears()
    seconds = time.perf_counter() - start
    stretch = sim.stretch()
    row = {"scene": name, "grid": "x".join(map(str, scene.cloths[0].resolution or ["mesh"])),
           "S x K": f"{scene.simulation.substeps} x {scene.simulation.iterations}", "time": f"{seconds:.2f}",
           "time unit": "s, whole run", "spread": "", "structural rms": f"{stretch.rms:.4%}",
           "structural max": f"{stretch.max:.3%}", "shear rms": f"{shear_rms(sim):.4%}", "torn": torn}
    sim.close()
    return row


def main(argv=None) -> int:
    p = arg_parser("bench.colour_order", __doc__)
    p.add_argument("--device", default=None)
    p.add_argument("--scenes", nargs="*", choices=list(BENCH_FRAMES), default=list(BENCH_FRAMES),
                   help="benchmark scenes (none: only --shipped)")
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    p.add_argument("--budgets", nargs="+", default=["4x8", "64x1"], help="S x K: substeps x sweeps")
    p.add_argument("--shipped", nargs="*", default=[], help="shipped scenes (scenes/NAME.toml), each at its settings")
    p.add_argument("--orders", nargs="+", default=list(TWO), help=f"family orders, or 'all': {', '.join(ORDERS)}")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", type=Path, default=None, help="write colour-order.md and .csv here")
    args = p.parse_args(argv)
    quiet_warp()
    try:
        budgets = [tuple(int(v) for v in b.split("x")) for b in args.budgets]
    except ValueError:
        p.error(f"--budgets takes SxK pairs such as 4x8, got {args.budgets}")
    orders = list(ORDERS) if args.orders == ["all"] else args.orders
    unknown = [o for o in orders if o not in ORDERS]
    if unknown:
        p.error(f"--orders: unknown {unknown}; expected 'all' or some of: {'; '.join(ORDERS)}")
    missing = [name for name in args.shipped if not (SCENES_DIR / f"{name}.toml").is_file()]
    if missing:
        p.error(f"--shipped: no scenes/{missing[0]}.toml")
    rows = []
    work = [(lambda name=name, n=n, s=s, k=k: bench_row(args.device, name, n, s, k, args.repeats))
            for name in args.scenes for n in args.sizes for s, k in budgets]
    work += [(lambda name=name: shipped_row(args.device, name)) for name in args.shipped]
    for run in work:
        for order in orders:
            rows.append({"order": order, **in_order(ORDERS[order], run)})
            print(rows[-1], flush=True)
    grids = ["--sizes", *map(str, args.sizes), "--budgets", *args.budgets] if args.scenes else []
    command = ("python -m bench.colour_order " + " ".join(
        [f"--device {args.device or 'cpu'}", "--scenes", *args.scenes, *grids]
        + (["--shipped", *args.shipped] if args.shipped else [])
        + ["--orders", *(["all"] if args.orders == ["all"] else [f"'{o}'" for o in orders])]))
    write_table(rows, args.out, "colour-order", f"Sweep order of a grid's stick families: {machine(args.device)}"
                f"\n\ncommand: `{command}`")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
