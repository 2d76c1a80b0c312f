"""Triangle-mesh colliders (warp_verlet/colliders/mesh.py, kernels/collide_mesh.py): a cloth dropped on a closed
mesh never ends a substep inside it, friction holds or lets it slide on an inclined mesh, bad meshes are
refused with one clear error, the cache keeps the mesh and reads it back, and a scene without one is as
before."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import trimesh
import warp as wp

from warp_verlet.colliders.mesh import MESH, MeshCollider, distances_to_triangles, winding_numbers
from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import SceneError
from warp_verlet.kernels.collide_mesh import surface_query
from warp_verlet.input.scene import parse_scene

HALF = np.array([0.3, 0.1, 0.3])  # the test box's half extents, centred at the origin
THICKNESS = 0.01
TOL = 2e-6  # m: float32 rounding of coordinates near 1 m after the push-out


def write_box(path: Path, half=HALF, transform=None) -> Path:
    box = trimesh.creation.box(extents=2 * np.asarray(half), transform=transform)
    box.export(str(path))
    return path


def table_parts(top=(0.4, 0.02, 0.3), top_y=0.5, leg=0.03):
    """(centre, half extents) of a low-poly table: a top whose upper face is top_y up, and four legs standing on
    y = 0 that touch its underside."""
    parts = [(np.array([0.0, top_y - top[1], 0.0]), np.array(top))]
    leg_half = (top_y - 2 * top[1]) / 2
    for sx in (-1, 1):
        for sz in (-1, 1):
            parts.append((np.array([sx * (top[0] - leg), leg_half, sz * (top[2] - leg)]),
                          np.array([leg / 2, leg_half, leg / 2])))
    return parts


def write_table(path: Path) -> Path:
    boxes = [trimesh.creation.box(extents=2 * h, transform=trimesh.transformations.translation_matrix(c))
             for c, h in table_parts()]
    trimesh.util.concatenate(boxes).export(str(path))
    return path


def box_sdf(points, centre, half) -> np.ndarray:
    """The exact signed distance to an axis-aligned box (negative inside)."""
    d = np.abs(points - centre) - half
    return np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)


def scene_of(tmp_path: Path, colliders: list, cloth: dict | None = None, **simulation):
    spec = {"resolution": [16, 16], "size": [0.9, 0.9], "origin": [-0.45, 0.15, -0.45], "orientation": "horizontal",
            "sticks": ["structural", "shear", "bend"], **(cloth or {})}
    scene_file = tmp_path / "scene.toml"
    return parse_scene({"simulation": {"substeps": 8, "iterations": 4, **simulation}, "cloth": [spec],
                        "collider": colliders}, file=str(scene_file), scene_path=scene_file)


# ------------------------------------------------------------------------------------------- contact


def test_a_cloth_dropped_on_a_box_is_never_inside_it_after_a_substep(tmp_path, device):
    write_box(tmp_path / "box.obj")
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "box.obj", "thickness": THICKNESS, "friction_coefficient": 0.3}])
    sim = Simulator(scene, device, use_graph=False)
    closest = []
    for _ in range(8 * 40):  # 40 frames: it lands, and drapes over the edges
        sim.step()
        closest.append(box_sdf(sim.positions().astype(np.float64), 0.0, HALF).min())
    assert min(closest) >= THICKNESS - TOL
    q = sim.positions()
    assert q[:, 1].min() < HALF[1] - 0.1  # the overhang hangs 10 cm below the top: it drapes over the edges
    assert np.abs(box_sdf(q.astype(np.float64), 0.0, HALF).min() - THICKNESS) < 1e-4  # and rests on it


def test_float64_positions_are_kept_out_as_float32_ones(tmp_path):
    # The query runs in float32 and the push-out in the positions' precision: a float64 run rests the cloth at
    # the same distance, to float32's rounding.
    write_box(tmp_path / "box.obj")
    collider = [{"type": "mesh", "mesh": "box.obj", "thickness": THICKNESS}]
    ends = []
    for precision in ("float32", "float64"):
        sim = Simulator(scene_of(tmp_path, collider, precision=precision), "cpu", use_graph=False)
        assert sim.precision == precision
        worst = np.inf
        for _ in range(8 * 20):
            sim.step()
            worst = min(worst, box_sdf(sim.positions().astype(np.float64), 0.0, HALF).min())
        assert worst >= THICKNESS - TOL
        ends.append(sim.positions().astype(np.float64))
    np.testing.assert_allclose(ends[0], ends[1], atol=1e-4)


def test_a_cloth_dropped_on_a_table_with_legs_never_enters_it(tmp_path):
    write_table(tmp_path / "table.obj")
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "table.obj", "thickness": THICKNESS}],
                     cloth={"origin": [-0.45, 0.6, -0.45]})
    sim = Simulator(scene, "cpu", use_graph=False)
    parts = table_parts()
    worst = np.inf
    for _ in range(8 * 40):
        sim.step()
        q = sim.positions().astype(np.float64)
        worst = min(worst, np.min([box_sdf(q, c, h) for c, h in parts], axis=0).min())  # the union's distance
    assert worst >= THICKNESS - TOL


@pytest.mark.parametrize("friction", [0.0, 1.0])
def test_on_an_inclined_mesh_no_friction_slides_and_static_friction_holds(tmp_path, friction):
    # A long slab tilted 30 degrees about Z (downhill: -X); a small cloth lands on it and is watched for 0.5 s.
    angle = np.radians(30.0)
    tilt = trimesh.transformations.rotation_matrix(angle, [0, 0, 1])
    write_box(tmp_path / "slab.obj", half=(2.0, 0.05, 0.5), transform=tilt)
    top = 0.05 / np.cos(angle)  # the slab's upper face above the origin
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "slab.obj", "thickness": THICKNESS, "friction_coefficient": friction}],
                     cloth={"resolution": [5, 5], "size": [0.1, 0.1], "origin": [-0.05, top + 0.04, -0.05]},
                     damping=0.0, fps=60)
    sim = Simulator(scene, "cpu", use_graph=False)
    for _ in range(8 * 6):  # a tenth of a second: it lands
        sim.step()
    start = sim.positions().mean(axis=0)
    for _ in range(8 * 30):
        sim.step()
    downhill = -(sim.positions().mean(axis=0) - start) @ np.array([np.cos(angle), np.sin(angle), 0.0])
    slide = 0.5 * 9.81 * np.sin(angle) * 0.5 ** 2  # frictionless, from rest, in 0.5 s: 0.61 m
    if friction == 0.0:
        assert downhill > 0.8 * slide  # it slides (it starts with some speed from the landing, too)
    else:
        # mu = 1 > tan(30 degrees): Coulomb friction holds it where it landed (tests/test_friction.py checks the law).
        assert downhill < 0.01 * slide


def test_the_kernel_pushes_out_along_the_outward_direction(tmp_path):
    # Particles placed by hand inside, on and near the box are moved exactly to thickness outside, along the
    # nearest face's normal; one already further out is left alone.
    write_box(tmp_path / "box.obj")
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "box.obj", "thickness": THICKNESS}],
                     cloth={"resolution": [1, 4], "size": [0.0, 0.3], "origin": [0.0, 0.0, 0.0]}, gravity=[0, 0, 0])
    sim = Simulator(scene, "cpu", use_graph=False)
    placed = np.array([[0.05, 0.02, 0.0],      # inside, nearest the top face
                       [0.29, 0.0, 0.01],      # inside, nearest the +X face
                       [0.0, 0.1, -0.1],       # on the top face
                       [0.0, -0.3, 0.0]], np.float32)  # far below: untouched
    sim.state.particle_q.assign(placed)
    sim.state.particle_q_inertial.assign(placed)
    sim.state.particle_dq.zero_()
    from warp_verlet.kernels.collide_mesh import collide_meshes

    c = sim.model.colliders
    wp.launch(collide_meshes, 4, inputs=[sim.state.particle_q, sim.state.particle_q_inertial, sim.state.particle_dq,
                                         sim.model.inv_mass, c.mesh_ids, sim.state.mesh_offsets, c.mesh_reach,
                                         c.mesh_thickness, c.mesh_friction, wp.empty(0, dtype=wp.vec3, device="cpu"),
                                         0],
              device="cpu")
    expected = np.array([[0.05, 0.11, 0.0], [0.31, 0.0, 0.01], [0.0, 0.11, -0.1], [0.0, -0.3, 0.0]])
    np.testing.assert_allclose(sim.positions(), expected, atol=TOL)


def test_two_runs_are_bit_identical(tmp_path, device):
    write_table(tmp_path / "table.obj")
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "table.obj", "thickness": THICKNESS, "friction_coefficient": 0.5}],
                     cloth={"origin": [-0.45, 0.6, -0.45]})
    runs = []
    for _ in range(2):
        sim = Simulator(scene, device)
        for _ in range(20):
            sim.step_frame()
        runs.append(sim.positions())
    assert np.array_equal(runs[0], runs[1])


def test_a_scene_without_a_mesh_launches_and_allocates_nothing_of_it(tmp_path, launches):
    ground = {"type": "plane", "point": [0.0, -0.5, 0.0]}
    plain = Simulator(scene_of(tmp_path, [ground]), "cpu", use_graph=False)
    plain.step()
    assert "collide_meshes" not in launches.of(plain.step)
    assert not any(name.startswith("mesh_") for name in vars(plain.model.colliders))
    write_box(tmp_path / "box.obj")
    with_mesh = Simulator(scene_of(tmp_path, [ground, {"type": "mesh", "mesh": "box.obj"}]), "cpu", use_graph=False)
    with_mesh.step()
    before = launches.of(plain.step)
    assert before[-1] == "collide_planes"
    # The meshes clamp once a substep, before the ground; nothing else changes.
    assert launches.of(with_mesh.step) == before[:-1] + ["collide_meshes", "collide_planes"]


def test_a_moving_mesh_pushes_through_a_curtain_and_leaves_no_particle_inside(tmp_path, device, launches):
    # A 20 cm box crosses a hanging curtain along +Z at 1 m/s (2 mm a substep, a fifth of the thickness).
    write_box(tmp_path / "box.obj", half=(0.1, 0.1, 0.1))
    path = [[0.0, 0.0, -0.1, -0.4], [0.8, 0.0, -0.1, 0.4]]
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "box.obj", "translate": path, "thickness": THICKNESS}],
                     cloth={"resolution": [12, 12], "size": [0.6, 0.6], "origin": [-0.3, 0.3, 0.0],
                            "orientation": "vertical", "pins": ["top-edge"]}, fps=60, frames=60)
    spec = scene.colliders[0]
    assert spec.moving and spec.offset_at(0.4) == (0.0, -0.1, 0.0)
    sim = Simulator(scene, device, use_graph=False)
    dt = sim.settings.dt
    worst, pushed = np.inf, 0.0
    for k in range(1, 8 * 50 + 1):
        if k == 2:
            issued = launches.of(sim.step)
            assert issued[-3:] == ["advance_clock", "place_moving_meshes", "collide_moving_meshes"]  # placed, then clamped
        else:
            sim.step()
        q = sim.positions().astype(np.float64)
        worst = min(worst, box_sdf(q, np.asarray(spec.offset_at(k * dt)), 0.1).min())
        pushed = max(pushed, q[:, 2].max())
    assert worst >= THICKNESS - TOL
    assert pushed > 0.3  # the box carried the curtain's middle along


def test_a_moving_mesh_is_time_sampled_in_the_cache(tmp_path):
    from pxr import Usd, UsdGeom

    from warp_verlet.apps.runner import run_scene
    from warp_verlet.output.cache_reader import open_cache, read_frame

    write_box(tmp_path / "box.obj", half=(0.1, 0.1, 0.1))
    lift = [[0.0, 0.0, -1.0, 0.0], [0.1, 0.0, -0.5, 0.0]]
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "box.obj", "name": "lift", "translate": lift},
                                {"type": "mesh", "mesh": "box.obj", "name": "still", "translate": [2.0, 0.0, 0.0]}],
                     fps=30, frames=6)
    run_scene(scene, tmp_path / "out.usdc", device="cpu")
    stage = Usd.Stage.Open(str(tmp_path / "out.usdc"))
    lift = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Colliders/lift"))
    op = lift.GetOrderedXformOps()[0]
    assert op.GetOpName() == "xformOp:translate" and op.GetNumTimeSamples() == 7  # frames 0 to 6
    still = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Colliders/still")).GetOrderedXformOps()[0]
    assert still.GetNumTimeSamples() == 0 and tuple(still.Get()) == (2.0, 0.0, 0.0)
    cache = open_cache(tmp_path / "out.usdc")
    for frame, height in [(0, -1.0), (1, -1.0 + 0.5 / 3), (6, -0.5)]:
        (lifted, _), (kept, _) = read_frame(cache, frame).meshes
        np.testing.assert_allclose(lifted, scene.colliders[0].points + [0.0, height, 0.0], atol=1e-6)
        np.testing.assert_allclose(kept, scene.colliders[1].points + [2.0, 0.0, 0.0], atol=1e-6)
    try:
        from browser import free_port

        from warp_verlet.apps.cache_player import CachePlayer
    except ImportError:  # the browser views need viser
        return
    player = CachePlayer(tmp_path / "out.usdc", port=free_port())
    try:
        player.show(6)  # view draws the moved mesh again, the still one as it was
        np.testing.assert_allclose(player.meshes[0].vertices, scene.colliders[0].points + [0.0, -0.5, 0.0], atol=1e-6)
        np.testing.assert_allclose(player.meshes[1].vertices, scene.colliders[1].points + [2.0, 0.0, 0.0], atol=1e-6)
    finally:
        player.server.stop()


# ------------------------------------------------------------------------------------------- bad input


def error_of(tmp_path: Path, collider: dict) -> SceneError:
    with pytest.raises(SceneError) as caught:
        scene_of(tmp_path, [{"type": "mesh", **collider}])
    err = caught.value
    assert err.file == str(tmp_path / "scene.toml"), str(err)
    return err


def test_a_missing_file_is_refused(tmp_path):
    err = error_of(tmp_path, {"mesh": "nowhere.obj"})
    assert err.key == "collider[0].mesh" and "nowhere.obj: no such file" in str(err)


def test_an_empty_mesh_is_refused(tmp_path):
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    err = error_of(tmp_path, {"mesh": "points.obj"})
    assert err.key == "collider[0].mesh" and "an empty mesh" in str(err)


def test_non_finite_points_are_refused(tmp_path):
    box = trimesh.creation.box()
    lines = [f"v {x} {y} {z}" for x, y, z in box.vertices] + ["f " + " ".join(str(i + 1) for i in f) for f in box.faces]
    lines[3] = "v nan 0.5 0.5"
    (tmp_path / "nan.obj").write_text("\n".join(lines) + "\n")
    err = error_of(tmp_path, {"mesh": "nan.obj"})
    assert err.key == "collider[0].mesh" and "vertex 3 is not a finite point" in str(err)


def test_an_open_mesh_is_refused(tmp_path):
    box = trimesh.creation.box()
    trimesh.Trimesh(box.vertices, box.faces[:-1], process=False).export(str(tmp_path / "open.obj"))
    err = error_of(tmp_path, {"mesh": "open.obj"})
    assert err.key == "collider[0].mesh" and "an open mesh: 3 edges border one triangle only" in str(err)
    assert "closed" in err.problem


def test_a_mesh_wound_both_ways_is_refused(tmp_path):
    box = trimesh.creation.box()
    faces = box.faces.copy()
    faces[0] = faces[0][::-1]
    trimesh.Trimesh(box.vertices, faces, process=False).export(str(tmp_path / "flipped.obj"))
    err = error_of(tmp_path, {"mesh": "flipped.obj"})
    assert "not a closed surface wound one way" in str(err)


def test_a_missing_prim_is_refused_and_a_usd_prim_is_read(tmp_path):
    from pxr import Usd, UsdGeom, Vt

    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    stage = Usd.Stage.CreateNew(str(tmp_path / "set.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)  # centimetres: the collider is read in metres
    mesh = UsdGeom.Mesh.Define(stage, "/Set/Box")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(box.vertices.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr([3] * len(box.faces))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(box.faces.reshape(-1).astype(np.int32)))
    stage.GetRootLayer().Save()
    err = error_of(tmp_path, {"mesh": "set.usda", "prim": "/Set/Nope"})
    assert err.key == "collider[0].mesh" and "no prim at /Set/Nope" in str(err) and "/Set/Box" in str(err)
    collider = scene_of(tmp_path, [{"type": "mesh", "mesh": "set.usda", "prim": "/Set/Box",
                                    "translate": [0.0, 1.0, 0.0]}]).colliders[0]
    assert isinstance(collider, MeshCollider) and collider.name == "mesh0"
    np.testing.assert_allclose(collider.points_at(0.0).min(axis=0), [-0.01, 0.99, -0.01])
    np.testing.assert_allclose(collider.points_at(0.0).max(axis=0), [0.01, 1.01, 0.01])


def test_a_translation_beyond_float32_is_refused(tmp_path):
    write_box(tmp_path / "box.obj")
    err = error_of(tmp_path, {"mesh": "box.obj", "translate": [0.0, 1e39, 0.0]})
    assert err.key == "collider[0].translate[1]" and "float32" in err.problem
    err = error_of(tmp_path, {"mesh": "box.obj", "translate": [[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, -1e39]]})
    assert err.key == "collider[0].translate[1][3]" and "float32" in err.problem
    err = error_of(tmp_path, {"mesh": "box.obj", "translate": [[1.0, 0.0, 0.0, 0.0], [0.5, 0.0, 0.0, 1.0]]})
    assert err.key == "collider[0].translate[1][0]" and "keyframe times must increase" in err.problem


def test_a_mesh_wound_inward_is_turned_outward_and_duplicates_are_welded(tmp_path):
    # Each face with its own three corners (as an exporter writing per-face normals does), wound inward.
    box = trimesh.creation.box()
    corners = box.vertices[box.faces[:, ::-1]].reshape(-1, 3)
    lines = [f"v {x} {y} {z}" for x, y, z in corners]
    lines += [f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}" for k in range(len(box.faces))]
    (tmp_path / "inward.obj").write_text("\n".join(lines) + "\n")
    collider = scene_of(tmp_path, [{"type": "mesh", "mesh": "inward.obj"}]).colliders[0]
    assert collider.points.shape == (8, 3) and collider.triangles.shape == (12, 3)
    a, b, c = (collider.points[collider.triangles[:, k]] for k in range(3))
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() > 0  # outward: a positive volume


def test_nothing_is_written_when_the_mesh_is_refused(tmp_path):
    from warp_verlet.apps.cli import main

    box = trimesh.creation.box()
    trimesh.Trimesh(box.vertices, box.faces[:-1], process=False).export(str(tmp_path / "open.obj"))
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text('[output]\npath = "out.usdc"\n[[cloth]]\nresolution = [2, 2]\nsize = [1.0, 1.0]\n'
                          '[[collider]]\ntype = "mesh"\nmesh = "open.obj"\n')
    assert main(["run", str(scene_file)]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["open.obj", "scene.toml"]


# ------------------------------------------------------------------------------------------- warnings


@wp.kernel
def near_first_and_full_queries(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), thickness: float, reach: float,
                                near_first: wp.array(dtype=wp.vec4), full: wp.array(dtype=wp.vec4)):
    """(closest point, sign) from the clamp's query and from one query over the whole reach; zeros: none found."""
    i = wp.tid()
    q = surface_query(mesh, points[i], thickness, reach)
    if q.result:
        c = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        near_first[i] = wp.vec4(c[0], c[1], c[2], q.sign)
    r = wp.mesh_query_point_sign_normal(mesh, points[i], reach)
    if r.result:
        c = wp.mesh_eval_position(mesh, r.face, r.u, r.v)
        full[i] = wp.vec4(c[0], c[1], c[2], r.sign)


def test_the_near_first_query_finds_what_the_full_query_finds_where_the_clamp_acts(tmp_path):
    # The clamp asks near the particle first and over the whole reach only where a ray finds it deep inside. On a
    # table with legs (concave, several parts, the legs touching the top's underside), at random points around
    # and inside it, it must return the full query's closest point and side wherever the clamp acts (inside, or
    # within the thickness outside), and may find nothing only for points outside and clear of the surface. (With
    # the upward ray alone, 12 points deep in the legs were missed: the ray meets the top's underside there.)
    thickness = 0.004  # the table's top is 40 mm thick and its legs 30 mm: room to be deeper than 2 thicknesses
    write_table(tmp_path / "table.obj")
    table = trimesh.load(str(tmp_path / "table.obj"), force="mesh")
    lo, hi = table.bounds
    reach = thickness + 0.5 * float(np.min(hi - lo))
    mesh = wp.Mesh(points=wp.array(np.asarray(table.vertices, np.float32), dtype=wp.vec3, device="cpu"),
                   indices=wp.array(np.asarray(table.faces, np.int32).ravel(), dtype=int, device="cpu"))
    rng = np.random.default_rng(5)
    points = rng.uniform(lo - 0.05, hi + 0.05, (20000, 3)).astype(np.float32)
    near_first, full = wp.zeros(len(points), dtype=wp.vec4, device="cpu"), wp.zeros(len(points), dtype=wp.vec4, device="cpu")
    wp.launch(near_first_and_full_queries, len(points), [mesh.id, wp.array(points, dtype=wp.vec3, device="cpu"),
                                                         thickness, reach], [near_first, full], device="cpu")
    near_first, full = near_first.numpy(), full.numpy()
    distance = np.linalg.norm(points - full[:, :3], axis=1)
    inside = full[:, 3] < 0
    acts = inside | ((full[:, 3] > 0) & (distance < thickness))
    assert (inside & (distance > 2 * thickness)).sum() > 100  # deep inside: found by the ray and the second query
    np.testing.assert_allclose(near_first[acts], full[acts], atol=1e-6)
    missed = near_first[:, 3] == 0
    assert np.all(full[missed, 3] >= 0) and np.all(distance[missed & (full[:, 3] > 0)] > 2 * thickness - 1e-6)


def test_a_cloth_starting_inside_the_mesh_is_warned_about(tmp_path):
    from warp_verlet.input.scene_warnings import start_inside_warnings

    write_box(tmp_path / "box.obj")
    inside = scene_of(tmp_path, [{"type": "mesh", "mesh": "box.obj", "name": "crate", "thickness": THICKNESS}],
                      cloth={"origin": [-0.45, 0.0, -0.45]})
    warnings = start_inside_warnings(inside)
    assert len(warnings) == 1 and "mesh 'crate'" in warnings[0]
    above = scene_of(tmp_path, [{"type": "mesh", "mesh": "box.obj", "thickness": THICKNESS}],
                     cloth={"origin": [-0.45, HALF[1] + 2 * THICKNESS, -0.45]})
    assert start_inside_warnings(above) == []


def test_the_inside_and_distance_helpers_agree_with_a_box():
    box = trimesh.creation.box(extents=2 * HALF)
    rng = np.random.default_rng(3)
    points = rng.uniform(-0.5, 0.5, (400, 3))
    corners = box.vertices[box.faces]
    sdf = box_sdf(points, 0.0, HALF)
    np.testing.assert_array_equal(winding_numbers(corners, points) > 0.5, sdf < 0)
    np.testing.assert_allclose(distances_to_triangles(corners, points), np.abs(sdf), atol=1e-12)


# ------------------------------------------------------------------------------------------- the cache


def test_the_cache_holds_the_mesh_and_reads_it_back(tmp_path):
    from pxr import Usd, UsdGeom

    from warp_verlet.apps.preview_render import frame_panel, render_panel
    from warp_verlet.apps.runner import run_scene
    from warp_verlet.output.cache_reader import open_cache, read_frame

    write_table(tmp_path / "table.obj")
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "table.obj", "name": "table", "purpose": "default"},
                                {"type": "plane", "name": "ground"}], cloth={"origin": [-0.45, 0.6, -0.45]},
                     frames=3)
    run_scene(scene, tmp_path / "out.usdc", device="cpu")
    stage = Usd.Stage.Open(str(tmp_path / "out.usdc"))
    prim = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Colliders/table"))
    assert prim and prim.GetPurposeAttr().Get() == "default"
    assert list(prim.GetFaceVertexCountsAttr().Get()) == [3] * 60  # five boxes
    assert not prim.GetPointsAttr().GetNumTimeSamples()  # written once
    cache = open_cache(tmp_path / "out.usdc")
    assert [kind.type for kind, _ in cache.colliders] == ["mesh", "plane"]
    frame = read_frame(cache, 3)
    (points, triangles), = frame.meshes
    spec = scene.colliders[0]
    np.testing.assert_array_equal(points, spec.points.astype(np.float32))
    np.testing.assert_array_equal(triangles, spec.triangles)
    assert len(frame.planes) == 1 and not frame.spheres
    panel = frame_panel(frame, cache.up_axis, 64, 48)
    assert len(panel.meshes) == 1 and len(panel.meshes[0].triangles) == 60
    # The preview draws it: the legs show below the cloth (12 % of the pixels change without it here).
    with_table = render_panel(panel, 64, 48).astype(int)
    without = render_panel(dataclasses.replace(panel, meshes=()), 64, 48).astype(int)
    assert (np.abs(with_table - without).max(axis=2) > 30).mean() > 0.05


@pytest.mark.cuda
def test_the_memory_estimate_counts_the_bvh_warp_allocates_on_cuda():
    # On CUDA what Warp allocates comes from the device's memory pool, which counts it: the arrays the kind makes
    # and the wp.Mesh built on them must take what the kind declares, within 1 % and 8 KiB (the pool may round
    # each of the twenty-odd allocations up; a term of the declaration missing is 4 % or more here).
    if not wp.is_cuda_available() or not wp.is_mempool_enabled("cuda:0"):
        pytest.skip("needs a CUDA device with a memory pool")
    box = trimesh.creation.box()
    for _ in range(5):
        box = box.subdivide()  # 12 x 4^5 = 12,288 triangles
    spec = MeshCollider("m", "test", np.asarray(box.vertices), np.asarray(box.faces, np.int32))
    with wp.ScopedDevice("cuda:0"):
        wp.synchronize()
        before = wp.get_mempool_used_mem_current("cuda:0")
        built = MESH.build((spec,), "cuda:0")
        wp.synchronize()
        used = wp.get_mempool_used_mem_current("cuda:0") - before
    declared = MESH.device_bytes(MESH.counts((spec,)))
    assert abs(used - declared) <= 0.01 * declared + 8192, (used, declared)
    del built


# ------------------------------------------------------------------------------------------- the pages


def test_live_draws_the_mesh_saves_it_and_view_draws_it_back(tmp_path):
    pytest.importorskip("viser", reason="the browser views need viser: pip install 'warp-verlet[live]'")
    from browser import free_port
    from pxr import Usd, UsdGeom

    from warp_verlet.apps.cache_player import CachePlayer
    from warp_verlet.apps.live_app import LiveApp
    from warp_verlet.apps.live_session import LiveSession

    write_table(tmp_path / "table.obj")
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "table.obj", "name": "table", "thickness": THICKNESS}],
                     cloth={"origin": [-0.45, 0.6, -0.45]})
    app = LiveApp(LiveSession(scene, "cpu"), port=free_port(), record_path=tmp_path / "live.usdc")
    try:
        drawing = app._collider_drawings["mesh"]
        assert len(drawing.items) == 1 and drawing.update is None  # drawn once: it never moves
        np.testing.assert_array_equal(drawing.items[0].vertices, scene.colliders[0].points.astype(np.float32))
        for _ in range(3):
            app.session.tick(1 / 60)
        app.session.save(tmp_path / "saved.usdc")
    finally:
        app.server.stop()
        app.session.close()
    stage = Usd.Stage.Open(str(tmp_path / "saved.usdc"))
    prim = stage.GetPrimAtPath("/World/Colliders/table")
    assert prim.IsA(UsdGeom.Mesh) and len(UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get()) == 60
    player = CachePlayer(tmp_path / "saved.usdc", port=free_port())
    try:
        handle = player.server.scene._handle_from_node_name["/colliders/mesh0"]
        assert len(handle.faces) == 60
    finally:
        player.server.stop()


def test_live_moves_a_moving_mesh_with_its_translation(tmp_path):
    pytest.importorskip("viser", reason="the browser views need viser: pip install 'warp-verlet[live]'")
    from browser import free_port

    from warp_verlet.apps.live_app import LiveApp
    from warp_verlet.apps.live_session import LiveSession

    write_box(tmp_path / "box.obj", half=(0.1, 0.1, 0.1))
    path = [[0.0, 0.0, -1.0, 0.0], [0.1, 0.0, -0.5, 0.0]]
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "box.obj", "translate": path}])
    app = LiveApp(LiveSession(scene, "cpu"), port=free_port(), record_path=tmp_path / "live.usdc")
    try:
        handle = app._collider_drawings["mesh"].items[0]
        np.testing.assert_allclose(handle.position, (0.0, -1.0, 0.0))
        for _ in range(12):  # 0.2 s: past the last keyframe
            app.session.tick(1 / 60)
        app.draw(0.0)
        np.testing.assert_allclose(handle.position, (0.0, -0.5, 0.0), atol=1e-6)
    finally:
        app.server.stop()
        app.session.close()


@pytest.mark.parametrize("suffix", [".usdc", ".usda"])
def test_the_cache_size_estimate_covers_the_mesh_prim(tmp_path, suffix):
    # The free-space check counts a mesh's points and triangles: what a 12,288-triangle mesh adds to a cache is
    # within its estimate, and more than a third of it (measured: about a half in crate files, two thirds in text).
    from warp_verlet.apps.runner import run_scene
    from warp_verlet.output.output_file import estimate_cache

    box = trimesh.creation.box()
    for _ in range(5):
        box = box.subdivide()
    box.export(str(tmp_path / "fine.obj"))
    sizes = []
    for colliders in ([{"type": "mesh", "mesh": "fine.obj", "translate": [0.0, -3.0, 0.0]}], []):
        scene = scene_of(tmp_path, colliders, frames=1)
        run_scene(scene, tmp_path / f"out{len(colliders)}{suffix}", device="cpu")
        sizes.append((tmp_path / f"out{len(colliders)}{suffix}").stat().st_size)
    added = sizes[0] - sizes[1]
    cached = MESH.cached(scene_of(tmp_path, [{"type": "mesh", "mesh": "fine.obj"}]).colliders[0])
    text = suffix == ".usda"
    estimated = estimate_cache((), [cached], text).static_bytes - estimate_cache((), [], text).static_bytes
    assert added <= estimated < 3 * added, (added, estimated)


# ------------------------------------------------------------------------------------- shipped scene


def test_the_curtain_leans_on_its_window_frame_and_never_enters_it():
    # scenes/curtain_frame.toml: the breeze presses the curtain against the frame prim read from the asset it
    # hangs in. Over half a second (it reaches the frame in the first frame) some particles rest on the frame,
    # and after every substep none is nearer than the thickness (signed distance by the winding number and the
    # exact distance to the frame's triangles, in metres and world space as the collider holds them).
    from warp_verlet.input.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parent.parent / "scenes" / "curtain_frame.toml")
    sim = Simulator(scene, "cpu", use_graph=False)
    (frame,) = sim.model.colliders.meshes
    assert frame.name == "frame" and frame.thickness == 0.02
    corners = frame.points[frame.triangles] + np.asarray(frame.keyframes[0][1])
    worst, touching = np.inf, 0
    for _ in range(scene.simulation.substeps * 12):
        sim.step()
        q = sim.positions().astype(np.float64)
        signed = np.where(winding_numbers(corners, q) > 0.5, -1.0, 1.0) * distances_to_triangles(corners, q)
        worst = min(worst, signed.min())
        touching = max(touching, int((signed < frame.thickness + 1e-4).sum()))
    assert worst >= frame.thickness - TOL
    assert touching >= 10  # it does lean on the frame: the check above is not vacuous
