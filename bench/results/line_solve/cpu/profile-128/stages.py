import time, sys, collections
from bench.convergence import build_scene
from bench.common import quiet_warp
from warp_verlet.core.simulator import Simulator
quiet_warp()
size = int(sys.argv[1]); S, K = (int(v) for v in sys.argv[2].split("x")); method = sys.argv[3]
sim = Simulator(build_scene("drape", size, method, S, K), "cpu", use_graph=False, threads=1)
print(sim.constraint_sets, sim.solver.stage_names)
for _ in range(3): sim.step_frame()
stages = sim.solver.bind(sim.state)
acc = collections.defaultdict(float)
wrapped = []
for name, run in stages:
    def timed(state, dt, run=run, name=name):
        t = time.perf_counter(); run(state, dt); acc[name] += time.perf_counter() - t
    wrapped.append((name, timed))
sim.solver.bind = lambda state: wrapped
frames = 10
t0 = time.perf_counter()
for _ in range(frames): sim.step_frame()
total = (time.perf_counter() - t0) / frames * 1e3
print(f"{size}^2 {method} {S}x{K}: {total:.2f} ms/frame")
for k, v in acc.items(): print(f"  {k:12s} {v / frames * 1e3:7.2f} ms/frame")
