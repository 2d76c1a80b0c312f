"""The clustered sweep of soft sticks (bend compliance 1.0 m/N, shear and structural rigid) with each stick's
compliance and tension held in global memory read inside the colour loop ("global") or staged in shared memory
with the sticks ("shared"); on one triangle-mesh model of the benchmark's hanging cloth, 32 sweeps captured in a graph,
CUDA events, median of 7; positions and tensions after one sweep compared bit for bit. DEV=cpu: the comparison
only.

    PYTHONPATH=. python bench/results/mesh/soft-registers/soft_modes.py 512 1024

As run on 2026-12-06 it also timed a third way, "registers" (each thread holding the compliance and tension of
its first stick of each colour in registers), with the kernel of commit 4dd5af5, which the next commit removed.
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
out = Path(os.environ.get("OUT", "/tmp"))
MODES = {"global": dict(stage_soft=False), "shared": dict(stage_soft=True)}
rows = []
for n in [int(a) for a in sys.argv[1:]] or [512, 1024]:
    with tempfile.TemporaryDirectory() as d:
        scene = grid_and_meshes(n, 4, 8, "corners", "ply", Path(d), compliance={"bend": 1.0})["triangle mesh"][0]
        sim = Simulator(scene, DEV, sticks="clustered")
        for _ in range(3):
            sim.step_frame()
        data, x = sim.model.constraints["stick clusters"], sim.state.particle_q
        print(f"{n}: the model stages soft sticks in shared memory: {data.stage_soft}", flush=True)
        start = wp.clone(x)
        tension = wp.zeros(len(data.rest), dtype=float, device=DEV)
        inv_dt2 = float((sim.settings.substeps * 60) ** 2)
        results = {}
        for mode, flags in MODES.items():
            kernel = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, True,
                                          block_dim=CLUSTER_BLOCK, **flags)

            def sweep():
                for first, count in data.launches:
                    wp.launch_tiled(kernel, dim=[count], block_dim=CLUSTER_BLOCK, device=DEV,
                                    inputs=[x, sim.model.inv_mass, data.region_start, data.region, data.stick_start,
                                            data.stick_ends, data.rest, data.compliance, inv_dt2, tension, first])

            wp.copy(x, start)
            tension.zero_()
            sweep()
            sweep()
            wp.synchronize()
            results[mode] = (x.numpy().copy(), tension.numpy().copy())
            row = {"size": n, "mode": mode}
            if DEV != "cpu":
                wp.copy(x, start)
                graph = captured(sweep, DEV)
                wp.capture_launch(graph)
                median_ms = graph_median_ms(graph)
                row["32 sweeps ms"] = round(median_ms, 4)
            rows.append(row)
            print(row, flush=True)
        for mode in ("shared",):
            same = all(np.array_equal(a, b) for a, b in zip(results["global"], results[mode]))
            print(f"{n}: {mode} equal to global bit for bit (positions and tensions, two sweeps): {same}", flush=True)
            rows.append({"size": n, "mode": mode, "bitwise": same})
        print(f"{n}: tension moved up to {np.abs(results['global'][1]).max():.3e}", flush=True)
        sim.close()
(out / os.environ.get("STEM", "soft_modes.json")).write_text(json.dumps(rows, indent=1))
