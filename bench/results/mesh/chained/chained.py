"""The clustered sweep as chained launches (chained_kernel.py: K sweeps a launch, each cluster waiting only on its
neighbours) beside the landed one (a launch per cluster colour), on one triangle-mesh model of the benchmark's
hanging cloth (4 x 8): positions after 8 sweeps compared bit for bit, and on CUDA 32 sweeps captured in a graph
and timed with CUDA events (median of 7).

    PYTHONPATH=. python bench/results/mesh/chained/chained.py 512 1024
"""
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import warp as wp

sys.path.insert(0, str(Path(__file__).parent))
from chained_kernel import chained_kernel  # noqa: E402

from bench.common import captured, graph_median_ms  # noqa: E402
from bench.mesh_throughput import grid_and_meshes  # noqa: E402
from warp_verlet.constraints import stick_clusters as sc  # noqa: E402
from warp_verlet.core.simulator import Simulator  # noqa: E402
from warp_verlet.geometry.colouring import shared_particle_pairs  # noqa: E402
from warp_verlet.kernels.stick_clusters import relax_stick_clusters  # noqa: E402

wp.config.quiet = True
DEV = os.environ.get("DEV", "cuda")
SLEEPS = [int(s) for s in os.environ.get("SLEEPS", "32").split()]
out = Path(os.environ.get("OUT", "/tmp"))
rows = []


def neighbours(data):
    region_start = data.region_start.numpy()
    region = data.region.numpy()
    clusters = len(region_start) - 1
    owner = np.repeat(np.arange(clusters), np.diff(region_start))
    pairs = np.unique(shared_particle_pairs(owner, region), axis=0)
    pairs = np.concatenate([pairs, pairs[:, ::-1], np.stack([np.arange(clusters)] * 2, axis=1)])
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    start = np.searchsorted(pairs[:, 0], np.arange(clusters + 1))
    return start.astype(np.int32), pairs[:, 1].astype(np.int32), clusters


for n in [int(a) for a in sys.argv[1:]] or [512, 1024]:
    with tempfile.TemporaryDirectory() as d:
        scene = grid_and_meshes(n, 4, 8, "corners", "ply", Path(d))["triangle mesh"][0]
        sim = Simulator(scene, DEV, sticks="clustered")
        for _ in range(3):
            sim.step_frame()
        x = sim.state.particle_q
        start = wp.clone(x)
        none = wp.empty(0, dtype=float, device=DEV)
        data = sim.model.constraints["stick clusters"]
        nb_start, nb, clusters = neighbours(data)
        degree = np.diff(nb_start)
        print(f"{n}: {clusters} clusters, {len(data.launches)} cluster colours, neighbours incl. self "
              f"mean {degree.mean():.1f} max {degree.max()}", flush=True)
        nb_start_d = wp.array(nb_start, dtype=int, device=DEV)
        nb_d = wp.array(nb, dtype=int, device=DEV)
        sync = wp.zeros(3, dtype=int, device=DEV)
        done = wp.zeros(clusters, dtype=int, device=DEV)
        broken = wp.zeros(1, dtype=int, device=DEV)
        landed = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=256)
        in_kernel = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=256, chained=True)
        chain = sc.ClusterChain(clusters, DEV)

        def landed_sweep():
            for first, count in data.launches:
                wp.launch_tiled(landed, dim=[count], block_dim=256, device=DEV,
                                inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                        data.stick_ends, data.rest, none, 0.0, none, first, *[data.no_ints] * 5])

        def in_kernel_sweep():
            wp.launch_tiled(in_kernel, dim=[clusters], block_dim=256, device=DEV,
                            inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                    data.stick_ends, data.rest, none, 0.0, none, 0, data.neighbour_start,
                                    data.neighbour, chain.counts, chain.done, chain.order_broken])

        def chained(k, sleep):
            kernel = chained_kernel(data.capacity, data.stick_capacity, data.colours, block_dim=256, sleep_ns=sleep)

            def work():
                wp.launch_tiled(kernel, dim=[clusters * k], block_dim=256, device=DEV,
                                inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                        data.stick_ends, data.rest, nb_start_d, nb_d, clusters, k, sync, done,
                                        broken])
            return work

        variants = [("landed", 1, landed_sweep), ("chained in the kernel", 1, in_kernel_sweep)]
        for sleep in SLEEPS:
            for k in (1, 8):
                variants.append((f"chained K={k} sleep={sleep}", k, chained(k, sleep)))
        reference = None
        for name, k, work in variants:
            wp.copy(x, start)
            for _ in range(8 // min(k, 8)):
                if k <= 8:
                    work()
            if k > 8:
                continue
            wp.synchronize()
            got = x.numpy().copy()
            if reference is None:
                reference = got
            row = {"size": n, "variant": name, "bitwise vs landed after 8 sweeps": bool(np.array_equal(got, reference)),
                   "broken": int(broken.numpy()[0]), "sync": sync.numpy().tolist()}
            rows.append(row)
            print(row, flush=True)
        if DEV != "cpu":
            for name, k, work in variants:
                wp.copy(x, start)
                graph = captured(work, DEV, times=32 // k)
                wp.capture_launch(graph)
                row = {"size": n, "variant": name, "32 sweeps ms": round(graph_median_ms(graph), 4)}
                rows.append(row)
                print(row, flush=True)
        sim.close()
(out / os.environ.get("STEM", "chained.json")).write_text(json.dumps(rows, indent=1))
