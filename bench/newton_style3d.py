"""Optional peer: the hanging cloth through Newton's Style3D cloth solver (or, as a second option, VBD).

    python -m bench.newton_style3d [--solver style3d|vbd] [--n 64] [--frames 60] [--device cuda]

Newton (github.com/newton-physics/newton, ``pip install newton``) is not a dependency of this project: this
module imports only numpy at import time, Warp and Newton inside the functions that need them, and ``main``
prints "Newton not installed: skipped" when ``import newton`` fails.

The cloth is warp_verlet's benchmark sheet: 1 m x 1 m, 0.2 kg spread evenly over an n x n grid of particles
(spacing 1/(n-1) m), vertical in the XY plane with its top edge at y = 1 m and x from -0.5 to 0.5 m, starting
flat and at rest, pinned at its two top corners (mass 0 and not ACTIVE), gravity (0, -9.81, 0), 60 fps, read
after ``frames`` frames (60 = 1 s). Positions come back in warp_verlet's row-major order: particle r * n + c,
row 0 the pinned top edge, column c along +X (so the pins are particles 0 and n - 1). ``run_peer(level=True)``
starts it level instead, in the plane y = 1 m with row r at z = r / (n - 1) m, as bench.convergence's swinging
scene.

Solvers and settings (each taken from Newton 1.8's own ``examples/cloth/example_cloth_hanging.py``):

* ``style3d``: ``newton.solvers.SolverStyle3D``, projective dynamics with a constant PD matrix assembled once
  (the "precompute") and solved by Jacobi-preconditioned PCG, 10 PCG iterations per non-linear iteration (its
  default). 2 substeps x 10 non-linear iterations. Stretch stiffness ``tri_aniso_ke = (1e4, 1e4, 1e3)``
  (weft, warp, shear), bending ``edge_aniso_ke = (2e-6, 1e-6, 5e-6)``: the example's stiff style3d cloth.
  Built with ``newton.solvers.style3d.add_cloth_grid``, whose area-lumped particle masses are then replaced by
  the even 0.2 kg / n^2 of warp_verlet. The solver scales velocities by 0.998 every substep (built in).
* ``vbd``: ``newton.solvers.SolverVBD``, vertex block descent on a graph-coloured grid. 4 substeps x 8
  iterations. The example's VBD stiffness: ``tri_ke = tri_ka = 1e3`` (membrane Lame parameters),
  ``edge_ke = 1e1`` (bending), with no damping (``tri_kd = edge_kd = 0``) by default. The example's own
  ``tri_kd = 1e2`` is a damping coefficient, not a stiffness, and on this light cloth (0.2 kg/m^2 against the
  example's 10) its damping Hessian (tri_kd / dt ~ 2.4e4) outweighs the membrane stiffness ~25 to 1, so 8
  iterations barely move the cloth back from its free-fall prediction: at n = 32 after 1 s the RMS structural
  stretch is 1.1 (the cloth hangs 2 m low), against 2.4e-2 with tri_kd = 0. ``vbd_tri_kd`` / ``--vbd-tri-kd``
  restores it. Built with ``ModelBuilder.add_cloth_grid`` (even masses already).

Both run without self-contact and without a ground (warp_verlet's hanging cloth has neither): Style3D's
built-in self-collision handler is switched off (``solver.collision = None``, as its source allows) unless
``self_contact=True``. On CUDA a frame's substep loop is captured once as a CUDA graph and replayed, as the
Newton examples do; on the CPU each frame is stepped directly.

What differs from warp_verlet: Newton solves a triangle membrane (StVK / PD springs on triangles) with dihedral
bending, not distance sticks, so positions differ by a model difference as well as by solver error; the RMS
structural stretch |D - L| / L over the same grid edges (``structural_stretch``) is the like-for-like measure.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

SKIP_MESSAGE = "Newton not installed: skipped"
SOLVERS = ("style3d", "vbd")

# The cloth (warp_verlet's benchmark sheet).
SIZE = 1.0                     # m, square
TOTAL_MASS = 0.2               # kg
TOP_LEFT = (-0.5, 1.0, 0.0)    # the origin: row 0, column 0
GRAVITY = (0.0, -9.81, 0.0)
FPS = 60.0

# Per solver: substeps, iterations (from Newton's example_cloth_hanging.py, as the brief asks).
SETTINGS = {
    "style3d": {"substeps": 2, "iterations": 10},
    "vbd": {"substeps": 4, "iterations": 8},
}
STYLE3D_TRI_ANISO_KE = (1.0e4, 1.0e4, 1.0e3)     # stretch (weft, warp, shear)
STYLE3D_EDGE_ANISO_KE = (2.0e-6, 1.0e-6, 5.0e-6)  # bending
VBD_TRI_KE = 1.0e3
VBD_TRI_KA = 1.0e3
VBD_TRI_KD = 0.0        # damping; Newton's example uses 1e2 (see the module docstring)
VBD_EDGE_KE = 1.0e1


def available() -> bool:
    """Whether Newton can be imported."""
    try:
        import newton  # noqa: F401
    except Exception:
        return False
    return True


def newton_to_grid_order(n: int) -> np.ndarray:
    """``order[k]`` is warp_verlet's index of Newton's particle k. Newton's grid helpers put particle
    j * n + i at local (i, j) * spacing, j growing up (+Y); warp_verlet's row 0 is the top edge."""
    k = np.arange(n * n)
    return (n - 1 - k // n) * n + k % n


def structural_stretch(points: np.ndarray, n: int) -> tuple[float, float]:
    """(RMS, max) of |D - L| / L over the grid's horizontal and vertical neighbour pairs, L = 1 / (n - 1),
    for ``points`` (n * n, 3) in warp_verlet's row-major order."""
    p = np.asarray(points, dtype=np.float64).reshape(n, n, 3)
    rest = SIZE / (n - 1)
    horizontal = np.linalg.norm(p[:, 1:] - p[:, :-1], axis=-1).ravel()
    vertical = np.linalg.norm(p[1:, :] - p[:-1, :], axis=-1).ravel()
    s = np.abs(np.concatenate([horizontal, vertical]) - rest) / rest
    return float(np.sqrt(np.mean(s * s))), float(s.max())


class NewtonFrames:
    """What every Newton cloth here shares: stepping a frame (its captured graph when ``graph`` is set, else
    ``simulate()``) and reading its positions in warp_verlet's particle order (``order[k]``: where Newton's
    particle k goes). A subclass sets ``graph``, ``state_0`` and ``order`` and defines ``simulate``; ``capture_frame``
also reads its ``device`` and ``substeps``."""

    graph = None

    def step_frame(self) -> None:
        import warp as wp

        if self.graph is not None:
            wp.capture_launch(self.graph)
        else:
            self.simulate()

    def capture_frame(self) -> bool:
        """On CUDA, record a frame of substeps as a graph (an even number of substeps leaves ``state_0`` holding
        the result, so the graph replays frame after frame). Whether it did."""
        import warp as wp

        if not self.device.is_cuda or self.substeps % 2:
            return False
        try:
            with wp.ScopedCapture(device=self.device) as capture:
                self.simulate()
        except Exception:
            self.graph = None
            return False
        self.graph = capture.graph
        return True

    def positions(self) -> np.ndarray:
        """(particles, 3) float32 in warp_verlet's particle order."""
        q = self.state_0.particle_q.numpy()
        out = np.empty_like(q)
        out[self.order] = q
        return out.astype(np.float32, copy=False)


class _NewtonCloth(NewtonFrames):
    """The hanging sheet as a Newton model and solver; ``step_frame`` advances one 1/60 s frame."""

    def __init__(self, solver: str, n: int, device, substeps: int, iterations: int, self_contact: bool,
                 vbd_tri_kd: float, level: bool = False):
        import math

        import warp as wp

        import newton

        self.n = n
        self.substeps = substeps
        self.iterations = iterations
        self.dt = 1.0 / (FPS * substeps)
        spacing = SIZE / (n - 1)
        ox, oy, oz = TOP_LEFT
        # Newton lays the grid's rows along +Y from pos; level, they are turned about X onto -Z, so that Newton's last
        # row (warp_verlet's pinned row 0) lies at z = oz and warp_verlet's row r at z = oz + r * spacing.
        pos, rot = (wp.vec3(ox, oy, oz + SIZE), wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), -0.5 * math.pi)) \
            if level else (wp.vec3(ox, oy - SIZE, oz), wp.quat_identity())
        grid = {"pos": pos, "rot": rot, "vel": wp.vec3(0.0, 0.0, 0.0),
                "dim_x": n - 1, "dim_y": n - 1, "cell_x": spacing, "cell_y": spacing,
                "mass": TOTAL_MASS / (n * n), "particle_radius": 0.0}

        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=GRAVITY)
        if solver == "style3d":
            from newton.solvers import style3d

            newton.solvers.SolverStyle3D.register_custom_attributes(builder)
            style3d.add_cloth_grid(builder, **grid, tri_aniso_ke=wp.vec3(*STYLE3D_TRI_ANISO_KE),
                                   edge_aniso_ke=wp.vec3(*STYLE3D_EDGE_ANISO_KE))
            # add_cloth_grid lumps triangle areas (edge and corner particles get less); use warp_verlet's even mass.
            builder.particle_mass[:] = [TOTAL_MASS / (n * n)] * (n * n)
        else:
            builder.add_cloth_grid(**grid, tri_ke=VBD_TRI_KE, tri_ka=VBD_TRI_KA, tri_kd=vbd_tri_kd,
                                   edge_ke=VBD_EDGE_KE, edge_kd=0.0)
        if len(builder.particle_q) != n * n:
            raise RuntimeError(f"expected {n * n} particles, Newton built {len(builder.particle_q)}")
        self.order = newton_to_grid_order(n)
        self.pins = [(n - 1) * n, (n - 1) * n + n - 1]  # Newton's indices of warp_verlet's particles 0 and n - 1
        for i in self.pins:
            builder.particle_mass[i] = 0.0
            builder.particle_flags[i] = builder.particle_flags[i] & ~int(newton.ParticleFlags.ACTIVE)
        if solver == "vbd":
            builder.color(include_bending=True)

        self.model = builder.finalize(device=device)
        self.model.set_gravity(GRAVITY)
        self.device = self.model.device
        self.contacts = None
        if solver == "style3d":
            self.solver = newton.solvers.SolverStyle3D(
                self.model, config=newton.solvers.SolverStyle3D.Config(iterations=iterations))
            if self_contact:
                self.contacts = newton.CollisionPipeline(self.model).contacts()
            else:
                self.solver.collision = None
        else:
            if self_contact:
                raise ValueError("self_contact is offered for style3d only")
            self.solver = newton.solvers.SolverVBD(self.model, iterations=iterations)
        self.state_0 = self.model.state()
        self.state_1 = self.model.state()
        self.control = self.model.control()
        self.graph = None

    def simulate(self) -> None:
        for _ in range(self.substeps):
            self.state_0.clear_forces()
            self.solver.step(self.state_0, self.state_1, self.control, self.contacts, self.dt)
            self.state_0, self.state_1 = self.state_1, self.state_0

    def capture(self) -> None:
        """On CUDA, record one frame's substep loop as a graph (Newton's examples do the same). An even number
        of substeps leaves ``state_0`` holding the result, so the graph can be replayed frame after frame."""
        import warp as wp

        if self.device.is_cuda and self.substeps % 2 == 0:
            with wp.ScopedCapture(device=self.device) as capture:
                self.simulate()
            self.graph = capture.graph



def run_peer(solver: str, n: int, frames: int = 60, device: str | None = None, *, substeps: int | None = None,
             iterations: int | None = None, self_contact: bool = False, vbd_tri_kd: float = VBD_TRI_KD,
             level: bool = False) -> dict:
    """Build the hanging sheet with ``n`` x ``n`` particles in Newton (``level``: started level, in the plane
    y = 1 m with its pinned edge at z = 0 and its rows along +Z, as bench.convergence's swinging scene), step
    ``frames`` frames with ``solver`` ("style3d" or "vbd") on ``device`` (Warp's default when None) and return

    setup_s        model build (builder, finalize, VBD's colouring) + solver construction (Style3D's PD-matrix
                   precompute); includes compiling Newton's kernels when Warp's kernel cache is cold
    first_frame_s  the first frame (on CUDA: graph capture + first replay)
    ms_per_frame   mean over frames 2 .. frames, synchronised (nan when frames < 2)
    positions      final (n * n, 3) float32, warp_verlet's particle order (pins are 0 and n - 1)
    substeps, iterations, note

    ``substeps`` / ``iterations`` override the solver's settings (``SETTINGS``); ``self_contact`` keeps
    Style3D's self-collision handler on; ``vbd_tri_kd`` is VBD's membrane damping (0; Newton's example: 1e2).
    """
    import warp as wp

    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    if n < 2:
        raise ValueError("n must be at least 2")
    if frames < 1:
        raise ValueError("frames must be at least 1")
    substeps = substeps or SETTINGS[solver]["substeps"]
    iterations = iterations or SETTINGS[solver]["iterations"]
    device = wp.get_device(device)

    wp.synchronize_device(device)
    t0 = time.perf_counter()
    cloth = _NewtonCloth(solver, n, device, substeps, iterations, self_contact, vbd_tri_kd, level)
    wp.synchronize_device(device)
    setup_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    cloth.capture()
    cloth.step_frame()
    wp.synchronize_device(device)
    first_frame_s = time.perf_counter() - t0

    ms_per_frame = float("nan")
    if frames > 1:
        t0 = time.perf_counter()
        for _ in range(frames - 1):
            cloth.step_frame()
        wp.synchronize_device(device)
        ms_per_frame = (time.perf_counter() - t0) * 1e3 / (frames - 1)

    if solver == "style3d":
        note = (f"SolverStyle3D, tri_aniso_ke={STYLE3D_TRI_ANISO_KE}, edge_aniso_ke={STYLE3D_EDGE_ANISO_KE}, "
                f"{cloth.solver.config.linear_iterations} PCG iterations per iteration, self-collision "
                f"{'on' if self_contact else 'off'}")
    else:
        note = (f"SolverVBD, tri_ke={VBD_TRI_KE:g}, tri_ka={VBD_TRI_KA:g}, tri_kd={vbd_tri_kd:g}, "
                f"edge_ke={VBD_EDGE_KE:g}, no self-contact")
    note += f"; {'CUDA graph per frame' if cloth.graph is not None else 'stepped without a graph'} on {device}"
    return {"solver": solver, "n": n, "setup_s": setup_s, "first_frame_s": first_frame_s,
            "ms_per_frame": ms_per_frame, "positions": cloth.positions(), "substeps": substeps,
            "iterations": iterations, "note": note}


def _quiet_warp() -> None:
    """No Warp start-up banner or module-load lines (Warp >= 1.19: log_level; before: quiet)."""
    import warp as wp

    if hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING
    else:
        wp.config.quiet = True


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.newton_style3d", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--solver", choices=SOLVERS, default="style3d")
    p.add_argument("--n", type=int, default=64, help="particles per side (default 64)")
    p.add_argument("--frames", type=int, default=60, help="frames at 60 fps (default 60 = 1 s)")
    p.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda (default: Warp's default)")
    p.add_argument("--self-contact", action="store_true", help="keep Style3D's self-collision handler on")
    p.add_argument("--vbd-tri-kd", type=float, default=VBD_TRI_KD,
                   help="VBD membrane damping (default 0; Newton's hanging-cloth example uses 1e2)")
    args = p.parse_args(argv)
    _quiet_warp()
    if not available():
        print(SKIP_MESSAGE)
        return 0
    r = run_peer(args.solver, args.n, args.frames, args.device, self_contact=args.self_contact,
                 vbd_tri_kd=args.vbd_tri_kd)
    rms, worst = structural_stretch(r["positions"], args.n)
    pos = r["positions"]
    print(f"Newton {r['solver']}, {args.n}x{args.n}, {r['substeps']} substeps x {r['iterations']} iterations, "
          f"{args.frames} frames ({r['note']})")
    print(f"  setup        {r['setup_s']:9.3f} s")
    print(f"  first frame  {r['first_frame_s']:9.3f} s")
    print(f"  per frame    {r['ms_per_frame']:9.3f} ms (mean of frames 2..{args.frames})")
    print(f"  stretch      RMS {rms:.3e}, max {worst:.3e}")
    print(f"  lowest y     {pos[:, 1].min():.4f} m (pins at y = {pos[0, 1]:.4f}, {pos[args.n - 1, 1]:.4f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
