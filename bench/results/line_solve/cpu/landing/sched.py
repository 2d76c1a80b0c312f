import sys, time
import numpy as np, warp as wp
wp.config.quiet = True
from bench.convergence import build_scene
from warp_verlet.core.simulator import Simulator
n, lo, hi, a, b = (int(v) for v in sys.argv[1:6])
method = sys.argv[6] if len(sys.argv) > 6 else "soft+lines"
sim = Simulator(build_scene("drape", n, method, lo, 1, 90), "cpu", threads=1)
times, late = [], []
for f in range(1, 91):
    want = hi if a <= f <= b else lo
    if sim.substeps != want:
        sim.retune(substeps=want)
    t0 = time.perf_counter(); sim.step_frame(); times.append(time.perf_counter() - t0)
    if f % 15 == 0:
        s = sim.stretch(sim.positions())
        if f >= 45: late.append(s.rms)
        print(f"frame {f}: substeps {sim.substeps} RMS {s.rms*100:.3f}% max {s.max*100:.2f}%", flush=True)
print(f"{n}^2 {lo}/{hi} in frames {a}-{b}: ms/frame {1000*np.mean(times[2:]):.1f}; mean RMS 45-90 {np.mean(late)*100:.3f}%")
