"""Self-collision and cloth–cloth contact (warp_verlet/constraints/self_contact.py): candidate pairs once a
substep, one Jacobi gather per sweep.

Indices are the colliding particles' (``particle`` maps them to the positions): every particle of a colliding
cloth, or with a stride a subset. Once a substep, each colliding particle lists its candidate pairs from the hash
grid (rebuilt just before, over their positions): the particles within ``reach`` × the pair's thickness (the mean
of the two particles'), except those closer than ``rest_exclusion`` × the thickness in the rest pose of one cloth.
In each sweep, for every candidate closer than the thickness, it takes its share of the push that separates the
pair to the thickness: (h - d) along the separation, times w_i / (w_i + w_j), and writes the average of its pushes
to ``x_out``; the caller copies ``x_out`` back. Every thread reads the same old positions and no thread writes
another's particle, and the grid's order is fixed, so the sum order is fixed and the result repeatable on every
device.

Friction (``friction``: (mu_k, mu_s) per particle; a pair takes the mean of its two) is Coulomb's at the position
level, as the colliders' (collide_response.py), on the pair's relative tangential move over the substep (each
particle's x - x_prev, x_prev = x_inertial - delta): below mu_s × the pair's push (h - d) it is removed, otherwise
shortened by mu_k × the push, each particle taking its inverse-mass share, averaged with the pushes. Over the
sweeps of a substep the pushes add up to the substep's normal correction and the removed slip to mu_k × it.
"""

from typing import Any

import warp as wp

from .collide_response import coulomb_removed
from .positions import for_positions


@wp.func
def pair_thickness(i: int, j: int, thickness: wp.array(dtype=float), rest: wp.array(dtype=wp.vec3),
                   cloth: wp.array(dtype=int), rest_exclusion: float):
    """The thickness of pair (i, j), or 0 where it never collides (either particle's cloth does not collide, or
    they are rest neighbours of one cloth)."""
    hj = thickness[j]
    if j == i or hj == 0.0:
        return 0.0
    h = 0.5 * (thickness[i] + hj)
    if cloth[j] == cloth[i]:
        if wp.length(rest[i] - rest[j]) < rest_exclusion * h:
            return 0.0  # as close as this at rest: they never collide
    return h


@wp.kernel
def contact_candidates(
    grid: wp.uint64,
    x: wp.array(dtype=Any),
    thickness: wp.array(dtype=float),
    rest: wp.array(dtype=wp.vec3),
    cloth: wp.array(dtype=int),
    rest_exclusion: float,
    reach: float,
    query_radius: Any,
    max_candidates: int,
    first: int,
    candidate: wp.array(dtype=int),
    candidate_count: wp.array(dtype=int),
):
    """Once a substep: each colliding particle's pairs within ``reach`` x their thickness, in the grid's order,
    the first ``max_candidates`` of them. Thread k takes the grid's (first + k)-th point in cell order, so that a
    warp's queries walk the same cells (a CPU thread takes a run of them from ``first``); a pair farther than the
    query radius (reach x the largest thickness) is dropped before its thickness and rest positions are read."""
    i = wp.hash_grid_point_id(grid, first + wp.tid())
    count = int(0)
    if thickness[i] > 0.0:
        xi = x[i]
        query = wp.hash_grid_query(grid, xi, query_radius)
        j = int(0)
        while wp.hash_grid_query_next(query, j):
            if wp.length(xi - x[j]) >= query_radius:
                continue
            h = pair_thickness(i, j, thickness, rest, cloth, rest_exclusion)
            if h > 0.0 and count < max_candidates:
                if wp.length(xi - x[j]) < type(query_radius)(reach * h):
                    candidate[i * max_candidates + count] = j
                    count += 1
    candidate_count[i] = count


@wp.kernel
def contact_gather(
    x_in: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    particle: wp.array(dtype=int),
    thickness: wp.array(dtype=float),
    candidate: wp.array(dtype=int),
    candidate_count: wp.array(dtype=int),
    max_candidates: int,
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    friction: wp.array(dtype=wp.vec2),
    first: int,
    x_out: wp.array(dtype=Any),
):
    """Each sweep: colliding particle i's (particle[i] of the positions) share of the push of every candidate pair
    closer than its thickness, and of the pair's friction, averaged, into x_out[i]."""
    i = first + wp.tid()
    pi = particle[i]
    xi = x_in[pi]
    wi = inv_mass[pi]
    found = candidate_count[i]
    if wi == 0.0 or found == 0:
        x_out[i] = xi
        return
    total = type(xi)(0.0)
    count = int(0)
    for k in range(found):
        j = candidate[i * max_candidates + k]
        pj = particle[j]
        d = xi - x_in[pj]
        dist = wp.length(d)
        gap = type(dist)(0.5 * (thickness[i] + thickness[j])) - dist
        if gap > type(dist)(0.0) and dist > type(dist)(0.0):  # closer than the thickness, with a direction
            share = wi / (wi + inv_mass[pj])
            total += d * (gap / dist * type(dist)(share))
            count += 1
            mu = 0.5 * (friction[i] + friction[j])  # (mu_k, mu_s); mu_s >= mu_k, so 0 means no friction
            if mu[1] > 0.0:
                n = d / dist
                relative = (xi - (x_inertial[pi] - delta[pi])) - (x_in[pj] - (x_inertial[pj] - delta[pj]))
                tangential = relative - n * wp.dot(relative, n)
                total -= tangential * (coulomb_removed(wp.length(tangential), gap, mu) * type(dist)(share))
    if count > 0:
        xi = xi + total / type(total[0])(float(count))
    x_out[i] = xi


@wp.kernel
def gather_positions(x: wp.array(dtype=Any), particle: wp.array(dtype=int), out: wp.array(dtype=Any)):
    """The colliding particles' positions, in their order: what the search reads where only some collide."""
    k = wp.tid()
    out[k] = x[particle[k]]


@wp.kernel
def scatter_positions(gathered: wp.array(dtype=Any), particle: wp.array(dtype=int), first: int,
                      x: wp.array(dtype=Any)):
    """The gather's result written back to the colliding particles (the copy back where only some collide)."""
    k = first + wp.tid()
    x[particle[k]] = gathered[k]


for_positions(contact_candidates, arrays=("x",), scalars=("query_radius",))
for_positions(contact_gather, arrays=("x_in", "x_out", "x_inertial", "delta"))
for_positions(gather_positions, arrays=("x", "out"))
for_positions(scatter_positions, arrays=("gathered", "x"))
