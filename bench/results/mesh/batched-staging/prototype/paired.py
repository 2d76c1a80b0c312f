"""Prototype measurement, for a GPU lease: the landed clustered sweep against paired_clusters.py (two clusters a
block, the second's loads issued before the first's colours) on one triangle-mesh model of the benchmark's hanging
cloth; 32 sweeps captured in a graph and timed with CUDA events (median of 7); the positions after one sweep
compared bit for bit. On the CPU (DEV=cpu) only the comparison runs. LAYOUTS lists the layouts as
particles:threads (default 256:256, the landed one; 512:512 adds clusters of 512 particles in blocks of 512).

    PYTHONPATH=.:bench/results/mesh/batched-staging/prototype python bench/results/mesh/batched-staging/prototype/paired.py 512 1024
"""
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from bench.common import captured, graph_median_ms
from bench.mesh_throughput import grid_and_meshes
from paired_clusters import paired_clusters
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
        for layout_text in os.environ.get("LAYOUTS", "256:256").split(","):
            particles, block = (int(v) for v in layout_text.split(":"))
            if particles == sc.CLUSTER_PARTICLES:
                data = sim.model.constraints["stick clusters"]
            else:
                data = sc.DeviceClusters(sc.cluster_layout(sim.model.host_sticks, sim.model.host_rest, colour,
                                                           len(sim.model.colour_ranges), sim.model.rest_positions,
                                                           particles), None, DEV)
            landed = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=block)
            paired = paired_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=block)

            def landed_sweep():
                for first, count in data.launches:
                    wp.launch_tiled(landed, dim=[count], block_dim=block, device=DEV,
                                    inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                            data.stick_ends, data.rest, none, 0.0, none, first])

            def paired_sweep():
                for first, count in data.launches:
                    wp.launch_tiled(paired, dim=[(count + 1) // 2], block_dim=block, device=DEV,
                                    inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                            data.stick_ends, data.rest, first, first + count])

            results = {}
            for name, sweep in (("landed", landed_sweep), ("paired", paired_sweep)):
                wp.copy(x, start)
                sweep()
                wp.synchronize()
                results[name] = x.numpy().copy()
                row = {"size": n, "layout": layout_text, "kernel": name}
                if DEV != "cpu":
                    wp.copy(x, start)
                    graph = captured(sweep, DEV)
                    median_ms = graph_median_ms(graph)
                    row["32 sweeps ms"] = round(median_ms, 4)
                rows.append(row)
                print(row, flush=True)
            same = bool(np.array_equal(results["landed"], results["paired"]))
            moved = float(np.abs(results["landed"] - start.numpy()).max())
            print(f"{n} {layout_text}: paired equal to landed bit for bit: {same} (a sweep moved up to {moved:.2e} m)")
            rows.append({"size": n, "layout": layout_text, "bitwise": same})
        sim.close()
(out / "paired.json").write_text(json.dumps(rows, indent=1))
