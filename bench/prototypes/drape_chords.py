"""Prototype (dropped): one-sided chord sticks along a grid's rows and columns at 2, 4, 8, ... spacings, a
constraint kind before the sticks, on the drape of bench.convergence. MODE=dense|sparse, ORDER=coarse|fine,
MINS, MAXLEV. Usage: PYTHONPATH=. python bench/prototypes/drape_chords.py N SxK plain|chords"""
import sys, time, os
import numpy as np
import warp as wp
wp.config.quiet = True
from warp_verlet.launches import BoundStage, recorded
from warp_verlet.constraints.kind import ConstraintSet
import warp_verlet.constraints as C
from bench import convergence as conv

@wp.kernel
def pull_chords(x: wp.array(dtype=wp.vec3), w: wp.array(dtype=float), a: wp.array(dtype=int),
                b: wp.array(dtype=int), rest: wp.array(dtype=float)):
    t = wp.tid()
    i = a[t]
    j = b[t]
    d = x[j] - x[i]
    dist = wp.length(d)
    if dist > rest[t]:
        wi = w[i]
        wj = w[j]
        if wi + wj > 0.0:
            s = (dist - rest[t]) / (dist * (wi + wj))
            x[i] = x[i] + d * (wi * s)
            x[j] = x[j] - d * (wj * s)

MODE = os.environ.get("MODE", "sparse")
MAXLEV = int(os.environ.get("MAXLEV", "20"))
MINS = int(os.environ.get("MINS", "2"))
ORDER = os.environ.get("ORDER", "coarse")
DIAG = int(os.environ.get("DIAG", "0"))
SLACK = float(os.environ.get("SLACK", "1.0"))

class Chords(ConstraintSet):
    name = "chords"
    def needed(self, req): return True
    def device_bytes(self, req): return 0
    def bind(self, model, state, solver):
        x0 = state.particle_q.numpy().astype(np.float64)
        n = int(round(np.sqrt(len(x0))))
        h = 1.0 / (n - 1)
        col = np.rint((x0[:, 0] - x0[:, 0].min()) / h).astype(int)
        row = np.rint((x0[:, 2] - x0[:, 2].min()) / h).astype(int)
        grid = np.full((n, n), -1)
        grid[row, col] = np.arange(len(x0))
        assert (grid >= 0).all()
        phases = []
        scales = []
        s = MINS
        while s <= n // 2 and len(scales) < MAXLEV:
            scales.append(s); s *= 2
        if ORDER == "coarse":
            scales = scales[::-1]
        dirs = [(0, 1), (1, 0)] + ([(1, 1), (1, -1)] if DIAG else [])
        total = 0
        for s in scales:
            for dr, dc in dirs:
                for parity in (0, 1):
                    a, b = [], []
                    r, c = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
                    r2, c2 = r + dr * s, c + dc * s
                    ok = (r2 >= 0) & (r2 < n) & (c2 >= 0) & (c2 < n)
                    pos = (c // s) if dc != 0 else (r // s)
                    if dc == 0:
                        pos = r // s
                    else:
                        pos = c // s if dr == 0 else r // s
                    ok &= (pos % 2 == parity)
                    if MODE == "sparse":
                        along = c if dr == 0 else r
                        ok &= (along % s == 0)
                        if dr != 0 and dc != 0:
                            ok &= (c % s == 0)
                        if dr != 0 and dc == 0:
                            ok &= (c % s == 0) if os.environ.get("SPARSE2") else True
                        if dr == 0:
                            ok &= (r % s == 0) if os.environ.get("SPARSE2") else True
                    a = grid[r[ok], c[ok]]; b = grid[r2[ok], c2[ok]]
                    L = np.linalg.norm(x0[b] - x0[a], axis=1) * SLACK
                    if len(a) == 0: continue
                    total += len(a)
                    A = wp.array(a.astype(np.int32), dtype=int, device=model.device)
                    B = wp.array(b.astype(np.int32), dtype=int, device=model.device)
                    R = wp.array(L.astype(np.float32), dtype=float, device=model.device)
                    phases.append([recorded(pull_chords, len(a), [state.particle_q, model.inv_mass, A, B, R])])
        print(f"# chords: {total} ({total / len(x0):.2f} per particle), {len(phases)} launches, scales {scales}", file=sys.stderr)
        return BoundStage(None, phases)

def main():
    n = int(sys.argv[1]); S, K = map(int, sys.argv[2].split("x")); use = sys.argv[3] == "chords"
    if use:
        kinds = list(C.CONSTRAINT_KINDS)
        kinds.insert(3, Chords())  # after tethers, before sticks
        C.CONSTRAINT_KINDS = tuple(kinds)
    extra = {}
    if len(sys.argv) > 4:
        import json; extra = json.loads(sys.argv[4])
    tables = conv.merge(conv.drape(n, S, K), extra)
    from warp_verlet.input.scene import parse_scene
    scene = parse_scene(tables, file="<drape>")
    out = conv.simulate(scene, sys.argv[5] if len(sys.argv) > 5 else "cpu", 1)
    print(f"{n} {S}x{K} {sys.argv[3]} {MODE} {ORDER}: {out['ms_per_frame']:.2f} ms  rms {out['rms']*100:.3f}%  max {out['max']*100:.2f}%  lowest {out['lowest_y']:.3f}")

main()
