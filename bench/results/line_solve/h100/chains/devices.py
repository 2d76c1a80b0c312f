"""The pinned 20-particle chain of bench/stability_cases/stiff.py (line_chain) on the CPU and on CUDA: depth of its
end below the pin after 8 s, per end mass, sweeps and line passes. Run from the repository root."""
import sys, numpy as np
sys.path.insert(0, "tests")
import bench_package  # noqa
import warp as wp
wp.config.quiet = True
from bench.stability_cases.base import damping, scene
from warp_verlet.core.simulator import Simulator
for dev in ("cpu", "cuda"):
    for ratio, K, passes in [(1e2, 1, 1), (1e2, 1, 2), (1e2, 8, 1), (1e3, 1, 4), (1e3, 1, 8), (1e3, 8, 4)]:
        n, light = 20, 1e-3
        sc = scene({"iterations": K, "damping": damping(0.98)},
                   {"name": "chain", "resolution": [1, n], "size": [0.0, 1.0], "mass": light * n,
                    "pins": ["top-left"], "particle_masses": [[0, n - 1, light * ratio]], "line_passes": passes})
        sim = Simulator(sc, dev)
        for _ in range(480):
            sim.step_frame()
        p = sim.positions().astype(np.float64)
        print(dev, ratio, K, passes, "depth %.6f offset %.2e form %s" % (p[0, 1] - p[-1, 1], abs(p[-1, 0] - p[0, 0]), sim.model.sticks_form), flush=True)
