"""Line solves (warp_verlet/constraints/line_solve.py): every row or every column of a grid's structural sticks
solved at once, one thread a line.

A line of n particles and n - 1 sticks is a chain. One Newton step on its stick lengths, with each particle moved
in the metric of its inverse mass, solves J W J^T lambda = -C, where C_k = |x_{k+1} - x_k| - L_k, J_k is -n_k on
the stick's first particle and +n_k on its second, and W_p = w_p (I - c c^T) for a particle in contact with
normal c (w_p I otherwise): a particle in contact slides along the collider and never moves into it. J W J^T is
tridiagonal (stick k shares one particle with k - 1 and one with k + 1), so the Thomas algorithm solves it in one
forward and one backward pass; the moves are dx_p = W_p J^T lambda. The recurrences run in float64: the matrix of
a free chain of n particles has a condition number about 0.4 n^2.
"""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.func
def weighted_dot(u: wp.vec3d, v: wp.vec3d, w: float, c: wp.vec3d):
    """u . W v with W = w (I - c c^T) (c = 0: no contact)."""
    return wp.float64(w) * (wp.dot(u, v) - wp.dot(c, u) * wp.dot(c, v))


@wp.func
def weighted(v: wp.vec3d, w: float, c: wp.vec3d):
    """W v with W = w (I - c c^T)."""
    return wp.float64(w) * (v - c * wp.dot(c, v))


@wp.kernel
def solve_lines(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    normal: wp.array(dtype=wp.vec3),
    line_first: wp.array(dtype=int),
    line_count: wp.array(dtype=int),
    step: int,
    rest_position: wp.array(dtype=wp.vec3),
    direction: wp.array(dtype=wp.vec3d),
    forward: wp.array(dtype=wp.vec2d),
):
    """One line per thread: particles line_first[t] + k step, k < line_count[t]; a stick's rest length is the
    distance of its two particles' rest positions. ``direction`` and ``forward`` (c', d' of the Thomas algorithm) are scratch, one entry
    per particle, indexed by each stick's first particle."""
    t = wp.tid()
    base = line_first[t]
    sticks = line_count[t] - 1
    if sticks < 1:
        return
    zero = wp.float64(0.0)
    # forward elimination: row k of the system is  b_{k-1} lambda_{k-1} + a_k lambda_k + b_k lambda_{k+1} = -C_k
    n_prev = wp.vec3d(zero, zero, zero)
    c_prime_prev = zero  # c'_{k-1}
    d_prime_prev = zero  # d'_{k-1}
    denominator_prev = wp.float64(1.0)
    pa = base
    xa = wp.vec3d(x[pa])
    wa = inv_mass[pa]
    ca = wp.vec3d(normal[pa])
    for k in range(sticks):
        pb = pa + step
        xb = wp.vec3d(x[pb])
        wb = inv_mass[pb]
        cb = wp.vec3d(normal[pb])
        d = xb - xa
        length = wp.length(d)
        n = wp.vec3d(zero, zero, zero)
        if length > zero:
            n = d / length
        a = weighted_dot(n, n, wa, ca) + weighted_dot(n, n, wb, cb)
        rhs = -(length - wp.length(wp.vec3d(rest_position[pb]) - wp.vec3d(rest_position[pa])))
        if a <= wp.float64(1.0e-12) * wp.float64(wa + wb):
            a = wp.float64(1.0)  # neither end can move along the stick: lambda_k = 0
            rhs = zero
        b_prev = zero
        if k > 0:
            b_prev = -weighted_dot(n_prev, n, wa, ca)  # the particle pa is shared with stick k - 1
            c_prime_prev = b_prev / denominator_prev
            forward[pa - step] = wp.vec2d(c_prime_prev, d_prime_prev)
        denominator = a - b_prev * c_prime_prev
        d_prime = (rhs - b_prev * d_prime_prev) / denominator
        direction[pa] = n
        n_prev = n
        d_prime_prev = d_prime
        denominator_prev = denominator
        pa = pb
        xa = xb
        wa = wb
        ca = cb
    # back substitution, moving each particle once both of its sticks' lambdas are known
    last = base + (sticks - 1) * step  # first particle of the last stick
    lam_next = d_prime_prev  # lambda_{m-1}
    n_next = n_prev
    p = last + step
    x[p] = x[p] + type(x[p])(weighted(n_next * lam_next, inv_mass[p], wp.vec3d(normal[p])))
    pa = last
    for j in range(sticks - 1):
        k = sticks - 2 - j
        pa = pa - step  # first particle of stick k
        f = forward[pa]
        lam = f[1] - f[0] * lam_next
        n = direction[pa]
        p = pa + step  # the particle between sticks k and k + 1
        x[p] = x[p] + type(x[p])(weighted(n * lam - n_next * lam_next, inv_mass[p], wp.vec3d(normal[p])))
        lam_next = lam
        n_next = n
    x[base] = x[base] - type(x[base])(weighted(n_next * lam_next, inv_mass[base], wp.vec3d(normal[base])))


for_positions(solve_lines, arrays=("x",))
