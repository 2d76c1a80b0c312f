"""Prototype measurement, for a GPU lease: the landed clustered sweep against paired_clusters.py (two clusters a
block, the second's loads issued before the first's colours) on one triangle-mesh model of the benchmark's hanging
cloth; 32 sweeps captured in a graph and timed with CUDA events (median of 7); the positions after one sweep
compared bit for bit. On the CPU (DEV=cpu) only the comparison runs.

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

from bench.mesh_throughput import grid_and_meshes
from paired_clusters import paired_clusters
from warp_verlet.constraints.stick_clusters import CLUSTER_BLOCK
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
        data, x = sim.model.constraints["stick clusters"], sim.state.particle_q
        start = wp.clone(x)
        none = wp.empty(0, dtype=float, device=DEV)
        landed = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=CLUSTER_BLOCK)
        paired = paired_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=CLUSTER_BLOCK)

        def landed_sweep():
            for first, count in data.launches:
                wp.launch_tiled(landed, dim=[count], block_dim=CLUSTER_BLOCK, device=DEV,
                                inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                        data.stick_ends, data.rest, none, 0.0, none, first])

        def paired_sweep():
            for first, count in data.launches:
                wp.launch_tiled(paired, dim=[(count + 1) // 2], block_dim=CLUSTER_BLOCK, device=DEV,
                                inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                        data.stick_ends, data.rest, first, first + count])

        results = {}
        for name, sweep in (("landed", landed_sweep), ("paired", paired_sweep)):
            wp.copy(x, start)
            sweep()
            wp.synchronize()
            results[name] = x.numpy().copy()
            row = {"size": n, "kernel": name}
            if DEV != "cpu":
                wp.copy(x, start)
                with wp.ScopedCapture(device=DEV) as capture:
                    for _ in range(32):
                        sweep()
                times = []
                for _ in range(7):
                    e0, e1 = wp.Event(enable_timing=True), wp.Event(enable_timing=True)
                    wp.record_event(e0)
                    wp.capture_launch(capture.graph)
                    wp.record_event(e1)
                    wp.synchronize()
                    times.append(wp.get_event_elapsed_time(e0, e1))
                row["32 sweeps ms"] = round(float(np.median(times)), 4)
            rows.append(row)
            print(row, flush=True)
        same = bool(np.array_equal(results["landed"], results["paired"]))
        moved = float(np.abs(results["landed"] - start.numpy()).max())
        print(f"{n}: paired equal to landed bit for bit: {same} (a sweep moved particles up to {moved:.2e} m)")
        rows.append({"size": n, "bitwise": same})
        sim.close()
(out / "paired.json").write_text(json.dumps(rows, indent=1))
