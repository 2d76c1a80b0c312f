import sys, time
import numpy as np, warp as wp
wp.config.quiet = True
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
obj = sys.argv[1]; S, K, passes = (int(v) for v in sys.argv[2:5]); frames = 90
data = {"simulation": {"fps": 60, "frames": frames, "substeps": S, "iterations": K, "damping": 0.24},
        "cloth": [{"name": "cloth", "mesh": obj, "translate": [0.0, 0.5, 0.0], "mass": 0.2,
                   "sticks": ["structural", "bend"], "compliance": {"bend": 1.0}, "line_passes": passes}],
        "collider": [{"type": "sphere", "radius": 0.25, "centre": [0.0, 0.0, 0.0]},
                     {"type": "plane", "point": [0.0, -0.5, 0.0]}]}
sim = Simulator(parse_scene(data, file="<mesh drape>"), "cpu", threads=1)
t = []; late = []
for f in range(frames):
    t0 = time.perf_counter(); sim.step_frame(); t.append(time.perf_counter() - t0)
    if (f + 1) in (47, 62, 76, 90):
        late.append(sim.stretch(sim.positions()).rms)
s = sim.stretch(sim.positions())
print(f"{obj.split('/')[-1]} {sim.model.particle_count} particles, {S} x {K}, passes {passes}: {1000*np.mean(t[2:]):.2f} ms/frame; "
      f"last RMS {s.rms*100:.3f}% max {s.max*100:.2f}%; mean RMS 2nd half {np.mean(late)*100:.3f}%", flush=True)
