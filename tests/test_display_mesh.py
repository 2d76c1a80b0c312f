"""What the browser views draw of a cloth (warp_verlet/apps/display_mesh.py): a large grid as a coarser grid, a large
mesh decimated by edge collapses to vertices of its own, and torn faces hidden on both."""

from __future__ import annotations

import numpy as np
import pytest

from mesh_files import grid_mesh, mesh_scene, triangulated, write_obj
from warp_verlet.apps.display_mesh import DisplayMesh, fan_triangles

fast_simplification = pytest.importorskip("fast_simplification", reason="pip install 'warp-verlet[live]'")


def wavy_sheet(n: int) -> tuple[np.ndarray, object]:
    """An n x n triangulated sheet, 1 m x 1.4 m, with a fold in it: not flat, so the decimation has a shape to keep."""
    points, quads = grid_mesh(n, n)
    points = points.astype(np.float64)
    points[:, 2] = 0.05 * np.sin(points[:, 0] * 12.0)
    return points, triangulated(quads)


def area(points: np.ndarray, triangles: np.ndarray) -> float:
    a, b, c = (points[triangles[:, k]] for k in range(3))
    return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def border_vertices(triangles: np.ndarray) -> np.ndarray:
    """Vertices on an edge that only one triangle has."""
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    return np.unique(unique[count == 1])


def test_a_large_grid_is_drawn_as_a_coarser_grid_through_its_edges():
    points, quads = grid_mesh(41, 31)
    display = DisplayMesh(quads, len(points), grid=(41, 31), max_grid_quads=10)
    assert display.reduced and display.drawn_vertex_count == 11 * 11
    rows, cols = np.divmod(display.vertex_index, 31)
    assert set(rows) == set(range(0, 41, 4)) and {0, 30} <= set(cols)  # both edges of each direction
    assert display.triangles().shape == (2 * 10 * 10, 3) and display.note == "41 x 31 vertices drawn as 11 x 11"
    # Fine face (row 5, col 7) lies in coarse quad (row 1, col 2): its two triangles, and only they, go.
    kept = display.triangles([5 * 30 + 7])
    assert len(kept) == 2 * 10 * 10 - 2
    gone = {tuple(t) for t in display.triangles()} - {tuple(t) for t in kept}
    assert {v // 11 for t in gone for v in t} == {1, 2} and {v % 11 for t in gone for v in t} == {2, 3}


def test_a_small_mesh_is_drawn_whole():
    points, faces = wavy_sheet(12)
    display = DisplayMesh(faces, len(points), max_grid_quads=16, rest_points=points)
    assert not display.reduced and display.note == ""
    np.testing.assert_array_equal(display.triangles(), fan_triangles(faces)[0])


def test_a_large_mesh_is_decimated_to_vertices_of_its_own():
    points, faces = wavy_sheet(90)  # 8100 vertices; the budget is (20 + 1)^2 = 441
    fine = fan_triangles(faces)[0]
    display = DisplayMesh(faces, len(points), max_grid_quads=20, rest_points=points)
    kept, triangles = display.vertex_index, display.triangles().astype(np.int64)
    assert display.reduced and "8,100 mesh vertices drawn as" in display.note and "decimated" in display.note
    # About the budget (the library counts triangles; the border it keeps adds some), each an original vertex.
    assert 0.6 * 441 <= len(kept) <= 1.6 * 441
    assert len(np.unique(kept)) == len(kept) and kept.max() < len(points)
    assert triangles.min() == 0 and triangles.max() == len(kept) - 1
    assert (np.diff(np.sort(triangles, axis=1), axis=1) > 0).all()  # no degenerate triangle
    # Each drawn vertex is one of those that collapsed into its coarse vertex.
    np.testing.assert_array_equal(display._collapsed_into[kept], np.arange(len(kept)))
    # The hem is kept: every border vertex is drawn, so the outline does not shrink.
    assert np.isin(border_vertices(fine), kept).all()
    # The shape is kept: the coarse surface through the drawn vertices has the fine one's area (the fold included)
    # within 0.5% (measured 0.19%; drawn at the vertices left standing it was 2.5%), and under 1% of its triangles
    # fold over against the sheet's +Z side (measured 8 of 882; 29 drawn at the vertices left standing).
    drawn = points[kept]
    assert area(drawn, triangles) == pytest.approx(area(points, fine), rel=0.005)
    a, b, c = (drawn[triangles[:, k]] for k in range(3))
    assert (np.cross(b - a, c - a)[:, 2] <= 0).mean() < 0.01
    # The coarse mesh and its clusters are the library's own (checked against its replay of the collapses).
    _, _, collapses = fast_simplification.simplify(points, fine.astype(np.int32), target_count=2 * 441,
                                                   return_collapses=True, preserve_border=True)
    _, replayed, mapping = fast_simplification.replay_simplification(points.astype(np.float32), fine.astype(np.int32),
                                                                     collapses)
    np.testing.assert_array_equal(triangles, replayed)
    np.testing.assert_array_equal(display._collapsed_into, mapping)
    # Points sent to the browser: the drawn vertices' own positions.
    np.testing.assert_array_equal(display.vertices(points), drawn.astype(np.float32))


def test_a_torn_face_hides_the_coarse_triangles_around_it():
    points, faces = wavy_sheet(60)
    display = DisplayMesh(faces, len(points), max_grid_quads=12, rest_points=points)
    everything = display.triangles()
    torn = [2 * (30 * 59 + 30)]  # a triangle in the middle of the sheet
    corners = fan_triangles(faces)[0][torn[0]]
    kept = display.triangles(torn)
    assert 0 < len(everything) - len(kept) <= 20  # a small hole, not none and not the cloth
    # Every coarse triangle left is clear of the drawn vertices that the torn face's corners collapsed into.
    touched = set(display._collapsed_into[corners].tolist())
    assert not touched & set(kept.ravel().tolist())
    assert touched <= set(everything.ravel().tolist())
    np.testing.assert_array_equal(display.triangles([]), everything)


def test_a_live_session_gathers_the_decimated_vertices(tmp_path):
    from warp_verlet.apps.live_session import LiveSession

    points, faces = wavy_sheet(40)
    write_obj(tmp_path / "sheet.obj", points, faces)
    scene = mesh_scene(tmp_path, {"mesh": "sheet.obj", "pins": [0, 39]})
    session = LiveSession(scene, "cpu")
    for _ in range(3):
        session.tick(1 / 60)
    start = session.current_points()[0]
    display = DisplayMesh(session.sim.model.cloths[0].topology.cache_faces, len(start), max_grid_quads=10,
                          rest_points=start)
    assert display.reduced
    session.set_drawn([display.vertex_index])
    # alpha = 1: the positions themselves, to the rounding of x_prev + (x - x_prev).
    np.testing.assert_allclose(session.drawn_points(1.0)[0], session.current_points()[0][display.vertex_index],
                               rtol=0, atol=1e-6)


def test_live_and_view_pages_draw_a_large_mesh_decimated(tmp_path):
    """The pages wire it up: a mesh cloth over the budget is drawn decimated in ``live`` (the mesh sent holds the
    drawn vertices, at the simulation's positions) and in ``view`` (from the cache's first frame), and says so."""
    pytest.importorskip("viser", reason="pip install 'warp-verlet[live]'")
    from browser import free_port
    from warp_verlet.apps.cache_player import CachePlayer
    from warp_verlet.apps.live_app import LiveApp
    from warp_verlet.apps.live_session import LiveSession
    from warp_verlet.apps.runner import run_scene

    points, faces = wavy_sheet(40)
    write_obj(tmp_path / "sheet.obj", points, faces)
    scene = mesh_scene(tmp_path, {"mesh": "sheet.obj", "pins": [0, 39]}, {"frames": 3})
    app = LiveApp(LiveSession(scene, "cpu"), port=free_port(), max_grid_quads=10)
    try:
        display = app.displays[0]
        assert display.reduced and "1,600 mesh vertices drawn as" in display.note
        for _ in range(3):
            app.session.tick(1 / 60)
        app.draw(1.0)
        sent = app.cloths[0].handle.vertices
        assert sent.shape == (display.drawn_vertex_count, 3) and sent.dtype == np.float32
        np.testing.assert_allclose(sent, app.session.current_points()[0][display.vertex_index], rtol=0, atol=1e-6)
        assert app.cloths[0].handle.faces.max() == display.drawn_vertex_count - 1
    finally:
        app.server.stop()
        app.session.close()

    run_scene(scene, tmp_path / "sheet.usdc", device="cpu")
    player = CachePlayer(tmp_path / "sheet.usdc", port=free_port(), max_grid_quads=10)
    try:
        [display] = player.displays.values()
        assert display.reduced and display.drawn_vertex_count < 1600
    finally:
        player.server.stop()


def test_a_mesh_with_loose_vertices_is_decimated_around_them():
    # A cache may hold vertices no face uses (a live scene refuses them, `view` plays any cache): the library drops
    # them and numbers the rest anew, so they are left out before it runs and never drawn.
    points, faces = wavy_sheet(60)
    loose = np.array([[5.0, 5.0, 5.0], [6.0, 6.0, 6.0]])
    mixed = np.concatenate([loose[:1], points, loose[1:]])  # one before every used vertex, one after
    shifted = fan_triangles(faces)[0] + 1
    display = DisplayMesh(shifted, len(mixed), max_grid_quads=12, rest_points=mixed)
    reference = DisplayMesh(faces, len(points), max_grid_quads=12, rest_points=points)
    np.testing.assert_array_equal(display.vertex_index, reference.vertex_index + 1)
    np.testing.assert_array_equal(display.triangles(), reference.triangles())
    np.testing.assert_array_equal(display.triangles([100, 2000]), reference.triangles([100, 2000]))
