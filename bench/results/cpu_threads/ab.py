"""bench.self_contact's folded drop at one size (8 substeps x 8 sweeps), frames 13-18 timed on the CPU with the
simulator's default relaxation threads (or THREADS), for the build whose tree is first on PYTHONPATH; one line a
run. Run it alternately on two trees to compare them:

    for r in 1 2 3 4 5; do for tree in BASE .; do (cd $tree && PYTHONPATH=$tree python \\
        /path/to/bench/results/cpu_threads/ab.py 256); done; done
"""
import os
import sys
import time

from bench import self_contact as bench
from bench.common import quiet_warp
from warp_verlet.core.simulator import Simulator

quiet_warp()
n = int(sys.argv[1]) if len(sys.argv) > 1 else 256
threads = int(os.environ.get("THREADS", "0")) or None
sim = Simulator(bench.folded_scene(n, True, 30, 8, 8), "cpu", threads=threads)
for _ in range(12):
    sim.step_frame()
start = time.perf_counter()
for _ in range(6):
    sim.step_frame()
tree = os.path.basename(os.path.dirname(os.path.dirname(os.path.abspath(bench.__file__))))
print(f"{tree} {n}^2 threads={sim.solver.threads}: {(time.perf_counter() - start) / 6 * 1e3:.1f} ms/frame "
      f"(load {os.getloadavg()[0]:.2f})", flush=True)
