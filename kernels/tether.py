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

PINNED_ROW = wp.constant(-2)
"""The first pin slot of a pinned particle's row (w = 0): the row's particle never moves."""


@wp.func
def tethered(xp: Any, x: wp.array(dtype=Any), pin: wp.array2d(dtype=int), length: wp.array2d(dtype=float), t: int):
    """Position ``xp`` of tether row t's particle moved back within length[t, k] of each pin[t, k] (a negative
    slot: no tether there), pins read from ``x``."""
    k = int(0)
    while k < pin.shape[1]:  # not range(), whose loop handles either sign of step: slower on the CPU
        a = pin[t, k]
        if a >= 0:
            d = xp - x[a]
            distance = wp.length(d)
            limit = type(distance)(length[t, k])
            if distance > limit:
                xp = x[a] + d * (limit / distance)
        k += 1
    return xp


@wp.kernel
def pull_tethers(
    x: wp.array(dtype=Any),
    first: int,
    pin: wp.array2d(dtype=int),
    length: wp.array2d(dtype=float),
    per_thread: int,
):
    """Thread t moves the particles of rows t * per_thread .. (t + 1) * per_thread - 1 in order (row r holds particle
    first + r; ``tethered``): one a thread on a GPU, a CPU piece's all in one loop
    (warp_verlet/launches.elements_per_thread; kernels/relax.py says why). Each moves only its own particle and
    reads only pins, so the order changes no bit; a row with no tether (a pin's, or an untethered cloth's
    particle) is left alone."""
    t = wp.tid() * per_thread
    if t < 0:  # never true (kernels/relax.py says why the signs are tested)
        return
    stop = t + per_thread
    while t < stop:
        if pin[t, 0] >= 0:  # a tether's first pin is in slot 0
            p = first + t
            x[p] = tethered(x[p], x, pin, length, t)
        t += 1


for_positions(pull_tethers, arrays=("x",))
