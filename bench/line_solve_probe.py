"""Probe: exact line solves (kernels/line_solve.py) before each substep's sweeps, on bench.convergence's drape.

python bench/line_solve_probe.py {plain|lines} N SxK [PASSES]   (one CPU thread)
Environment: LINES (families of lines: h, v rows and columns of structural sticks; d, a the shear diagonals;
h2, v2 the bend sticks' rows and columns; default all six), FAM (the cloth's stick families, comma-separated),
COMP (a JSON compliance table). Results: bench/results/global_solve.md, "Tried and dropped: line solves".
"""
import os, sys, time, numpy as np
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import warp as wp
wp.config.quiet = True
from warp_verlet import constraints
from warp_verlet.constraints.kind import ConstraintSet
from warp_verlet.launches import BoundStage, recorded
from warp_verlet.kernels.line_solve import solve_lines
from warp_verlet.kernels.global_solve import copy_positions, contact_normals

PASSES = int(sys.argv[4]) if len(sys.argv) > 4 else 1

class Lines(ConstraintSet):
    name = "lines"
    reads_positions_before_sweeps = True
    def needed(self, req): return True
    def device_bytes(self, req): return 0
    def bind(self, model, state, solver):
        slot = model.cloths[0]
        top = slot.topology
        rows, cols, first = top.rows, top.cols, slot.first
        rp = model.host_rest_positions if hasattr(model, "host_rest_positions") else model.rest_positions
        rp = np.asarray(rp)[first:first + rows * cols].reshape(rows, cols, 3)
        col_gap = np.linalg.norm(rp[0, 1:] - rp[0, :-1], axis=1).astype(np.float32)
        row_gap = np.linalg.norm(rp[1:, 0] - rp[:-1, 0], axis=1).astype(np.float32)
        dev = model.device
        n = model.particle_count
        x = state.particle_q
        normal = wp.zeros(n, dtype=wp.vec3, device=dev)
        snap = wp.zeros(n, dtype=model.position_dtype, device=dev)
        direction = wp.zeros(n, dtype=wp.vec3d, device=dev)
        forward = wp.zeros(n, dtype=wp.vec2d, device=dev)
        rest = wp.array(np.asarray(model.rest_positions, np.float32), dtype=wp.vec3, device=dev)
        fams = os.environ.get("LINES", "h,v,d,a,h2,v2").split(",")
        idx = np.arange(rows * cols).reshape(rows, cols) + first
        groups = []
        def add(starts, counts, step):
            keep = np.asarray(counts) >= 2
            if keep.any():
                groups.append((wp.array(np.asarray(starts)[keep].astype(np.int32), dtype=int, device=dev),
                               wp.array(np.asarray(counts)[keep].astype(np.int32), dtype=int, device=dev), step))
        for fam in fams:
            if fam == "h": add(idx[:, 0], [cols] * rows, 1)
            if fam == "v": add(idx[0, :], [rows] * cols, cols)
            if fam == "h2":
                for o in (0, 1): add(idx[:, o], [(cols - o + 1) // 2] * rows, 2)
            if fam == "v2":
                for o in (0, 1): add(idx[o, :], [(rows - o + 1) // 2] * cols, 2 * cols)
            if fam == "d":  # (r, c) -> (r+1, c+1)
                st = [idx[0, c] for c in range(cols)] + [idx[r, 0] for r in range(1, rows)]
                ct = [min(rows, cols - c) for c in range(cols)] + [min(rows - r, cols) for r in range(1, rows)]
                add(st, ct, cols + 1)
            if fam == "a":  # (r, c) -> (r+1, c-1)
                st = [idx[0, c] for c in range(cols)] + [idx[r, cols - 1] for r in range(1, rows)]
                ct = [min(rows, c + 1) for c in range(cols)] + [min(rows - r, cols) for r in range(1, rows)]
                add(st, ct, cols - 1)
        solves = [recorded(solve_lines, g[0].shape[0], [x, model.inv_mass, normal, g[0], g[1], g[2], rest, direction, forward]) for g in groups]
        bound = [kind.bind(model, state) for kind, _ in model.colliders.kinds]
        clamps = [t for b in bound for t in b.clamps]
        snapshot = recorded(copy_positions, n, [x], [snap])
        normals = recorded(contact_normals, n, [x, snap], [normal])
        def run(state, dt):
            snapshot.run()
            for c in clamps: c.run()
            normals.run()
            for _ in range(PASSES):
                [q.run() for q in solves]
        return BoundStage(run, [])

constraints.CONSTRAINT_KINDS = (Lines(),) + constraints.CONSTRAINT_KINDS if sys.argv[1] == "lines" else constraints.CONSTRAINT_KINDS

from bench import convergence as cv
n = int(sys.argv[2]); S, K = map(int, sys.argv[3].split("x"))
import os
fam = os.environ.get("FAM")
over = {"cloth": {"sticks": fam.split(",")}} if fam else {}
import json
if os.environ.get("COMP"): over.setdefault("cloth", {})["compliance"] = json.loads(os.environ["COMP"])
cv.METHODS["fam"] = over
scene = cv.build_scene("drape", n, "fam", S, K)
t = time.perf_counter()
row = cv.simulate(scene, "cpu", 1)
print(sys.argv[1:], {k: v for k, v in row.items() if not isinstance(v, np.ndarray)}, f"{time.perf_counter()-t:.1f}s")
