"""The pinned 20-particle chain of bench/stability_cases/stiff.py (line_chain) on the CPU and on CUDA: depth of its
end below the pin after 8 s, per end mass, sweeps and line passes. Run from the repository root (PYTHONPATH=.)."""
import warp as wp

from bench.stability_cases.stiff import settled_chain

wp.config.quiet = True
for dev in ("cpu", "cuda"):
    for ratio, K, passes in [(1e2, 1, 1), (1e2, 1, 2), (1e2, 8, 1), (1e3, 1, 4), (1e3, 1, 8), (1e3, 8, 4)]:
        sim = settled_chain(dev, 20, ratio, K, passes)
        p = sim.positions().astype(float)
        print(dev, ratio, K, passes, "depth %.6f offset %.2e form %s" % (p[0, 1] - p[-1, 1], abs(p[-1, 0] - p[0, 0]),
                                                                        sim.model.sticks_form), flush=True)
