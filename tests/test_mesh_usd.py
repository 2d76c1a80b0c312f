"""USD in and out for mesh cloth: a prim read and written back point for point, override layers composed over
their asset, torn faces with face-corner UVs, and collider purpose."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdShade

from mesh_files import grid_mesh, mesh_scene, write_usd_mesh
from warp_verlet.geometry.faces import Faces
from warp_verlet.apps.runner import run_scene
from warp_verlet.output.usd_writer import validate_cache

ROWS, COLS = 6, 8
CENTIMETRES = 0.01  # the asset's metersPerUnit
OFFSET = (20.0, 150.0, -30.0)  # its parent Xform's translate, in centimetres


def corner_uvs(faces: Faces) -> np.ndarray:
    """One UV per face corner, repeating across faces (so an indexed primvar shares values)."""
    u = (faces.indices % COLS) / (COLS - 1)
    v = (faces.indices // COLS) / (ROWS - 1)
    return np.stack([u, v], axis=1).astype(np.float32)


@pytest.fixture
def asset(tmp_path):
    """A curtain in centimetres under a moved parent, with indexed face-corner UVs, a material and a pin subset."""
    points, faces = grid_mesh(ROWS, COLS, size=(100.0, 140.0))  # cm
    return write_usd_mesh(tmp_path / "curtain.usda", points, faces, meters_per_unit=CENTIMETRES, translate=OFFSET,
                          uvs=corner_uvs(faces), uv_interpolation="faceVarying", indexed_uvs=True, material=True,
                          subsets={"rings": ("face", range(COLS - 1))})


def curtain(asset, **keys) -> dict:
    return {"mesh": asset.name, "prim": "/Set/Cloth", "pins": [{"subset": "rings"}], "sticks": ["structural", "bend"],
            **keys}


def asset_points(asset) -> np.ndarray:
    stage = Usd.Stage.Open(str(asset))  # kept alive while its prims are read
    return np.asarray(UsdGeom.Mesh.Get(stage, "/Set/Cloth").GetPointsAttr().Get(), np.float64)


def test_prim_round_trips_through_a_cache(tmp_path, asset):
    """Same topology, the same UVs flattened per face corner, and frame 0 is the asset's points in world
    space and metres."""
    scene = mesh_scene(tmp_path, curtain(asset), {"frames": 2})
    run_scene(scene, device="cpu")
    out = tmp_path / "out.usda"
    assert validate_cache(out) == []
    cache_stage, source_stage = Usd.Stage.Open(str(out)), Usd.Stage.Open(str(asset))
    cache = UsdGeom.Mesh.Get(cache_stage, "/World/cloth")
    source = UsdGeom.Mesh.Get(source_stage, "/Set/Cloth")
    assert list(cache.GetFaceVertexCountsAttr().Get()) == list(source.GetFaceVertexCountsAttr().Get())
    assert list(cache.GetFaceVertexIndicesAttr().Get()) == list(source.GetFaceVertexIndicesAttr().Get())
    st_cache = UsdGeom.PrimvarsAPI(cache).GetPrimvar("st")
    st_source = UsdGeom.PrimvarsAPI(source).GetPrimvar("st")
    assert st_cache.GetInterpolation() == UsdGeom.Tokens.faceVarying
    np.testing.assert_array_equal(np.asarray(st_cache.ComputeFlattened()), np.asarray(st_source.ComputeFlattened()))
    expected = (asset_points(asset) + OFFSET) * CENTIMETRES
    np.testing.assert_allclose(np.asarray(cache.GetPointsAttr().Get(0)), expected, atol=2e-7)


def test_override_layer_composes_over_the_asset(tmp_path, asset):
    """Opening the override layer gives the asset with its hierarchy and material, and the cloth's points at
    every frame are the standalone cache's, brought into the prim's own space."""
    frames = 12
    standalone = tmp_path / "standalone.usda"
    run_scene(mesh_scene(tmp_path, curtain(asset), {"frames": frames, "wind": [0.0, 0.0, 5.0]}, {"path": str(standalone)}), device="cpu")
    layer = tmp_path / "override.usda"
    run_scene(mesh_scene(tmp_path, curtain(asset), {"frames": frames, "wind": [0.0, 0.0, 5.0]},
                         {"path": str(layer), "kind": "override"}),
              device="cpu")
    assert validate_cache(layer) == []

    composed = Usd.Stage.Open(str(layer))
    assert [str(p) for p in composed.GetRootLayer().subLayerPaths] == ["curtain.usda"]
    prim = composed.GetPrimAtPath("/Set/Cloth")
    assert UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0].GetPath() == "/Set/Looks/Velvet"
    assert composed.GetDefaultPrim().GetPath() == "/Set"
    assert UsdGeom.GetStageMetersPerUnit(composed) == CENTIMETRES
    # The override layer itself holds only overs: no prim of its own is defined in it.
    specs = []
    composed.GetRootLayer().Traverse("/", lambda path: specs.append(composed.GetRootLayer().GetPrimAtPath(path)))
    assert {s.specifier for s in specs if s is not None} == {__import__("pxr").Sdf.SpecifierOver}

    np.testing.assert_allclose(np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(0)), asset_points(asset), atol=2e-5)
    cache_stage = Usd.Stage.Open(str(standalone))
    cache = UsdGeom.Mesh.Get(cache_stage, "/World/cloth").GetPointsAttr()
    to_world = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(0), np.float64)
    for frame in (0, 5, frames):
        local = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(frame), np.float64)
        world = (local @ to_world[:3, :3] + to_world[3, :3]) * CENTIMETRES
        np.testing.assert_allclose(world, np.asarray(cache.Get(frame)), atol=1e-6)
    assert np.abs(np.asarray(cache.Get(frames)) - np.asarray(cache.Get(0))).max() > 0.01  # it moved


def test_torn_faces_leave_the_topology_with_their_corner_uvs(tmp_path, asset):
    """A tearing mesh with face-corner UVs: each topology sample carries one UV per kept corner."""
    scene = mesh_scene(tmp_path, curtain(asset, tear_threshold=1.05, mass=50.0),
                       {"frames": 20, "wind": [0.0, 0.0, 80.0]}, {"torn_faces": "remove"})
    summary = run_scene(scene, device="cpu")
    assert summary.torn
    out = tmp_path / "out.usda"
    assert validate_cache(out) == []
    stage = Usd.Stage.Open(str(out))
    mesh = UsdGeom.Mesh.Get(stage, "/World/cloth")
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    times = mesh.GetFaceVertexIndicesAttr().GetTimeSamples()
    assert len(times) >= 2 and st.GetAttr().GetTimeSamples() == times
    for t in times:
        assert len(st.Get(t)) == len(mesh.GetFaceVertexIndicesAttr().Get(t))
    assert len(mesh.GetFaceVertexCountsAttr().Get(times[-1])) < (ROWS - 1) * (COLS - 1)


@pytest.mark.parametrize("purpose", [None, "guide", "default"])
def test_collider_purpose(tmp_path, purpose):
    sphere = {"type": "sphere", "name": "ball", "radius": 0.2, "centre": [0.5, -1.0, 0.0]}
    plane = {"type": "plane", "name": "floor", "point": [0.0, -2.0, 0.0]}
    if purpose:
        sphere["purpose"] = plane["purpose"] = purpose
    points, faces = grid_mesh(3, 3)
    asset = write_usd_mesh(tmp_path / "a.usda", points, faces)
    run_scene(mesh_scene(tmp_path, {"mesh": asset.name, "prim": "/Set/Cloth"}, {"frames": 1},
                         colliders=[sphere, plane]), device="cpu")
    stage = Usd.Stage.Open(str(tmp_path / "out.usda"))
    for name in ("ball", "floor"):
        assert UsdGeom.Imageable(stage.GetPrimAtPath(f"/World/Colliders/{name}")).GetPurposeAttr().Get() == (purpose or "guide")
