import sys, time, tomllib
import numpy as np, warp as wp
wp.config.quiet = True
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
S, K, passes, frames = (int(v) for v in sys.argv[1:5])
path = "scenes/tablecloth.toml"
data = tomllib.load(open(path, "rb"))
data["simulation"].update(substeps=S, iterations=K, frames=frames)
data["cloth"][0]["line_passes"] = passes
sim = Simulator(parse_scene(data, file=path), "cpu", threads=1)
print(sim.constraint_sets, sim.model.particle_count)
t=[]; late=[]
for f in range(frames):
    t0=time.perf_counter(); sim.step_frame(); t.append(time.perf_counter()-t0)
    if (f+1) % 15 == 0:
        s = sim.stretch(sim.positions()); print(f"frame {f+1}: RMS {s.rms*100:.3f}% max {s.max*100:.2f}%", flush=True)
        if f + 1 >= frames // 2: late.append(s.rms)
print(f"S={S} K={K} passes={passes}: ms/frame {1000*np.mean(t[2:]):.2f}; mean RMS 2nd half {np.mean(late)*100:.3f}%")
