"""Mesh files for the mesh-cloth tests: a grid's own quads written as USD or OBJ, and mesh scenes around them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

from warp_verlet.geometry.faces import Faces, grid_faces
from warp_verlet.input.scene import ClothSpec, parse_scene
from warp_verlet.geometry.topology import grid_positions


def grid_mesh(rows: int, cols: int, size=(1.0, 1.4)) -> tuple[np.ndarray, Faces]:
    """The points (float32, exactly the grid's) and quads of the grid cloth of that shape and size."""
    return grid_positions(ClothSpec(name="g", resolution=(rows, cols), size=size)), grid_faces(rows, cols)


def triangulated(faces: Faces) -> Faces:
    """Each quad split along its 0-2 diagonal."""
    quads = faces.as_uniform()
    return Faces.uniform(np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]))


def write_usd_mesh(path: Path, points: np.ndarray, faces: Faces, *, prim: str = "/Set/Cloth",
                   translate=(0.0, 0.0, 0.0), meters_per_unit: float = 1.0, uvs: np.ndarray | None = None,
                   uv_interpolation: str = "vertex", indexed_uvs: bool = False, pinned_primvar: np.ndarray | None = None,
                   subsets: dict | None = None, material: bool = False) -> Path:
    """A USD asset holding one Mesh under an Xform parent that is moved by ``translate`` (in stage units)."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    parent = UsdGeom.Xform.Define(stage, Sdf.Path(prim).GetParentPath())
    parent.AddTranslateOp().Set(Gf.Vec3d(*translate))
    stage.SetDefaultPrim(stage.GetPrimAtPath(Sdf.Path(prim).GetPrefixes()[0]))
    mesh = UsdGeom.Mesh.Define(stage, prim)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(faces.counts))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.indices))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    primvars = UsdGeom.PrimvarsAPI(mesh)
    if uvs is not None:
        st = primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, uv_interpolation)
        if indexed_uvs:  # each distinct UV once, and an index per element
            values, index = np.unique(np.asarray(uvs, np.float32), axis=0, return_inverse=True)
            st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(values)))
            st.SetIndices(Vt.IntArray.FromNumpy(index.astype(np.int32).ravel()))
        else:
            st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(uvs, np.float32)))
    if pinned_primvar is not None:
        pv = primvars.CreatePrimvar("pinned", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex)
        pv.Set(Vt.IntArray.FromNumpy(np.asarray(pinned_primvar, np.int32)))
    for name, (element, members) in (subsets or {}).items():
        UsdGeom.Subset.CreateGeomSubset(mesh, name, element, Vt.IntArray([int(m) for m in members]))
    if material:
        looks = UsdShade.Material.Define(stage, "/Set/Looks/Velvet")
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(looks)
    stage.Save()
    return path


def write_obj(path: Path, points: np.ndarray, faces: Faces) -> Path:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(points, np.float64).tolist()]
    for f in range(len(faces)):
        corners = faces.indices[faces.offsets[f]:faces.offsets[f + 1]] + 1
        lines.append("f " + " ".join(map(str, corners)))
    path.write_text("\n".join(lines) + "\n")
    return path


def mesh_scene(tmp_path: Path, cloth: dict, simulation: dict | None = None, output: dict | None = None,
               colliders: list | None = None):
    """A one-cloth scene whose file would sit in tmp_path (mesh paths are relative to it)."""
    doc = {"simulation": simulation or {}, "output": {"path": str(tmp_path / "out.usda"), **(output or {})},
           "cloth": [{"name": "cloth", **cloth}]}
    if colliders:
        doc["collider"] = colliders
    return parse_scene(doc, str(tmp_path / "scene.toml"), tmp_path / "scene.toml")
