"""Long-range attachments (tethers; Kim, Chentanez and Mueller 2012, NvCloth's tether constraints).

Each free particle of a pinned cloth is tied to its nearest pins: |x - x_pin| <= L, where L is the rest-pose
distance along the cloth (times a slack scale). The constraint is unilateral (it acts only when the particle
is too far) and moves only the free particle, since a pin has w = 0. So one thread owns one particle and
reads only pins, which never move: no colouring, no atomics, one launch per sweep, deterministic.

Why: a Gauss-Seidel sweep carries a correction about one stick per colour pass, so a big cloth hanging from
a few pins stays stretched for hundreds of sweeps. A tether gives every particle the pin's answer at once.
"""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.kernel
def pull_tethers(
    x: wp.array(dtype=Any),
    particle: wp.array(dtype=int),
    pin: wp.array2d(dtype=int),
    length: wp.array2d(dtype=float),
):
    """Thread t moves particle[t] back within length[t, k] of each pin[t, k] (pin -1: no tether there)."""
    t = wp.tid()
    p = particle[t]
    xp = x[p]
    for k in range(pin.shape[1]):
        a = pin[t, k]
        if a >= 0:
            d = xp - x[a]
            distance = wp.length(d)
            limit = type(distance)(length[t, k])
            if distance > limit:
                xp = x[a] + d * (limit / distance)
    x[p] = xp


for_positions(pull_tethers, arrays=("x",))
