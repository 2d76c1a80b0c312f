"""Max structural stretch and where, hanging sheet with tethers, a given form, on the CPU."""
import sys, time
import numpy as np
from bench.implicit_grid import sheet
from bench.common import quiet_warp
from warp_verlet.core.simulator import Simulator
quiet_warp()
n, s, form = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
k = int(sys.argv[5]) if len(sys.argv) > 5 else 1
frames = int(sys.argv[4]) if len(sys.argv) > 4 else 60
sim = Simulator(sheet(n, s, k), "cpu", sticks=form)
t = time.perf_counter()
for f in range(frames):
    sim.step_frame()
x = sim.positions().astype(np.float64).reshape(n, n, 3)
h = 1.0 / (n - 1)
hs = np.linalg.norm(x[:, 1:] - x[:, :-1], axis=2) / h - 1
vs = np.linalg.norm(x[1:] - x[:-1], axis=2) / h - 1
st = sim.stretch()
print(f"{n}^2 {s}x{k} {form}: rms {st.rms:.4%} max {st.max:.4%} ({time.perf_counter()-t:.0f} s)")
for name, a in (("h", hs), ("v", vs)):
    idx = np.argsort(-np.abs(a), axis=None)[:6]
    print(name, [(int(i // a.shape[1]), int(i % a.shape[1]), round(float(a.flat[i]) * 100, 3)) for i in idx])
