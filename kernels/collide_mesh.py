"""Triangle-mesh colliders: particles are projected out of closed meshes (the response: collide_response.py).

Each particle asks each mesh's BVH for its closest point within the mesh's reach (its thickness outside, and
deep enough inside to find any inside point: colliders/mesh.py); the sign from the normals there
(``wp.mesh_query_point_sign_normal``) says whether it is inside. The BVH holds the mesh untranslated: the
particle is queried at its position less the mesh's translation (the State's, placed on the device clock for a
moving mesh), so a moving mesh needs no refit. The query runs in float32, the mesh's precision; the depth and
direction are then taken in the positions' precision.
"""

from typing import Any

import warp as wp

from .collide_response import keyframed, project_out
from .positions import for_positions


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
):
    """Keeps each free particle ``thickness`` outside every mesh: along the face's normal where its closest point
    lies inside a face, else along the outward direction from that point."""
    i = wp.tid()
    if inv_mass[i] == 0.0:
        return
    xi = x[i]
    for m in range(meshes.shape[0]):
        query = wp.mesh_query_point_sign_normal(meshes[m], wp.vec3(xi) - offsets[m], reach[m])
        if query.result:
            closest = x.dtype(wp.mesh_eval_position(meshes[m], query.face, query.u, query.v) + offsets[m])
            d = xi - closest
            n = x.dtype(wp.mesh_eval_face_normal(meshes[m], query.face))
            height = wp.dot(d, n)  # signed distance, when the closest point lies inside the face
            in_face = query.u > 0.0 and query.v > 0.0 and query.u + query.v < 1.0
            distance = wp.length(d)
            # Off the face (at an edge or a corner), the way out is along d. So close to the surface that d is
            # float32 rounding, the face's normal is the better guess.
            rounding = type(distance)(1.0e-6) * (type(distance)(1.0) + wp.length(closest))
            if not in_face and distance > rounding:
                height = type(distance)(query.sign) * distance
                n = d / height  # outward: away from the surface outside, towards it inside
            depth = type(distance)(thickness[m]) - height
            if depth > type(depth)(0.0):
                xi = project_out(i, xi, n, depth, friction[m], x_inertial, delta)
    x[i] = xi


for_positions(collide_meshes, arrays=("x", "x_inertial", "delta"))


@wp.kernel
def place_meshes(
    clock: wp.array(dtype=wp.float64),
    key_start: wp.array(dtype=int),
    key_times: wp.array(dtype=float),
    key_offsets: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.vec3),
):
    """Translation of mesh m at the current time: linear between keyframes, held before the first and after
    the last. A mesh of one keyframe is left where it is."""
    m = wp.tid()
    t = float(clock[0])
    first = key_start[m]
    last = key_start[m + 1] - 1
    if last == first:
        return
    offsets[m] = keyframed(t, first, last, key_times, key_offsets)
