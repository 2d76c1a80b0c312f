"""Numerical stability on stiff and extreme cases, at benchmark sizes.

    python -m bench.stability --out bench/results/stability
    python -m bench.stability --device cuda --out bench/results/stability-cuda
    python -m bench.stability --cases heavy_chain two_places      # a few cases only

The cases and their pass criteria live in ``bench/stability_cases/``; ``tests/test_stability.py`` runs the
same cases at small sizes. Each row is one criterion: the measured value, the bound (with where it comes
from), the margin bound / measured (inf where the measured value is 0 or below, e.g. an energy that only
fell) and pass/fail. A case that raises is reported as one failing row. Writes ``stability.md`` and
``stability.csv`` with ``--out``. Exit status 1 when any row fails.
"""

from __future__ import annotations

import math
import sys
import time
import traceback
from pathlib import Path

import warp as wp

from . import stability_cases as cases
from .common import arg_parser, machine, quiet_warp, write_table

COLUMNS = ["case", "criterion", "measured", "bound", "margin", "result", "bound from", "note", "seconds"]


def fmt(v: float) -> str:
    if math.isinf(v):
        return "inf"
    return f"{v:.3g}"


def run(names: list[str], device: str, size: str) -> list[dict]:
    rows = []
    for name in names:
        start = time.perf_counter()
        try:
            checks = cases.CASES[name](device, size)
        except Exception as exc:  # a case that crashes is a failure of that case, reported like the others
            checks = [cases.Check(name, "case ran to the end", 1.0, 0.0, "must not raise",
                                  f"{type(exc).__name__}: {exc}".replace("\n", " ")[:300])]
            traceback.print_exc()
        seconds = time.perf_counter() - start
        for c in checks:
            rows.append({"case": c.case, "criterion": c.criterion, "measured": fmt(c.measured), "bound": fmt(c.bound),
                         "margin": fmt(c.margin), "result": "pass" if c.passed else "FAIL", "bound from": c.basis,
                         "note": c.note.replace("|", "/"), "seconds": f"{seconds:.1f}"})
        print(f"{name}: {sum(c.passed for c in checks)}/{len(checks)} pass ({seconds:.1f} s)", file=sys.stderr)
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = arg_parser("bench.stability", __doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (default cpu)")
    parser.add_argument("--size", choices=cases.SIZES, default="bench", help="bench (default) or the tests' sizes")
    parser.add_argument("--cases", nargs="+", choices=list(cases.CASES), default=list(cases.CASES))
    parser.add_argument("--out", type=Path, help="folder for stability.md and stability.csv")
    args = parser.parse_args(argv)
    quiet_warp()
    wp.init()

    rows = run(args.cases, args.device, args.size)
    failed = sum(r["result"] != "pass" for r in rows)
    title = "\n".join([
        f"Stability suite ({args.size} sizes), device {args.device}: {len(rows) - failed} of {len(rows)} criteria pass",
        "",
        *machine(args.device).lines(["bench.stability", *argv]),
        "",
        "Criteria and bounds: `bench/stability_cases/` (each case's docstring and comments). margin = bound / "
        "measured; inf where the measured value is 0 or below.",
    ])
    write_table(rows, args.out, "stability", title, COLUMNS)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
