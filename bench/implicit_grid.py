"""Implicit grid sticks against stick arrays, and the target_stretch budget against the fixed budget it chooses,
in one run on one device.

    python -m bench.implicit_grid --device cuda --out bench/results/implicit_grid
    python -m bench.implicit_grid --device cpu --sizes 64 --budgets 4x8 --target-size 0   # a smoke run

The scene is the benchmark's hanging sheet (bench.common.hanging_sheet: 1 m, pinned at its top corners, three rigid
stick families) with tethers, n x n particles. For each size, each sticks' form (``--forms``; "explicit": every
stick's ends, rest length and weight, and every tether, read from arrays; "implicit": the sticks computed from the
grid in a launch per colour, kernels/grid_relax.py, and the tethers computed too; "tiled": the sticks computed
and swept tile by tile in shared memory, kernels/grid_tiles.py, the tethers from their table; "auto": what the
simulator picks) and each budget S x K (substeps x sweeps), it runs 60 frames: frames 1-2 are a warm-up
(compilation, graph capture), frames 3-60 are timed in ``--repeats`` batches and the median batch gives ms/frame
(the spread is half the range). Beside it: G stick projections per second, the RMS and max structural stretch at
frame 60 (explicit and implicit must agree bit for bit, so their errors are equal; "same positions" says whether
they do; the tiled sweep projects in another order and has its own), and the bandwidth the explicit form's data needs
per frame (RELAX_BYTES_PER_PROJECTION per stick projection, as bench.throughput counts it, plus the tether table
and the positions per sweep) over the measured time, next to the device-to-device copy rate measured in the same
run: an implicit row above 100% moves less data than that, from cache.

The budget table runs ``target_stretch`` at ``--target-size`` with 1 sweep per substep: 20 frames to settle,
then frames timed as above; and then the fixed budget it settled on (the substeps it chose most in the timed
frames), timed the same way. Its stretch is reduced on the device and read a frame late (simulator.StretchReadback).
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator

from .common import (HANGING_DAMPING, add_compliance_arg, arg_parser, compliance_of, copy_bandwidth, hanging_sheet,
                     machine, median_spread, quiet_warp, scene, time_frames, write_table)
from .throughput import RELAX_BYTES_PER_PROJECTION

FRAMES, WARM_UP, SETTLE = 60, 2, 20
FORMS = ("explicit", "auto", "implicit", "tiled")
"""Stick arrays and the tether table; the simulator's choice; implicit sticks and tethers, a launch per colour;
implicit sticks swept tile by tile in shared memory (kernels/grid_tiles.py) with the tether table."""


def sheet(n: int, substeps: int, iterations: int, compliance: dict | None = None, **simulation):
    """The hanging sheet with tethers; ``compliance``: soft stick families (m/N; none: all rigid)."""
    soft = {"compliance": compliance} if compliance else {}
    return scene({"frames": FRAMES, "substeps": substeps, "iterations": iterations, "damping": HANGING_DAMPING,
                  **simulation}, hanging_sheet(n, tethers=True, **soft), name=f"<hanging sheet {n}x{n}, tethers>")


def explicit_bytes_per_sweep(sim: Simulator) -> int:
    """What one sweep of the explicit form reads and writes at least: 64 B per stick projection, the tether
    table (particle, pins and lengths) and each tethered particle's position read and written."""
    need = sim.solver.req
    tethers = need.tethered * (4 + need.tethers_per_particle * 8 + 2 * need.position_bytes)
    return sim.model.stick_count * RELAX_BYTES_PER_PROJECTION + tethers


def timed(sim: Simulator, repeats: int) -> tuple[float, float]:
    """Seconds per frame (median of ``repeats`` batches of frames 3-60) and the spread; ends at frame 60."""
    for _ in range(WARM_UP):
        sim.step_frame()
    batch = (FRAMES - WARM_UP) // repeats
    per_frame, spread = median_spread(time_frames(sim, batch, repeats))
    for _ in range(FRAMES - WARM_UP - batch * repeats):
        sim.step_frame()
    return per_frame, spread


def budget_rows(device: str, sizes: list[int], budgets: list[tuple[int, int]], repeats: int,
                copy_gbs: float | None, forms: tuple[str, ...] = FORMS, compliance: dict | None = None) -> list[dict]:
    rows = []
    for n in sizes:
        finals = {}
        for form in forms:
            sim = Simulator(sheet(n, *budgets[0], compliance), device, sticks=form)
            for substeps, iterations in budgets:
                sim.retune(substeps=substeps, iterations=iterations)
                sim.reset()
                per_frame, spread = timed(sim, repeats)
                points = sim.positions()
                stretch = sim.stretch(points)
                sweeps = substeps * iterations
                projections = sim.model.stick_count * sweeps
                data = explicit_bytes_per_sweep(sim) * sweeps
                key = (substeps, iterations)
                if "grid tiles" in sim.constraint_sets:  # another order of the same projections: its own error
                    same = "(tile order)"
                else:  # the colour order: the first such form is the others' reference, bit for bit
                    same = "" if key not in finals else ("yes" if np.array_equal(points, finals[key]) else "NO")
                    finals.setdefault(key, points)
                row = {"grid": f"{n}x{n}", "S x K": f"{substeps} x {iterations}", "sticks": form,
                       "constraint sets": " + ".join(sim.constraint_sets), "ms/frame": f"{per_frame * 1e3:.3f}",
                       "spread": f"±{spread * 100:.1f}%", "G proj/s": f"{projections / per_frame / 1e9:.1f}",
                       "stretch rms": f"{stretch.rms:.3%}", "stretch max": f"{stretch.max:.2%}",
                       "same positions": same,
                       "explicit data GB/s": f"{data / per_frame / 1e9:.0f}"}
                if copy_gbs:
                    row["of copy"] = f"{data / per_frame / 1e9 / copy_gbs * 100:.0f}%"
                rows.append(row)
                print(row, flush=True)
            sim.close()
            del sim
    return rows


def target_rows(device: str, n: int, target: float, repeats: int) -> list[dict]:
    """target_stretch at 1 sweep per substep, then the fixed budget it settled on, timed alike."""
    adaptive_scene = parse_scene({"simulation": {"fps": 60, "frames": FRAMES, "iterations": 1,
                                                 "damping": HANGING_DAMPING, "target_stretch": target},
                                  "cloth": [hanging_sheet(n, tethers=True)]}, file=f"<hanging sheet {n}x{n}, target>")
    adaptive = Simulator(adaptive_scene, device)
    for _ in range(SETTLE):
        adaptive.step_frame()
    before = Counter(adaptive.budget.frames_at)
    batch = (FRAMES - SETTLE) // repeats
    per_frame, spread = median_spread(time_frames(adaptive, batch, repeats))
    adaptive.settle_budget()
    chosen = Counter(adaptive.budget.frames_at) - before
    settled = chosen.most_common(1)[0][0]
    stretch = adaptive.stretch()
    rows = [{"grid": f"{n}x{n}", "budget": f"target_stretch {target:g}",
             "substeps chosen (x frames)": ", ".join(f"{s} x {f}" for s, f in sorted(chosen.items())),
             "ms/frame": f"{per_frame * 1e3:.3f}", "spread": f"±{spread * 100:.1f}%",
             "stretch rms": f"{stretch.rms:.4%}", "stretch max": f"{stretch.max:.3%}"}]
    adaptive.close()
    fixed = Simulator(sheet(n, settled, 1), device)
    for _ in range(SETTLE):
        fixed.step_frame()
    per_fixed, spread = median_spread(time_frames(fixed, batch, repeats))
    stretch = fixed.stretch()
    rows.append({"grid": f"{n}x{n}", "budget": f"fixed {settled} x 1", "substeps chosen (x frames)": "",
                 "ms/frame": f"{per_fixed * 1e3:.3f}", "spread": f"±{spread * 100:.1f}%",
                 "stretch rms": f"{stretch.rms:.4%}", "stretch max": f"{stretch.max:.3%}"})
    rows[0]["vs fixed"] = f"{(per_frame / per_fixed - 1) * 100:+.1f}%"
    rows[1]["vs fixed"] = ""
    for row in rows:
        print(row, flush=True)
    return rows


def main(argv=None) -> int:
    p = arg_parser("bench.implicit_grid", __doc__)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[256, 1024, 2048])
    p.add_argument("--budgets", nargs="+", default=["4x8", "32x1", "64x1"], help="S x K: substeps x sweeps")
    p.add_argument("--large-budgets", nargs="+", default=["32x1", "64x1"],
                   help="the budgets of sizes of 2048 and more")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--target", type=float, default=0.001, help="target_stretch of the budget table")
    p.add_argument("--target-size", type=int, default=1024, help="grid of the budget table (0: none)")
    p.add_argument("--out", type=Path, default=None, help="write implicit-grid.md/.csv and target-stretch.md/.csv")
    p.add_argument("--block-dim", type=int, default=None, help="threads per block of the implicit sticks' launches")
    p.add_argument("--forms", nargs="+", default=list(FORMS), choices=FORMS, help="the sticks' forms to run")
    p.add_argument("--tile", type=int, default=None, help="cells per side of the tiled sweep's tiles")
    p.add_argument("--max-registers", type=int, default=None,
                   help="registers a thread of the tiled sweep may use (0: the compiler's choice)")
    add_compliance_arg(p)
    p.add_argument("--tethers-apart", action="store_true",
                   help="run the first sweep's tether pass as its own launch, not inside the Verlet step")
    args = p.parse_args(argv)
    compliance = compliance_of(p, args.compliance)
    quiet_warp()
    if args.tethers_apart:
        from warp_verlet.core import stages

        stages.FOLD_TETHERS_INTO_INTEGRATE = dict.fromkeys(stages.FOLD_TETHERS_INTO_INTEGRATE, False)
    if args.tile:
        from warp_verlet.constraints import sticks

        if args.tile < 4 or args.tile % 4:
            p.error(f"--tile must be a multiple of 4 (a bend colour's parity repeats every 4 cells), got {args.tile}")
        sticks.GRID_TILE = args.tile
    if args.max_registers is not None:
        from warp_verlet.constraints import sticks

        sticks.GRID_TILE_MAX_REGISTERS = args.max_registers or None
    if args.block_dim:
        from warp_verlet.constraints import sticks

        sticks.GRID_BLOCK_DIM = args.block_dim
    device = wp.get_device(args.device)
    copy_gbs = copy_bandwidth(device) if device.is_cuda else None

    def parse(budgets):
        return [tuple(int(v) for v in b.lower().split("x")) for b in budgets]

    rows = []
    for n in args.sizes:
        rows += budget_rows(str(device), [n], parse(args.large_budgets if n >= 2048 else args.budgets), args.repeats,
                            copy_gbs, tuple(args.forms), compliance)
    title = ("Hanging sheet with tethers at 1 s, stick and tether arrays (explicit) against implicit grid sticks: "
             "a launch per colour with implicit tethers (implicit), swept tile by tile with the tether table (tiled), "
             f"and what the simulator picks (auto)"
             f"{', compliance ' + ', '.join(args.compliance) + ' m/N' if compliance else ''}: {machine(device)}")
    if copy_gbs:
        title += f"; device copy {copy_gbs:.0f} GB/s (read + write)"
    write_table(rows, args.out, "implicit-grid", title)
    if args.target_size:
        budget = target_rows(str(device), args.target_size, args.target, args.repeats)
        write_table(budget, args.out, "target-stretch", f"target_stretch against the fixed budget it settled on, "
                    f"implicit grid sticks, 1 sweep per substep: {machine(device)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
