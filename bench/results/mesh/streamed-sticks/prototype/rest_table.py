"""Prototype: the clustered sweep (rigid sticks) with 4-byte sticks where a cluster's rest lengths repeat. Each
cluster keeps a table of its distinct rest lengths; a stick is one int, its two places in the region (E bits
each, E from the region capacity) and the index of its rest length in its cluster's table above them. Lossless:
the same float32 rest lengths, so the same positions bit for bit. A mesh whose clusters hold more distinct
lengths than the index's bits can address keeps the 8-byte sticks (``encode`` returns None).

    PYTHONPATH=. python bench/results/mesh/streamed-sticks/prototype/rest_table.py 512 1024
"""
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.kernels.grid_tiles import block_barrier, shared_sweep_options
from warp_verlet.kernels.positions import scaled
from warp_verlet.kernels.relax import stick_correction
from warp_verlet.kernels.stick_clusters import streamed_int


def encode(layout):
    """(packed sticks (S,) int32, table_start (C + 1,) int32, table (T,) float32, end bits, table capacity), or
    None where a cluster's distinct rest lengths do not fit the bits left."""
    end_bits = max(1, int(layout.capacity - 1).bit_length())
    index_bits = 32 - 2 * end_bits
    clusters = len(layout.region_start) - 1
    per_cluster = np.diff(layout.stick_start[::layout.colours])
    owner = np.repeat(np.arange(clusters), per_cluster)
    # distinct (cluster, rest) pairs, in cluster order
    keys = np.stack([owner, layout.rest.view(np.int32)], axis=1)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    table_start = np.zeros(clusters + 1, np.int64)
    np.cumsum(np.bincount(unique[:, 0], minlength=clusters), out=table_start[1:])
    index = inverse - table_start[owner]
    largest = int(np.diff(table_start).max())
    if largest > (1 << index_bits) - 1 if index_bits < 31 else False:
        return None
    local = layout.stick_local.astype(np.int64)
    packed = local[:, 0] | local[:, 1] << end_bits | index << 2 * end_bits
    packed = packed.astype(np.uint32).view(np.int32)
    table = unique[:, 1].astype(np.int32).view(np.float32)
    return packed, table_start.astype(np.int32), table, end_bits, -(-largest // 32) * 32


def relax_rest_table(region_capacity, stick_capacity, table_capacity, colours, end_bits, block_dim):
    CAPACITY, STICKS, TABLE, COLOURS, STARTS = region_capacity, stick_capacity, table_capacity, colours, colours + 1
    E = end_bits
    END_MASK = (1 << E) - 1
    INDEX_MASK = (1 << (32 - 2 * E)) - 1
    STICK_BATCH = -(-stick_capacity // block_dim)
    REGION_BATCH = -(-region_capacity // block_dim)
    stick_ints = wp.types.vector(length=STICK_BATCH, dtype=int)
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
    def put_rest(t: wp.tile(dtype=float, shape=(TABLE,), storage="shared"), i: int, value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_start(t: wp.tile(dtype=int, shape=(STARTS,), storage="shared"), i: int, value: int): ...

    @wp.func
    def region_places(region: wp.array(dtype=int), r0: int, count: int, e0: int, threads: int):
        places = region_ints()
        for j in range(REGION_BATCH):
            places[j] = region[r0 + wp.min(e0 + j * threads, count - 1)]
        return places

    options = shared_sweep_options(None)
    options["module_options"] = {**options["module_options"], "max_unroll": max(STICK_BATCH, REGION_BATCH)}

    @wp.kernel(module="unique", **options)
    def relax_rest_table_clusters(
        x: wp.array(dtype=wp.vec3),
        inv_mass: wp.array(dtype=float),
        region_start: wp.array(dtype=int),
        region: wp.array(dtype=int),
        stick_start: wp.array(dtype=int),
        sticks_packed: wp.array(dtype=int),
        table_start: wp.array(dtype=int),
        table: wp.array(dtype=float),
        first_cluster: int,
    ):
        block, lane = wp.tid()
        threads = wp.block_dim()
        c = first_cluster + block
        r0 = region_start[c]
        count = region_start[c + 1] - r0
        base = c * COLOURS
        s0 = stick_start[base]
        sticks = stick_start[base + COLOURS] - s0
        t0 = table_start[c]
        lengths = table_start[c + 1] - t0
        points = wp.tile_empty(shape=CAPACITY, dtype=wp.vec3, storage="shared")
        weights = wp.tile_empty(shape=CAPACITY, dtype=float, storage="shared")
        ends = wp.tile_empty(shape=STICKS, dtype=int, storage="shared")
        rests = wp.tile_empty(shape=TABLE, dtype=float, storage="shared")
        starts = wp.tile_empty(shape=STARTS, dtype=int, storage="shared")
        e0 = lane
        while e0 < count:
            places = region_places(region, r0, count, e0, threads)
            moved = region_points()
            held = region_floats()
            for j in range(REGION_BATCH):
                moved[j] = x[places[j]]
                held[j] = inv_mass[places[j]]
            for j in range(REGION_BATCH):
                if e0 + j * threads < count:
                    put_point(points, e0 + j * threads, moved[j])
                    put_weight(weights, e0 + j * threads, held[j])
            e0 += REGION_BATCH * threads
        e0 = lane
        while e0 < sticks:
            packed_ends = stick_ints()
            for j in range(STICK_BATCH):
                packed_ends[j] = streamed_int(sticks_packed, s0 + wp.min(e0 + j * threads, sticks - 1))
            for j in range(STICK_BATCH):
                if e0 + j * threads < sticks:
                    put_ends(ends, e0 + j * threads, packed_ends[j])
            e0 += STICK_BATCH * threads
        e = lane
        while e < lengths:
            put_rest(rests, e, table[t0 + e])
            e += threads
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
                a = packed & END_MASK
                b = (packed >> E) & END_MASK
                r = rests[(packed >> (2 * E)) & INDEX_MASK]
                wa = weights[a]
                wb = weights[b]
                xa = points[a]
                xb = points[b]
                d = stick_correction(xa, xb, wa, wb, r, 1.0)
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

    return relax_rest_table_clusters


if __name__ == "__main__":
    from bench.common import captured, graph_median_ms
    from bench.mesh_throughput import grid_and_meshes
    from warp_verlet.constraints import stick_clusters as sc
    from warp_verlet.core.simulator import Simulator
    from warp_verlet.kernels.stick_clusters import relax_stick_clusters

    wp.config.quiet = True
    DEV = os.environ.get("DEV", "cuda")
    out = Path(os.environ.get("OUT", "/tmp"))
    rows = []
    for n in [int(a) for a in sys.argv[1:]] or [512, 1024]:
        with tempfile.TemporaryDirectory() as d:
            scenes = grid_and_meshes(n, 4, 8, "corners", "ply", Path(d))
            for variant in ("triangle mesh", "quad mesh"):
                sim = Simulator(scenes[variant][0], DEV, sticks="clustered")
                for _ in range(3):
                    sim.step_frame()
                x = sim.state.particle_q
                start = wp.clone(x)
                none = wp.empty(0, dtype=float, device=DEV)
                data = sim.model.constraints["stick clusters"]
                colour = np.repeat(np.arange(len(sim.model.colour_ranges)), [k for _, k in sim.model.colour_ranges])
                layout = sc.cluster_layout(sim.model.host_sticks, sim.model.host_rest, colour,
                                           len(sim.model.colour_ranges), sim.model.rest_positions)
                packed, table_start, table, end_bits, table_capacity = encode(layout)
                print(f"{n} {variant}: {len(table)} distinct (cluster, rest) pairs for {len(packed)} sticks, "
                      f"at most {int(np.diff(table_start).max())} a cluster, {end_bits} bits an end", flush=True)
                packed_d = wp.array(packed, dtype=int, device=DEV)
                table_start_d = wp.array(table_start, dtype=int, device=DEV)
                table_d = wp.array(table, dtype=float, device=DEV)
                landed = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=256)
                tabled = relax_rest_table(data.capacity, data.stick_capacity, table_capacity, data.colours, end_bits,
                                          256)

                def landed_sweep():
                    for first, count in data.launches:
                        wp.launch_tiled(landed, dim=[count], block_dim=256, device=DEV,
                                        inputs=[x, sim.model.inv_mass, data.region_start, data.region,
                                                data.stick_start, data.stick_ends, data.rest, none, 0.0, none, first])

                def tabled_sweep():
                    for first, count in data.launches:
                        wp.launch_tiled(tabled, dim=[count], block_dim=256, device=DEV,
                                        inputs=[x, sim.model.inv_mass, data.region_start, data.region,
                                                data.stick_start, packed_d, table_start_d, table_d, first])

                results = {}
                for name, sweep in (("landed", landed_sweep), ("rest table", tabled_sweep)):
                    wp.copy(x, start)
                    sweep()
                    wp.synchronize()
                    results[name] = x.numpy().copy()
                    row = {"size": n, "variant": variant, "kernel": name}
                    if DEV != "cpu":
                        wp.copy(x, start)
                        graph = captured(sweep, DEV)
                        wp.capture_launch(graph)
                        median_ms = graph_median_ms(graph)
                        row["32 sweeps ms"] = round(median_ms, 4)
                    rows.append(row)
                    print(row, flush=True)
                same = bool(np.array_equal(results["landed"], results["rest table"]))
                print(f"{n} {variant}: rest table equal to landed bit for bit: {same}", flush=True)
                rows.append({"size": n, "variant": variant, "bitwise": same})
                sim.close()
    (out / os.environ.get("STEM", "rest_table.json")).write_text(json.dumps(rows, indent=1))
