"""Line solves (warp_verlet/constraints/line_solve.py): every row or every column of a grid's structural sticks
solved exactly at once, a block per line.

A line of M sticks (M + 1 particles p_0 .. p_M) is a chain. One Newton step on its stick lengths, each particle
moved in the metric of its inverse mass, solves

    J W J^T lambda = -C,    x += W J^T lambda,

where C_k = |x_{p_k+1} - x_{p_k}| - L_k, J_k is -n_k on the stick's first particle and +n_k on its second (n_k its
direction), and W_p = w_p (I - c c^T) for a particle in contact with normal c (w_p I otherwise): a particle in
contact slides along the collider and does not move into it or off it. J W J^T is tridiagonal and symmetric:
stick k's diagonal is n_k . W n_k summed over its two ends, and sticks k and k + 1 couple through their shared
particle by -n_k . W n_{k+1}.

A block solves it by cyclic reduction in shared memory (Hockney 1965): each level eliminates the odd equations of
the one before, at a stride twice as long, so log2(P) levels of independent updates, a barrier between levels,
carry the correction along the whole line; back substitution walks the levels down again. The system is padded to
P (a power of two, the kernel's capacity) with identity equations. A block first stages its line's positions,
inverse masses and contact normals in shared memory (each particle read from global memory once, every load of a
thread issued before it waits on one), and writes each particle back once, moved. The block's threads take the
equations of a level in turn; on the CPU one lane takes them all, in the same order, so the arithmetic is the same on every
device. The coefficients and multipliers are float64: the matrix of a free chain of n particles has a condition
number of about 0.4 n^2.

A pivot of the reduction that cancels to under ``PIVOT_FLOOR`` times its value before the level is raised to
that (static pivoting with perturbation, as sparse direct solvers do: Li and Demmel 1998). A line's system is
singular where a stretch of it cannot move along itself at both ends: a line pinned at both ends at its rest
length (the top row of a cloth hung by two corners) is straight, and equal multipliers on all its sticks put no
net force on any particle; so is a free particle between two neighbours that a collider holds along the line. In
the singular direction the multipliers move no particle, so any finite value serves, but an exact zero pivot made
NaN, and a near-zero one divided the sticks' rounding (about 6e-8 of a coordinate in float32) by the square of
the line's sag angle and threw the row off (NaN within a frame for a 16 x 16 cloth hung by two corners at 16
substeps). A well-conditioned line never cancels that far: a free straight line's pivots halve at each level.
"""

import warp as wp

from .grid_tiles import block_barrier
from .positions import POSITION_TYPES

_KERNELS: dict = {}

PIVOT_FLOOR = 1.0e-6
"""A reduction's pivot is at least this times its value before its level (bench/results/line_solve/README.md,
"Singular lines")."""


def line_solve_kernel(capacity: int, vector, threads: int, max_registers: int | None = None):
    """The line solve's kernel for lines of at most ``capacity`` sticks (a power of two: the shared arrays'
    length), positions of type ``vector`` (wp.vec3 or wp.vec3d) and blocks of ``threads`` threads (1 on the CPU);
    ``max_registers`` caps a CUDA thread's registers (None: the compiler's choice)."""
    if capacity < 2 or capacity & (capacity - 1):
        raise AssertionError(f"a line solve's capacity must be a power of two of at least 2, got {capacity}")
    key = (capacity, vector, threads, max_registers)
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(capacity, vector, threads, max_registers)
    return _KERNELS[key]


@wp.func
def weighted_dot(u: wp.vec3d, v: wp.vec3d, w: wp.float64, c: wp.vec3d):
    """u . W v with W = w (I - c c^T) (c = 0: no contact)."""
    return w * (wp.dot(u, v) - wp.dot(c, u) * wp.dot(c, v))


def _make_kernel(capacity: int, vector, threads: int, max_registers: int | None):
    FLOOR = wp.float64(PIVOT_FLOOR)
    P = capacity
    POINTS = capacity + 1
    VEC = vector
    REAL = dict(POSITION_TYPES)[vector]
    THREADS = threads
    # A thread's particles to stage, at most: a compile-time count, which Warp unrolls (up to its max_unroll), so
    # that a thread issues all of its loads before it waits on any.
    STAGING_TURNS = -(-POINTS // threads)

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_real(t: wp.tile(dtype=wp.float64, shape=(P,), storage="shared"), i: int, value: wp.float64): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_direction(t: wp.tile(dtype=wp.vec3, shape=(P,), storage="shared"), i: int, value: wp.vec3): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_point(t: wp.tile(dtype=VEC, shape=(POINTS,), storage="shared"), i: int, value: VEC): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_weight(t: wp.tile(dtype=float, shape=(POINTS,), storage="shared"), i: int, value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_normal(t: wp.tile(dtype=wp.vec3, shape=(POINTS,), storage="shared"), i: int, value: wp.vec3): ...

    options = {} if max_registers is None else {"cuda_max_registers": max_registers}

    @wp.kernel(module="unique", **options)
    def solve_lines(
        x: wp.array(dtype=VEC),
        inv_mass: wp.array(dtype=float),
        contact: int,
        normal: wp.array(dtype=wp.vec3),
        lines: wp.array(dtype=wp.vec4i),
        rest: wp.array(dtype=float),
    ):
        """Block b solves line lines[b] = (first particle, sticks M, step between its particles, its first rest
        length in ``rest``); ``normal`` is read where ``contact`` is 1 (the contact normal of each particle, 0 where
        none)."""
        block, lane = wp.tid()
        line = lines[block]
        first = line[0]
        sticks = line[1]
        step = line[2]
        rest_first = line[3]
        zero = wp.float64(0.0)
        diagonal = wp.tile_empty(shape=P, dtype=wp.float64, storage="shared")
        lower = wp.tile_empty(shape=P, dtype=wp.float64, storage="shared")  # couples equation k to k - stride
        upper = wp.tile_empty(shape=P, dtype=wp.float64, storage="shared")  # couples equation k to k + stride
        rhs = wp.tile_empty(shape=P, dtype=wp.float64, storage="shared")  # -C, then the multipliers
        direction = wp.tile_empty(shape=P, dtype=wp.vec3, storage="shared")
        point = wp.tile_empty(shape=POINTS, dtype=VEC, storage="shared")  # the line's particles, staged once
        weight = wp.tile_empty(shape=POINTS, dtype=float, storage="shared")
        contact_normal = wp.tile_empty(shape=POINTS, dtype=wp.vec3, storage="shared")

        # The line's positions, inverse masses and contact normals, read from global memory once.
        for turn in range(STAGING_TURNS):
            q = lane + turn * THREADS
            if q <= sticks:
                p = first + q * step
                put_point(point, q, x[p])
                put_weight(weight, q, inv_mass[p])
                if contact == 1:
                    put_normal(contact_normal, q, normal[p])
                else:
                    put_normal(contact_normal, q, wp.vec3(0.0))
        block_barrier()

        # Each stick's direction, stretch and diagonal; identity equations past the line's end.
        k = lane
        while k < P:
            a = wp.float64(1.0)
            d = zero
            n32 = wp.vec3(0.0)
            if k < sticks:
                e = wp.vec3d(point[k + 1] - point[k])
                length = wp.length(e)
                wa = wp.float64(weight[k])
                wb = wp.float64(weight[k + 1])
                ca = wp.vec3d(contact_normal[k])
                cb = wp.vec3d(contact_normal[k + 1])
                if length > zero:
                    n = e / length
                    a = weighted_dot(n, n, wa, ca) + weighted_dot(n, n, wb, cb)
                    d = wp.float64(rest[rest_first + k]) - length
                    n32 = wp.vec3(n)
                if a <= wp.float64(1.0e-12) * (wa + wb) or length == zero:
                    a = wp.float64(1.0)  # neither end can move along the stick: its multiplier is 0
                    d = zero
            put_real(diagonal, k, a)
            put_real(rhs, k, d)
            put_real(lower, k, zero)
            put_real(upper, k, zero)
            put_direction(direction, k, n32)
            k += THREADS
        block_barrier()

        # Sticks k and k + 1 couple through their shared particle.
        k = lane
        while k < sticks - 1:
            coupling = -weighted_dot(wp.vec3d(direction[k]), wp.vec3d(direction[k + 1]),
                                     wp.float64(weight[k + 1]), wp.vec3d(contact_normal[k + 1]))
            put_real(upper, k, coupling)
            put_real(lower, k + 1, coupling)
            k += THREADS
        block_barrier()

        # Cyclic reduction: at stride s, equation k = 2 s j + 2 s - 1 absorbs equations k - s and k + s, which
        # this level leaves alone, and then couples to k - 2 s and k + 2 s.
        s = int(1)
        while s < P:
            j = lane
            while j < P // (2 * s):
                k = 2 * s * j + 2 * s - 1
                alpha = -lower[k] / diagonal[k - s]
                a = diagonal[k] + alpha * upper[k - s]
                d = rhs[k] + alpha * rhs[k - s]
                low = alpha * lower[k - s]
                up = zero
                if k + s < P:
                    beta = -upper[k] / diagonal[k + s]
                    a += beta * lower[k + s]
                    d += beta * rhs[k + s]
                    up = beta * upper[k + s]
                a = wp.max(a, FLOOR * diagonal[k])  # a cancels only where the line is (nearly) singular
                put_real(diagonal, k, a)
                put_real(rhs, k, d)
                put_real(lower, k, low)
                put_real(upper, k, up)
                j += THREADS
            block_barrier()
            s *= 2
        # The last equation stands alone; back substitution, stride P / 2 down to 1, each multiplier written over
        # its right-hand side.
        if lane == 0:
            put_real(rhs, P - 1, rhs[P - 1] / diagonal[P - 1])
        block_barrier()
        s = P // 2
        while s >= 1:
            j = lane
            while j < P // (2 * s):
                k = 2 * s * j + s - 1
                d = rhs[k] - lower[k] * wp.where(k >= s, rhs[wp.max(k - s, 0)], zero)
                if k + s < P:
                    d -= upper[k] * rhs[k + s]
                put_real(rhs, k, d / diagonal[k])
                j += THREADS
            block_barrier()
            s = s // 2

        # Each particle moves by W (n_{q-1} lambda_{q-1} - n_q lambda_q): the second end of stick q - 1 and the
        # first of stick q.
        for turn in range(STAGING_TURNS):
            q = lane + turn * THREADS
            if q <= sticks:
                f = wp.vec3d(0.0, 0.0, 0.0)
                if q > 0:
                    f += wp.vec3d(direction[q - 1]) * rhs[q - 1]
                if q < sticks:
                    f -= wp.vec3d(direction[q]) * rhs[q]
                c = wp.vec3d(contact_normal[q])
                move = (f - c * wp.dot(c, f)) * wp.float64(weight[q])
                x[first + q * step] = point[q] + VEC(REAL(move[0]), REAL(move[1]), REAL(move[2]))

    return solve_lines
