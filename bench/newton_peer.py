"""Optional peer: the same hanging cloth through Newton's VBD cloth solver (``pip install newton``), on the CPU.

    python -m bench.newton_peer [--size 64] [--substeps 4] [--iterations 8] [--frames 30]

Newton (github.com/newton-physics/newton) is not a dependency of this project; when ``import newton`` fails
every entry point prints "Newton not installed: skipped" and does nothing else.

What is the same: particle count and layout (``ModelBuilder.add_cloth_grid``, reordered to warp_verlet's
row-major order, rows running down -Y), cloth size, total mass spread evenly, the pinned particles (mass 0
and not ACTIVE), the start pose at rest, gravity, frame rate, substeps and iterations per substep.
What is not: Newton's VBD solves a StVK triangle membrane (``tri_ke``, ``tri_ka``) with dihedral bending
(``edge_ke``) by vertex block descent, not distance sticks; it has no damping. So its positions differ
from warp_verlet's by a model difference as well as by solver error; the RMS structural stretch |D - L|/L over
the same grid edges is the like-for-like measure of how well each holds the weave. (Newton's XPBD solver with
springs on the same sticks was tried too: its un-averaged Jacobi spring sum diverges on this cloth at every
stiffness tried, 1e2 .. 1e6 N/m, so it is not offered here.)
"""

from __future__ import annotations

import sys
import time

import numpy as np

from warp_verlet.core.simulator import Simulator

from .common import arg_parser, hanging_cloth, quiet_warp

SKIP_MESSAGE = "Newton not installed: skipped"
TRI_KE = 1.0e4      # membrane stiffness (Newton's tri_ke and tri_ka)
EDGE_KE = 1.0e-3    # bending stiffness


def available() -> bool:
    try:
        import newton  # noqa: F401
    except Exception:
        return False
    return True


class NewtonCloth:
    """One vertical cloth of a warp_verlet scene in Newton, stepped with SolverVBD on ``device``."""

    def __init__(self, scene, substeps: int | None = None, iterations: int | None = None, device: str = "cpu",
                 tri_ke: float = TRI_KE, edge_ke: float = EDGE_KE):
        import warp as wp

        import newton

        if len(scene.cloths) != 1 or scene.colliders:
            raise ValueError("the Newton peer handles one cloth and no colliders")
        spec = scene.cloths[0]
        if spec.orientation != "vertical" or any(scene.simulation.wind):
            raise ValueError("the Newton peer handles a vertical cloth without wind")
        s = scene.simulation
        self.substeps = substeps or s.substeps
        self.iterations = iterations or s.iterations
        self.dt = 1.0 / (s.fps * self.substeps)
        rows, cols = spec.resolution
        height, width = spec.size
        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=tuple(float(g) for g in s.gravity))
        ox, oy, oz = spec.origin
        builder.add_cloth_grid(pos=wp.vec3(ox, oy - height, oz), rot=wp.quat_identity(), vel=wp.vec3(0.0),
                               dim_x=cols - 1, dim_y=rows - 1, cell_x=width / (cols - 1), cell_y=height / (rows - 1),
                               mass=spec.mass / (rows * cols), tri_ke=tri_ke, tri_ka=tri_ke, tri_kd=0.0,
                               edge_ke=edge_ke, edge_kd=0.0, particle_radius=0.0)
        # Newton's particle j * cols + i sits at row rows - 1 - j, column i of warp_verlet's grid.
        k = np.arange(rows * cols)
        self.order = (rows - 1 - k // cols) * cols + k % cols
        for r, c in spec.pins:
            i = (rows - 1 - r) * cols + c
            builder.particle_mass[i] = 0.0
            builder.particle_flags[i] = builder.particle_flags[i] & ~int(newton.ParticleFlags.ACTIVE)
        builder.color(include_bending=True)
        self.model = builder.finalize(device=device)
        self.solver = newton.solvers.SolverVBD(self.model, iterations=self.iterations)
        self.state, self.next_state = self.model.state(), self.model.state()
        self.control = self.model.control()
        self.device = self.model.device

    def step_frame(self) -> None:
        for _ in range(self.substeps):
            self.state.clear_forces()
            self.solver.step(self.state, self.next_state, self.control, None, self.dt)
            self.state, self.next_state = self.next_state, self.state

    def positions(self) -> np.ndarray:
        """(N, 3) float32 in warp_verlet's particle order."""
        q = self.state.particle_q.numpy()
        out = np.empty_like(q)
        out[self.order] = q
        return out


def run(scene, substeps: int, iterations: int, frames: int, repeats: int = 1, device: str = "cpu") -> dict:
    """Wall seconds of each of ``repeats`` runs of ``frames`` frames from the initial state (after a one-frame
    warm-up that compiles Newton's kernels) and the last run's positions after every frame, (F, N, 3) in
    warp_verlet's order (copying them out costs ~0.1 ms a frame against Newton's hundreds)."""
    import warp as wp

    warm = NewtonCloth(scene, substeps, iterations, device)
    warm.step_frame()
    times = []
    for _ in range(repeats):
        cloth = NewtonCloth(scene, substeps, iterations, device)
        traj = []
        wp.synchronize_device(cloth.device)
        start = time.perf_counter()
        for _ in range(frames):
            cloth.step_frame()
            traj.append(cloth.positions())
        wp.synchronize_device(cloth.device)
        times.append(time.perf_counter() - start)
    return {"times": times, "trajectory": np.stack(traj)}


def main(argv=None) -> int:
    p = arg_parser("bench.newton_peer", __doc__)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--substeps", type=int, default=4)
    p.add_argument("--iterations", type=int, default=8)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--repeats", type=int, default=1)
    args = p.parse_args(argv)
    if not available():
        print(SKIP_MESSAGE)
        return 0
    quiet_warp()
    scene = hanging_cloth(args.size, args.substeps, args.iterations)
    r = run(scene, args.substeps, args.iterations, args.frames, args.repeats)
    per_frame = float(np.median(r["times"])) / args.frames
    sim = Simulator(scene, device="cpu")
    for _ in range(args.frames):
        sim.step_frame()
    print(f"{args.size}x{args.size}, {args.substeps} substeps x {args.iterations} iterations, {args.frames} frames:")
    print(f"  Newton VBD    {per_frame * 1e3:8.2f} ms/frame, RMS structural stretch {sim.stretch(r['trajectory'][-1]).rms:.3e}")
    print(f"  warp_verlet   (same frames)         RMS structural stretch {sim.stretch().rms:.3e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
