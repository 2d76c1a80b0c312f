"""bench.throughput and bench.overlap at tiny sizes: its tables have the promised columns and finite numbers, and the
stage breakdown shows that a scene without colliders or tearing spends no time in those stages."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import overlap, throughput
from warp_verlet.core.simulator import Simulator


def read(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def test_plain_scene_spends_nothing_in_absent_stages(tmp_path):
    assert throughput.main(["--device", "cpu", "--sizes", "8", "12", "--repeats", "1", "--out", str(tmp_path)]) == 0
    rows = read(tmp_path / "throughput.csv")
    assert [r["grid"] for r in rows] == ["8x8", "12x12"]
    for r in rows:
        for key in ("ms/frame", "Mproj/s", "ns/proj", "bytes/particle", "stretch rms", "stretch max"):
            assert math.isfinite(float(r[key])) and float(r[key]) > 0, key  # it takes time; a hanging cloth stretches
        assert int(r["colours"]) == 12
    stages = read(tmp_path / "throughput-stages.csv")
    for r in stages:
        assert float(r["integrate"]) > 0 and float(r["relax"]) > 0 and float(r["USD write"]) > 0
        assert float(r["collide"]) == 0 and float(r["tear"]) == 0  # never launched, not merely fast


def test_colliders_and_tearing_show_up_as_stages(tmp_path):
    tear = 1.05  # low enough for the 8 x 8 cloth to tear some sticks in its 60 frames (at 1.5 it tears none)
    args = ["--device", "cpu", "--sizes", "8", "--repeats", "1", "--colliders", "--tear", str(tear),
            "--out", str(tmp_path)]
    assert throughput.main(args) == 0
    (row,) = read(tmp_path / "throughput-colliders-tear.csv")
    # The sticks torn by the bench's last frame are those a plain run of the same scene tears in as many frames
    # (the CPU run is deterministic, whatever the thread count), and the scene does tear.
    reference = Simulator(throughput.bench_scene(8, 4, 8, colliders=True, tear=tear), "cpu")
    for _ in range(throughput.FRAMES):
        reference.step_frame()
    assert int(row["torn"]) == reference.torn_count() > 0
    (stages,) = read(tmp_path / "throughput-colliders-tear-stages.csv")
    assert float(stages["collide"]) > 0 and float(stages["tear"]) > 0


def test_overlap_bench_reports_the_three_wall_times(tmp_path):
    assert overlap.main(["--device", "cpu", "--sizes", "8", "--frames", "3", "--repeats", "1", "--out", str(tmp_path)]) == 0
    (row,) = read(tmp_path / "overlap.csv")
    times = [float(row[f"{k} ms/frame"]) for k in ("simulation only", "sequential", "overlapped")]
    assert all(math.isfinite(t) and t > 0 for t in times)
    assert row["hidden"].endswith("%")
