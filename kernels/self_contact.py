"""Self-collision and cloth–cloth contact (warp_verlet/constraints/self_contact.py): one Jacobi gather per sweep.

Each particle of a colliding cloth finds its neighbours in the hash grid (rebuilt at the start of the substep),
and for every pair closer than the pair's thickness (the mean of the two particles') that was not closer than
``rest_exclusion`` × the thickness in the rest pose of one cloth, takes its share of the push that separates the
pair to the thickness: (h - d) along the separation, times w_i / (w_i + w_j). It writes the average of its
pushes to ``x_out``; the caller copies ``x_out`` back. Every thread reads the same old positions and no thread
writes another's particle, so the sum order is fixed and the result repeatable on every device.
"""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.kernel
def contact_gather(
    grid: wp.uint64,
    x_in: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    thickness: wp.array(dtype=float),
    rest: wp.array(dtype=wp.vec3),
    cloth: wp.array(dtype=int),
    rest_exclusion: float,
    query_radius: Any,
    first: int,
    x_out: wp.array(dtype=Any),
):
    i = first + wp.tid()
    xi = x_in[i]
    hi = thickness[i]
    wi = inv_mass[i]
    if hi == 0.0 or wi == 0.0:
        x_out[i] = xi
        return
    total = type(xi)(0.0)
    count = int(0)
    query = wp.hash_grid_query(grid, xi, query_radius)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        hj = thickness[j]
        if j == i or hj == 0.0:
            continue
        h = 0.5 * (hi + hj)
        if cloth[j] == cloth[i]:
            if wp.length(rest[i] - rest[j]) < rest_exclusion * h:
                continue  # rest neighbours: as close as this at rest, they never collide
        d = xi - x_in[j]
        dist = wp.length(d)
        gap = type(dist)(h) - dist
        if gap <= type(dist)(0.0) or dist == type(dist)(0.0):
            continue  # apart, or at one point (no direction to push along)
        share = wi / (wi + inv_mass[j])
        total += d * (gap / dist * type(dist)(share))
        count += 1
    if count > 0:
        xi = xi + total / type(total[0])(float(count))
    x_out[i] = xi


for_positions(contact_gather, arrays=("x_in", "x_out"), scalars=("query_radius",))
