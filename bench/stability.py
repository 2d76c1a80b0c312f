"""Numerical stability on stiff and extreme cases, at benchmark sizes.

    python bench/stability.py --out bench/results/stability
    python bench/stability.py --device cuda --out bench/results/stability-cuda
    python bench/stability.py --cases heavy_chain two_places      # a few cases only

The cases and their pass criteria live in ``bench/stability_cases.py``; ``tests/test_stability.py`` runs the
same cases at small sizes. Each row is one criterion: the measured value, the bound (with where it comes
from), the margin bound / measured (inf where the measured value is 0 or below, e.g. an energy that only
fell) and pass/fail. A case that raises is reported as one failing row. Writes ``stability.md`` and
``stability.csv`` with ``--out``. Exit status 1 when any row fails.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import platform
import shlex
import sys
import time
import traceback
from datetime import datetime
from pathlib import Path

import numpy as np
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent))
import stability_cases as cases  # noqa: E402

COLUMNS = ["case", "criterion", "measured", "bound", "margin", "result", "bound from", "note", "seconds"]


def machine_lines(device: str, argv: list[str]) -> list[str]:
    d = wp.get_device(device)
    if d.is_cuda:
        where = f"{d.name} (CUDA)"
    else:
        cpu = platform.processor() or platform.machine()
        try:
            cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                       if line.lower().startswith("model name"))
        except (OSError, StopIteration):
            pass
        where = f"CPU {cpu}, {os.cpu_count()} logical CPUs (Warp's CPU backend runs a kernel on 1 thread)"
    return [
        f"- machine: {where}",
        f"- Warp {wp.__version__}, numpy {np.__version__}, Python {platform.python_version()}, {platform.system()}",
        f"- date: {datetime.now().isoformat(timespec='seconds')}",
        f"- command: `{shlex.join(['python', 'bench/stability.py', *argv])}`",
    ]


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


def table(rows: list[dict]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(r[k].replace("|", "/") for k in COLUMNS) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (default cpu)")
    parser.add_argument("--size", choices=cases.SIZES, default="bench", help="bench (default) or the tests' sizes")
    parser.add_argument("--cases", nargs="+", choices=list(cases.CASES), default=list(cases.CASES))
    parser.add_argument("--out", type=Path, help="folder for stability.md and stability.csv")
    args = parser.parse_args(argv)
    cases.quiet()
    wp.init()

    rows = run(args.cases, args.device, args.size)
    failed = sum(r["result"] != "pass" for r in rows)
    text = "\n".join([
        f"### Stability suite ({args.size} sizes), device {args.device}: "
        f"{len(rows) - failed} of {len(rows)} criteria pass",
        "",
        *machine_lines(args.device, argv),
        "",
        "Criteria and bounds: `bench/stability_cases.py` (each case's docstring and comments). margin = bound / "
        "measured; inf where the measured value is 0 or below.",
        "",
        table(rows),
    ])
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "stability.md").write_text(text)
        with open(args.out / "stability.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS)
            writer.writeheader()
            writer.writerows(rows)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
