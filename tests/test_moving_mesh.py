"""Moving triangle-mesh colliders (warp_verlet/colliders/mesh.py, kernels/collide_mesh.py): a mesh moved by its USD
prim's time-sampled transform, by keyframed rotation, or deformed by time-sampled points never leaves a particle
inside it after a substep, even at 5 m/s; friction acts relative to the moving surface, so a cloth lying on a
moving platform is carried along; the cache plays the motion back; bad animated input is refused with one clear
error; the memory estimate counts what a moving mesh allocates."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from warp_verlet.colliders.mesh import distances_to_triangles, winding_numbers
from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene

THICKNESS = 0.01
TOL = 2e-6  # m: float32 rounding of coordinates near 1 m after the push-out
SPEED = 5.0  # m/s
CM = 0.01  # the USD assets' metersPerUnit


def scene_of(tmp_path: Path, colliders: list, cloth: dict | None = None, **simulation):
    spec = {"resolution": [12, 12], "size": [0.6, 0.6], "origin": [-0.3, 0.3, 0.25], "orientation": "vertical",
            "pins": ["top-edge"], "sticks": ["structural", "shear", "bend"], **(cloth or {})}
    scene_file = tmp_path / "scene.toml"
    return parse_scene({"simulation": {"fps": 60, "substeps": 16, "iterations": 4, **simulation}, "cloth": [spec],
                        "collider": colliders}, file=str(scene_file), scene_path=scene_file)


def signed_distances(spec, time: float, points: np.ndarray) -> np.ndarray:
    """Each point's distance to the mesh collider ``spec`` placed at ``time``, negative inside (float64)."""
    corners = spec.points_at(time)[spec.triangles]
    inside = winding_numbers(corners, points) > 0.5
    return np.where(inside, -1.0, 1.0) * distances_to_triangles(corners, points)


def deepest(scene, device: str, seconds: float) -> tuple[float, float]:
    """(the least signed distance of any free particle to the mesh after any substep, the farthest any particle
    went along +Z): the mesh must keep every particle THICKNESS outside."""
    sim = Simulator(scene, device, use_graph=False)
    spec = scene.colliders[0]
    free = sim.model.host_inv_mass > 0
    worst, pushed = np.inf, -np.inf
    for k in range(1, round(seconds / sim.settings.dt) + 1):
        sim.step()
        q = sim.positions().astype(np.float64)[free]
        worst = min(worst, signed_distances(spec, k * sim.settings.dt, q).min())
        pushed = max(pushed, q[:, 2].max())
    return worst, pushed


def cube_points(half: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed cube of half side ``half`` centred at the origin: (points, face counts, face indices)."""
    box = trimesh.creation.box(extents=[2 * half] * 3)
    triangles = np.asarray(box.faces, np.int32)
    return np.asarray(box.vertices, np.float64), np.full(len(triangles), 3, np.int32), triangles.ravel()


def write_usd(path: Path, translate_samples=None, point_samples=None, topology_samples=None, scale_samples=None,
              spin_samples=None, codes_per_second: float = 24.0) -> Path:
    """A USD file in centimetres with a cube Mesh at /Rig/Box: its parent's translate time-sampled by
    ``translate_samples`` {time code: (x, y, z) cm}, its points by ``point_samples`` {time code: (V, 3) cm}, its
    faceVertexIndices by ``topology_samples`` {time code: indices}, its parent's scale by ``scale_samples``, and
    its own rotateY by ``spin_samples`` {time code: degrees}."""
    from pxr import Gf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, CM)
    stage.SetTimeCodesPerSecond(codes_per_second)
    rig = UsdGeom.Xform.Define(stage, "/Rig")
    if translate_samples:
        op = rig.AddTranslateOp()
        for code, value in translate_samples.items():
            op.Set(Gf.Vec3d(*value), code)
    if scale_samples:
        op = rig.AddScaleOp()
        for code, value in scale_samples.items():
            op.Set(Gf.Vec3f(*value), code)
    mesh = UsdGeom.Mesh.Define(stage, "/Rig/Box")
    if spin_samples:
        op = mesh.AddRotateYOp()
        for code, value in spin_samples.items():
            op.Set(float(value), code)
    points, counts, indices = cube_points(10.0)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices))
    for code, value in (topology_samples or {}).items():
        mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(np.asarray(value, np.int32)), code)
    if point_samples:
        for code, value in point_samples.items():
            mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(value, np.float32)), code)
    else:
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    stage.GetRootLayer().Save()
    return path


# The cube crosses the curtain (z = 0.25 m) along +Z at 5 m/s: from z = -0.4 m at 0 s to 0.8 m at 0.24 s.
CROSSING = 0.24  # s
START_Z, END_Z = -0.4, -0.4 + SPEED * CROSSING


@pytest.mark.parametrize("how", ["usd-translate", "usd-points"])
def test_a_mesh_moved_by_its_usd_animation_at_5_m_s_leaves_no_particle_inside(tmp_path, device, how):
    # 5 m/s is 5.2 mm a substep, half the thickness. The asset is in centimetres at 24 time codes a second.
    codes = {0.0: START_Z, CROSSING * 24.0: END_Z}
    if how == "usd-translate":
        write_usd(tmp_path / "rig.usda", translate_samples={c: (0.0, 0.0, z / CM) for c, z in codes.items()})
    else:
        cube = cube_points(10.0)[0]
        write_usd(tmp_path / "rig.usda", point_samples={c: cube + (0.0, 0.0, z / CM) for c, z in codes.items()})
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "rig.usda", "prim": "/Rig/Box", "thickness": THICKNESS}])
    spec = scene.colliders[0]
    assert spec.moving and bool(spec.point_samples) == (how == "usd-points")
    np.testing.assert_allclose(spec.points_at(0.12).mean(axis=0), [0.0, 0.0, START_Z + SPEED * 0.12], atol=1e-6)
    worst, pushed = deepest(scene, device, 0.3)
    assert worst >= THICKNESS - TOL
    assert pushed > 0.6  # the cube carried the curtain's middle along through its whole crossing


def test_a_keyframed_rotation_at_5_m_s_leaves_no_particle_inside(tmp_path, device):
    # A 1 m paddle turning about Y at 10 rad/s (its tips at 5 m/s) sweeps through the curtain: rotate keyframes,
    # the angle linear in time, as translate's.
    trimesh.creation.box(extents=[1.0, 0.1, 0.04]).export(str(tmp_path / "paddle.obj"))
    turn = math.degrees(10.0 * 0.3)
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "paddle.obj", "thickness": THICKNESS,
                                 "rotate": [[0.0, 0.0, 0.0, 0.0], [0.3, 0.0, turn, 0.0]]}])
    spec = scene.colliders[0]
    c, s = math.cos(math.radians(turn / 3)), math.sin(math.radians(turn / 3))  # a third of the way, at 0.1 s
    about_y = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    np.testing.assert_allclose(spec.points_at(0.1), spec.points @ about_y.T, atol=1e-5)
    worst, pushed = deepest(scene, device, 0.3)
    assert worst >= THICKNESS - TOL
    assert pushed > 0.4  # the paddle swept the curtain along


def platform_run(tmp_path: Path, friction: float, how: str = "keyframes") -> tuple[float, float]:
    """(how far the cloth lying on the platform moved along +X, how far the platform did) over 1.3 s: the
    platform, a 1 m slab, slides 0.3 m along +X from 0.1 s to 1.1 s, easing in and out (smoothstep, keyed every
    10 ms: its speed changes by at most 0.018 m/s a key, under what friction takes off in a substep), by translate
    keyframes or by its time-sampled USD points."""
    times = np.linspace(0.0, 1.0, 101)
    keys = [(0.0, 0.0)] + [(0.1 + t + (1e-9 if k == 0 else 0.0), 0.3 * (3 * t ** 2 - 2 * t ** 3))
                           for k, t in enumerate(times)]
    slab = trimesh.creation.box(extents=[1.0, 0.1, 1.0])
    if how == "keyframes":
        slab.export(str(tmp_path / "slab.obj"))
        collider = {"mesh": "slab.obj", "translate": [[t, x, -0.05, 0.0] for t, x in keys]}
    else:
        corners = np.asarray(slab.vertices) + (0.0, -0.05, 0.0)
        write_usd(tmp_path / "slab.usda", point_samples={t * 24.0: (corners + (x, 0.0, 0.0)) / CM for t, x in keys})
        collider = {"mesh": "slab.usda", "prim": "/Rig/Box"}
    cloth = {"resolution": [10, 10], "size": [0.4, 0.4], "origin": [-0.2, THICKNESS, -0.2],
             "orientation": "horizontal", "pins": []}
    scene = scene_of(tmp_path, [{"type": "mesh", "thickness": THICKNESS, "friction_coefficient": friction,
                                 **collider}], cloth=cloth, substeps=8)
    sim = Simulator(scene, "cpu", use_graph=False)
    start = sim.positions().astype(np.float64)
    for _ in range(round(1.3 * 60)):
        sim.step_frame()
    moved = (sim.positions().astype(np.float64) - start)[:, 0].mean()
    platform = scene.colliders[0].points_at(1.3).mean(axis=0)[0] - scene.colliders[0].points_at(0.0).mean(axis=0)[0]
    return float(moved), float(platform)


@pytest.mark.parametrize("how", ["keyframes", "usd-points"])
def test_friction_on_a_moving_mesh_carries_the_cloth_with_it(tmp_path, how):
    # Sticking (mu = 1 > the platform's 1.8 m/s^2 / g), the cloth moves with the surface it touches: within
    # 1 mm of the platform's 0.3 m (the deforming one's surface moves by its points' moves, its BVH's velocities).
    # Without friction it stays where it was.
    moved, platform = platform_run(tmp_path, 1.0, how)
    assert platform == pytest.approx(0.3, abs=1e-6)
    assert moved == pytest.approx(platform, abs=1e-3)
    still, _ = platform_run(tmp_path, 0.0, how)
    assert abs(still) < 0.01


# ------------------------------------------------------------------------------------------- bad input


def usd_error(tmp_path: Path, **samples) -> str:
    name = f"bad{len(list(tmp_path.glob('bad*.usda')))}.usda"
    write_usd(tmp_path / name, **samples)
    with pytest.raises(SceneError) as caught:
        scene_of(tmp_path, [{"type": "mesh", "mesh": name, "prim": "/Rig/Box"}])
    text = str(caught.value)
    assert "scene.toml" in text and "collider[0].mesh" in text and f"{name} prim /Rig/Box" in text
    assert text.count("\n") == 0  # one line
    return text


def test_animated_usd_input_that_cannot_collide_is_refused_with_one_clear_error(tmp_path):
    cube, _, indices = cube_points(10.0)
    turned = np.roll(indices.reshape(-1, 3), 1, axis=0).ravel()  # the same triangles in another order
    assert "its topology changes over time (faceVertexIndices at time code 2 differs from time code 0)" in usd_error(
        tmp_path, topology_samples={0.0: indices, 2.0: turned})
    assert "its topology changes over time (7 points at time code 3, 8 at time code 0)" in usd_error(
        tmp_path, point_samples={0.0: cube, 3.0: cube[:7]})
    broken = cube.copy()
    broken[5, 1] = np.nan
    assert "vertex 5 is not a finite point at time code 24 (1 s)" in usd_error(
        tmp_path, point_samples={0.0: cube, 24.0: broken})
    assert "its local-to-world transform is not finite at time code 12 (0.5 s)" in usd_error(
        tmp_path, translate_samples={0.0: (0.0, 0.0, 0.0), 12.0: (0.0, np.inf, 0.0)})
    assert "at 1 s its transform scales or shears it relative to time 0" in usd_error(
        tmp_path, scale_samples={0.0: (1.0, 1.0, 1.0), 24.0: (2.0, 1.0, 1.0)})


# ------------------------------------------------------------------------------------------- cache, memory


def test_a_rotating_mesh_plays_back_from_the_cache(tmp_path):
    from pxr import Usd, UsdGeom

    from warp_verlet.apps.runner import run_scene
    from warp_verlet.output.cache_reader import open_cache, read_frame

    trimesh.creation.box(extents=[1.0, 0.1, 0.04]).export(str(tmp_path / "paddle.obj"))
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "paddle.obj", "name": "paddle", "translate": [0.0, -1.0, 0.0],
                                 "rotate": [[0.0, 10.0, 0.0, 0.0], [0.1, 10.0, 200.0, 30.0]]}], frames=6, substeps=2)
    run_scene(scene, tmp_path / "out.usda", device="cpu")
    stage = Usd.Stage.Open(str(tmp_path / "out.usda"))
    ops = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Colliders/paddle"))
    assert [op.GetOpName() for op in ops.GetOrderedXformOps()] == ["xformOp:translate", "xformOp:orient"]
    cache = open_cache(tmp_path / "out.usda")
    spec = scene.colliders[0]
    for frame in (0, 3, 5, 6):  # at the keys, between them and after the last: as the simulation places it
        (points, triangles), = read_frame(cache, frame).meshes
        np.testing.assert_allclose(points, spec.points_at(frame / 60), atol=2e-5)
        np.testing.assert_array_equal(triangles, spec.triangles)


def test_the_memory_estimate_counts_what_moving_meshes_allocate(tmp_path):
    from test_memory import mesh_native_bytes, simulator_bytes

    from warp_verlet.core.memory import estimate

    trimesh.creation.box(extents=[1.0, 0.1, 0.04]).export(str(tmp_path / "paddle.obj"))
    cube = cube_points(10.0)[0]
    write_usd(tmp_path / "rig.usda", point_samples={0.0: cube, 12.0: cube * 1.5, 24.0: cube})
    colliders = [{"type": "mesh", "mesh": "paddle.obj", "rotate": [[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 90.0, 0.0]]},
                 {"type": "mesh", "mesh": "rig.usda", "prim": "/Rig/Box", "translate": [2.0, 0.0, 0.0]},
                 {"type": "mesh", "mesh": "paddle.obj", "translate": [0.0, -2.0, 0.0]}]

    def allocated_and_estimated(scene) -> tuple[int, int]:
        sim = Simulator(scene, "cpu", use_graph=False)
        sim.step()
        return simulator_bytes(sim) + mesh_native_bytes(sim), estimate(scene).device_bytes

    with_meshes = allocated_and_estimated(scene_of(tmp_path, colliders))
    without = allocated_and_estimated(scene_of(tmp_path, []))
    # What the three meshes (rotating, deforming, still) add is what the estimate adds for them.
    assert with_meshes[0] - without[0] == with_meshes[1] - without[1] > 0


@pytest.mark.parametrize("how", ["usd-translate", "usd-points", "rotate"])
def test_a_moving_mesh_steps_alike_with_and_without_the_frames_capture(tmp_path, device, how):
    # A rigid mesh's placing replays from the captured frame; a deforming mesh's BVH refit does not (Warp's CPU
    # capture does not record it), so its frames are stepped launch by launch: the same positions, bit for bit.
    codes = {0.0: START_Z, CROSSING * 24.0: END_Z}
    if how == "rotate":
        trimesh.creation.box(extents=[1.0, 0.1, 0.04]).export(str(tmp_path / "paddle.obj"))
        collider = {"mesh": "paddle.obj", "rotate": [[0.0, 0.0, 0.0, 0.0], [0.3, 0.0, 172.0, 0.0]]}
    elif how == "usd-translate":
        write_usd(tmp_path / "rig.usda", translate_samples={c: (0.0, 0.0, z / CM) for c, z in codes.items()})
        collider = {"mesh": "rig.usda", "prim": "/Rig/Box"}
    else:
        cube = cube_points(10.0)[0]
        write_usd(tmp_path / "rig.usda", point_samples={c: cube + (0.0, 0.0, z / CM) for c, z in codes.items()})
        collider = {"mesh": "rig.usda", "prim": "/Rig/Box"}
    scene = scene_of(tmp_path, [{"type": "mesh", "thickness": THICKNESS, **collider}])
    runs = []
    for use_graph in (True, False):
        sim = Simulator(scene, device, use_graph=use_graph)
        for _ in range(12):
            sim.step_frame()
        runs.append(sim.positions())
    assert np.array_equal(*runs)
    assert runs[0][:, 2].max() > 0.3  # the mesh pushed the curtain


def test_live_turns_a_rotating_mesh(tmp_path):
    pytest.importorskip("viser", reason="the browser views need viser: pip install 'warp-verlet[live]'")
    from browser import free_port

    from warp_verlet.apps.live_app import LiveApp
    from warp_verlet.apps.live_session import LiveSession

    trimesh.creation.box(extents=[1.0, 0.1, 0.04]).export(str(tmp_path / "paddle.obj"))
    scene = scene_of(tmp_path, [{"type": "mesh", "mesh": "paddle.obj", "translate": [0.0, -1.0, 0.0],
                                 "rotate": [[0.0, 0.0, 0.0, 0.0], [0.1, 0.0, 90.0, 0.0]]}])
    app = LiveApp(LiveSession(scene, "cpu"), port=free_port(), record_path=tmp_path / "live.usdc")
    try:
        handle = app._collider_drawings["mesh"].items[0]
        for _ in range(12):  # 0.2 s: past the last keyframe
            app.session.tick(1 / 60)
        app.draw(0.0)
        half = math.sqrt(0.5)  # a quarter turn about +Y: (w, x, y, z) = (cos 45°, 0, sin 45°, 0)
        np.testing.assert_allclose(np.abs(handle.wxyz), (half, 0.0, half, 0.0), atol=1e-6)
        np.testing.assert_allclose(handle.position, (0.0, -1.0, 0.0), atol=1e-6)
    finally:
        app.server.stop()
        app.session.close()
