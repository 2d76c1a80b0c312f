"""Sphere colliders: particles are projected out of spheres (the response: collide_response.py); a moving
sphere's centre is placed on the device clock first."""

from typing import Any

import warp as wp

from .collide_response import keyframed, project_out
from .positions import for_positions


@wp.kernel
def collide_spheres(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    centres: wp.array(dtype=wp.vec3),
    radii: wp.array(dtype=float),
    friction: wp.array(dtype=wp.vec2),  # (mu_k, mu_s) per collider
    pushes: wp.array(dtype=wp.vec3),  # empty, or each particle's pushes summed (collide_response.py)
    first: int,  # the first particle (a CPU thread clamps a run of them from here)
):
    """``radii`` already include each sphere's thickness."""
    i = first + wp.tid()
    if inv_mass[i] == 0.0:
        return
    xi = x[i]
    for s in range(centres.shape[0]):
        d = xi - x.dtype(centres[s])
        distance = wp.length(d)
        depth = type(distance)(radii[s]) - distance
        if depth > type(depth)(0.0):
            # A particle exactly at the centre has no outward direction: push it up (+Y), a fixed choice so
            # that the result stays deterministic.
            n = x.dtype(wp.vec3(0.0, 1.0, 0.0))
            if distance > type(distance)(1.0e-12):
                n = d / distance
            xi = project_out(i, xi, n, depth, friction[s], x_inertial, delta, pushes)
    x[i] = xi


for_positions(collide_spheres, arrays=("x", "x_inertial", "delta"))


@wp.kernel
def advance_clock(clock: wp.array(dtype=wp.float64), dt: wp.float64):
    """Simulated time on the device, so that a captured CUDA graph replays moving colliders correctly."""
    clock[0] = clock[0] + dt


@wp.kernel
def place_spheres(
    clock: wp.array(dtype=wp.float64),
    key_start: wp.array(dtype=int),
    key_times: wp.array(dtype=float),
    key_centres: wp.array(dtype=wp.vec3),
    centres: wp.array(dtype=wp.vec3),
):
    """Centre of sphere s at the current time: linear between keyframes, held before the first and after
    the last. A sphere of one keyframe is left where it is: it starts there, and a live session may have
    dragged it."""
    s = wp.tid()
    t = float(clock[0])
    first = key_start[s]
    last = key_start[s + 1] - 1
    if last == first:
        return
    centres[s] = keyframed(t, first, last, key_times, key_centres)
