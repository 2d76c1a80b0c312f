"""Which order to hold a mesh cloth's particles in: the input order, Morton order (what the Model uses) or reverse
Cuthill-McKee, timed in turns on the same scenes.

    python -m bench.particle_orders --device cpu --sizes 256 512 --threads 1 --out bench/results/mesh --stem orders-cpu-epyc
    python -m bench.particle_orders --device cuda --sizes 512 1024 --out bench/results/mesh --stem orders-h100

For each size n, bench.mesh_throughput's quad mesh and triangle mesh (the benchmark hanging cloth's points and
faces as a mesh file, n x n particles), their vertices listed in a random order (--shuffle, the default: a mesh
whose vertex numbering follows no path across the surface) or in the grid's row-major order (--no-shuffle). Each
order gets its own Simulator of the same scene; after two warm-up frames the simulators take turns, --frames
frames each per round over --rounds rounds, so that a change in the machine's load falls on every order alike;
ms/frame is each order's median round, spread half its range.

Orders: "input" is Simulator's particle_order "input"; "Morton" is "morton" (warp_verlet/geometry/particle_order.py);
"RCM" is scipy.sparse.csgraph.reverse_cuthill_mckee of the stick graph, put in Morton's place for its Simulator
(scipy is not a dependency of warp-verlet: this benchmark needs it installed). "order s" is the time the order
itself takes on the host.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

import numpy as np
import warp as wp

from warp_verlet.core import model as model_module
from warp_verlet.core.simulator import Simulator
from warp_verlet.geometry.particle_order import locality_order
from warp_verlet.geometry.topology import build_cloth

from .common import arg_parser, machine, quiet_warp, write_table
from .mesh_throughput import grid_and_meshes

ORDERS = ("input", "Morton", "RCM")
MESHES = ("quad mesh", "triangle mesh")


def rcm_order(particles: int, sticks: np.ndarray) -> np.ndarray:
    """Reverse Cuthill-McKee of the graph whose edges are the sticks: ``order[k]`` is the particle at place k."""
    import scipy.sparse as sparse
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    ones = np.ones(len(sticks), np.int8)
    graph = sparse.coo_matrix((ones, (sticks[:, 0], sticks[:, 1])), shape=(particles, particles)).tocsr()
    return np.asarray(reverse_cuthill_mckee((graph + graph.T).tocsr(), symmetric_mode=True), np.int32)


def simulators(the_scene, device: str, threads: int | None) -> tuple[dict, dict]:
    """One Simulator per order of ``the_scene``'s mesh cloth, and each order's host time in seconds."""
    topology = build_cloth(the_scene.cloths[0])
    start = time.perf_counter()
    morton = locality_order(topology.positions)
    seconds = {"input": 0.0, "Morton": time.perf_counter() - start}
    start = time.perf_counter()
    rcm = rcm_order(topology.particle_count, topology.sticks)
    seconds["RCM"] = time.perf_counter() - start
    sims = {"input": Simulator(the_scene, device, threads=threads, particle_order="input"),
            "Morton": Simulator(the_scene, device, threads=threads, particle_order="morton")}
    with mock.patch.object(model_module, "locality_order", lambda points: rcm):
        sims["RCM"] = Simulator(the_scene, device, threads=threads, particle_order="morton")
    assert np.array_equal(sims["Morton"].model.scene_particle, morton)
    assert np.array_equal(sims["RCM"].model.scene_particle, rcm)
    return sims, seconds


def in_turns(sims: dict, frames: int, rounds: int) -> dict[str, list[float]]:
    """Seconds per frame of each simulator, per round, the simulators taking turns."""
    for sim in sims.values():
        sim.step_frame()  # compiles, initialises the Verlet state
        sim.step_frame()  # captures the frame
    out = {name: [] for name in sims}
    for _ in range(rounds):
        for name, sim in sims.items():
            wp.synchronize_device(sim.device)
            start = time.perf_counter()
            for _ in range(frames):
                sim.step_frame()
            wp.synchronize_device(sim.device)
            out[name].append((time.perf_counter() - start) / frames)
    return out


def main(argv=None) -> int:
    p = arg_parser("bench.particle_orders", __doc__)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    p.add_argument("--frames", type=int, default=3, help="frames per order per round (default 3)")
    p.add_argument("--rounds", type=int, default=6, help="rounds of turns (default 6)")
    p.add_argument("--threads", type=int, default=None, help="CPU relaxation threads (default: automatic)")
    p.add_argument("--no-shuffle", action="store_true", help="the mesh files list their vertices in row-major order")
    p.add_argument("--out", type=Path, default=None, help="write STEM.md and STEM.csv here")
    p.add_argument("--stem", default="particle_orders", help="output names (default particle_orders)")
    args = p.parse_args(argv)
    quiet_warp()
    device = wp.get_device(args.device)
    command = ["bench.particle_orders", *(argv if argv is not None else sys.argv[1:])]
    rows = []
    for n in args.sizes:
        with tempfile.TemporaryDirectory(prefix="particle_orders-") as tmp:
            scenes = grid_and_meshes(n, 4, 8, "corners", "ply", Path(tmp), shuffle=not args.no_shuffle)
            for variant in MESHES:
                sims, seconds = simulators(scenes[variant][0], str(device), args.threads)
                try:
                    times = in_turns(sims, args.frames, args.rounds)
                finally:
                    for sim in sims.values():
                        sim.close()
                input_ms = statistics.median(times["input"]) * 1e3
                for name in ORDERS:
                    ms = statistics.median(times[name]) * 1e3
                    rows.append({"size": f"{n}x{n}", "variant": variant, "particle order": name,
                                 "ms/frame": f"{ms:.3f}",
                                 "spread": f"±{(max(times[name]) - min(times[name])) / 2 / (ms / 1e3) * 100:.1f}%",
                                 "vs input": f"{ms / input_ms:.2f}x", "order s": f"{seconds[name]:.3f}",
                                 "threads": sims[name].threads})
                    print(rows[-1], flush=True)
    where = machine(device)
    title = (f"Particle orders of a mesh cloth, hanging cloth (4 substeps x 8 iterations, coloured Gauss-Seidel), "
             f"{'row-major' if args.no_shuffle else 'shuffled'} vertex lists: {where}\n\n"
             + "\n".join(where.lines(command)) + "\n\n"
             f"- The orders take turns: {args.rounds} rounds of {args.frames} frames each; ms/frame is the median "
             "round. vs input: against the input order's median. order s: the order's host time (Morton: "
             "particle_order.locality_order; RCM: scipy's reverse_cuthill_mckee of the stick graph).\n")
    write_table(rows, args.out, args.stem, title)
    return 0


if __name__ == "__main__":
    sys.exit(main())
