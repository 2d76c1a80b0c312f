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
def into_ball(p: Any, centre: Any, radius: Any):
    """``p`` moved to the nearest point of the ball of ``radius`` about ``centre`` (itself when inside), in the
    precision of its arguments."""
    d = p - centre
    distance = wp.length(d)
    if distance > radius:
        return centre + d * (radius / distance)
    return p


@wp.func
def into_ball_squared(p: wp.vec3d, centre: wp.vec3d, radius: wp.float64):
    """``into_ball`` in float64, its test on squares: no root for a point inside."""
    d = p - centre
    distance_sq = wp.length_sq(d)
    if distance_sq > radius * radius:
        return centre + d * (radius / wp.sqrt(distance_sq))
    return p


@wp.func
def into_two_balls(p: wp.vec3d, a: wp.vec3d, la: wp.float64, b: wp.vec3d, lb: wp.float64):
    """The nearest point to ``p`` of the intersection of the balls (a, la) and (b, lb): the nearest point of one
    ball where it lies in the other, else the nearest point of the circle where their spheres meet. In float64:
    near the line between the pins that circle's radius is a small difference of large squares, and a point of
    one sphere just outside the other lies far from the circle's nearest point where the spheres cross at a
    shallow angle. The tests compare squares, so a point inside both balls takes no root."""
    qa = into_ball_squared(p, a, la)
    if wp.length_sq(qa - b) <= lb * lb:
        return qa
    qb = into_ball_squared(p, b, lb)
    if wp.length_sq(qb - a) <= la * la:
        return qb
    axis = b - a
    gap = wp.length(axis)
    if gap == wp.float64(0.0):
        return qb
    u = axis * (wp.float64(1.0) / gap)
    along = (gap * gap + la * la - lb * lb) / (wp.float64(2.0) * gap)  # the circle's centre, from a along u
    rho2 = la * la - along * along
    w = (p - a) - u * wp.dot(p - a, u)  # p's offset from the axis
    across_sq = wp.length_sq(w)
    if rho2 <= wp.float64(0.0) or across_sq == wp.float64(0.0):
        # The spheres touch at one point of the axis (a cloth's edge running straight between its two pins, the
        # lengths' rounding deciding whether they overlap), or p lies on the axis: that point.
        return a + u * wp.clamp(along, wp.float64(0.0), gap)
    return a + u * along + w * wp.sqrt(rho2 / across_sq)


@wp.func
def within_pins(p: Any, x: wp.array(dtype=Any), a: int, la: Any, b: int, lb: Any):
    """``p`` moved to the nearest point within ``la`` of pin a (in the precision of the positions) and, where
    b >= 0, within ``lb`` of pin b (both at once, in float64: ``into_two_balls``), the pins read from ``x``."""
    if b < 0:
        return into_ball(p, x[a], la)
    return type(p)(into_two_balls(wp.vec3d(p), wp.vec3d(x[a]), wp.float64(la), wp.vec3d(x[b]), wp.float64(lb)))


@wp.func
def tethered(xp: Any, x: wp.array(dtype=Any), pin: wp.array2d(dtype=int), length: wp.array2d(dtype=float), t: int):
    """Position ``xp`` of tether row t's particle moved to the nearest point within length[t, k] of each pin[t, k]
    (a negative slot: no tether there), pins read from ``x``. With two tethers this is the nearest point of both
    balls at once (``into_two_balls``): projected onto one after the other, a particle near the line between two
    pins (the top edge of a cloth hung by two corners) is moved mostly sideways, towards whichever pin comes last,
    and the order flips where the nearer pin does, which the sticks are left to undo."""
    a = pin[t, 0]
    if a < 0:
        return xp
    b = int(-1)
    lb = float(0.0)
    if pin.shape[1] > 1:
        b = pin[t, 1]
        lb = length[t, 1]
    return within_pins(xp, x, a, type(xp[0])(length[t, 0]), b, type(xp[0])(lb))


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
