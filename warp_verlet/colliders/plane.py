"""Plane colliders: infinite planes, drawn in the cache as a square (kernels/collide_plane.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..scene_keys import Key, any_real, real, vector
from .kind import (FLOAT, VEC3, ColliderLaunches, InsideReport, LiveDrawing, clamp_launches, coulomb,
                   push_record)


@dataclass(frozen=True)
class PlaneCollider:
    """An infinite plane through ``point`` whose ``normal`` (unit length) points to the free side."""

    name: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    thickness: float = 0.0
    friction_coefficient: float = 0.0  # Coulomb's mu_k
    static_friction_coefficient: float | None = None  # mu_s; None: mu_k
    display_size: float = 10.0
    purpose: str = "guide"  # USD purpose of its prim in a cache


def unit_vector(v: tuple[float, ...]) -> tuple[float, ...] | None:
    """``v`` / |v|, or None for the zero vector. Scaled by its largest component first, so that neither a
    huge vector ([1e300, 1e300, 0]: the sum of squares is inf) nor a tiny one (squares underflow to 0) loses
    its direction."""
    scale = max(abs(x) for x in v)
    if scale == 0.0:
        return None
    scaled = [x / scale for x in v]
    length = math.hypot(*scaled)  # in [1, sqrt(3)]
    return tuple(x / length for x in scaled)


POINT = Key("point", vector(3, any_real), (0.0, 0.0, 0.0), type="[x, y, z] numbers", unit="m", allowed="finite",
            doc="A point on the plane.")
NORMAL = Key("normal", vector(3, any_real), (0.0, 1.0, 0.0), type="[x, y, z] numbers", allowed="finite, non-zero",
             doc="Points to the free side; normalised on loading (scaled first, so `[1e300, 1e300, 0]` keeps its "
                 "direction).")
DISPLAY_SIZE = Key("display_size", real(0.0, lo_open=True), 10.0, type="number", unit="m", allowed="> 0",
                   doc="Side of the square written to the cache to show the plane (the collision plane itself is "
                       "infinite).")


class PlaneKind:
    """Infinite planes: clamped last, so that nothing clamped before them pushes cloth through."""

    type = "plane"
    spec = PlaneCollider
    keys = (POINT, NORMAL, DISPLAY_SIZE)

    # ------------------------------------------------------------------ scene input
    def read(self, table, shared: dict[str, Any]) -> PlaneCollider:
        normal = unit_vector(NORMAL.take(table))
        if normal is None:
            raise table.error("normal", "expected a non-zero vector")
        return PlaneCollider(point=POINT.take(table), normal=normal, display_size=DISPLAY_SIZE.take(table),
                             **shared)

    def check_numbers(self, spec: PlaneCollider, file: str, key: str) -> None:
        from ..errors import SceneError
        from ..scene_keys import FLOAT32_MAX, float32_fits

        limit = f"float32 holds magnitudes up to {FLOAT32_MAX:.3g}"
        for name, values in (("point", spec.point), ("display_size", (spec.display_size,))):
            for k, v in enumerate(values):
                if not float32_fits(v):
                    where = f"{key}.{name}" if len(values) == 1 else f"{key}.{name}[{k}]"
                    raise SceneError(file, where, f"expected a number that float32 can hold ({limit}), got {v:g}")
        far = max(abs(v) for v in spec.point)
        if not float32_fits(far + spec.display_size):
            where = (f"{key}.point[{[abs(v) for v in spec.point].index(far)}]" if far >= spec.display_size
                     else f"{key}.display_size")
            raise SceneError(file, where, f"the drawn square reaches beyond what float32 can hold ({limit})")

    def start_inside(self, spec: PlaneCollider, points) -> InsideReport:
        import numpy as np

        height = (points - np.asarray(spec.point)) @ np.asarray(spec.normal)
        inside = height < spec.thickness
        side = "behind" if spec.thickness == 0 else f"behind or within thickness = {spec.thickness:.4g} m of"
        return InsideReport(inside, f"{side} plane '{spec.name}'",
                            "move the cloth's origin to the plane's free side (the way its normal points), or move "
                            "the plane")

    # ------------------------------------------------------------------ simulation core
    def counts(self, specs: tuple[PlaneCollider, ...]) -> tuple[int]:
        return (len(specs),)

    def device_bytes(self, counts: tuple[int]) -> int:
        (planes,) = counts
        return planes * (2 * VEC3 + 3 * FLOAT)  # points, normals, thickness, friction (mu_k, mu_s)

    def build(self, specs: tuple[PlaneCollider, ...], device) -> dict[str, Any]:
        import warp as wp

        return {
            "planes": specs,
            "plane_points": wp.array([p.point for p in specs], dtype=wp.vec3),
            "plane_normals": wp.array([p.normal for p in specs], dtype=wp.vec3),
            "plane_thickness": wp.array([p.thickness for p in specs], dtype=float),
            "plane_friction": wp.array([coulomb(p) for p in specs], dtype=wp.vec2),
        }

    def state_arrays(self, colliders) -> dict[str, Any]:
        return {}  # a plane never moves

    def bind(self, model, state, pushes=None) -> ColliderLaunches:
        from ..kernels.collide_plane import collide_planes
        from ..launches import recorded

        c = model.colliders
        removed = push_record(pushes, model.device)

        def clamp(first: int, count: int):
            return recorded(collide_planes, count,
                            [state.particle_q, state.particle_q_inertial, state.particle_dq, model.inv_mass,
                             c.plane_points, c.plane_normals, c.plane_thickness, c.plane_friction, removed, first])

        return clamp_launches(clamp, model.particle_count)

    # ------------------------------------------------------------------ output
    def samples(self, colliders, state, always_moving: bool = False):
        import numpy as np

        return np.zeros((0, 3), np.float32)

    def cached(self, spec: PlaneCollider, always_moving: bool = False) -> "CachedPlane":
        return CachedPlane(spec.name, spec.point, spec.normal, spec.display_size, spec.purpose)

    def owns_prim(self, prim, under_colliders: bool) -> bool:
        from pxr import UsdGeom

        return under_colliders and prim.IsA(UsdGeom.Mesh)  # the writer draws a plane as a one-quad mesh

    def read_prim(self, prim, reader) -> dict[str, Any]:
        """The quad's corners as authored, as the drawing primitive ``planes`` (drawing clips them to the
        content); nothing for a quad that cannot be drawn."""
        import numpy as np
        from pxr import UsdGeom

        plane, time = UsdGeom.Mesh(prim), reader.time
        points = reader.attribute(plane, "points", lambda: plane.GetPointsAttr().Get(time))
        if points is not None and len(points) >= 3:
            corners = np.asarray(points, dtype=np.float64)
            if np.isfinite(corners).all():  # older caches of an overflowing normal hold NaN corners
                return {"planes": reader.to_world(plane, corners)}
        return {}

    def add_to_live(self, app, specs: tuple[PlaneCollider, ...]) -> LiveDrawing:
        """The quads the cache draws; they never move, and the camera frames the cloth, not the ground."""
        return LiveDrawing([draw_plane(app.server, plane.name, plane_corners(self.cached(plane))) for plane in specs])


@dataclass(frozen=True)
class CachedPlane:
    """A plane collider in the cache, drawn as a square of side ``size`` centred on ``point``."""

    name: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    size: float
    purpose: str = "guide"

    @property
    def moving(self) -> bool:
        return False

    def define(self, stage, path):
        """A one-quad Mesh, seen from both sides; nothing to sample per frame."""
        from pxr import UsdGeom, Vt

        plane = UsdGeom.Mesh.Define(stage, path)
        corners = plane_corners(self)
        plane.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(corners))
        plane.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(Vt.Vec3fArray.FromNumpy(corners)))
        plane.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
        plane.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
        plane.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        plane.CreateDoubleSidedAttr(True)
        plane.CreatePurposeAttr(self.purpose)
        return None


def plane_corners(plane: CachedPlane):
    """The square's corners, counter-clockwise seen from the normal's side."""
    import numpy as np

    n = np.asarray(plane.normal, dtype=np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    h = plane.size / 2
    p = np.asarray(plane.point, dtype=np.float64)
    return np.array([p - h * u - h * v, p + h * u - h * v, p + h * u + h * v, p - h * u + h * v], np.float32)


PLANE = PlaneKind()


LIVE_COLOUR = (115, 115, 115)  # sRGB, on the live and view pages


def draw_plane(server, name: str, corners):
    """A plane collider on a viser page (live and view), as the writer draws it: one quad (4 corners), seen
    from both sides, half transparent."""
    import numpy as np

    corners = np.asarray(corners, dtype=np.float32)
    return server.scene.add_mesh_simple(f"/colliders/{name}", corners, np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                                        color=LIVE_COLOUR, opacity=0.35, side="double")
