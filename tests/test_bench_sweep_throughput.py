"""bench.sweep_throughput: a smoke test at tiny size (its columns, and that every backend ran every variant)."""

from __future__ import annotations

import csv
import importlib.util

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import sweep_throughput as stp


@pytest.mark.slow
def test_sweep_throughput_outputs(tmp_path):
    ray = importlib.util.find_spec("ray") is not None
    args = ["--cases", "6x2", "--variants", "3", "--workers", "1", "--noop", "5", "--out", str(tmp_path),
            "--stem", "smoke"] + ([] if ray else ["--no-ray"])
    assert stp.main(args) == 0
    with open(tmp_path / "smoke.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["case", *stp.COLUMNS]
    names = [r["backend"] for r in rows]
    assert names == ["inline (this process)", "local pool, 1 worker(s)"] + (["Ray, local instance"] if ray else [])
    for r in rows:
        assert r["case"] == "6x2" and int(r["variants"]) == 3
        assert float(r["total s"]) > 0 and float(r["variants/s"]) > 0 and float(r["task s (median)"]) > 0
    md = (tmp_path / "smoke.md").read_text()
    assert "3 variants of a 6 x 6 hanging cloth, 2 frames" in md and "ProcessPoolExecutor (spawn), 1 worker" in md
    assert ("Ray " in md and "num_cpus = 1" in md) if ray else "Ray" not in md.split("### Bare")[1]
