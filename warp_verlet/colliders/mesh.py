"""Triangle-mesh colliders: a closed mesh read from any file trimesh reads or from a USD prim, still or moving,
with a BVH (``wp.Mesh``) that each particle queries (kernels/collide_mesh.py).

A mesh moves by keyframed ``translate`` and ``rotate`` in the scene, and by its USD prim's own animation: a
time-sampled local-to-world transform (the prim's or an ancestor's xform ops) moves it rigidly, time-sampled
``points`` deform it. Rigid motion is a pose per keyframe (a rotation and a translation, relative to the mesh at
time 0), dense enough that the device's linear and spherical-linear interpolation between them follows the
scene's keyframes (Euler angles linear in time, as ``translate``) and USD's own interpolation of the asset within
``POSE_TOLERANCE``. The BVH is built once, over the mesh at time 0 without its translation; each particle is moved
into the mesh's frame by the State's pose, so a rigidly moving mesh needs no refit. A deforming mesh's points are
placed each substep from its samples (linear between them, as USD interpolates points) and its BVH refitted.
Friction acts on the cloth's motion relative to the surface point it touches (that point's move over the
substep, from the poses or, for a deforming mesh, from its points' moves), so a moving mesh carries cloth along.
In the cache, a mesh from a USD prim is a reference to that prim (ReferencedMesh), any other a copy of its
triangles (CachedMesh).

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
from .kind import (FLOAT, FLOAT64, INT, VEC3, ColliderLaunches, InsideReport, LiveDrawing, clamp_launches, coulomb,
                   push_record)

MESH_ID = 8  # bytes of a wp.Mesh id (uint64) on the device
QUAT = 16  # bytes of a wp.quat
POSE_TOLERANCE = 1.0e-5
"""m: how far the device's interpolation between two poses (or two deforming samples) may stray from the motion
it stands for, at the mesh's bounding-box corners (or points); keyframes are halved until it holds."""
MAX_HALVINGS = 12
"""Times an interval between two given keyframes is halved at most (4096 poses)."""
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
    # Rigid motion beyond ``keyframes`` (a keyframed rotate, a time-sampled USD transform): poses ((time s,
    # (qx, qy, qz, qw), (x, y, z) m), ...), each placing ``points`` (rotated about the origin, then translated);
    # empty: ``keyframes`` alone, unrotated.
    poses: tuple = ()
    # A mesh read from a USD prim: (the file, absolute; the prim's path), which its cache prim references, and
    # the scene's rotate keyframes and scale, which the cache applies over it (with ``keyframes``).
    usd_prim: tuple | None = None
    rotate_keys: tuple = ((0.0, (0.0, 0.0, 0.0)),)
    scale: tuple = (1.0, 1.0, 1.0)
    # A deforming mesh (time-sampled USD points): ((time s, (V, 3) float64 points in the frame of ``points``),
    # ...), linear between them and held at the ends; empty: rigid.
    point_samples: tuple = ()

    @property
    def moving(self) -> bool:
        return bool(self.poses) or bool(self.point_samples) or len({offset for _, offset in self.keyframes}) > 1

    @property
    def rigid_poses(self) -> tuple:
        """Its poses ((time, quaternion (x, y, z, w), translation), ...): ``poses``, or ``keyframes`` unrotated."""
        return self.poses or tuple((t, (0.0, 0.0, 0.0, 1.0), offset) for t, offset in self.keyframes)

    def pose_at(self, time: float):
        """(3, 3) rotation and (3,) translation (float64) placing ``points`` at ``time`` s."""
        import numpy as np

        poses = self.rigid_poses
        times = [t for t, _, _ in poses]
        k = int(np.clip(np.searchsorted(times, time, side="right") - 1, 0, len(poses) - 1))
        if time <= times[0] or k == len(poses) - 1:
            _, q, offset = poses[0] if time <= times[0] else poses[-1]
            return quat_matrix(q), np.asarray(offset, np.float64)
        (t0, q0, o0), (t1, q1, o1) = poses[k], poses[k + 1]
        f = (time - t0) / (t1 - t0)
        return (quat_matrix(slerp(q0, q1, f)),
                (1 - f) * np.asarray(o0, np.float64) + f * np.asarray(o1, np.float64))

    def local_points_at(self, time: float):
        """(V, 3) float64: the mesh in its own frame at ``time`` s (``points``, or a deforming mesh's)."""
        import numpy as np

        if not self.point_samples:
            return self.points
        times = [t for t, _ in self.point_samples]
        if time <= times[0]:
            return self.point_samples[0][1]
        if time >= times[-1]:
            return self.point_samples[-1][1]
        k = int(np.searchsorted(times, time, side="right") - 1)
        (t0, p0), (t1, p1) = self.point_samples[k], self.point_samples[k + 1]
        f = (time - t0) / (t1 - t0)
        return (1 - f) * p0 + f * p1

    def offset_at(self, time: float) -> tuple[float, float, float]:
        """Its translation at ``time`` s."""
        import numpy as np

        times = [t for t, _ in self.keyframes]
        offsets = np.asarray([o for _, o in self.keyframes], np.float64)
        return tuple(float(np.interp(time, times, offsets[:, k])) for k in range(3))

    def points_at(self, time: float):
        """(V, 3) float64: its points in the scene at ``time`` s."""
        import numpy as np

        if not self.poses:
            return self.local_points_at(time) + np.asarray(self.offset_at(time))
        rotation, offset = self.pose_at(time)
        return self.local_points_at(time) @ rotation.T + offset

    @property
    def reach(self) -> float:
        """How far from its surface each particle looks for the mesh: the thickness outside, and inside as deep
        as any inside point can be. From a point inside a closed mesh, the nearer of the two bounding-box faces
        across its thinnest side is at most half that side away, and the way there leaves the mesh, so no
        inside point is further than half the thinnest side from the surface."""
        import numpy as np

        thinnest = max(float(np.min(p.max(axis=0) - p.min(axis=0)))
                       for p in [self.points] + [p for _, p in self.point_samples])
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


@accepts(ARRAY)
def _rotate(value: Any, key: str) -> tuple[tuple[float, tuple[float, float, float]], ...]:
    """[x, y, z] degrees (a fixed rotation), or keyframes [[t, x, y, z], ...]: ((t, (x, y, z)), ...)."""
    return _translate(value, key)


ROTATE = Key("rotate", _rotate, ((0.0, (0.0, 0.0, 0.0)),), "[x, y, z] numbers, or array of [t, x, y, z]",
             "degrees; s, degrees", default_text="`[0.0, 0.0, 0.0]`",
             allowed="finite; keyframes: at least one, times strictly increasing",
             doc="Rotations about the fixed X, then Y, then Z axes, after `scale`: by `[x, y, z]`, or along keyframes "
                 "`[[t, x, y, z], ...]`, the angles linear between them (so `[[0, 0, 0, 0], [1, 0, 360, 0]]` turns "
                 "once about Y in a second) and held at the ends. The mesh turns about the scene's origin, before "
                 "`translate`. A rotating mesh gets time-sampled `xformOp:translate` and `xformOp:orient` in the "
                 "cache.")
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
        from ..geometry.mesh_io import USD_SUFFIXES, read_mesh, read_usd_animation, to_scene, transform_matrix

        relative = FILE.take(table)
        prim = PRIM.take(table)
        keyframes = TRANSLATE.take(table)
        rotate_keys = ROTATE.take(table)
        scale = SCALE.take(table)
        table.finish()  # no unknown key: the file is read only once every key is known to be good
        path = Path(relative)
        if not path.is_absolute():
            path = (table.directory or Path()) / path
        rotation_at = _keyed(rotate_keys)
        start = transform_matrix((0.0, 0.0, 0.0), rotation_at(0.0), scale)
        try:
            source = read_mesh(path, prim, start)
            animation = (read_usd_animation(path, prim) if path.suffix.lower() in USD_SUFFIXES else None)
            if animation is not None and animation.moves:
                # the mesh at the scene's time 0 (read_mesh took the asset's first sample)
                points = to_scene(source.description, start @ animation.world_at(0.0), animation.points_at(0.0))
            else:
                animation, points = None, source.points
            points, triangles, sources = closed_triangles(source.description, points, source.faces, sources=True)
            motion = _motion(source.description, points, sources, keyframes, rotate_keys, scale, animation)
        except MeshError as exc:
            raise table.error("mesh", str(exc)) from None
        usd_prim = (path.resolve(), prim) if path.suffix.lower() in USD_SUFFIXES else None
        return MeshCollider(source=source.description, points=points, triangles=triangles, keyframes=keyframes,
                            usd_prim=usd_prim, rotate_keys=rotate_keys, scale=tuple(scale), **motion, **shared)

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
    def counts(self, specs: tuple[MeshCollider, ...]) -> tuple[int, ...]:
        """(meshes, their points, their triangles, their poses when one moves (else 0), the deforming meshes'
        points, their samples' points, their samples)."""
        moving = any(s.moving for s in specs)
        deforming = [s for s in specs if s.point_samples]
        return (len(specs), sum(len(s.points) for s in specs), sum(len(s.triangles) for s in specs),
                sum(len(s.rigid_poses) if s.moving else 1 for s in specs) if moving else 0,
                sum(len(s.points) for s in deforming), sum(len(s.points) * len(s.point_samples) for s in deforming),
                sum(len(s.point_samples) for s in deforming))

    def device_bytes(self, counts: tuple[int, ...]) -> int:
        meshes, points, triangles, keys = counts[:4]
        deforming_points, sample_points, samples = counts[4:] if len(counts) > 4 else (0, 0, 0)
        given = points * VEC3 + 3 * triangles * INT  # the points and indices the meshes are built from
        # ids, reach, thickness, friction, the start translation; the State's translation
        per_mesh = meshes * (MESH_ID + 4 * FLOAT + 2 * VEC3)  # friction: (mu_k, mu_s)
        bvh = triangles * TRIANGLE_BVH_BYTES + (2 * triangles - meshes) * NODE_BYTES
        bvh += meshes * (INT + DESCRIPTOR_BYTES)
        moving = 0
        if keys:
            # key starts (one more than the meshes), each pose's time, translation and rotation, the State's
            # clock; per mesh whether it deforms, its start rotation, and the State's rotation and the pose at the
            # substep's start (a translation and a rotation)
            moving = (meshes + 1) * INT + keys * (FLOAT + VEC3 + QUAT) + FLOAT64
            moving += meshes * (INT + QUAT + QUAT + VEC3 + QUAT)
        # a deforming mesh's samples and their times, and its points' displacement over a substep (its velocities)
        deforming = sample_points * VEC3 + samples * FLOAT + deforming_points * VEC3
        return given + per_mesh + bvh + moving + deforming

    def build(self, specs: tuple[MeshCollider, ...], device) -> dict[str, Any]:
        import numpy as np
        import warp as wp

        # One points array and one index array for all meshes; each wp.Mesh is built on its views of them.
        point_start = np.r_[0, np.cumsum([len(s.points) for s in specs])]
        index_start = 3 * np.r_[0, np.cumsum([len(s.triangles) for s in specs])]
        points = wp.array(np.concatenate([s.points for s in specs]).astype(np.float32), dtype=wp.vec3)
        indices = wp.array(np.concatenate([s.triangles.reshape(-1) for s in specs]).astype(np.int32), dtype=wp.int32)
        # A deforming mesh's points move each substep: their move over it is the wp.Mesh's velocities (one array
        # for all deforming meshes, as their samples and sample times; each mesh uses its views of them).
        deforming = [k for k, s in enumerate(specs) if s.point_samples]
        displacement = samples = sample_times = None
        views: dict[int, tuple] = {}
        if deforming:
            displacement = wp.zeros(sum(len(specs[k].points) for k in deforming), dtype=wp.vec3)
            samples = wp.array(np.concatenate([p for k in deforming for _, p in specs[k].point_samples])
                               .astype(np.float32), dtype=wp.vec3)
            sample_times = wp.array([t for k in deforming for t, _ in specs[k].point_samples], dtype=float)
            at = [0, 0, 0]  # where the next deforming mesh's displacement, samples and times start
            for k in deforming:
                sizes = (len(specs[k].points), len(specs[k].points) * len(specs[k].point_samples),
                         len(specs[k].point_samples))
                views[k] = tuple(a[start:start + size] for a, start, size in
                                 zip((displacement, samples, sample_times), at, sizes))
                at = [start + size for start, size in zip(at, sizes)]
        bvhs = tuple(wp.Mesh(points=points[point_start[k]:point_start[k + 1]],
                             indices=indices[index_start[k]:index_start[k + 1]],
                             velocities=views[k][0] if k in views else None)
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
            "mesh_start": wp.array([s.pose_at(0.0)[1] if s.moving else s.keyframes[0][1] for s in specs],
                                   dtype=wp.vec3),
        }
        if moving:
            poses = [s.rigid_poses if s.moving else s.rigid_poses[:1] for s in specs]
            start = np.r_[0, np.cumsum([len(p) for p in poses])].astype(np.int32)
            out["mesh_key_start"] = wp.array(start, dtype=int)
            out["mesh_key_times"] = wp.array([t for p in poses for t, _, _ in p], dtype=float)
            out["mesh_key_offsets"] = wp.array([o for p in poses for _, _, o in p], dtype=wp.vec3)
            out["mesh_key_rotations"] = wp.array([q for p in poses for _, q, _ in p], dtype=wp.quat)
            out["mesh_rotation_start"] = wp.array([quat_of_matrix(s.pose_at(0.0)[0]) for s in specs], dtype=wp.quat)
            out["mesh_deforms"] = wp.array([int(bool(s.point_samples)) for s in specs], dtype=int)
            out["mesh_displacements"] = displacement
            out["mesh_samples"] = samples
            out["mesh_sample_times"] = sample_times
            # per deforming mesh: its points, and its views of the three arrays above
            out["mesh_deforming"] = tuple((k, points[point_start[k]:point_start[k + 1]], *views[k]) for k in deforming)
        return out

    def state_arrays(self, colliders) -> dict[str, Any]:
        import warp as wp

        meshes = getattr(colliders, "meshes", ())
        moving = getattr(colliders, "meshes_move", False)
        return {"mesh_clock": wp.zeros(1, dtype=wp.float64) if moving else None,
                "mesh_offsets": wp.clone(colliders.mesh_start) if meshes else None,
                "mesh_rotations": wp.clone(colliders.mesh_rotation_start) if moving else None,
                "mesh_offsets_before": wp.clone(colliders.mesh_start) if moving else None,
                "mesh_rotations_before": wp.clone(colliders.mesh_rotation_start) if moving else None}

    def bind(self, model, state, pushes=None) -> ColliderLaunches:
        import warp as wp

        from ..kernels.collide_mesh import (collide_meshes, collide_moving_meshes, place_mesh_points,
                                            place_moving_meshes)
        from ..kernels.collide_sphere import advance_clock
        from ..launches import recorded

        removed = push_record(pushes, model.device)
        c = model.colliders
        if not c.meshes_move:
            def clamp(first: int, count: int):
                return recorded(collide_meshes, count,
                                [state.particle_q, state.particle_q_inertial, state.particle_dq, model.inv_mass,
                                 c.mesh_ids, state.mesh_offsets, c.mesh_reach, c.mesh_thickness, c.mesh_friction,
                                 removed, first])

            return clamp_launches(clamp, model.particle_count)
        clock = state.mesh_clock
        place = recorded(place_moving_meshes, len(c.meshes),
                         [clock, c.mesh_key_start, c.mesh_key_times, c.mesh_key_offsets, c.mesh_key_rotations],
                         [state.mesh_offsets, state.mesh_rotations, state.mesh_offsets_before,
                          state.mesh_rotations_before])
        deform = [(recorded(place_mesh_points, len(points), [clock, times, samples], [points, displacement]),
                   c.mesh_bvhs[k]) for k, points, displacement, samples, times in c.mesh_deforming]

        def advance(dt: float) -> None:
            wp.launch(advance_clock, 1, inputs=[clock, wp.float64(dt)])
            place.run()
            for points, bvh in deform:
                points.run()
                bvh.refit()

        def moving_clamp(first: int, count: int):
            return recorded(collide_moving_meshes, count,
                            [state.particle_q, state.particle_q_inertial, state.particle_dq, model.inv_mass,
                             c.mesh_ids, state.mesh_offsets, state.mesh_rotations, state.mesh_offsets_before,
                             state.mesh_rotations_before, c.mesh_deforms, c.mesh_reach, c.mesh_thickness,
                             c.mesh_friction, removed, first])

        return clamp_launches(moving_clamp, model.particle_count, (advance,))

    def capturable(self, specs: tuple[MeshCollider, ...], device) -> bool:
        """Whether a frame's launches replay from a capture: not with a deforming mesh, whose BVH refit
        (``wp.Mesh.refit``) Warp's CPU capture does not record (and which is untried in a CUDA graph), so such a
        frame is stepped launch by launch."""
        return not any(s.point_samples for s in specs)

    # ------------------------------------------------------------------ output
    def samples(self, colliders, state, always_moving: bool = False):
        """Translations of the meshes moved by translate keyframes alone, in scene order (a live session drags no
        mesh: the same then); the others' motion is authored with their prims (CachedMesh)."""
        import numpy as np

        if not colliders.meshes_move:
            return np.zeros((0, 3), np.float32)
        return state.mesh_offsets.numpy()[[_sampled_per_frame(s) for s in colliders.meshes]]

    def cached(self, spec: MeshCollider, always_moving: bool = False):
        if spec.usd_prim is not None:
            return ReferencedMesh(spec.name, *spec.usd_prim, spec.keyframes, spec.rotate_keys, spec.scale,
                                  spec.purpose)
        return CachedMesh(spec.name, spec.points, spec.triangles, spec.keyframes[0][1], _sampled_per_frame(spec),
                          spec.purpose, poses=spec.poses)

    def owns_prim(self, prim, under_colliders: bool) -> bool:
        """A Mesh under /World/Colliders other than a plane's single quad."""
        from pxr import UsdGeom

        if not (under_colliders and prim.IsA(UsdGeom.Mesh)):
            return False
        counts = UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get()
        return counts is not None and list(counts) != [4]

    def read_prim(self, prim, reader) -> dict[str, Any]:
        """The triangles as written (or as the referenced asset has them: polygons fanned from their first
        corner), as the drawing primitive ``meshes``: (points (V, 3), triangles (T, 3))."""
        import numpy as np
        from pxr import UsdGeom

        mesh, time = UsdGeom.Mesh(prim), reader.time
        points = reader.attribute(mesh, "points", lambda: mesh.GetPointsAttr().Get(time))
        indices = reader.attribute(mesh, "faceVertexIndices", lambda: mesh.GetFaceVertexIndicesAttr().Get(time))
        counts = reader.attribute(mesh, "faceVertexCounts", lambda: mesh.GetFaceVertexCountsAttr().Get(time))
        if points is None or indices is None or counts is None or len(indices) < 3:
            return {}
        counts, corners = np.asarray(counts, np.int64), np.asarray(indices, np.int64)
        if (counts < 3).any() or counts.sum() != len(corners):
            return {}
        per_face = counts - 2
        start = np.repeat(np.r_[0, np.cumsum(counts)[:-1]], per_face)
        j = np.arange(per_face.sum()) - np.repeat(np.cumsum(per_face) - per_face, per_face)
        triangles = np.stack([corners[start], corners[start + j + 1], corners[start + j + 2]], axis=1)
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
            sim = app.session.sim
            rotations = sim.state.mesh_rotations.numpy()
            for handle, spec, offset, q in zip(drawn, specs, sim.state.mesh_offsets.numpy(), rotations):
                if not np.allclose(handle.position, offset):
                    handle.position = tuple(float(v) for v in offset)
                wxyz = (float(q[3]), float(q[0]), float(q[1]), float(q[2]))
                if not np.allclose(handle.wxyz, wxyz):
                    handle.wxyz = wxyz
                if spec.point_samples:  # a deforming mesh is drawn again with its points now
                    handle.vertices = spec.local_points_at(sim.time).astype(np.float32)

        return LiveDrawing(drawn, frame, update)


def _sampled_per_frame(spec: MeshCollider) -> bool:
    """Whether the cache samples the mesh's translation per frame: a mesh from a file other than USD moved by
    translate keyframes alone (other motion is authored from its keyframes when its prim is defined)."""
    return spec.moving and not spec.poses and not spec.point_samples and spec.usd_prim is None


@dataclass(frozen=True, eq=False)
class CachedMesh:
    """A mesh collider from a file other than USD in the cache: its triangles, written once, and its translation
    (sampled per frame when keyframes alone move it); a mesh that rotates gets its ``poses`` as time samples of
    its translate and orient ops, at their own times (USD interpolates between them as the simulation does:
    linearly, and spherically for the rotations)."""

    name: str
    points: Any
    triangles: Any
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    moving: bool = False
    purpose: str = "guide"
    poses: tuple = ()  # ((time s, quaternion (x, y, z, w), translation), ...)

    def cache_bytes(self, float_bytes: int, int_bytes: int) -> int:
        """At most what its prim takes in a cache whose numbers take these bytes (output_file.estimate_cache):
        its points, a count and three indices per triangle, the prim itself, and its poses' time samples (a time,
        a translation and a quaternion each)."""
        poses = 8 * float_bytes * len(self.poses)
        return 512 + 3 * float_bytes * len(self.points) + 4 * int_bytes * len(self.triangles) + poses

    def define(self, stage, path):
        """A Mesh prim of triangles, wound counter-clockwise seen from outside, with a translate: sampled per
        frame when it moves by keyframes alone (the op returned), else set once or from its poses."""
        import numpy as np
        from pxr import Gf, Usd, UsdGeom, Vt

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
        codes = stage.GetTimeCodesPerSecond()  # a time code is a frame
        if self.poses:
            orient = mesh.AddOrientOp()
            for t, q, offset in self.poses:
                op.Set(Gf.Vec3d(*offset), Usd.TimeCode(t * codes))
                orient.Set(Gf.Quatf(float(q[3]), float(q[0]), float(q[1]), float(q[2])), Usd.TimeCode(t * codes))
            return None
        if self.moving:
            return op  # sampled per frame in write_frame
        op.Set(tuple(float(v) for v in self.offset))
        return None


@dataclass(frozen=True, eq=False)
class ReferencedMesh:
    """A mesh collider read from a USD prim, in the cache: a USD reference to that prim (a path relative to the
    cache where there is one), so that the cache carries the asset's own geometry and animation (its points and
    its own xform ops, time-sampled or not) instead of a copy. It is the child of an Xform at
    ``/World/Colliders/<name>`` that places it as the simulation does: the scene's translate and rotate (time-sampled
    at their keyframes, which USD interpolates as the scene does) and scale, the asset's metersPerUnit, and the
    transform of the prim's parent in the asset (sampled where an ancestor's xform ops are)."""

    name: str
    file: Any  # the asset, an absolute Path
    prim_path: str
    translate_keys: tuple
    rotate_keys: tuple
    scale: tuple
    purpose: str = "guide"
    moving: bool = False  # never sampled per frame: its motion is authored from its keys and its asset

    def cache_bytes(self, float_bytes: int, int_bytes: int) -> int:
        """At most what its prims take (output_file.estimate_cache): the Xform, its keys, the reference."""
        keys = len(self.translate_keys) + len(self.rotate_keys)
        return 2048 + 4 * float_bytes * keys + 17 * float_bytes * len(self._parent_samples())

    def _parent_samples(self) -> list:
        """[(time code of the asset, (4, 4) parent-to-world matrix, USD's row-vector convention), ...]: one
        (held) when no ancestor moves, else at the ancestors' time samples and between them, halved where a
        matrix interpolated between two samples strays from USD's own by more than POSE_TOLERANCE (in asset
        units times the size of the prim)."""
        import numpy as np
        from pxr import Usd, UsdGeom

        stage = Usd.Stage.Open(str(self.file), Usd.Stage.LoadAll)
        prim = stage.GetPrimAtPath(self.prim_path)
        codes: set[float] = set()
        at = prim.GetParent()
        while at and not at.IsPseudoRoot():
            if at.IsA(UsdGeom.Xformable):
                codes.update(UsdGeom.Xformable(at).GetTimeSamples())
            at = at.GetParent()
        xformable = UsdGeom.Xformable(prim)

        def parent(code: float):
            return np.asarray(xformable.ComputeParentToWorldTransform(Usd.TimeCode(code)), np.float64)

        if len(codes) < 2:
            return [(None, parent(min(codes) if codes else 0.0))]
        extent = UsdGeom.Boundable(prim).ComputeLocalBound(Usd.TimeCode.EarliestTime(), UsdGeom.Tokens.default_)
        size = max(1.0, float(np.abs(np.asarray(extent.GetRange().GetSize())).max()))
        return _refine(sorted(codes), parent, lambda a, b, f: (1 - f) * a + f * b,
                       lambda a, b: float(np.abs(a - b).max()) * size)

    def define(self, stage, path):
        """The Xform that places the asset's prim, and its child referencing it; returns None (nothing to sample
        per frame)."""
        import os
        from pathlib import Path

        from pxr import Gf, Usd, UsdGeom

        xform = UsdGeom.Xform.Define(stage, path)
        xform.CreatePurposeAttr(self.purpose)
        codes = stage.GetTimeCodesPerSecond()  # a time code is a frame
        for op, keys in ((xform.AddTranslateOp(), self.translate_keys), (xform.AddRotateXYZOp(), self.rotate_keys)):
            if len({v for _, v in keys}) == 1:
                op.Set(Gf.Vec3d(*keys[0][1]))
            else:
                for t, value in keys:
                    op.Set(Gf.Vec3d(*value), Usd.TimeCode(t * codes))
        xform.AddScaleOp().Set(Gf.Vec3d(*self.scale))
        asset = Usd.Stage.Open(str(self.file), Usd.Stage.LoadAll)
        units = UsdGeom.GetStageMetersPerUnit(asset)
        xform.AddScaleOp(UsdGeom.XformOp.PrecisionDouble, "metersPerUnit").Set(Gf.Vec3d(units, units, units))
        parent = xform.AddTransformOp(UsdGeom.XformOp.PrecisionDouble, "assetParent")
        per_second = asset.GetTimeCodesPerSecond()
        for code, matrix in self._parent_samples():
            value = Gf.Matrix4d(*(float(v) for v in matrix.ravel()))
            if code is None:
                parent.Set(value)
            else:
                parent.Set(value, Usd.TimeCode(code / per_second * codes))
        layer = Path(stage.GetRootLayer().realPath or stage.GetRootLayer().identifier)
        try:
            target = Path(os.path.relpath(self.file, layer.parent)).as_posix()
        except ValueError:  # another drive (Windows): only the absolute path reaches it
            target = Path(self.file).as_posix()
        child = stage.DefinePrim(path.AppendChild(self.prim_path.rsplit("/", 1)[-1]))
        child.GetReferences().AddReference(target, self.prim_path)
        UsdGeom.Imageable(child).CreatePurposeAttr(self.purpose)
        return None


MESH = MeshKind()


LIVE_COLOUR = (178, 184, 194)  # sRGB, on the live and view pages, as a sphere's


def draw_mesh(server, name: str, points, triangles, position=(0.0, 0.0, 0.0)):
    """A mesh collider on a viser page (live and view): its triangles, moved to ``position``."""
    import numpy as np

    return server.scene.add_mesh_simple(f"/colliders/{name}", np.asarray(points, np.float32),
                                        np.asarray(triangles, np.uint32), color=LIVE_COLOUR, side="double",
                                        position=tuple(float(v) for v in position))


# --------------------------------------------------------------------------------------------- motion


def _keyed(keys):
    """The function of time (s) that ``keys`` ((t, (x, y, z)), ...) describe: linear between them, held at the
    ends (float64)."""
    import numpy as np

    times = [t for t, _ in keys]
    values = np.asarray([v for _, v in keys], np.float64)
    return lambda time: np.array([np.interp(time, times, values[:, k]) for k in range(3)])


def quat_matrix(q):
    """(3, 3) rotation of the unit quaternion ``q`` (x, y, z, w)."""
    import numpy as np

    x, y, z, w = (float(v) for v in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def quat_of_matrix(m):
    """The unit quaternion (x, y, z, w) of the (3, 3) rotation ``m`` (Shepperd's method: from its largest
    diagonal term, for accuracy)."""
    import numpy as np

    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > max(m[0, 0], m[1, 1], m[2, 2]):
        w = 0.5 * np.sqrt(1.0 + trace)
        q = ((m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w), w)
    elif m[0, 0] >= m[1, 1] and m[0, 0] >= m[2, 2]:
        x = 0.5 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (x, (m[0, 1] + m[1, 0]) / (4 * x), (m[0, 2] + m[2, 0]) / (4 * x), (m[2, 1] - m[1, 2]) / (4 * x))
    elif m[1, 1] >= m[2, 2]:
        y = 0.5 * np.sqrt(1.0 - m[0, 0] + m[1, 1] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / (4 * y), y, (m[1, 2] + m[2, 1]) / (4 * y), (m[0, 2] - m[2, 0]) / (4 * y))
    else:
        z = 0.5 * np.sqrt(1.0 - m[0, 0] - m[1, 1] + m[2, 2])
        q = ((m[0, 2] + m[2, 0]) / (4 * z), (m[1, 2] + m[2, 1]) / (4 * z), z, (m[1, 0] - m[0, 1]) / (4 * z))
    q = np.asarray(q, np.float64)
    return q / np.linalg.norm(q)


def slerp(q0, q1, f: float):
    """Spherical-linear interpolation from ``q0`` to ``q1`` at fraction ``f``, the short way round (as
    ``wp.quat_slerp``)."""
    import numpy as np

    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    if np.dot(q0, q1) < 0:
        q1 = -q1
    angle = np.arccos(np.clip(np.dot(q0, q1), -1.0, 1.0))
    if angle < 1e-12:
        return q0
    return (np.sin((1 - f) * angle) * q0 + np.sin(f * angle) * q1) / np.sin(angle)


def _refine(times, sample, interpolate, deviation, too_far=None) -> list:
    """[(time, value), ...] at ``times`` and, where interpolating between two neighbours strays from ``sample``
    at their middle by more than POSE_TOLERANCE (or ``too_far(va, vb)``), halved until it does not (at most
    MAX_HALVINGS times)."""
    values = [(t, sample(t)) for t in times]

    def halve(a, va, b, vb, depth: int) -> list:
        middle = 0.5 * (a + b)
        vm = sample(middle)
        close = deviation(interpolate(va, vb, 0.5), vm) <= POSE_TOLERANCE and not (too_far and too_far(va, vb))
        if depth >= MAX_HALVINGS or close:
            return [(b, vb)]
        return halve(a, va, middle, vm, depth + 1) + halve(middle, vm, b, vb, depth + 1)

    out = values[:1]
    for (a, va), (b, vb) in zip(values, values[1:]):
        out += halve(a, va, b, vb, 0)
    return out


def _motion(description: str, points, sources, keyframes, rotate_keys, scale, animation) -> dict[str, tuple]:
    """A mesh's motion beyond its translation keyframes, as MeshCollider's ``poses`` and ``point_samples``: from
    its rotate keyframes and its USD prim's ``animation`` (None: not animated). ``points`` are the mesh at time 0
    (welded: point k is the file's point ``sources[k]``)."""
    import numpy as np

    from ..geometry.mesh_cloth import MeshError
    from ..geometry.mesh_io import to_scene, transform_matrix

    translation_at, rotation_at = _keyed(keyframes), _keyed(rotate_keys)

    def scene_matrix(t: float):
        return transform_matrix((0.0, 0.0, 0.0), rotation_at(t), scale)

    start = scene_matrix(0.0)
    rotates = len({r for _, r in rotate_keys}) > 1
    out: dict[str, tuple] = {}
    rigid = None
    key_times = {t for t, _ in keyframes} | {t for t, _ in rotate_keys}
    if animation is not None and animation.point_times:
        def deformed(t: float):
            return to_scene(description, start @ animation.world_at(t), animation.points_at(t))[sources]

        times = sorted(set(animation.point_times) | set(animation.transform_times))
        samples = _refine(times, deformed, lambda a, b, f: (1 - f) * a + f * b,
                          lambda a, b: float(np.abs(a - b).max()))
        out["point_samples"] = tuple(samples)
        if rotates:
            inverse = np.linalg.inv(start)
            rigid = (lambda t: scene_matrix(t) @ inverse), sorted(key_times)
    elif rotates or (animation is not None and animation.transform_times):
        world = animation.world_at if animation is not None else (lambda t: np.eye(4))
        inverse = np.linalg.inv(start @ world(0.0))
        times = key_times | (set(animation.transform_times) if animation is not None else set())
        rigid = (lambda t: scene_matrix(t) @ world(t) @ inverse), sorted(times)
    if rigid is None:
        return out
    relative, times = rigid
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
    corners = points.min(axis=0) + corners * (points.max(axis=0) - points.min(axis=0))

    def pose(t: float):
        m = relative(t)
        rotation = m[:3, :3]
        if not (np.abs(rotation.T @ rotation - np.eye(3)).max() < 1e-6 and np.linalg.det(rotation) > 0):
            raise MeshError(f"{description}: at {t:g} s its transform scales or shears it relative to time 0; a "
                            "mesh collider moves rigidly (rotates and translates), or deforms by time-sampled "
                            "points")
        return quat_of_matrix(rotation), m[:3, 3] + translation_at(t)

    def placed(p):
        return corners @ quat_matrix(p[0]).T + p[1]

    # Two poses a half turn apart (or nearly) have no one shortest way between them, and float32 rounding may
    # pick either: keep neighbours within a quarter turn (|q0 . q1| >= cos 45 degrees).
    poses = _refine(times, pose, lambda a, b, f: (slerp(a[0], b[0], f), (1 - f) * a[1] + f * b[1]),
                    lambda a, b: float(np.abs(placed(a) - placed(b)).max()),
                    lambda a, b: abs(float(np.dot(a[0], b[0]))) < np.cos(np.pi / 4) - 1e-9)
    out["poses"] = []
    previous = None
    for t, (q, offset) in poses:
        if previous is not None and np.dot(q, previous) < 0:
            q = -q  # the same rotation, on the side of the last one: USD's orient samples slerp between them
        previous = q
        out["poses"].append((float(t), tuple(float(v) for v in q), tuple(float(v) for v in offset)))
    out["poses"] = tuple(out["poses"])
    return out


# --------------------------------------------------------------------------------------------- geometry


def closed_triangles(description: str, points, faces, sources: bool = False):
    """The mesh's triangles (polygons fanned from their first corner), its points welded where they coincide
    exactly and only the points a triangle uses kept, each closed part turned outward; a MeshError when it is
    empty or not closed. Returns (points (V, 3) float64, triangles (T, 3) int32), and with ``sources`` the index
    of each kept point in ``points`` (the first of those welded into it)."""
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
    unique, first, welded = np.unique(np.asarray(points, np.float64), axis=0, return_index=True,
                                      return_inverse=True)
    triangles = welded.reshape(-1)[triangles]
    triangles = triangles[(triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2])
                          & (triangles[:, 2] != triangles[:, 0])]  # collapsed by the weld
    if not len(triangles):
        raise MeshError(f"{description}: an empty mesh: every triangle has two corners at one point")
    used, triangles = np.unique(triangles, return_inverse=True)
    points, triangles = unique[used], triangles.reshape(-1, 3)
    _check_closed(description, points, triangles)
    triangles = _outward(points, triangles).astype(np.int32)
    return (points, triangles, first[used]) if sources else (points, triangles)


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
