import sys, time
import numpy as np, warp as wp
wp.config.quiet = True
from bench.convergence import scene_tables
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
n = int(sys.argv[1]); target = float(sys.argv[2]); method = sys.argv[3] if len(sys.argv) > 3 else "soft+lines"
t = scene_tables("drape", n, method, 16, 1, 90)
sim_t = t["simulation"]; sim_t.pop("substeps"); sim_t["target_stretch"] = target
extra = sys.argv[4:] 
for kv in extra:
    k, v = kv.split("="); sim_t[k] = eval(v)
sim = Simulator(parse_scene(t, file="<drape budget>"), "cpu", threads=1)
times = []
for f in range(1, 91):
    t0 = time.perf_counter(); sim.step_frame(); times.append(time.perf_counter() - t0)
    if f % 15 == 0:
        s = sim.stretch(sim.positions())
        print(f"frame {f}: substeps {sim.substeps} RMS {s.rms*100:.3f}% max {s.max*100:.2f}%", flush=True)
print("ms/frame mean over 3..90:", 1000 * np.mean(times[2:]))
print(sim.budget.report())
print("precision:", sim.model.position_dtype)
