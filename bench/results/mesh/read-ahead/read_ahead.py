"""The clustered sweep with each lane's first stick of the next colour read ahead of the barrier (``read_ahead``)
against reading it after, on one model of the benchmark's hanging cloth (rigid sticks; VARIANT: "triangle mesh"
or "quad mesh"), 32 sweeps captured in a graph, CUDA events, median of 7, each kernel timed twice in turn;
positions after one sweep compared bit for bit. DEV=cpu: the comparison only.

    PYTHONPATH=. python bench/results/mesh/read-ahead/read_ahead.py 1024

As run on 2026-12-06 with the kernel of read-ahead.diff applied (a ``read_ahead`` keyword of
relax_stick_clusters, default True); the kernel was not kept, so this script needs that diff to run again.
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
from warp_verlet.constraints.stick_clusters import CLUSTER_BLOCK
from warp_verlet.core.simulator import Simulator
from warp_verlet.kernels.stick_clusters import relax_stick_clusters

wp.config.quiet = True
DEV = os.environ.get("DEV", "cuda")
VARIANT = os.environ.get("VARIANT", "triangle mesh")
out = Path(os.environ.get("OUT", "/tmp"))
rows = []
for n in [int(a) for a in sys.argv[1:]] or [1024]:
    with tempfile.TemporaryDirectory() as d:
        sim = Simulator(grid_and_meshes(n, 4, 8, "corners", "ply", Path(d))[VARIANT][0], DEV, sticks="clustered")
        for _ in range(3):
            sim.step_frame()
        data, x = sim.model.constraints["stick clusters"], sim.state.particle_q
        start = wp.clone(x)
        none = wp.empty(0, dtype=float, device=DEV)
        graphs, results = {}, {}
        for read_ahead in (False, True):
            kernel = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=CLUSTER_BLOCK,
                                          read_ahead=read_ahead)

            def sweep():
                for first, count in data.launches:
                    wp.launch_tiled(kernel, dim=[count], block_dim=CLUSTER_BLOCK, device=DEV,
                                    inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                            data.stick_ends, data.rest, none, 0.0, none, first])

            wp.copy(x, start)
            sweep()
            wp.synchronize()
            results[read_ahead] = x.numpy().copy()
            if DEV != "cpu":
                graphs[read_ahead] = captured(sweep, DEV)
        for turn in range(2 if DEV != "cpu" else 0):
            for read_ahead, graph in graphs.items():
                wp.copy(x, start)
                wp.capture_launch(graph)
                median_ms = graph_median_ms(graph)
                row = {"size": n, "variant": VARIANT, "read ahead": read_ahead, "turn": turn,
                       "32 sweeps ms": round(median_ms, 4)}
                rows.append(row)
                print(row, flush=True)
        same = bool(np.array_equal(results[False], results[True]))
        print(f"{n} {VARIANT}: read ahead equal to reading after bit for bit: {same}", flush=True)
        rows.append({"size": n, "variant": VARIANT, "bitwise": same})
        sim.close()
(out / os.environ.get("STEM", "read_ahead.json")).write_text(json.dumps(rows, indent=1))
