"""Divergence guard: the first particle whose position is not finite or lies beyond a bound.

Run once per frame, it replaces a host-side scan of the frame's positions: the host reads back one
integer. ``atomic_min`` makes the answer the lowest such index whatever the thread order.
"""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.kernel
def find_diverged(x: wp.array(dtype=Any), bound: float, first: wp.array(dtype=int)):
    i = wp.tid()
    p = x[i]
    b = type(p[0])(bound)
    # NaN fails every comparison, so one negated test catches NaN, inf and far-away particles alike.
    if not (wp.abs(p[0]) <= b and wp.abs(p[1]) <= b and wp.abs(p[2]) <= b):
        wp.atomic_min(first, 0, i)


for_positions(find_diverged, arrays=("x",))
