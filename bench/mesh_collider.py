"""A triangle-mesh collider's cost and how well it holds: a cloth dropped on a closed mesh (an icosphere), against
the same cloth dropped on an analytic sphere of the same radius (the cheapest collider) and with no collider.

    python -m bench.mesh_collider [--sizes 64 128] [--subdivisions 5 6] [--frames 60] [--substeps 8]
                                  [--iterations 8] [--device cpu] [--out bench/results]
    python -m bench.mesh_collider --device cuda --sizes 256 1024 --substeps 32
    python -m bench.mesh_collider --triangles 10000 100000 [...]   # lat-long spheres of exactly N triangles
    python -m bench.mesh_collider --peer [...]   # beside NVIDIA Newton, when installed (bench/newton_mesh_collider.py)

--out writes mesh_collider.md and mesh_collider.csv there; bench/results/mesh_collider.md keeps a reading of the
measured run above its table, to carry over when the run is repeated.

The cloth: n x n particles, a 1 m square of 0.3 kg, structural + shear + bend sticks (bend compliance 1 m/N),
laid horizontal 0.1 m above a sphere of radius 0.3 m at the origin, released at rest: it lands at about
1.4 m/s and drapes over it. The collider: a trimesh icosphere of radius 0.3 m (subdivision 5: 20,480 triangles;
6: 81,920), or, for each --triangles N, a lat-long sphere of radius 0.3 m with exactly N triangles (row "lat-long
mesh"; ``latlong_segments`` says which counts it can make; --triangles alone gives no icosphere rows unless
--subdivisions is given too), or a sphere collider of radius 0.3 m, or none; thickness half the cloth's spacing
(0.5 / (n - 1) m), Coulomb friction 0.5. 60 fps, --substeps substeps and --iterations sweeps, damping 0.5 /s. On
the CPU, one thread (``Simulator(..., threads=1)``).

Columns: ms/frame (the median frame's wall time over --frames frames, frame 1 excluded as the warm-up; the
median, since other work on a shared machine slows some frames); the same as a multiple of the run without a
collider; clamp ms/frame, the mesh clamp's own time per frame (its kernel, recorded as the solver records it,
replayed --substeps times on a copy of each frame's end state after timing the frame; the median frame, frame 1
excluded) and its share of ms/frame; and the deepest
penetration over the run, max(0, thickness - signed distance) in mm, taken at the end of every frame (after
timing it) against the collider the row has: for a mesh row, against its own triangles by the kernel's own
query (``wp.mesh_query_point_sign_normal``, negative inside); for the sphere row and the row without a
collider, against the analytic sphere (|x| - 0.3 m), so that the last shows how far the cloth falls through.

--peer adds NVIDIA Newton's rows for the same scene (bench/newton_mesh_collider.py, which lists what differs):
newton-vbd (SolverVBD) and newton-style3d (SolverStyle3D), each without a collider and on each mesh (the same
points and triangles, a static Newton mesh shape), measured by the same meter at the end of every frame, with a
"simulator" column and a "graph" column (whether a frame ran as one captured graph: warp-verlet captures on the
CPU too; Newton's rows capture on CUDA only); their "x none" is against their own run without a collider and
their clamp columns are "-" (Newton's contact runs inside its solver). Without Newton it prints "Newton not
installed: skipped" and the table has warp-verlet's rows alone.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
import warp as wp

from warp_verlet.core.simulator import Simulator
from warp_verlet.input.scene import parse_scene

from . import newton_mesh_collider
from .common import arg_parser, machine, quiet_warp, timed_frames, write_table

STEM = "mesh_collider"
SIZE, MASS, RADIUS, DROP = 1.0, 0.3, 0.3, 0.1  # m, kg, m, m above the sphere's top
FRICTION = 0.5


def icosphere(subdivisions: int):
    """(points (V, 3), triangles (T, 3)) of the icosphere of radius RADIUS, counter-clockwise from outside."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=RADIUS)
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32)


def latlong_segments(triangles: int) -> tuple[int, int]:
    """(segments round the axis u, stacks v) of the lat-long sphere with exactly ``triangles`` = 2 u (v - 1)
    triangles: of the divisor pairs u x (v - 1) of triangles / 2 with u >= 3 and v >= 3, the one whose cells are
    nearest square (u nearest 2 (v - 1), on a log scale; on a tie, more stacks). Raises ValueError naming the
    count when none has cells within 4:1 of square (an odd count, or one whose half has no divisor near its
    square root: a prime, say)."""
    half = triangles // 2
    pairs = [(half // k, k + 1) for k in range(2, half + 1) if half % k == 0 and half // k >= 3] \
        if triangles % 2 == 0 and triangles > 0 else []
    pairs = [(u, v) for u, v in pairs if abs(np.log(u / (2 * (v - 1)))) <= np.log(4.0)]
    if not pairs:
        raise ValueError(f"a lat-long sphere has 2 u (v - 1) triangles (u segments, v stacks); {triangles} is not "
                         f"such a count with cells within 4:1 of square (use an even count whose half factors "
                         f"into two near its square root, e.g. 10000 = 2 x 100 x 50 or 100000 = 2 x 250 x 200)")
    return min(pairs, key=lambda p: (abs(np.log(p[0] / (2 * (p[1] - 1)))), -p[1]))


def latlong_sphere(triangles: int):
    """(points (V, 3), triangles (T, 3)) of a closed lat-long sphere of radius RADIUS at the origin with exactly
    ``triangles`` triangles, counter-clockwise from outside: two poles on the Y axis, v - 1 rings of u points
    (every point on the sphere), a fan of u triangles round each pole and two triangles per quad between rings
    (segments and stacks from ``latlong_segments``)."""
    u, v = latlong_segments(triangles)
    polar = np.pi * np.arange(1, v) / v                      # the rings' angles from +Y
    azimuth = 2.0 * np.pi * np.arange(u) / u
    ring = np.stack([np.sin(polar)[:, None] * np.cos(azimuth), np.repeat(np.cos(polar)[:, None], u, axis=1),
                     np.sin(polar)[:, None] * np.sin(azimuth)], axis=-1).reshape(-1, 3)
    points = RADIUS * np.concatenate([[[0.0, 1.0, 0.0]], ring, [[0.0, -1.0, 0.0]]])
    top, bottom = 0, len(points) - 1
    j = np.arange(u)
    nxt = (j + 1) % u
    faces = [np.stack([np.full(u, top), 1 + nxt, 1 + j], axis=1)]
    for r in range(v - 2):
        a, b = 1 + r * u + j, 1 + r * u + nxt              # this ring's points, the next ring's below them
        c, d = a + u, b + u
        faces += [np.stack([a, b, d], axis=1), np.stack([a, d, c], axis=1)]
    last = 1 + (v - 2) * u
    faces.append(np.stack([np.full(u, bottom), last + j, last + nxt], axis=1))
    return points, np.concatenate(faces).astype(np.int32)


def collider_mesh(collider: str, size: int):
    """The mesh of a "mesh" row (the icosphere of ``size`` subdivisions) or a "latlong" row (``size``
    triangles)."""
    return icosphere(size) if collider == "mesh" else latlong_sphere(size)


def drop_scene(n: int, collider: str, subdivisions: int, folder: Path, frames: int, substeps: int,
               iterations: int):
    """The cloth over a sphere; ``collider`` is "mesh" (the icosphere of ``subdivisions``), "latlong" (the
    lat-long sphere of ``subdivisions`` triangles), each written to ``folder``, "sphere" or "none"."""
    thickness = 0.5 * SIZE / (n - 1)
    cloth = {"name": "sheet", "resolution": [n, n], "size": [SIZE, SIZE], "origin": [-0.5, RADIUS + DROP, -0.5],
             "orientation": "horizontal", "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 1.0},
             "mass": MASS}
    colliders = []
    if collider in ("mesh", "latlong"):
        path = folder / f"{'icosphere' if collider == 'mesh' else 'latlong'}{subdivisions}.obj"
        if not path.exists():
            points, triangles = collider_mesh(collider, subdivisions)
            trimesh.Trimesh(points, triangles, process=False).export(str(path))
        colliders = [{"type": "mesh", "name": "ball", "mesh": path.name, "thickness": thickness,
                      "friction_coefficient": FRICTION}]
    elif collider == "sphere":
        colliders = [{"type": "sphere", "name": "ball", "centre": [0.0, 0.0, 0.0], "radius": RADIUS,
                      "thickness": thickness, "friction_coefficient": FRICTION}]
    scene_file = folder / "scene.toml"
    scene = parse_scene({"simulation": {"fps": 60, "frames": frames, "substeps": substeps, "iterations": iterations,
                                        "damping": 0.5}, "cloth": [cloth], "collider": colliders},
                        file="<bench.mesh_collider>", scene_path=scene_file)
    return scene, thickness


@wp.kernel
def deepest_below(mesh: wp.uint64, x: wp.array(dtype=wp.vec3), thickness: float, out: wp.array(dtype=float)):
    """The largest thickness - signed distance to the mesh over the particles (atomic max: order-free)."""
    i = wp.tid()
    query = wp.mesh_query_point_sign_normal(mesh, x[i], 1.0e6)
    if query.result:
        distance = wp.length(x[i] - wp.mesh_eval_position(mesh, query.face, query.u, query.v))
        wp.atomic_max(out, 0, thickness - query.sign * distance)


class PointsPenetrationMeter:
    """The deepest penetration of given positions (any order), measured on ``device``: against ``mesh`` ((points,
    triangles), the row's collider) by the kernel's own query, else against the analytic sphere."""

    def __init__(self, thickness: float, mesh=None, device=None, particles: int = 0):
        self.thickness, self.device = thickness, wp.get_device(device)
        self.mesh = None
        if mesh is not None:
            points, triangles = mesh
            self.mesh = wp.Mesh(points=wp.array(points.astype(np.float32), dtype=wp.vec3, device=self.device),
                                indices=wp.array(triangles.ravel(), dtype=wp.int32, device=self.device))
            self.points = wp.empty(particles, dtype=wp.vec3, device=self.device)
            self.out = wp.empty(1, dtype=float, device=self.device)

    def penetration_of(self, q: np.ndarray) -> float:
        if self.mesh is None:
            below = self.thickness - (np.linalg.norm(np.asarray(q, dtype=np.float64), axis=1) - RADIUS)
            return max(0.0, float(below.max()))
        self.points.assign(np.asarray(q, dtype=np.float32))  # float32 or float64 positions alike
        self.out.fill_(0.0)
        wp.launch(deepest_below, len(self.points), inputs=[wp.uint64(self.mesh.id), self.points, self.thickness,
                                                           self.out], device=self.device)
        return float(self.out.numpy()[0])


class PenetrationMeter(PointsPenetrationMeter):
    """The deepest penetration at a frame end: against the row's mesh on the simulator's device, else against
    the analytic sphere."""

    def __init__(self, sim: Simulator, thickness: float, mesh=None):
        super().__init__(thickness, mesh, sim.device, sim.model.particle_count)
        self.sim = sim

    def penetration(self) -> float:
        return self.penetration_of(self.sim.positions())


class ClampTimer:
    """The mesh clamp's own time per frame: its kernel recorded as the solver binds it, but against scratch copies
    of the State's positions, so that timing it leaves the run alone. Each frame's end state is copied in (not
    timed) and the clamp replayed ``substeps`` times on it."""

    def __init__(self, sim: Simulator, substeps: int):
        from warp_verlet.kernels.collide_mesh import collide_meshes

        model, state, c = sim.model, sim.state, sim.model.colliders
        self.sim, self.substeps = sim, substeps
        self.pairs = [(wp.empty_like(a), a) for a in (state.particle_q, state.particle_q_inertial, state.particle_dq)]
        q, inertial, dq = (scratch for scratch, _ in self.pairs)
        no_pushes = wp.empty(0, dtype=wp.vec3, device=sim.device)  # no stage reads the clamp's pushes here
        self.launch = wp.launch(collide_meshes, model.particle_count,
                                inputs=[q, inertial, dq, model.inv_mass, c.mesh_ids, state.mesh_offsets, c.mesh_reach,
                                        c.mesh_thickness, c.mesh_friction, no_pushes, 0], device=sim.device,
                                record_cmd=True)

    def frame_ms(self) -> float:
        for scratch, source in self.pairs:
            wp.copy(scratch, source)
        wp.synchronize_device(self.sim.device)
        begin = time.perf_counter()
        for _ in range(self.substeps):
            self.launch.launch()
        wp.synchronize_device(self.sim.device)
        return 1e3 * (time.perf_counter() - begin)


def run(n: int, collider: str, subdivisions: int, folder: Path, frames: int, substeps: int, iterations: int,
        device: str) -> dict:
    scene, thickness = drop_scene(n, collider, subdivisions, folder, frames, substeps, iterations)
    start = time.perf_counter()
    sim = Simulator(scene, device, threads=1)
    build = time.perf_counter() - start
    mesh = collider_mesh(collider, subdivisions) if collider in ("mesh", "latlong") else None
    meter = PenetrationMeter(sim, thickness, mesh)
    clamp = ClampTimer(sim, substeps) if mesh is not None else None
    readings, clamp_times = [], []

    def measure() -> None:
        readings.append(meter.penetration())
        if clamp is not None:
            clamp_times.append(clamp.frame_ms())

    times = timed_frames(sim, frames, measure)
    worst = max([0.0, *readings])
    ms = 1e3 * statistics.median(times[1:])
    row = {"n": n, "particles": n * n, "collider": "lat-long mesh" if collider == "latlong" else collider,
           "triangles": len(mesh[1]) if mesh else "-",
           "ms/frame": round(ms, 3), "clamp ms/frame": "-", "clamp share": "-",
           "deepest mm": round(1e3 * worst, 3), "thickness mm": round(1e3 * thickness, 3),
           "build s": round(build, 2), "graph": sim.replays_frames}
    if clamp is not None:
        clamp_ms = statistics.median(clamp_times[1:])
        row["clamp ms/frame"] = round(clamp_ms, 3)
        row["clamp share"] = f"{100 * clamp_ms / ms:.0f}%"
    sim.close()
    return row


def main(argv: list[str] | None = None) -> int:
    parser = arg_parser("bench.mesh_collider", __doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128], help="particles along each side")
    parser.add_argument("--subdivisions", type=int, nargs="+", default=None,
                        help="icosphere subdivisions of the mesh colliders (5: 20,480 triangles, 6: 81,920); "
                             "default 5 6 unless --triangles is given")
    parser.add_argument("--triangles", type=int, nargs="+", default=[],
                        help="lat-long sphere mesh colliders of exactly these many triangles (e.g. 10000 100000)")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=8, help="sweeps per substep")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--out", type=Path, default=None, help="directory for mesh_collider.md and .csv")
    parser.add_argument("--peer", action="store_true",
                        help="also run NVIDIA Newton's VBD and Style3D solvers on the scene, when Newton is installed")
    args = parser.parse_args(argv)
    if args.subdivisions is None:
        args.subdivisions = [] if args.triangles else [5, 6]
    if any(n < 4 for n in args.sizes) or args.frames < 2 or any(s < 0 or s > 7 for s in args.subdivisions):
        parser.error("each size needs 4 particles a side or more, --frames at least 2, subdivisions 0 to 7")
    for count in args.triangles:
        try:
            latlong_segments(count)
        except ValueError as error:
            parser.error(f"--triangles {count}: {error}")
    quiet_warp()
    if args.peer and not newton_mesh_collider.available():
        print(newton_mesh_collider.SKIP_MESSAGE)
        args.peer = False
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for n in args.sizes:
            cases = [("none", 0), ("sphere", 0)] + [("mesh", s) for s in args.subdivisions] \
                + [("latlong", t) for t in args.triangles]
            size_rows = [run(n, kind, s, folder, args.frames, args.substeps, args.iterations, args.device)
                         for kind, s in cases]
            for row in size_rows:
                row["x none"] = round(row["ms/frame"] / size_rows[0]["ms/frame"], 2)
            rows += [{"simulator": "warp-verlet", **row} for row in size_rows]
            if args.peer:
                rows += newton_mesh_collider.peer_rows(n, cases, args.frames, args.substeps, args.iterations,
                                                       args.device)
    where = machine(args.device)
    command = ["bench.mesh_collider", *(sys.argv[1:] if argv is None else argv)]
    on = "one CPU thread" if wp.get_device(args.device).is_cpu else str(where)
    title = (f"Mesh collider: a 1 m cloth dropped on a sphere of radius {RADIUS} m (an icosphere mesh, a lat-long "
             f"mesh, an analytic "
             f"sphere, or none), {args.frames} frames at 60 fps, {args.substeps} substeps, {args.iterations} sweeps, "
             f"{on}\n\n" + "\n".join(where.lines(command)))
    columns = ["n", "particles", "collider", "triangles", "ms/frame", "x none", "clamp ms/frame", "clamp share",
               "deepest mm", "thickness mm", "build s"]
    if args.peer:
        columns = ["simulator", *columns, "graph"]
    write_table([{k: row[k] for k in columns} for row in rows], args.out, STEM, title, columns)
    return 0


if __name__ == "__main__":
    sys.exit(main())
