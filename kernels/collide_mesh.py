"""Triangle-mesh colliders: particles are projected out of closed meshes (the response: collide_response.py).

Each particle asks each mesh's BVH for its closest point within the mesh's reach (its thickness outside, and
deep enough inside to find any inside point: colliders/mesh.py); the sign from the normals there
(``wp.mesh_query_point_sign_normal``) says whether it is inside. The query first looks near the particle only,
and over the whole reach only for a particle a ray test finds deep inside (``surface_query``). The BVH holds the
mesh in its own frame: the particle is queried at its position less the mesh's translation (``collide_meshes``, where no mesh moves), or
moved into the mesh's frame by its rotation and translation (``collide_moving_meshes``, placed on the device
clock each substep), so a rigidly moving mesh needs no refit; a deforming mesh's points are placed each substep
(``place_mesh_points``) and its BVH refitted. The query runs in float32, the mesh's precision; the depth and
direction are then taken in the positions' precision.
"""

from typing import Any

import warp as wp

from .collide_response import key_interval, project_out, project_out_moving
from .positions import for_positions


@wp.func
def surface_depth(xi: Any, closest: Any, face_normal: Any, u: float, v: float, sign: float, thickness: float):
    """The way out of a mesh for a particle at ``xi`` whose closest surface point is ``closest`` (both in the
    positions' type, in the world), at barycentric (u, v) of a face of normal ``face_normal``, on the ``sign``
    side (the query's: -1 inside), and how far it must go to be ``thickness`` outside: (outward direction,
    depth; depth <= 0 when it already is)."""
    d = xi - closest
    n = face_normal
    height = wp.dot(d, n)  # signed distance, when the closest point lies inside the face
    in_face = u > 0.0 and v > 0.0 and u + v < 1.0
    distance = wp.length(d)
    # Off the face (at an edge or a corner), the way out is along d. So close to the surface that d is float32
    # rounding, the face's normal is the better guess.
    rounding = type(distance)(1.0e-6) * (type(distance)(1.0) + wp.length(closest))
    if not in_face and distance > rounding:
        height = type(distance)(sign) * distance
        n = d / height  # outward: away from the surface outside, towards it inside
    return n, type(distance)(thickness) - height


NEAR_BAND = 2.0
"""The first query looks for the surface within this × the thickness: every particle the clamp acts on outside is
within one thickness of it, and most particles of a cloth are nowhere near the surface, where a small radius lets
the BVH prune almost everything."""


@wp.func
def inside_by_ray(mesh: wp.uint64, p: wp.vec3, direction: wp.vec3):
    """Whether the first face a ray from ``p`` meets is crossed from behind (``p`` is inside a closed mesh). Where
    two parts touch (a table's leg under its top) a ray through the shared face may meet the other part's front
    at the same distance, so ``surface_query`` asks two rays, up and sideways: taking an outside particle for an
    inside one costs only the longer query, the reverse a missed push."""
    ray = wp.mesh_query_ray(mesh, p, direction, 1.0e6)
    return ray.result and ray.sign < 0.0


@wp.func
def surface_query(mesh: wp.uint64, p: wp.vec3, thickness: float, reach: float):
    """The closest surface point within ``reach`` of ``p`` (the mesh's frame) where it matters, with the
    ``wp.mesh_query_point_sign_normal`` sign. First within NEAR_BAND x ``thickness``; with nothing there, ``p`` is
    either outside and clear of the surface (nothing to do) or deep inside, which rays tell (``inside_by_ray``).
    Only then the query over the whole reach, whose radius makes the BVH visit far more of the mesh."""
    query = wp.mesh_query_point_sign_normal(mesh, p, NEAR_BAND * thickness)
    if not query.result:
        if inside_by_ray(mesh, p, wp.vec3(0.0, 1.0, 0.0)) or inside_by_ray(mesh, p, wp.vec3(0.6, 0.0, 0.8)):
            query = wp.mesh_query_point_sign_normal(mesh, p, reach)
    return query


@wp.kernel
def collide_meshes(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    meshes: wp.array(dtype=wp.uint64),
    offsets: wp.array(dtype=wp.vec3),
    reach: wp.array(dtype=float),
    thickness: wp.array(dtype=float),
    friction: wp.array(dtype=wp.vec2),  # (mu_k, mu_s) per collider
    pushes: wp.array(dtype=wp.vec3),  # empty, or each particle's pushes summed (collide_response.py)
    first: int,  # the first particle (a CPU thread clamps a run of them from here)
):
    """Keeps each free particle ``thickness`` outside every mesh: along the face's normal where its closest point
    lies inside a face, else along the outward direction from that point."""
    i = first + wp.tid()
    if inv_mass[i] == 0.0:
        return
    xi = x[i]
    for m in range(meshes.shape[0]):
        query = surface_query(meshes[m], wp.vec3(xi) - offsets[m], thickness[m], reach[m])
        if query.result:
            closest = x.dtype(wp.mesh_eval_position(meshes[m], query.face, query.u, query.v) + offsets[m])
            normal = x.dtype(wp.mesh_eval_face_normal(meshes[m], query.face))
            n, depth = surface_depth(xi, closest, normal, query.u, query.v, query.sign, thickness[m])
            if depth > type(depth)(0.0):
                xi = project_out(i, xi, n, depth, friction[m], x_inertial, delta, pushes)
    x[i] = xi


for_positions(collide_meshes, arrays=("x", "x_inertial", "delta"))


@wp.kernel
def collide_moving_meshes(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    meshes: wp.array(dtype=wp.uint64),
    offsets: wp.array(dtype=wp.vec3),
    rotations: wp.array(dtype=wp.quat),
    offsets_before: wp.array(dtype=wp.vec3),
    rotations_before: wp.array(dtype=wp.quat),
    deforms: wp.array(dtype=int),
    reach: wp.array(dtype=float),
    thickness: wp.array(dtype=float),
    friction: wp.array(dtype=wp.vec2),  # (mu_k, mu_s) per collider
    pushes: wp.array(dtype=wp.vec3),  # empty, or each particle's pushes summed (collide_response.py)
    first: int,  # the first particle (a CPU thread clamps a run of them from here)
):
    """``collide_meshes`` for scenes where a mesh moves: each BVH holds its mesh in its own frame, placed by a
    rotation and a translation (the State's, at the end of the substep; ``*_before`` at its start), and the
    points of a deforming mesh are placed and refitted each substep, with their displacement over the substep as
    the wp.Mesh's velocities. Friction acts on the particle's motion relative to the surface point it touches,
    which moved by (its place now) - (its place at the start of the substep)."""
    i = first + wp.tid()
    if inv_mass[i] == 0.0:
        return
    xi = x[i]
    for m in range(meshes.shape[0]):
        q = rotations[m]
        local = wp.quat_rotate_inv(q, wp.vec3(xi) - offsets[m])
        query = surface_query(meshes[m], local, thickness[m], reach[m])
        if query.result:
            on_surface = wp.mesh_eval_position(meshes[m], query.face, query.u, query.v)
            closest = x.dtype(wp.quat_rotate(q, on_surface) + offsets[m])
            normal = x.dtype(wp.quat_rotate(q, wp.mesh_eval_face_normal(meshes[m], query.face)))
            n, depth = surface_depth(xi, closest, normal, query.u, query.v, query.sign, thickness[m])
            if depth > type(depth)(0.0):
                was = on_surface
                if deforms[m] != 0:
                    was = on_surface - wp.mesh_eval_velocity(meshes[m], query.face, query.u, query.v)
                surface_step = closest - x.dtype(wp.quat_rotate(rotations_before[m], was) + offsets_before[m])
                xi = project_out_moving(i, xi, n, depth, friction[m], x_inertial, delta, surface_step,
                                        pushes)
    x[i] = xi


for_positions(collide_moving_meshes, arrays=("x", "x_inertial", "delta"))


@wp.kernel
def place_moving_meshes(
    clock: wp.array(dtype=wp.float64),
    key_start: wp.array(dtype=int),
    key_times: wp.array(dtype=float),
    key_offsets: wp.array(dtype=wp.vec3),
    key_rotations: wp.array(dtype=wp.quat),
    offsets: wp.array(dtype=wp.vec3),
    rotations: wp.array(dtype=wp.quat),
    offsets_before: wp.array(dtype=wp.vec3),
    rotations_before: wp.array(dtype=wp.quat),
):
    """Mesh m's place at the current time, its place until now kept as where it was at the substep's start:
    translation linear and rotation spherical-linear between keyframes (dense enough that this follows the
    scene's and the asset's own interpolation: colliders/mesh.py), held before the first and after the last."""
    m = wp.tid()
    offsets_before[m] = offsets[m]
    rotations_before[m] = rotations[m]
    t = float(clock[0])
    first = key_start[m]
    last = key_start[m + 1] - 1
    if last == first:
        return
    k, f = key_interval(t, first, last, key_times)
    offset = key_offsets[first]
    rotation = key_rotations[first]
    if k >= last:
        offset = key_offsets[last]
        rotation = key_rotations[last]
    elif k >= first:
        offset = wp.lerp(key_offsets[k], key_offsets[k + 1], f)
        rotation = wp.quat_slerp(key_rotations[k], key_rotations[k + 1], f)
    offsets[m] = offset
    rotations[m] = rotation


@wp.kernel
def place_mesh_points(
    clock: wp.array(dtype=wp.float64),
    sample_times: wp.array(dtype=float),
    samples: wp.array(dtype=wp.vec3),
    points: wp.array(dtype=wp.vec3),
    displacement: wp.array(dtype=wp.vec3),
):
    """A deforming mesh's point v at the current time, linear between its samples (each ``points.shape[0]``
    long, one after the other) and held at the ends, and how far it moved since the last placing."""
    v = wp.tid()
    n = points.shape[0]
    t = float(clock[0])
    last = sample_times.shape[0] - 1
    k, f = key_interval(t, 0, last, sample_times)
    p = samples[v]
    if k >= last:
        p = samples[last * n + v]
    elif k >= 0:
        p = wp.lerp(samples[k * n + v], samples[(k + 1) * n + v], f)
    displacement[v] = p - points[v]
    points[v] = p
