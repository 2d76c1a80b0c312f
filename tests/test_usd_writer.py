"""Tests of the USD point-cache writer and validator, on small hand-built shapes (no simulator, no warp)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from dataclasses import replace

import numpy as np
import pytest
from pxr import Usd, UsdGeom, Vt

from warp_verlet.errors import OutputError
from warp_verlet.geometry.faces import Faces
from warp_verlet.output.usd_writer import CachedShape, PointCacheWriter, validate_cache

from meshes import HOUSE  # tests/meshes.py (pytest puts tests/ on sys.path)

ROWS, COLS, ROPE_N = 3, 4, 5


def grid_shape(name: str = "cloth", rows: int = ROWS, cols: int = COLS) -> CachedShape:
    # The same quad layout as topology.build_cloth: (r,c) -> (r+1,c) -> (r+1,c+1) -> (r,c+1).
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (r * cols + c).ravel()
    faces = np.stack([a, a + cols, a + cols + 1, a + 1], axis=1).astype(np.int32)
    uu, vv = np.meshgrid(np.arange(cols) / (cols - 1), 1.0 - np.arange(rows) / (rows - 1), indexing="xy")
    uvs = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float32)
    return CachedShape(name=name, faces=faces, uvs=uvs, point_count=rows * cols)


def rope_shape(name: str = "rope", n: int = ROPE_N) -> CachedShape:
    faces = np.zeros((0, 4), np.int32)  # no faces: a rope
    return CachedShape(name=name, faces=faces, uvs=np.zeros((n, 2), np.float32), point_count=n)


def random_frames(rng: np.random.Generator, shapes: list[CachedShape], count: int) -> list[list[np.ndarray]]:
    return [[rng.normal(size=(s.point_count, 3)).astype(np.float32) for s in shapes] for _ in range(count)]


def samples(attr: Usd.Attribute) -> list[float]:
    return list(attr.GetTimeSamples())


@pytest.mark.parametrize("ext", [".usdc", ".usda", ".usd"])
def test_round_trip(tmp_path, ext):
    shapes = [grid_shape(), rope_shape()]
    frames = random_frames(np.random.default_rng(1), shapes, 7)
    path = tmp_path / f"cache{ext}"
    start = 3
    with PointCacheWriter(path, shapes, fps=24.0, up_axis="Z", meters_per_unit=0.01, save_every=3,
                          start_frame=start, metadata={"simulator": "warp-verlet 0.1.0", "scene": "a.toml"}) as w:
        for i, pts in enumerate(frames):
            w.write_frame(start + i, pts)
        assert w.frames_written == 7

    stage = Usd.Stage.Open(str(path))
    assert stage.GetStartTimeCode() == start and stage.GetEndTimeCode() == start + 6
    layer = stage.GetRootLayer()
    assert layer.timeCodesPerSecond == 24.0 and layer.framesPerSecond == 24.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    assert stage.GetDefaultPrim().GetPath() == "/World" and stage.GetDefaultPrim().IsA(UsdGeom.Xform)
    assert dict(layer.customLayerData) == {"simulator": "warp-verlet 0.1.0", "scene": "a.toml"}

    mesh = UsdGeom.Mesh.Get(stage, "/World/cloth")
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert mesh.GetDoubleSidedAttr().Get() is True
    assert mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.rightHanded
    # Topology is authored once, untimed.
    for attr in (mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr()):
        assert attr.GetNumTimeSamples() == 0
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [4] * len(shapes[0].faces)
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()), shapes[0].faces.indices)
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetTypeName() == "texCoord2f[]" and st.GetInterpolation() == UsdGeom.Tokens.vertex
    np.testing.assert_array_equal(np.asarray(st.Get()), shapes[0].uvs)  # exact: float32 in, float32 out

    rope = UsdGeom.BasisCurves.Get(stage, "/World/rope")
    times = [float(start + i) for i in range(7)]
    for k, prim in enumerate((mesh, rope)):
        assert samples(prim.GetPointsAttr()) == times
        assert samples(prim.GetExtentAttr()) == times
        for i, t in enumerate(times):
            got = np.asarray(prim.GetPointsAttr().Get(t))
            assert got.dtype == np.float32
            np.testing.assert_array_equal(got, frames[i][k])  # exact float32 equality
    # The mesh extent is exactly the float32 bounding box of the points.
    for i, t in enumerate(times):
        ext = np.asarray(mesh.GetExtentAttr().Get(t))
        np.testing.assert_array_equal(ext, [frames[i][0].min(axis=0), frames[i][0].max(axis=0)])
    del stage
    assert validate_cache(path) == []


def test_rope_is_linear_basis_curves(tmp_path):
    path = tmp_path / "rope.usdc"
    pts = np.stack([np.linspace(0, 1, ROPE_N), np.zeros(ROPE_N), np.zeros(ROPE_N)], axis=1).astype(np.float32)
    with PointCacheWriter(path, [rope_shape()], fps=30.0, meters_per_unit=0.01) as w:
        w.write_frame(0, [pts])

    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath("/World/rope")
    assert prim.IsA(UsdGeom.BasisCurves) and not prim.IsA(UsdGeom.Mesh)
    curves = UsdGeom.BasisCurves(prim)
    assert list(curves.GetCurveVertexCountsAttr().Get()) == [ROPE_N]
    assert curves.GetTypeAttr().Get() == UsdGeom.Tokens.linear
    assert curves.GetWrapAttr().Get() == UsdGeom.Tokens.nonperiodic
    assert curves.GetWidthsInterpolation() == UsdGeom.Tokens.constant
    # 5 mm in stage units: centimetres here. float32 storage, so compare to 1e-6 relative.
    widths = np.asarray(curves.GetWidthsAttr().Get())
    assert widths.shape == (1,) and widths[0] == pytest.approx(0.5, rel=1e-6)
    assert not UsdGeom.PrimvarsAPI(curves).GetPrimvar("st")  # ropes carry no UVs
    # The extent pads the points by half the width on every side (float32: 1e-6 absolute).
    ext = np.asarray(curves.GetExtentAttr().Get(0))
    np.testing.assert_allclose(ext, [[-0.25, -0.25, -0.25], [1.25, 0.25, 0.25]], atol=1e-6)
    del stage
    assert validate_cache(path) == []


def test_nothing_extra_is_authored(tmp_path):
    path = tmp_path / "cache.usdc"
    shapes = [grid_shape(), rope_shape()]
    with PointCacheWriter(path, shapes, fps=30.0) as w:
        for f, pts in enumerate(random_frames(np.random.default_rng(2), shapes, 2)):
            w.write_frame(f, pts)

    stage = Usd.Stage.Open(str(path))
    authored = {p.GetName(): {a.GetName() for a in p.GetAttributes() if a.HasAuthoredValue()}
                for p in stage.Traverse()}
    assert authored == {
        "World": set(),
        "cloth": {"points", "extent", "faceVertexCounts", "faceVertexIndices", "subdivisionScheme",
                  "doubleSided", "orientation", "primvars:st"},
        "rope": {"points", "extent", "curveVertexCounts", "type", "wrap", "widths"},
    }
    mesh = UsdGeom.Mesh.Get(stage, "/World/cloth")
    for attr in (mesh.GetNormalsAttr(), mesh.GetVelocitiesAttr(), mesh.GetHoleIndicesAttr()):
        assert not attr.HasAuthoredValue()


@pytest.mark.parametrize("breakage", ["stale_extent", "wrong_point_count", "st_size", "no_up_axis"])
def test_validate_cache_finds_problems(tmp_path, breakage):
    path = tmp_path / "cache.usdc"
    shapes = [grid_shape()]
    with PointCacheWriter(path, shapes, fps=30.0) as w:
        for f, pts in enumerate(random_frames(np.random.default_rng(3), shapes, 3)):
            w.write_frame(f, pts)
    assert validate_cache(path) == []

    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh.Get(stage, "/World/cloth")
    points = np.asarray(mesh.GetPointsAttr().Get(1))
    if breakage == "stale_extent":  # move the points without updating the extent
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points + 10.0), 1)
        expected = "extent"
    elif breakage == "wrong_point_count":
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points[:-1])), 1)
        expected = "points"
    elif breakage == "st_size":
        UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Set(Vt.Vec2fArray([(0.0, 0.0)] * 3))
        expected = "primvars:st"
    else:
        stage.ClearMetadata("upAxis")
        expected = "upAxis"
    stage.GetRootLayer().Save()
    del mesh, stage

    problems = validate_cache(path)
    assert problems, f"{breakage} went unnoticed"
    assert any(expected in p for p in problems), problems


def test_validate_cache_missing_file(tmp_path):
    assert validate_cache(tmp_path / "nope.usdc")


CRASH_SCRIPT = textwrap.dedent("""
    import os, sys
    import numpy as np
    from warp_verlet.output.usd_writer import CachedShape, PointCacheWriter

    faces = np.array([[0, 2, 3, 1]], np.int32)
    shape = CachedShape("cloth", faces, np.zeros((4, 2), np.float32), 4)
    w = PointCacheWriter(sys.argv[1], [shape], fps=30.0, save_every=5)
    for f in range(12):
        w.write_frame(f, [np.full((4, 3), f, np.float32) + np.arange(4, dtype=np.float32)[:, None]])
    os._exit(1)  # a crash: no close(), no finalizers, frames 10 and 11 were never saved
""")


def test_crash_leaves_the_saved_frames(tmp_path):
    path = tmp_path / "crash.usdc"
    result = subprocess.run([sys.executable, "-c", CRASH_SCRIPT, str(path)], capture_output=True, text=True)
    assert result.returncode == 1, result.stderr

    stage = Usd.Stage.Open(str(path))
    assert stage.GetStartTimeCode() == 0 and stage.GetEndTimeCode() == 9
    points = UsdGeom.Mesh.Get(stage, "/World/cloth").GetPointsAttr()
    assert samples(points) == [float(f) for f in range(10)]
    for f in range(10):
        expected = np.full((4, 3), f, np.float32) + np.arange(4, dtype=np.float32)[:, None]
        np.testing.assert_array_equal(np.asarray(points.Get(f)), expected)
    del points, stage
    assert validate_cache(path) == []


def test_exception_in_context_still_saves(tmp_path):
    path = tmp_path / "cache.usdc"
    shapes = [grid_shape()]
    with pytest.raises(RuntimeError, match="boom"):
        with PointCacheWriter(path, shapes, fps=30.0, save_every=10) as w:
            for f, pts in enumerate(random_frames(np.random.default_rng(4), shapes, 3)):
                w.write_frame(f, pts)
            raise RuntimeError("boom")
    w.close()  # idempotent
    stage = Usd.Stage.Open(str(path))
    assert stage.GetEndTimeCode() == 2
    assert samples(UsdGeom.Mesh.Get(stage, "/World/cloth").GetPointsAttr()) == [0.0, 1.0, 2.0]


def test_overwrites_existing_file(tmp_path):
    path = tmp_path / "cache.usdc"
    shapes = [grid_shape()]
    frames = random_frames(np.random.default_rng(5), shapes, 5)
    for count in (5, 2):
        with PointCacheWriter(path, shapes, fps=30.0) as w:
            for f in range(count):
                w.write_frame(f, frames[f])
    stage = Usd.Stage.Open(str(path))
    assert samples(UsdGeom.Mesh.Get(stage, "/World/cloth").GetPointsAttr()) == [0.0, 1.0]
    assert stage.GetEndTimeCode() == 1


def test_unwritable_paths_raise_output_error(tmp_path):
    missing = tmp_path / "no_such_dir" / "cache.usdc"
    with pytest.raises(OutputError, match="no_such_dir"):
        PointCacheWriter(missing, [grid_shape()], fps=30.0)
    assert not missing.parent.exists()  # USD would create it silently; the writer must not

    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    with pytest.raises(OutputError, match="file.txt"):
        PointCacheWriter(a_file / "cache.usdc", [grid_shape()], fps=30.0)
    with pytest.raises(OutputError, match=r"\.usdc"):
        PointCacheWriter(tmp_path / "cache.abc", [grid_shape()], fps=30.0)


def test_path_open_in_process_raises_output_error(tmp_path):
    path = tmp_path / "cache.usdc"
    PointCacheWriter(path, [grid_shape()], fps=30.0).close()
    stage = Usd.Stage.Open(str(path))  # holds the layer, so USD cannot create a new one there
    with pytest.raises(OutputError, match="open in this process"):
        PointCacheWriter(path, [grid_shape()], fps=30.0)
    del stage
    PointCacheWriter(path, [grid_shape()], fps=30.0).close()  # fine once released


def test_bad_frames_raise_value_error(tmp_path):
    shapes = [grid_shape(), rope_shape()]
    good = random_frames(np.random.default_rng(6), shapes, 1)[0]
    with PointCacheWriter(tmp_path / "cache.usdc", shapes, fps=30.0, start_frame=1) as w:
        with pytest.raises(ValueError, match="before the start frame"):
            w.write_frame(0, good)
        w.write_frame(2, good)
        for frame in (2, 1):  # repeated and going back
            with pytest.raises(ValueError, match="frames must increase"):
                w.write_frame(frame, good)
        with pytest.raises(ValueError, match="one per shape"):
            w.write_frame(3, good[:1])
        with pytest.raises(ValueError, match="rope"):
            w.write_frame(3, [good[0], good[1][:-1]])
        # A rejected call authors nothing, not even for the shapes that were fine.
        assert w.frames_written == 1
        w.write_frame(3, good)
    stage = Usd.Stage.Open(str(tmp_path / "cache.usdc"))
    assert samples(UsdGeom.Mesh.Get(stage, "/World/cloth").GetPointsAttr()) == [2.0, 3.0]
    with pytest.raises(RuntimeError, match="closed"):
        w.write_frame(4, good)


def test_writer_does_not_import_warp():
    code = "import sys, warp_verlet.output.usd_writer; sys.exit('warp' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_hole_indices_are_sampled_only_when_the_hidden_set_changes(tmp_path):
    path = tmp_path / "torn.usda"
    torn = replace(grid_shape("torn"), tears=True)
    shapes = [torn, grid_shape("calm")]
    frames = random_frames(np.random.default_rng(5), shapes, 5)
    hidden_per_frame = [None, [], [2, 0], [0, 2, 2], None]  # unchanged, unchanged, change, same set, unchanged
    with PointCacheWriter(path, shapes, fps=24.0) as w:
        for f, (pts, hidden) in enumerate(zip(frames, hidden_per_frame)):
            w.write_frame(f, pts, hidden_faces=[hidden, None])
    assert validate_cache(path) == []

    stage = Usd.Stage.Open(str(path))
    holes = UsdGeom.Mesh.Get(stage, "/World/torn").GetHoleIndicesAttr()
    assert samples(holes) == [0.0, 2.0]
    assert list(holes.Get(0)) == [] and list(holes.Get(1)) == [] and list(holes.Get(4)) == [0, 2]
    assert not UsdGeom.Mesh.Get(stage, "/World/calm").GetHoleIndicesAttr().HasAuthoredValue()


def test_bad_hidden_faces_are_rejected_before_anything_is_authored(tmp_path):
    torn = replace(grid_shape("torn"), tears=True)
    shapes = [torn, grid_shape("calm")]
    pts = random_frames(np.random.default_rng(6), shapes, 1)[0]
    with PointCacheWriter(tmp_path / "c.usdc", shapes, fps=24.0) as w:
        n_faces = len(torn.faces)
        with pytest.raises(ValueError, match=r"hidden face indices must lie in \[0, 6\)"):
            w.write_frame(0, pts, hidden_faces=[[n_faces], None])
        with pytest.raises(ValueError, match="does not tear"):
            w.write_frame(0, pts, hidden_faces=[None, [1]])
        assert w.frames_written == 0
        w.write_frame(0, pts, hidden_faces=[[1], None])


def test_validate_cache_finds_hole_indices_outside_the_mesh(tmp_path):
    path = tmp_path / "cache.usdc"
    shapes = [grid_shape()]
    with PointCacheWriter(path, shapes, fps=30.0) as w:
        w.write_frame(0, random_frames(np.random.default_rng(7), shapes, 1)[0])
    stage = Usd.Stage.Open(str(path))
    UsdGeom.Mesh.Get(stage, "/World/cloth").CreateHoleIndicesAttr().Set(Vt.IntArray([0, 99]), 0)
    stage.GetRootLayer().Save()
    del stage
    assert any("holeIndices" in p for p in validate_cache(path))


# ------------------------------------------------------------------------------- faces of any size


def triangulated_grid(rows: int = ROWS, cols: int = COLS) -> Faces:
    """The grid's quads, each cut into two triangles along its (r,c)-(r+1,c+1) diagonal."""
    quads = grid_shape(rows=rows, cols=cols).faces.as_uniform()
    return Faces.uniform(np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]))


@pytest.mark.parametrize("faces, point_count, hidden", [
    (triangulated_grid(), ROWS * COLS, [1, 7]),
    (HOUSE, 7, [0]),
], ids=["triangles", "tri-quad-pentagon"])
def test_faces_of_any_size_round_trip(tmp_path, faces, point_count, hidden):
    path = tmp_path / "mesh.usda"
    uvs = np.random.default_rng(8).random((point_count, 2)).astype(np.float32)
    shape = CachedShape("mesh", faces, uvs, point_count, tears=True)
    frames = random_frames(np.random.default_rng(9), [shape], 3)
    with PointCacheWriter(path, [shape], fps=24.0) as w:
        for f, (pts, holes) in enumerate(zip(frames, [None, hidden, None])):
            w.write_frame(f, pts, hidden_faces=[holes])
    assert validate_cache(path) == []

    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh.Get(stage, "/World/mesh")
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexCountsAttr().Get()), faces.counts)
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()), faces.indices)
    np.testing.assert_array_equal(np.asarray(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Get()), uvs)
    for f, pts in enumerate(frames):
        np.testing.assert_array_equal(np.asarray(mesh.GetPointsAttr().Get(f)), pts[0])
    holes = mesh.GetHoleIndicesAttr()
    assert samples(holes) == [0.0, 1.0]
    assert list(holes.Get(0)) == [] and list(holes.Get(1)) == hidden and list(holes.Get(2)) == hidden


def test_an_f_by_k_array_is_taken_as_uniform_faces():
    triangles = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    shape = CachedShape("tris", triangles, np.zeros((4, 2), np.float32), 4)
    assert isinstance(shape.faces, Faces) and shape.faces == Faces.uniform(triangles)
    assert not shape.is_rope and len(shape.faces) == 2
    assert rope_shape().is_rope and rope_shape().faces == Faces.empty()


@pytest.mark.parametrize("faces, words", [
    (Faces([3, 2], [0, 1, 2, 2, 3]), "face 1 of 2 has 2"),
    (Faces([3, 4], [0, 1, 2, 2, 1, 3, 4]), "face 1 of 2 uses vertex 4; vertex indices must be in [0, 4)"),
    (Faces([4], [0, 1, 2]), "1 faces with 4 corners in all need 4 vertex indices, got 3"),
])
def test_bad_faces_are_refused_naming_the_shape(tmp_path, faces, words):
    shape = CachedShape("bad", faces, np.zeros((4, 2), np.float32), 4)
    with pytest.raises(ValueError) as err:
        PointCacheWriter(tmp_path / "c.usdc", [shape], fps=24.0)
    assert str(err.value).startswith("shape 'bad': ") and words in str(err.value)
    assert not (tmp_path / "c.usdc").exists()


def test_validate_cache_finds_faces_of_fewer_than_three_corners(tmp_path):
    path = tmp_path / "cache.usdc"
    shape = CachedShape("cloth", HOUSE, np.zeros((7, 2), np.float32), 7)
    with PointCacheWriter(path, [shape], fps=30.0) as w:
        w.write_frame(0, random_frames(np.random.default_rng(10), [shape], 1)[0])
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh.Get(stage, "/World/cloth")
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray([5, 4, 1, 2]))  # USD's own topology check accepts these
    stage.GetRootLayer().Save()
    del mesh, stage
    problems = validate_cache(path)
    assert any("/World/cloth" in p and "at least 3 corners" in p and "face 2 of 4 has 1" in p for p in problems)
