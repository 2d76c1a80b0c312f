"""Prototype: the clustered sweep's rigid kernel with a cluster's own particles (a run of consecutive particle
indices in its region, under Morton order) staged and written back without their region indices; the halo through
the indices as before. Timed against the landed kernel on one triangle-mesh model (32 sweeps captured, CUDA events,
median of 7, three alternating rounds), positions compared bit for bit.

    PYTHONPATH=. python bench/results/mesh/own-run/own_run.py 512 1024
"""
import json, os, sys, tempfile
from pathlib import Path

import numpy as np
import warp as wp

from bench.common import captured, graph_median_ms
from bench.mesh_throughput import grid_and_meshes
from warp_verlet.constraints.stick_clusters import CLUSTER_BLOCK
from warp_verlet.core.simulator import Simulator
from warp_verlet.kernels.stick_clusters import relax_stick_clusters, streamed_int, streamed_float
from warp_verlet.kernels.grid_tiles import block_barrier, shared_sweep_options
from warp_verlet.kernels.positions import scaled
from warp_verlet.kernels.relax import stick_correction

wp.config.quiet = True
DEV = os.environ.get("DEV", "cuda")
out = Path(os.environ.get("OUT", "/tmp"))


def make_kernel(region_capacity, stick_capacity, colours, block_dim, max_registers=None):
    CAPACITY, STICKS = region_capacity, stick_capacity
    STICK_BATCH = -(-stick_capacity // block_dim)
    REGION_BATCH = -(-region_capacity // block_dim)
    stick_ints = wp.types.vector(length=STICK_BATCH, dtype=int)
    stick_floats = wp.types.vector(length=STICK_BATCH, dtype=float)
    region_ints = wp.types.vector(length=REGION_BATCH, dtype=int)
    region_floats = wp.types.vector(length=REGION_BATCH, dtype=float)
    region_points = wp.types.matrix(shape=(REGION_BATCH, 3), dtype=float)
    COLOURS = colours
    STARTS = colours + 1

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
    def region_places(region: wp.array(dtype=int), r0: int, count: int, e0: int, threads: int, own: wp.vec3i):
        places = region_ints()
        for j in range(REGION_BATCH):
            e = wp.min(e0 + j * threads, count - 1)
            k = e - own[0]
            if k >= 0 and k < own[2]:
                places[j] = own[1] + k
            else:
                places[j] = region[r0 + e]
        return places

    options = shared_sweep_options(max_registers)
    options["module_options"] = {**options["module_options"], "max_unroll": max(STICK_BATCH, REGION_BATCH)}

    @wp.kernel(module="unique", **options)
    def relax_own_run(
        x: wp.array(dtype=wp.vec3),
        inv_mass: wp.array(dtype=float),
        region_start: wp.array(dtype=int),
        region: wp.array(dtype=int),
        own_run: wp.array(dtype=wp.vec3i),
        stick_start: wp.array(dtype=int),
        stick_ends: wp.array(dtype=int),
        stick_rest: wp.array(dtype=float),
        first_cluster: int,
    ):
        block, lane = wp.tid()
        threads = wp.block_dim()
        c = first_cluster + block
        r0 = region_start[c]
        count = region_start[c + 1] - r0
        own = own_run[c]
        base = c * COLOURS
        s0 = stick_start[base]
        sticks = stick_start[base + COLOURS] - s0
        points = wp.tile_empty(shape=CAPACITY, dtype=wp.vec3, storage="shared")
        weights = wp.tile_empty(shape=CAPACITY, dtype=float, storage="shared")
        ends = wp.tile_empty(shape=STICKS, dtype=int, storage="shared")
        rests = wp.tile_empty(shape=STICKS, dtype=float, storage="shared")
        starts = wp.tile_empty(shape=STARTS, dtype=int, storage="shared")
        e0 = lane
        while e0 < count:
            places = region_places(region, r0, count, e0, threads, own)
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
            places = region_places(region, r0, count, e0, threads, own)
            for j in range(REGION_BATCH):
                if e0 + j * threads < count:
                    x[places[j]] = points[e0 + j * threads]
            e0 += REGION_BATCH * threads

    return relax_own_run


def own_runs(region_start, region, own_count):
    """Per cluster (place of its own run in the region, first particle, length): its own particles where they are
    consecutive indices forming one run of the sorted region, else (0, 0, 0)."""
    runs = np.zeros((len(region_start) - 1, 3), np.int32)
    found = 0
    for c in range(len(region_start) - 1):
        part = region[region_start[c]:region_start[c + 1]]
        jumps = np.flatnonzero(np.diff(part) != 1)
        bounds = np.r_[0, jumps + 1, len(part)]
        lengths = np.diff(bounds)
        k = int(np.argmax(lengths))
        runs[c] = (bounds[k], part[bounds[k]], lengths[k])
        found += lengths[k]
    return runs, found


rows = []
for n in [int(a) for a in sys.argv[1:]] or [512, 1024]:
    with tempfile.TemporaryDirectory() as d:
        scene = grid_and_meshes(n, 4, 8, "corners", "ply", Path(d))["triangle mesh"][0]
        sim = Simulator(scene, DEV, sticks="clustered", particle_order="morton")
        for _ in range(3):
            sim.step_frame()
        data = sim.model.constraints["stick clusters"]
        runs, found = own_runs(data.region_start.numpy(), data.region.numpy(), None)
        print(f"{n}: region entries {len(data.region)}, in runs {found} ({found / len(data.region):.1%}); "
              f"run lengths {np.percentile(runs[:, 2], [0, 50, 100])}", flush=True)
        own = wp.array(runs, dtype=wp.vec3i, device=DEV)
        x = sim.state.particle_q
        start = wp.clone(x)
        none = wp.empty(0, dtype=float, device=DEV)
        landed = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, False, block_dim=CLUSTER_BLOCK)
        variants = {"landed": landed,
                    "own run": make_kernel(data.capacity, data.stick_capacity, data.colours, CLUSTER_BLOCK),
                    "own run, 32 registers": make_kernel(data.capacity, data.stick_capacity, data.colours,
                                                          CLUSTER_BLOCK, 32)}

        def sweeper(name, kernel):
            def sweep():
                for first, count in data.launches:
                    if name == "landed":
                        inputs = [x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                  data.stick_ends, data.rest, none, 1e4, none, first]
                    else:
                        inputs = [x, sim.model.inv_mass, data.region_start, data.region, own, data.stick_start,
                                  data.stick_ends, data.rest, first]
                    wp.launch_tiled(kernel, dim=[count], block_dim=CLUSTER_BLOCK, device=DEV, inputs=inputs)
            return sweep

        results, graphs = {}, {}
        for name, kernel in variants.items():
            sweep = sweeper(name, kernel)
            wp.copy(x, start)
            sweep()
            wp.synchronize()
            results[name] = x.numpy().copy()
            if DEV != "cpu":
                wp.copy(x, start)
                graphs[name] = captured(sweep, DEV)
                wp.capture_launch(graphs[name])
        same = {name: bool(np.array_equal(results["landed"], r)) for name, r in results.items()}
        times = {name: [] for name in graphs}
        for _ in range(3):
            for name, graph in graphs.items():
                wp.copy(x, start)
                times[name].append(graph_median_ms(graph))
        for name in variants:
            row = {"size": n, "kernel": name, "bit for bit": same[name]}
            if times.get(name):
                row["32 sweeps ms"] = round(float(np.median(times[name])), 4)
                row["runs"] = [round(t, 4) for t in times[name]]
            rows.append(row)
            print(row, flush=True)
        sim.close()
(out / "own_run.json").write_text(json.dumps(rows, indent=1))
