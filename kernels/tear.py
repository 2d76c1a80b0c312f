"""Tearing: a stick stretched beyond its tear length (threshold x rest length), or one whose tension passes its
tear force (tear_tension x rest length), is removed.

Removal sets the stick's weight (in the State, not the Model) to 0. The relaxation kernels already turn a weight of 0 into no
correction, so a torn stick stays in its colour's slot and needs no relax-kernel variant, no compaction
and no new colouring: a subset of a valid colouring is still valid.

Each thread decides one stick from the same positions and writes only that stick's weight, so the set
of torn sticks is the same whatever the thread order. The counter is an integer atomic, whose sum does not
depend on order either; the host reads that one integer per frame to learn whether anything tore.
"""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.kernel
def tear_sticks(
    x: wp.array(dtype=Any),
    ends: wp.array(dtype=wp.vec2i),
    tear_length: wp.array(dtype=float),
    weight: wp.array(dtype=float),
    torn_count: wp.array(dtype=int),
):
    s = wp.tid()
    if weight[s] == 0.0:
        return  # already torn
    e = ends[s]
    length = wp.length(x[e[1]] - x[e[0]])
    if length > type(length)(tear_length[s]):
        weight[s] = 0.0
        wp.atomic_add(torn_count, 0, 1)


@wp.kernel
def tear_sticks_by_tension(
    x: wp.array(dtype=Any),
    ends: wp.array(dtype=wp.vec2i),
    tear_length: wp.array(dtype=float),
    tension: wp.array(dtype=float),
    tear_force: wp.array(dtype=float),
    inv_dt2: float,
    blend: float,
    force: wp.array(dtype=float),
    weight: wp.array(dtype=float),
    torn_count: wp.array(dtype=int),
):
    """tear_sticks for a scene with a cloth that tears by tension. The force a stick transmitted over the substep
    is mu / dt^2 (N; mu the Lagrange multiplier its projections added up, kernels/relax.py); ``force`` keeps its
    running average, moved by ``blend`` (1 - exp(-dt / tau)) towards it each substep. The stick tears when it is
    longer than its tear length (+inf where its cloth sets no tear_threshold) or when that average exceeds its
    tear force (N, tear_tension x rest length; +inf where its cloth sets no tear_tension). Only pulling tears: a
    pushed stick's mu is negative."""
    s = wp.tid()
    if weight[s] == 0.0:
        return  # already torn
    average = force[s] + (tension[s] * inv_dt2 - force[s]) * blend
    force[s] = average
    e = ends[s]
    length = wp.length(x[e[1]] - x[e[0]])
    if length > type(length)(tear_length[s]) or average > tear_force[s]:
        weight[s] = 0.0
        wp.atomic_add(torn_count, 0, 1)


for_positions(tear_sticks, arrays=("x",))
for_positions(tear_sticks_by_tension, arrays=("x",))
