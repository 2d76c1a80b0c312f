"""Plane colliders: particles are projected out of infinite planes (the response: collide_response.py)."""

from typing import Any

import warp as wp

from .collide_response import project_out
from .positions import for_positions


@wp.kernel
def collide_planes(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    thickness: wp.array(dtype=float),
    friction: wp.array(dtype=wp.vec2),  # (mu_k, mu_s) per collider
    pushes: wp.array(dtype=wp.vec3),  # empty, or each particle's pushes summed (collide_response.py)
    first: int,  # the first particle (a CPU thread clamps a run of them from here)
):
    """Collider data is float32; it is converted to the positions' precision (x.dtype) before any use."""
    i = first + wp.tid()
    if inv_mass[i] == 0.0:
        return  # pins are where the user put them
    xi = x[i]
    for p in range(points.shape[0]):
        n = x.dtype(normals[p])
        depth = type(xi[0])(thickness[p]) - wp.dot(xi - x.dtype(points[p]), n)
        if depth > type(depth)(0.0):
            xi = project_out(i, xi, n, depth, friction[p], x_inertial, delta, pushes)
    x[i] = xi


for_positions(collide_planes, arrays=("x", "x_inertial", "delta"))
