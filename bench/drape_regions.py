"""Where the drape is stretched: its structural sticks' stretch on the ball, on the ground and hanging free.

    python -m bench.drape_regions --device cuda --sizes 256 1024 --budgets 64x2 16x32
    python -m bench.drape_regions --device cpu --sizes 64 128 --budgets 16x2 \\
        --families structural,shear,bend structural,shear structural

The scene is bench.convergence's drape (1 m, 0.2 kg, no pins, dropped flat from 0.5 m onto a 0.25 m ball, ground
at -0.5 m, read at 1.5 s), for each size, budget S x K (substeps x sweeps), method (bench.convergence's METHODS)
and set of stick families (``--families``, comma-separated; all rigid, as in the drape). A stick is "on the
ball" when its midpoint is within 2 cm of the ball's surface, "on the ground" within 2 cm of the ground, else
"free". Per region: the share of the structural sticks there, their RMS and mean signed stretch (D - L) / L
(positive: stretched), and the largest |stretch|. "row" is the signed stretch of eight consecutive sticks of the
middle row, at the top of the ball, so a pattern that follows the colouring shows. Writes drape-regions.md and
.csv with ``--out``.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import warp as wp

from .common import arg_parser, machine, quiet_warp, write_table
from .convergence import METHODS, merge, scene_tables, simulate
from warp_verlet.input.scene import parse_scene

BALL_RADIUS, GROUND = 0.25, -0.5  # m: bench.convergence.drape's ball (at the origin) and ground
BAND = 0.02  # m: a stick within this of a surface counts as lying on it


def structural_stretch(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(signed stretch (D - L) / L, midpoints) of the n x n grid's structural sticks, rows' then columns',
    float64 (the drape's rest spacing is 1 / (n - 1) along both axes)."""
    x = np.asarray(x, np.float64).reshape(n, n, 3)
    h = 1.0 / (n - 1)
    along = [(x[:, 1:], x[:, :-1]), (x[1:, :], x[:-1, :])]
    stretch = np.concatenate([(np.linalg.norm(a - b, axis=-1) / h - 1.0).ravel() for a, b in along])
    middle = np.concatenate([(0.5 * (a + b)).reshape(-1, 3) for a, b in along])
    return stretch, middle


def regions(middle: np.ndarray) -> dict[str, np.ndarray]:
    ball = np.abs(np.linalg.norm(middle, axis=1) - BALL_RADIUS) < BAND
    ground = (middle[:, 1] - GROUND < BAND) & ~ball
    return {"ball": ball, "ground": ground, "free": ~(ball | ground)}


def row_at_top(stretch: np.ndarray, n: int, count: int = 8) -> list[float]:
    """The signed stretch of ``count`` consecutive sticks (all, in a shorter row) about the middle of the middle
    row."""
    rows = stretch[: n * (n - 1)].reshape(n, n - 1)
    count = min(count, n - 1)
    start = (n - 1) // 2 - count // 2
    return [float(v) for v in rows[n // 2, start:start + count]]


def pct(v: float) -> str:
    return "–" if not math.isfinite(v) else f"{100 * v:.2f}%"


def measure(n: int, substeps: int, sweeps: int, method: str, families: list[str], device: str) -> dict:
    tables = merge(scene_tables("drape", n, method, substeps, sweeps), {"cloth": {"sticks": families}})
    result = simulate(parse_scene(tables, file=f"<drape {n}^2>"), device, None)
    stretch, middle = structural_stretch(result["positions"], n)
    row = {"grid": f"{n}²", "method": method, "families": ", ".join(families), "S x K": f"{substeps} x {sweeps}",
           "ms/frame": f"{result['ms_per_frame']:.2f}", "RMS": pct(result["rms"]), "max": pct(result["max"])}
    for name, mask in regions(middle).items():
        part = stretch[mask]
        share = mask.mean()
        row[f"{name}: share"] = f"{100 * share:.0f}%"
        row[f"{name}: RMS / mean / max"] = ("–" if not part.size else
                                            f"{pct(np.sqrt(np.mean(part ** 2)))} / {pct(part.mean())} / "
                                            f"{pct(np.abs(part).max())}")
    row["row at the top"] = " ".join(f"{100 * v:+.1f}" for v in row_at_top(stretch, n))
    return row


def main(argv: list[str] | None = None) -> int:
    p = arg_parser("bench.drape_regions", __doc__)
    p.add_argument("--device", default="cpu")
    p.add_argument("--sizes", type=int, nargs="+", default=[64])
    p.add_argument("--budgets", nargs="+", default=["16x2"], help="S x K: substeps x sweeps")
    p.add_argument("--methods", nargs="+", default=["plain"], choices=list(METHODS))
    p.add_argument("--families", nargs="+", default=["structural,shear,bend"],
                   help="stick families, comma-separated, one set per run")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    quiet_warp()
    budgets = []
    for text in args.budgets:
        try:
            s, k = (int(v) for v in text.lower().split("x"))
        except ValueError:
            p.error(f"a budget is substeps x sweeps, such as 16x2; got {text!r}")
        budgets.append((s, k))
    rows = [measure(n, s, k, method, families.split(","), args.device)
            for n in args.sizes for method in args.methods for families in args.families for s, k in budgets]
    title = (f"The drape's structural stretch by region at 1.5 s (on the ball: within {100 * BAND:.0f} cm of its "
             f"surface): {machine(args.device)}\n\ncommand: `python -m bench.drape_regions {' '.join(argv or sys.argv[1:])}`")
    write_table(rows, args.out, "drape-regions", title)
    return 0


if __name__ == "__main__":
    wp.init()
    raise SystemExit(main())
