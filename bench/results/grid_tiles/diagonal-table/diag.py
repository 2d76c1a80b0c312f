import sys, numpy as np, warp as wp
wp.config.quiet = True
from bench.convergence import build_scene, simulate
import warp_verlet.constraints.sticks as st
from warp_verlet.core.simulator import Simulator
# bit-identity on CUDA: 256^2, 10 frames, table vs none
pos = {}
for flag in (False, True):
    st.GRID_TILE_DIAGONAL_TABLE = flag
    sim = Simulator(build_scene("hanging", 256, "tethers", 16, 2, None), "cuda", sticks="tiled")
    for _ in range(10):
        sim.step_frame()
    pos[flag] = sim.positions().copy()
print("cuda bit-identical:", np.array_equal(pos[False], pos[True]), flush=True)
cases = [(1024, 64, 1), (1024, 32, 1), (1024, 4, 8), (2048, 64, 1)]
for n, s, k in cases:
    for rep in range(2):
        for flag in (False, True):
            st.GRID_TILE_DIAGONAL_TABLE = flag
            r = simulate(build_scene("hanging", n, "tethers", s, k, None), "cuda", None)
            print(f"{n}^2 {s}x{k} table={flag!s:5} rep{rep}: {r['ms_per_frame']:.3f} ms/frame "
                  f"(mean {r['ms_per_frame_mean']:.3f})  RMS {r['rms']*100:.4f}% max {r['max']*100:.3f}%", flush=True)
