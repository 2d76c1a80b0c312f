"""Aerodynamic drag and lift on each face of a cloth, from the air's velocity relative to the face.

One thread per face (a triangle, a quad or any polygon of k corners, as the cloth's faces come):

- its velocity v_face is the mean of its corners' Verlet velocities (x - x_prev) / dt_prev, where in the
  summed form (integrate.py) x - x_prev = delta + (x - x_inertial);
- its vector area S = 1/2 sum_k (x_k - x_0) x (x_k+1 - x_0) gives the area A = |S| and the unit normal
  n = S / A (exact for a flat polygon; for a bent quad, the area it presents to the flow);
- the air's velocity v_air at the centroid is the keyframed velocity at the device clock plus the gusts, a sum
  of seeded sinusoids g(x, t) = sum_m d_m sin(K_m . x - w_m t + phi_m) (warp_verlet/core/aerodynamics.py
  draws d, K, w and phi from the seed);
- with v = v_air - v_face, rho the density and C_d, C_l the cloth's coefficients,

      drag  F_d = 1/2 rho C_d A |v| (v . n) n
      lift  F_l = 1/2 rho C_l A |v|^2 cos(theta) sin(theta) l
                = 1/2 rho C_l A ( |v| (v . n) n - (v . n)^2 v / |v| )

  where theta is the angle between v and n and l = (n - cos(theta) v/|v|) / sin(theta) is the unit vector
  across v in the plane of v and n, on n's side (NvCloth's wind model; Keckeisen et al. 2004). Drag is the
  pressure on the face: along its normal, proportional to the area it presents to the flow, so a face edge-on
  to the wind feels none. Lift vanishes edge-on and face-on, and peaks at 45 degrees. Neither depends on
  which way n points.
- An explicit force of the velocity can overshoot: a light face in a fast flow would be pushed past the air's
  own velocity within one step, and back, and grow. So the force is scaled by
  s = min(1, sigma A0 / (1/2 rho (C_d + C_l) |v| dt A)), where sigma is the face's lightest areal density
  (kg/m^2, of the corner that its share accelerates most), A0 its rest area (their product built on the host)
  and A its area now: the normal velocity the force changes in one step, 1/2 rho (C_d + C_l) |v| |v . n| dt
  (A / A0) / sigma, is then at most |v . n|, so the face never overtakes the air. Where it does not bind (|v|
  below sigma A0 / (1/2 rho (C_d + C_l) dt A)) the force is exact. The area now counts because a stretched
  face presents more area to the flow while its corners keep their mass: bounded by the rest area alone, a
  light strip stretched many times its width in a 17 m/s flow took more force each step and went to NaN.

Each face writes its force divided by its corner count to its own slot of ``share``; ``air_acceleration``
gathers a particle's shares over its faces in a fixed order (a CSR built on the host), so the sum does not
depend on thread order. A torn face (beside a stick whose weight is 0) feels no force.
"""

from typing import Any

import warp as wp

from .collide_response import keyframed
from .positions import for_positions


@wp.kernel
def face_forces(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    delta: wp.array(dtype=Any),
    face_start: wp.array(dtype=int),
    face_corner: wp.array(dtype=int),
    face_params: wp.array(dtype=wp.vec3),  # (C_d, C_l, lightest areal density x rest area, kg)
    side_entry: wp.array(dtype=int),  # per corner, the tear entry of the side to the next corner (-1: none); empty: no tearing
    stick_weight: wp.array(dtype=float),
    clock: wp.array(dtype=wp.float64),  # empty: the air does not change with time
    key_times: wp.array(dtype=float),
    key_values: wp.array(dtype=wp.vec3),
    gust_direction: wp.array(dtype=wp.vec3),  # per mode, m/s; empty: no gusts
    gust_wave: wp.array(dtype=wp.vec3),  # per mode, rad/m
    gust_timing: wp.array(dtype=wp.vec2),  # per mode, (rad/s, phase rad)
    density: float,
    inv_dt_prev: Any,
    dt: Any,
    share: wp.array(dtype=Any),
):
    f = wp.tid()
    first = face_start[f]
    end = face_start[f + 1]
    zero = x[face_corner[first]] * type(dt)(0.0)
    if side_entry.shape[0] > 0:
        for k in range(first, end):
            e = side_entry[k]
            if e >= 0:
                if stick_weight[e] == 0.0:
                    share[f] = zero
                    return
    corners = type(dt)(float(end - first))
    # One pass over the corners, relative to the first (so that float32 keeps the small differences of a face
    # far from the origin): the sum of (x_k - x_0) x (x_k+1 - x_0) is twice the vector area, the closing side
    # adding nothing.
    origin = x[face_corner[first]]
    centre = zero
    velocity = zero
    area_vector = zero
    previous = zero
    for k in range(first, end):
        p = face_corner[k]
        xp = x[p]
        r = xp - origin
        centre = centre + r
        velocity = velocity + (delta[p] + (xp - x_inertial[p]))
        area_vector = area_vector + wp.cross(previous, r)
        previous = r
    centre = origin + centre / corners
    velocity = velocity * (inv_dt_prev / corners)
    area_vector = area_vector * type(dt)(0.5)
    area = wp.length(area_vector)

    t = float(0.0)
    if clock.shape[0] > 0:
        t = float(clock[0])
    air = keyframed(t, 0, key_times.shape[0] - 1, key_times, key_values)
    if gust_direction.shape[0] > 0:
        where = wp.vec3(float(centre[0]), float(centre[1]), float(centre[2]))
        for m in range(gust_direction.shape[0]):
            timing = gust_timing[m]
            air = air + gust_direction[m] * wp.sin(wp.dot(gust_wave[m], where) - timing[0] * t + timing[1])
    relative = x.dtype(air) - velocity
    speed = wp.length(relative)
    if area == type(area)(0.0) or speed == type(speed)(0.0):
        share[f] = zero
        return
    n = area_vector / area
    normal_speed = wp.dot(relative, n)
    params = face_params[f]
    cd = type(dt)(params[0])
    cl = type(dt)(params[1])
    pressure = type(dt)(0.5) * type(dt)(density) * area  # 1/2 rho A
    drag = n * (cd * speed * normal_speed)
    lift = (n * (speed * normal_speed) - relative * (normal_speed * normal_speed / speed)) * cl
    # The overshoot limit (see the module's docstring): the largest normal velocity change in one step is at most
    # the normal relative velocity itself.
    rate = type(dt)(0.5) * type(dt)(density) * (cd + cl) * speed * dt * area
    scale = type(dt)(1.0)
    rest_mass = type(dt)(params[2])  # sigma A0, kg
    if rate > rest_mass:
        scale = rest_mass / rate
    share[f] = (drag + lift) * (pressure * scale / corners)


for_positions(face_forces, arrays=("x", "x_inertial", "delta", "share"), scalars=("inv_dt_prev", "dt"))


@wp.func
def air_acceleration(
    i: int,
    inv_mass: float,
    share: wp.array(dtype=Any),
    particle_face_start: wp.array(dtype=int),
    particle_face: wp.array(dtype=int),
):
    """Particle i's acceleration from the air: its faces' shares, summed in the CSR's fixed order, over its mass."""
    total = share[0] * type(share[0][0])(0.0)
    for k in range(particle_face_start[i], particle_face_start[i + 1]):
        total = total + share[particle_face[k]]
    return total * type(share[0][0])(inv_mass)
