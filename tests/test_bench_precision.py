"""bench.precision at tiny sizes: both tables come out, with every budget in the precision it names."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import precision


def read(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_precision_bench_writes_cost_and_reach(tmp_path):
    assert precision.main(["--sizes", "6", "8", "--frames", "3", "--out", str(tmp_path)]) == 0
    cost = read(tmp_path / "precision-cost.csv")
    assert [(r["grid"], r["precision"]) for r in cost[:2]] == [("6²", "float32"), ("6²", "float64")]
    assert len(cost) == 2 * 2 * len(precision.COST_BUDGETS)
    assert all(math.isfinite(float(r["ms/frame"])) and float(r["float64 / float32"]) > 0 for r in cost)
    reach = read(tmp_path / "precision-reach.csv")
    assert [(r["precision"], r["S x K"]) for r in reach] == [(p, f"{s} x {k}") for p, s, k in precision.REACH_BUDGETS]
    assert all(r["grid"] == "8²" and r["RMS stretch"].endswith("%") for r in reach)
