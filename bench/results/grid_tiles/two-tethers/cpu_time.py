import time, sys
from bench.convergence import build_scene
from bench.common import quiet_warp
from warp_verlet.core.simulator import Simulator
quiet_warp()
n, s = int(sys.argv[1]), int(sys.argv[2])
sim = Simulator(build_scene("hanging", n, "tethers", s, 1), "cpu", threads=1)
for _ in range(5): sim.step_frame()
best = 1e9
for rep in range(5):
    t = time.perf_counter()
    for _ in range(20): sim.step_frame()
    best = min(best, (time.perf_counter() - t) / 20)
print(f"{n}^2 {s}x1: {best*1e3:.3f} ms/frame, stretch {sim.stretch().rms:.4%} / {sim.stretch().max:.4%}")
