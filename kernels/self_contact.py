"""Self-collision and cloth–cloth contact (warp_verlet/constraints/self_contact.py): candidate pairs once a
substep, one Jacobi gather per sweep.

Once a substep, the cell grid is rebuilt (``grid_keys``, a radix sort, ``grid_ranges``) and each particle of a
colliding cloth lists its candidate pairs from it (``contact_candidates``): the particles within ``reach`` × the pair's thickness (the mean of the two particles'), except those
closer than ``rest_exclusion`` × the thickness in the rest pose of one cloth. In each sweep, for every candidate
closer than the thickness, it takes its share of the push that separates the pair to the thickness: (h - d)
along the separation, times w_i / (w_i + w_j), and writes the average of its pushes to ``x_out``; the caller
copies ``x_out`` back. Every thread reads the same old positions and no thread writes another's particle, and the
grid's order is fixed, so the sum order is fixed and the result repeatable on every device.

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


@wp.func
def grid_cell(x: Any, inv_cell: float):
    """The integer cell of point ``x`` in cells of 1 / ``inv_cell`` metres."""
    s = type(x[0])(inv_cell)
    return wp.vec3i(int(wp.floor(x[0] * s)), int(wp.floor(x[1] * s)), int(wp.floor(x[2] * s)))


@wp.func
def cell_key(c: wp.vec3i, dims: wp.vec3i):
    """The table slot of cell ``c``: its coordinates wrapped onto a dims[0] x dims[1] x dims[2] table (a cell far
    away shares a slot with one inside, and the query checks distances)."""
    a = c[0] % dims[0]
    b = c[1] % dims[1]
    d = c[2] % dims[2]
    if a < 0:
        a += dims[0]
    if b < 0:
        b += dims[1]
    if d < 0:
        d += dims[2]
    return (a * dims[1] + b) * dims[2] + d


@wp.kernel
def grid_keys(
    x: wp.array(dtype=Any),
    thickness: wp.array(dtype=float),
    inv_cell: float,
    dims: wp.vec3i,
    cells: int,
    keys: wp.array(dtype=int),
    order: wp.array(dtype=int),
    cell_start: wp.array(dtype=int),
    cell_end: wp.array(dtype=int),
):
    """Each particle's table slot (``cells`` for one that does not collide: it sorts last and is in no cell), with
    its own index as the value the sort carries. First it empties the slot that the previous build's ``keys[i]``
    (sorted) named: between them the threads empty every slot the previous build filled, and no other."""
    i = wp.tid()
    old = keys[i]
    if old >= 0 and old < cells:
        cell_start[old] = 0
        cell_end[old] = 0
    key = cells
    if thickness[i] > 0.0:
        key = cell_key(grid_cell(x[i], inv_cell), dims)
    keys[i] = key
    order[i] = i


@wp.kernel
def grid_ranges(keys: wp.array(dtype=int), count: int, cells: int, cell_start: wp.array(dtype=int),
                cell_end: wp.array(dtype=int)):
    """After the sort: each filled slot's range [start, end) in the sorted order, from where its key begins and
    ends (an empty slot keeps start = end = 0)."""
    i = wp.tid()
    key = keys[i]
    if key >= cells:
        return
    if i == 0 or keys[i - 1] != key:
        cell_start[key] = i
    if i == count - 1 or keys[i + 1] != key:
        cell_end[key] = i + 1


@wp.kernel
def contact_candidates(
    x: wp.array(dtype=Any),
    thickness: wp.array(dtype=float),
    rest: wp.array(dtype=wp.vec3),
    cloth: wp.array(dtype=int),
    rest_exclusion: float,
    reach: float,
    inv_cell: float,
    dims: wp.vec3i,
    order: wp.array(dtype=int),
    cell_start: wp.array(dtype=int),
    cell_end: wp.array(dtype=int),
    max_candidates: int,
    candidate: wp.array(dtype=int),
    candidate_count: wp.array(dtype=int),
):
    """Once a substep: each colliding particle's pairs within ``reach`` x their thickness, the first
    ``max_candidates`` of them in a fixed order: the 27 cells around it (a cell is at least the reach, so they
    hold every pair within it), then the particles of a cell by index."""
    i = wp.tid()
    count = int(0)
    if thickness[i] > 0.0:
        xi = x[i]
        c = grid_cell(xi, inv_cell)
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    key = cell_key(c + wp.vec3i(dx, dy, dz), dims)
                    for k in range(cell_start[key], cell_end[key]):
                        j = order[k]
                        h = pair_thickness(i, j, thickness, rest, cloth, rest_exclusion)
                        if h > 0.0 and count < max_candidates:
                            if wp.length(xi - x[j]) < type(xi[0])(reach * h):
                                candidate[i * max_candidates + count] = j
                                count += 1
    candidate_count[i] = count


@wp.kernel
def contact_gather(
    x_in: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
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
    """Each sweep: a particle's share of the push of every candidate pair closer than its thickness, and of the
    pair's friction, averaged."""
    i = first + wp.tid()
    xi = x_in[i]
    wi = inv_mass[i]
    found = candidate_count[i]
    if wi == 0.0 or found == 0:
        x_out[i] = xi
        return
    total = type(xi)(0.0)
    count = int(0)
    for k in range(found):
        j = candidate[i * max_candidates + k]
        d = xi - x_in[j]
        dist = wp.length(d)
        gap = type(dist)(0.5 * (thickness[i] + thickness[j])) - dist
        if gap > type(dist)(0.0) and dist > type(dist)(0.0):  # closer than the thickness, with a direction
            share = wi / (wi + inv_mass[j])
            total += d * (gap / dist * type(dist)(share))
            count += 1
            mu = 0.5 * (friction[i] + friction[j])  # (mu_k, mu_s); mu_s >= mu_k, so 0 means no friction
            if mu[1] > 0.0:
                n = d / dist
                relative = (xi - (x_inertial[i] - delta[i])) - (x_in[j] - (x_inertial[j] - delta[j]))
                tangential = relative - n * wp.dot(relative, n)
                total -= tangential * (coulomb_removed(wp.length(tangential), gap, mu) * type(dist)(share))
    if count > 0:
        xi = xi + total / type(total[0])(float(count))
    x_out[i] = xi


for_positions(grid_keys, arrays=("x",))
for_positions(contact_candidates, arrays=("x",))
for_positions(contact_gather, arrays=("x_in", "x_out", "x_inertial", "delta"))
