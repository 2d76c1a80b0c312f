"""The global correction (warp_verlet/core/global_solve.py): Gauss-Newton steps on stiff sticks with contact inside
the operator, solved by conjugate gradients with a fixed iteration count (so a frame can be captured).

The step minimises, from the Verlet prediction x~,

    E(x) = 1/2 sum_i m_i / h^2 |x_i - x~_i|^2 + 1/2 sum_s k_s (|x_b - x_a| - L_s)^2

with the matrix H = M / h^2 + sum_s k_s (J_s^T J_s + G_s) + sum_contacts kc_i n_i n_i^T, where J_s is the
stick's unit direction n_s (with the sign of each end), G_s the stiffness across a stretched stick (see
``sideways``), and n_i the normal a collider pushed particle i out along. The contact term makes the particle stiff along its normal only: the step cannot push it back into the
collider, and it slides freely along the surface.

Every per-particle sum is a gather over the particle's incident sticks, in the fixed order of a CSR table built
on the host, and every dot product is a fixed two-pass reduction: no float atomics, so a device gives the same
result every run: the kernels that touch every particle also sum their chunk's share of a dot product, and
``sum_chunks`` adds the chunks level by level in index order. The conjugate-gradient vectors are float32 (a correction, not a position); positions keep
their own type.
"""

from typing import Any

import warp as wp

from .positions import for_positions



@wp.kernel
def stick_directions(
    x: wp.array(dtype=Any),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    weight: wp.array(dtype=float),
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
):
    """Each stick's unit direction a -> b and its stretch |x_b - x_a| - L (0 for a torn stick, weight 0)."""
    s = wp.tid()
    e = ends[s]
    d = x[e[1]] - x[e[0]]
    length = wp.length(d)
    if weight[s] == 0.0 or length == type(length)(0.0):
        direction[s] = wp.vec3(0.0)
        residual[s] = 0.0
        return
    direction[s] = wp.vec3(float(d[0] / length), float(d[1] / length), float(d[2] / length))
    residual[s] = float(length - type(length)(rest[s]))


@wp.kernel
def contact_normals(
    x: wp.array(dtype=Any),
    x_before: wp.array(dtype=Any),
    normal: wp.array(dtype=wp.vec3),
):
    """The direction the colliders moved each particle (0 where none did): the contact normal of the step."""
    i = wp.tid()
    d = x[i] - x_before[i]
    length = wp.length(d)
    if length > type(length)(0.0):
        normal[i] = wp.vec3(float(d[0] / length), float(d[1] / length), float(d[2] / length))
    else:
        normal[i] = wp.vec3(0.0)


@wp.kernel
def assemble(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    inv_h2: float,
    stiffness: float,
    contact_scale: float,
    offsets: wp.array(dtype=int),
    incident: wp.array(dtype=int),
    rest: wp.array(dtype=float),
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
    contact: wp.array(dtype=wp.vec3),
    rhs: wp.array(dtype=wp.vec3),
    diagonal_inverse: wp.array(dtype=wp.mat33),
    contact_stiffness: wp.array(dtype=float),
):
    """Per particle: the right-hand side -grad E and the inverse of H's 3x3 diagonal block (the Jacobi
    preconditioner), and the contact's stiffness. ``incident`` holds 2 s + end for each stick s at the particle
    (end 0: the particle is a, end 1: b), in the CSR order of ``offsets``. A pinned particle gets zeros: it never
    moves."""
    i = wp.tid()
    w = inv_mass[i]
    if w == 0.0:
        rhs[i] = wp.vec3(0.0)
        diagonal_inverse[i] = wp.mat33(0.0)
        contact_stiffness[i] = 0.0
        return
    m_h2 = inv_h2 / w
    lag = x[i] - x_inertial[i]
    g = wp.vec3(float(lag[0]), float(lag[1]), float(lag[2])) * m_h2
    n_c = contact[i]
    # A contact's push is not an error of inertia: only the lag along the surface is pulled back.
    g = g - n_c * wp.dot(g, n_c)
    block = wp.identity(3, dtype=float) * m_h2
    for t in range(offsets[i], offsets[i + 1]):
        code = incident[t]
        s = code // 2
        n = direction[s]
        if code % 2 == 0:
            g = g - n * (stiffness * residual[s])
        else:
            g = g + n * (stiffness * residual[s])
        across = stiffness * sideways(rest[s], residual[s])
        block = block + wp.outer(n, n) * (stiffness - across) + wp.identity(3, dtype=float) * across
    kc = contact_scale * (block[0, 0] + block[1, 1] + block[2, 2]) * wp.dot(n_c, n_c)
    block = block + wp.outer(n_c, n_c) * kc
    rhs[i] = -g
    diagonal_inverse[i] = wp.inverse(block)
    contact_stiffness[i] = kc


@wp.func
def sideways(rest: float, residual: float):
    """The stiffness across a stretched stick, per unit of its stiffness along it: (L - L0) / L, the part of the
    spring's Hessian that Gauss-Newton drops. Without it a flat cloth has no stiffness out of its plane but its
    mass, and a step would throw a particle far along any small force there. A slack stick gets none (its true
    value is negative: keeping the matrix positive definite)."""
    return wp.max(residual, 0.0) / (rest + residual)


@wp.func
def operator_row(
    i: int,
    p: wp.array(dtype=wp.vec3),
    inv_mass: wp.array(dtype=float),
    inv_h2: float,
    stiffness: float,
    offsets: wp.array(dtype=int),
    incident: wp.array(dtype=int),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
    contact: wp.array(dtype=wp.vec3),
    contact_stiffness: wp.array(dtype=float),
):
    """Row i of H p, gathered over the particle's sticks (0 for a pin)."""
    w = inv_mass[i]
    if w == 0.0:
        return wp.vec3(0.0)
    pi = p[i]
    out = pi * (inv_h2 / w)
    for t in range(offsets[i], offsets[i + 1]):
        code = incident[t]
        s = code // 2
        e = ends[s]
        other = e[1]
        if code % 2 == 1:
            other = e[0]
        n = direction[s]
        d = pi - p[other]
        across = stiffness * sideways(rest[s], residual[s])
        out = out + n * ((stiffness - across) * wp.dot(n, d)) + d * across
    n_c = contact[i]
    return out + n_c * (contact_stiffness[i] * wp.dot(n_c, pi))


# The conjugate-gradient scalars: r.z, p.Hp, the next r.z, and the step lengths alpha and beta.
RZ, PQ, RZ_NEW, ALPHA, BETA = 0, 1, 2, 3, 4


@wp.kernel
def cg_start(
    rhs: wp.array(dtype=wp.vec3),
    diagonal_inverse: wp.array(dtype=wp.mat33),
    count: int,
    chunk: int,
    r: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    dx: wp.array(dtype=wp.vec3),
    partial: wp.array(dtype=wp.float64),
):
    """r = rhs, z = p = D^-1 r, dx = 0; thread t also sums r.z over its chunk of ``chunk`` particles."""
    t = wp.tid()
    acc = wp.float64(0.0)
    for i in range(t * chunk, wp.min(t * chunk + chunk, count)):
        ri = rhs[i]
        zi = diagonal_inverse[i] * ri
        r[i] = ri
        z[i] = zi
        p[i] = zi
        dx[i] = wp.vec3(0.0)
        acc += wp.float64(wp.dot(ri, zi))
    partial[t] = acc


@wp.kernel
def cg_operator(
    p: wp.array(dtype=wp.vec3),
    inv_mass: wp.array(dtype=float),
    inv_h2: float,
    stiffness: float,
    offsets: wp.array(dtype=int),
    incident: wp.array(dtype=int),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
    contact: wp.array(dtype=wp.vec3),
    contact_stiffness: wp.array(dtype=float),
    count: int,
    chunk: int,
    q: wp.array(dtype=wp.vec3),
    partial: wp.array(dtype=wp.float64),
):
    """q = H p over thread t's chunk, and the chunk's sum of p.q."""
    t = wp.tid()
    acc = wp.float64(0.0)
    for i in range(t * chunk, wp.min(t * chunk + chunk, count)):
        qi = operator_row(i, p, inv_mass, inv_h2, stiffness, offsets, incident, ends, rest, direction, residual,
                          contact, contact_stiffness)
        q[i] = qi
        acc += wp.float64(wp.dot(p[i], qi))
    partial[t] = acc


@wp.kernel
def cg_advance(
    scalars: wp.array(dtype=wp.float64),
    p: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    diagonal_inverse: wp.array(dtype=wp.mat33),
    count: int,
    chunk: int,
    dx: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    partial: wp.array(dtype=wp.float64),
):
    """dx += alpha p, r -= alpha q, z = D^-1 r over thread t's chunk, and the chunk's sum of the new r.z."""
    t = wp.tid()
    alpha = float(scalars[ALPHA])
    acc = wp.float64(0.0)
    for i in range(t * chunk, wp.min(t * chunk + chunk, count)):
        dx[i] = dx[i] + p[i] * alpha
        ri = r[i] - q[i] * alpha
        zi = diagonal_inverse[i] * ri
        r[i] = ri
        z[i] = zi
        acc += wp.float64(wp.dot(ri, zi))
    partial[t] = acc


@wp.kernel
def cg_direction(scalars: wp.array(dtype=wp.float64), z: wp.array(dtype=wp.vec3), p: wp.array(dtype=wp.vec3)):
    """p = z + beta p."""
    i = wp.tid()
    p[i] = z[i] + p[i] * float(scalars[BETA])


@wp.kernel
def sum_chunks(values: wp.array(dtype=wp.float64), count: int, chunk: int, sums: wp.array(dtype=wp.float64)):
    """One level of a fixed-order sum: thread t adds its chunk of ``values`` in index order."""
    t = wp.tid()
    acc = wp.float64(0.0)
    for i in range(t * chunk, wp.min(t * chunk + chunk, count)):
        acc += values[i]
    sums[t] = acc


@wp.kernel
def cg_scalars(total: wp.array(dtype=wp.float64), stage: int, scalars: wp.array(dtype=wp.float64)):
    """Store a finished sum and derive the step lengths. ``stage`` 0: the first r.z; 1: p.Hp, giving alpha; 2:
    the next r.z, giving beta (and the next iteration's r.z). A zero denominator (the residual is gone) gives a
    zero step, never a division by zero."""
    value = total[0]
    zero = wp.float64(0.0)
    if stage == 0:
        scalars[RZ] = value
    elif stage == 1:
        scalars[PQ] = value
        alpha = zero
        if value > zero:
            alpha = scalars[RZ] / value
        scalars[ALPHA] = alpha
    else:
        beta = zero
        if scalars[RZ] > zero:
            beta = value / scalars[RZ]
        scalars[BETA] = beta
        scalars[RZ] = value


@wp.kernel
def apply_correction(x: wp.array(dtype=Any), dx: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    d = dx[i]
    x[i] = x[i] + type(x[i])(type(x[i][0])(d[0]), type(x[i][0])(d[1]), type(x[i][0])(d[2]))


for_positions(stick_directions, arrays=("x",))
for_positions(contact_normals, arrays=("x", "x_before"))
for_positions(assemble, arrays=("x", "x_inertial"))
for_positions(apply_correction, arrays=("x",))
