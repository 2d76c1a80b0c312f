"""Drape probe: stretch over time, tiled vs a launch per colour, with and without line passes."""
import sys, time
import numpy as np, warp as wp
wp.config.quiet = True
from bench import convergence as cv
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator

def run(n, S, K, lines, sticks="auto", frames=90):
    t = cv.merge(cv.drape(n, S, K, frames), {"cloth": {"compliance": {"shear": 1.0, "bend": 1.0}, "line_passes": lines}})
    sim = Simulator(parse_scene(t, file="<p>"), "cuda", sticks=sticks)
    hist = []
    timed = 0.0
    for f in range(frames):
        wp.synchronize()
        t0 = time.perf_counter()
        sim.step_frame()
        wp.synchronize()
        if f >= 2:
            timed += time.perf_counter() - t0
        if f % 15 == 14:
            s = sim.stretch()
            hist.append(f"{f+1}:{100*s.rms:.2f}/{100*s.max:.1f}/{sim.positions()[:,1].min():.2f}")
    s = sim.stretch()
    print(f"| {n}² | {sticks} | {sim.model.sticks_form} | {S} x {K} | {lines} | {timed/(frames-2)*1e3:.2f} | {100*s.rms:.3f}% | {100*s.max:.2f}% | {' '.join(hist)} |", flush=True)
    sim.close()

print("| grid | sticks asked | form | S x K | line passes | ms/frame | RMS | max | frame: RMS%/max%/lowest y |")
print("|---|---|---|---|---|---|---|---|---|")
# (grid, substeps, sweeps, line passes[, sticks]) of each run; the list differed between the leases:
# probe-1.md: (1024, 64, 1, 1, "implicit"), (1024, 64, 1, 0, "implicit"), (1024, 64, 1, 1), (256, 64, 1, 1), (256, 32, 1, 1)
# probe-2.md: the list below; probe-staged.md: (1024, 64, 1, 1), (1024, 64, 2, 1)
RUNS = [(1024, 64, 2, 0), (1024, 64, 2, 1), (1024, 64, 1, 0), (2048, 64, 1, 0), (2048, 64, 1, 1)]
for args in RUNS:
    run(*args)
