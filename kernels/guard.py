"""Divergence guard: the first particle whose position is not finite or lies beyond a bound.

Run once per frame, it replaces a host-side scan of the frame's positions: the host reads back one
integer. ``atomic_min`` makes the answer the lowest such index whatever the thread order.
"""

import warp as wp


@wp.kernel
def find_diverged(x: wp.array(dtype=wp.vec3), bound: float, first: wp.array(dtype=int)):
    i = wp.tid()
    p = x[i]
    # NaN fails every comparison, so one negated test catches NaN, inf and far-away particles alike.
    if not (wp.abs(p[0]) <= bound and wp.abs(p[1]) <= bound and wp.abs(p[2]) <= bound):
        wp.atomic_min(first, 0, i)
