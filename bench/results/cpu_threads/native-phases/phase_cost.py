"""What a phase costs each CPU thread of an uncaptured PhaseTeam: T threads run PHASES phases of tiny pieces (each
thread's piece of a 64-element array, reading a neighbour the other thread wrote in the phase before), meeting
after every phase at the Python barrier (python_barrier_team.py: warp_verlet/core/cpu_team.py as it was before,
commit 1981cc8) or at the native barrier launched from Python (the PhaseTeam of this tree). Alternates the two
ROUNDS times; prints microseconds a phase for each and whether each ended with the sequential result bit for bit.

    PYTHONPATH=. python bench/results/cpu_threads/native-phases/phase_cost.py [THREADS] [PHASES] [ROUNDS]
"""
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

sys.path.insert(0, str(Path(__file__).parent))
from python_barrier_team import PhaseTeam as PythonBarrierTeam  # noqa: E402

from bench.common import quiet_warp  # noqa: E402
from warp_verlet.core.cpu_team import PhaseTeam  # noqa: E402

quiet_warp()
THREADS = int(sys.argv[1]) if len(sys.argv) > 1 else 2
PHASES = int(sys.argv[2]) if len(sys.argv) > 2 else 2000
ROUNDS = int(sys.argv[3]) if len(sys.argv) > 3 else 3
N = 64


@wp.kernel
def piece(src: wp.array(dtype=float), dst: wp.array(dtype=float), first: int, count: int, phase: int):
    for k in range(count):
        i = first + k
        dst[i] = src[i] * 0.5 + src[(i + 1) % src.shape[0]] * 0.25 + float(phase)


def pieces(t):
    base = N // THREADS
    return t * base, base if t < THREADS - 1 else N - base * (THREADS - 1)


def arrays():
    return (wp.array(np.arange(N, dtype=np.float32) * 1e-3, dtype=float, device="cpu"),
            wp.zeros(N, dtype=float, device="cpu"))


def phases_of(a, b):
    return [[wp.launch(piece, 1, inputs=[*((a, b) if p % 2 == 0 else (b, a)), *pieces(t), p], device="cpu",
                       record_cmd=True).launch for t in range(THREADS)] for p in range(PHASES)]


a, b = arrays()
for phase in phases_of(a, b):
    for task in phase:
        task()
expected = a.numpy().copy()

for round_ in range(ROUNDS):
    for name, kind in (("Python barrier", PythonBarrierTeam), ("native barrier", PhaseTeam)):
        a, b = arrays()
        team = kind(phases_of(a, b), repeats=1)
        start = time.perf_counter()
        team.run()
        us = (time.perf_counter() - start) / PHASES * 1e6
        same = np.array_equal(a.numpy(), expected)
        team.close()
        print(f"round {round_ + 1}, {THREADS} threads, {PHASES} phases: {name} {us:.1f} us a phase "
              f"(bit for bit: {same})", flush=True)
