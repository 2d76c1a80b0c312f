"""Tearing: a stick stretched beyond its tear length (threshold x rest length) is removed.

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


for_positions(tear_sticks, arrays=("x",))
