"""The multilevel pass (warp_verlet/constraints/multilevel.py): unilateral coarse sticks, and the prolongation of a
level's moves to the particles of the next finer level.

Both run at the start of a substep's relaxation, when every free particle still sits at the position the
Verlet step predicted (``x_inertial``): a particle's move in the pass is x - x_inertial, with no snapshot.
"""

from typing import Any

import warp as wp

from .positions import for_positions, scaled
from .relax import stick_correction


@wp.kernel
def limit_coarse_colour(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    ends: wp.array(dtype=wp.vec2i),
    limit: wp.array(dtype=float),
    first: int,
):
    """One colour of a level's coarse sticks: pull the two ends back within ``limit`` of each other (never
    push them apart: a coarse stick only forbids stretching, so the cloth may fold and drape)."""
    s = first + wp.tid()
    e = ends[s]
    i = e[0]
    j = e[1]
    xi = x[i]
    xj = x[j]
    length = wp.length(xj - xi)
    if length <= type(length)(limit[s]):
        return
    wi = inv_mass[i]
    wj = inv_mass[j]
    c = stick_correction(xi, xj, wi, wj, limit[s], 1.0)
    x[i] = xi + scaled(c, wi)
    x[j] = xj - scaled(c, wj)


@wp.kernel
def prolongate(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    child: wp.array(dtype=int),
    parents: wp.array(dtype=wp.vec4i),
    weights: wp.array(dtype=wp.vec4),
):
    """Move each child by the bilinear interpolation of its four parents' moves since the pass began. A
    child is never a parent at the same level, so threads read and write disjoint particles."""
    t = wp.tid()
    p = child[t]
    if inv_mass[p] == 0.0:
        return
    ps = parents[t]
    ws = weights[t]
    xp = x[p]
    shift = type(xp)(0.0)
    for k in range(4):
        a = ps[k]
        shift += scaled(x[a] - x_inertial[a], ws[k])
    x[p] = xp + shift


for_positions(limit_coarse_colour, arrays=("x",))
for_positions(prolongate, arrays=("x", "x_inertial"))
