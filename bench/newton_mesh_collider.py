"""Optional peer for bench.mesh_collider: the same cloth dropped on the same triangle-mesh sphere, through NVIDIA
Newton's VBD solver (``newton.solvers.SolverVBD``) and Style3D solver (``newton.solvers.SolverStyle3D``), the
mesh a static Newton mesh shape, measured with bench.mesh_collider's own penetration meter.

    python -m bench.mesh_collider --peer [--sizes 16 32] [--triangles 10000] [--frames 20] [--device cpu]

Written against Newton 1.8.0 (the newton-1.8.0-py3-none-any.whl wheel; it needs warp-lang and numpy only).

Newton (github.com/newton-physics/newton, ``pip install newton``) is not a dependency of this project: this
module imports Newton only inside the functions that need it, and ``peer_rows`` prints "Newton not installed:
skipped" and returns no rows when ``import newton`` fails.

The same as warp-verlet's run: n x n particles of a 1 m square, 0.3 kg spread evenly (0.3 / n^2 kg each), laid
horizontal at y = 0.4 m, 0.1 m above the sphere's top (row r along +Z, column c along +X, origin (-0.5, 0.4,
-0.5)), released at rest; gravity (0, -9.81, 0); no ground (bench.mesh_collider has none); 60 fps, the same
substeps and iterations per substep (VBD: block-descent iterations; Style3D: non-linear iterations, each of 10
PCG iterations). The collider: the very points and triangles bench.mesh_collider gives warp-verlet and its meter
(``collider_mesh``: the icosphere of the row's subdivisions, or the lat-long sphere of exactly the row's
triangles, radius 0.3 m at the origin), as ``newton.Mesh(points, triangles)`` added with
``ModelBuilder.add_shape_mesh(body=-1, ...)``: a static shape on no body, its transform the identity, its
``margin`` 0. Newton builds the grid with ``ModelBuilder.add_cloth_grid`` (VBD) or
``newton.solvers.style3d.add_cloth_grid`` (Style3D), rotated a quarter turn about +X so that its particle j * n + i
lands on warp-verlet's particle r * n + c with r = j, c = i; the order is found by matching rest positions to grid
cells (bench.newton_self_contact's ``grid_order``), not assumed, and ``NewtonFrames.positions`` puts Newton's
positions in warp-verlet's order.

The contact distance (``contact_distances``): warp-verlet keeps each particle at least the thickness, half the
spacing, 0.5 / (n - 1) m, outside the mesh. Newton pushes a particle whose distance to the shape (along the
contact normal) is less than its ``particle_radius`` + the shape's ``margin``: the radius is the thickness, the
margin 0, so both push from the same distance. Newton's ``CollisionPipeline(soft_contact_gap=...)`` is
detection-only slack: a particle is given a contact when its signed distance to the mesh (the mesh's BVH query,
parity sign for this closed mesh) is under radius + gap, and only then pushed, so the gap must cover how far a
particle moves between detections. It is the thickness plus the landing speed's move in one substep,
sqrt(2 g 0.1 m) / (60 x substeps) (1.4 m/s: 2.9 mm at 8 substeps, 0.73 mm at 32).

Measured: the deepest penetration is bench.mesh_collider's ``PointsPenetrationMeter`` (the same
``deepest_below`` kernel and ``wp.mesh_query_point_sign_normal`` query against the same triangles, max(0,
thickness - signed distance); for the row without a collider, the analytic sphere) on Newton's positions in
warp-verlet's order, at the end of every frame, outside the timing; ms/frame is the median frame's synchronised
wall time, frame 1 excluded. Each solver has a row without a collider (its "x none" is against it) and one per
mesh; there is no analytic-sphere row (Newton's sphere shape is another collider, not asked for here).

What differs (Newton's model is not warp-verlet's):

* Cloth model. Newton solves a triangle membrane with dihedral bending, not distance sticks: VBD an StVK
  membrane ``tri_ke = tri_ka = 1e4`` with bending ``edge_ke = 1e-3`` and no element damping; Style3D its
  projective-dynamics springs ``tri_aniso_ke = (1e4, 1e4, 1e3)``, bending ``edge_aniso_ke = (2e-6, 1e-6,
  5e-6)`` (bench.newton_self_contact's cloths). warp-verlet's sticks are rigid (its bend sticks soft, 1 m/N).
  Style3D's grid helper lumps triangle areas into masses; they are replaced by the even 0.3 / n^2 kg.
* Damping. warp-verlet damps velocity at 0.5 /s; VBD has no global velocity damping (none is set); Style3D
  scales velocities by 0.998 each substep (built in, not adjustable: about 0.96 /s at 8 substeps, 3.8 /s at 32).
* Contact law. warp-verlet projects each particle found inside the thickness out to it along the face normal (or
  the direction to the closest point off a face), a hard constraint, at every substep, from the particle's
  current position. Newton pushes by a penalty: a particle record per contact, holding the closest point and the
  normal found at detection, and a force k (radius - d) along that normal while d, the distance to that point's
  tangent plane, is under the radius, with damping k_d on the approach (its Hessian in the solve: VBD's
  per-vertex block, Style3D's PD system and PCG). VBD's k is the mean of ``soft_contact_ke`` (1e3 N/m) and the
  mesh shape's ``ke`` (1e5 N/m), 5.05e4 N/m; its k_d the mean of ``soft_contact_kd`` and the shape's ``kd``
  (1e-2 each). Style3D's body contact takes ``soft_contact_ke`` (1e3 N/m) and ``soft_contact_kd`` (1e-2)
  alone. These are bench.newton_self_contact's ground values (its ground shape is ke 1e5). A penalty gives
  way under load: the deepest-mm column counts the particles pressed inside the thickness.
* Friction. Coulomb 0.5 in both. Newton's coefficient is the geometric mean of ``soft_contact_mu`` and the
  shape's ``mu``, 0.5 each; it is a force in the solve, regularised below a slip speed of 1e-2 m/s
  (``friction_epsilon``, both solvers' default), where it acts as a stiff viscous force rather than sticking.
  warp-verlet's friction is Coulomb's at the position level, applied with the clamp: a particle pushed out by
  d sticks while its tangential move in the substep is under 0.5 d, else that move is shortened by 0.5 d.
* Collision detection. warp-verlet queries the mesh's BVH for every particle at every substep (its clamp). VBD's
  solver owns its ``newton.CollisionPipeline`` and detects once per step, before initialisation (its default
  for the rigid slot, ``PRE_INIT``), i.e. once per substep. For Style3D this module runs the same pipeline before
  every substep too, not once a frame as Newton's example_cloth_style3d does, so that both peers detect as
  often as warp-verlet queries (a frame's 23 mm of fall at 1.4 m/s is more than any gap here). Both use the
  pipeline's soft (particle-shape) contacts only: one record per particle within reach, no edge or face
  records (``enable_rigid_soft_full_surface_contact`` off, its default), so a mesh corner can poke between
  particles, as it can in warp-verlet.
* Self-contact. warp-verlet's run has none; VBD's particle self-contact is off (its default) and Style3D's
  collision handler is kept for its body contacts with its self-contact stiffnesses set to 0 (its triangle
  and edge BVHs are still refitted every substep, a cost warp-verlet's run does not have). Without a collider
  Style3D's handler is removed (``solver.collision = None``), as bench.newton_style3d does.
* Graphs. On CUDA, Newton's frame of substeps is captured once as a graph and replayed (as Newton's examples
  do), when the capture succeeds (it needs an even number of substeps; a failed capture falls back to stepping
  directly); on the CPU Newton's frames are stepped directly. warp-verlet replays its captured frame on the CPU
  too. The "graph" column says, row by row, which ran.
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np

from .common import timed_frames
from .newton_self_contact import (CONTACT_KD, CONTACT_KE, STYLE3D_EDGE_ANISO_KE, STYLE3D_TRI_ANISO_KE, VBD_EDGE_KE,
                                  VBD_TRI_KE, available, grid_order)
from .newton_style3d import NewtonFrames

SKIP_MESSAGE = "Newton not installed: skipped"
SOLVERS = ("vbd", "style3d")
LABELS = {"vbd": "newton-vbd", "style3d": "newton-style3d"}

GRAVITY = (0.0, -9.81, 0.0)
FPS = 60.0
SHAPE_KE = 1.0e5                # N/m, the mesh shape's stiffness (VBD's contact: the mean of it and CONTACT_KE)


def contact_distances(n: int, substeps: int) -> tuple[float, float, float]:
    """(warp-verlet's thickness, Newton's ``particle_radius``, Newton's ``soft_contact_gap``) in m for an n x n
    cloth at ``substeps`` substeps a frame: the radius is the thickness 0.5 / (n - 1) m (Newton pushes inside
    radius + the shape's margin 0); the gap, detection-only, is the thickness plus the landing speed's move in a
    substep, sqrt(2 g 0.1 m) / (60 substeps)."""
    from . import mesh_collider as bench

    thickness = 0.5 * bench.SIZE / (n - 1)
    landing = math.sqrt(2.0 * -GRAVITY[1] * bench.DROP)
    return thickness, thickness, thickness + landing / (FPS * substeps)


def peer_cases(cases: list[tuple[str, int]]) -> list[tuple[str, int]]:
    """Newton's rows of bench.mesh_collider's ``cases`` ((collider, subdivisions or triangles) pairs): the run
    without a collider first, then each mesh ("mesh" or "latlong") in order; no analytic sphere."""
    return [("none", 0)] + [(kind, size) for kind, size in cases if kind in ("mesh", "latlong")]


class NewtonDroppedCloth(NewtonFrames):
    """bench.mesh_collider's cloth over a static mesh shape in Newton (or with no collider when ``mesh`` is None);
    ``step_frame`` advances one 1/60 s frame."""

    def __init__(self, solver: str, n: int, mesh, substeps: int, iterations: int, device=None):
        """``mesh``: (points (V, 3), triangles (T, 3)), bench.mesh_collider's ``collider_mesh``, or None."""
        import warp as wp

        import newton

        from . import mesh_collider as bench

        if solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        self.substeps, self.dt = substeps, 1.0 / (FPS * substeps)
        spacing = bench.SIZE / (n - 1)
        _, radius, gap = contact_distances(n, substeps)
        origin = (-0.5 * bench.SIZE, bench.RADIUS + bench.DROP, -0.5 * bench.SIZE)
        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=GRAVITY)
        grid = {"pos": wp.vec3(*origin), "rot": wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), 0.5 * math.pi),
                "vel": wp.vec3(0.0, 0.0, 0.0), "dim_x": n - 1, "dim_y": n - 1, "cell_x": spacing,
                "cell_y": spacing, "mass": bench.MASS / (n * n), "particle_radius": radius}
        if solver == "style3d":
            from newton.solvers import style3d

            newton.solvers.SolverStyle3D.register_custom_attributes(builder)
            style3d.add_cloth_grid(builder, **grid, tri_aniso_ke=wp.vec3(*STYLE3D_TRI_ANISO_KE),
                                   edge_aniso_ke=wp.vec3(*STYLE3D_EDGE_ANISO_KE))
            builder.particle_mass[:] = [bench.MASS / (n * n)] * (n * n)  # not its area-lumped masses
        else:
            builder.add_cloth_grid(**grid, tri_ke=VBD_TRI_KE, tri_ka=VBD_TRI_KE, tri_kd=0.0, edge_ke=VBD_EDGE_KE,
                                   edge_kd=0.0)
            builder.color(include_bending=True)
        if mesh is not None:
            points, triangles = mesh
            shape = newton.ModelBuilder.ShapeConfig(ke=SHAPE_KE, kd=CONTACT_KD, mu=bench.FRICTION, margin=0.0)
            builder.add_shape_mesh(body=-1, mesh=newton.Mesh(np.asarray(points, dtype=np.float32),
                                                             np.asarray(triangles, dtype=np.int32).ravel(),
                                                             compute_inertia=False),
                                   cfg=shape)
        self.order = grid_order(np.asarray(builder.particle_q), n, origin, spacing)

        self.model = builder.finalize(device=device)
        self.model.soft_contact_ke, self.model.soft_contact_kd = CONTACT_KE, CONTACT_KD
        self.model.soft_contact_mu = bench.FRICTION
        self.device = self.model.device
        self.state_0, self.state_1 = self.model.state(), self.model.state()
        self.control = self.model.control()
        self.pipeline = self.contacts = None
        if mesh is not None:
            self.pipeline = newton.CollisionPipeline(self.model, broad_phase="nxn", soft_contact_gap=gap)
        if solver == "vbd":
            # The solver owns the pipeline and detects inside step(), before each step's initialisation.
            self.solver = newton.solvers.SolverVBD(self.model, iterations=iterations,
                                                   collision_pipeline=self.pipeline)
        else:
            if self.pipeline is not None:
                self.contacts = self.pipeline.contacts()
            self.solver = newton.solvers.SolverStyle3D(
                self.model, config=newton.solvers.SolverStyle3D.Config(iterations=iterations))
            if mesh is None:
                self.solver.collision = None  # no contacts at all
            else:  # keep its body contact, drop its self-contact
                collision = self.solver.collision
                collision.stiff_vf = collision.stiff_ee = collision.stiff_ef = 0.0
        self.solver_name, self.graph = solver, None

    def simulate(self) -> None:
        for _ in range(self.substeps):
            if self.contacts is not None:  # Style3D: detect before every substep (VBD does inside step)
                self.pipeline.collide(self.state_0, self.contacts)
            self.state_0.clear_forces()
            self.solver.step(self.state_0, self.state_1, self.control, self.contacts, self.dt)
            self.state_0, self.state_1 = self.state_1, self.state_0


def run(solver: str, n: int, collider: str, size: int, frames: int, substeps: int, iterations: int,
        device) -> dict:
    """One row of bench.mesh_collider's table for Newton's ``solver``: ``collider`` "none", "mesh" (the icosphere
    of ``size`` subdivisions) or "latlong" (the lat-long sphere of ``size`` triangles)."""
    import warp as wp

    from . import mesh_collider as bench

    if collider not in ("none", "mesh", "latlong"):
        raise ValueError(f"Newton's rows have no {collider!r} collider")
    mesh = bench.collider_mesh(collider, size) if collider != "none" else None
    thickness, _, _ = contact_distances(n, substeps)
    device = wp.get_device(device)
    wp.synchronize_device(device)
    began = time.perf_counter()
    cloth = NewtonDroppedCloth(solver, n, mesh, substeps, iterations, device)
    captured = cloth.capture_frame()
    wp.synchronize_device(device)
    build = time.perf_counter() - began
    meter = bench.PointsPenetrationMeter(thickness, mesh, device, n * n)
    readings = []
    times = timed_frames(cloth, frames, lambda: readings.append(meter.penetration_of(cloth.positions())))
    return {"simulator": LABELS[solver], "n": n, "particles": n * n,
            "collider": "lat-long mesh" if collider == "latlong" else collider,
            "triangles": len(mesh[1]) if mesh is not None else "-",
            "ms/frame": round(1e3 * statistics.median(times[1:]), 3), "clamp ms/frame": "-", "clamp share": "-",
            "deepest mm": round(1e3 * max([0.0, *readings]), 3), "thickness mm": round(1e3 * thickness, 3),
            "build s": round(build, 2), "graph": captured}


def peer_rows(n: int, cases: list[tuple[str, int]], frames: int, substeps: int, iterations: int, device,
              solvers=SOLVERS, report=print) -> list[dict]:
    """Newton's rows for one size: each solver without a collider and on each mesh of ``cases`` (bench.mesh_collider's
    (collider, size) pairs; ``peer_cases``), "x none" against its own run without; none (and
    ``report(SKIP_MESSAGE)``) without Newton."""
    if not available():
        report(SKIP_MESSAGE)
        return []
    rows = []
    for solver in solvers:
        solver_rows = [run(solver, n, kind, size, frames, substeps, iterations, device)
                       for kind, size in peer_cases(cases)]
        for row in solver_rows:
            row["x none"] = round(row["ms/frame"] / solver_rows[0]["ms/frame"], 2)
        rows += solver_rows
    return rows
