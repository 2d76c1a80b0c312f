"""What every collider kind does to a particle it finds inside: move it out, and apply friction.

Clamping last, once per substep, means no stick correction can push a particle back through a surface in
the same substep (the pitfall of shifting particles through boundaries). Verlet turns the projection into a
velocity change by itself: the move is part of x - x_prev.

Friction scales the tangential part of the implicit velocity v = x - x_prev of a particle in contact by
(1 - friction). In the summed-form state (integrate.py), x_prev = x_inertial - delta, so removing
friction * v_t from v means subtracting it from delta.

A collider's thickness is added to its surface: the cloth rests that far outside the render-visible
surface, so the two never z-fight. Each kind's kernel (collide_sphere.py, collide_plane.py) finds the depth
and the outward normal; this module is the response they share.
"""

from typing import Any

import warp as wp

from .positions import scaled


@wp.func
def project_out(
    i: int,
    xi: Any,
    normal: Any,
    depth: Any,
    friction: float,
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
):
    """Move xi out by depth along normal, apply friction to its implicit velocity, return the new position."""
    xi = xi + normal * depth
    if friction > 0.0:
        v = xi - (x_inertial[i] - delta[i])
        tangential = v - normal * wp.dot(v, normal)
        delta[i] = delta[i] - scaled(tangential, friction)
    return xi
