"""bench.particle_orders at a tiny size: a row per mesh variant and order with finite times, and the RCM and Morton
simulators really hold their orders (the benchmark checks that itself)."""

from __future__ import annotations

import csv
import math

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")

pytest.importorskip("scipy")
from bench import particle_orders  # noqa: E402


def test_a_row_per_variant_and_order(tmp_path):
    args = ["--device", "cpu", "--sizes", "6", "--frames", "1", "--rounds", "1", "--threads", "1", "--out", str(tmp_path)]
    assert particle_orders.main(args) == 0
    with open(tmp_path / "particle_orders.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(r["variant"], r["particle order"]) for r in rows] == [
        (v, o) for v in ("quad mesh", "triangle mesh") for o in ("input", "Morton", "RCM")]
    for r in rows:
        assert math.isfinite(float(r["ms/frame"])) and float(r["ms/frame"]) > 0
        assert float(r["order s"]) >= 0
