"""bench/mesh_collider.py at a tiny size: a row per collider, each timed, the mesh clamp's share measured, and the
penetration it reports zero with a collider and large without one; --peer without Newton skips Newton's rows with
one line, and with it adds them (bench/newton_mesh_collider.py), its cloth and mesh the same as warp-verlet's."""

from __future__ import annotations

import csv
import math

import pytest

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


def test_penetration_meter_measures_given_points_against_the_mesh_and_the_sphere():
    """The meter Newton's rows share with warp-verlet's: thickness - signed distance, the sign negative inside."""
    import numpy as np
    import pytest
    import trimesh

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))  # a closed mesh, its top face at y = 0.5
    mesh = np.asarray(box.vertices), np.asarray(box.faces, dtype=np.int32)
    thickness, far = 0.01, [0.0, 3.0, 0.0]
    meter = mesh_collider.PointsPenetrationMeter(thickness, mesh, "cpu", 2)
    assert meter.penetration_of(np.array([[0.1, 0.505, 0.2], far])) == pytest.approx(0.005, abs=1e-6)
    assert meter.penetration_of(np.array([far, [0.1, 0.45, -0.2]])) == pytest.approx(0.06, abs=1e-6)  # inside
    assert meter.penetration_of(np.array([far, far])) == 0.0
    sphere = mesh_collider.PointsPenetrationMeter(thickness)  # no mesh: the analytic sphere of radius 0.3 m
    assert sphere.penetration_of(np.array([[0.0, 0.305, 0.0], far])) == pytest.approx(0.005, abs=1e-12)
    assert sphere.penetration_of(np.array([far, [0.0, 0.0, -0.29]])) == pytest.approx(0.02, abs=1e-12)
    assert sphere.penetration_of(np.array([far])) == 0.0


def test_peer_without_newton_prints_the_skip_and_keeps_the_table(tmp_path, capsys, monkeypatch):
    import sys

    from bench import newton_mesh_collider

    monkeypatch.setitem(sys.modules, "newton", None)  # `import newton` raises ImportError, installed or not
    assert not newton_mesh_collider.available()
    assert mesh_collider.main(["--sizes", "6", "--triangles", "48", "--frames", "2", "--peer",
                               "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count(newton_mesh_collider.SKIP_MESSAGE) == 1
    with open(tmp_path / "mesh_collider.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(r["n"], r["collider"]) for r in rows] == [("6", "none"), ("6", "sphere"), ("6", "lat-long mesh")]
    assert "simulator" not in rows[0] and "graph" not in rows[0]  # warp-verlet's table as without --peer
    reported = []
    assert newton_mesh_collider.peer_rows(6, [("latlong", 48)], 2, 8, 8, "cpu", report=reported.append) == []
    assert reported == [newton_mesh_collider.SKIP_MESSAGE]


def test_newtons_contact_distances_and_cases():
    import math

    import pytest

    from bench import newton_mesh_collider

    # 11 particles a side: spacing 0.1 m, thickness 0.05 m; the gap adds sqrt(2 x 9.81 x 0.1) m/s x 1/480 s.
    thickness, radius, gap = newton_mesh_collider.contact_distances(11, 8)
    assert thickness == radius == 0.05
    assert gap == pytest.approx(0.05 + math.sqrt(1.962) / 480.0, rel=1e-15)
    assert gap == pytest.approx(0.052918154382, abs=1e-12)
    cases = [("none", 0), ("sphere", 0), ("mesh", 2), ("latlong", 48), ("mesh", 3)]
    assert newton_mesh_collider.peer_cases(cases) == [("none", 0), ("mesh", 2), ("latlong", 48), ("mesh", 3)]


@pytest.mark.slow
def test_newtons_cloth_and_mesh_are_warp_verlets_when_newton_is_installed(tmp_path):
    """Newton's particles, reordered, start on warp-verlet's; its mesh shape holds the same points and triangles."""
    pytest.importorskip("newton")
    import numpy as np

    from warp_verlet.geometry.topology import grid_positions

    from bench import newton_mesh_collider

    n = 7
    mesh = mesh_collider.latlong_sphere(48)
    scene, _ = mesh_collider.drop_scene(n, "latlong", 48, tmp_path, 2, 8, 4)
    for solver in newton_mesh_collider.SOLVERS:
        cloth = newton_mesh_collider.NewtonDroppedCloth(solver, n, mesh, 8, 4, "cpu")
        np.testing.assert_allclose(cloth.positions(), grid_positions(scene.cloths[0]), atol=1e-6)
        assert cloth.model.particle_mass.numpy() == pytest.approx(np.full(n * n, 0.3 / (n * n)), rel=1e-6)
        shape = cloth.model.shape_source[0]
        assert (shape.vertices == mesh[0].astype(np.float32)).all()
        assert (shape.indices == mesh[1].ravel()).all()
        assert shape.is_watertight
        assert cloth.model.particle_radius.numpy() == pytest.approx(np.full(n * n, 0.5 / (n - 1)), rel=1e-6)


@pytest.mark.slow
def test_newton_rows_when_newton_is_installed():
    pytest.importorskip("newton")
    from bench import newton_mesh_collider

    rows = newton_mesh_collider.peer_rows(8, [("none", 0), ("sphere", 0), ("latlong", 48)], 20, 8, 4, "cpu")
    assert [(r["simulator"], r["collider"], r["triangles"]) for r in rows] == [
        ("newton-vbd", "none", "-"), ("newton-vbd", "lat-long mesh", 48),
        ("newton-style3d", "none", "-"), ("newton-style3d", "lat-long mesh", 48)]
    for r in rows:
        assert math.isfinite(r["ms/frame"]) and r["ms/frame"] > 0 and r["particles"] == 64
    # Without a collider the cloth falls through the sphere's place (20 frames: 0.54 m down); on the mesh Newton's
    # penalty holds it, pressed at most a tenth of the thickness (71 mm) inside it.
    assert rows[0]["x none"] == rows[2]["x none"] == 1.0
    assert rows[0]["deepest mm"] > 100.0 + rows[0]["thickness mm"] and rows[2]["deepest mm"] > 100.0
    assert 0.0 <= rows[1]["deepest mm"] <= 0.1 * rows[1]["thickness mm"]
    assert 0.0 <= rows[3]["deepest mm"] <= 0.1 * rows[3]["thickness mm"]
