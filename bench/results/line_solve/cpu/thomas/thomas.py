import time, sys
import numpy as np
import warp as wp
from bench.convergence import build_scene
from bench.common import quiet_warp
from warp_verlet.core.simulator import Simulator
from warp_verlet.launches import clamp_noting_normals, noted_pushes
from warp_verlet.kernels.line_solve import line_solve_kernel, weighted_dot, PIVOT_FLOOR
quiet_warp()

FLOOR = wp.float64(PIVOT_FLOOR)

@wp.kernel
def solve_lines_thomas(x: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float), contact: int,
                       normal: wp.array(dtype=wp.vec3), lines: wp.array(dtype=wp.vec4i), rest: wp.array(dtype=float),
                       direction: wp.array(dtype=wp.vec3d), pivot: wp.array(dtype=wp.float64),
                       rhs: wp.array(dtype=wp.float64), coupling: wp.array(dtype=wp.float64), capacity: int):
    b = wp.tid()
    line = lines[b]
    first = line[0]
    sticks = line[1]
    step = line[2]
    rest_first = line[3]
    base = b * capacity
    zero = wp.float64(0.0)
    pa = x[first]
    wa = wp.float64(inv_mass[first])
    ca = wp.vec3d(0.0, 0.0, 0.0)
    if contact == 1:
        ca = wp.vec3d(normal[first])
    prev_n = wp.vec3d(0.0, 0.0, 0.0)
    prev_pivot = wp.float64(1.0)
    prev_rhs = zero
    k = int(0)
    while k < sticks:
        p = first + (k + 1) * step
        pb = x[p]
        wb = wp.float64(inv_mass[p])
        cb = wp.vec3d(0.0, 0.0, 0.0)
        if contact == 1:
            cb = wp.vec3d(normal[p])
        e = wp.vec3d(pb - pa)
        length = wp.length(e)
        a = wp.float64(1.0)
        d = zero
        n = wp.vec3d(0.0, 0.0, 0.0)
        if length > zero:
            n = e / length
            a = weighted_dot(n, n, wa, ca) + weighted_dot(n, n, wb, cb)
            d = wp.float64(rest[rest_first + k]) - length
        if a <= wp.float64(1.0e-12) * (wa + wb) or length == zero:
            a = wp.float64(1.0)
            d = zero
            n = wp.vec3d(0.0, 0.0, 0.0)
        c = zero
        if k > 0:
            c = -weighted_dot(prev_n, n, wa, ca)  # couples stick k - 1 and k through particle k (the shared one)
            m = c / prev_pivot
            a_new = a - m * c
            a = wp.max(a_new, FLOOR * a)
            d = d - m * prev_rhs
        direction[base + k] = n
        pivot[base + k] = a
        rhs[base + k] = d
        coupling[base + k] = c
        prev_n = n
        prev_pivot = a
        prev_rhs = d
        pa = pb
        wa = wb
        ca = cb
        k += 1
    # back substitution
    lam_next = zero
    k = sticks - 1
    while k >= 0:
        lam = rhs[base + k]
        if k + 1 < sticks:
            lam -= coupling[base + k + 1] * lam_next
        lam = lam / pivot[base + k]
        rhs[base + k] = lam
        lam_next = lam
        k -= 1
    q = int(0)
    while q <= sticks:
        p = first + q * step
        f = wp.vec3d(0.0, 0.0, 0.0)
        if q > 0:
            f += direction[base + q - 1] * rhs[base + q - 1]
        if q < sticks:
            f -= direction[base + q] * rhs[base + q]
        cn = wp.vec3d(0.0, 0.0, 0.0)
        if contact == 1:
            cn = wp.vec3d(normal[p])
        move = (f - cn * wp.dot(cn, f)) * wp.float64(inv_mass[p])
        x[p] = x[p] + wp.vec3(float(move[0]), float(move[1]), float(move[2]))
        q += 1

size = int(sys.argv[1])
sim = Simulator(build_scene("drape", size, "soft+lines", 32, 1), "cpu", use_graph=False, threads=1)
for _ in range(int(sys.argv[2]) if len(sys.argv) > 2 else 3): sim.step_frame()
model, state, solver = sim.model, sim.state, sim.solver
data, x = model.constraints["line solves"], state.particle_q
n = model.particle_count
pushes = noted_pushes(model, solver, "line")
bound = [kind.bind(model, state, pushes) for kind, _ in model.colliders.kinds]
clamps = [task for launches in bound for task in launches.clamps]
snapshot = wp.empty(n, dtype=model.position_dtype, device="cpu"); normal = wp.empty(n, dtype=wp.vec3, device="cpu")
contact = clamp_noting_normals(x, clamps, snapshot, normal, pushes)
kernel = line_solve_kernel(data.capacity, model.position_dtype, 1, None)
for task in contact: task.run()
x0 = wp.clone(x)
L = data.lines.shape[0]; cap = data.capacity
scr = [wp.zeros(L * cap, dtype=wp.vec3d, device="cpu")] + [wp.zeros(L * cap, dtype=wp.float64, device="cpu") for _ in range(3)]
def cr(first, count):
    return wp.launch_tiled(kernel, dim=[count], block_dim=1, record_cmd=True, device="cpu",
                           inputs=[x, model.inv_mass, 1, normal, data.lines[first:first + count], data.rest])
def th(first, count):
    return wp.launch(solve_lines_thomas, dim=count, record_cmd=True, device="cpu",
                     inputs=[x, model.inv_mass, 1, normal, data.lines[first:first + count], data.rest] + scr + [cap])
for name, make in (("cyclic", cr), ("thomas", th)):
    passes = [make(0, data.row_lines[0]), make(data.column_start, data.column_lines[0])]
    wp.copy(x, x0)
    for p in passes: p.launch()
    res = x.numpy().copy()
    R = 50
    t = time.perf_counter()
    for _ in range(R):
        wp.copy(x, x0)
        for p in passes: p.launch()
    tl = (time.perf_counter() - t) / R
    t = time.perf_counter()
    for _ in range(R):
        wp.copy(x, x0)
    tc = (time.perf_counter() - t) / R
    print(f"{name}: {(tl-tc)*1e3:.3f} ms per pass (copy {tc*1e3:.3f})", flush=True)
    if name == "cyclic": ref = res
    else: print("max |diff| m", np.abs(res - ref).max(), "max move", np.abs(ref - x0.numpy()).max())
