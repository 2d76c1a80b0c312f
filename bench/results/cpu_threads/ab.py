"""One scene at one size, 8 substeps x 8 sweeps, frames 13-18 timed on the CPU with the simulator's default
relaxation threads (or THREADS), for the build whose tree is first on PYTHONPATH; one line a run. The scenes:
``folded``, bench.self_contact's folded cloth dropped on the ground with self-collision; ``mesh-ball``,
bench.mesh_collider's cloth dropped on an icosphere of 20,480 triangles. Run it alternately on two trees to compare
them:

    for r in 1 2 3 4 5; do for tree in BASE .; do (cd $tree && PYTHONPATH=$tree python \\
        /path/to/bench/results/cpu_threads/ab.py folded 256); done; done
"""
import os
import sys
import tempfile
import time
from pathlib import Path

from bench import mesh_collider, self_contact
from bench.common import quiet_warp
from warp_verlet.core.simulator import Simulator

quiet_warp()
kind, n = sys.argv[1], int(sys.argv[2])
threads = int(os.environ.get("THREADS", "0")) or None
with tempfile.TemporaryDirectory() as folder:
    if kind == "folded":
        scene = self_contact.folded_scene(n, True, 30, 8, 8)
    else:
        scene, _ = mesh_collider.drop_scene(n, "mesh", 5, Path(folder), 30, 8, 8)
    sim = Simulator(scene, "cpu", threads=threads)
    for _ in range(12):
        sim.step_frame()
    start = time.perf_counter()
    for _ in range(6):
        sim.step_frame()
tree = os.path.basename(os.path.dirname(os.path.dirname(os.path.abspath(self_contact.__file__))))
print(f"{tree} {kind} {n}^2 threads={sim.solver.threads}: {(time.perf_counter() - start) / 6 * 1e3:.1f} ms/frame "
      f"(load {os.getloadavg()[0]:.2f})", flush=True)
