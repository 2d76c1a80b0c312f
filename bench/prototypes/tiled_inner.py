"""Prototype (dropped): a scene of bench.convergence on one CPU thread with a chosen sticks form; with this
commit's kernels/grid_tiles.py, INNER passes over a tile's colours per staging and TILE_SHIFT cells of tile
offset every other sweep. Usage: PYTHONPATH=. python bench/prototypes/tiled_inner.py N SxK FORM [SCENE] [JSON]"""
import sys, os, json, time
import numpy as np, warp as wp
wp.config.quiet = True
from bench import convergence as conv
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
n = int(sys.argv[1]); S, K = map(int, sys.argv[2].split("x")); form = sys.argv[3]
kind = sys.argv[4] if len(sys.argv) > 4 else "drape"
extra = json.loads(sys.argv[5]) if len(sys.argv) > 5 else {}
tables = conv.merge(conv.SCENES[kind][0](n, S, K), extra)
scene = parse_scene(tables, file="<x>")
sim = Simulator(scene, "cpu", threads=1, sticks=form)
t = time.perf_counter()
for f in range(scene.simulation.frames):
    sim.step_frame()
x = sim.positions(); st = sim.stretch(x)
print(f"{kind} {n} {S}x{K} {form} INNER={os.environ.get('INNER','1')}: rms {st.rms*100:.3f}% max {st.max*100:.2f}% lowest {x[:,1].min():.3f}  {(time.perf_counter()-t)/scene.simulation.frames*1e3:.0f} ms/frame")
