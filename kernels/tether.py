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
def into_two_balls(p: Any, a: Any, la: Any, b: Any, lb: Any):
    """The nearest point to ``p`` of the intersection (a lens) of the balls (a, la) and (b, lb), in the precision of
    the arguments: ``p`` where it lies in both; the nearest point of one ball where ``p`` lies in the cone from that
    ball's centre through the part of its sphere inside the other ball; else the nearest point of the circle where
    the two spheres meet.

    Near the line between the pins (the top rows of a cloth hung by two corners) the lens is thin: la + lb - gap is
    a small difference of large lengths, and so is the circle's radius. Written as the difference of squares
    (la + lb)^2 - gap^2, computed in float64 from the coordinates' exact differences, it keeps its digits; the rest
    is well conditioned in float32. The cone tests compare angles by a cross product, not distances to the other
    centre, which hardly change along a sphere that crosses the other at a shallow angle."""
    pa = p - a
    pb = p - b
    da_sq = wp.length_sq(pa)
    db_sq = wp.length_sq(pb)
    outside_a = da_sq > la * la
    outside_b = db_sq > lb * lb
    if not outside_a and not outside_b:
        return p
    axis = b - a
    gap_sq = wp.length_sq(wp.vec3d(b) - wp.vec3d(a))  # exact differences of the coordinates
    sum_l = wp.float64(la) + wp.float64(lb)
    gap = wp.sqrt(type(la)(gap_sq))
    if lb + gap <= la:  # ball b lies in ball a (a gap of 0 comes here or to the next test)
        return into_ball(p, b, lb)
    if la + gap <= lb:
        return into_ball(p, a, la)
    thickness = type(la)(sum_l * sum_l - gap_sq) / (la + lb + gap)  # la + lb - gap, with its digits
    u = axis / gap
    # The circle's centre lies at `along` from a towards b, and at along_b from b: la - along and lb - along_b are
    # the lens's half-thicknesses, in proportion to thickness.
    la_minus_along = thickness * (lb - la + gap) / (type(la)(2.0) * gap)
    along = la - la_minus_along
    if thickness <= type(la)(0.0):
        # The spheres touch at one point of the axis (a cloth's edge running straight between its two pins, the
        # lengths' rounding deciding whether they overlap) or are apart: that point, or the nearest of the axis.
        return a + u * wp.clamp(along, type(la)(0.0), gap)
    along_b = lb - thickness * (la - lb + gap) / (type(la)(2.0) * gap)
    radius = wp.sqrt(wp.max(la_minus_along * (la + along), type(la)(0.0)))  # la^2 - along^2
    s = wp.dot(pa, u)
    w = pa - u * s  # p's offset from the axis
    across = wp.length(w)
    # In the half-plane through the axis and p, p is at (s, across) from a and the circle at (along, radius): p
    # lies in a's cone where its angle from the axis is the smaller, and the same seen from b.
    if outside_a and s * radius >= across * along:
        return a + pa * (la / wp.sqrt(da_sq))
    if outside_b and -wp.dot(pb, u) * radius >= across * along_b:
        return b + pb * (lb / wp.sqrt(db_sq))
    if across == type(la)(0.0):
        return a + u * along
    return a + u * along + w * (radius / across)


@wp.func
def within_pins(p: Any, x: wp.array(dtype=Any), a: int, la: Any, b: int, lb: Any):
    """``p`` moved to the nearest point within ``la`` of pin a and, where b >= 0, within ``lb`` of pin b (both at
    once: ``into_two_balls``), the pins read from ``x``."""
    if b < 0:
        return into_ball(p, x[a], la)
    return into_two_balls(p, x[a], la, x[b], lb)


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
