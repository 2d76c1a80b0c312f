"""bench.convergence's hanging cloth with tethers, started level (it swings down about its pinned top edge):
ms/frame (the fastest of 5 blocks of 20 frames after 5) and the stretch at 1 s, one CPU thread."""
import sys, time
from dataclasses import replace
from bench.convergence import build_scene
from bench.common import quiet_warp
from warp_verlet.core.simulator import Simulator
quiet_warp()
n, s = int(sys.argv[1]), int(sys.argv[2])
scene = build_scene("hanging", n, "tethers", s, 1)
scene = replace(scene, cloths=tuple(replace(c, orientation="horizontal") for c in scene.cloths))
sim = Simulator(scene, "cpu", threads=1)
for _ in range(5): sim.step_frame()
best = 1e9
for rep in range(5):
    t = time.perf_counter()
    for _ in range(11): sim.step_frame()
    best = min(best, (time.perf_counter() - t) / 11)
st = sim.stretch()
print(f"{n}^2 {s}x1 level start: {best*1e3:.3f} ms/frame, stretch {st.rms:.4%} / {st.max:.4%}")
