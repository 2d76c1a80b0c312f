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
    # A thread's particles, segments and reduced equations, at most: compile-time counts.
    PARTICLE_TURNS = -(-POINTS // threads)
    SEGMENT_TURNS = -(-S // threads)
    REDUCED_TURNS = -(-R // threads)

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_reduced(t: wp.tile(dtype=wp.float64, shape=(R,), storage="shared"), i: int, value: wp.float64): ...

    @wp.func
    def contact_normal_of(normal: wp.array(dtype=wp.vec3), contact: int, p: int):
        c = wp.vec3d(0.0, 0.0, 0.0)
        if contact == 1:
            c = wp.vec3d(normal[p])
        return c

    @wp.func
    def stick_row(x: wp.array(dtype=VEC), inv_mass: wp.array(dtype=float), contact: int,
                  normal: wp.array(dtype=wp.vec3), first: int, step: int, rest: wp.array(dtype=float),
                  rest_first: int, sticks: int, k: int):
        """Stick k's direction (float32, as the couplings and moves take it), diagonal and right-hand side; an
        identity equation past the line's end or where neither end can move along the stick."""
        a = wp.float64(1.0)
        d = wp.float64(0.0)
        n32 = wp.vec3(0.0)
        if k < sticks:
            pa = first + k * step
            pb = pa + step
            e = wp.vec3d(x[pb] - x[pa])
            length = wp.length(e)
            wa = wp.float64(inv_mass[pa])
            wb = wp.float64(inv_mass[pb])
            if length > wp.float64(0.0):
                n = e * (wp.float64(1.0) / length)
                a = weighted_dot(n, n, wa, contact_normal_of(normal, contact, pa)) + weighted_dot(
                    n, n, wb, contact_normal_of(normal, contact, pb))
                d = wp.float64(rest[rest_first + k]) - length
                n32 = wp.vec3(n)
            if a <= wp.float64(1.0e-12) * (wa + wb) or length == wp.float64(0.0):
                a = wp.float64(1.0)  # its multiplier is 0
                d = wp.float64(0.0)
        return n32, a, d

    @wp.func
    def coupling(inv_mass: wp.array(dtype=float), contact: int, normal: wp.array(dtype=wp.vec3), first: int,
                 step: int, sticks: int, k: int, before: wp.vec3, after: wp.vec3):
        """The coupling of sticks k - 1 and k (directions ``before`` and ``after``) through particle k; 0 where
        either is not a stick of the line."""
        c = wp.float64(0.0)
        if k > 0 and k < sticks:
            p = first + k * step
            c = -weighted_dot(wp.vec3d(before), wp.vec3d(after), wp.float64(inv_mass[p]),
                              contact_normal_of(normal, contact, p))
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
        eliminated: wp.array2d(dtype=wp.vec3d),
        direction: wp.array2d(dtype=wp.vec3),
    ):
        """Block b solves line lines[b] = (first particle, sticks M, step between its particles, its first rest
        length in ``rest``); ``normal`` is read where ``contact`` is 1 (the contact normal of each particle, 0 where
        none). ``eliminated[b]`` and ``direction[b]`` are the block's working rows (P each): equation i of segment j
        at i S + j, so that a segment's lanes read and write neighbouring addresses; ``eliminated`` holds its
        coupling to the segment's first unknown (the previous segment's last, for its first equation), to its last
        (the next segment's first, for its last equation) and its right-hand side, which becomes its multiplier."""
        block, lane = wp.tid()
        line = lines[block]
        first = line[0]
        sticks = line[1]
        step = line[2]
        rest_first = line[3]
        zero = wp.float64(0.0)
        one = wp.float64(1.0)
        # The reduced system, twice (parallel cyclic reduction reads one and writes the other).
        lower = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        diagonal = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        upper = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        reduced = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        lower_next = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        diagonal_next = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        upper_next = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")
        reduced_next = wp.tile_empty(shape=R, dtype=wp.float64, storage="shared")

        # 1. Each segment eliminated in order. Down: equation i (the segment's i-th) is left coupled to the
        # segment's first unknown and the next equation's unknown; up: to the first and the last unknowns.
        for turn in range(SEGMENT_TURNS):
            j = lane + turn * THREADS
            if j < S:
                s = j * M_SEG
                before = wp.vec3(0.0)
                if s > 0:
                    before, unused_a, unused_d = stick_row(x, inv_mass, contact, normal, first, step, rest,
                                                           rest_first, sticks, s - 1)
                n, a, d = stick_row(x, inv_mass, contact, normal, first, step, rest, rest_first, sticks, s)
                low = coupling(inv_mass, contact, normal, first, step, sticks, s, before, n)
                previous = wp.vec3d(zero, zero, zero)  # the previous equation: to the first, to the next, rhs
                for i in range(M_SEG):
                    k = s + i
                    direction[block, i * S + j] = n
                    after, a_next, d_next = stick_row(x, inv_mass, contact, normal, first, step, rest, rest_first,
                                                      sticks, k + 1)
                    up = coupling(inv_mass, contact, normal, first, step, sticks, k + 1, n, after)
                    row = wp.vec3d(zero, zero, zero)
                    if i >= 2:  # eliminate the previous equation's unknown; its coupling to the first carries on
                        pivot = one / (a - low * previous[1])
                        row = wp.vec3d(-pivot * low * previous[0], pivot * up, pivot * (d - low * previous[2]))
                    else:
                        pivot = one / a
                        row = wp.vec3d(pivot * low, pivot * up, pivot * d)
                    eliminated[block, i * S + j] = row
                    previous = row
                    n = after
                    a = a_next
                    d = d_next
                    low = up
                # Up: equations m - 3 .. 1 take in the one after them, so each couples to the last unknown only
                # (equation m - 2 already does); then the first takes in the second.
                if M_SEG >= 3:
                    following = eliminated[block, (M_SEG - 2) * S + j]
                    i = M_SEG - 3
                    while i >= 1:
                        row = eliminated[block, i * S + j]
                        c = row[1]
                        following = wp.vec3d(row[0] - c * following[0], -c * following[1],
                                             row[2] - c * following[2])
                        eliminated[block, i * S + j] = following
                        i -= 1
                    row = eliminated[block, j]
                    c = row[1]
                    pivot = one / (one - c * following[0])
                    eliminated[block, j] = wp.vec3d(pivot * row[0], -pivot * c * following[1],
                                                    pivot * (row[2] - c * following[2]))
                # The segment's first and last equations are rows 2 j and 2 j + 1 of the reduced system.
                head = eliminated[block, j]
                tail = eliminated[block, (M_SEG - 1) * S + j]
                put_reduced(lower, 2 * j, head[0])
                put_reduced(diagonal, 2 * j, one)
                put_reduced(upper, 2 * j, head[1])
                put_reduced(reduced, 2 * j, head[2])
                put_reduced(lower, 2 * j + 1, tail[0])
                put_reduced(diagonal, 2 * j + 1, one)
                put_reduced(upper, 2 * j + 1, tail[1])
                put_reduced(reduced, 2 * j + 1, tail[2])
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
                    row = eliminated[block, i * S + j]
                    eliminated[block, i * S + j] = wp.vec3d(row[0], row[1], row[2] - row[0] * lambda_first
                                                            - row[1] * lambda_last)
                eliminated[block, j] = wp.vec3d(zero, zero, lambda_first)
                eliminated[block, (M_SEG - 1) * S + j] = wp.vec3d(zero, zero, lambda_last)
        block_barrier()

        # Each particle moves by W (n_{q-1} lambda_{q-1} - n_q lambda_q): the second end of stick q - 1 and the
        # first of stick q.
        for turn in range(PARTICLE_TURNS):
            q = lane + turn * THREADS
            if q <= sticks:
                pull = wp.vec3d(0.0, 0.0, 0.0)
                if q > 0:
                    o = ((q - 1) % M_SEG) * S + (q - 1) // M_SEG
                    pull += wp.vec3d(direction[block, o]) * eliminated[block, o][2]
                if q < sticks:
                    o = (q % M_SEG) * S + q // M_SEG
                    pull -= wp.vec3d(direction[block, o]) * eliminated[block, o][2]
                p = first + q * step
                cn = contact_normal_of(normal, contact, p)
                move = (pull - cn * wp.dot(cn, pull)) * wp.float64(inv_mass[p])
                x[p] = x[p] + VEC(REAL(move[0]), REAL(move[1]), REAL(move[2]))

    return solve_lines
