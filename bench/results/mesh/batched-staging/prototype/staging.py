"""Prototype: the clustered sweep's staging, base (a load and store at a time) against batched loads, on one
model; each variant's sweeps captured in a graph and timed with CUDA events; bitwise agreement checked.

As run on 2026-12-06, beside base_clusters.py, made by
    git show 7b4e94b:kernels/stick_clusters.py | sed 's/^from \./from warp_verlet.kernels./' > base_clusters.py
and with the batched kernel of that day's working tree as warp_verlet.kernels.stick_clusters (the landed kernel
keeps its signature: relax_stick_clusters(..., block_dim=N)). The first lease ran sizes 512 and 1024 with another
list of kernels (base and batched at 256 particles / 128 threads and 128 / 64, batched at 256 / 64 and 256 / 256);
the second (STEM=staging-h200.json) ran 1024 with the list here."""
import sys, tempfile, time, json, os
from pathlib import Path
import numpy as np
import warp as wp
sys.path.insert(0, os.path.dirname(__file__))
import base_clusters
from bench.mesh_throughput import grid_and_meshes
from warp_verlet.core.simulator import Simulator
from warp_verlet.constraints import stick_clusters as sc
from warp_verlet.kernels.stick_clusters import relax_stick_clusters

wp.config.quiet = True
DEV = os.environ.get("DEV", "cuda")
out = Path(os.environ.get("OUT", "/tmp"))
sizes = [int(a) for a in sys.argv[1:]] or [512, 1024]
rows = []
for n in sizes:
    with tempfile.TemporaryDirectory() as d:
        scenes = grid_and_meshes(n, 4, 8, "corners", "ply", Path(d))
        for variant in ("triangle mesh",):
            t = time.time()
            sim = Simulator(scenes[variant][0], DEV, sticks="clustered")
            build = time.time() - t
            for _ in range(3):
                sim.step_frame()
            data = sim.model.constraints["stick clusters"]
            x = sim.state.particle_q
            start = wp.clone(x)
            layouts = {256: data}
            lay5 = sc.cluster_layout(sim.model.host_sticks, sim.model.host_rest,
                                     np.repeat(np.arange(len(sim.model.colour_ranges)), [k for _, k in sim.model.colour_ranges]),
                                     len(sim.model.colour_ranges), sim.model.rest_positions, 512)
            layouts[512] = sc.DeviceClusters(lay5, None, DEV)
            # a second layout: clusters of 128 particles
            colour = np.repeat(np.arange(len(sim.model.colour_ranges)), [k for _, k in sim.model.colour_ranges])
            lay = sc.cluster_layout(sim.model.host_sticks, sim.model.host_rest, colour, len(sim.model.colour_ranges),
                                    sim.model.rest_positions, 128)
            layouts[128] = sc.DeviceClusters(lay, None, DEV)
            L5 = layouts[512]
            kernels = [
                ("base 256/128", 256, 128, base_clusters.relax_stick_clusters(data.capacity, data.stick_capacity, data.colours)),
                ("batched 256/256", 256, 256, relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, block_dim=256)),
                ("batched 512/256", 512, 256, relax_stick_clusters(L5.capacity, L5.stick_capacity, L5.colours, block_dim=256)),
                ("batched 512/512", 512, 512, relax_stick_clusters(L5.capacity, L5.stick_capacity, L5.colours, block_dim=512)),
                ("base 512/256", 512, 256, base_clusters.relax_stick_clusters(L5.capacity, L5.stick_capacity, L5.colours)),
            ]
            results = {}
            for name, cp, bd, k in kernels:
                lay = layouts[cp]
                none = wp.empty(0, dtype=float, device=DEV)
                def sweep():
                    for first, count in lay.launches:
                        wp.launch_tiled(k, dim=[count], block_dim=bd, device=DEV,
                                        inputs=[x, sim.model.inv_mass, lay.region_start, lay.region, lay.stick_start,
                                                lay.stick_ends, lay.rest, none, 0.0, none, first])
                wp.copy(x, start); sweep(); wp.synchronize()
                results[name] = x.numpy().copy()
                wp.copy(x, start)
                if DEV == "cpu":
                    continue
                with wp.ScopedCapture(device=DEV) as cap:
                    for _ in range(32):
                        sweep()
                wp.capture_launch(cap.graph); wp.synchronize()
                times = []
                for _ in range(7):
                    e0 = wp.Event(enable_timing=True); e1 = wp.Event(enable_timing=True)
                    wp.record_event(e0); wp.capture_launch(cap.graph); wp.record_event(e1); wp.synchronize()
                    times.append(wp.get_event_elapsed_time(e0, e1))
                med = float(np.median(times))
                row = {"size": n, "variant": variant, "kernel": name, "32 sweeps ms": round(med, 4),
                       "per launch us": round(med * 1000 / 32 / len(lay.launches), 2), "launches": len(lay.launches),
                       "capacity": lay.capacity, "stick capacity": lay.stick_capacity, "build s": round(build, 1)}
                rows.append(row); print(row, flush=True)
            same = {name: bool(np.array_equal(results[name], results["base 256/128" if " 256/" in name else "base 512/256"])) for name in results}
            print("bitwise equal to base of the same layout:", same, flush=True)
            rows.append({"size": n, "bitwise": same})
            sim.close()
(out / os.environ.get("STEM", "staging.json")).write_text(json.dumps(rows, indent=1))
