"""Line passes on hanging chains: a 20-particle chain with a heavy end and a uniform 200-particle rope, pinned at
one end, released level, settled for 8 s (60 fps, 4 substeps, 0.98 of the velocity kept a substep), with and
without line passes. Run from the repository root: PYTHONPATH=. python bench/results/line_solve/cpu/chains.py"""
import warp as wp

from bench.stability_cases.stiff import settled_chain

wp.config.quiet = True
print("| line | mass ratio (end / others) | sweeps | line passes | hanging depth, m (rest 1 m) | max stretch |")
print("|---|---|---|---|---|---|")
for n, ratio in [(20, 1e2), (20, 1e3), (20, 1e4), (200, 1)]:
    for sweeps in (1, 8):
        for passes in (0, 1, 4):
            sim = settled_chain("cpu", n, ratio, sweeps, passes)
            p = sim.positions().astype(float)
            depth = p[0, 1] - p[-1, 1]
            print(f"| {n} particles | {ratio:g} | {sweeps} | {passes} | {depth:.4f} | {sim.stretch().max:.3g} |",
                  flush=True)
