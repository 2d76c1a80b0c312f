"""Prototype (dropped): Chebyshev semi-iterative acceleration of a substep's sweeps (Wang 2015), a constraint
kind after the sticks, on the drape of bench.convergence. RHO, WARM, GAMMA.
Usage: PYTHONPATH=. python bench/prototypes/drape_chebyshev.py N SxK plain|cheby"""
import sys, os, json
import numpy as np
import warp as wp
wp.config.quiet = True
from warp_verlet.launches import BoundStage, recorded
from warp_verlet.constraints.kind import ConstraintSet
import warp_verlet.constraints as C
from bench import convergence as conv

@wp.kernel
def start(x: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3), counter: wp.array(dtype=int)):
    i = wp.tid()
    p1[i] = x[i]
    if i == 0:
        counter[0] = 0

@wp.kernel
def blend(x: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3), p2: wp.array(dtype=wp.vec3),
          omega: wp.array(dtype=float), counter: wp.array(dtype=int)):
    i = wp.tid()
    w = omega[counter[0]]
    y = x[i]
    if w != 1.0:
        y = p2[i] + (x[i] - p2[i]) * w
    p2[i] = p1[i]
    p1[i] = y
    x[i] = y

@wp.kernel
def bump(counter: wp.array(dtype=int)):
    counter[0] = counter[0] + 1

RHO = float(os.environ.get("RHO", "0.99"))
WARM = int(os.environ.get("WARM", "2"))
GAMMA = float(os.environ.get("GAMMA", "1.0"))

def omegas(K):
    out = []
    w = 1.0
    for k in range(K):
        if k < WARM:
            w = 1.0
        elif k == WARM:
            w = 2.0 / (2.0 - RHO * RHO)
        else:
            w = 4.0 / (4.0 - RHO * RHO * w)
        out.append(1.0 + GAMMA * (w - 1.0))
    return out

class Cheby(ConstraintSet):
    name = "chebyshev"
    reads_positions_before_sweeps = True
    def needed(self, req): return True
    def device_bytes(self, req): return 0
    def bind(self, model, state, solver):
        K = solver.settings.iterations
        dev = model.device
        x = state.particle_q
        n = x.shape[0]
        self.p1 = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.p2 = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.counter = wp.zeros(1, dtype=int, device=dev)
        om = omegas(K)
        print("# omegas", [round(v, 3) for v in om], file=sys.stderr)
        self.om = wp.array(np.array(om + [1.0], np.float32), dtype=float, device=dev)
        s = recorded(start, n, [x, self.p1, self.counter])
        b = recorded(blend, n, [x, self.p1, self.p2, self.om, self.counter])
        c = recorded(bump, 1, [self.counter])
        def run(state_, dt):
            s.run()
        return BoundStage(run, [[b], [c]])

def main():
    n = int(sys.argv[1]); S, K = map(int, sys.argv[2].split("x")); use = sys.argv[3] == "cheby"
    if use:
        C.CONSTRAINT_KINDS = tuple(list(C.CONSTRAINT_KINDS) + [Cheby()])
    extra = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
    tables = conv.merge(conv.drape(n, S, K), extra)
    from warp_verlet.input.scene import parse_scene
    scene = parse_scene(tables, file="<drape>")
    out = conv.simulate(scene, sys.argv[5] if len(sys.argv) > 5 else "cpu", 1)
    print(f"{n} {S}x{K} {sys.argv[3]} rho={RHO} warm={WARM}: {out['ms_per_frame']:.2f} ms  rms {out['rms']*100:.3f}%  max {out['max']*100:.2f}%  lowest {out['lowest_y']:.3f}")

main()
