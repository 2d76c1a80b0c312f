"""What a phase costs each CPU thread, captured or not: T threads run PHASES phases of tiny pieces (each thread's
piece of a 64-element array, reading a neighbour the other thread wrote in the phase before), run by ``PhaseTeam``
from Python (a recorded launch a phase, then the barrier: a Python barrier until 2026-12-06, the native barrier
launched from Python since, native-phases/README.md) or as a captured frame (kernels/team_barrier.py; one graph a
thread, replayed from C++ by a ``FrameReplayer``). Prints microseconds a phase for each, and whether both ended
with the sequential result bit for bit.

    PYTHONPATH=. python bench/results/cpu_threads/barrier_cost.py [THREADS] [PHASES]
"""
import sys
import time

import numpy as np
import warp as wp

from bench.common import quiet_warp
from warp_verlet.core.cpu_team import FrameReplayer, FrameTeam, PhaseTeam, TeamRecording

quiet_warp()
THREADS = int(sys.argv[1]) if len(sys.argv) > 1 else 2
PHASES = int(sys.argv[2]) if len(sys.argv) > 2 else 2000
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

a, b = arrays()
team = PhaseTeam(phases_of(a, b), repeats=1)
start = time.perf_counter()
team.run()
python_us = (time.perf_counter() - start) / PHASES * 1e6
python_same = np.array_equal(a.numpy(), expected)
team.close()

a, b = arrays()
recording = TeamRecording(THREADS)
team = PhaseTeam(phases_of(a, b), repeats=1)
team.recording = recording
with wp.ScopedCapture(device="cpu") as capture:
    team.run()
frame = FrameTeam([capture.graph, *recording.member_graphs()], recording)
replayer = FrameReplayer(THREADS)
start = time.perf_counter()
replayer.run(frame)
native_us = (time.perf_counter() - start) / PHASES * 1e6
native_same = np.array_equal(a.numpy(), expected)
replayer.close()
print(f"{THREADS} threads, {PHASES} phases: from Python {python_us:.1f} us a phase (bit for bit: {python_same}); "
      f"captured {native_us:.2f} us a phase (bit for bit: {native_same})")
