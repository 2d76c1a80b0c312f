"""Frames of the benchmark's hanging cloth as a triangle mesh and a quad mesh (4 x 8, clustered sticks), with the
clustered sweep as one launch per cluster colour and chained (one launch a sweep), in one process: ms per frame
(frames 3-60 in 3 batches, median) and whether the positions at frame 60 are the same bit for bit.

    PYTHONPATH=. python bench/results/mesh/chained/frames.py 1024
    SOFT_BEND=1.0 ROUNDS=1 VARIANTS="triangle mesh" PYTHONPATH=. python bench/results/mesh/chained/frames.py 1024
"""
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from bench.mesh_throughput import grid_and_meshes
from warp_verlet.constraints import stick_clusters as sc
from warp_verlet.core.simulator import Simulator

wp.config.quiet = True
DEV = os.environ.get("DEV", "cuda")
FRAMES = int(os.environ.get("FRAMES", "60"))
ROUNDS = int(os.environ.get("ROUNDS", "2"))  # each build, per-colour then chained, this many times
VARIANTS = os.environ.get("VARIANTS", "triangle mesh,quad mesh").split(",")
SOFT = {"bend": float(os.environ["SOFT_BEND"])} if os.environ.get("SOFT_BEND") else None  # compliance, m/N
out = Path(os.environ.get("OUT", "/tmp"))
rows = []
for n in [int(a) for a in sys.argv[1:]] or [1024]:
    with tempfile.TemporaryDirectory() as d:
        scenes = grid_and_meshes(n, 4, 8, "corners", "ply", Path(d), compliance=SOFT)
        for variant in VARIANTS:
            final = {}
            for chained in (False, True) * ROUNDS:
                sc.CHAINED_SWEEP = chained
                sim = Simulator(scenes[variant][0], DEV, sticks="clustered")
                sim.step_frame()
                sim.step_frame()
                wp.synchronize()
                batches = []
                per = (FRAMES - 2) // 3
                for _ in range(3):
                    t = time.perf_counter()
                    for _ in range(per):
                        sim.step_frame()
                    wp.synchronize()
                    batches.append((time.perf_counter() - t) / per * 1e3)
                x = sim.positions()
                stretch = sim.stretch()
                same = None
                if chained in final:
                    same = bool(np.array_equal(final[chained], x))
                final.setdefault(chained, x)
                row = {"size": n, "variant": variant, "soft": SOFT, "chained": chained, "ms/frame": round(statistics.median(batches), 4),
                       "batches": [round(b, 4) for b in batches], "rms": float(stretch.rms), "max": float(stretch.max),
                       "repeat bit for bit": same}
                rows.append(row)
                print(row, flush=True)
                sim.close()
            same = bool(np.array_equal(final[False], final[True]))
            rows.append({"size": n, "variant": variant, "chained equals per-colour bit for bit": same})
            print(rows[-1], flush=True)
(out / os.environ.get("STEM", "frames.json")).write_text(json.dumps(rows, indent=1))
