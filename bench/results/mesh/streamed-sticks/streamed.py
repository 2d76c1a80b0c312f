"""The clustered sweep with its sticks loaded as data read once (``streamed``: CUDA's __ldcs, evicted from the
caches first) against plain loads, on one triangle-mesh model of the benchmark's hanging cloth, for clusters of
256 particles in blocks of 256 threads (the landed layout) and of 512 in blocks of 512; 32 sweeps captured in a
graph and timed with CUDA events (median of 7), positions after one sweep compared bit for bit. On the CPU
(DEV=cpu) only the comparison runs.

    PYTHONPATH=. python bench/results/mesh/streamed-sticks/streamed.py 512 1024

As run on 2026-12-06, when relax_stick_clusters took a ``streamed`` keyword (commit 25e54ad to 73bc29e); the kernel
now always streams its sticks, so the comparison runs again on a checkout of one of those commits.
"""
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import warp as wp

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
        scene = grid_and_meshes(n, 4, 8, "corners", "ply", Path(d))["triangle mesh"][0]
        sim = Simulator(scene, DEV, sticks="clustered")
        for _ in range(3):
            sim.step_frame()
        x = sim.state.particle_q
        start = wp.clone(x)
        none = wp.empty(0, dtype=float, device=DEV)
        colour = np.repeat(np.arange(len(sim.model.colour_ranges)), [k for _, k in sim.model.colour_ranges])
        for particles, block in ((256, 256), (512, 512)):
            if particles == sc.CLUSTER_PARTICLES:
                data = sim.model.constraints["stick clusters"]
            else:
                data = sc.DeviceClusters(sc.cluster_layout(sim.model.host_sticks, sim.model.host_rest, colour,
                                                           len(sim.model.colour_ranges), sim.model.rest_positions,
                                                           particles), None, DEV)
            results = {}
            for streamed in (False, True):
                kernel = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=block,
                                              streamed=streamed)

                def sweep():
                    for first, count in data.launches:
                        wp.launch_tiled(kernel, dim=[count], block_dim=block, device=DEV,
                                        inputs=[x, sim.model.inv_mass, data.region_start, data.region,
                                                data.stick_start, data.stick_ends, data.rest, none, 0.0, none, first])

                wp.copy(x, start)
                sweep()
                wp.synchronize()
                results[streamed] = x.numpy().copy()
                row = {"size": n, "layout": f"{particles}/{block}", "streamed": streamed}
                if DEV != "cpu":
                    wp.copy(x, start)
                    graph = captured(sweep, DEV)
                    wp.capture_launch(graph)
                    median_ms = graph_median_ms(graph)
                    row["32 sweeps ms"] = round(median_ms, 4)
                rows.append(row)
                print(row, flush=True)
            same = bool(np.array_equal(results[False], results[True]))
            print(f"{n} {particles}/{block}: streamed equal to plain bit for bit: {same}", flush=True)
            rows.append({"size": n, "layout": f"{particles}/{block}", "bitwise": same})
        sim.close()
(out / os.environ.get("STEM", "streamed.json")).write_text(json.dumps(rows, indent=1))
