"""Triangle-mesh colliders: particles are projected out of closed meshes (the response: collide_response.py).

Each particle asks each mesh's BVH for its closest point within the mesh's reach (its thickness outside, and
deep enough inside to find any inside point: colliders/mesh.py); the sign from the normals there
(``wp.mesh_query_point_sign_normal``) says whether it is inside. The query runs in float32, the mesh's precision;
the depth and direction are then taken in the positions' precision.
"""

from typing import Any

import warp as wp

from .collide_response import project_out
from .positions import for_positions


@wp.kernel
def collide_meshes(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    meshes: wp.array(dtype=wp.uint64),
    reach: wp.array(dtype=float),
    thickness: wp.array(dtype=float),
    friction: wp.array(dtype=float),
):
    """Keeps each free particle ``thickness`` outside every mesh, along the outward direction from its closest
    point (the face's normal when it lies on the surface)."""
    i = wp.tid()
    if inv_mass[i] == 0.0:
        return
    xi = x[i]
    for m in range(meshes.shape[0]):
        query = wp.mesh_query_point_sign_normal(meshes[m], wp.vec3(xi), reach[m])
        if query.result:
            closest = x.dtype(wp.mesh_eval_position(meshes[m], query.face, query.u, query.v))
            d = xi - closest
            distance = wp.length(d)
            sign = type(distance)(query.sign)
            depth = type(distance)(thickness[m]) - sign * distance
            if depth > type(depth)(0.0):
                n = x.dtype(wp.mesh_eval_face_normal(meshes[m], query.face))
                if distance > type(distance)(1.0e-9):
                    n = d * (sign / distance)  # outward: away from the surface outside, towards it inside
                xi = project_out(i, xi, n, depth, friction[m], x_inertial, delta)
    x[i] = xi


for_positions(collide_meshes, arrays=("x", "x_inertial", "delta"))
