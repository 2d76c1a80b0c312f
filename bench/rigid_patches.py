"""Rigid patches two ways: shape matching (the library's ``rigid patches`` kind) against all-pairs sticks (a
constraint kind defined here, in the bench only), on the same swinging cloth.

    python -m bench.rigid_patches [--cloth 64] [--patches 2 5 10 20] [--sweeps 16 4] [--frames 90]
                                  [--out bench/results]

--out writes rigid_patches.md and rigid_patches.csv there; bench/results/rigid_patches.md keeps a reading of
the measured run above its table, to carry over when the run is repeated.

The cloth is scenes/banner_batten.toml's swing at --cloth x --cloth particles: 1 m square, 0.3 kg, held at the
two corners of one edge (with the default tethers to them), released level at 1.5 m, structural + shear + bend
sticks (bend compliance 0.5 m/N), 60 fps, 8 substeps, damping 0.8 /s. One square patch of k x k particles sits in its middle (rows and columns
(n - k) // 2 onwards). For each patch size and each sweep count, three runs of --frames frames on one CPU thread
(``Simulator(..., threads=1)``):

- ``shape matching``: the library's kind (warp_verlet/constraints/rigid_patches.py), one thread per patch,
  last in every sweep: one launch per sweep;
- ``all-pairs sticks``: every pair of the patch's particles a rigid stick (rest = its rest-pose distance,
  weight 1), coloured by ``warp_verlet.geometry.colouring.colour`` (a particle of a k x k patch touches k² - 1 of
  them, so the patch needs that many colours or more; past 63 the rest go into the overflow colour) and
  projected by the library's ``relax_colour`` kernel, one launch per colour per sweep, last in every sweep as
  the patches are;
- ``no patch``: the same cloth without one, to show how far the same particles bend when nothing holds them.

The all-pairs kind is registered for its runs by replacing the ``rigid patches`` entry of the constraint
registry (``warp_verlet.constraints.CONSTRAINT_KINDS``) and of every module that took the registry by name
(model.py, stages.py, simulator.py), and put back afterwards: the library is not edited, so this also shows
that a kind can be added from outside. Its overflow colour is one launch whose threads share particles, which
Warp's CPU backend runs one after another (Gauss-Seidel, deterministic); a GPU would race, so the bench runs on
the CPU only.

Columns: ms/frame (the median frame's wall time, frame 1 excluded: it is the warm-up; the median, since other
work on a shared machine slows some frames), the worst |distance - rest
distance| over every pair of the patch's particles at every frame (m, and relative to the patch's size, its
largest rest distance), the cloth's structural stretch |D - L| / L (the worst per-frame RMS and the worst
maximum over the run), the launches the patch method adds to a sweep and all launches of a sweep, and the
Simulator's construction time (the all-pairs colouring is most of it).
"""

from __future__ import annotations

import statistics
import sys
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np

from warp_verlet.geometry.colouring import check_partition, colour, colour_ranges
from warp_verlet.constraints import ConstraintSet
from warp_verlet.constraints.rigid_patches import RIGID_PATCHES, RigidPatches
from warp_verlet.launches import FLOAT, VEC2I, BoundStage, elements_per_thread, recorded, split_tasks
from warp_verlet.input.scene import Scene, parse_scene
from warp_verlet.core.simulator import Simulator

from .common import arg_parser, machine, quiet_warp, write_table

METHODS = ("shape matching", "all-pairs sticks", "no patch")
STEM = "rigid_patches"


# ------------------------------------------------------------------------------- the all-pairs sticks kind

class PairSticks:
    """The patches' sticks on the device, sorted by colour: ``ends`` (S,) vec2i, ``rest`` (S,) float32 m,
    ``weight`` (S,) float32 (all 1: rigid), and per colour (first, count, whether it is the overflow colour)."""

    def __init__(self, model, scene: Scene, device):
        import warp as wp

        ends, rest = [], []
        for slot, spec in zip(model.cloths, scene.cloths):
            for patch in spec.options[RIGID_PATCHES.name]:
                members = np.asarray(patch, np.int64) + slot.first
                i, j = np.triu_indices(len(members), k=1)
                a, b = members[i], members[j]
                p = model.rest_positions.astype(np.float64)
                ends.append(np.stack([a, b], axis=1))
                rest.append(np.linalg.norm(p[a] - p[b], axis=1))
        ends = np.concatenate(ends).astype(np.int32)
        colouring = colour(ends)
        overflow = colouring.count - 1 if colouring.overflow else None
        check_partition(ends, colouring.colour, overflow)
        order, ranges = colour_ranges(colouring)
        self.count = len(ends)
        self.colours = colouring.count
        self.ranges = [(first, count, overflow is not None and colouring.colour[order[first]] == overflow)
                       for first, count in ranges]
        self.ends = wp.array(ends[order], dtype=wp.vec2i, device=device)
        self.rest = wp.array(np.concatenate(rest)[order].astype(np.float32), dtype=float, device=device)
        self.weight = wp.array(np.ones(len(ends), np.float32), dtype=float, device=device)


class AllPairsSticks(ConstraintSet):
    """Each of a cloth's ``rigid_patches`` as rigid sticks between all pairs of its particles. It owns the
    library's ``rigid_patches`` key and resolves it as the library does, so it reads the same scenes."""

    name = "all-pairs sticks"
    cloth_keys = (RIGID_PATCHES,)

    def check_cloth(self, spec, table):
        return RigidPatches().check_cloth(spec, table)

    def count(self, scene) -> int:
        return sum(len(p) * (len(p) - 1) // 2 for c in scene.cloths for p in c.options.get(RIGID_PATCHES.name, ()))

    def needed(self, req) -> bool:
        return req.count(self.name) > 0

    def device_bytes(self, req) -> int:
        return req.count(self.name) * (VEC2I + FLOAT + FLOAT)  # ends, rest length, weight

    def build(self, model, scene, device):
        import warp as wp

        if wp.get_device(device).is_cuda:
            raise RuntimeError("the all-pairs overflow colour is one launch whose threads share particles: CPU only")
        return PairSticks(model, scene, device)

    def bind(self, model, state, solver) -> BoundStage:
        from warp_verlet.kernels.relax import relax_colour

        data, x = model.constraints[self.name], state.particle_q

        def make(first, count):  # on the CPU one thread, the sticks in order: the overflow colour's order too
            k = elements_per_thread(count, model.device)
            return recorded(relax_colour, count // k, [x, model.inv_mass, data.ends, data.rest, data.weight, first, k])

        phases = [[make(first, count)] if overflow else split_tasks(make, first, count, solver.threads)
                  for first, count, overflow in data.ranges]
        return BoundStage(None, phases)


REGISTRY_NAMES = (("warp_verlet.constraints", "CONSTRAINT_KINDS"),)
"""The registry's one name: everything else reads it through ``constraints.kinds()`` at each call."""


@contextmanager
def registered(kind, replacing: str = RigidPatches.name):
    """Within the block, ``kind`` takes the place of the registry's kind named ``replacing``, in every name
    of REGISTRY_NAMES; the registry is put back afterwards."""
    import importlib

    modules = [(importlib.import_module(module), name) for module, name in REGISTRY_NAMES]
    saved = [getattr(module, name) for module, name in modules]
    if any(kinds is not saved[0] for kinds in saved):
        raise RuntimeError("the registry names no longer hold one tuple: update REGISTRY_NAMES")
    if replacing not in [k.name for k in saved[0]]:
        raise RuntimeError(f"no constraint kind named {replacing!r} to replace")
    patched = tuple(kind if k.name == replacing else k for k in saved[0])
    try:
        for module, name in modules:
            setattr(module, name, patched)
        yield
    finally:
        for (module, name), kinds in zip(modules, saved):
            setattr(module, name, kinds)


# ------------------------------------------------------------------------------------------- the runs

def swinging_cloth(cloth: int, patch: int | None, sweeps: int, frames: int) -> Scene:
    """scenes/banner_batten.toml's swing at cloth x cloth particles, with a patch x patch square in the middle
    (none for ``patch`` None)."""
    spec = {"name": "banner", "resolution": [cloth, cloth], "size": [1.0, 1.0], "origin": [0.0, 1.5, 0.0],
            "orientation": "horizontal", "mass": 0.3, "pins": ["top-left", "top-right"],
            "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 0.5}}
    if patch is not None:
        start = (cloth - patch) // 2
        spec["rigid_patches"] = [[[r, c] for r in range(start, start + patch) for c in range(start, start + patch)]]
    return parse_scene({"simulation": {"fps": 60, "frames": frames, "substeps": 8, "iterations": sweeps,
                                       "damping": 0.8}, "cloth": [spec]}, file=f"<swinging cloth {cloth}x{cloth}>")


def patch_members(cloth: int, patch: int) -> np.ndarray:
    start = (cloth - patch) // 2
    rows = np.arange(start, start + patch)
    return (rows[:, None] * cloth + rows[None, :]).ravel()


def pair_distances(points: np.ndarray) -> np.ndarray:
    p = points.astype(np.float64)
    i, j = np.triu_indices(len(p), k=1)
    return np.linalg.norm(p[i] - p[j], axis=1)


def launches_per_sweep(sim: Simulator) -> dict[str, int]:
    """The launches each constraint set a sweep runs issues, by set name."""
    from warp_verlet import constraints

    out = {}
    for kind in constraints.kinds():
        if kind.needed(sim.solver.req):
            bound = kind.bind(sim.model, sim.state, sim.solver)
            out[kind.name] = sum(1 for phase in bound.phases for task in phase if task is not None)
    return out


def run(method: str, cloth: int, patch: int, sweeps: int, frames: int) -> dict:
    """One row of the table."""
    scene = swinging_cloth(cloth, None if method == "no patch" else patch, sweeps, frames)
    members = patch_members(cloth, patch)
    with registered(AllPairsSticks()) if method == "all-pairs sticks" else nullcontext():
        start = time.perf_counter()
        sim = Simulator(scene, "cpu", threads=1)
        build = time.perf_counter() - start
        counts = launches_per_sweep(sim)
        own = {"shape matching": RigidPatches.name, "all-pairs sticks": AllPairsSticks.name}.get(method)
        rest = pair_distances(sim.model.rest_positions[members])
        size = float(rest.max())
        worst = rms = peak = 0.0
        seconds = []
        for frame in range(frames):
            start = time.perf_counter()
            sim.step_frame()
            if frame:  # frame 0 is the warm-up
                seconds.append(time.perf_counter() - start)
            points = sim.positions()
            worst = max(worst, float(np.abs(pair_distances(points[members]) - rest).max()))
            stretch = sim.stretch(points)
            rms, peak = max(rms, stretch.rms), max(peak, stretch.max)
        sim.close()
    return {"patch": f"{patch}x{patch}", "sweeps": sweeps, "method": method,
            "ms/frame": f"{1e3 * statistics.median(seconds):.2f}",
            "worst pair error m": f"{worst:.2e}", "worst pair error / patch size": f"{worst / size:.1e}",
            "stretch rms": f"{100 * rms:.3f}%", "stretch max": f"{100 * peak:.2f}%",
            "patch launches / sweep": counts.get(own, 0) if own else 0,
            "launches / sweep": sum(counts.values()), "build s": f"{build:.2f}"}


def main(argv: list[str] | None = None) -> int:
    parser = arg_parser("bench.rigid_patches", __doc__)
    parser.add_argument("--cloth", type=int, default=64, help="particles along each side of the cloth")
    parser.add_argument("--patches", type=int, nargs="+", default=[2, 5, 10, 20], help="particles along a patch's side")
    parser.add_argument("--sweeps", type=int, nargs="+", default=[16, 4], help="sweeps per substep")
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--out", type=Path, default=None, help="directory for rigid_patches.md and .csv")
    args = parser.parse_args(argv)
    if any(not 2 <= p <= args.cloth for p in args.patches) or args.frames < 2:
        parser.error("each patch needs 2 to --cloth particles a side, and --frames at least 2")
    quiet_warp()
    rows = [run(method, args.cloth, patch, sweeps, args.frames)
            for patch in args.patches for sweeps in args.sweeps for method in METHODS]
    where = machine("cpu")
    command = ["bench.rigid_patches", *(sys.argv[1:] if argv is None else argv)]
    title = (f"Rigid patches: shape matching against all-pairs sticks, a {args.cloth}x{args.cloth} swinging "
             f"cloth, {args.frames} frames at 60 fps, 8 substeps, one CPU thread\n\n" + "\n".join(where.lines(command)))
    write_table(rows, args.out, STEM, title)
    return 0


if __name__ == "__main__":
    sys.exit(main())
