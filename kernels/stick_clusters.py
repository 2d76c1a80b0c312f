"""Clustered sweeps over stick arrays (warp_verlet/constraints/stick_clusters.py): the mesh's form of the grid's
tiled sweep (kernels/grid_tiles.py), block Gauss-Seidel over clusters of particles held in shared memory.

A cluster owns the sticks whose first particle it holds; its *region* is its particles and the other ends of its
sticks. A block stages its cluster's region (positions and weights) in shared memory, projects the cluster's
sticks colour by colour in the stick colouring's order, a thread per stick of the colour (a colour's sticks share
no particle; a barrier separates the colours), and writes the region back. Clusters are coloured so that the
regions of one cluster colour share no particle: a launch per cluster colour, Gauss-Seidel across them.

Chained (large meshes, constraints/stick_clusters.py ``MIN_CHAINED_PARTICLES``), a sweep is one launch of every
cluster instead: a block takes the next cluster from a counter, in the cluster colours' order, and before it reads
its region waits only for the clusters whose regions share a particle with its own (each one before it in the
order to have finished this sweep, each one after it, and itself, the sweep before), then publishes its own count
of finished sweeps. Two clusters that share a particle update it in the launches' order, so the positions are the
same bit for bit; blocks of different colours overlap instead of a launch's blocks staging, projecting and writing
back in step. A block waits only for clusters taken before its own, by blocks that are running or done, so none
waits forever. Rigid sticks are staged before the wait, since they do not move. The positions are read from L2
(``__ldcg``), since a multiprocessor's L1 may hold what an earlier block read, and published behind a
``__threadfence`` (bench/results/mesh/chained).

Each stick is stored once, in the order the blocks read it (cluster colour, cluster, stick colour), with its two
ends as places in its cluster's region packed into one int (``a | b << 16``; a region holds at most 2048
particles), so that a block reads its sticks as one contiguous run. A block stages its sticks (ends, rest lengths
and the colours' starts) in shared memory with its region, before the first barrier, so that the colour loop,
which runs a projection, a barrier and the next colour, touches shared memory only (unless a soft stick's
compliance and tension are not staged). Read from global memory inside the loop, each colour waited on its own
sticks' loads. A lane issues all of its share of the staging's loads before it stores any (an unrolled batch in
registers): a store to shared memory waits on its load, and the compiler does not move the next global load above
it, so staged one element at a time a lane had a single load in flight, while every block of a launch (under one
wave at 1024^2) staged at once. The write-back batches the region's indices the same way
(bench/results/mesh/batched-staging). With soft sticks staged, a lane goes further: the sticks' loads go out
before the region's stores, so that they overlap the region's second round trip (its indices, then positions);
the rigid kernel would need more than 32 registers a thread for that, and loses more by it than it gains
(bench/results/mesh/joint-staging).

A sweep reads each stick once, and a large mesh's sticks (8 bytes each, 50 MB at 1024^2) outgrow the L2 cache that
would otherwise hold the positions, weights and region indices every launch reads again. So the sticks' staging
loads are marked as data read once (``streamed_int``, ``streamed_float``: CUDA's ``__ldcs``, evicted first), which
leaves the L2 to the data that is reused (bench/results/mesh/streamed-sticks).

The projection is ``stick_correction`` (``compliant_correction`` for soft sticks), as in every other form. A soft
stick's compliance and tension are either staged with the stick and its tension written back after the colours,
or read and written in global memory inside the colour loop (a stick is projected once a sweep, by one thread, so
either is the same arithmetic). Staged, they take a third more shared memory a block, and measured faster at
every size; global memory serves where staging would pass a block's shared-memory limit
(constraints/stick_clusters.py, ``stage_soft_sticks``). Only the order of the projections differs from the other
forms, and that order is fixed (cluster colour, cluster, stick colour, stick), which the CPU runs literally (one
lane per block).
"""

import warp as wp

from .grid_tiles import block_barrier, shared_sweep_options
from .positions import scaled
from .relax import compliant_correction, stick_correction

_STREAMED_LOAD = """
#if defined(__CUDA_ARCH__)
    return __ldcs(wp::address(values, i));
#else
    return wp::index(values, i);
#endif
"""


@wp.func_native(_STREAMED_LOAD)
def streamed_int(values: wp.array(dtype=int), i: int) -> int:
    """values[i], loaded on CUDA as data read once (evicted from the caches first)."""
    ...


@wp.func_native(_STREAMED_LOAD)
def streamed_float(values: wp.array(dtype=float), i: int) -> float:
    """values[i], loaded on CUDA as data read once (evicted from the caches first)."""
    ...


_WAIT_FOR_CLUSTER = """
#if defined(__CUDA_ARCH__)
    volatile int* flag = (volatile int*)wp::address(done, d);
    while ((int)((unsigned)*flag - (unsigned)need) < 0) {
#if __CUDA_ARCH__ >= 700
        __nanosleep(32);  // leave the issue slots to the blocks being waited for
#endif
    }
    __threadfence();
    return 0;
#else
    return (int)((unsigned)wp::index(done, d) - (unsigned)need) < 0 ? 1 : 0;
#endif
"""


@wp.func_native(_WAIT_FOR_CLUSTER)
def wait_for_cluster(done: wp.array(dtype=int), d: int, need: int) -> int:
    """Wait until cluster d's count of finished sweeps, done[d], reaches ``need`` (compared as a wrapping
    difference), then see every store it made before. On the CPU, where a launch's blocks run one after another,
    nothing can be waited for: return 1 where it has not been reached (the items' order is broken), else 0."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    __threadfence();
#endif
""")
def release_fence():
    """This thread's global stores are seen by the whole device before any store it makes after this."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    atomicExch((int*)wp::address(done, c), value);
#else
    wp::index(done, c) = value;
#endif
""")
def publish_done(done: wp.array(dtype=int), c: int, value: int):
    """done[c] = value, as one store another block may be spinning on."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    const float* p = (const float*)wp::address(x, i);
    return wp::vec3(__ldcg(p), __ldcg(p + 1), __ldcg(p + 2));
#else
    return wp::index(x, i);
#endif
""")
def load_from_l2(x: wp.array(dtype=wp.vec3), i: int) -> wp.vec3:
    """x[i], read from L2, where another block's stores of this launch are seen (a multiprocessor's L1 may still
    hold what an earlier block on it read)."""
    ...


_KERNELS: dict = {}


@wp.func
def wait_for_neighbours(c: int, finished_sweeps: int, lane: int, threads: int, neighbour_start: wp.array(dtype=int),
                        neighbour: wp.array(dtype=int), done: wp.array(dtype=int), order_broken: wp.array(dtype=int)):
    """A chained sweep's wait before cluster c reads its region: each neighbour before c in the order has finished
    this sweep (finished_sweeps + 1), each after it, and c itself, the one before. The block's lanes share the
    list; a barrier must follow before any lane reads the region."""
    k = neighbour_start[c] + lane
    while k < neighbour_start[c + 1]:
        other = neighbour[k]
        need = finished_sweeps
        if other < c:
            need = finished_sweeps + 1
        if wait_for_cluster(done, other, need) != 0:
            order_broken[0] = 1
        k += threads


def relax_stick_clusters(region_capacity: int, stick_capacity: int, colours: int, compliant: bool = False,
                         max_registers: int | None = None, stage_soft: bool = True, *, block_dim: int,
                         chained: bool = False):
    """The clustered sweep's kernel for regions of at most ``region_capacity`` particles, clusters of at most
    ``stick_capacity`` sticks, and ``colours`` stick colours (the shared arrays' lengths and the colour loop's
    bound, compile-time constants), for blocks of ``block_dim`` threads on CUDA (it sizes the staging's batches;
    launched with another block size, the kernel gives the same positions in more or fewer batches).
    ``compliant``: XPBD sticks (kernels/relax.py), each with its compliance and the tension it has accumulated over
    the substep's sweeps, staged in shared memory and written back with the sticks (``stage_soft``) or read and
    written in global memory; otherwise the compliance and tension arrays are not read. ``max_registers`` caps a
    CUDA thread's registers (None: the compiler's). ``chained``: one launch a sweep, each block taking the next
    cluster in order and waiting for its neighbours (the module's docstring); otherwise one launch a cluster colour
    (``first_cluster`` its first cluster), and the chain's arrays are not read."""
    key = (region_capacity, stick_capacity, colours, compliant, max_registers, compliant and stage_soft, block_dim,
           chained)
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(*key)
    return _KERNELS[key]


def _make_kernel(region_capacity: int, stick_capacity: int, colours: int, compliant: bool, max_registers: int | None,
                 stage_soft: bool, block_dim: int, chained: bool):
    CAPACITY = region_capacity
    STICKS = stick_capacity
    # Loads a lane issues before it stores any of them: all of its share of the block's sticks (or region) at
    # block_dim threads, so that a CUDA lane has them all in flight at once.
    STICK_BATCH = -(-stick_capacity // block_dim)
    REGION_BATCH = -(-region_capacity // block_dim)
    stick_ints = wp.types.vector(length=STICK_BATCH, dtype=int)
    stick_floats = wp.types.vector(length=STICK_BATCH, dtype=float)
    region_ints = wp.types.vector(length=REGION_BATCH, dtype=int)
    region_floats = wp.types.vector(length=REGION_BATCH, dtype=float)
    region_points = wp.types.matrix(shape=(REGION_BATCH, 3), dtype=float)
    STAGED_SOFT = compliant and stage_soft
    UNSTAGED_SOFT = compliant and not stage_soft
    SOFT_STICKS = stick_capacity if STAGED_SOFT else 1  # the compliances' and tensions' shared arrays
    COLOURS = colours
    STARTS = colours + 1
    CHAINED = chained

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_point(t: wp.tile(dtype=wp.vec3, shape=(CAPACITY,), storage="shared"), i: int, value: wp.vec3): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_weight(t: wp.tile(dtype=float, shape=(CAPACITY,), storage="shared"), i: int, value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_ends(t: wp.tile(dtype=int, shape=(STICKS,), storage="shared"), i: int, value: int): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_rest(t: wp.tile(dtype=float, shape=(STICKS,), storage="shared"), i: int, value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_soft(t: wp.tile(dtype=float, shape=(SOFT_STICKS,), storage="shared"), i: int, value: float): ...

    @wp.func
    def region_places(region: wp.array(dtype=int), r0: int, count: int, e0: int, threads: int):
        """A lane's batch of the region's particles from its place e0 (a lane past the region reads its last
        particle again, so that every load of the batch is issued unconditionally)."""
        places = region_ints()
        for j in range(REGION_BATCH):
            places[j] = region[r0 + wp.min(e0 + j * threads, count - 1)]
        return places

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_start(t: wp.tile(dtype=int, shape=(STARTS,), storage="shared"), i: int, value: int): ...

    @wp.func
    def stage_sticks(ends: wp.tile(dtype=int, shape=(STICKS,), storage="shared"),
                     rests: wp.tile(dtype=float, shape=(STICKS,), storage="shared"),
                     stick_ends: wp.array(dtype=int), stick_rest: wp.array(dtype=float), s0: int, sticks: int,
                     lane: int, threads: int):
        """A rigid cluster's sticks into shared memory, a batch's loads before its stores."""
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

    options = shared_sweep_options(max_registers)
    options["module_options"] = {**options["module_options"], "max_unroll": max(STICK_BATCH, REGION_BATCH)}

    @wp.kernel(module="unique", **options)
    def relax_stick_clusters(
        x: wp.array(dtype=wp.vec3),
        inv_mass: wp.array(dtype=float),
        region_start: wp.array(dtype=int),
        region: wp.array(dtype=int),
        stick_start: wp.array(dtype=int),
        stick_ends: wp.array(dtype=int),
        stick_rest: wp.array(dtype=float),
        stick_compliance: wp.array(dtype=float),
        inv_dt2: float,
        tension: wp.array(dtype=float),
        first_cluster: int,
        neighbour_start: wp.array(dtype=int),
        neighbour: wp.array(dtype=int),
        chain: wp.array(dtype=int),
        done: wp.array(dtype=int),
        order_broken: wp.array(dtype=int),
    ):
        """One sweep over the clusters first_cluster, first_cluster + 1, ... (one cluster colour; block k takes
        cluster first_cluster + k). Cluster c's region is region[region_start[c] : region_start[c + 1]]; its
        sticks of colour n are stick_start[c * COLOURS + n] .. stick_start[c * COLOURS + n + 1] - 1, each given
        by its ends' places in the region, packed a | b << 16. Compliant: stick_compliance (m/N) and tension (the
        substep's mu so far, updated) are in the same order as the sticks.

        Chained (a launch of every cluster, blocks = clusters): a block takes the next cluster c from chain[0] and
        waits for each cluster of neighbour[neighbour_start[c] : neighbour_start[c + 1]] (those whose regions share
        a particle with c's, and c itself) to have finished chain[2] + 1 sweeps if it comes before c, chain[2] if
        not (done[d]: the sweeps cluster d has finished); it then sets done[c] to chain[2] + 1. The block that
        finishes last starts the next launch's count: chain[0] and chain[1] (blocks finished) to 0, chain[2] + 1.
        On the CPU a wait that would not be met sets order_broken[0] to 1 instead."""
        block, lane = wp.tid()
        threads = wp.block_dim()
        starts = wp.tile_empty(shape=STARTS, dtype=int, storage="shared")
        c = first_cluster + block
        finished_sweeps = int(0)
        if wp.static(CHAINED):
            if lane == 0:
                put_start(starts, 0, wp.atomic_add(chain, 0, 1))
                put_start(starts, 1, chain[2])
            block_barrier()
            c = starts[0]
            finished_sweeps = starts[1]
            block_barrier()  # every lane has read them before the staging reuses the starts
        r0 = region_start[c]
        count = region_start[c + 1] - r0
        base = c * COLOURS
        s0 = stick_start[base]
        sticks = stick_start[base + COLOURS] - s0
        points = wp.tile_empty(shape=CAPACITY, dtype=wp.vec3, storage="shared")
        weights = wp.tile_empty(shape=CAPACITY, dtype=float, storage="shared")
        ends = wp.tile_empty(shape=STICKS, dtype=int, storage="shared")
        rests = wp.tile_empty(shape=STICKS, dtype=float, storage="shared")
        alphas = wp.tile_empty(shape=SOFT_STICKS, dtype=float, storage="shared")
        tensions = wp.tile_empty(shape=SOFT_STICKS, dtype=float, storage="shared")
        if wp.static(STAGED_SOFT):
            if wp.static(CHAINED):
                wait_for_neighbours(c, finished_sweeps, lane, threads, neighbour_start, neighbour, done, order_broken)
                block_barrier()
            # One batch: region indices and colour starts, then positions and weights, then the sticks, before any
            # store (the module's docstring says why only here).
            e_region = lane
            e_stick = lane
            e_start = lane
            while e_region < count or e_stick < sticks or e_start < STARTS:
                places = region_ints()
                start = int(0)
                if e_region < count:
                    places = region_places(region, r0, count, e_region, threads)
                if e_start < STARTS:
                    start = stick_start[base + e_start]
                moved = region_points()
                held = region_floats()
                if e_region < count:
                    for j in range(REGION_BATCH):
                        if wp.static(CHAINED):
                            moved[j] = load_from_l2(x, places[j])
                        else:
                            moved[j] = x[places[j]]
                        held[j] = inv_mass[places[j]]
                packed_ends = stick_ints()
                rest_lengths = stick_floats()
                stick_alphas = stick_floats()
                stick_tensions = stick_floats()
                if e_stick < sticks:
                    for j in range(STICK_BATCH):
                        s = s0 + wp.min(e_stick + j * threads, sticks - 1)
                        packed_ends[j] = streamed_int(stick_ends, s)
                        rest_lengths[j] = streamed_float(stick_rest, s)
                        stick_alphas[j] = streamed_float(stick_compliance, s)
                        stick_tensions[j] = tension[s]
                if e_region < count:
                    for j in range(REGION_BATCH):
                        if e_region + j * threads < count:
                            put_point(points, e_region + j * threads, moved[j])
                            put_weight(weights, e_region + j * threads, held[j])
                if e_stick < sticks:
                    for j in range(STICK_BATCH):
                        if e_stick + j * threads < sticks:
                            put_ends(ends, e_stick + j * threads, packed_ends[j])
                            put_rest(rests, e_stick + j * threads, rest_lengths[j])
                            put_soft(alphas, e_stick + j * threads, stick_alphas[j])
                            put_soft(tensions, e_stick + j * threads, stick_tensions[j])
                if e_start < STARTS:
                    put_start(starts, e_start, start - s0)
                e_region += REGION_BATCH * threads
                e_stick += STICK_BATCH * threads
                e_start += threads
        else:
            if wp.static(CHAINED):
                # The sticks do not move: staged while the neighbours finish, before the wait.
                stage_sticks(ends, rests, stick_ends, stick_rest, s0, sticks, lane, threads)
                wait_for_neighbours(c, finished_sweeps, lane, threads, neighbour_start, neighbour, done, order_broken)
                block_barrier()
            e0 = lane
            while e0 < count:
                # A batch's loads first, then its stores.
                places = region_places(region, r0, count, e0, threads)
                moved = region_points()
                held = region_floats()
                for j in range(REGION_BATCH):
                    if wp.static(CHAINED):
                        moved[j] = load_from_l2(x, places[j])
                    else:
                        moved[j] = x[places[j]]
                    held[j] = inv_mass[places[j]]
                for j in range(REGION_BATCH):
                    if e0 + j * threads < count:
                        put_point(points, e0 + j * threads, moved[j])
                        put_weight(weights, e0 + j * threads, held[j])
                e0 += REGION_BATCH * threads
            if wp.static(not CHAINED):
                stage_sticks(ends, rests, stick_ends, stick_rest, s0, sticks, lane, threads)
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
                if wp.static(STAGED_SOFT):
                    d, mu = compliant_correction(xa, xb, wa, wb, rests[s], 1.0, alphas[s], inv_dt2, tensions[s])
                    put_soft(tensions, s, mu)
                elif wp.static(UNSTAGED_SOFT):
                    d, mu = compliant_correction(xa, xb, wa, wb, rests[s], 1.0, stick_compliance[s0 + s], inv_dt2,
                                                 tension[s0 + s])
                    tension[s0 + s] = mu
                else:
                    d = stick_correction(xa, xb, wa, wb, rests[s], 1.0)
                put_point(points, a, xa + scaled(d, wa))
                put_point(points, b, xb - scaled(d, wb))
                s += threads
            block_barrier()  # the next colour reads this one's moves

        e0 = lane
        while e0 < count:
            places = region_places(region, r0, count, e0, threads)
            for j in range(REGION_BATCH):
                if e0 + j * threads < count:
                    x[places[j]] = points[e0 + j * threads]
            e0 += REGION_BATCH * threads
        if wp.static(STAGED_SOFT):
            e = lane
            while e < sticks:
                tension[s0 + e] = tensions[e]
                e += threads
        if wp.static(CHAINED):
            release_fence()
            block_barrier()
            if lane == 0:
                publish_done(done, c, finished_sweeps + 1)
                if wp.atomic_add(chain, 1, 1) == region_start.shape[0] - 2:
                    chain[0] = 0
                    chain[1] = 0
                    chain[2] = finished_sweeps + 1

    return relax_stick_clusters
