"""Where the drape's longest structural sticks sit, at 256^2 16x1 with a line pass (the 1024^2 64x1 landing ratio)."""
import sys, time
import numpy as np, warp as wp
wp.config.quiet = True
from bench.convergence import build_scene
from warp_verlet.core.simulator import Simulator
n = int(sys.argv[1]) if len(sys.argv) > 1 else 256
S = int(sys.argv[2]) if len(sys.argv) > 2 else 16
method = sys.argv[3] if len(sys.argv) > 3 else "soft+lines"
sim = Simulator(build_scene("drape", n, method, S, 1, 90), "cpu", threads=1)
m = sim.model
keep = np.flatnonzero(m.structural)
st = m.host_sticks[keep]
rest = m.host_rest[keep].astype(np.float64)
t0 = time.time()
for f in range(1, 91):
    sim.step_frame()
    if f in (10, 15, 20, 25, 30, 45, 60, 90):
        p = m.to_device_order(sim.positions()).astype(np.float64)
        L = np.linalg.norm(p[st[:, 1]] - p[st[:, 0]], axis=1)
        e = (L - rest) / rest
        dball = np.linalg.norm(p, axis=1) - 0.25
        hgr = p[:, 1] + 0.5
        onball = dball < 1e-3 * 0.25 + 2e-5
        onground = hgr < 2e-5
        order = np.argsort(-np.abs(e))[:200]
        top = order[:8]
        a, b = st[top, 0], st[top, 1]
        # classify top 200
        c = st[order]
        kinds = {}
        for i, j in c:
            k = ("ball" if onball[i] else "free") + "-" + ("ball" if onball[j] else "free")
            if onground[i] or onground[j]:
                k += "+ground"
            kinds[k] = kinds.get(k, 0) + 1
        print(f"frame {f}: RMS {np.sqrt(np.mean(e*e))*100:.3f}% max {np.abs(e).max()*100:.2f}%  "
              f"on ball {onball.mean()*100:.0f}% on ground {onground.mean()*100:.0f}%  top200 {kinds}  [{time.time()-t0:.0f}s]")
        for s_, i, j in zip(e[top], a, b):
            mid = 0.5 * (p[i] + p[j])
            print(f"   {s_*100:+7.2f}%  ends {i},{j} (row {i//n} col {i%n} -> row {j//n} col {j%n})  "
                  f"mid ({mid[0]:+.3f},{mid[1]:+.3f},{mid[2]:+.3f}) dball {dball[i]:+.2e},{dball[j]:+.2e} "
                  f"hgr {hgr[i]:.3f},{hgr[j]:.3f}")
