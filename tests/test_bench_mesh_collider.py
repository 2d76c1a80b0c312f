"""bench/mesh_collider.py at a tiny size: a row per collider, each timed, the mesh clamp's share measured, and the
penetration it reports zero with a collider and large without one."""

from __future__ import annotations

import csv
import math

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import mesh_collider


def test_each_collider_is_measured_and_only_the_colliders_hold(tmp_path):
    assert mesh_collider.main(["--sizes", "12", "--subdivisions", "2", "3", "--frames", "20",
                               "--out", str(tmp_path)]) == 0
    with open(tmp_path / "mesh_collider.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(r["n"], r["collider"], r["triangles"]) for r in rows] == [
        ("12", "none", "-"), ("12", "sphere", "-"), ("12", "mesh", "320"), ("12", "mesh", "1280")]
    for r in rows:
        assert math.isfinite(float(r["ms/frame"])) and float(r["ms/frame"]) > 0
    assert float(rows[0]["x none"]) == 1.0
    for r in rows[2:]:
        clamp, share = float(r["clamp ms/frame"]), float(r["clamp share"].rstrip("%"))
        assert clamp > 0 and 0 < share
    deepest = [float(r["deepest mm"]) for r in rows]
    thickness = float(rows[0]["thickness mm"])
    # Without a collider the cloth falls through the sphere's place (20 frames: 0.54 m down, far past its top
    # 0.1 m below); with one it is kept out at frame ends to float32 rounding of coordinates near 1 m (2e-3 mm,
    # tests/test_mesh_collider.py's TOL).
    assert deepest[0] > 100.0 + thickness
    assert all(0.0 <= d <= 2e-3 for d in deepest[1:])
    assert "command: `" in (tmp_path / "mesh_collider.md").read_text()
