"""Prototype: the clustered sweep (rigid sticks) as one launch for K sweeps, each block taking the next
(sweep, cluster) item from a counter and waiting only on the clusters whose regions share a particle with its own:
those of a lower cluster colour must have finished this sweep, those of a higher colour (and itself) the previous
one. Any two clusters that share a particle then update it in the coloured launches' order, so the positions are
theirs bit for bit, but a launch is no longer a wave of blocks that stage, project and write back in step.

Items are taken in order (sweep, cluster), clusters numbered in colour order, so an item waits only on items
taken before it, by blocks that are running or done: no block can wait forever.
"""
import warp as wp

from warp_verlet.kernels.grid_tiles import block_barrier, shared_sweep_options
from warp_verlet.kernels.positions import scaled
from warp_verlet.kernels.relax import stick_correction
from warp_verlet.kernels.stick_clusters import streamed_float, streamed_int

_WAIT = """
#if defined(__CUDA_ARCH__)
    volatile int* flag = (volatile int*)wp::address(done, d);
    while ((int)(*flag - need) < 0) { __nanosleep(sleep_ns); }
    __threadfence();
    return 0;
#else
    return (int)(wp::index(done, d) - need) < 0 ? 1 : 0;
#endif
"""


@wp.func_native(_WAIT)
def wait_done(done: wp.array(dtype=int), d: int, need: int, sleep_ns: int) -> int:
    """Wait until done[d] reaches need (in wrapping int arithmetic). On the CPU, where items run one after another,
    return 1 if it has not (a broken order), else 0."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    __threadfence();
#endif
""")
def release_fence():
    """This thread's global stores are visible to the whole device before any store it makes after."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    atomicExch((int*)wp::address(done, c), value);
#else
    wp::index(done, c) = value;
#endif
""")
def publish(done: wp.array(dtype=int), c: int, value: int):
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    const float* p = (const float*)wp::address(x, i);
    return wp::vec3(__ldcg(p), __ldcg(p + 1), __ldcg(p + 2));
#else
    return wp::index(x, i);
#endif
""")
def load_l2(x: wp.array(dtype=wp.vec3), i: int) -> wp.vec3:
    """x[i], read from L2 (not the multiprocessor's L1, which another block's earlier read may have left stale)."""
    ...


_KERNELS = {}


def chained_kernel(region_capacity, stick_capacity, colours, *, block_dim, sleep_ns=32, max_registers=None):
    key = (region_capacity, stick_capacity, colours, block_dim, sleep_ns, max_registers)
    if key not in _KERNELS:
        _KERNELS[key] = _make(*key)
    return _KERNELS[key]


def _make(region_capacity, stick_capacity, colours, block_dim, sleep_ns, max_registers):
    CAPACITY = region_capacity
    STICKS = stick_capacity
    STICK_BATCH = -(-stick_capacity // block_dim)
    REGION_BATCH = -(-region_capacity // block_dim)
    stick_ints = wp.types.vector(length=STICK_BATCH, dtype=int)
    stick_floats = wp.types.vector(length=STICK_BATCH, dtype=float)
    region_ints = wp.types.vector(length=REGION_BATCH, dtype=int)
    region_floats = wp.types.vector(length=REGION_BATCH, dtype=float)
    region_points = wp.types.matrix(shape=(REGION_BATCH, 3), dtype=float)
    COLOURS = colours
    STARTS = colours + 1
    SLEEP = sleep_ns

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_point(t: wp.tile(dtype=wp.vec3, shape=(CAPACITY,), storage="shared"), i: int, value: wp.vec3): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_weight(t: wp.tile(dtype=float, shape=(CAPACITY,), storage="shared"), i: int, value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_ends(t: wp.tile(dtype=int, shape=(STICKS,), storage="shared"), i: int, value: int): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_rest(t: wp.tile(dtype=float, shape=(STICKS,), storage="shared"), i: int, value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_start(t: wp.tile(dtype=int, shape=(STARTS,), storage="shared"), i: int, value: int): ...

    @wp.func
    def region_places(region: wp.array(dtype=int), r0: int, count: int, e0: int, threads: int):
        places = region_ints()
        for j in range(REGION_BATCH):
            places[j] = region[r0 + wp.min(e0 + j * threads, count - 1)]
        return places

    options = shared_sweep_options(max_registers)
    options["module_options"] = {**options["module_options"], "max_unroll": max(STICK_BATCH, REGION_BATCH)}

    @wp.kernel(module="unique", **options)
    def relax_chained(
        x: wp.array(dtype=wp.vec3),
        inv_mass: wp.array(dtype=float),
        region_start: wp.array(dtype=int),
        region: wp.array(dtype=int),
        stick_start: wp.array(dtype=int),
        stick_ends: wp.array(dtype=int),
        stick_rest: wp.array(dtype=float),
        neighbour_start: wp.array(dtype=int),
        neighbour: wp.array(dtype=int),
        clusters: int,
        sweeps: int,
        sync: wp.array(dtype=int),  # [ticket, finished, sweeps finished before this launch]
        done: wp.array(dtype=int),
        broken: wp.array(dtype=int),
    ):
        block, lane = wp.tid()
        threads = wp.block_dim()
        item_tile = wp.tile_empty(shape=STARTS, dtype=int, storage="shared")
        if lane == 0:
            put_start(item_tile, 1, sync[2])
            put_start(item_tile, 0, wp.atomic_add(sync, 0, 1))
        block_barrier()
        item = item_tile[0]
        earlier_sweeps = item_tile[1]
        block_barrier()  # item_tile is reused for the colours' starts below
        sweep = item // clusters
        c = item - sweep * clusters
        base_flag = earlier_sweeps + sweep
        k = neighbour_start[c] + lane
        k_end = neighbour_start[c + 1]
        while k < k_end:
            other = neighbour[k]
            need = base_flag
            if other < c:
                need = base_flag + 1
            if wait_done(done, other, need, SLEEP) != 0:
                broken[0] = 1
            k += threads
        block_barrier()

        r0 = region_start[c]
        count = region_start[c + 1] - r0
        base = c * COLOURS
        s0 = stick_start[base]
        sticks = stick_start[base + COLOURS] - s0
        points = wp.tile_empty(shape=CAPACITY, dtype=wp.vec3, storage="shared")
        weights = wp.tile_empty(shape=CAPACITY, dtype=float, storage="shared")
        ends = wp.tile_empty(shape=STICKS, dtype=int, storage="shared")
        rests = wp.tile_empty(shape=STICKS, dtype=float, storage="shared")
        starts = item_tile
        e0 = lane
        while e0 < count:
            places = region_places(region, r0, count, e0, threads)
            moved = region_points()
            held = region_floats()
            for j in range(REGION_BATCH):
                moved[j] = load_l2(x, places[j])
                held[j] = inv_mass[places[j]]
            for j in range(REGION_BATCH):
                if e0 + j * threads < count:
                    put_point(points, e0 + j * threads, moved[j])
                    put_weight(weights, e0 + j * threads, held[j])
            e0 += REGION_BATCH * threads
        e0 = lane
        while e0 < sticks:
            packed_ends = stick_ints()
            rest_lengths = stick_floats()
            for j in range(STICK_BATCH):
                s = s0 + wp.min(e0 + j * threads, sticks - 1)
                packed_ends[j] = streamed_int(stick_ends, s)
                rest_lengths[j] = streamed_float(stick_rest, s)
            for j in range(STICK_BATCH):
                if e0 + j * threads < sticks:
                    put_ends(ends, e0 + j * threads, packed_ends[j])
                    put_rest(rests, e0 + j * threads, rest_lengths[j])
            e0 += STICK_BATCH * threads
        e = lane
        while e < STARTS:
            put_start(starts, e, stick_start[base + e] - s0)
            e += threads
        block_barrier()

        for n in range(COLOURS):
            s = starts[n] + lane
            stop = starts[n + 1]
            while s < stop:
                packed = ends[s]
                a = packed & 0xFFFF
                b = packed >> 16
                wa = weights[a]
                wb = weights[b]
                xa = points[a]
                xb = points[b]
                d = stick_correction(xa, xb, wa, wb, rests[s], 1.0)
                put_point(points, a, xa + scaled(d, wa))
                put_point(points, b, xb - scaled(d, wb))
                s += threads
            block_barrier()

        e0 = lane
        while e0 < count:
            places = region_places(region, r0, count, e0, threads)
            for j in range(REGION_BATCH):
                if e0 + j * threads < count:
                    x[places[j]] = points[e0 + j * threads]
            e0 += REGION_BATCH * threads
        release_fence()
        block_barrier()
        if lane == 0:
            publish(done, c, base_flag + 1)
            if wp.atomic_add(sync, 1, 1) == clusters * sweeps - 1:
                sync[1] = 0
                sync[0] = 0
                sync[2] = earlier_sweeps + sweeps

    return relax_chained
