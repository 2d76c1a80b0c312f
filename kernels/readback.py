"""What a viewer reads back each frame, computed on the device so that only the result crosses to the host:
the drawn particles' interpolated positions (a few thousand vec3 instead of every particle's three arrays),
and the structural stretch reduced to three numbers (instead of every position and a numpy pass over every
stick)."""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.kernel
def gather_drawn(x: wp.array(dtype=Any), x_inertial: wp.array(dtype=Any), dq: wp.array(dtype=Any),
                 particle: wp.array(dtype=int), alpha: float, out: wp.array(dtype=wp.vec3f)):
    """out[i]: particle[i] between its position after the previous substep (x_inertial - dq, as
    ``State.previous_positions``) and now, ``alpha`` of the way: what ``Simulator.render_positions`` gives."""
    i = wp.tid()
    p = particle[i]
    now = x[p]
    before = x_inertial[p] - dq[p]
    v = before + (now - before) * type(now[0])(alpha)
    out[i] = wp.vec3f(wp.float32(v[0]), wp.float32(v[1]), wp.float32(v[2]))


@wp.kernel
def structural_stretch(x: wp.array(dtype=Any), ends: wp.array(dtype=wp.vec2i), rest: wp.array(dtype=float),
                       weight_entry: wp.array(dtype=int), weight: wp.array(dtype=float),
                       sum_squares: wp.array(dtype=wp.float64), largest: wp.array(dtype=float),
                       count: wp.array(dtype=int)):
    """|D - L| / L of structural stick i in float64 (as ``Model.structural_stretch`` on the host), skipped when
    torn (its weight entry is 0; ``weight`` is empty for a scene that cannot tear); summed as squares, maxed
    and counted with atomics (the sum's order, and so its last bits, may vary between runs on a GPU)."""
    i = wp.tid()
    if weight.shape[0] > 0:
        if weight[weight_entry[i]] == 0.0:
            return
    a = x[ends[i][0]]
    b = x[ends[i][1]]
    dx = wp.float64(b[0]) - wp.float64(a[0])
    dy = wp.float64(b[1]) - wp.float64(a[1])
    dz = wp.float64(b[2]) - wp.float64(a[2])
    length = wp.sqrt(dx * dx + dy * dy + dz * dz)
    r = wp.float64(rest[i])
    s = wp.abs(length - r) / r
    wp.atomic_add(sum_squares, 0, s * s)
    wp.atomic_max(largest, 0, wp.float32(s))
    wp.atomic_add(count, 0, 1)


for_positions(gather_drawn, arrays=("x", "x_inertial", "dq"))
for_positions(structural_stretch, arrays=("x",))
