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

from .positions import for_positions, shifted, to_vec3



@wp.kernel
def stick_directions(
    x: wp.array(dtype=Any),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    weight: wp.array(dtype=float),
    compliance: wp.array(dtype=float),
    rigid: float,
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
):
    """Each stick's unit direction a -> b, its stretch |x_b - x_a| - L, and its spring's stiffness (N/m): ``rigid``
    for a rigid stick, 1 / compliance for a soft one (never stiffer than rigid), 0 for a torn one."""
    s = wp.tid()
    e = ends[s]
    d = x[e[1]] - x[e[0]]
    length = wp.length(d)
    if weight[s] == 0.0 or length == type(length)(0.0):
        direction[s] = wp.vec3(0.0)
        residual[s] = 0.0
        stiffness[s] = 0.0
        return
    direction[s] = to_vec3(d / length)
    residual[s] = float(length - type(length)(rest[s]))
    k = rigid
    if compliance[s] > 0.0:
        k = wp.min(rigid, 1.0 / compliance[s])
    stiffness[s] = k


@wp.kernel
def copy_positions(x: wp.array(dtype=Any), copy: wp.array(dtype=Any)):
    """A kernel, not ``wp.copy``: a CPU frame capture replays kernels only."""
    i = wp.tid()
    copy[i] = x[i]


@wp.kernel
def zero_vectors(v: wp.array(dtype=wp.vec3)):
    """A kernel, not ``array.zero_()``: a CPU frame capture replays kernels only."""
    i = wp.tid()
    v[i] = wp.vec3(0.0)


@wp.kernel
def contact_normals(
    x: wp.array(dtype=Any),
    x_before: wp.array(dtype=Any),
    pushes: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
):
    """The direction the colliders pushed each particle (0 where none did): the contact normal of the step. Their
    pushes summed where ``pushes`` has entries (a scene with friction, which tilts the move), else their move
    (without friction, the push itself)."""
    i = wp.tid()
    d = x[i] - x_before[i]
    if pushes.shape[0] > 0:
        d = x.dtype(pushes[i])
    length = wp.length(d)
    if length > type(length)(0.0):
        normal[i] = to_vec3(d / length)
    else:
        normal[i] = wp.vec3(0.0)


@wp.kernel
def assemble(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    inv_h2: float,
    stiffness: wp.array(dtype=float),
    contact_scale: float,
    offsets: wp.array(dtype=int),
    incident: wp.array(dtype=int),
    rest: wp.array(dtype=float),
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
    contact: wp.array(dtype=wp.vec3),
    rhs: wp.array(dtype=wp.vec3),
    mass_h2: wp.array(dtype=float),
    extra: wp.array(dtype=wp.mat33),
):
    """Per particle of the cloth: the right-hand side -grad E, its m / h^2 (0 for a pin, which never moves), and
    its contact block kc n n^T. ``incident`` holds 2 s + end for each stick s at the particle (end 0: the
    particle is a, end 1: b), in the CSR order of ``offsets``."""
    i = wp.tid()
    w = inv_mass[i]
    if w == 0.0:
        rhs[i] = wp.vec3(0.0)
        mass_h2[i] = 0.0
        extra[i] = wp.mat33(0.0)
        return
    m_h2 = inv_h2 / w
    g = to_vec3(x[i] - x_inertial[i]) * m_h2
    n_c = contact[i]
    # A contact's push is not an error of inertia: only the lag along the surface is pulled back.
    g = g - n_c * wp.dot(g, n_c)
    diagonal = m_h2
    for t in range(offsets[i], offsets[i + 1]):
        code = incident[t]
        s = code // 2
        n = direction[s]
        k = stiffness[s]
        if code % 2 == 0:
            g = g - n * (k * residual[s])
        else:
            g = g + n * (k * residual[s])
        diagonal = diagonal + k * (1.0 + 2.0 * sideways(rest[s], residual[s])) / 3.0
    rhs[i] = -g
    mass_h2[i] = m_h2
    extra[i] = wp.outer(n_c, n_c) * (contact_scale * 3.0 * diagonal)


@wp.func
def sideways(rest: float, residual: float):
    """The stiffness across a stretched stick, per unit of its stiffness along it: (L - L0) / L, the part of the
    spring's Hessian that Gauss-Newton drops. Without it a flat cloth has no stiffness out of its plane but its
    mass, and a step would throw a particle far along any small force there. A slack stick gets none (its true
    value is negative: keeping the matrix positive definite).

    The slack case returns before dividing: a stick that a collider folds to nearly a point (two particles
    clamped onto one spot of the ground) has a length below float32's resolution of its rest length, so
    ``rest + residual`` is exactly 0, and 0 / 0 would poison the whole solve with NaN."""
    if residual > 0.0:
        return residual / (rest + residual)
    return float(0.0)


@wp.func
def spring_block(n: wp.vec3, k: float, rest: float, residual: float):
    """A stick spring's 3 x 3 Hessian block: k along its direction n, k (L - L0) / L across it when stretched."""
    across = k * sideways(rest, residual)
    return wp.outer(n, n) * (k - across) + wp.identity(3, dtype=float) * across


@wp.func
def spring_times(n: wp.vec3, k: float, rest: float, residual: float, d: wp.vec3):
    """``spring_block(n, k, rest, residual) * d``, without forming the block (the operator's inner loop)."""
    across = k * sideways(rest, residual)
    return n * ((k - across) * wp.dot(n, d)) + d * across


@wp.func
def other_end(code: int, ends: wp.array(dtype=wp.vec2i)):
    """The particle at the far end of incidence entry ``code`` (2 s + the near end's index in the stick)."""
    e = ends[code // 2]
    if code % 2 == 1:
        return e[0]
    return e[1]


@wp.func
def operator_row(
    i: int,
    p: wp.array(dtype=wp.vec3),
    mass_h2: wp.array(dtype=float),
    extra: wp.array(dtype=wp.mat33),
    stiffness: wp.array(dtype=float),
    offsets: wp.array(dtype=int),
    incident: wp.array(dtype=int),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
):
    """Row i of H p on one level, gathered over the node's sticks (0 for a pin)."""
    m_h2 = mass_h2[i]
    if m_h2 == 0.0:
        return wp.vec3(0.0)
    pi = p[i]
    out = pi * m_h2 + extra[i] * pi
    for t in range(offsets[i], offsets[i + 1]):
        code = incident[t]
        s = code // 2
        out = out + spring_times(direction[s], stiffness[s], rest[s], residual[s], pi - p[other_end(code, ends)])
    return out


@wp.kernel
def level_operator(
    p: wp.array(dtype=wp.vec3),
    mass_h2: wp.array(dtype=float),
    extra: wp.array(dtype=wp.mat33),
    stiffness: wp.array(dtype=float),
    offsets: wp.array(dtype=int),
    incident: wp.array(dtype=int),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
    q: wp.array(dtype=wp.vec3),
):
    """q = H p on one level."""
    i = wp.tid()
    q[i] = operator_row(i, p, mass_h2, extra, stiffness, offsets, incident, ends, rest, direction, residual)


@wp.kernel
def level_diagonal(
    mass_h2: wp.array(dtype=float),
    extra: wp.array(dtype=wp.mat33),
    stiffness: wp.array(dtype=float),
    offsets: wp.array(dtype=int),
    incident: wp.array(dtype=int),
    rest: wp.array(dtype=float),
    direction: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
    diagonal_inverse: wp.array(dtype=wp.mat33),
):
    """The inverse of each node's 3 x 3 diagonal block of H (0 for a pin): the Jacobi smoother's."""
    i = wp.tid()
    m_h2 = mass_h2[i]
    if m_h2 == 0.0:
        diagonal_inverse[i] = wp.mat33(0.0)
        return
    block = wp.identity(3, dtype=float) * m_h2 + extra[i]
    for t in range(offsets[i], offsets[i + 1]):
        s = incident[t] // 2
        block = block + spring_block(direction[s], stiffness[s], rest[s], residual[s])
    diagonal_inverse[i] = wp.inverse(block)


@wp.kernel
def restrict_level(
    fine_mass_h2: wp.array(dtype=float),
    fine_extra: wp.array(dtype=wp.mat33),
    family_offsets: wp.array(dtype=int),
    family: wp.array(dtype=int),
    family_weight: wp.array(dtype=float),
    fixed: wp.array(dtype=int),
    mass_h2: wp.array(dtype=float),
    extra: wp.array(dtype=wp.mat33),
):
    """A coarse node's mass and contact block: the sum over its fine family (itself, and the fine nodes it is a
    parent of) weighted by the prolongation's weights, P^T M P lumped. A pinned node stays fixed."""
    c = wp.tid()
    if fixed[c] != 0:
        mass_h2[c] = 0.0
        extra[c] = wp.mat33(0.0)
        return
    m = float(0.0)
    block = wp.mat33(0.0)
    for t in range(family_offsets[c], family_offsets[c + 1]):
        f = family[t]
        w = family_weight[t]
        m = m + fine_mass_h2[f] * w
        block = block + fine_extra[f] * w
    mass_h2[c] = m
    extra[c] = block


@wp.kernel
def restrict_residual(
    b: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    family_offsets: wp.array(dtype=int),
    family: wp.array(dtype=int),
    family_weight: wp.array(dtype=float),
    mass_h2: wp.array(dtype=float),
    coarse_b: wp.array(dtype=wp.vec3),
):
    """coarse b = P^T (b - H e) (0 at a pinned coarse node)."""
    c = wp.tid()
    out = wp.vec3(0.0)
    if mass_h2[c] != 0.0:
        for t in range(family_offsets[c], family_offsets[c + 1]):
            f = family[t]
            out = out + (b[f] - q[f]) * family_weight[t]
    coarse_b[c] = out


@wp.kernel
def prolong_add(
    coarse_e: wp.array(dtype=wp.vec3),
    parents: wp.array(dtype=wp.vec4i),
    weights: wp.array(dtype=wp.vec4),
    mass_h2: wp.array(dtype=float),
    e: wp.array(dtype=wp.vec3),
):
    """e += P coarse_e: each fine node by its four parents' bilinear weights (a node the coarse level keeps is
    its own parent, weight 1). A pin is never moved."""
    i = wp.tid()
    if mass_h2[i] == 0.0:
        return
    ps = parents[i]
    ws = weights[i]
    out = e[i]
    for k in range(4):
        out = out + coarse_e[ps[k]] * ws[k]
    e[i] = out


@wp.kernel
def smooth_start(b: wp.array(dtype=wp.vec3), diagonal_inverse: wp.array(dtype=wp.mat33), omega: float,
                 e: wp.array(dtype=wp.vec3)):
    """The first Jacobi sweep from e = 0: e = omega D^-1 b."""
    i = wp.tid()
    e[i] = (diagonal_inverse[i] * b[i]) * omega


@wp.kernel
def smooth(b: wp.array(dtype=wp.vec3), q: wp.array(dtype=wp.vec3), diagonal_inverse: wp.array(dtype=wp.mat33),
           omega: float, e: wp.array(dtype=wp.vec3)):
    """A damped Jacobi sweep, with q = H e: e += omega D^-1 (b - q)."""
    i = wp.tid()
    e[i] = e[i] + (diagonal_inverse[i] * (b[i] - q[i])) * omega


@wp.kernel
def dot_values(a: wp.array(dtype=wp.vec3), b: wp.array(dtype=wp.vec3), values: wp.array(dtype=wp.float64)):
    """Each node's share of a.b, in float64, for the fixed-order sum."""
    i = wp.tid()
    values[i] = wp.float64(wp.dot(a[i], b[i]))


# The conjugate-gradient scalars: r.z, p.Hp, the next r.z, and the step lengths alpha and beta.
RZ, PQ, RZ_NEW, ALPHA, BETA = 0, 1, 2, 3, 4


@wp.kernel
def cg_start(rhs: wp.array(dtype=wp.vec3), r: wp.array(dtype=wp.vec3), dx: wp.array(dtype=wp.vec3)):
    """r = rhs, dx = 0 (the preconditioner then gives z, and p = z)."""
    i = wp.tid()
    r[i] = rhs[i]
    dx[i] = wp.vec3(0.0)


@wp.kernel
def cg_advance(scalars: wp.array(dtype=wp.float64), p: wp.array(dtype=wp.vec3), q: wp.array(dtype=wp.vec3),
               dx: wp.array(dtype=wp.vec3), r: wp.array(dtype=wp.vec3)):
    """dx += alpha p, r -= alpha q."""
    i = wp.tid()
    alpha = float(scalars[ALPHA])
    dx[i] = dx[i] + p[i] * alpha
    r[i] = r[i] - q[i] * alpha


@wp.kernel
def cg_direction(scalars: wp.array(dtype=wp.float64), z: wp.array(dtype=wp.vec3), p: wp.array(dtype=wp.vec3)):
    """p = z + beta p (beta 0 on the first iteration: p = z)."""
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
        scalars[BETA] = zero  # the first direction is z itself
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


LINE_SEARCH = 4  # step lengths tried: 1, 1/2, 1/4 and 0 (so a step never raises the energy)
STEP = 5  # the scalars' slot of the chosen step length; slots STEP + 1 .. hold each candidate's energy


@wp.kernel
def candidate_energy(
    x: wp.array(dtype=Any),
    x_inertial: wp.array(dtype=Any),
    dx: wp.array(dtype=wp.vec3),
    step: float,
    inv_mass: wp.array(dtype=float),
    inv_h2: float,
    contact: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=int),
    incident: wp.array(dtype=int),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
    values: wp.array(dtype=wp.float64),
):
    """Each particle's share of E at x + step dx: its inertia (along the surface, for a contact, as the right-hand
    side counts it) and half of each of its sticks' spring energy."""
    i = wp.tid()
    w = inv_mass[i]
    if w == 0.0:
        values[i] = wp.float64(0.0)
        return
    xi = shifted(x[i], dx[i], step)
    lag = to_vec3(xi - x_inertial[i])
    n_c = contact[i]
    lag = lag - n_c * wp.dot(lag, n_c)
    energy = wp.float64(0.5 * inv_h2 / w * wp.dot(lag, lag))
    for t in range(offsets[i], offsets[i + 1]):
        code = incident[t]
        s = code // 2
        other = other_end(code, ends)
        xo = shifted(x[other], dx[other], step)
        c = float(wp.length(xo - xi)) - rest[s]
        energy += wp.float64(0.25 * stiffness[s] * c * c)
    values[i] = energy


@wp.kernel
def keep_energy(total: wp.array(dtype=wp.float64), candidate: int, scalars: wp.array(dtype=wp.float64)):
    scalars[STEP + 1 + candidate] = total[0]


@wp.kernel
def choose_step(scalars: wp.array(dtype=wp.float64)):
    """The step length of the lowest energy among the candidates (the longest, on a tie)."""
    best = 0
    for c in range(1, LINE_SEARCH):
        if scalars[STEP + 1 + c] < scalars[STEP + 1 + best]:
            best = c
    step = wp.float64(0.0)
    if best < LINE_SEARCH - 1:
        step = wp.float64(1.0) / wp.float64(float(1 << best))
    scalars[STEP] = step


@wp.kernel
def apply_correction(x: wp.array(dtype=Any), dx: wp.array(dtype=wp.vec3), scalars: wp.array(dtype=wp.float64)):
    i = wp.tid()
    x[i] = shifted(x[i], dx[i], float(scalars[STEP]))


@wp.kernel
def hand_over_tension(
    x: wp.array(dtype=Any),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
    h2: float,
    tension: wp.array(dtype=float),
):
    """Start each stick's tension (N s^2, the sweeps' XPBD multiplier) at its spring's force over the step where the
    correction left it: mu = k C h^2. A soft stick's sweeps then begin at the spring's balance (C = mu compliance /
    h^2) and move it only as far as the rigid sticks' projections change it; from mu = 0 they would apply the
    spring's force a second time. A rigid stick's projection ignores mu, but tearing by tension reads the
    force the correction carried plus the sweeps'."""
    s = wp.tid()
    e = ends[s]
    c = float(wp.length(x[e[1]] - x[e[0]])) - rest[s]
    tension[s] = c * h2 * stiffness[s]


for_positions(stick_directions, arrays=("x",))
for_positions(hand_over_tension, arrays=("x",))
for_positions(contact_normals, arrays=("x", "x_before"))
for_positions(copy_positions, arrays=("x", "copy"))
for_positions(assemble, arrays=("x", "x_inertial"))
for_positions(apply_correction, arrays=("x",))
for_positions(candidate_energy, arrays=("x", "x_inertial"))
