"""Frames stepped without capture on CPU threads (Simulator(use_graph=False), as a varying dt or a deforming mesh
collider steps them): the benchmark's hanging cloth, 4 x 8, the phases' team with the Python barrier
(python_barrier_team.py) against the native one (this tree), alternated ROUNDS times; ms a frame (frames 3-FRAMES,
median of three batches) and whether both end at one thread's positions bit for bit.

    PYTHONPATH=. python bench/results/cpu_threads/native-phases/frames_uncaptured.py SIZE THREADS [FRAMES] [ROUNDS]
"""
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from python_barrier_team import PhaseTeam as PythonBarrierTeam  # noqa: E402

from bench.common import hanging_cloth, quiet_warp  # noqa: E402
from warp_verlet.core import solver as solver_module  # noqa: E402
from warp_verlet.core.cpu_team import PhaseTeam  # noqa: E402
from warp_verlet.core.simulator import Simulator  # noqa: E402

quiet_warp()
SIZE, THREADS = int(sys.argv[1]), int(sys.argv[2])
FRAMES = int(sys.argv[3]) if len(sys.argv) > 3 else 26
ROUNDS = int(sys.argv[4]) if len(sys.argv) > 4 else 3
scene = hanging_cloth(SIZE)


def run(threads):
    sim = Simulator(scene, "cpu", threads=threads, use_graph=False)
    sim.step_frame()
    sim.step_frame()
    batches = []
    per = (FRAMES - 2) // 3
    for _ in range(3):
        start = time.perf_counter()
        for _ in range(per):
            sim.step_frame()
        batches.append((time.perf_counter() - start) / per * 1e3)
    x = sim.positions()
    sim.close()
    return statistics.median(batches), x


_, reference = run(1)
for round_ in range(ROUNDS):
    for name, kind in (("Python barrier", PythonBarrierTeam), ("native barrier", PhaseTeam)):
        solver_module.PhaseTeam = kind
        ms, x = run(THREADS)
        print(f"round {round_ + 1}, {SIZE}^2, {THREADS} threads, uncaptured: {name} {ms:.2f} ms a frame "
              f"(one thread's positions bit for bit: {np.array_equal(x, reference)})", flush=True)
