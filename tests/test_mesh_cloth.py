"""Mesh cloth: sticks from faces, welding, pins, the bad-mesh errors, and a mesh that is a grid behaving as the grid."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

from mesh_files import grid_mesh, mesh_scene, triangulated, write_obj, write_usd_mesh
from meshes import HOUSE, HOUSE_POINTS
from warp_verlet.errors import SceneError
from warp_verlet.geometry.faces import Faces
from warp_verlet.geometry.mesh_cloth import NonManifoldWarning, SourceMesh, prepare, stick_families, weld
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.geometry.topology import build_cloth

ALL = ["structural", "shear", "bend"]


def pairs(sticks: np.ndarray) -> set[tuple[int, int]]:
    return {tuple(p) for p in np.sort(sticks, axis=1).tolist()}


def source(points, faces: Faces, what: str = "test mesh") -> SourceMesh:
    from pathlib import Path

    return SourceMesh(description=what, file=Path(what), points=np.asarray(points, np.float64), faces=faces)


# -- sticks from faces ------------------------------------------------------------------------------------------

def test_triangle_mesh_sticks_are_its_edges_and_one_bend_per_interior_edge():
    """Counted against trimesh's own edge and face-adjacency tables (an independent implementation)."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    points, faces = grid_mesh(7, 9)
    for vertices, triangles in ((sphere.vertices, sphere.faces), (points, triangulated(faces).as_uniform())):
        reference = trimesh.Trimesh(vertices, triangles, process=False)
        mesh = prepare(source(vertices, Faces.uniform(triangles)))
        sticks, family = stick_families(mesh, tuple(ALL))
        assert pairs(sticks[family == 0]) == pairs(reference.edges_unique)
        assert (family == 1).sum() == 0  # triangles have no diagonals
        assert pairs(sticks[family == 2]) == pairs(reference.face_adjacency_unshared)
        assert len(sticks) == len(reference.edges_unique) + len(reference.face_adjacency)


def test_mixed_faces_follow_the_rules_worked_out_by_hand():
    """HOUSE: a pentagon, a quad and a triangle (tests/meshes.py). Edges 1-2, 2-6 and 2-3 are interior."""
    mesh = prepare(source(HOUSE_POINTS, HOUSE))
    sticks, family = stick_families(mesh, tuple(ALL))
    assert pairs(sticks[family == 0]) == {(0, 1), (1, 2), (2, 3), (3, 4), (0, 4), (1, 5), (5, 6), (2, 6), (3, 6)}
    assert pairs(sticks[family == 1]) == {(1, 6), (2, 5)}  # the quad's diagonals
    # Per interior edge, one stick through each end: 1-2 gives 0-5 (and 3-6, a mesh edge already);
    # 2-6 gives 1-3 and 3-5; 2-3 gives 1-6 (a shear stick already) and 4-6.
    assert pairs(sticks[family == 2]) == {(0, 5), (1, 3), (3, 5), (4, 6)}


def test_quad_mesh_of_a_grid_has_the_grids_sticks_pins_and_masses(tmp_path):
    points, faces = grid_mesh(6, 9)
    asset = write_usd_mesh(tmp_path / "grid.usda", points, faces)
    mesh = build_cloth(mesh_scene(tmp_path, {"mesh": asset.name, "prim": "/Set/Cloth", "sticks": ALL,
                                             "mass_distribution": "even",
                                             "pins": [{"min": [-1, -1e-3, -1], "max": [9, 1e-3, 1]}]}).cloths[0])
    grid = build_cloth(parse_scene({"cloth": [{"resolution": [6, 9], "size": [1.0, 1.4], "sticks": ALL,
                                               "pins": ["top-edge"]}]}).cloths[0])
    for family in range(3):
        assert pairs(mesh.sticks[mesh.family == family]) == pairs(grid.sticks[grid.family == family])
    np.testing.assert_array_equal(mesh.positions, grid.positions)
    np.testing.assert_array_equal(mesh.inv_mass, grid.inv_mass)
    by_pair = lambda t: dict(zip(map(tuple, np.sort(t.sticks, axis=1).tolist()), t.rest_length.tolist()))  # noqa: E731
    assert by_pair(mesh) == by_pair(grid)  # bit-equal rest lengths
    assert mesh.vertex_particle is None and mesh.cache_faces == faces  # nothing welded: vertices are particles


@pytest.mark.parametrize("solver", ["jacobi", "coloured"])
def test_quad_mesh_of_a_grid_moves_as_the_grid(tmp_path, solver):
    """Jacobi sums each particle's corrections in a fixed order (by neighbour), so the same sticks give the
    same motion bit for bit. The coloured solver visits the sticks in another order (graph colours against
    the grid's analytic ones), and Gauss-Seidel's answer depends on the order: measured 2.4-3.0 mm apart
    after a 0.38 m swing at 10, 40 and 160 iterations alike (both held to 2e-4 stretch), so the bound is 1%
    of the swing, which a wrong stick, rest length or mass exceeds many times over."""
    rows, cols = 8, 10
    points, faces = grid_mesh(rows, cols)
    asset = write_usd_mesh(tmp_path / "grid.usda", points, faces)
    simulation = {"relaxation": solver, "frames": 30, "substeps": 8, "iterations": 40, "wind": [0.0, 0.0, 3.0]}
    common = {"sticks": ALL, "tethers": False}
    mesh_cloth = mesh_scene(tmp_path, {"mesh": asset.name, "prim": "/Set/Cloth", "mass_distribution": "even",
                                       "pins": [0, cols - 1], **common}, simulation)
    grid_cloth = parse_scene({"simulation": simulation, "cloth": [{"resolution": [rows, cols], "size": [1.0, 1.4],
                                                                   "pins": ["top-left", "top-right"], **common}]})
    runs = []
    for scene in (mesh_cloth, grid_cloth):
        sim = Simulator(scene, "cpu", threads=1)
        for _ in range(30):
            sim.step_frame()
        runs.append(sim.positions())
    moved = np.abs(runs[1] - points).max()
    assert moved > 0.1  # it swung: the comparison below is about motion, not a resting cloth
    if solver == "jacobi":
        np.testing.assert_array_equal(runs[0], runs[1])
    else:
        assert np.abs(runs[0] - runs[1]).max() < 1e-2 * moved


# -- welding -----------------------------------------------------------------------------------------------------

def brute_force_weld(points: np.ndarray, distance: float) -> np.ndarray:
    n = len(points)
    label = np.arange(n)
    for i in range(n):
        for j in range(i + 1, n):
            if np.linalg.norm(points[i] - points[j]) <= distance:
                old, new = max(label[i], label[j]), min(label[i], label[j])
                label[label == old] = new
    _, particle = np.unique(label, return_inverse=True)
    return particle


@pytest.mark.parametrize("seed", range(5))
def test_weld_matches_brute_force_on_clusters(seed):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-1, 1, (40, 3))
    points = np.repeat(centres, rng.integers(1, 4, 40), axis=0)
    points = points + rng.normal(0, 3e-3, points.shape)  # some within 1e-2 of each other, some chained
    rng.shuffle(points)
    np.testing.assert_array_equal(weld(points, 1e-2), brute_force_weld(points, 1e-2))
    np.testing.assert_array_equal(weld(points, 0.0), np.arange(len(points)))  # no exact duplicates here


def test_weld_keeps_first_occurrence_order_and_merges_only_within_the_distance():
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0], [1, 0, 0.4e-3], [1, 0, 2.5e-3]], np.float64)
    np.testing.assert_array_equal(weld(p, 1e-3), [0, 1, 0, 1, 2])
    np.testing.assert_array_equal(weld(p, 0.0), [0, 1, 0, 2, 3])


def test_seam_duplicates_are_welded_and_every_vertex_follows_its_particle(tmp_path):
    """Two halves of a grid with the middle column duplicated (a UV seam): the same sticks as the whole
    grid, and the cache keeps all the vertices, the duplicates moving with their particle."""
    rows, cols = 5, 7
    points, faces = grid_mesh(rows, cols)
    quads = faces.as_uniform()
    seam = np.arange(rows) * cols + cols // 2
    copies = np.arange(rows) + rows * cols
    right = (quads % cols >= cols // 2).all(axis=1)
    remap = np.arange(rows * cols)
    remap[seam] = copies
    split = np.where(right[:, None], remap[quads], quads)
    split_points = np.concatenate([points, points[seam]])
    asset = write_usd_mesh(tmp_path / "seam.usda", split_points, Faces.uniform(split))
    scene = mesh_scene(tmp_path, {"mesh": asset.name, "prim": "/Set/Cloth", "sticks": ALL, "pins": [0]},
                       {"frames": 3})
    topology = build_cloth(scene.cloths[0])
    assert topology.particle_count == rows * cols and topology.vertex_count == rows * cols + rows
    whole = build_cloth(parse_scene({"cloth": [{"resolution": [rows, cols], "size": [1.0, 1.4], "sticks": ALL}]}).cloths[0])
    assert pairs(topology.sticks) == pairs(whole.sticks)
    sim = Simulator(scene, "cpu")
    sim.step_frame()
    vertices = topology.cache_points(sim.positions())
    np.testing.assert_array_equal(vertices[copies], vertices[seam])
    assert topology.cache_faces == Faces.uniform(split)  # the faces as read, duplicates and all


@pytest.mark.parametrize("suffix", ["obj", "ply", "stl", "off", "glb"])
def test_every_trimesh_format_gives_the_same_cloth(tmp_path, suffix):
    """STL stores three corners per triangle and no shared vertices: welding rebuilds the connectivity."""
    points, faces = grid_mesh(4, 5)
    triangles = triangulated(faces).as_uniform()
    path = tmp_path / f"cloth.{suffix}"
    trimesh.Trimesh(points, triangles, process=False).export(path)
    scene = mesh_scene(tmp_path, {"mesh": path.name, "sticks": ALL})
    topology = build_cloth(scene.cloths[0])
    assert topology.particle_count == 20
    reference = trimesh.Trimesh(points, triangles, process=False)
    assert (topology.family == 0).sum() == len(reference.edges_unique)
    assert (topology.family == 2).sum() == len(reference.face_adjacency)


def test_transform_scales_rotates_then_translates(tmp_path):
    points, faces = grid_mesh(3, 3, size=(1.0, 1.0))
    obj = write_obj(tmp_path / "c.obj", points, triangulated(faces))
    scene = mesh_scene(tmp_path, {"mesh": obj.name, "scale": 2.0, "rotate": [90.0, 0.0, 0.0],
                                  "translate": [0.0, 3.0, 0.0]})
    moved = build_cloth(scene.cloths[0]).positions
    # (x, y, z) -> scaled (2x, 2y, 2z) -> 90 degrees about X: (2x, -2z, 2y) -> + (0, 3, 0)
    expected = np.stack([2 * points[:, 0], -2 * points[:, 2] + 3.0, 2 * points[:, 1]], axis=1)
    np.testing.assert_allclose(moved, expected, atol=1e-6)


# -- pins and masses ---------------------------------------------------------------------------------------------

def test_pins_by_index_box_primvar_and_subset(tmp_path):
    rows, cols = 4, 5
    points, faces = grid_mesh(rows, cols)
    marked = np.zeros(rows * cols, np.int32)
    marked[[3, 17]] = 1
    asset = write_usd_mesh(tmp_path / "a.usda", points, faces, pinned_primvar=marked,
                           subsets={"corner": ("face", [0])})
    cloth = {"mesh": asset.name, "prim": "/Set/Cloth"}
    pinned = lambda pins: build_cloth(mesh_scene(tmp_path, {**cloth, "pins": pins}).cloths[0]).pinned.tolist()  # noqa: E731
    assert pinned([7]) == [7]
    assert pinned([{"min": [-1, -1e-3, -1], "max": [10, 1e-3, 1]}]) == list(range(cols))  # the top row
    assert pinned([{"primvar": "pinned"}]) == [3, 17]
    assert pinned([{"subset": "corner"}]) == [0, 1, cols, cols + 1]  # face 0's corners
    assert pinned([1, {"primvar": "pinned"}, 1]) == [1, 3, 17]
    topology = build_cloth(mesh_scene(tmp_path, {**cloth, "pins": [{"subset": "corner"}]}).cloths[0])
    assert (topology.inv_mass[[0, 1, cols, cols + 1]] == 0).all() and (np.delete(topology.inv_mass, [0, 1, 5, 6]) > 0).all()


def test_area_mass_distribution_follows_the_faces(tmp_path):
    """On a grid, a corner carries a quarter cell, a border particle half, an inner one a whole cell."""
    points, faces = grid_mesh(4, 4, size=(3.0, 3.0))
    asset = write_usd_mesh(tmp_path / "a.usda", points, faces)
    topology = build_cloth(mesh_scene(tmp_path, {"mesh": asset.name, "prim": "/Set/Cloth", "mass": 9.0}).cloths[0])
    mass = (1.0 / topology.inv_mass).reshape(4, 4)
    np.testing.assert_allclose(mass[0, 0], 0.25, rtol=1e-6)
    np.testing.assert_allclose(mass[0, 1], 0.5, rtol=1e-6)
    np.testing.assert_allclose(mass[1, 1], 1.0, rtol=1e-6)
    np.testing.assert_allclose(mass.sum(), 9.0, rtol=1e-6)


# -- bad meshes and bad keys -------------------------------------------------------------------------------------

def scene_error(tmp_path, cloth: dict, **kw) -> str:
    with pytest.raises(SceneError) as caught:
        mesh_scene(tmp_path, cloth, **kw)
    message = str(caught.value)
    assert message.startswith(str(tmp_path / "scene.toml") + ": cloth[0].")  # the scene file and the key
    return message


def test_bad_meshes_are_one_clear_error_each(tmp_path):
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    # A degenerate triangle (collinear corners) beside a good one.
    write_obj(tmp_path / "flat.obj", np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]]), Faces.uniform([[0, 1, 3], [0, 1, 2]]))
    assert "face 1 (vertices [0, 1, 2]) is degenerate" in scene_error(tmp_path, {"mesh": "flat.obj"})
    # Two corners of a face at one place: welded into one particle, a zero-length edge.
    write_usd_mesh(tmp_path / "zero.usda", np.concatenate([square, square[:1]]), Faces([4, 3], [0, 1, 2, 3, 0, 2, 4]))
    message = scene_error(tmp_path, {"mesh": "zero.usda", "prim": "/Set/Cloth"})
    assert "face 1 (vertices [0, 2, 4]) has a zero-length edge" in message and "zero.usda" in message
    # No faces at all.
    (tmp_path / "empty.obj").write_text("v 0 0 0\nv 1 0 0\n")
    assert "mesh is empty" in scene_error(tmp_path, {"mesh": "empty.obj"})
    # Not a mesh file of any kind, a missing file, a missing prim, a prim that is not a mesh.
    (tmp_path / "junk.obj").write_bytes(b"\x00\xff garbage \x01" * 50)
    assert "junk.obj" in scene_error(tmp_path, {"mesh": "junk.obj"})
    (tmp_path / "junk.usda").write_text("#usda 1.0\n( this is not usd")
    assert "junk.usda: cannot open as USD" in scene_error(tmp_path, {"mesh": "junk.usda", "prim": "/A"})
    assert "nothere.obj: no such file" in scene_error(tmp_path, {"mesh": "nothere.obj"})
    write_usd_mesh(tmp_path / "ok.usda", square, Faces.uniform([[0, 1, 2, 3]]))
    message = scene_error(tmp_path, {"mesh": "ok.usda", "prim": "/Set/Missing"})
    assert "no prim at /Set/Missing (meshes in the file: /Set/Cloth)" in message
    assert "is a Xform, not a Mesh" in scene_error(tmp_path, {"mesh": "ok.usda", "prim": "/Set"})
    assert "name the mesh with prim" in scene_error(tmp_path, {"mesh": "ok.usda"})
    # A loose vertex no face uses.
    write_obj(tmp_path / "loose.obj", np.concatenate([square, [[5.0, 5.0, 5.0]]]), Faces.uniform([[0, 1, 2, 3]]))
    assert "vertex 4 is used by no face" in scene_error(tmp_path, {"mesh": "loose.obj"})


def test_a_non_finite_vertex_is_reported_as_the_file_has_it(tmp_path):
    """An inf coordinate is named with the vertex as written, before a rotation would spread NaN to the other
    coordinates, in plain numbers (no numpy reprs), and with no numpy warning from the transform."""
    (tmp_path / "inf.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv inf 1 0\nf 1 2 3\nf 2 4 3\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        message = scene_error(tmp_path, {"mesh": "inf.obj", "rotate": [30.0, 0.0, 0.0]})
    assert message.endswith("inf.obj: vertex 3 is not a finite point: (inf, 1, 0) in the file (1 such vertices)")
    assert "nan" not in message and "np." not in message


def test_a_non_finite_source_point_is_reported_in_plain_numbers():
    """A SourceMesh built through the API, with no file: prepare names the point without numpy reprs."""
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 1, 0]], np.float64)
    with pytest.raises(ValueError) as caught:
        prepare(source(points, Faces.uniform([[0, 1, 2], [1, 3, 2]])))
    assert str(caught.value) == "test mesh: vertex 3 is not a finite point: (nan, 1, 0)"


def test_a_vertex_beyond_float32_is_reported_as_such(tmp_path):
    """1e39 is a finite float64 but no float32: said as that, not as the welding problem it would become."""
    (tmp_path / "far.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e39 1 0\nf 1 2 3\nf 2 4 3\n")
    message = scene_error(tmp_path, {"mesh": "far.obj"})
    assert "far.obj: vertex 3 is at (1e+39, 1, 0) m in the scene, beyond float32's range (+-3.4e+38)" in message
    assert "weld" not in message
    # The range is checked in the scene's frame: a point that fits in the file but not once scaled is refused too.
    (tmp_path / "near.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e38 1 0\nf 1 2 3\nf 2 4 3\n")
    assert "vertex 3 is at (1e+39, 10, 0) m in the scene" in scene_error(tmp_path, {"mesh": "near.obj", "scale": 10.0})


@pytest.mark.parametrize("face", ["f 0 1 2", "f 1 2 0", "f 1/1 0/2 3/3", "f 1 2 -0"])
def test_an_obj_face_naming_vertex_0_is_refused_as_such(tmp_path, face):
    """OBJ numbers vertices from 1: a face naming 0 is that mistake, not a loose vertex."""
    (tmp_path / "zero.obj").write_text(f"# a triangle\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n{face}\n")
    message = scene_error(tmp_path, {"mesh": "zero.obj"})
    assert message.endswith(f"zero.obj: line 6: face '{face}' names vertex 0; OBJ numbers vertices from 1 (or from "
                            "-1 back from the last)")


def test_non_manifold_edges_are_simulated_with_a_warning(tmp_path):
    """Three triangles on one edge (a fin): allowed, warned, and no bend stick crosses that edge."""
    points = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], np.float64)
    write_obj(tmp_path / "fin.obj", points, Faces.uniform([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))
    with pytest.warns(NonManifoldWarning, match="1 edge is shared by more than two faces"):
        scene = mesh_scene(tmp_path, {"mesh": "fin.obj", "sticks": ALL})
    topology = build_cloth(scene.cloths[0])
    assert (topology.family == 2).sum() == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)
        assert "tearing needs a manifold mesh" in scene_error(tmp_path, {"mesh": "fin.obj", "tear_threshold": 1.5})


def test_bad_mesh_keys_name_the_key(tmp_path):
    points, faces = grid_mesh(3, 3)
    write_usd_mesh(tmp_path / "a.usda", points, faces, pinned_primvar=np.zeros(9, np.int32))
    base = {"mesh": "a.usda", "prim": "/Set/Cloth"}
    assert "cloth[0].resolution: a mesh cloth takes its particles from the mesh" in scene_error(tmp_path, {**base, "resolution": [2, 2]})
    assert "cloth[0].pins[0]: vertex 9 is outside the mesh (0 .. 8)" in scene_error(tmp_path, {**base, "pins": [9]})
    assert "cloth[0].pins[1]: the box" in scene_error(tmp_path, {**base, "pins": [0, {"min": [5, 5, 5], "max": [6, 6, 6]}]})
    assert "cloth[0].pins[0]: primvar 'pinned' marks no vertex" in scene_error(tmp_path, {**base, "pins": [{"primvar": "pinned"}]})
    assert "no primvar 'nope'" in scene_error(tmp_path, {**base, "pins": [{"primvar": "nope"}]})
    assert "no GeomSubset 'nope'" in scene_error(tmp_path, {**base, "pins": [{"subset": "nope"}]})
    assert "cloth[0].pins[0].min" in scene_error(tmp_path, {**base, "pins": [{"min": [0, 0], "max": [1, 1, 1]}]})
    assert "cloth[0].scale" in scene_error(tmp_path, {**base, "scale": -1.0})
    assert "cloth[0].particle_masses[0][1]" in scene_error(tmp_path, {**base, "particle_masses": [[0, 0.0]]})
    assert "multilevel" in str(pytest.raises(SceneError, mesh_scene, tmp_path, base, {"multilevel": True}).value)
    write_obj(tmp_path / "c.obj", points, triangulated(faces))
    assert "pins by primvar ('x') need a USD file" in scene_error(tmp_path, {"mesh": "c.obj", "pins": [{"primvar": "x"}]})
    assert "prim is for USD files only" in scene_error(tmp_path, {"mesh": "c.obj", "prim": "/A"})


def test_validate_reports_the_mesh_and_its_welding(tmp_path, capsys):
    """`warp-verlet validate` as a user runs it on a mesh scene: the weld and pins are stated, nothing is run."""
    from warp_verlet.apps.cli import main

    points, faces = grid_mesh(3, 4)
    write_usd_mesh(tmp_path / "a.usda", np.concatenate([points, points[:2]]),
                   Faces(np.r_[faces.counts, 3], np.r_[faces.indices, 12, 13, 5]))  # two duplicates of 0 and 1
    (tmp_path / "s.toml").write_text('[[cloth]]\nname = "panel"\nmesh = "a.usda"\nprim = "/Set/Cloth"\npins = [0, 12]\n')
    assert main(["validate", str(tmp_path / "s.toml")]) == 0
    out = capsys.readouterr().out
    assert "12 particles" in out
    assert f"cloth panel: {tmp_path / 'a.usda'} prim /Set/Cloth, 7 faces, 14 vertices welded into 12 particles" in out
    assert "1 pinned" in out  # vertex 12 is a duplicate of vertex 0: one particle
