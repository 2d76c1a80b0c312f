"""Rigid patches (warp_verlet/constraints/rigid_patches.py, kernels/rigid_patches.py): every pairwise distance
inside a patch stays at its rest value while the cloth moves, a patch's centre of mass follows free fall, the
projection keeps momentum, patches compose with pins, and bad patches are refused."""

from __future__ import annotations

import numpy as np
import pytest

from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator

RIGID_TOLERANCE = 1.0e-6
"""Metres a pairwise distance inside a 0.2 m patch may be off its rest value at a frame: the patch's last
projection puts it on its rest shape exactly, up to float32 rounding of positions near 2 m (about 2.4e-7)."""

LABEL = {"min": [0.3, -1.0, 0.2], "max": [0.5, 3.0, 0.4]}  # a 5 x 5 square of the flag below


def flag(simulation: dict | None = None, **cloth) -> dict:
    spec = {"name": "flag", "resolution": [16, 24], "size": [0.6, 0.9], "origin": [0.0, 2.0, 0.0],
            "orientation": "horizontal", "pins": ["top-left", "top-right"], "sticks": ["structural", "shear"]}
    spec.update(cloth)
    return {"simulation": {"fps": 60, "substeps": 8, "iterations": 16, "damping": 0.5, **(simulation or {})},
            "cloth": [spec]}


def distances(points: np.ndarray) -> np.ndarray:
    p = points.astype(np.float64)
    return np.linalg.norm(p[:, None] - p[None], axis=2)


def worst_pair_error(sim: Simulator, members: np.ndarray, frames: int) -> tuple[float, float]:
    """(worst |distance - rest distance| inside the patch over the frames, how far the patch moved)."""
    start = sim.positions()[members]
    rest = distances(start)
    worst = 0.0
    for _ in range(frames):
        sim.step_frame()
        worst = max(worst, float(np.abs(distances(sim.positions()[members]) - rest).max()))
    return worst, float(np.abs(sim.positions()[members] - start).max())


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_a_patch_keeps_its_shape_while_the_cloth_falls_and_folds(precision):
    sim = Simulator(parse_scene(flag({"precision": precision}, rigid_patches=[[LABEL]])), "cpu")
    (patch,) = sim.scene.cloths[0].options["rigid_patches"]
    assert len(patch) == 25
    members = np.array(patch)
    worst, moved = worst_pair_error(sim, members, 90)
    assert moved > 0.2, "the patch hardly moved: the test would pass without the constraint"
    assert worst <= RIGID_TOLERANCE
    plain = Simulator(parse_scene(flag({"precision": precision})), "cpu")
    assert worst_pair_error(plain, members, 90)[0] > 100 * RIGID_TOLERANCE  # the same square without it bends


def test_the_patch_runs_last_in_a_sweep(launches):
    sim = Simulator(parse_scene(flag(rigid_patches=[[LABEL]])), "cpu", use_graph=False)
    assert sim.constraint_sets[-1] == "rigid patches"
    names = launches.of(sim.step)
    assert names.count("match_patches") == sim.settings.iterations
    assert names.index("match_patches") > names.index("relax_colour")


def test_a_free_falling_patch_follows_free_fall():
    # No pins: the whole cloth and its two patches fall freely from rest; each patch's centre of mass drops
    # g t^2 / 2, as every particle does (constant-acceleration Verlet is exact for it).
    data = flag({"frames": 30, "damping": 0.0}, pins=[], rigid_patches=[[LABEL], [[0, 0], [0, 1], [1, 0], [1, 1]]])
    sim = Simulator(parse_scene(data), "cpu")
    patches = [np.array(p) for p in sim.scene.cloths[0].options["rigid_patches"]]
    start = [sim.positions()[p].astype(np.float64).mean(0) for p in patches]
    for _ in range(30):
        sim.step_frame()
    t = 30 / 60
    for p, c0 in zip(patches, start):
        expected = c0 + np.array([0.0, -0.5 * 9.81 * t * t, 0.0])
        assert np.abs(sim.positions()[p].astype(np.float64).mean(0) - expected).max() < 1e-5


def test_the_projection_keeps_the_cloths_momentum():
    # A cloth thrown tumbling (each particle its own velocity) with a patch: the projections move particles but
    # not the mass-weighted centroid, so the cloth's centre of mass follows x0 + v0 t + g t^2 / 2 exactly.
    data = flag({"frames": 30, "damping": 0.0}, pins=[], rigid_patches=[[LABEL]])
    sim = Simulator(parse_scene(data), "cpu")
    rng = np.random.default_rng(3)
    velocity = rng.normal(0.0, 1.0, (sim.model.particle_count, 3))
    sim.state.set_velocity(velocity)
    x0 = sim.positions().astype(np.float64).mean(0)
    v0 = velocity.mean(0)  # equal masses
    for _ in range(30):
        sim.step_frame()
    t = 30 / 60
    expected = x0 + v0 * t + np.array([0.0, -0.5 * 9.81 * t * t, 0.0])
    assert np.abs(sim.positions().astype(np.float64).mean(0) - expected).max() < 1e-4


def test_a_patch_holding_a_pin_turns_about_it():
    # The patch's corner is the cloth's only pin: the patch swings about it, rigid, the pin where it was.
    data = flag(pins=["top-left"], rigid_patches=[[[r, c] for r in range(4) for c in range(4)]])
    sim = Simulator(parse_scene(data), "cpu")
    members = np.array(sim.scene.cloths[0].options["rigid_patches"][0])
    pin = sim.positions()[0].copy()
    worst, moved = worst_pair_error(sim, members, 60)
    assert moved > 0.05 and worst <= RIGID_TOLERANCE
    assert np.array_equal(sim.positions()[0], pin)


def test_patches_on_a_mesh_cloth(tmp_path):
    from test_angle_limit import strip_obj

    strip_obj(tmp_path / "strip.obj")  # 4 x 20 vertices, 0.05 m apart, in the y = 1 plane
    data = {"simulation": {"fps": 60, "substeps": 8, "iterations": 16},
            "cloth": [{"mesh": "strip.obj", "pins": [0, 20, 40, 60], "sticks": ["structural", "shear"],
                       "rigid_patches": [[{"min": [0.6, 0.0, -1.0], "max": [0.8, 2.0, 1.0]}], [10, 11, 30, 31]]}]}
    sim = Simulator(parse_scene(data, str(tmp_path / "s.toml"), tmp_path / "s.toml"), "cpu")
    first, second = (np.array(p) for p in sim.scene.cloths[0].options["rigid_patches"])
    assert len(first) == 4 * 5 and list(second) == [10, 11, 30, 31]
    for members in (first, second):
        sim2 = Simulator(parse_scene(data, str(tmp_path / "s.toml"), tmp_path / "s.toml"), "cpu")
        worst, moved = worst_pair_error(sim2, members, 45)
        assert moved > 0.05 and worst <= RIGID_TOLERANCE


@pytest.mark.parametrize("patches, key, problem", [
    ([[0]], "rigid_patches[0]", "two particles or more"),
    ([[0, 1], [1, 2]], "rigid_patches[1]", "shares particle 1 with rigid_patches[0]"),
    ([[0, 10_000]], "rigid_patches[0][1]", "outside the grid"),
    ([[[0, 0], [99, 0]]], "rigid_patches[0][1]", "outside the 16 x 24 grid"),
    ([[{"min": [5, 5, 5], "max": [6, 6, 6]}]], "rigid_patches[0][0]", "holds no particle"),
    ([["top-middle"]], "rigid_patches[0][0]", "unknown pin name"),
    ([[0, 1.5]], "rigid_patches[0][1]", "expected a particle index"),
    ([], "rigid_patches", "expected an array of patches"),
    ([[]], "rigid_patches[0]", "non-empty array"),
    ([[{"min": [1, 0, 0], "max": [0, 1, 1]}]], "rigid_patches[0][0]", "min <= max"),
])
def test_bad_patches_are_refused_naming_the_key(patches, key, problem):
    with pytest.raises(SceneError) as err:
        parse_scene(flag(rigid_patches=patches), "flag.toml")
    assert f"cloth[0].{key}" in str(err.value) and problem in str(err.value), str(err.value)


# ------------------------------------------------------------------ patches selected by a USD primvar or GeomSubset

CURTAIN_ROWS, CURTAIN_COLS = 25, 33  # scenes/assets/make_assets.py's write_curtain


def curtain(tmp_path, **cloth) -> dict:
    """scenes/curtain_override.toml's curtain (scenes/assets/curtain.usda: cm, Z up), hung from its rings."""
    from pathlib import Path

    asset = Path(__file__).resolve().parent.parent / "scenes" / "assets" / "curtain.usda"
    spec = {"name": "curtain", "mesh": str(asset), "prim": "/Set/Window/Curtain", "pins": [{"primvar": "rings"}],
            "mass": 0.6, "sticks": ["structural", "shear"], **cloth}
    return {"simulation": {"fps": 24, "substeps": 8, "iterations": 8, "gravity": [0.0, 0.0, -9.81],
                           "wind": [0.0, 4.0, 0.0]}, "cloth": [spec]}


def test_the_curtain_assets_hem_subset_is_a_rigid_batten(tmp_path):
    # The asset's GeomSubset "hem" holds the bottom row of faces: its patch is their corners, the last two rows
    # of the 25 x 33 vertices (the asset's vertices are its particles: nothing to weld).
    data = curtain(tmp_path, rigid_patches=[[{"subset": "hem"}]])
    sim = Simulator(parse_scene(data, str(tmp_path / "s.toml"), tmp_path / "s.toml"), "cpu")
    cloth = sim.scene.cloths[0]
    assert np.array_equal(cloth.mesh.mesh.particle_of_vertex, np.arange(CURTAIN_ROWS * CURTAIN_COLS))
    (patch,) = cloth.options["rigid_patches"]
    assert list(patch) == list(range((CURTAIN_ROWS - 2) * CURTAIN_COLS, CURTAIN_ROWS * CURTAIN_COLS))
    worst, moved = worst_pair_error(sim, np.array(patch), 24)
    assert moved > 0.05, "the hem hardly moved: the test would pass without the constraint"
    assert worst <= 1.6 / 0.2 * RIGID_TOLERANCE  # a 1.6 m batten: the float32 rounding scales with its size


def write_marked_grid(path, rows: int = 6, cols: int = 8) -> dict:
    """A rows x cols grid of quads (0.1 m apart, in the z = 0 plane, y up) as a USD Mesh /Set/Cloth with
    primvars "label" (vertex: 1 on a 2 x 3 block), "tabs" (uniform: 1 on two faces) and "blank" (vertex, all
    0), and GeomSubsets "corner" (three points at the top right) and "hem" (faces: the bottom row), no two
    sharing a vertex. Returns what each marks, as vertex indices, and the top row."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    index = np.arange(rows * cols).reshape(rows, cols)
    y, x = np.meshgrid(-0.1 * np.arange(rows), 0.1 * np.arange(cols), indexing="ij")
    points = np.stack([x, y + 1.0, np.zeros_like(x)], axis=-1).reshape(-1, 3).astype(np.float32)
    a = index[:-1, :-1].ravel()
    quads = np.stack([a, a + 1, a + cols + 1, a + cols], axis=1)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.Xform.Define(stage, "/Set")
    mesh = UsdGeom.Mesh.Define(stage, "/Set/Cloth")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4] * len(quads)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.ravel().astype(np.int32)))
    primvars = UsdGeom.PrimvarsAPI(mesh)
    label = np.zeros(rows * cols, np.int32)
    label[index[2:4, 3:6].ravel()] = 1
    primvars.CreatePrimvar("label", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex).Set(Vt.IntArray.FromNumpy(label))
    tab_faces = [0, 2 * (cols - 1)]  # the first faces of the first and the third rows
    tabs = np.zeros(len(quads), np.int32)
    tabs[tab_faces] = 1
    primvars.CreatePrimvar("tabs", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.uniform).Set(Vt.IntArray.FromNumpy(tabs))
    primvars.CreatePrimvar("blank", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex).Set(
        Vt.IntArray.FromNumpy(np.zeros(rows * cols, np.int32)))
    corner = [int(index[0, -1]), int(index[0, -2]), int(index[1, -1])]
    UsdGeom.Subset.CreateGeomSubset(mesh, "corner", UsdGeom.Tokens.point, Vt.IntArray(corner))
    hem_faces = list(range((rows - 2) * (cols - 1), (rows - 1) * (cols - 1)))
    UsdGeom.Subset.CreateGeomSubset(mesh, "hem", UsdGeom.Tokens.face, Vt.IntArray(hem_faces))
    stage.Save()
    return {"label": sorted(index[2:4, 3:6].ravel().tolist()), "tabs": sorted(set(quads[tab_faces].ravel().tolist())),
            "corner": sorted(corner), "hem": sorted(index[-2:].ravel().tolist()), "top": index[0].tolist()}


def marked_grid_scene(tmp_path, patches, pins=None):
    marked = write_marked_grid(tmp_path / "grid.usda")
    data = {"simulation": {"fps": 60, "substeps": 8, "iterations": 16},
            "cloth": [{"mesh": "grid.usda", "prim": "/Set/Cloth", "pins": pins if pins is not None else marked["top"][:1],
                       "sticks": ["structural", "shear"], "rigid_patches": patches}]}
    return data, marked


def load(tmp_path, data):
    return parse_scene(data, str(tmp_path / "s.toml"), tmp_path / "s.toml")


def test_patches_by_primvar_and_subset_select_what_the_usd_marks(tmp_path):
    patches = [[{"primvar": "label"}], [{"primvar": "tabs"}], [{"subset": "corner"}], [{"subset": "hem"}]]
    data, marked = marked_grid_scene(tmp_path, patches)
    scene = load(tmp_path, data)
    resolved = scene.cloths[0].options["rigid_patches"]
    assert [list(p) for p in resolved] == [marked[n] for n in ("label", "tabs", "corner", "hem")]
    # The same patches written as vertex indices make the same cloth, step for step.
    by_index = load(tmp_path, {**data, "cloth": [{**data["cloth"][0], "rigid_patches": [marked[n] for n in
                                                    ("label", "tabs", "corner", "hem")]}]})
    a, b = Simulator(scene, "cpu"), Simulator(by_index, "cpu")
    moved = a.positions().copy()
    for _ in range(20):
        a.step_frame()
        b.step_frame()
    assert np.abs(a.positions() - moved).max() > 0.05  # the cloth swung about its one pin
    assert np.array_equal(a.positions(), b.positions())


def test_a_primvar_patch_mixed_with_indices_and_boxes_stays_rigid(tmp_path):
    # One patch from a primvar, one vertex index and a box around one more vertex: their union is one rigid body.
    data, marked = marked_grid_scene(tmp_path, [[{"primvar": "label"}, 8 * 1 + 4,
                                                 {"min": [0.25, 0.55, -1.0], "max": [0.35, 0.65, 1.0]}]])
    sim = Simulator(load(tmp_path, data), "cpu")
    (patch,) = sim.scene.cloths[0].options["rigid_patches"]
    assert list(patch) == sorted(set(marked["label"]) | {8 * 1 + 4, 8 * 4 + 3})  # the box holds row 4, column 3
    worst, moved = worst_pair_error(sim, np.array(patch), 30)
    assert moved > 0.05 and worst <= RIGID_TOLERANCE


@pytest.mark.parametrize("patch, key, problem", [
    ({"primvar": "blank"}, "rigid_patches[0][0]", "primvar 'blank' marks no vertex of the mesh"),
    ({"primvar": "nope"}, "mesh", "no primvar 'nope' (its primvars: "),
    ({"subset": "nope"}, "mesh", "no GeomSubset 'nope' (its subsets: corner, hem)"),
    ({"subset": ""}, "rigid_patches[0][0].subset", "expected a non-empty string"),
    ({"subset": "hem", "primvar": "label"}, "rigid_patches[0][0]", "expected a particle index"),
])
def test_bad_named_patches_are_refused_naming_the_key(tmp_path, patch, key, problem):
    data, _ = marked_grid_scene(tmp_path, [[patch, 0]])
    with pytest.raises(SceneError) as err:
        load(tmp_path, data)
    assert f"s.toml: cloth[0].{key}: " in str(err.value) and problem in str(err.value), str(err.value)


def test_named_patches_need_a_usd_mesh(tmp_path):
    from mesh_files import write_obj
    from warp_verlet.geometry.faces import grid_faces

    write_obj(tmp_path / "grid.obj", np.array([[x, y, 0.0] for y in range(3) for x in range(3)]), grid_faces(3, 3))
    data = {"cloth": [{"mesh": "grid.obj", "pins": [0], "rigid_patches": [[1, 2], [{"subset": "hem"}]]}]}
    with pytest.raises(SceneError, match=r"cloth\[0\]\.rigid_patches\[1\]\[0\]: selecting vertices by subset \('hem'\) "
                                         r"needs a USD file; the mesh is a \.obj file"):
        load(tmp_path, data)
    grid = flag(rigid_patches=[[0, {"primvar": "label"}]])
    with pytest.raises(SceneError, match=r"cloth\[0\]\.rigid_patches\[0\]\[1\]: a primvar selects vertices of a mesh "
                                         "read from USD"):
        parse_scene(grid, "flag.toml")


def test_only_the_named_sets_asked_for_are_read(tmp_path):
    # The seam: each constraint kind declares the vertex sets its options name; the mesh reader looks up the
    # pins' and theirs, each once, and nothing else.
    from warp_verlet.input import mesh_scene
    from warp_verlet.constraints.rigid_patches import RigidPatches

    data, _ = marked_grid_scene(tmp_path, [[{"primvar": "tabs"}], [{"subset": "hem"}, {"primvar": "label"}]],
                                pins=[{"subset": "corner"}])
    scene = load(tmp_path, data)
    source = scene.cloths[0].mesh.mesh.source
    assert set(source.named_vertices) == {("subset", "corner"), ("primvar", "tabs"), ("subset", "hem"),
                                          ("primvar", "label")}
    written = parse_scene_options(data)
    assert RigidPatches().named_vertex_sets(written) == (
        ("primvar", "tabs", "cloth[0].rigid_patches[0][0]"), ("subset", "hem", "cloth[0].rigid_patches[1][0]"),
        ("primvar", "label", "cloth[0].rigid_patches[1][1]"))
    assert mesh_scene.kinds_vertex_sets(written) == RigidPatches().named_vertex_sets(written)
    assert RigidPatches().named_vertex_sets(scene.cloths[0].options) == ()  # resolved: indices only


def parse_scene_options(data: dict) -> dict:
    """The rigid_patches option of the scene's first cloth as written (parsed, not resolved)."""
    from warp_verlet.constraints.rigid_patches import RIGID_PATCHES
    from warp_verlet.scene_keys import Table

    t = Table("s.toml", "cloth[0]", data["cloth"][0])
    return {RIGID_PATCHES.name: RIGID_PATCHES.take(t)}


def test_patches_hold_on_every_device_and_repeat_bit_for_bit(device):
    runs = []
    for _ in range(2):
        sim = Simulator(parse_scene(flag(rigid_patches=[[LABEL]])), device)
        members = np.array(sim.scene.cloths[0].options["rigid_patches"][0])
        worst, moved = worst_pair_error(sim, members, 45)
        assert moved > 0.1 and worst <= RIGID_TOLERANCE
        runs.append(sim.positions())
    assert np.array_equal(runs[0], runs[1])  # deterministic per device
