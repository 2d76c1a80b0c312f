import time, sys
import warp as wp
from bench.convergence import build_scene
from bench.common import quiet_warp
from warp_verlet.core.simulator import Simulator
from warp_verlet.launches import clamp_noting_normals, noted_pushes
from warp_verlet.kernels.line_solve import line_solve_kernel
quiet_warp()
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
def lines(first, count):
    return wp.launch_tiled(kernel, dim=[count], block_dim=1, record_cmd=True, device="cpu",
                           inputs=[x, model.inv_mass, 1, normal, data.lines[first:first + count], data.rest])
passes = [lines(0, data.row_lines[0]), lines(data.column_start, data.column_lines[0])]
x0 = wp.clone(x)
R = 50
t = time.perf_counter()
for _ in range(R):
    for task in contact: task.run()
tc = (time.perf_counter() - t) / R
t = time.perf_counter()
for _ in range(R):
    for p in passes: p.launch()
tl = (time.perf_counter() - t) / R
print(f"{size}^2: contact noting {tc*1e3:.3f} ms, line solves {tl*1e3:.3f} ms per substep; lines {data.row_lines[0]}+{data.column_lines[0]}, capacity {data.capacity}")
for task in contact:
    t = time.perf_counter()
    for _ in range(R): task.run()
    print(f"   {getattr(task, 'name', task)!s:60.60s} {(time.perf_counter() - t) / R * 1e3:.3f} ms")
