"""Writes the mesh assets the shipped scenes read: ``python scenes/assets/make_assets.py`` (deterministic).

- ``tablecloth.obj``: a round tablecloth of radius 0.75 m with a 4 cm hem turned down at its rim, triangles
  cut in concentric rings (ring k has 6k vertices, so the triangles are nearly equilateral) and UVs from a
  planar projection. tablecloth.toml drops it on a round table.
- ``curtain.usda``: a small set in centimetres, Z up, holding a pleated curtain as quads, with face-corner
  UVs, a material bound to it, a ``rings`` primvar marking the vertices hung on curtain rings, and a
  ``hem`` GeomSubset of the bottom row of faces, and the window's frame behind it (+Y): one closed Mesh, a
  rectangular ring of quads 8 cm deep around the opening, its head behind the rail, its sill behind the hem and
  its jambs behind the curtain's sides. curtain_override.toml writes a layer over the curtain; curtain_frame.toml
  also keeps the curtain out of the frame, a mesh collider read from the same file.
- ``table.obj``: a table with legs for a mesh collider, Y up: a top 1.2 m x 0.8 m, 4 cm thick, its upper face
  0.75 m up, on four legs 5 cm square standing on the ground (y = 0) and reaching the top's underside. The top
  and each leg are a closed box (8 points, 12 triangles, counter-clockwise seen from outside), so the whole
  is closed. cloth_on_table.toml drops a cloth on it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def disc_with_hem(radius: float = 0.75, rings: int = 18, hem: float = 0.04) -> tuple[np.ndarray, list[list[int]]]:
    """Points (x, 0, z) of a disc in concentric rings plus one ring turned down by ``hem``, and its triangles,
    counter-clockwise seen from above (+Y)."""
    points = [(0.0, 0.0, 0.0)]
    ring_start = [0]
    for k in range(1, rings + 1):
        ring_start.append(len(points))
        angles = 2 * np.pi * np.arange(6 * k) / (6 * k)
        r = radius * k / rings
        points += [(r * np.cos(a), 0.0, -r * np.sin(a)) for a in angles]  # -sin: counter-clockwise from +Y
    faces = []
    for k in range(1, rings + 1):
        inner = list(range(ring_start[k - 1], ring_start[k - 1] + max(6 * (k - 1), 1)))
        outer = list(range(ring_start[k], ring_start[k] + 6 * k))
        faces += _stitch(inner, outer)
    # The hem: a copy of the rim ring, lowered, joined to the rim by a band of triangles.
    rim = list(range(ring_start[rings], ring_start[rings] + 6 * rings))
    hem_start = len(points)
    points += [(x, -hem, z) for x, _, z in (points[i] for i in rim)]
    lowered = [hem_start + i for i in range(len(rim))]
    for i in range(len(rim)):
        j = (i + 1) % len(rim)
        faces += [[rim[i], lowered[i], lowered[j]], [rim[i], lowered[j], rim[j]]]
    return np.asarray(points), faces


def _stitch(inner: list[int], outer: list[int]) -> list[list[int]]:
    """Triangles between two closed rings, walking both by angle (the next vertex of the ring that is behind)."""
    faces = []
    i = o = 0
    n_in, n_out = len(inner), len(outer)
    if n_in == 1:  # the centre: a fan
        return [[inner[0], outer[m], outer[(m + 1) % n_out]] for m in range(n_out)]
    while i < n_in or o < n_out:
        if o < n_out and (i >= n_in or (o + 1) / n_out <= (i + 1) / n_in):
            faces.append([inner[i % n_in], outer[o], outer[(o + 1) % n_out]])
            o += 1
        else:
            faces.append([inner[i % n_in], outer[o % n_out], inner[(i + 1) % n_in]])
            i += 1
    return faces


def write_tablecloth(path: Path) -> None:
    points, faces = disc_with_hem()
    radius = np.abs(points[:, [0, 2]]).max()
    uv = 0.5 + 0.5 * points[:, [0, 2]] / radius * np.array([1.0, -1.0])
    lines = ["# tablecloth.obj: written by scenes/assets/make_assets.py (radius 0.75 m, 4 cm hem)"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in points]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}" for i in face) for face in faces]
    path.write_text("\n".join(lines) + "\n")


def write_curtain(path: Path, rows: int = 25, cols: int = 33) -> None:
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    width, height, pleat = 160.0, 120.0, 3.0  # cm
    x = np.linspace(0.0, width, cols)
    z = np.linspace(0.0, -height, rows)  # Z up: the curtain hangs down -Z from its rail
    xx, zz = np.meshgrid(x, z)
    yy = pleat * np.sin(2 * np.pi * xx / 20.0)  # pleats every 20 cm
    points = np.stack([xx, yy, zz], axis=-1).reshape(-1, 3).astype(np.float32)
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (r * cols + c).ravel()
    quads = np.stack([a, a + 1, a + cols + 1, a + cols], axis=1)  # counter-clockwise seen from -Y
    corner_uv = np.stack([(quads % cols) / (cols - 1), 1.0 - (quads // cols) / (rows - 1)], axis=-1).reshape(-1, 2)

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetMetadata("comment", "Written by scenes/assets/make_assets.py: a pleated curtain on a rail, in cm, Z up")
    root = UsdGeom.Xform.Define(stage, "/Set")
    stage.SetDefaultPrim(root.GetPrim())
    window = UsdGeom.Xform.Define(stage, "/Set/Window")
    window.AddTranslateOp().Set(Gf.Vec3d(-80.0, 0.0, 230.0))  # the rail, 2.3 m up
    mesh = UsdGeom.Mesh.Define(stage, "/Set/Window/Curtain")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(Vt.Vec3fArray.FromNumpy(points)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4] * len(quads)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.ravel().astype(np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDoubleSidedAttr(True)
    primvars = UsdGeom.PrimvarsAPI(mesh)
    st = primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray.FromNumpy(corner_uv.astype(np.float32)))
    rings = np.zeros(rows * cols, np.int32)
    rings[0:cols:4] = 1  # a ring every 4th vertex of the top row, 20 cm apart
    primvars.CreatePrimvar("rings", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex).Set(Vt.IntArray.FromNumpy(rings))
    UsdGeom.Subset.CreateGeomSubset(mesh, "hem", UsdGeom.Tokens.face,
                                    Vt.IntArray(list(range((rows - 2) * (cols - 1), (rows - 1) * (cols - 1)))))
    material = UsdShade.Material.Define(stage, "/Set/Looks/Linen")
    shader = UsdShade.Shader.Define(stage, "/Set/Looks/Linen/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.85, 0.8, 0.7))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    floor = UsdGeom.Mesh.Define(stage, "/Set/Floor")
    corners = [(-150.0, -150.0, 0.0), (150.0, -150.0, 0.0), (150.0, 150.0, 0.0), (-150.0, 150.0, 0.0)]
    floor.CreatePointsAttr(corners)
    floor.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(Vt.Vec3fArray(corners)))
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    floor.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    frame_points, frame_quads = window_frame()
    frame = UsdGeom.Mesh.Define(stage, "/Set/Window/Frame")  # after the others, so that they are written as before
    frame.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(frame_points.astype(np.float32)))
    frame.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(Vt.Vec3fArray.FromNumpy(frame_points.astype(np.float32))))
    frame.CreateFaceVertexCountsAttr(Vt.IntArray([4] * len(frame_quads)))
    frame.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for quad in frame_quads for i in quad]))
    frame.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    stage.GetRootLayer().Save()


def window_frame(outer=((-10.0, -130.0), (170.0, 10.0)), inner=((12.0, -112.0), (148.0, -8.0)),
                 front: float = 6.0, back: float = 14.0) -> tuple[np.ndarray, list[list[int]]]:
    """A closed rectangular ring in the window's frame (cm, Z up, the curtain's rail at z = 0 running along X
    from 0 to 160, its pleats within 3 cm of y = 0): the rectangle ``outer`` less ``inner`` ((x, z) low and high
    corners) between y = ``front`` and y = ``back``. Its 16 points (outer front, outer back, inner front, inner
    back, 4 each) and 16 quads, counter-clockwise seen from outside."""
    rings = [[(x0, z0), (x1, z0), (x1, z1), (x0, z1)] for (x0, z0), (x1, z1) in (outer, inner)]
    points = [(x, y, z) for ring in rings for y in (front, back) for x, z in ring]
    outer_front, outer_back, inner_front, inner_back = (list(range(4 * k, 4 * k + 4)) for k in range(4))
    quads = []
    for k in range(4):
        j = (k + 1) % 4
        quads += [[outer_front[k], outer_front[j], inner_front[j], inner_front[k]],  # the face towards the curtain
                  [outer_back[k], inner_back[k], inner_back[j], outer_back[j]],      # the face away from it
                  [outer_front[k], outer_back[k], outer_back[j], outer_front[j]],    # the outside walls
                  [inner_front[k], inner_front[j], inner_back[j], inner_back[k]]]    # the opening's walls
    return np.asarray(points), quads


def box(lo, hi) -> tuple[np.ndarray, list[list[int]]]:
    """The corners of the box [lo, hi] (index bit 0: x, bit 1: y, bit 2: z at its high end) and its 12
    triangles, counter-clockwise seen from outside."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    points = np.array([[(hi if k >> axis & 1 else lo)[axis] for axis in range(3)] for k in range(8)])
    quads = [[0, 4, 6, 2], [1, 3, 7, 5],  # -x, +x
             [0, 1, 5, 4], [2, 6, 7, 3],  # -y, +y
             [0, 2, 3, 1], [4, 5, 7, 6]]  # -z, +z
    return points, [t for a, b, c, d in quads for t in ([a, b, c], [a, c, d])]


def write_table(path: Path, width: float = 1.2, depth: float = 0.8, height: float = 0.75, top: float = 0.04,
                leg: float = 0.05, inset: float = 0.06) -> None:
    boxes = [box((-width / 2, height - top, -depth / 2), (width / 2, height, depth / 2))]
    for sx in (-1, 1):
        for sz in (-1, 1):
            x, z = sx * (width / 2 - inset), sz * (depth / 2 - inset)
            boxes.append(box((x - leg / 2, 0.0, z - leg / 2), (x + leg / 2, height - top, z + leg / 2)))
    lines = [f"# table.obj: written by scenes/assets/make_assets.py (top {width} m x {depth} m, {height} m up, "
             "on four legs; each part a closed box)"]
    for points, _ in boxes:
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in points]
    for k, (_, faces) in enumerate(boxes):
        lines += ["f " + " ".join(str(8 * k + i + 1) for i in face) for face in faces]
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    write_tablecloth(HERE / "tablecloth.obj")
    write_curtain(HERE / "curtain.usda")
    write_table(HERE / "table.obj")
    print(f"wrote {HERE / 'tablecloth.obj'}, {HERE / 'curtain.usda'} and {HERE / 'table.obj'}")
