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


def test_latlong_spheres_have_exactly_the_asked_triangles_and_are_closed():
    import numpy as np
    import pytest
    import trimesh

    for count, shape in [(10000, (100, 51)), (100000, (250, 201))]:
        assert mesh_collider.latlong_segments(count) == shape
        points, triangles = mesh_collider.latlong_sphere(count)
        assert triangles.shape == (count, 3)
        mesh = trimesh.Trimesh(points, triangles, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        # Outward (positive volume), every point on the icosphere's sphere (radius 0.3 m at the origin), and
        # within 0.2 % of the ball's volume (the inscribed polyhedron: 10,000 triangles lose about 0.16 %).
        assert mesh.volume == pytest.approx(4.0 / 3.0 * np.pi * mesh_collider.RADIUS ** 3, rel=2e-3)
        np.testing.assert_allclose(np.linalg.norm(points, axis=1), mesh_collider.RADIUS, rtol=1e-12)
        np.testing.assert_allclose(points.mean(axis=0), 0.0, atol=1e-12)
        assert len(np.unique(triangles)) == len(points) == 2 + shape[0] * (shape[1] - 1)


def test_a_triangle_count_that_cannot_be_exact_is_a_usage_error(capsys):
    import pytest

    for count in (9999, 10002, 4, 0):  # odd; 2 x 3 x 1667 (no near-square factors); too few; none
        with pytest.raises(ValueError, match=f"{count} is not such a count"):
            mesh_collider.latlong_segments(count)
    with pytest.raises(SystemExit) as stopped:
        mesh_collider.main(["--sizes", "8", "--triangles", "10000", "10002"])
    assert stopped.value.code == 2
    assert "--triangles 10002: a lat-long sphere has 2 u (v - 1) triangles" in capsys.readouterr().err


def test_triangles_alone_give_lat_long_rows_only(tmp_path):
    assert mesh_collider.main(["--sizes", "8", "--triangles", "48", "--frames", "3", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "mesh_collider.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(r["collider"], r["triangles"]) for r in rows] == [("none", "-"), ("sphere", "-"), ("lat-long mesh", "48")]
    assert float(rows[2]["clamp ms/frame"]) > 0
    assert float(rows[2]["deepest mm"]) <= 2e-3  # kept out, as the icosphere rows are
