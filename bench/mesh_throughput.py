"""Throughput of mesh cloth beside the grid of the same size, in the same run, with the error each figure bought.

    python -m bench.mesh_throughput --device cpu --sizes 32 64 128 --threads 1 --out bench/results/mesh --stem cpu-epyc
    python -m bench.mesh_throughput --device cuda --sizes 128 512 1024 --out bench/results/mesh --stem h100

For each size n, three variants of the benchmark hanging cloth (bench.common.hanging_cloth: n x n particles,
1 m, 0.2 kg, the same pins, structural + shear + bend sticks, no tethers, its damping, 60 fps):

- grid: the grid cloth itself (the analytic 12-colour colouring);
- quad mesh: the grid's points (float32, bit for bit) and quads written to a temporary .usdc and loaded as a
  mesh cloth (prim /Set/Cloth), mass_distribution "even": the grid's particles, sticks and masses, so the
  same physics; only the colouring (Warp's graph colouring) and the stick order differ;
- triangle mesh: the same quads split along their (r, c)-(r+1, c+1) diagonal, written to a temporary OBJ
  (or, with --triangles ply, a binary PLY) and read by trimesh. Its sticks are not the grid's: the diagonal
  is a face side, so structural; triangles have no shear sticks; a bend stick joins the two corners
  opposite each interior edge (across a diagonal, that is the other diagonal). Its stretch is therefore
  not the same measure as the grid's: it includes the diagonals, and the cloth is stiffer in shear.

Particle order (--orders): "reordered" holds a mesh cloth's particles on the device in Morton order of their rest
positions (Simulator's particle_order "morton": warp_verlet/geometry/particle_order.py); "input" holds them as
the file numbers them (the default, "auto", picks Morton order only where it brings the sticks' ends much closer
in memory). --orders input reordered gives each mesh variant a row per order in the same
run; "reorder s" is the time the Model spends renumbering the cloth (its Morton order and the renumbered
topology, timed apart from the Simulator). A grid's particles stay in row-major order either way. The mesh files
list the grid's points in row-major order, already an order with locality; --shuffle writes them in a random
order (seeded), as a mesh whose vertex numbering follows no path across the surface.

--setup-only times the host-side setup of the reordering at each size instead of simulating: the quad mesh's
topology built, its Morton order, the renumbered topology, the sticks sorted by colour then first and second
particle (beside the stable sort by colour alone it replaces), and Warp's graph colouring of the sticks
(--no-colouring leaves it out: minutes at 1024^2).

Pins: hanging_cloth's (its two top corners) by default, each given to a mesh as a box around the pinned
point (a quarter of the spacing on each side); --pins top-edge pins the whole top row instead, one box
around it, and the grid by "top-edge".

Each variant simulates 60 frames (1 s) at --substeps x --iterations (4 x 8, as bench.throughput): frames
1-2 are a warm-up (compilation, graph capture), frames 3-60 are timed in --repeats equal batches, the
median batch gives ms per frame and the spread is half the range. Stick projections per second are sticks
x substeps x iterations over that time. Stretch |D - L|/L (RMS and max, a ratio: 1.0 is 100%) is over the
structural sticks at frame 60. "load s" is parse_scene's time (for a mesh: reading, welding and checking it; writing the file
beforehand is not counted); "build s" is the Simulator's construction (topology, colouring, device arrays).

Setup at 1024^2 (1M particles), measured on a shared 2-core AMD EPYC: the quad .usdc writes in 0.5 s and
loads (parse_scene: read, weld, check) in 6 s; the triangle OBJ takes 7 s to write and 18 s to load, 11 s
of it trimesh's OBJ reader (--triangles ply, a binary PLY: 0.2 s to write, 2 s to read). The larger cost
is the Simulator's construction for a mesh: Warp's graph colouring needs the stick-conflict graph
(warp_verlet.geometry.colouring.stick_conflict_edges), which took about 3.5 minutes per mesh variant at 1024^2
(1 s at 128^2, 27 s at 512^2; a grid, coloured analytically, builds in 12 s at 1024^2); --setup-only times it
again (bench/results/mesh/setup-cpu-epyc.md: 28 s at 1024^2 since). On a machine
with a 10-minute limit per command, run 1024 on its own. The files live in a temporary directory
removed at the end.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.geometry.faces import Faces, grid_faces
from warp_verlet.input.scene import Scene, parse_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.geometry.topology import grid_positions

from .common import (HANGING_DAMPING, add_compliance_arg, arg_parser, compliance_of, hanging_cloth, hanging_sheet,
                     machine, median_spread, quiet_warp, scene, time_frames, write_table)

FRAMES, WARM_UP = 60, 2
PRIM = "/Set/Cloth"
VARIANTS = ("grid", "quad mesh", "triangle mesh")
ORDERS = ("input", "reordered")  # --orders: Simulator's particle_order "input" and "morton"
ORDER_NAMES = {"input": "input", "reordered": "Morton"}  # the table's "particle order" column
SHUFFLE_SEED = 7


# ---------------------------------------------------------------- mesh files

def write_usd(path: Path, points: np.ndarray, faces: Faces) -> Path:
    """One Mesh at PRIM under an Xform, metres, Y up, the points as float32 as given."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, Sdf.Path(PRIM).GetParentPath())
    mesh = UsdGeom.Mesh.Define(stage, PRIM)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces.counts, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces.indices, np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    stage.Save()
    return path


def write_obj(path: Path, points: np.ndarray, triangles: np.ndarray) -> Path:
    """Vertices with 9 significant digits (float32 points read back bit for bit), 1-based faces."""
    with open(path, "w") as f:
        np.savetxt(f, np.asarray(points, np.float64), fmt="v %.9g %.9g %.9g")
        np.savetxt(f, np.asarray(triangles, np.int64) + 1, fmt="f %d %d %d")
    return path


def write_ply(path: Path, points: np.ndarray, triangles: np.ndarray) -> Path:
    """Binary little-endian PLY: float32 vertices, faces as (uchar 3, int32 x 3)."""
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\nproperty float x\n"
              f"property float y\nproperty float z\nelement face {len(triangles)}\n"
              "property list uchar int vertex_indices\nend_header\n")
    face = np.empty(len(triangles), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"], face["v"] = 3, triangles
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(np.ascontiguousarray(points, "<f4").tobytes())
        f.write(face.tobytes())
    return path


def triangulate(quads: Faces) -> np.ndarray:
    """(2F, 3): each quad (a, b, c, d) split along its a-c diagonal."""
    q = quads.as_uniform()
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


# ---------------------------------------------------------------- scenes

def simulation_table(substeps: int, iterations: int, frames: int = FRAMES) -> dict:
    """bench.common.hanging_cloth's [simulation] table (grid_and_meshes checks that the scenes agree)."""
    return {"frames": frames, "substeps": substeps, "iterations": iterations, "damping": HANGING_DAMPING,
            "relaxation": "coloured"}


def pin_boxes(grid: Scene) -> list[dict]:
    """The grid cloth's pins as mesh pins: one box around the top row when the whole row is pinned, else
    one box around each pinned point, a quarter of the spacing on each side."""
    spec = grid.cloths[0]
    rows, cols = spec.resolution
    points = grid_positions(spec).astype(np.float64).reshape(rows, cols, 3)
    margin = 0.25 * min(spec.size[0] / (rows - 1), spec.size[1] / (cols - 1))
    pins = sorted(spec.pins)
    if pins == [(0, c) for c in range(cols)]:
        groups = [points[0]]
    else:
        groups = [points[r, c][None] for r, c in pins]
    return [{"min": (g.min(axis=0) - margin).tolist(), "max": (g.max(axis=0) + margin).tolist()} for g in groups]


def shuffled(points: np.ndarray, faces: Faces, seed: int = SHUFFLE_SEED) -> tuple[np.ndarray, Faces]:
    """The same mesh with its vertices listed in a random order: the points permuted, the faces renumbered."""
    order = np.random.default_rng(seed).permutation(len(points))
    place = np.empty(len(points), np.int64)
    place[order] = np.arange(len(points))
    return points[order], Faces(faces.counts, place[faces.indices])


def grid_and_meshes(n: int, substeps: int, iterations: int, pins: str, triangles: str, folder: Path,
                    shuffle: bool = False, compliance: dict | None = None):
    """The three variants' scenes, each with the seconds its parse_scene took (mesh files written into
    ``folder`` first, not counted). ``shuffle``: the mesh files list their vertices in a random order.
    ``compliance``: every variant's stick families given these compliances (m/N; none: all rigid)."""
    import trimesh  # noqa: F401  (imported now, so that "load s" times the reading and not the import)

    simulation = simulation_table(substeps, iterations)
    start = time.perf_counter()
    soft = {"compliance": compliance} if compliance else {}
    if pins == "corners" and not soft:
        sheet, grid = hanging_sheet(n), hanging_cloth(n, substeps, iterations)  # the benchmark scene itself
    else:
        sheet = hanging_sheet(n, **soft) if pins == "corners" else hanging_sheet(n, pins=["top-edge"], **soft)
        grid = scene(simulation, sheet, name=f"<hanging cloth {n}x{n}, {pins}{', soft' if soft else ''}>")
    out = {"grid": (grid, time.perf_counter() - start)}

    spec = grid.cloths[0]
    points, quads = grid_positions(spec), grid_faces(*spec.resolution)
    triangle_faces = Faces.uniform(triangulate(quads))
    if shuffle:
        points_q, quads = shuffled(points, quads)
        points_t, triangle_faces = shuffled(points, triangle_faces, SHUFFLE_SEED + 1)
    else:
        points_q = points_t = points
    files = {"quad mesh": write_usd(folder / f"grid{n}.usdc", points_q, quads)}
    writer = write_ply if triangles == "ply" else write_obj
    files["triangle mesh"] = writer(folder / f"grid{n}.{triangles}", points_t, triangle_faces.as_uniform())
    keep = {k: sheet[k] for k in ("name", "mass", "sticks", "tethers", "compliance") if k in sheet}
    for variant, path in files.items():
        cloth = {**keep, "mesh": path.name, "pins": pin_boxes(grid), "mass_distribution": "even"}
        if path.suffix == ".usdc":
            cloth["prim"] = PRIM
        doc = {"simulation": {"fps": 60, **simulation}, "output": {"path": str(folder / "out.usdc")},
               "cloth": [cloth]}
        start = time.perf_counter()
        mesh = parse_scene(doc, f"<{variant} {n}x{n}>", folder / "scene.toml")
        out[variant] = (mesh, time.perf_counter() - start)
        if mesh.simulation != grid.simulation:
            raise RuntimeError(f"{variant}: simulation settings differ from the grid's")
        if len(mesh.cloths[0].mesh.pins) != len(set(spec.pins)):
            raise RuntimeError(f"{variant}: {len(mesh.cloths[0].mesh.pins)} pins, the grid has {len(set(spec.pins))}")
    return out


# ---------------------------------------------------------------- measuring

def reorder_seconds(the_scene: Scene) -> float:
    """The host time the Model spends renumbering the scene's mesh cloths: each one's Morton order and its
    renumbered topology (build_cloth itself, which either order needs, not counted)."""
    from warp_verlet.geometry.particle_order import locality_order, reorder_topology
    from warp_verlet.geometry.topology import build_cloth

    total = 0.0
    for spec in the_scene.cloths:
        topology = build_cloth(spec)
        if topology.is_grid:
            continue
        start = time.perf_counter()
        reorder_topology(topology, locality_order(topology.positions))
        total += time.perf_counter() - start
    return total


def measure(variant: str, n: int, the_scene: Scene, load_s: float, device: str, repeats: int, use_graph: bool,
            threads: int | None, frames: int = FRAMES, order: str = "reordered", sticks: str = "auto",
            label: str | None = None) -> dict:
    mesh = variant != "grid"
    start = time.perf_counter()
    sim = Simulator(the_scene, device, use_graph=use_graph, threads=threads, sticks=sticks,
                    particle_order="morton" if order == "reordered" else "input")
    build_s = time.perf_counter() - start
    try:
        sim.step_frame()  # warm-up: compiles kernels, initialises the Verlet state
        sim.step_frame()  # on CUDA: captures the frame graph
        batch = (frames - WARM_UP) // repeats
        per_frame, spread = median_spread(time_frames(sim, batch, repeats))
        for _ in range(frames - WARM_UP - batch * repeats):
            sim.step_frame()  # so that the error is always read at the last frame
        s = sim.settings
        projections = sim.model.stick_count * s.substeps * s.iterations
        stretch = sim.stretch()
        colouring = sim.model.colouring
        return {
            "size": f"{n}x{n}",
            "variant": label or variant,
            "sticks form": sim.model.sticks_form,
            "particle order": ORDER_NAMES[order] if mesh else "row-major",
            "particles": sim.model.particle_count,
            "sticks": sim.model.stick_count,
            "colours": sim.model.colour_count,
            "balance": f"{colouring.balance:.2f}" if colouring is not None else "",
            "threads": sim.threads,
            "load s": f"{load_s:.2f}",
            "build s": f"{build_s:.2f}",
            "reorder s": f"{reorder_seconds(the_scene):.3f}" if mesh and order == "reordered" else "",
            "ms/frame": f"{per_frame * 1e3:.3f}",
            "spread": f"±{spread * 100:.1f}%",
            "Mproj/s": f"{projections / per_frame / 1e6:.1f}",
            "stretch rms": f"{stretch.rms:.2e}",
            "stretch max": f"{stretch.max:.2e}",
            "frames timed": batch * repeats,
        }
    finally:
        sim.close()


def notes(rows: list[dict]) -> str:
    """Per size: each mesh row's speed against the grid's (naming its particle order where the run had both)."""
    out = []
    both = len({r["particle order"] for r in rows if r["variant"] != "grid"}) > 1
    for size in dict.fromkeys(r["size"] for r in rows):
        mine = [r for r in rows if r["size"] == size]
        grid = float(next(r for r in mine if r["variant"] == "grid")["ms/frame"])
        parts = [f"{r['variant']}{' (' + r['particle order'] + ' order)' if both else ''} "
                 f"{float(r['ms/frame']) / grid:.2f}x the grid's time" for r in mine if r["variant"] != "grid"]
        out.append(f"- {size}: " + ", ".join(parts))
    return "\n".join(out)


def setup_costs(n: int, folder: Path, colouring: bool) -> dict:
    """Seconds of the host-side setup at n x n for the quad mesh: its topology (build_cloth), its Morton order,
    the renumbered topology, the sticks sorted by colour then first and second particle and, for comparison, by
    colour alone (a stable sort), and Warp's graph colouring (``colouring``)."""
    from warp_verlet.geometry.colouring import graph_colouring, stick_order
    from warp_verlet.geometry.particle_order import locality_order, reorder_topology
    from warp_verlet.geometry.topology import build_cloth

    the_scene, load_s = grid_and_meshes(n, 4, 8, "corners", "ply", folder)["quad mesh"]
    clock = time.perf_counter
    start = clock()
    topology = build_cloth(the_scene.cloths[0])
    built = clock()
    order = locality_order(topology.positions)
    ordered = clock()
    reordered = reorder_topology(topology, order)
    renumbered = clock()
    row = {"size": f"{n}x{n}", "particles": topology.particle_count, "sticks": len(topology.sticks),
           "load s": f"{load_s:.2f}", "build_cloth s": f"{built - start:.2f}", "Morton order s": f"{ordered - built:.3f}",
           "renumber s": f"{renumbered - ordered:.3f}", "reorder s": f"{renumbered - built:.3f}"}
    # A colouring to sort by; its sizes do not matter to the sort's time, so without Warp's one takes 12 colours.
    sticks = reordered.sticks
    if colouring:
        start = clock()
        colour = graph_colouring(sticks).colour
        row["graph colouring s"] = f"{clock() - start:.1f}"
    else:
        colour = (np.arange(len(sticks)) % 12).astype(np.int32)
        row["graph colouring s"] = ""
    start = clock()
    stick_order(colour, sticks)
    sorted_by_particles = clock()
    np.argsort(colour, kind="stable")
    row["stick sort s"] = f"{sorted_by_particles - start:.3f}"
    row["colour sort s"] = f"{clock() - sorted_by_particles:.3f}"
    return row


def main(argv=None) -> int:
    p = arg_parser("bench.mesh_throughput", __doc__)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--frames", type=int, default=FRAMES, help=f"frames per variant (default {FRAMES}: 1 s)")
    p.add_argument("--substeps", type=int, default=4)
    p.add_argument("--iterations", type=int, default=8)
    p.add_argument("--no-graph", action="store_true", help="launch kernels one by one, no graph/capture replay")
    p.add_argument("--threads", type=int, default=None, help="CPU relaxation threads (default: automatic)")
    p.add_argument("--pins", choices=("corners", "top-edge"), default="corners",
                   help="hanging_cloth's two top corners (default), or the whole top row")
    p.add_argument("--triangles", choices=("obj", "ply"), default="obj",
                   help="file format of the triangle mesh (default obj; ply loads ~5x faster at 1024^2)")
    p.add_argument("--orders", choices=ORDERS, nargs="+", default=["reordered"],
                   help="the mesh cloths' particle order on the device: reordered (Morton, the default) and/or input; "
                        "each order given is one row per mesh variant")
    p.add_argument("--sticks", choices=("auto", "explicit", "clustered"), nargs="+", default=["auto"],
                   help="the mesh variants' stick forms (Simulator's sticks; the grid always takes auto): with "
                        "several, a row per form")
    p.add_argument("--shuffle", action="store_true", help="the mesh files list their vertices in a random order")
    add_compliance_arg(p)
    p.add_argument("--setup-only", action="store_true",
                   help="time the reordering's host-side setup at each size instead of simulating")
    p.add_argument("--no-colouring", action="store_true", help="with --setup-only: leave Warp's graph colouring out")
    p.add_argument("--out", type=Path, default=None, help="write STEM.md and STEM.csv here")
    p.add_argument("--stem", default="mesh_throughput", help="output names (default mesh_throughput)")
    args = p.parse_args(argv)
    if min(args.sizes) < 2:
        p.error("--sizes: a mesh needs at least 2 x 2 particles")
    if args.frames - WARM_UP < args.repeats:
        p.error(f"--frames: {WARM_UP} warm-up frames and at least one per repeat")
    compliance = compliance_of(p, args.compliance)
    quiet_warp()
    device = wp.get_device(args.device)
    command = ["bench.mesh_throughput", *(argv if argv is not None else sys.argv[1:])]
    if args.setup_only:
        return setup_only(args, device, command)
    rows = []
    orders = list(dict.fromkeys(args.orders))
    for n in args.sizes:
        with tempfile.TemporaryDirectory(prefix="mesh_throughput-") as tmp:
            scenes = grid_and_meshes(n, args.substeps, args.iterations, args.pins, args.triangles, Path(tmp),
                                     args.shuffle, compliance)
            for variant in VARIANTS:
                the_scene, load_s = scenes[variant]
                forms = list(dict.fromkeys(args.sticks)) if variant != "grid" else ["auto"]
                for order in orders if variant != "grid" else orders[:1]:
                    for form in forms:
                        label = f"{variant}, {form}" if len(forms) > 1 else variant
                        row = measure(variant, n, the_scene, load_s, str(device), args.repeats, not args.no_graph,
                                      args.threads, args.frames, order, form, label)
                        rows.append(row)
                        print(row, flush=True)
    where = machine(device)
    pins = "its two top corners" if args.pins == "corners" else "its top row"
    title = (f"Mesh cloth beside the grid: hanging cloth pinned at {pins}, {args.frames} frames, "
             f"{args.substeps} substeps x {args.iterations} iterations, coloured Gauss-Seidel"
             f"{', compliance ' + ', '.join(args.compliance) + ' m/N' if compliance else ''}"
             f"{', no graph capture' if args.no_graph else ''}: "
             f"{where}\n\n" + "\n".join(where.lines(command)) + "\n\n"
             "- grid: the grid cloth (analytic colouring). quad mesh: its exact points and quads from a .usdc, "
             "mass_distribution \"even\": the same particles, sticks and masses, graph colouring. triangle mesh: "
             f"the quads split along one diagonal, from {args.triangles.upper()} via trimesh. The mesh files list "
             f"their vertices {'in a random order (--shuffle)' if args.shuffle else 'in the grid' + chr(39) + 's row-major order'}.\n"
             "- particle order: how the device holds a mesh cloth's particles (Simulator's particle_order: Morton is "
             "\"auto\", input is \"input\"); reorder s: the host time of the Morton order and the renumbered "
             "topology, part of build s.\n"
             "- The triangle mesh has different sticks: its diagonals are structural (face sides), it has no "
             "shear sticks, and its bend sticks join the corners opposite each edge. Its stretch is over those "
             "structural sticks, diagonals included, so it is not the same measure as the grid's and quad "
             "mesh's.\n"
             "- sticks form: how the sweep runs (Simulator's sticks): explicit, a launch per colour of stick "
             "arrays; clustered, stick arrays swept cluster by cluster in shared memory; implicit or tiled, a "
             "grid's sticks computed in the kernel, a launch per colour or tile by tile.\n"
             "- balance: largest colour over smallest. load s: parse_scene (the mesh read, welded, checked; "
             "files written beforehand, not counted). build s: the Simulator's construction (colouring "
             "included). Mproj/s: sticks x substeps x iterations per second. Stretch |D - L|/L over the "
             f"structural sticks at frame {args.frames}, as a ratio (1.0 is 100%).\n" + notes(rows))
    write_table(rows, args.out, args.stem, title)
    return 0


def setup_only(args, device, command) -> int:
    rows = []
    for n in args.sizes:
        with tempfile.TemporaryDirectory(prefix="mesh_throughput-") as tmp:
            rows.append(setup_costs(n, Path(tmp), not args.no_colouring))
            print(rows[-1], flush=True)
    where = machine(device)
    title = (f"Mesh cloth particle reordering, host-side setup of the quad mesh: {where}\n\n"
             + "\n".join(where.lines(command)) + "\n\n"
             "- load s: parse_scene (the .usdc read, welded, checked). build_cloth s: its topology (sticks from the "
             "faces). Morton order s: the particles' Morton order. renumber s: the topology renumbered "
             "(particle_order.reorder_topology). reorder s: the two together, what particle_order \"morton\" adds to "
             "a mesh cloth's build. stick sort s: the sticks sorted by colour, then first and second particle "
             "(colouring.stick_order); colour sort s: the stable sort by colour alone it replaced. graph colouring "
             "s: Warp's graph colouring of the sticks, the bulk of a mesh cloth's build.\n")
    write_table(rows, args.out, args.stem, title)
    return 0


if __name__ == "__main__":
    sys.exit(main())
