"""Optional peer for bench.self_contact: the same folded cloth dropped on the ground, through NVIDIA Newton's VBD
solver (``newton.solvers.SolverVBD``, its particle self-contact on) and Style3D solver
(``newton.solvers.SolverStyle3D``, its collision handler on), measured with bench.self_contact's own meter.

    python -m bench.self_contact --peer [--sizes 32 64] [--frames 60] [--device cpu]

Written against Newton 1.8.0 (the newton-1.8.0-py3-none-any.whl wheel; it needs warp-lang and numpy only).

Newton (github.com/newton-physics/newton, ``pip install newton``) is not a dependency of this project: this
module imports Newton only inside the functions that need it, and
``peer_rows`` prints "Newton not installed: skipped" and returns no rows when ``import newton`` fails.

The same as warp-verlet's run: n x n particles of a 1 m square, 0.3 kg spread evenly (0.3 / n^2 kg each), laid
horizontal at y = 0.1 m (row r along +Z, column c along +X, origin (-0.5, 0.1, -0.5)), the rest sheet flat (Newton's
triangle rest shapes and rest dihedral angles come from it), started from bench.self_contact's fold of it (the
positions, in Newton's order), at rest; gravity (0, -9.81, 0); a ground plane y = 0 with friction 0.5; 60 fps,
the same substeps and iterations per substep (VBD: block-descent iterations; Style3D: non-linear iterations, each
of 10 PCG iterations); the same contact distance, warp-verlet's thickness 0.8 x the spacing 1 / (n - 1) m: VBD's
``particle_self_contact_margin`` (the distance at which vertex-triangle and edge-edge pairs start to push) is the
thickness, its ``particle_self_contact_gap`` (detection reach beyond it) half of it; Style3D's
``Collision.radius`` is half the thickness (it pushes pairs closer than 2 x radius; its built-in 3 mm radius is
set once in its constructor, for garments, and is replaced here before the first step). Newton builds the grid
with ``ModelBuilder.add_cloth_grid`` (VBD) or ``newton.solvers.style3d.add_cloth_grid`` (Style3D), rotated a
quarter turn about +X so that its particle j * n + i lands on warp-verlet's particle r * n + c with r = j, c = i;
the order is found by matching rest positions to grid cells, not assumed. The worst penetration is
bench.self_contact's ``PointsGapMeter`` (its ``GapMeter``'s measure) on Newton's positions in warp-verlet's order,
with warp-verlet's rest positions, thickness and rest exclusion (pairs closer than 1.5 thicknesses at rest are not
counted), at the end of every frame, outside the timing; ms/frame is the median frame's synchronised wall time,
frame 1 excluded.

What differs (Newton's model is not warp-verlet's):

* Cloth model. Newton solves a triangle membrane with dihedral bending, not distance sticks: VBD an StVK
  membrane ``tri_ke = tri_ka = 1e4`` with bending ``edge_ke = 1e-3`` (bench.newton_peer's VBD cloth) and no
  element damping; Style3D its projective-dynamics springs ``tri_aniso_ke = (1e4, 1e4, 1e3)``, bending
  ``edge_aniso_ke = (2e-6, 1e-6, 5e-6)`` (bench.newton_style3d's cloth). warp-verlet's sticks are rigid (its bend
  sticks soft, 1 m/N). Style3D's grid helper lumps triangle areas into masses; they are replaced by the even
  0.3 / n^2 kg.
* Damping. warp-verlet damps velocity at 0.5 /s; VBD has no global velocity damping (none is set); Style3D scales
  velocities by 0.998 each substep (built in, not adjustable).
* Contact laws. warp-verlet projects particle-particle distances to the thickness (a hard constraint, a hash grid
  rebuilt each substep). VBD's self-contact is a log-barrier force between vertex-triangle and edge-edge pairs
  within the margin, stiffness ``soft_contact_ke = 1e3`` N/m (damping ``soft_contact_kd = 1e-2``), with
  divide-and-truncate steps that keep each vertex inside its conservative bound; pairs within 2 topological rings
  are ignored (its default). Style3D's is a penalty on vertex-face, edge-edge and edge-face pairs (its built-in
  stiffness coefficients). Neither keeps particle-particle distances, which the meter measures: a vertex may sit
  the thickness above a triangle's interior and nearer than the thickness to none of its corners, or the other way.
* Friction. The ground's friction coefficient is 0.5 in both (Newton's shape ``mu`` and ``soft_contact_mu``,
  0.5 each; VBD mixes them by their geometric mean). VBD's self-contact takes its friction from the same
  ``soft_contact_mu``, so it has 0.5 too; warp-verlet's self-contact has none (``self_friction_coefficient`` 0,
  its default).
* The ground. warp-verlet keeps particles above y = 0 by projection (plane thickness 0). Newton pushes a particle
  whose centre is within ``particle_radius`` of the plane by a penalty (the pipeline's ``soft_contact_gap`` is the
  thickness, for detection): the radius is 0.1 x the thickness, so the lower layer rests about that far above the
  ground. VBD's ground stiffness is the mean of the ground shape's ``ke`` (1e5 N/m) and ``soft_contact_ke``
  (1e3 N/m): with the ground at 1e3 too, the 64 x 64 cloth's lower layer, pressed by the upper one's barrier,
  went 4 mm into the ground and bounced 2 cm back up. Style3D's ground takes ``soft_contact_ke`` alone.
* Collision detection. VBD's solver owns its ``newton.CollisionPipeline`` and detects ground contacts and
  self-contacts inside each ``step`` (Newton's example_cloth_bending pattern). Style3D's self-contact candidates
  come from its own BVHs, refitted at each substep; its ground contacts from a pipeline run once a frame, before
  the substeps (Newton's example_cloth_style3d pattern).
* Graphs. On CUDA, Newton's frame of substeps is captured once as a graph and replayed (as Newton's examples do),
  when the capture succeeds; warp-verlet's self-contact frame is stepped launch by launch there. On the CPU
  Newton's frames are stepped directly (Style3D's host calls cannot be captured there, as its example says);
  warp-verlet replays its CPU capture.

Each solver runs twice, as warp-verlet does, with its self-contact off and on; "off" keeps the ground (VBD:
``particle_enable_self_contact=False``; Style3D: its self-contact stiffnesses set to 0, its ground contact kept).
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np

from warp_verlet.geometry.topology import grid_positions

from .common import timed_frames
from .newton_style3d import NewtonFrames

SKIP_MESSAGE = "Newton not installed: skipped"
SOLVERS = ("vbd", "style3d")
LABELS = {"vbd": "newton-vbd", "style3d": "newton-style3d"}

GRAVITY = (0.0, -9.81, 0.0)
FPS = 60.0
GROUND_FRICTION = 0.5
CONTACT_KE = 1.0e3              # N/m, Newton's soft contact stiffness (ground and VBD self-contact)
CONTACT_KD = 1.0e-2             # its damping
GROUND_KE = 1.0e5               # N/m, the ground shape's stiffness (VBD's ground contact: the mean of it and CONTACT_KE)
RADIUS_FRACTION = 0.1           # Newton's particle_radius (ground contact) / warp-verlet's thickness
VBD_TRI_KE = 1.0e4              # membrane (tri_ke and tri_ka), bench.newton_peer's
VBD_EDGE_KE = 1.0e-3            # bending, bench.newton_peer's
STYLE3D_TRI_ANISO_KE = (1.0e4, 1.0e4, 1.0e3)     # bench.newton_style3d's
STYLE3D_EDGE_ANISO_KE = (2.0e-6, 1.0e-6, 5.0e-6)


def available() -> bool:
    """Whether Newton can be imported."""
    try:
        import newton  # noqa: F401
    except Exception:
        return False
    return True


def grid_order(points: np.ndarray, n: int, origin, spacing: float) -> np.ndarray:
    """``order[k]``: warp-verlet's index (r * n + c, r along +Z, c along +X) of the particle at ``points[k]``, a
    horizontal n x n grid ``spacing`` apart from ``origin``. Raises when the points are not such a grid."""
    p = np.asarray(points, dtype=np.float64)
    cell = (p - np.asarray(origin, dtype=np.float64)) / spacing
    c, r = np.rint(cell[:, 0]).astype(int), np.rint(cell[:, 2]).astype(int)
    order = r * n + c
    off_grid = np.abs(cell[:, [0, 2]] - np.stack([c, r], axis=1)).max() if len(p) else 0.0
    if (len(p) != n * n or off_grid > 1e-3 or np.abs(cell[:, 1]).max() > 1e-3 or c.min() < 0 or r.min() < 0
            or c.max() >= n or r.max() >= n or len(np.unique(order)) != n * n):
        raise RuntimeError(f"Newton's cloth is not warp-verlet's {n} x {n} grid (off by {off_grid:.3g} cells)")
    return order


class NewtonFoldedCloth(NewtonFrames):
    """bench.self_contact's folded cloth in Newton; ``step_frame`` advances one 1/60 s frame."""

    def __init__(self, solver: str, n: int, start: np.ndarray, origin, self_contact: bool, substeps: int,
                 iterations: int, device=None):
        """``start``: the folded positions, (n * n, 3) in warp-verlet's order; ``origin``: the rest grid's
        particle 0."""
        import warp as wp

        import newton

        if solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        self.substeps, self.dt = substeps, 1.0 / (FPS * substeps)
        spacing = 1.0 / (n - 1)
        thickness = 0.8 * spacing
        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=GRAVITY)
        grid = {"pos": wp.vec3(*origin), "rot": wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), 0.5 * math.pi),
                "vel": wp.vec3(0.0, 0.0, 0.0), "dim_x": n - 1, "dim_y": n - 1, "cell_x": spacing,
                "cell_y": spacing, "mass": 0.3 / (n * n), "particle_radius": RADIUS_FRACTION * thickness}
        if solver == "style3d":
            from newton.solvers import style3d

            newton.solvers.SolverStyle3D.register_custom_attributes(builder)
            style3d.add_cloth_grid(builder, **grid, tri_aniso_ke=wp.vec3(*STYLE3D_TRI_ANISO_KE),
                                   edge_aniso_ke=wp.vec3(*STYLE3D_EDGE_ANISO_KE))
            builder.particle_mass[:] = [0.3 / (n * n)] * (n * n)  # not its area-lumped masses
        else:
            builder.add_cloth_grid(**grid, tri_ke=VBD_TRI_KE, tri_ka=VBD_TRI_KE, tri_kd=0.0, edge_ke=VBD_EDGE_KE,
                                   edge_kd=0.0)
            builder.color(include_bending=True)
        ground = newton.ModelBuilder.ShapeConfig(ke=GROUND_KE, kd=CONTACT_KD, mu=GROUND_FRICTION)
        builder.add_ground_plane(cfg=ground)
        self.order = grid_order(np.asarray(builder.particle_q), n, origin, spacing)

        self.model = builder.finalize(device=device)
        self.model.soft_contact_ke, self.model.soft_contact_kd = CONTACT_KE, CONTACT_KD
        self.model.soft_contact_mu = GROUND_FRICTION
        self.device = self.model.device
        self.state_0, self.state_1 = self.model.state(), self.model.state()
        self.control = self.model.control()
        folded = np.asarray(start, dtype=np.float32)[self.order]  # Newton's particle k is warp-verlet's order[k]
        for state in (self.state_0, self.state_1):
            state.particle_q.assign(folded)
        self.pipeline = newton.CollisionPipeline(self.model, broad_phase="nxn", soft_contact_gap=thickness)
        if solver == "vbd":
            self.contacts = None  # the solver owns the pipeline and detects inside step()
            self.solver = newton.solvers.SolverVBD(
                self.model, iterations=iterations, particle_enable_self_contact=self_contact,
                particle_self_contact_margin=thickness, particle_self_contact_gap=0.5 * thickness,
                collision_pipeline=self.pipeline)
        else:
            self.contacts = self.pipeline.contacts()
            self.solver = newton.solvers.SolverStyle3D(
                self.model, config=newton.solvers.SolverStyle3D.Config(iterations=iterations))
            collision = self.solver.collision
            collision.radius = 0.5 * thickness  # it pushes pairs closer than 2 x radius apart
            if not self_contact:  # keep its ground contact, drop its self-contact
                collision.stiff_vf = collision.stiff_ee = collision.stiff_ef = 0.0
            collision.rebuild_bvh(self.state_0.particle_q)
        self.solver_name, self.graph = solver, None

    def simulate(self) -> None:
        if self.contacts is not None:
            self.pipeline.collide(self.state_0, self.contacts)
        for _ in range(self.substeps):
            self.state_0.clear_forces()
            self.solver.step(self.state_0, self.state_1, self.control, self.contacts, self.dt)
            self.state_0, self.state_1 = self.state_1, self.state_0


def run(solver: str, n: int, self_contact: bool, frames: int, substeps: int, iterations: int, device) -> dict:
    """One row of bench.self_contact's table for Newton's ``solver``, with its self-contact on or off."""
    import warp as wp

    from . import self_contact as bench

    spec = bench.folded_scene(n, True, frames, substeps, iterations).cloths[0]
    rest = grid_positions(spec)
    thickness = bench.DEFAULT_FRACTION * bench.SIZE / (n - 1)
    start = bench.folded(rest, bench.SIZE / (n - 1), thickness)
    device = wp.get_device(device)
    wp.synchronize_device(device)
    began = time.perf_counter()
    cloth = NewtonFoldedCloth(solver, n, start, spec.origin, self_contact, substeps, iterations, device)
    captured = cloth.capture_frame()
    wp.synchronize_device(device)
    build = time.perf_counter() - began
    meter = bench.PointsGapMeter(rest, thickness, device)
    readings = []
    times = timed_frames(cloth, frames, lambda: readings.append(meter.penetration_of(cloth.positions())))
    return {"simulator": LABELS[solver], "n": n, "self_collision": "on" if self_contact else "off",
            "particles": n * n, "ms/frame": round(1e3 * statistics.median(times[1:]), 3),
            "worst penetration": round(max([0.0, *readings]), 4), "build s": round(build, 2),
            "graph": captured}


def peer_rows(n: int, frames: int, substeps: int, iterations: int, device, solvers=SOLVERS,
              report=print) -> list[dict]:
    """Newton's rows for one size, each solver with its self-contact off and on, "x without" against its own
    run without; none (and ``report(SKIP_MESSAGE)``) without Newton."""
    if not available():
        report(SKIP_MESSAGE)
        return []
    rows = []
    for solver in solvers:
        without, with_contact = (run(solver, n, on, frames, substeps, iterations, device) for on in (False, True))
        for row in (without, with_contact):
            row["x without"] = round(row["ms/frame"] / without["ms/frame"], 2)
            rows.append(row)
    return rows
