"""A mesh cloth's particles held in Morton order on the device, and each colour's sticks sorted by particle: what
the user sees stays in the scene's order (the cache, pins and masses by vertex index, torn faces, the Simulator's
readbacks), sorting inside a colour changes no bit, and a reordered run is the same physics as one in the input
order (bit for bit with the Jacobi solver, whose sums follow the scene's order; within a tolerance with Gauss-Seidel,
whose order is another)."""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from mesh_files import grid_mesh, mesh_scene, write_usd_mesh
from warp_verlet.apps import runner
from warp_verlet.core import model as model_module
from warp_verlet.core import simulator as simulator_module
from warp_verlet.core.model import Model
from warp_verlet.core.simulator import Simulator, build_model, resolve_device
from warp_verlet.errors import ArgumentError
from warp_verlet.geometry.colouring import grid_colouring, stick_order
from warp_verlet.geometry.faces import Faces
from warp_verlet.geometry.particle_order import locality_order, morton_codes, reorder_topology
from warp_verlet.geometry.topology import build_cloth
from warp_verlet.input.scene import parse_scene

ROWS, COLS = 8, 10
ALL = ["structural", "shear", "bend"]
SEAM_COLUMN = COLS // 2


def curtain_file(tmp_path, seed: int = 3):
    """The ROWS x COLS grid's quads as a USD mesh whose middle column is duplicated (a UV seam, welded back into
    one particle per point) and whose vertices are listed in a random order: the particles come in no spatial
    order, and the cache has more vertices than particles. Returns the file and its points (float32)."""
    points, faces = grid_mesh(ROWS, COLS)
    quads = faces.as_uniform()
    seam = np.arange(ROWS) * COLS + SEAM_COLUMN
    copies = np.arange(ROWS) + ROWS * COLS
    right = (quads % COLS >= SEAM_COLUMN).all(axis=1)
    remap = np.arange(ROWS * COLS)
    remap[seam] = copies
    quads = np.where(right[:, None], remap[quads], quads)
    points = np.concatenate([points, points[seam]])
    order = np.random.default_rng(seed).permutation(len(points))
    place = np.empty(len(points), np.int64)
    place[order] = np.arange(len(points))
    points, quads = points[order], place[quads]
    return write_usd_mesh(tmp_path / "curtain.usda", points, Faces.uniform(quads)), points


def top_row_vertices(points: np.ndarray) -> np.ndarray:
    return np.flatnonzero(points[:, 1] == points[:, 1].max())


def curtain(tmp_path, simulation: dict | None = None, output: dict | None = None, colliders=None, **keys):
    """A mesh scene of :func:`curtain_file`: pinned by two vertex indices (the top corners) and by a box (the
    top row's middle), one vertex given a heavy mass."""
    asset, points = curtain_file(tmp_path)
    top = top_row_vertices(points)
    corners = [int(top[np.argmin(points[top, 0])]), int(top[np.argmax(points[top, 0])])]
    y = float(points[:, 1].max())
    cloth = {"mesh": asset.name, "prim": "/Set/Cloth", "sticks": ALL, "tethers": False,
             "pins": [*corners, {"min": [0.4, y - 1e-3, -1.0], "max": [0.6, y + 1e-3, 1.0]}],
             "particle_masses": [[int(np.argmin(points[:, 1])), 0.5]], **keys}
    sim = {"frames": 12, "substeps": 8, "iterations": 20, "wind": [0.0, 0.0, 6.0], **(simulation or {})}
    return mesh_scene(tmp_path, cloth, sim, output, colliders), points


def run(scene, frames: int, **simulator) -> np.ndarray:
    sim = Simulator(scene, "cpu", threads=1, **{"particle_order": "morton", **simulator})
    try:
        for _ in range(frames):
            sim.step_frame()
        return sim.positions()
    finally:
        sim.close()


def model_of(scene, particle_order: str = "morton") -> Model:
    return build_model(scene, resolve_device("cpu"), particle_order=particle_order)[0]


def scene_pairs(model: Model) -> np.ndarray:
    """The model's sticks in scene indices, each (low, high), sorted: comparable between particle orders."""
    pairs = np.sort(model.scene_particles(model.host_sticks), axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


# -- the order itself ---------------------------------------------------------------------------------------------

def test_morton_order_visits_a_grid_block_by_block():
    """On a 4 x 4 grid of points (one cell each) Morton order visits the four 2 x 2 blocks one after another,
    each in Z order: the order written out by hand from the interleaved bits."""
    x, y = np.meshgrid(np.arange(4.0), np.arange(4.0), indexing="xy")
    points = np.stack([x.ravel(), y.ravel(), np.zeros(16)], axis=1)  # point r * 4 + c at (c, r, 0)
    expected = [0, 1, 4, 5, 2, 3, 6, 7, 8, 9, 12, 13, 10, 11, 14, 15]
    # 2^21 - 1 cells over a span of 3: columns land on cells 0, 699050, 1398100, 2097151, whose bits interleave
    # in the same order as 0, 1, 2, 3 do.
    assert locality_order(points).tolist() == expected
    codes = morton_codes(points)[expected]
    assert (codes[1:] > codes[:-1]).all()


def test_renumbered_topology_is_the_same_cloth(tmp_path):
    """Every per-particle array follows its particle, the sticks are the same pairs with the same rest lengths,
    the faces the same polygons, and each cache vertex shows the same point."""
    scene, _ = curtain(tmp_path)
    top = build_cloth(scene.cloths[0])
    order = locality_order(top.positions)
    assert not np.array_equal(order, np.arange(len(order)))  # shuffled input: the order is a real permutation
    new = reorder_topology(top, order)
    np.testing.assert_array_equal(new.positions, top.positions[order])
    np.testing.assert_array_equal(new.inv_mass, top.inv_mass[order])
    back = order[new.sticks]  # the renumbered sticks in the old numbering
    old = {(min(a, b), max(a, b)): (r, f) for (a, b), r, f in zip(top.sticks.tolist(), top.rest_length, top.family)}
    assert {(min(a, b), max(a, b)): (r, f) for (a, b), r, f in zip(back.tolist(), new.rest_length, new.family)} == old
    assert (new.sticks[:, 0] < new.sticks[:, 1]).all()
    np.testing.assert_array_equal(order[new.faces.indices], top.faces.indices)
    np.testing.assert_array_equal(np.sort(order[new.pinned]), np.sort(top.pinned))
    np.testing.assert_array_equal(new.cache_points(new.positions), top.cache_points(top.positions))
    assert new.cache_faces == top.cache_faces


def test_a_grid_is_never_renumbered():
    grid = parse_scene({"cloth": [{"resolution": [4, 5], "size": [1.0, 1.0], "sticks": ALL, "pins": ["top-left"]}]})
    model = model_of(grid)
    assert model.scene_particle is None and model.device_particle is None
    with pytest.raises(ArgumentError, match="grid"):
        reorder_topology(build_cloth(grid.cloths[0]), np.arange(20))


def test_particle_order_is_checked(tmp_path):
    scene, _ = curtain(tmp_path)
    with pytest.raises(ArgumentError, match="particle_order must be 'auto', 'morton' or 'input', got 'hilbert'"):
        Simulator(scene, "cpu", particle_order="hilbert")


# -- sticks in each colour ----------------------------------------------------------------------------------------

def test_each_colour_reads_memory_forward(tmp_path):
    """Inside every colour the sticks are in increasing order of their first particle (no two share one), each
    stored (low, high): a launch walks the particle array forward."""
    scene, _ = curtain(tmp_path)
    for particle_order in ("morton", "input"):
        model = model_of(scene, particle_order)
        ends = model.host_sticks
        assert (ends[:, 0] < ends[:, 1]).all()
        for first, count in model.colour_ranges:
            assert np.all(np.diff(ends[first:first + count, 0]) > 0), (particle_order, first)


def test_a_grid_keeps_its_stick_order():
    """A grid's colours are in row-major order of their first particle already: the sort is the identity there,
    so grids (the golden scenes, the implicit grid sticks) are untouched."""
    top = build_cloth(parse_scene({"cloth": [{"resolution": [7, 9], "size": [1.0, 1.0], "sticks": ALL}]}).cloths[0])
    colour = grid_colouring(top.grid_class, top.anchor).colour
    np.testing.assert_array_equal(stick_order(colour, top.sticks), np.argsort(colour, kind="stable"))


@pytest.mark.parametrize("particle_order", ["morton", "input"])
def test_sorting_sticks_inside_a_colour_changes_no_bit(tmp_path, monkeypatch, particle_order):
    """The sticks of one colour share no particle, so projecting them in another order gives the same bits: the
    same run with the sticks in their colouring's order (a stable sort by colour, as before the sort by particle)
    ends at exactly the same positions."""
    scene, points = curtain(tmp_path)
    sorted_run = run(scene, 10, particle_order=particle_order)
    sorted_sticks = model_of(scene, particle_order).host_sticks
    monkeypatch.setattr(model_module, "stick_order", lambda colour, sticks: np.argsort(colour, kind="stable"))
    unsorted_sticks = model_of(scene, particle_order).host_sticks
    assert not np.array_equal(sorted_sticks, unsorted_sticks)  # the two runs visit the sticks in other orders
    unsorted_run = run(scene, 10, particle_order=particle_order)
    assert np.abs(sorted_run - build_cloth(scene.cloths[0]).positions).max() > 0.05  # it moved
    np.testing.assert_array_equal(sorted_run, unsorted_run)


# -- the scene's order at every boundary ---------------------------------------------------------------------------

def test_model_is_the_input_order_model_renumbered(tmp_path):
    """Every per-particle array of a reordered Model, taken back to the scene's order, is the input-order Model's,
    and its sticks are the same pairs of scene particles."""
    scene, _ = curtain(tmp_path)
    ordered, plain = model_of(scene), model_of(scene, "input")
    assert plain.scene_particle is None
    assert not np.array_equal(ordered.scene_particle, np.arange(ordered.particle_count))
    np.testing.assert_array_equal(ordered.device_particle[ordered.scene_particle], np.arange(ordered.particle_count))
    np.testing.assert_array_equal(ordered.to_scene_order(ordered.rest_positions), plain.rest_positions)
    np.testing.assert_array_equal(ordered.to_scene_order(ordered.host_inv_mass), plain.host_inv_mass)
    np.testing.assert_array_equal(scene_pairs(ordered), scene_pairs(plain))
    assert ordered.cloths[0].topology is not ordered.cloths[0].device_topology
    np.testing.assert_array_equal(ordered.cloths[0].topology.positions, plain.cloths[0].topology.positions)


def test_cache_is_in_input_vertex_order(tmp_path):
    """With the particles reordered, frame 0 of the cache is the file's points exactly, vertex for vertex; the
    pinned vertices (by index and by box) stay exactly at rest in every frame; the seam's duplicates move with
    their twins."""
    scene, points = curtain(tmp_path)
    runner.run_scene(scene, device="cpu")
    assert model_of(scene).scene_particle is not None  # the run was reordered
    stage = Usd.Stage.Open(str(tmp_path / "out.usda"))
    cache = UsdGeom.Mesh.Get(stage, "/World/cloth").GetPointsAttr()
    np.testing.assert_array_equal(np.asarray(cache.Get(0), np.float32), points)
    top = top_row_vertices(points)
    x = points[top, 0]
    pinned = top[(x == x.min()) | (x == x.max()) | ((x >= 0.4) & (x <= 0.6))]
    assert len(pinned) == 3  # the two corners by index, the one top vertex in the box
    last = np.asarray(cache.Get(scene.simulation.frames), np.float32)
    np.testing.assert_array_equal(last[pinned], points[pinned])
    moving = np.setdiff1d(np.arange(len(points)), pinned)
    assert np.abs(last[moving] - points[moving]).max() > 0.05  # the rest swung
    twins = {}
    for v, p in enumerate(points.tolist()):
        twins.setdefault(tuple(p), []).append(v)
    pairs = [v for v in twins.values() if len(v) == 2]
    assert len(pairs) == ROWS
    for a, b in pairs:
        np.testing.assert_array_equal(last[a], last[b])


def test_simulator_speaks_the_scene_order(tmp_path):
    """positions, set_positions, previous_positions, render_points, diverged_particle and set_velocity take and
    give scene indices whatever order the device holds."""
    scene, _ = curtain(tmp_path)
    sim = Simulator(scene, "cpu", threads=1, particle_order="morton")
    rest = build_cloth(scene.cloths[0]).positions
    np.testing.assert_array_equal(sim.positions(), rest)
    sim.step_frame()
    moved = sim.positions()
    pinned = build_cloth(scene.cloths[0]).pinned
    np.testing.assert_array_equal(moved[pinned], rest[pinned])
    np.testing.assert_array_equal(sim.previous_positions()[pinned], rest[pinned])
    chosen = np.array([5, 0, 17, 42], np.int32)
    # alpha 0 gives the previous positions exactly: the device's gather against the host's readback
    np.testing.assert_array_equal(sim.render_points(chosen, 0.0), sim.previous_positions()[chosen])
    assert np.abs(sim.render_points(chosen, 0.0) - moved[chosen]).max() > 0  # they are not the positions
    shifted = moved + np.float32(0.01)
    sim.state.set_positions(shifted)
    np.testing.assert_array_equal(sim.positions(), shifted)
    broken = shifted.copy()
    broken[17] = np.nan
    sim.state.set_positions(broken)
    assert sim.diverged_particle() == 17
    sim.state.set_positions(shifted)
    free = int(np.flatnonzero(build_cloth(scene.cloths[0]).inv_mass > 0)[3])
    velocity = np.zeros((len(rest), 3))
    velocity[free] = (0.0, 0.0, 5.0)
    sim.state.set_velocity(velocity)
    start = sim.positions()
    sim.step()
    step = np.abs(sim.positions() - start)[:, 2]
    assert int(np.argmax(step)) == free  # the particle given the velocity moved furthest along it
    sim.close()


def test_take_state_crosses_particle_orders(tmp_path):
    """A simulator in the input order continues exactly from a reordered one's state, torn sticks included."""
    scene, _ = curtain(tmp_path, {"wind": [0.0, 0.0, 60.0], "iterations": 4}, tear_threshold=1.005)
    ordered = Simulator(scene, "cpu", threads=1, particle_order="morton")
    for _ in range(6):
        ordered.step_frame()
    assert ordered.torn_count() > 0
    plain = Simulator(scene, "cpu", threads=1, particle_order="input")
    plain.take_state(ordered)
    np.testing.assert_array_equal(plain.positions(), ordered.positions())
    np.testing.assert_array_equal(plain.previous_positions(), ordered.previous_positions())
    torn = lambda sim: {tuple(p) for p in np.sort(sim.model.scene_particles(sim.model.host_sticks[sim.torn_sticks()]), axis=1).tolist()}  # noqa: E731
    assert torn(plain) == torn(ordered)
    ordered.close()
    plain.close()


def test_torn_faces_are_the_input_faces(tmp_path):
    """The same sticks torn (given by scene particles) hide the same faces, by their index in the file, whatever
    the order the device holds the particles in; and they are the faces beside those edges."""
    scene, _ = curtain(tmp_path, tear_threshold=1.5)
    top = build_cloth(scene.cloths[0])
    edges = np.array([(int(a), int(b)) for a, b in top.sticks[:200:37]])  # a few sticks, in scene indices
    hidden = []
    for particle_order in ("morton", "input"):
        sim = Simulator(scene, "cpu", threads=1, particle_order=particle_order)
        sim.model.restore_tears(sim.state, edges)
        hidden.append(sim.model.hidden_faces(sim.sync_tears())[0])
        sim.close()
    np.testing.assert_array_equal(hidden[0], hidden[1])
    corners = np.split(top.faces.indices, np.cumsum(top.faces.counts)[:-1])
    structural = {tuple(sorted(e)) for e, f in zip(top.sticks.tolist(), top.family) if f == 0}
    beside = {k for k, face in enumerate(corners) for a, b in zip(face, np.roll(face, -1))
              if tuple(sorted((int(a), int(b)))) in {tuple(sorted(e)) for e in edges.tolist()} & structural}
    assert len(beside) > 0 and set(hidden[0].tolist()) == beside


# -- the same physics -----------------------------------------------------------------------------------------------

def test_jacobi_runs_bit_for_bit_in_either_order(tmp_path, monkeypatch):
    """The Jacobi solver sums each particle's corrections in the scene's order of its neighbours, and every other
    stage here works particle by particle (Verlet, air on faces, tethers, rigid patches, a sphere), so a reordered
    run writes the same cache, bit for bit, as one in the input order, torn faces included: every index that
    crosses the boundary (pins by vertex and box, a mass by vertex, patch members, faces, tethers' pins) is mapped
    right, or a bit would differ."""
    air = {"velocity": [0.0, 0.0, 6.0], "density": 1.2}
    sphere = {"type": "sphere", "name": "ball", "radius": 0.3, "centre": [0.5, -1.2, 0.3]}
    _, points = curtain_file(tmp_path)
    lowest = [int(v) for v in np.argsort(points[:, 1], kind="stable")[:3]]  # three vertices of the bottom row
    scene, _ = curtain(tmp_path, {"relaxation": "jacobi", "air": air, "frames": 10}, {"torn_faces": "remove"},
                       [sphere], tethers=True, tear_threshold=1.005, rigid_patches=[lowest])
    caches = []
    for particle_order in ("morton", "input"):
        monkeypatch.setattr(simulator_module, "Simulator", partial(Simulator, particle_order=particle_order))
        out = tmp_path / f"{particle_order}.usda"  # two files: a layer once opened is not read again
        summary = runner.run_scene(replace(scene, output=replace(scene.output, path=out)), device="cpu")
        stage = Usd.Stage.Open(str(out))
        mesh = UsdGeom.Mesh.Get(stage, "/World/cloth")
        times = mesh.GetFaceVertexIndicesAttr().GetTimeSamples()
        caches.append(([np.asarray(mesh.GetPointsAttr().Get(f)) for f in range(11)],
                       [list(mesh.GetFaceVertexIndicesAttr().Get(t)) for t in times], summary.torn))
    (points_a, faces_a, torn_a), (points_b, faces_b, torn_b) = caches
    assert torn_a == torn_b and torn_a > 0 and len(faces_a) >= 2  # it tore, and the cache shows it
    assert faces_a == faces_b
    for a, b in zip(points_a, points_b):
        np.testing.assert_array_equal(a, b)


def test_gauss_seidel_in_either_order_is_the_same_cloth(tmp_path):
    """The coloured solver projects in another order when the particles are renumbered (other colours, other
    order inside each sweep), so the runs differ by what Gauss-Seidel leaves unconverged, not by physics. Both
    hold every structural stick to 0.3% of its length here (20 iterations, 8 substeps), so a particle's two
    positions differ by far less than the 0.16 m spacing (measured: 4.6 mm): the bound is 10% of the spacing,
    while the cloth swings more than twice the spacing, and a particle shown in another's place is a spacing or
    more away."""
    scene, points = curtain(tmp_path, {"frames": 20})
    ordered = Simulator(scene, "cpu", threads=1, particle_order="morton")
    plain = Simulator(scene, "cpu", threads=1, particle_order="input")
    for _ in range(20):
        ordered.step_frame()
        plain.step_frame()
    spacing = 1.4 / (COLS - 1)
    a, b = ordered.positions(), plain.positions()
    assert np.abs(a - build_cloth(scene.cloths[0]).positions).max() > 2 * spacing
    assert ordered.stretch().max < 3e-3 and plain.stretch().max < 3e-3
    assert np.abs(a - b).max() < 0.1 * spacing
    ordered.close()
    plain.close()


def test_live_recording_saves_the_input_vertex_order(tmp_path, monkeypatch):
    """A live session records each frame as the device holds it and saves it through the scene's order: every
    saved frame of a reordered mesh is, vertex for vertex, what a batch simulator's positions give."""
    from warp_verlet.apps.live_session import LiveSession
    from warp_verlet.geometry import particle_order

    monkeypatch.setattr(particle_order, "LOCALITY_GAIN", 0.0)  # "auto" renumbers even this small mesh
    from warp_verlet.output.cache_reader import open_cache, read_cloths

    scene, points = curtain(tmp_path)
    session = LiveSession(scene, "cpu")
    assert session.sim.model.scene_particle is not None
    for _ in range(4):
        session.tick(1.0 / scene.simulation.fps)
    assert session.save(tmp_path / "live.usdc") == 5
    cache = open_cache(tmp_path / "live.usdc")
    topology = build_cloth(scene.cloths[0])
    batch = Simulator(scene, "cpu", particle_order="morton")
    for frame in range(5):
        if frame:
            batch.step_frame()
        np.testing.assert_array_equal(read_cloths(cache, frame)[0].points, topology.cache_points(batch.positions()))
    np.testing.assert_array_equal(read_cloths(cache, 0)[0].points, points)
    session.close()
    batch.close()


def test_a_mesh_moves_the_same_whatever_order_its_file_lists_its_vertices(tmp_path):
    """Morton order depends on the rest positions alone, so the same mesh listed in two vertex orders is held
    in one order on the device, coloured and projected alike: the two runs agree bit for bit, vertex for
    vertex, with the Gauss-Seidel solver too (the pins are a box, so they pick the same points)."""
    points, faces = grid_mesh(ROWS, COLS)
    order = np.random.default_rng(5).permutation(len(points))
    place = np.empty(len(points), np.int64)
    place[order] = np.arange(len(points))
    files = {"row-major": write_usd_mesh(tmp_path / "rows.usda", points, faces),
             "shuffled": write_usd_mesh(tmp_path / "shuffled.usda", points[order],
                                        Faces(faces.counts, place[faces.indices]))}
    top = {"min": [-1.0, -1e-3, -1.0], "max": [2.0, 1e-3, 1.0]}
    scenes = {name: mesh_scene(tmp_path, {"mesh": asset.name, "prim": "/Set/Cloth", "sticks": ALL, "pins": [top]},
                               {"frames": 10, "substeps": 8, "iterations": 10, "wind": [0.0, 0.0, 6.0]})
              for name, asset in files.items()}
    runs = {name: run(scene, 10) for name, scene in scenes.items()}
    assert np.abs(runs["row-major"] - points).max() > 0.05  # it swung
    np.testing.assert_array_equal(runs["shuffled"], runs["row-major"][order])
    # In the input order the two differ (other colours, another Gauss-Seidel order): the test is not vacuous.
    plain = {name: run(scene, 10, particle_order="input") for name, scene in scenes.items()}
    assert not np.array_equal(plain["shuffled"], plain["row-major"][order])


def test_simulator_gathers_positions_on_the_device_as_the_state_does_on_the_host(tmp_path):
    """Simulator.positions() puts a renumbered cloth back in the scene's order on the device; State.positions()
    does it on the host: the same gather, the same bits, and a snapshot that later steps leave alone."""
    scene, _ = curtain(tmp_path)
    sim = Simulator(scene, "cpu", threads=1, particle_order="morton")
    sim.step_frame()
    first = sim.positions()
    np.testing.assert_array_equal(first, sim.state.positions())
    np.testing.assert_array_equal(first, sim.model.to_scene_order(sim.state.particle_q.numpy()))
    kept = first.copy()
    sim.step_frame()
    np.testing.assert_array_equal(first, kept)
    assert not np.array_equal(sim.positions(), kept)
    sim.close()


def test_auto_renumbers_a_mesh_only_where_its_file_order_scatters_its_sticks(tmp_path):
    """A mesh whose file lists its vertices row by row is held as it is (Morton order measured slower on a GPU
    there); the same mesh with its vertex list shuffled is renumbered, since Morton order brings its sticks' ends
    more than LOCALITY_GAIN times closer in memory."""
    from warp_verlet.geometry.particle_order import LOCALITY_GAIN, inverse_order, mean_stick_span

    points, faces = grid_mesh(24, 24)
    order = np.random.default_rng(5).permutation(len(points))
    place = np.empty(len(points), np.int64)
    place[order] = np.arange(len(points))
    files = {False: write_usd_mesh(tmp_path / "rows.usda", points, faces),
             True: write_usd_mesh(tmp_path / "shuffled.usda", points[order], Faces(faces.counts, place[faces.indices]))}
    for shuffled, asset in files.items():
        scene = mesh_scene(tmp_path, {"mesh": asset.name, "prim": "/Set/Cloth", "sticks": ALL}, {"frames": 1})
        model = model_of(scene, "auto")
        assert (model.scene_particle is not None) == shuffled
        top = model.cloths[0].topology
        gain = mean_stick_span(top.sticks) / mean_stick_span(top.sticks, inverse_order(locality_order(top.positions)))
        assert (gain > LOCALITY_GAIN) == shuffled
        assert model_of(scene, "morton").scene_particle is not None  # "morton" renumbers either way
