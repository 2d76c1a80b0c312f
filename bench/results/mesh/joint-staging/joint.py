"""The clustered sweep as it is (kernels/stick_clusters.py: a staged-soft kernel stages in one batch of loads)
against the kernel staged one kind after another (commit 88a8c52's kernels/stick_clusters.py, its relative
imports made absolute, as ``base_clusters`` on PYTHONPATH), on one triangle-mesh model of
the benchmark's hanging cloth: rigid, and with soft bend sticks (compliance 1 m/N, staged where they fit). 32
sweeps captured in a graph and timed with CUDA events (median of 7), alternating base and new three times; the
positions after one sweep compared bit for bit. On the CPU (DEV=cpu) only the comparison runs.

    PYTHONPATH=.:DIR_OF_base_clusters python bench/results/mesh/joint-staging/joint.py 512 1024
"""
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import warp as wp

import base_clusters
from bench.common import captured, graph_median_ms
from bench.mesh_throughput import grid_and_meshes
from warp_verlet.constraints.stick_clusters import CLUSTER_BLOCK
from warp_verlet.core.simulator import Simulator
from warp_verlet.kernels.stick_clusters import relax_stick_clusters

wp.config.quiet = True
DEV = os.environ.get("DEV", "cuda")
out = Path(os.environ.get("OUT", "/tmp"))
rows = []
for n in [int(a) for a in sys.argv[1:]] or [512, 1024]:
    for soft in (False, True):
        with tempfile.TemporaryDirectory() as d:
            compliance = {"bend": 1.0} if soft else None
            scene = grid_and_meshes(n, 4, 8, "corners", "ply", Path(d), compliance=compliance)["triangle mesh"][0]
            sim = Simulator(scene, DEV, sticks="clustered")
            for _ in range(3):
                sim.step_frame()
            data = sim.model.constraints["stick clusters"]
            x = sim.state.particle_q
            start = wp.clone(x)
            compliant = data.compliance is not None
            none = wp.empty(0, dtype=float, device=DEV)
            tension = wp.zeros(len(data.rest), dtype=float, device=DEV) if compliant else none
            alpha = data.compliance if compliant else none
            kernels = {
                name: make(data.capacity, data.stick_capacity, data.colours, compliant, stage_soft=data.stage_soft,
                           block_dim=CLUSTER_BLOCK)
                for name, make in (("staged by kind", base_clusters.relax_stick_clusters),
                                   ("one batch", relax_stick_clusters))}
            results, graphs = {}, {}
            for name, kernel in kernels.items():
                def sweep(kernel=kernel):
                    for first, count in data.launches:
                        wp.launch_tiled(kernel, dim=[count], block_dim=CLUSTER_BLOCK, device=DEV,
                                        inputs=[x, sim.model.inv_mass, data.region_start, data.region,
                                                data.stick_start, data.stick_ends, data.rest, alpha, 1e4, tension,
                                                first])

                wp.copy(x, start)
                tension.zero_() if compliant else None
                sweep()
                wp.synchronize()
                results[name] = (x.numpy().copy(), tension.numpy().copy() if compliant else None)
                if DEV != "cpu":
                    wp.copy(x, start)
                    graphs[name] = captured(sweep, DEV)
                    wp.capture_launch(graphs[name])
            first = next(iter(results.values()))
            same = all(np.array_equal(a, b) for other in results.values() for a, b in zip(first, other)
                       if a is not None)
            times = {name: [] for name in graphs}
            for _ in range(3):
                for name, graph in graphs.items():
                    wp.copy(x, start)
                    times[name].append(graph_median_ms(graph))
            for name in kernels:
                row = {"size": n, "sticks": "soft bend" if soft else "rigid", "staged soft": data.stage_soft,
                       "kernel": name, "bit for bit": same}
                if times.get(name):
                    row["32 sweeps ms"] = round(float(np.median(times[name])), 4)
                    row["runs"] = [round(t, 4) for t in times[name]]
                rows.append(row)
                print(row, flush=True)
            sim.close()
(out / os.environ.get("STEM", "joint.json")).write_text(json.dumps(rows, indent=1))
