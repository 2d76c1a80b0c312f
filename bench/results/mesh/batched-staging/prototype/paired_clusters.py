"""Prototype, not measured yet: the clustered sweep (kernels/stick_clusters.py, rigid sticks only) with each block
taking two clusters of one cluster colour and issuing the second's staging loads before it projects the first, so
that one cluster's loads are in flight while the other's colours run (a launch of the landed kernel stages, then
projects, then writes back, every block in step). The two clusters' regions are disjoint (one cluster colour), so
the positions are the landed kernel's bit for bit. On the CPU (one lane a block) only the first batch is loaded
ahead; the rest follow as in the landed kernel."""

import warp as wp

from warp_verlet.kernels.grid_tiles import block_barrier, shared_sweep_options
from warp_verlet.kernels.positions import scaled
from warp_verlet.kernels.relax import stick_correction


def paired_clusters(region_capacity: int, stick_capacity: int, colours: int, block_dim: int = 256):
    CAPACITY, STICKS, COLOURS, STARTS = region_capacity, stick_capacity, colours, colours + 1
    STICK_BATCH = -(-stick_capacity // block_dim)
    REGION_BATCH = -(-region_capacity // block_dim)
    stick_ints = wp.types.vector(length=STICK_BATCH, dtype=int)
    stick_floats = wp.types.vector(length=STICK_BATCH, dtype=float)
    region_ints = wp.types.vector(length=REGION_BATCH, dtype=int)
    region_floats = wp.types.vector(length=REGION_BATCH, dtype=float)
    region_points = wp.types.matrix(shape=(REGION_BATCH, 3), dtype=float)

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

    options = shared_sweep_options(None)
    options["module_options"] = {**options["module_options"], "max_unroll": max(STICK_BATCH, REGION_BATCH)}

    @wp.kernel(module="unique", **options)
    def relax_paired_clusters(
        x: wp.array(dtype=wp.vec3),
        inv_mass: wp.array(dtype=float),
        region_start: wp.array(dtype=int),
        region: wp.array(dtype=int),
        stick_start: wp.array(dtype=int),
        stick_ends: wp.array(dtype=int),
        stick_rest: wp.array(dtype=float),
        first_cluster: int,
        end_cluster: int,
    ):
        """Block k sweeps clusters first_cluster + 2k and, where it is below end_cluster, the one after."""
        block, lane = wp.tid()
        threads = wp.block_dim()
        points = wp.tile_empty(shape=CAPACITY, dtype=wp.vec3, storage="shared")
        weights = wp.tile_empty(shape=CAPACITY, dtype=float, storage="shared")
        ends = wp.tile_empty(shape=STICKS, dtype=int, storage="shared")
        rests = wp.tile_empty(shape=STICKS, dtype=float, storage="shared")
        starts = wp.tile_empty(shape=STARTS, dtype=int, storage="shared")
        # The first batch of the block's first cluster, loaded here; each pass loads the next cluster's first
        # batch before it projects its own.
        c = first_cluster + 2 * block
        r0 = region_start[c]
        count = region_start[c + 1] - r0
        s0 = stick_start[c * COLOURS]
        sticks = stick_start[c * COLOURS + COLOURS] - s0
        places = region_ints()
        moved = region_points()
        held = region_floats()
        packed_ends = stick_ints()
        rest_lengths = stick_floats()
        for j in range(REGION_BATCH):
            places[j] = region[r0 + wp.min(lane + j * threads, count - 1)]
        for j in range(REGION_BATCH):
            moved[j] = x[places[j]]
            held[j] = inv_mass[places[j]]
        for j in range(STICK_BATCH):
            s = s0 + wp.min(lane + j * threads, sticks - 1)
            packed_ends[j] = stick_ends[s]
            rest_lengths[j] = stick_rest[s]
        for k in range(2):
            if c < end_cluster:
                # Store the batch loaded ahead, then load and store any further ones (the CPU's single lane).
                for j in range(REGION_BATCH):
                    if lane + j * threads < count:
                        put_point(points, lane + j * threads, moved[j])
                        put_weight(weights, lane + j * threads, held[j])
                for j in range(STICK_BATCH):
                    if lane + j * threads < sticks:
                        put_ends(ends, lane + j * threads, packed_ends[j])
                        put_rest(rests, lane + j * threads, rest_lengths[j])
                e0 = lane + REGION_BATCH * threads
                while e0 < count:
                    for j in range(REGION_BATCH):
                        e = e0 + j * threads
                        if e < count:
                            p = region[r0 + e]
                            put_point(points, e, x[p])
                            put_weight(weights, e, inv_mass[p])
                    e0 += REGION_BATCH * threads
                e0 = lane + STICK_BATCH * threads
                while e0 < sticks:
                    for j in range(STICK_BATCH):
                        e = e0 + j * threads
                        if e < sticks:
                            put_ends(ends, e, stick_ends[s0 + e])
                            put_rest(rests, e, stick_rest[s0 + e])
                    e0 += STICK_BATCH * threads
                e = lane
                while e < STARTS:
                    put_start(starts, e, stick_start[c * COLOURS + e] - s0)
                    e += threads
                block_barrier()
                # The next cluster's first batch, in flight while this one's colours run (its region is another
                # one of this cluster colour's, which no block here writes).
                cn = c + 1
                rn = int(0)
                countn = int(0)
                sn = int(0)
                sticksn = int(0)
                if k == 0 and cn < end_cluster:
                    rn = region_start[cn]
                    countn = region_start[cn + 1] - rn
                    sn = stick_start[cn * COLOURS]
                    sticksn = stick_start[cn * COLOURS + COLOURS] - sn
                    for j in range(REGION_BATCH):
                        places[j] = region[rn + wp.min(lane + j * threads, countn - 1)]
                    for j in range(STICK_BATCH):
                        s = sn + wp.min(lane + j * threads, sticksn - 1)
                        packed_ends[j] = stick_ends[s]
                        rest_lengths[j] = stick_rest[s]
                    for j in range(REGION_BATCH):
                        moved[j] = x[places[j]]
                        held[j] = inv_mass[places[j]]
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
                    out = region_ints()
                    for j in range(REGION_BATCH):
                        out[j] = region[r0 + wp.min(e0 + j * threads, count - 1)]
                    for j in range(REGION_BATCH):
                        if e0 + j * threads < count:
                            x[out[j]] = points[e0 + j * threads]
                    e0 += REGION_BATCH * threads
                block_barrier()  # the shared arrays are free for the next cluster
                c = cn
                r0 = rn
                count = countn
                s0 = sn
                sticks = sticksn

    return relax_paired_clusters
