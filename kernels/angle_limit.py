"""The angle limit (warp_verlet/constraints/angle_limit.py): a unilateral bound on how far a cloth bends.

Two forms, each one launch per colour, weighted by inverse mass:

- a *joint* (a, b, c) of three particles along a grid's row or column, or along a rope: the angle between the
  successive sticks a-b and b-c (0 when straight) stays at or under the limit;
- a *hinge* (wing A, wing B, p, q) across a mesh's interior edge p-q: the dihedral angle between its two faces
  (0 when flat) stays within plus or minus the limit.

Each projection is one linearised step on the angle itself, Delta x_i = -C w_i grad_i(theta) / sum_j w_j
|grad_j(theta)|^2 with C the excess over the limit, which is bounded near a full fold, where the cosine's
gradient vanishes; a configuration with no defined direction (a joint folded exactly back on itself, a
hinge with a degenerate face) is left alone. A thread projects ``per_thread`` elements in order from
``first + tid * per_thread``: 1 for a colour, all of them for the overflow colour, whose elements may share
particles.
"""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.kernel
def limit_joints(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    joints: wp.array(dtype=wp.vec3i),
    limit: wp.array(dtype=float),
    first: int,
    per_thread: int,
):
    start = first + wp.tid() * per_thread
    for e in range(start, start + per_thread):
        j = joints[e]
        xa = x[j[0]]
        xb = x[j[1]]
        xc = x[j[2]]
        u = xb - xa
        v = xc - xb
        lu = wp.length(u)
        lv = wp.length(v)
        if lu > type(xa[0])(0.0) and lv > type(xa[0])(0.0):
            uh = u / lu
            vh = v / lv
            cosine = wp.dot(uh, vh)
            sine = wp.length(wp.cross(uh, vh))
            theta = wp.atan2(sine, cosine)
            excess = theta - type(xa[0])(limit[e])
            if excess > type(xa[0])(0.0) and sine > type(xa[0])(1.0e-6):
                # grad theta = -grad cos(theta) / sin(theta); d cos / du = (vh - cos uh) / |u|, likewise for v
                ga = (vh - cosine * uh) / (lu * sine)
                gc = -(uh - cosine * vh) / (lv * sine)
                gb = -(ga + gc)
                wa = type(xa[0])(inv_mass[j[0]])
                wb = type(xa[0])(inv_mass[j[1]])
                wc = type(xa[0])(inv_mass[j[2]])
                norm = wa * wp.dot(ga, ga) + wb * wp.dot(gb, gb) + wc * wp.dot(gc, gc)
                if norm > type(xa[0])(0.0):
                    s = -excess / norm
                    x[j[0]] = xa + ga * (s * wa)
                    x[j[1]] = xb + gb * (s * wb)
                    x[j[2]] = xc + gc * (s * wc)


@wp.func
def hinge_angle(x1: Any, x2: Any, x3: Any, x4: Any):
    """The dihedral angle of the hinge with wings x1, x2 across the edge x3-x4 (0 when flat, signed), and its
    gradients with respect to x1 .. x4 (Bridson, Marino and Fedkiw 2003, "Simulation of clothing with folds and
    wrinkles", section 4); a zero angle and zero gradients when a face is degenerate."""
    e = x4 - x3
    le = wp.length(e)
    n1 = wp.cross(x1 - x3, x1 - x4)
    n2 = wp.cross(x2 - x4, x2 - x3)
    q1 = wp.dot(n1, n1)
    q2 = wp.dot(n2, n2)
    zero = type(x1)(type(x1[0])(0.0))
    if le <= type(x1[0])(0.0) or q1 <= type(x1[0])(0.0) or q2 <= type(x1[0])(0.0):
        return type(x1[0])(0.0), zero, zero, zero, zero
    eh = e / le
    m1 = n1 / q1
    m2 = n2 / q2
    g1 = m1 * le
    g2 = m2 * le
    g3 = m1 * (wp.dot(x1 - x4, eh)) + m2 * (wp.dot(x2 - x4, eh))
    g4 = -(m1 * (wp.dot(x1 - x3, eh)) + m2 * (wp.dot(x2 - x3, eh)))
    n1h = n1 / wp.sqrt(q1)
    n2h = n2 / wp.sqrt(q2)
    theta = wp.atan2(wp.dot(wp.cross(n2h, n1h), eh), wp.dot(n1h, n2h))
    return theta, g1, g2, g3, g4


@wp.kernel
def limit_hinges(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    hinges: wp.array(dtype=wp.vec4i),
    limit: wp.array(dtype=float),
    first: int,
    per_thread: int,
):
    start = first + wp.tid() * per_thread
    for e in range(start, start + per_thread):
        h = hinges[e]
        x1 = x[h[0]]
        x2 = x[h[1]]
        x3 = x[h[2]]
        x4 = x[h[3]]
        theta, g1, g2, g3, g4 = hinge_angle(x1, x2, x3, x4)
        bound = type(x1[0])(limit[e])
        excess = type(x1[0])(0.0)
        if theta > bound:
            excess = theta - bound
        if theta < -bound:
            excess = theta + bound
        if excess != type(x1[0])(0.0):
            w1 = type(x1[0])(inv_mass[h[0]])
            w2 = type(x1[0])(inv_mass[h[1]])
            w3 = type(x1[0])(inv_mass[h[2]])
            w4 = type(x1[0])(inv_mass[h[3]])
            norm = w1 * wp.dot(g1, g1) + w2 * wp.dot(g2, g2) + w3 * wp.dot(g3, g3) + w4 * wp.dot(g4, g4)
            if norm > type(x1[0])(0.0):
                s = -excess / norm
                x[h[0]] = x1 + g1 * (s * w1)
                x[h[1]] = x2 + g2 * (s * w2)
                x[h[2]] = x3 + g3 * (s * w3)
                x[h[3]] = x4 + g4 * (s * w4)


for_positions(limit_joints, arrays=("x",))
for_positions(limit_hinges, arrays=("x",))
