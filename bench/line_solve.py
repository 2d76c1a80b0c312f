"""What one line pass costs: the line solves of a grid cloth (``line_passes``), launched alone on a crumpled sheet.

    python -m bench.line_solve [--device cuda] [--sizes 256 1024 ...] [--threads 128 256 ...] [--registers 64 0]
        [--repeats 50]

A horizontal n x n sheet (structural sticks; shear and bend soft) lying 1 mm inside the ground and crumpled by
0.1 spacing of noise, so that every particle is in contact and every stick is off its length. Per size and block
size (``--threads``, the threads of a CUDA block; the CPU runs one lane) and register cap (``--registers``, 0: the
compiler's choice): the time of the stage's per-substep run
(snapshot, clamp, contact normals, one pass of rows and one of columns), the fastest of ``--repeats`` runs after
a warm-up, in µs, per particle in ns, and the structural stretch (RMS / max) before and after one run.
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np


def run(device: str, n: int, threads: int, registers: int, repeats: int) -> dict:
    import warp as wp

    from warp_verlet.constraints import line_solve
    from warp_verlet.constraints.line_solve import LineSolves
    from warp_verlet.core.simulator import Simulator
    from warp_verlet.input.scene import parse_scene

    wp.config.quiet = True
    line_solve.LINE_THREADS = threads
    line_solve.LINE_MAX_REGISTERS = registers or None
    tables = {"simulation": {"substeps": 16, "iterations": 1},
              "cloth": [{"name": "sheet", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 0.0, -0.5],
                         "orientation": "horizontal", "mass": 0.2, "sticks": ["structural", "shear", "bend"],
                         "compliance": {"shear": 1.0, "bend": 1.0}, "line_passes": 1}],
              "collider": [{"type": "plane", "point": [0.0, 0.0, 0.0]}]}
    sim = Simulator(parse_scene(tables, file="<bench.line_solve>"), device, use_graph=False)
    rng = np.random.default_rng(1)
    spacing = 1.0 / (n - 1)
    crumpled = sim.model.rest_positions + rng.normal(0.0, 0.1 * spacing, (sim.model.particle_count, 3))
    crumpled[:, 1] = -0.001
    with wp.ScopedDevice(sim.device):
        stage = LineSolves().bind(sim.model, sim.state, sim.solver)
        dt = sim.scene.simulation.dt
        sim.state.set_positions(crumpled)
        before = sim.stretch()
        stage.run(sim.state, dt)
        after = sim.stretch()
        times = []
        for _ in range(repeats):
            sim.state.set_positions(crumpled)
            wp.synchronize_device()
            start = time.perf_counter()
            stage.run(sim.state, dt)
            wp.synchronize_device()
            times.append(time.perf_counter() - start)
    best = min(times)
    return {"n": n, "threads": threads, "registers": registers or "–", "us": best * 1e6, "ns_per_particle": best * 1e9 / (n * n),
            "before": before, "after": after}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--sizes", type=int, nargs="*", default=[64, 256])
    p.add_argument("--threads", type=int, nargs="*", default=[256], choices=[32, 64, 128, 256, 512])
    p.add_argument("--registers", type=int, nargs="*", default=[64])
    p.add_argument("--repeats", type=int, default=50)
    args = p.parse_args(argv)
    print("| grid | threads a block | registers | µs a run | ns a particle | stretch before (RMS / max) | after |")
    print("|---|---|---|---|---|---|---|")
    for n in args.sizes:
        for threads, registers in itertools.product(args.threads, args.registers):
            r = run(args.device, n, threads, registers, args.repeats)
            print(f"| {n}² | {threads} | {r['registers']} | {r['us']:.1f} | {r['ns_per_particle']:.2f} | {r['before'].rms:.2%} / "
                  f"{r['before'].max:.2%} | {r['after'].rms:.3%} / {r['after'].max:.3%} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
