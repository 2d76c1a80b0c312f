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

A block solves it in three steps (the partition method of GPU tridiagonal solvers; Laszlo, Giles and Appleyard
2016), on a system padded to P equations (a power of two, the kernel's capacity) with identity equations:

1. The equations are cut into S segments of m = P / S. One lane a segment eliminates its segment in order (as
   Thomas' algorithm does, down and then up), leaving each of its equations coupled only to the segment's first
   and last unknowns, and its first and last equations to the neighbouring segments' last and first.
2. Those first and last equations form a tridiagonal system of 2 S unknowns, solved by parallel cyclic reduction
   (Hockney and Jesshope): each of log2(2 S) steps folds every equation's neighbours at a doubling stride into it,
   all equations at once, until none couples to another.
3. Each lane finds its segment's unknowns from its two ends.

Why: cyclic reduction over the whole line takes 2 log2(P) barrier-separated levels, most with few threads busy,
and its strided reads fall on the same shared-memory banks; a segment's elimination needs no barrier and its
lanes read neighbouring addresses (a segment's equation i of every segment lies together), and the reduced system
is short.

A block first stages its line's positions, inverse masses and contact normals in shared memory (each particle
read from global memory once, every load of a thread issued before it waits on one), and writes each particle
back once, moved. On the CPU one lane takes every segment in turn, the same arithmetic in the same order. The
coefficients and multipliers are float64: the matrix of a free chain of n particles has a condition number of
about 0.4 n^2.
"""

import warp as wp

from .grid_tiles import block_barrier
from .positions import POSITION_TYPES

_KERNELS: dict = {}


def line_solve_kernel(capacity: int, vector, segments: int, threads: int, max_registers: int | None = None):
    """The line solve's kernel for lines of at most ``capacity`` sticks (a power of two: the shared arrays'
    length), positions of type ``vector`` (wp.vec3 or wp.vec3d), ``segments`` segments a line (a power of two, at
    most capacity / 2) and blocks of ``threads`` threads (``segments`` on a GPU, 1 on the CPU); ``max_registers``
    caps a CUDA thread's registers (None: the compiler's choice)."""
    if capacity < 2 or capacity & (capacity - 1):
        raise AssertionError(f"a line solve's capacity must be a power of two of at least 2, got {capacity}")
    if segments < 1 or segments & (segments - 1) or 2 * segments > capacity:
        raise AssertionError(f"a line solve's segments must be a power of two of at most {capacity // 2}, "
                             f"got {segments}")
    key = (capacity, vector, segments, threads, max_registers)
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(capacity, vector, segments, threads, max_registers)
    return _KERNELS[key]


@wp.func
def weighted_dot(u: wp.vec3d, v: wp.vec3d, w: wp.float64, c: wp.vec3d):
    """u . W v with W = w (I - c c^T) (c = 0: no contact)."""
    return w * (wp.dot(u, v) - wp.dot(c, u) * wp.dot(c, v))


def _make_kernel(capacity: int, vector, segments: int, threads: int, max_registers: int | None):
    P = capacity
    POINTS = capacity + 1
    S = segments
    R = 2 * segments  # the reduced system's unknowns: each segment's first and last
    M_SEG = capacity // segments
    VEC = vector
    REAL = dict(POSITION_TYPES)[vector]
    THREADS = threads
    # A thread's particles to stage, at most: a compile-time count, which Warp unrolls (up to its max_unroll), so
    # that a thread issues all of its loads before it waits on any.
    STAGING_TURNS = -(-POINTS // threads)
    SEGMENT_TURNS = -(-S // threads)
    REDUCED_TURNS = -(-R // threads)

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_real(t: wp.tile(dtype=wp.float64, shape=(P,), storage="shared"), i: int, value: wp.float64): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_reduced(t: wp.tile(dtype=wp.float64, shape=(R,), storage="shared"), i: int, value: wp.float64): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_direction(t: wp.tile(dtype=wp.vec3, shape=(P,), storage="shared"), i: int, value: wp.vec3): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_point(t: wp.tile(dtype=VEC, shape=(POINTS,), storage="shared"), i: int, value: VEC): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_weight(t: wp.tile(dtype=float, shape=(POINTS,), storage="shared"), i: int, value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_normal(t: wp.tile(dtype=wp.vec3, shape=(POINTS,), storage="shared"), i: int, value: wp.vec3): ...

    @wp.func
    def stick_row(point: wp.tile(dtype=VEC, shape=(POINTS,), storage="shared"),
                  weight: wp.tile(dtype=float, shape=(POINTS,), storage="shared"),
                  contact_normal: wp.tile(dtype=wp.vec3, shape=(POINTS,), storage="shared"),
                  rest: wp.array(dtype=float), rest_first: int, sticks: int, k: int):
        """Stick k's direction (float32, as the couplings and moves take it), diagonal and right-hand side; an
        identity equation past the line's end or where neither end can move along the stick."""
        a = wp.float64(1.0)
        d = wp.float64(0.0)
        n32 = wp.vec3(0.0)
        if k < sticks:
            e = wp.vec3d(point[k + 1] - point[k])
            length = wp.length(e)
            wa = wp.float64(weight[k])
            wb = wp.float64(weight[k + 1])
            if length > wp.float64(0.0):
                n = e * (wp.float64(1.0) / length)
                a = weighted_dot(n, n, wa, wp.vec3d(contact_normal[k])) + weighted_dot(
                    n, n, wb, wp.vec3d(contact_normal[k + 1]))
                d = wp.float64(rest[rest_first + k]) - length
                n32 = wp.vec3(n)
            if a <= wp.float64(1.0e-12) * (wa + wb) or length == wp.float64(0.0):
                a = wp.float64(1.0)  # its multiplier is 0
                d = wp.float64(0.0)
        return n32, a, d

    @wp.func
    def coupling(weight: wp.tile(dtype=float, shape=(POINTS,), storage="shared"),
                 contact_normal: wp.tile(dtype=wp.vec3, shape=(POINTS,), storage="shared"),
                 sticks: int, k: int, before: wp.vec3, after: wp.vec3):
        """The coupling of sticks k - 1 and k (directions ``before`` and ``after``) through particle k; 0 where
        either is not a stick of the line."""
        c = wp.float64(0.0)
        if k > 0 and k < sticks:
            c = -weighted_dot(wp.vec3d(before), wp.vec3d(after), wp.float64(weight[k]),
                              wp.vec3d(contact_normal[k]))
        return c

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
        one = wp.float64(1.0)
        # A segment's eliminated equations, equation i of segment j at i S + j: its coupling to the segment's first
        # unknown (the previous segment's last, for the first equation), to its last unknown (the next segment's
        # first, for the last equation) and its right-hand side, which becomes its multiplier.
        to_first = wp.tile_empty(shape=P, dtype=wp.float64, storage="shared")
        to_last = wp.tile_empty(shape=P, dtype=wp.float64, storage="shared")
        rhs = wp.tile_empty(shape=P, dtype=wp.float64, storage="shared")
        direction = wp.tile_empty(shape=P, dtype=wp.vec3, storage="shared")
        # The reduced system, twice (parallel cyclic reduction reads one and writes the other).
        lower = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        diagonal = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        upper = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        reduced = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        lower_next = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        diagonal_next = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        upper_next = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        reduced_next = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
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

        # 1. Each segment eliminated in order. Down: equation i (the segment's i-th) is left coupled to the
        # segment's first unknown and the next equation's unknown; up: to the first and the last unknowns.
        for turn in range(SEGMENT_TURNS):
            j = lane + turn * THREADS
            if j < S:
                s = j * M_SEG
                before = wp.vec3(0.0)
                if s > 0:
                    before, unused_a, unused_d = stick_row(point, weight, contact_normal, rest, rest_first, sticks,
                                                           s - 1)
                n, a, d = stick_row(point, weight, contact_normal, rest, rest_first, sticks, s)
                low = coupling(weight, contact_normal, sticks, s, before, n)
                previous_to_first = zero
                previous_to_next = zero
                previous_rhs = zero
                for i in range(M_SEG):
                    k = s + i
                    put_direction(direction, k, n)
                    after, a_next, d_next = stick_row(point, weight, contact_normal, rest, rest_first, sticks, k + 1)
                    up = coupling(weight, contact_normal, sticks, k + 1, n, after)
                    f = low
                    t = up
                    r = d
                    if i >= 2:  # eliminate the previous equation's unknown; its coupling to the first carries on
                        pivot = one / (a - low * previous_to_next)
                        f = -pivot * low * previous_to_first
                        t = pivot * up
                        r = pivot * (d - low * previous_rhs)
                    else:
                        pivot = one / a
                        f = pivot * low
                        t = pivot * up
                        r = pivot * d
                    put_real(to_first, i * S + j, f)
                    put_real(to_last, i * S + j, t)
                    put_real(rhs, i * S + j, r)
                    previous_to_first = f
                    previous_to_next = t
                    previous_rhs = r
                    n = after
                    a = a_next
                    d = d_next
                    low = up
                # Up: equations m - 3 .. 1 take in the one after them, so each couples to the last unknown only
                # (equation m - 2 already does).
                next_first = previous_to_first  # (unused for m = 2)
                next_last = zero
                next_rhs = zero
                if M_SEG >= 3:
                    next_first = to_first[(M_SEG - 2) * S + j]
                    next_last = to_last[(M_SEG - 2) * S + j]
                    next_rhs = rhs[(M_SEG - 2) * S + j]
                    i = M_SEG - 3
                    while i >= 1:
                        c = to_last[i * S + j]
                        f = to_first[i * S + j] - c * next_first
                        t = -c * next_last
                        r = rhs[i * S + j] - c * next_rhs
                        put_real(to_first, i * S + j, f)
                        put_real(to_last, i * S + j, t)
                        put_real(rhs, i * S + j, r)
                        next_first = f
                        next_last = t
                        next_rhs = r
                        i -= 1
                    # The first equation takes in the second: it couples to the previous segment's last unknown
                    # and this segment's last.
                    c = to_last[j]
                    pivot = one / (one - c * next_first)
                    put_real(to_first, j, pivot * to_first[j])
                    put_real(rhs, j, pivot * (rhs[j] - c * next_rhs))
                    put_real(to_last, j, -pivot * c * next_last)
                # The segment's first and last equations are rows 2 j and 2 j + 1 of the reduced system.
                last = (M_SEG - 1) * S + j
                put_reduced(lower, 2 * j, to_first[j])
                put_reduced(diagonal, 2 * j, one)
                put_reduced(upper, 2 * j, to_last[j])
                put_reduced(reduced, 2 * j, rhs[j])
                put_reduced(lower, 2 * j + 1, to_first[last])
                put_reduced(diagonal, 2 * j + 1, one)
                put_reduced(upper, 2 * j + 1, to_last[last])
                put_reduced(reduced, 2 * j + 1, rhs[last])
        block_barrier()

        # 2. Parallel cyclic reduction of the reduced system: at stride h, equation e takes in e - h and e + h,
        # and then couples to e - 2 h and e + 2 h. After log2(R) steps each equation stands alone.
        h = int(1)
        flip = int(0)
        while h < R:
            for turn in range(REDUCED_TURNS):
                e = lane + turn * THREADS
                if e < R:
                    if flip == 0:
                        b = diagonal[e]
                        l = lower[e]
                        u = upper[e]
                        r = reduced[e]
                        new_l = zero
                        new_u = zero
                        if e >= h:
                            alpha = -l / diagonal[e - h]
                            b += alpha * upper[e - h]
                            r += alpha * reduced[e - h]
                            new_l = alpha * lower[e - h]
                        if e + h < R:
                            beta = -u / diagonal[e + h]
                            b += beta * lower[e + h]
                            r += beta * reduced[e + h]
                            new_u = beta * upper[e + h]
                        put_reduced(diagonal_next, e, b)
                        put_reduced(lower_next, e, new_l)
                        put_reduced(upper_next, e, new_u)
                        put_reduced(reduced_next, e, r)
                    else:
                        b = diagonal_next[e]
                        l = lower_next[e]
                        u = upper_next[e]
                        r = reduced_next[e]
                        new_l = zero
                        new_u = zero
                        if e >= h:
                            alpha = -l / diagonal_next[e - h]
                            b += alpha * upper_next[e - h]
                            r += alpha * reduced_next[e - h]
                            new_l = alpha * lower_next[e - h]
                        if e + h < R:
                            beta = -u / diagonal_next[e + h]
                            b += beta * lower_next[e + h]
                            r += beta * reduced_next[e + h]
                            new_u = beta * upper_next[e + h]
                        put_reduced(diagonal, e, b)
                        put_reduced(lower, e, new_l)
                        put_reduced(upper, e, new_u)
                        put_reduced(reduced, e, r)
            block_barrier()
            flip = 1 - flip
            h *= 2

        # 3. Each segment's unknowns from its first and last; every multiplier written over its right-hand side.
        for turn in range(SEGMENT_TURNS):
            j = lane + turn * THREADS
            if j < S:
                lambda_first = zero
                lambda_last = zero
                if flip == 0:
                    lambda_first = reduced[2 * j] / diagonal[2 * j]
                    lambda_last = reduced[2 * j + 1] / diagonal[2 * j + 1]
                else:
                    lambda_first = reduced_next[2 * j] / diagonal_next[2 * j]
                    lambda_last = reduced_next[2 * j + 1] / diagonal_next[2 * j + 1]
                for i in range(1, M_SEG - 1):
                    o = i * S + j
                    put_real(rhs, o, rhs[o] - to_first[o] * lambda_first - to_last[o] * lambda_last)
                put_real(rhs, j, lambda_first)
                put_real(rhs, (M_SEG - 1) * S + j, lambda_last)
        block_barrier()

        # Each particle moves by W (n_{q-1} lambda_{q-1} - n_q lambda_q): the second end of stick q - 1 and the
        # first of stick q.
        for turn in range(STAGING_TURNS):
            q = lane + turn * THREADS
            if q <= sticks:
                pull = wp.vec3d(0.0, 0.0, 0.0)
                if q > 0:
                    pull += wp.vec3d(direction[q - 1]) * rhs[((q - 1) % M_SEG) * S + (q - 1) // M_SEG]
                if q < sticks:
                    pull -= wp.vec3d(direction[q]) * rhs[(q % M_SEG) * S + q // M_SEG]
                cn = wp.vec3d(contact_normal[q])
                move = (pull - cn * wp.dot(cn, pull)) * wp.float64(weight[q])
                x[first + q * step] = point[q] + VEC(REAL(move[0]), REAL(move[1]), REAL(move[2]))

    return solve_lines
