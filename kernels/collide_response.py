"""What every collider kind does to a particle it finds inside: move it out, and apply friction.

Clamping last, once per substep, means no stick correction can push a particle back through a surface in
the same substep (the pitfall of shifting particles through boundaries). Verlet turns the projection into a
velocity change by itself: the move is part of x - x_prev.

Friction is Coulomb's, at the position level (Macklin et al. 2014, "Unified Particle Physics", section 6): a
particle pushed out by d_n in a substep has moved tangentially by s_t over that substep (from x_prev, the
tangential part of x - x_prev after the push). When |s_t| < mu_s d_n it sticks, and s_t is taken off its
position; otherwise it slides, and s_t is shortened by mu_k d_n. On a plane d_n is g cos(theta) dt^2 per
substep and the step's speed change g sin(theta) dt^2, so the particle sticks when tan(theta) < mu_s and
otherwise slides at g (sin(theta) - mu_k cos(theta)), whatever the substeps. Moving the position (not the
implicit velocity) is what makes a stuck particle stay put: x_prev is kept, so Verlet's next step sees the
removed displacement as removed velocity too. In the summed-form state (integrate.py), x_prev = x_inertial -
delta.

A collider's thickness is added to its surface: the cloth rests that far outside the render-visible
surface, so the two never z-fight. Each kind's kernel (collide_sphere.py, collide_plane.py) finds the depth
and the outward normal; this module is the response they share.
"""

from typing import Any

import warp as wp


@wp.func
def coulomb_removed(slip: Any, depth: Any, friction: wp.vec2):
    """Coulomb's law at the position level: the fraction of a tangential move ``slip`` long that friction takes
    off, for a normal correction ``depth`` and ``friction`` = (mu_k, mu_s): all of it while slip < mu_s depth (it
    sticks), else mu_k depth / slip of it (it slides)."""
    removed = type(depth)(1.0)
    if slip >= depth * type(depth)(friction[1]):  # slip >= mu_s depth > 0
        removed = wp.min(depth * type(depth)(friction[0]) / slip, type(depth)(1.0))
    return removed


@wp.func
def key_interval(t: float, first: int, last: int, key_times: wp.array(dtype=float)):
    """Where time ``t`` falls among keys ``first`` .. ``last``: (k, f), between keys k and k + 1 at fraction f;
    k = first - 1 before (or at) the first key, k = last at or after the last, both held."""
    k = first - 1
    f = float(0.0)
    if t >= key_times[last]:
        k = last
    elif t > key_times[first]:
        for j in range(first, last):
            t0 = key_times[j]
            t1 = key_times[j + 1]
            if t >= t0 and t < t1:
                k = j
                f = (t - t0) / (t1 - t0)
    return k, f


@wp.func
def keyframed(t: float, first: int, last: int, key_times: wp.array(dtype=float), key_values: wp.array(dtype=wp.vec3)):
    """A collider's keyframed vec3 at time ``t`` (its keys ``first`` .. ``last``): linear between keyframes, held
    at the first before it and at the last after it."""
    k, f = key_interval(t, first, last, key_times)
    v = key_values[first]
    if k >= last:
        v = key_values[last]
    elif k >= first:
        v = wp.lerp(key_values[k], key_values[k + 1], f)
    return v


@wp.func
def project_out_moving(
    i: int,
    xi: Any,
    normal: Any,
    depth: Any,
    friction: wp.vec2,
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    surface_step: Any,
    pushes: wp.array(dtype=wp.vec3),
):
    """``project_out`` against a moving surface: friction acts on the particle's displacement over the substep
    relative to ``surface_step``, how far the surface point it touches moved over the same substep, so that a
    particle stuck to a moving body is carried along with it. Where ``pushes`` has an entry a particle, the push
    out (normal x depth) is added to it: a stage that needs the contact's normal (launches.clamp_noting_normals)
    reads it there, since friction tilts the particle's whole move off the normal."""
    push = normal * depth
    xi = xi + push
    if pushes.shape[0] > 0:
        pushes[i] = pushes[i] + wp.vec3(float(push[0]), float(push[1]), float(push[2]))
    if friction[1] > 0.0:  # mu_s >= mu_k, so no static friction means no friction (and the frictionless bits)
        step = xi - (x_inertial[i] - delta[i]) - surface_step
        tangential = step - normal * wp.dot(step, normal)
        xi = xi - tangential * coulomb_removed(wp.length(tangential), depth, friction)
    return xi


@wp.func
def project_out(
    i: int,
    xi: Any,
    normal: Any,
    depth: Any,
    friction: wp.vec2,
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    pushes: wp.array(dtype=wp.vec3),
):
    """Move xi out by depth along normal, apply Coulomb friction (``friction`` = (mu_k, mu_s), mu_s >= mu_k) to
    its tangential displacement over the substep, return the new position: ``project_out_moving`` against a
    surface that stays put."""
    return project_out_moving(i, xi, normal, depth, friction, x_inertial, delta, type(xi)(0.0), pushes)
