"""Verlet integration in summed form: positions only, no stored velocity.

The textbook update is x_new = x + d (x - x_prev) + a dt^2. In exact arithmetic that is the same as keeping,
instead of x_prev, the last step's position increment ``delta`` = x_inertial - x_prev together with the
position the step predicted, ``x_inertial``; then x - x_prev = delta + (x - x_inertial), where
x - x_inertial is what the constraints (and colliders) moved the particle since. This *summed form*
(Hairer, Lubich & Wanner, Geometric Numerical Integration, 2nd ed., VIII.5) keeps the rounding of the
large coordinate x out of the implicit velocity: with x_prev stored, each step's rounding of x (half an ulp
of |x|) becomes a velocity error that grows quadratically with the step count; here it does not, and a
free fall stays within a few ulps of x0 + a t^2 / 2 (see tests/test_integrate.py).

Variable time steps use the time-step-corrected form, exact for constant acceleration. With h = dt and
h' = dt_prev the host passes

    velocity_scale = drag * min(h / h', max_dt_ratio)
    accel_offset   = a * h * (h + h') / 2

For x(t) = x0 + v t + a t^2 / 2: x - x_prev = v h' - a h'^2 / 2; scaled by h / h' it is v h - a h h' / 2, and
adding a h (h + h') / 2 leaves exactly v h + a h^2 / 2. With h = h' this is the textbook a h^2. (The seed
article keeps a h^2 with a variable step, which is exact only when the step is constant.)
"""

from typing import Any

import warp as wp

from .aerodynamics import air_acceleration
from .positions import for_positions
from .tether import PINNED_ROW, tethered


@wp.kernel
def verlet_start(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    accel: Any,
    dt: Any,
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
):
    """Exact start for constant acceleration: x_prev = x0 - v0 dt + a dt^2 / 2, so the first step lands on
    x0 + v0 dt + a dt^2 / 2. ``delta`` holds the initial velocity v0 (m/s) on entry (State.start_velocity, put
    there by the solver just before) and leaves as delta = x0 - x_prev, with x_inertial = x0. ``accel`` and
    ``dt`` come in the position type: in float64 a float32 dt would put a relative error of 6e-8 into every
    step."""
    i = wp.tid()
    x_inertial[i] = x[i]
    if inv_mass[i] == 0.0:
        delta[i] = type(accel)(0.0)  # pinned: no implicit velocity
    else:
        delta[i] = delta[i] * dt - accel * (type(dt)(0.5) * dt * dt)


@wp.func
def implicit_move(i: int, x: wp.array(dtype=Any), x_inertial: wp.array(dtype=Any), delta: wp.array(dtype=Any)):
    """x - x_prev, with the constraints' moves since the last step folded in."""
    return delta[i] + (x[i] - x_inertial[i])


@wp.func
def take_step(i: int, x: wp.array(dtype=Any), x_inertial: wp.array(dtype=Any), delta: wp.array(dtype=Any), step: Any):
    """Move particle i by ``step``, which is both its prediction and its next increment."""
    xi = x[i] + step
    x[i] = xi
    x_inertial[i] = xi
    delta[i] = step


@wp.kernel
def verlet_step(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    velocity_scale: Any,
    accel_offset: Any,
):
    i = wp.tid()
    if inv_mass[i] == 0.0:
        return  # pins never move
    take_step(i, x, x_inertial, delta, implicit_move(i, x, x_inertial, delta) * velocity_scale + accel_offset)


@wp.kernel
def verlet_step_tethered(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    velocity_scale: Any,
    accel_offset: Any,
    pin: wp.array2d(dtype=int),
    length: wp.array2d(dtype=float),
):
    """verlet_step, then the first sweep's tether pass (kernels/tether.py), launched over a tether table whose
    row i is particle i for every particle: a pin's row says so in its first slot (PINNED_ROW), so no weight is
    read, and the row index is the particle, so no index is either (a load every other one waits on). The pass
    reads only pins, which no thread here moves, so the pair is bit for bit the two launches one after the
    other, and the position makes one trip through memory instead of two."""
    i = wp.tid()
    if pin[i, 0] == PINNED_ROW:
        return  # pins never move
    step = implicit_move(i, x, x_inertial, delta) * velocity_scale + accel_offset
    xi = x[i] + step
    x_inertial[i] = xi
    delta[i] = step
    x[i] = tethered(xi, x, pin, length, i)


@wp.kernel
def verlet_step_air(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    velocity_scale: Any,
    accel_offset: Any,
    share: wp.array(dtype=Any),
    particle_face_start: wp.array(dtype=int),
    particle_face: wp.array(dtype=int),
    force_scale: Any,
):
    """verlet_step with each particle's own acceleration from the air (kernels/aerodynamics.py) added to the
    uniform one: ``force_scale`` is dt (dt + dt_prev) / 2, the factor ``accel_offset`` has."""
    i = wp.tid()
    if inv_mass[i] == 0.0:
        return  # pins never move
    air = air_acceleration(i, inv_mass[i], share, particle_face_start, particle_face)
    take_step(i, x, x_inertial, delta,
              implicit_move(i, x, x_inertial, delta) * velocity_scale + accel_offset + air * force_scale)


for_positions(verlet_start, arrays=("x", "x_inertial", "delta"), vectors=("accel",), scalars=("dt",))
for_positions(verlet_step, arrays=("x", "x_inertial", "delta"), vectors=("accel_offset",), scalars=("velocity_scale",))
for_positions(verlet_step_tethered, arrays=("x", "x_inertial", "delta"), vectors=("accel_offset",),
              scalars=("velocity_scale",))
for_positions(verlet_step_air, arrays=("x", "x_inertial", "delta", "share"), vectors=("accel_offset",),
              scalars=("velocity_scale", "force_scale"))
