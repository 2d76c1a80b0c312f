"""Rigid patches (warp_verlet/constraints/rigid_patches.py): each patch's particles put back on their rest shape,
turned and moved as the patch has moved, by shape matching (Mueller, Heidelberger, Teschner and Gross 2005,
"Meshless deformations based on shape matching").

One thread per patch (patches share no particle), its members in order: the mass-weighted centroid c of the
current positions (summed as offsets from the first member, in float64), the rotation R nearest to
A = sum m_i (x_i - c) q_i^T (q_i: the member's rest offset from the rest centroid) from the polar decomposition
of A by ``wp.svd3``, with the sign that keeps R a rotation, and every free member set to c + R q_i. The weights
give a pin an overwhelming mass, so a patch holding a pin turns about it; the centroid of the weights does not
move, so the patch's momentum is kept.
"""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.kernel
def match_patches(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    patch_start: wp.array(dtype=int),
    member: wp.array(dtype=int),
    rest_offset: wp.array(dtype=wp.vec3),
    weight: wp.array(dtype=float),
    first: int,
):
    patch = first + wp.tid()
    begin = patch_start[patch]
    end = patch_start[patch + 1]
    # In float64 whatever the positions' type, and as offsets from the first member: float32 sums of positions
    # near a few metres round by a few spacings a projection, all one way, and the SVD of a flat patch's rank-2
    # matrix by about 1e-7, which thousands of projections a second would turn into a drift of the patch.
    x0 = x[member[begin]]
    centre = wp.vec3d(0.0)
    total = wp.float64(0.0)
    for k in range(begin, end):
        m = wp.float64(weight[k])
        centre = centre + wp.vec3d(x[member[k]] - x0) * m
        total = total + m
    centre = centre / total
    a = wp.mat33d(0.0)
    for k in range(begin, end):
        a = a + wp.outer((wp.vec3d(x[member[k]] - x0) - centre) * wp.float64(weight[k]), wp.vec3d(rest_offset[k]))
    u = wp.mat33d(0.0)
    sigma = wp.vec3d(0.0)
    v = wp.mat33d(0.0)
    wp.svd3(a, u, sigma, v)
    r = u * wp.transpose(v)
    if wp.determinant(r) < wp.float64(0.0):
        # A reflection fits as well when the patch is flat or straight: flip the axis of the least singular value.
        u = u * wp.diag(wp.vec3d(1.0, 1.0, -1.0))
        r = u * wp.transpose(v)
    for k in range(begin, end):
        i = member[k]
        if inv_mass[i] > 0.0:
            x[i] = x0 + type(x0)(centre + r * wp.vec3d(rest_offset[k]))


for_positions(match_patches, arrays=("x",))
