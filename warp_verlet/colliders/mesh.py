"""Triangle-mesh colliders: a closed mesh read from any file trimesh reads or from a USD prim, still or moved by
keyframed translations, with a BVH (``wp.Mesh``) that each particle queries (kernels/collide_mesh.py).

The BVH is built once, over the mesh scaled and rotated; its translation lives in the State (as a sphere's
centre does) and each particle is queried at its position less that translation, so a moving mesh needs no
refit. Like a moving sphere, it pushes the cloth out and its friction acts on the cloth's own velocity, not the
velocity relative to the mesh.

Inside is told from outside by the normals at the closest point (``wp.mesh_query_point_sign_normal``): one
closest-point query per particle gives the push-out direction and the sign together, with no extra rays (the
parity test casts rays on top of the closest-point query it needs anyway). The sign is right only on a closed
surface whose triangles all wind the same way, so a mesh is welded (exact duplicate points become one), refused
when an edge borders one triangle only or two triangles wound the same way, and each of its closed parts is
turned outward (positive volume) when loaded. A table with legs is closed when its top and legs are each a
closed box.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..scene_keys import ARRAY, Key, accepts, any_real, scale_factors, text, vector
from .kind import FLOAT, FLOAT64, INT, VEC3, ColliderLaunches, InsideReport, LiveDrawing, coulomb, keyframe_arrays

MESH_ID = 8  # bytes of a wp.Mesh id (uint64) on the device
# What Warp allocates for one wp.Mesh of T triangles besides the points and indices it is given (warp/native
# mesh.cpp, mesh.cu, bvh.cpp, bvh.cu, Warp 1.19): each triangle's bounds (two vec3), the BVH's 2T - 1 nodes
# (two 16-byte halves, a parent and a count each), its T primitive indices, and per mesh its root and the
# Mesh and BVH descriptors (bounded above by DESCRIPTOR_BYTES).
NODE_BYTES = 2 * 16 + 2 * INT
TRIANGLE_BVH_BYTES = 2 * VEC3 + INT
DESCRIPTOR_BYTES = 1024


@dataclass(frozen=True, eq=False)
class MeshCollider:
    """A closed triangle mesh: ``points`` (V, 3) float64 m, welded, scaled and rotated into the scene's axes;
    ``triangles`` (T, 3) int32, each closed part wound counter-clockwise seen from outside; moved by
    ``keyframes`` ((time s, (x, y, z)), ...), linearly, held at the ends. ``source`` names the file (and the
    prim) in messages."""

    name: str
    source: str
    points: Any
    triangles: Any
    keyframes: tuple[tuple[float, tuple[float, float, float]], ...] = ((0.0, (0.0, 0.0, 0.0)),)
    thickness: float = 0.0
    friction_coefficient: float = 0.0  # Coulomb's mu_k
    static_friction_coefficient: float | None = None  # mu_s; None: mu_k
    purpose: str = "guide"  # USD purpose of its prim in a cache

    @property
    def moving(self) -> bool:
        return len({offset for _, offset in self.keyframes}) > 1

    def offset_at(self, time: float) -> tuple[float, float, float]:
        """Its translation at ``time`` s."""
        import numpy as np

        times = [t for t, _ in self.keyframes]
        offsets = np.asarray([o for _, o in self.keyframes], np.float64)
        return tuple(float(np.interp(time, times, offsets[:, k])) for k in range(3))

    def points_at(self, time: float):
        """(V, 3) float64: its points in the scene at ``time`` s."""
        import numpy as np

        return self.points + np.asarray(self.offset_at(time))

    @property
    def reach(self) -> float:
        """How far from its surface each particle looks for the mesh: the thickness outside, and inside as deep
        as any inside point can be. From a point inside a closed mesh, the nearer of the two bounding-box faces
        across its thinnest side is at most half that side away, and the way there leaves the mesh, so no
        inside point is further than half the thinnest side from the surface."""
        import numpy as np

        thinnest = float(np.min(self.points.max(axis=0) - self.points.min(axis=0)))
        return self.thickness + 0.5 * thinnest


@accepts(ARRAY)
def _translate(value: Any, key: str) -> tuple[tuple[float, tuple[float, float, float]], ...]:
    """[x, y, z] (a still mesh), or keyframes [[t, x, y, z], ...] as a sphere's path: ((t, (x, y, z)), ...)."""
    if isinstance(value, list) and value and all(isinstance(item, list) for item in value):
        from .sphere import read_path

        return read_path(value, key)
    return ((0.0, vector(3, any_real)(value, key)),)


FILE = Key("mesh", text, type="string",
           allowed="a file trimesh reads (`.obj`, `.ply`, `.stl`, `.off`, `.glb`, …) or a USD file (`.usd`, `.usda`, "
                   "`.usdc`, `.usdz`)",
           doc="The collider's triangle mesh, relative to the scene file's directory. It must be closed (every edge "
               "between two triangles wound the same way); its points are welded where they coincide exactly.")
PRIM = Key("prim", text, None, "string", default_text="required for USD, refused otherwise",
           allowed='an absolute prim path, e.g. `"/Set/Table"`', doc="The Mesh prim to read.")
TRANSLATE = Key("translate", _translate, ((0.0, (0.0, 0.0, 0.0)),), "[x, y, z] numbers, or array of [t, x, y, z]",
                "m; s, m", default_text="`[0.0, 0.0, 0.0]`",
                allowed="finite; keyframes: at least one, times strictly increasing",
                doc="Moves the mesh, after `rotate`: by `[x, y, z]`, or along keyframes `[[t, x, y, z], ...]`, linear "
                    "between them and held at the first before it and at the last after it, as a sphere's `path`. A "
                    "moving mesh gets a time-sampled `xformOp:translate` in the cache.")
ROTATE = Key("rotate", vector(3, any_real), (0.0, 0.0, 0.0), "[x, y, z] numbers", "degrees", allowed="finite",
             doc="Rotations about the fixed X, then Y, then Z axes, after `scale`.")
SCALE = Key("scale", scale_factors, (1.0, 1.0, 1.0), "number or [x, y, z]", default_text="`1.0`", allowed="> 0",
            doc="Scales the mesh first.")


class MeshKind:
    """Still triangle meshes: clamped after spheres and before planes, so that the ground still clamps last."""

    type = "mesh"
    spec = MeshCollider
    keys = (FILE, PRIM, TRANSLATE, ROTATE, SCALE)

    # ------------------------------------------------------------------ scene input
    def read(self, table, shared: dict[str, Any]) -> MeshCollider:
        from pathlib import Path

        from ..geometry.mesh_cloth import MeshError
        from ..geometry.mesh_io import read_mesh, transform_matrix

        relative = FILE.take(table)
        prim = PRIM.take(table)
        keyframes = TRANSLATE.take(table)
        matrix = transform_matrix((0.0, 0.0, 0.0), ROTATE.take(table), SCALE.take(table))
        table.finish()  # no unknown key: the file is read only once every key is known to be good
        path = Path(relative)
        if not path.is_absolute():
            path = (table.directory or Path()) / path
        try:
            source = read_mesh(path, prim, matrix)
            points, triangles = closed_triangles(source.description, source.points, source.faces)
        except MeshError as exc:
            raise table.error("mesh", str(exc)) from None
        return MeshCollider(source=source.description, points=points, triangles=triangles, keyframes=keyframes,
                            **shared)

    def check_numbers(self, spec: MeshCollider, file: str, key: str) -> None:
        import numpy as np

        from ..errors import SceneError
        from ..scene_keys import FLOAT32_MAX, float32_fits

        # The points were checked against float32's range when read (mesh_io.to_scene).
        limit = f"float32 holds magnitudes up to {FLOAT32_MAX:.3g}"
        for k, (_, offset) in enumerate(spec.keyframes):
            far = np.abs(spec.points).max() + np.abs(np.asarray(offset))
            for axis, v in enumerate(offset):
                if not float32_fits(v) or not float32_fits(far[axis]):
                    moving = len(spec.keyframes) > 1
                    where = f"{key}.translate[{k}][{axis + 1}]" if moving else f"{key}.translate[{axis}]"
                    raise SceneError(file, where, f"expected a number that float32 can hold ({limit}) with the mesh "
                                     f"moved by it, got {v:g}")
        if not float32_fits(spec.reach):
            raise SceneError(file, f"{key}.thickness", f"thickness + half the mesh's thinnest side = {spec.reach:g} m, "
                             f"which float32 cannot hold (float32 holds magnitudes up to {FLOAT32_MAX:.3g})")

    def start_inside(self, spec: MeshCollider, points) -> InsideReport:
        import numpy as np

        inside = np.zeros(len(points), bool)
        placed = spec.points_at(0.0)
        lo = placed.min(axis=0) - spec.thickness
        hi = placed.max(axis=0) + spec.thickness
        near = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))  # only these can be inside
        corners = placed[spec.triangles]
        chunk = max(1, 2_000_000 // max(len(corners), 1))
        for start in range(0, len(near), chunk):
            index = near[start:start + chunk]
            p = points[index]
            found = winding_numbers(corners, p) > 0.5
            if spec.thickness > 0:
                found |= distances_to_triangles(corners, p) < spec.thickness
            inside[index] = found
        side = "inside" if spec.thickness == 0 else f"inside or within thickness = {spec.thickness:.4g} m of"
        return InsideReport(inside, f"{side} mesh '{spec.name}' (at time 0)",
                            "move the cloth's origin, or the mesh's translate, so that they start apart")

    # ------------------------------------------------------------------ simulation core
    def counts(self, specs: tuple[MeshCollider, ...]) -> tuple[int, int, int, int]:
        """(meshes, their points, their triangles, their keyframes when one moves, else 0)."""
        moving = any(s.moving for s in specs)
        return (len(specs), sum(len(s.points) for s in specs), sum(len(s.triangles) for s in specs),
                sum(len(s.keyframes) for s in specs) if moving else 0)

    def device_bytes(self, counts: tuple[int, int, int, int]) -> int:
        meshes, points, triangles, keys = counts
        given = points * VEC3 + 3 * triangles * INT  # the points and indices the meshes are built from
        # ids, reach, thickness, friction, the start translation; the State's translation
        per_mesh = meshes * (MESH_ID + 4 * FLOAT + 2 * VEC3)  # friction: (mu_k, mu_s)
        bvh = triangles * TRIANGLE_BVH_BYTES + (2 * triangles - meshes) * NODE_BYTES
        bvh += meshes * (INT + DESCRIPTOR_BYTES)
        # key starts (one more than the meshes), keyframe times and translations, the State's clock
        moving = ((meshes + 1) * INT + keys * (FLOAT + VEC3) + FLOAT64) if keys else 0
        return given + per_mesh + bvh + moving

    def build(self, specs: tuple[MeshCollider, ...], device) -> dict[str, Any]:
        import numpy as np
        import warp as wp

        # One points array and one index array for all meshes; each wp.Mesh is built on its views of them.
        point_start = np.r_[0, np.cumsum([len(s.points) for s in specs])]
        index_start = 3 * np.r_[0, np.cumsum([len(s.triangles) for s in specs])]
        points = wp.array(np.concatenate([s.points for s in specs]).astype(np.float32), dtype=wp.vec3)
        indices = wp.array(np.concatenate([s.triangles.reshape(-1) for s in specs]).astype(np.int32), dtype=wp.int32)
        bvhs = tuple(wp.Mesh(points=points[point_start[k]:point_start[k + 1]],
                             indices=indices[index_start[k]:index_start[k + 1]])
                     for k in range(len(specs)))
        moving = any(s.moving for s in specs)
        out = {
            "meshes": specs,
            "meshes_move": moving,
            "mesh_bvhs": bvhs,  # kept alive: the kernel reaches them by id
            "mesh_points": points,
            "mesh_indices": indices,
            "mesh_ids": wp.array([m.id for m in bvhs], dtype=wp.uint64),
            "mesh_reach": wp.array([s.reach for s in specs], dtype=float),
            "mesh_thickness": wp.array([s.thickness for s in specs], dtype=float),
            "mesh_friction": wp.array([coulomb(s) for s in specs], dtype=wp.vec2),
            "mesh_start": wp.array([s.keyframes[0][1] for s in specs], dtype=wp.vec3),
        }
        if moving:
            out["mesh_key_start"], out["mesh_key_times"], out["mesh_key_offsets"] = keyframe_arrays(specs)
        return out

    def state_arrays(self, colliders) -> dict[str, Any]:
        import warp as wp

        meshes = getattr(colliders, "meshes", ())
        moving = getattr(colliders, "meshes_move", False)
        return {"mesh_clock": wp.zeros(1, dtype=wp.float64) if moving else None,
                "mesh_offsets": wp.clone(colliders.mesh_start) if meshes else None}

    def bind(self, model, state) -> ColliderLaunches:
        import warp as wp

        from ..kernels.collide_mesh import collide_meshes, place_meshes
        from ..kernels.collide_sphere import advance_clock
        from ..launches import recorded

        c = model.colliders
        before = ()
        if c.meshes_move:
            clock = state.mesh_clock
            place = recorded(place_meshes, len(c.meshes), [clock, c.mesh_key_start, c.mesh_key_times,
                                                           c.mesh_key_offsets], [state.mesh_offsets])

            def advance(dt: float) -> None:
                wp.launch(advance_clock, 1, inputs=[clock, wp.float64(dt)])
                place.run()

            before = (advance,)
        clamp = recorded(collide_meshes, model.particle_count,
                         [state.particle_q, state.particle_q_inertial, state.particle_dq, model.inv_mass,
                          c.mesh_ids, state.mesh_offsets, c.mesh_reach, c.mesh_thickness, c.mesh_friction])
        return ColliderLaunches(before, (clamp,))

    # ------------------------------------------------------------------ output
    def samples(self, colliders, state, always_moving: bool = False):
        """Translations of the moving meshes, in scene order (a live session drags no mesh: the same then)."""
        import numpy as np

        if not colliders.meshes_move:
            return np.zeros((0, 3), np.float32)
        return state.mesh_offsets.numpy()[[s.moving for s in colliders.meshes]]

    def cached(self, spec: MeshCollider, always_moving: bool = False) -> "CachedMesh":
        return CachedMesh(spec.name, spec.points, spec.triangles, spec.keyframes[0][1], spec.moving, spec.purpose)

    def owns_prim(self, prim, under_colliders: bool) -> bool:
        """A Mesh under /World/Colliders other than a plane's single quad."""
        from pxr import UsdGeom

        if not (under_colliders and prim.IsA(UsdGeom.Mesh)):
            return False
        counts = UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get()
        return counts is not None and list(counts) != [4]

    def read_prim(self, prim, reader) -> dict[str, Any]:
        """The triangles as written, as the drawing primitive ``meshes``: (points (V, 3), triangles (T, 3))."""
        import numpy as np
        from pxr import UsdGeom

        mesh, time = UsdGeom.Mesh(prim), reader.time
        points = reader.attribute(mesh, "points", lambda: mesh.GetPointsAttr().Get(time))
        indices = reader.attribute(mesh, "faceVertexIndices", lambda: mesh.GetFaceVertexIndicesAttr().Get(time))
        if points is None or indices is None or len(indices) < 3 or len(indices) % 3:
            return {}
        triangles = np.asarray(indices, np.int64).reshape(-1, 3)
        if triangles.min() < 0 or triangles.max() >= len(points):
            return {}
        world = reader.to_world(mesh, reader.finite(mesh, points))
        return {"meshes": (world, triangles)}

    def add_to_live(self, app, specs: tuple[MeshCollider, ...]) -> LiveDrawing:
        """The meshes as the cache draws them, at their translations; the per-frame update follows the moving
        ones (None when none moves)."""
        import numpy as np

        state = app.session.sim.state
        offsets = state.mesh_offsets.numpy()
        drawn = [draw_mesh(app.server, m.name, m.points, m.triangles, offsets[i]) for i, m in enumerate(specs)]
        frame = [p + offsets[i] for i, m in enumerate(specs) for p in (m.points.min(axis=0), m.points.max(axis=0))]
        if not any(m.moving for m in specs):
            return LiveDrawing(drawn, frame)

        def update() -> None:
            for handle, offset in zip(drawn, app.session.sim.state.mesh_offsets.numpy()):
                if not np.allclose(handle.position, offset):
                    handle.position = tuple(float(v) for v in offset)

        return LiveDrawing(drawn, frame, update)


@dataclass(frozen=True, eq=False)
class CachedMesh:
    """A mesh collider in the cache: its triangles, written once, and its translation (sampled per frame when
    it moves)."""

    name: str
    points: Any
    triangles: Any
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    moving: bool = False
    purpose: str = "guide"

    def cache_bytes(self, float_bytes: int, int_bytes: int) -> int:
        """At most what its prim takes in a cache whose numbers take these bytes (output_file.estimate_cache):
        its points, a count and three indices per triangle, and the prim itself."""
        return 512 + 3 * float_bytes * len(self.points) + 4 * int_bytes * len(self.triangles)

    def define(self, stage, path):
        """A Mesh prim of triangles, wound counter-clockwise seen from outside, with a translate: sampled per
        frame when it moves (the op returned), else set once."""
        import numpy as np
        from pxr import UsdGeom, Vt

        mesh = UsdGeom.Mesh.Define(stage, path)
        points = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(self.points, np.float32))
        mesh.CreatePointsAttr(points)
        mesh.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(points))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(self.triangles), 3, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(self.triangles, np.int32).ravel()))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        mesh.CreatePurposeAttr(self.purpose)
        op = mesh.AddTranslateOp()
        if self.moving:
            return op  # sampled per frame in write_frame
        op.Set(tuple(float(v) for v in self.offset))
        return None


MESH = MeshKind()


LIVE_COLOUR = (178, 184, 194)  # sRGB, on the live and view pages, as a sphere's


def draw_mesh(server, name: str, points, triangles, position=(0.0, 0.0, 0.0)):
    """A mesh collider on a viser page (live and view): its triangles, moved to ``position``."""
    import numpy as np

    return server.scene.add_mesh_simple(f"/colliders/{name}", np.asarray(points, np.float32),
                                        np.asarray(triangles, np.uint32), color=LIVE_COLOUR, side="double",
                                        position=tuple(float(v) for v in position))


# --------------------------------------------------------------------------------------------- geometry


def closed_triangles(description: str, points, faces):
    """The mesh's triangles (polygons fanned from their first corner), its points welded where they coincide
    exactly and only the points a triangle uses kept, each closed part turned outward; a MeshError when it is
    empty or not closed. Returns (points (V, 3) float64, triangles (T, 3) int32)."""
    import numpy as np

    from ..geometry.mesh_cloth import MeshError

    try:
        faces.validate(len(points), description)
    except ValueError as exc:
        raise MeshError(str(exc)) from None
    counts = faces.counts.astype(np.int64)
    per_face = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), per_face)
    start = np.r_[0, np.cumsum(counts)[:-1]][face]
    j = np.arange(len(face)) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    corners = faces.indices.astype(np.int64)
    triangles = np.stack([corners[start], corners[start + j + 1], corners[start + j + 2]], axis=1)
    if not len(triangles):
        raise MeshError(f"{description}: an empty mesh: no triangle to collide with")
    unique, welded = np.unique(np.asarray(points, np.float64), axis=0, return_inverse=True)
    triangles = welded.reshape(-1)[triangles]
    triangles = triangles[(triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2])
                          & (triangles[:, 2] != triangles[:, 0])]  # collapsed by the weld
    if not len(triangles):
        raise MeshError(f"{description}: an empty mesh: every triangle has two corners at one point")
    used, triangles = np.unique(triangles, return_inverse=True)
    points, triangles = unique[used], triangles.reshape(-1, 3)
    _check_closed(description, points, triangles)
    return points, _outward(points, triangles).astype(np.int32)


def _check_closed(description: str, points, triangles) -> None:
    """Every directed edge once, and its reverse once: each edge between exactly two triangles wound alike."""
    import numpy as np

    from ..geometry.mesh_cloth import MeshError

    n = len(points)
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    keys = directed[:, 0] * n + directed[:, 1]
    found, count = np.unique(keys, return_counts=True)
    reverse = directed[:, 1] * n + directed[:, 0]
    open_edges = ~np.isin(reverse, found)
    how = ("the collider tells inside from outside by the surface's normals, which needs a closed surface (a table "
           "top and each leg a closed box, say)")

    def at(edge) -> str:
        a, b = points[edge[0]], points[edge[1]]
        return "(" + ", ".join(f"{v:g}" for v in a) + ") - (" + ", ".join(f"{v:g}" for v in b) + ")"

    if (count > 1).any():
        twice = int(np.flatnonzero(keys == found[np.argmax(count > 1)])[0])
        raise MeshError(f"{description}: not a closed surface wound one way: the edge {at(directed[twice])} m is "
                        f"used in the same direction by {int(count.max())} triangles (faces wound against their "
                        f"neighbours, or more than two faces on one edge); {how}")
    if open_edges.any():
        first = int(np.flatnonzero(open_edges)[0])
        raise MeshError(f"{description}: an open mesh: {int(open_edges.sum())} edges border one triangle only, e.g. "
                        f"{at(directed[first])} m; {how}")


def _outward(points, triangles):
    """``triangles`` with every connected part that encloses a negative volume reversed."""
    import numpy as np

    label = np.arange(len(points))
    while True:  # connected parts by propagating the smallest point index over the triangles
        lowest = label[triangles].min(axis=1)
        new = label.copy()
        np.minimum.at(new, triangles.reshape(-1), np.repeat(lowest, 3))
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    part = label[triangles[:, 0]]
    a, b, c = (points[triangles[:, k]] for k in range(3))
    volume = np.einsum("ij,ij->i", a, np.cross(b, c))  # six times each tetrahedron's signed volume
    parts, where = np.unique(part, return_inverse=True)
    inward = (np.bincount(where, weights=volume) < 0)[where]
    out = triangles.copy()
    out[inward] = out[inward][:, ::-1]
    return out


def winding_numbers(corners, points):
    """The generalized winding number of each point (M, 3) about the triangles (T, 3, 3): 1 inside a closed
    outward surface, 0 outside (Van Oosterom and Strackee's solid angle, summed)."""
    import numpy as np

    r = corners[None, :, :, :] - points[:, None, None, :]  # (M, T, 3, 3)
    length = np.linalg.norm(r, axis=-1)
    a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
    la, lb, lc = length[:, :, 0], length[:, :, 1], length[:, :, 2]
    numerator = np.einsum("mtk,mtk->mt", a, np.cross(b, c))
    denominator = (la * lb * lc + np.einsum("mtk,mtk->mt", a, b) * lc + np.einsum("mtk,mtk->mt", b, c) * la
                   + np.einsum("mtk,mtk->mt", c, a) * lb)
    return (2 * np.arctan2(numerator, denominator)).sum(axis=1) / (4 * np.pi)


def distances_to_triangles(corners, points):
    """The distance of each point (M, 3) to the nearest of the triangles (T, 3, 3) (Ericson, Real-Time
    Collision Detection, 5.1.5: the closest point by the Voronoi region of the triangle it lies in)."""
    import numpy as np

    p = points[:, None, :]
    a, b, c = corners[None, :, 0], corners[None, :, 1], corners[None, :, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.sum(ab * ap, -1), np.sum(ac * ap, -1)
    bp = p - b
    d3, d4 = np.sum(ab * bp, -1), np.sum(ac * bp, -1)
    cp = p - c
    d5, d6 = np.sum(ab * cp, -1), np.sum(ac * cp, -1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in, w_in = vb / denom, vc / denom
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    closest = a + ab * v_in[..., None] + ac * w_in[..., None]  # inside the face
    regions = [  # later conditions win, so the vertex regions come last
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc[..., None]),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[..., None]),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[..., None]),
        ((d6 >= 0) & (d5 <= d6), np.broadcast_to(c, closest.shape)),
        ((d3 >= 0) & (d4 <= d3), np.broadcast_to(b, closest.shape)),
        ((d1 <= 0) & (d2 <= 0), np.broadcast_to(a, closest.shape)),
    ]
    for where, point in regions:
        closest = np.where(where[..., None], point, closest)
    return np.linalg.norm(p - closest, axis=-1).min(axis=1)
