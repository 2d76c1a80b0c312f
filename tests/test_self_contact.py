"""Self-collision and cloth–cloth contact (warp_verlet/constraints/self_contact.py, kernels/self_contact.py): a
folded cloth dropped on the ground keeps its layers a thickness apart at every substep (and passes through
itself without it), two stacked cloths keep their order, contact adds no energy, two runs are bit-identical,
a scene without it launches and allocates nothing new, and bad keys are refused."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import self_contact as self_contact_bench

from conftest import make_scene
from warp_verlet.constraints.self_contact import (DEFAULT_FRACTION, GRID_CELL, MESH_SUBSET_RADIUS, REST_EXCLUSION,
                                                  colliding_particles)
from warp_verlet.core.memory import estimate
from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene

GAP_TOLERANCE = 0.15
"""ε: the closest non-neighbour pair may be (1 - ε) × the thickness. Contacts are resolved inside the sweeps and
the ground clamps after them, so a particle pressed between the ground and a falling layer is put back up into
that layer by up to its share of the substep's approach: here the layer lands at about 1.7 m/s, 3.5 mm per
2 ms substep against a 27 mm thickness, 13% (measured 11%; the same drop without self-collision: 94%)."""

N, SIZE, HEIGHT = 16, 0.5, 0.15  # particles per side, m, m above the ground
SPACING = SIZE / (N - 1)
THICKNESS = DEFAULT_FRACTION * SPACING
GROUND = {"type": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0], "friction_coefficient": 0.5}


def sheet(name: str, y: float, **keys) -> dict:
    return {"name": name, "resolution": [N, N], "size": [SIZE, SIZE], "origin": [-0.25, y, -0.25],
            "orientation": "horizontal", "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 1.0},
            "mass": 0.2, **keys}


def drop(cloths: list[dict], device: str = "cpu", colliders=(GROUND,), **sim) -> Simulator:
    data = {"simulation": {"fps": 60, "substeps": 8, "iterations": 8, "damping": 0.5, **sim}, "cloth": cloths,
            "collider": list(colliders)}
    return Simulator(parse_scene(data, file="<test>"), device)


def folded(rest: np.ndarray) -> np.ndarray:
    """The test sheet folded in half over itself, as the benchmark folds its own (bench.self_contact.folded)."""
    return self_contact_bench.folded(rest, SPACING, THICKNESS)


def closest_non_neighbours(x: np.ndarray, rest: np.ndarray) -> float:
    """The smallest distance between two particles that were not rest neighbours (REST_EXCLUSION × the
    thickness apart or more at rest), as a fraction of the thickness; all pairs, in float64."""
    x = x.astype(np.float64)
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    d[np.linalg.norm(rest[:, None] - rest[None], axis=2) < REST_EXCLUSION * THICKNESS] = np.inf
    return float(d.min() / THICKNESS)


def folded_drop(self_collision: bool, frames: int = 16, device: str = "cpu"):
    """(the simulator, the closest non-neighbours at each substep) for the folded sheet dropped on the ground."""
    sim = drop([sheet("sheet", HEIGHT, self_collision=self_collision)], device)
    rest = sim.model.rest_positions.astype(np.float64)
    sim.state.set_positions(folded(rest))
    gaps = []
    for _ in range(frames * sim.settings.substeps):
        sim.step()
        gaps.append(closest_non_neighbours(sim.positions(), rest))
    return sim, np.array(gaps)


def test_the_thickness_defaults_to_a_fraction_of_the_spacing():
    scene = make_scene(resolution=[11, 21], size=[1.0, 1.0], self_collision=True)
    assert scene.cloths[0].options["collision_thickness"] == pytest.approx(DEFAULT_FRACTION * 1.0 / 20)
    assert make_scene(self_collision=True, collision_thickness=0.1).cloths[0].options["collision_thickness"] == 0.1


def test_a_folded_cloth_keeps_its_layers_apart_at_every_substep():
    sim, gaps = folded_drop(True)
    assert gaps[0] > 1.4  # starts apart: the fold's gap is 1.5 thicknesses
    assert gaps.min() >= 1.0 - GAP_TOLERANCE
    assert gaps[-1] < 1.1, "the layers never met: the test would pass without the contacts"
    assert sim.positions()[:, 1].min() >= 0.0 and sim.positions()[:, 1].max() < 3 * THICKNESS  # landed
    _, without = folded_drop(False)
    assert without.min() < 0.5  # the same drop without self-collision passes through itself


def kinetic_and_potential(sim: Simulator, dt: float) -> float:
    x = sim.positions().astype(np.float64)
    v = (x - sim.state.previous_positions().astype(np.float64)) / dt
    mass = 1.0 / sim.model.host_inv_mass.astype(np.float64)
    return float((0.5 * mass * (v * v).sum(1) + mass * 9.81 * x[:, 1]).sum())


def thrown_sheets(self_collision: bool) -> tuple[list[float], list[float]]:
    """Two sheets in free fall, the upper one thrown down at 1 m/s onto the lower one from 3 thicknesses above,
    no ground, no damping: (the energy, the least height of the upper sheet over the lower, particle over
    particle) at each substep."""
    sim = drop([sheet("lower", HEIGHT, self_collision=self_collision),
                sheet("upper", HEIGHT + 3 * THICKNESS, self_collision=self_collision)], colliders=(), damping=0.0)
    velocity = np.zeros((sim.model.particle_count, 3))
    velocity[sim.model.cloths[1].particles, 1] = -1.0
    sim.state.set_velocity(velocity)
    energies, gaps = [], []
    for _ in range(10 * sim.settings.substeps):
        sim.step()
        energies.append(kinetic_and_potential(sim, sim.dt))
        lower_y, upper_y = (sim.positions()[slot.particles, 1].astype(np.float64) for slot in sim.model.cloths)
        gaps.append(float((upper_y - lower_y).min()))
    return energies, gaps


def test_contact_is_inelastic_and_adds_no_energy():
    # Gravity pulls both sheets alike, so they meet at 1 m/s, and a position-level contact stops the approach
    # without a bounce: the sheets then fall together a thickness apart, having lost the relative motion's
    # energy, (1/2) (m m / (m + m)) v^2 = 0.05 J for two 0.2 kg sheets, and never more than the same throw
    # without contact (where they pass through each other) has. Tolerances: 0.5 mJ (Verlet's velocity
    # estimate (x - x_prev) / dt), 10% of the loss, 5% of the thickness.
    with_contact, gaps = thrown_sheets(True)
    free, free_gaps = thrown_sheets(False)
    assert min(free_gaps) < 0.0  # without contact the upper sheet passes through the lower
    added = np.array(with_contact) - np.array(free)
    assert added.max() <= 5e-4
    assert added[-1] == pytest.approx(-0.5 * 0.1 * 1.0 ** 2, rel=0.1)
    assert min(gaps) >= (1.0 - GAP_TOLERANCE) * THICKNESS
    assert gaps[-1] <= 1.05 * THICKNESS  # no bounce


def test_two_stacked_cloths_keep_their_order():
    # The same sheet twice, 1.5 thicknesses apart: both fall alike until the lower one lands, then the upper one
    # lands on it, particle over particle.
    upper_y = HEIGHT + 1.5 * THICKNESS
    for contact, ordered in ((True, True), (False, False)):
        sim = drop([sheet("lower", HEIGHT, self_collision=contact), sheet("upper", upper_y, self_collision=contact)])
        for _ in range(30):
            sim.step_frame()
        lower, upper = (sim.positions()[slot.particles].astype(np.float64) for slot in sim.model.cloths)
        assert lower[:, 1].max() < 2 * THICKNESS  # both landed
        above = upper[:, 1] - lower[:, 1]
        assert (above.min() >= (1.0 - GAP_TOLERANCE) * THICKNESS) == ordered


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_two_runs_are_bit_identical(device, precision):
    # The second run steps without the frame's capture (a CUDA graph, or Warp's CPU capture): the hash grid's
    # rebuild must be replayed by the capture too.
    def run(use_graph: bool):
        scene = drop([sheet("lower", HEIGHT, self_collision=True),
                      sheet("upper", HEIGHT + 1.5 * THICKNESS, self_collision=True)], precision=precision).scene
        sim = Simulator(scene, device, use_graph=use_graph)
        for _ in range(15):
            sim.step_frame()
        return sim.positions()

    first, second = run(True), run(False)
    assert np.array_equal(first, second)
    assert np.abs(first[:N * N, 1]).max() < HEIGHT  # it fell and met the ground: the runs did something


def test_contact_runs_after_the_sticks_in_every_sweep(launches):
    sim = drop([sheet("sheet", HEIGHT, self_collision=True)])
    sim = Simulator(sim.scene, "cpu", use_graph=False)
    assert sim.constraint_sets[-1] == "self contact"
    names = launches.of(sim.step)
    assert names.count("contact_gather") == sim.settings.iterations
    first_stick = next(k for k, name in enumerate(names) if name.startswith("relax_"))
    assert names.index("contact_gather") > first_stick


def test_the_search_divides_over_cpu_threads_bit_for_bit(launches):
    # Each thread of the CPU team searches its own run of the grid's points once a substep; a particle's candidates
    # do not depend on who finds them, so every thread count gives the same positions.
    scene = drop([sheet("lower", HEIGHT, self_collision=True),
                  sheet("upper", HEIGHT + 1.5 * THICKNESS, self_collision=True)]).scene
    positions = []
    for threads in (1, 2, 3):
        sim = Simulator(scene, "cpu", use_graph=False, threads=threads)
        assert launches.of(sim.step).count("contact_candidates") == threads
        for _ in range(15):
            sim.step_frame()
        positions.append(sim.positions())
        sim.close()
    assert np.abs(positions[0][:N * N, 1]).max() < HEIGHT  # it fell and met the ground
    assert all(np.array_equal(positions[0], other) for other in positions[1:])


def test_a_scene_without_self_collision_launches_and_allocates_nothing_new(launches):
    plain = drop([sheet("sheet", HEIGHT)]).scene
    off = drop([sheet("sheet", HEIGHT, self_collision=False)]).scene
    assert estimate(plain).device_bytes == estimate(off).device_bytes
    sim = Simulator(off, "cpu", use_graph=False)
    assert "self contact" not in sim.constraint_sets
    names = launches.of(sim.step)
    assert "contact_gather" not in names
    assert not any(name.startswith("self_contact") for name in vars(sim.model))
    assert "contact_positions" not in sim.solver._scratch
    on = drop([sheet("sheet", HEIGHT, self_collision=True)]).scene
    assert estimate(on).device_bytes > estimate(off).device_bytes


@pytest.mark.parametrize("keys, problem", [
    ({"self_collision": True, "collision_thickness": 0.0}, r"collision_thickness.*expected a number in \(0"),
    ({"self_collision": True, "collision_thickness": -0.01}, r"collision_thickness.*expected a number in \(0"),
    ({"self_collision": True, "collision_thickness": 0.5}, r"collision_thickness.*at most the cloth's rest spacing, "
                                                           r"0\.333333 m, got 0\.5 m"),
    ({"collision_thickness": 0.1}, r"collision_thickness.*needs self_collision = true"),
    ({"self_collision_stride": 2}, r"self_collision_stride.*needs self_collision = true"),
    ({"self_collision": True, "self_collision_stride": 0}, r"self_collision_stride.*expected an integer >= 1"),
    ({"self_collision": True, "self_collision_stride": 4}, r"self_collision_stride.*expected less than the cloth's "
                                                           r"4 particles along its shorter side, got 4"),
    ({"self_collision": True, "self_collision_stride": 2, "collision_thickness": 0.7},
     r"collision_thickness.*at most 2 × the cloth's rest spacing, 0\.666667 m, got 0\.7 m"),
    ({"self_collision": "yes"}, r"self_collision.*expected true or false"),
])
def test_bad_keys_are_refused(keys, problem):
    with pytest.raises(SceneError, match=problem):
        make_scene(resolution=[4, 4], size=[1.0, 1.0], **keys)


def test_a_mesh_cloths_default_is_its_median_edge(tmp_path):
    from test_angle_limit import strip_obj

    strip_obj(tmp_path / "strip.obj")  # 4 x 20 vertices, 0.05 m apart
    data = {"cloth": [{"mesh": "strip.obj", "self_collision": True}]}
    scene = parse_scene(data, str(tmp_path / "s.toml"), tmp_path / "s.toml")
    assert scene.cloths[0].options["collision_thickness"] == pytest.approx(DEFAULT_FRACTION * 0.05, rel=1e-6)



def test_a_mesh_stride_collides_a_spread_subset(tmp_path):
    """On a mesh, self_collision_stride = k keeps particles at least MESH_SUBSET_RADIUS × k median edges apart
    with every particle within that of one (so no particle of another layer passes between them at the default
    thickness, 0.8 k edges); the thickness follows k; the Model holds them in its own particle order."""
    from test_angle_limit import strip_obj

    strip_obj(tmp_path / "strip.obj", rows=12, cols=12)  # 12 x 12 vertices, 0.05 m apart
    data = {"cloth": [{"mesh": "strip.obj", "self_collision": True, "self_collision_stride": 2}]}
    scene = parse_scene(data, str(tmp_path / "s.toml"), tmp_path / "s.toml")
    spec = scene.cloths[0]
    assert spec.options["collision_thickness"] == pytest.approx(DEFAULT_FRACTION * 2 * 0.05, rel=1e-6)
    points = spec.mesh.mesh.particle_points
    kept = colliding_particles(spec)
    radius = MESH_SUBSET_RADIUS * 2 * 0.05
    d = np.linalg.norm(points[:, None] - points[None], axis=2)
    assert 0 < len(kept) < len(points)
    assert d[np.ix_(kept, kept)][~np.eye(len(kept), dtype=bool)].min() >= radius  # spread
    assert d[:, kept].min(axis=1).max() < radius  # covering
    sim = Simulator(scene, "cpu", particle_order="morton")  # the device's order is not the scene's
    assert sim.model.scene_particle is not None
    held = sim.model.constraints["self contact"].particle.numpy()
    np.testing.assert_array_equal(held, np.sort(sim.model.device_particles(kept)))
    sim.step_frame()  # it runs


STRIDE = 2
STRIDE_THICKNESS = DEFAULT_FRACTION * STRIDE * SPACING
STRIDED = (lambda kept: (kept[:, None] * N + kept[None, :]).ravel())(np.r_[np.arange(0, N, STRIDE), N - 1])
"""The test sheet's colliding particles with a stride of 2: rows and columns 0, 2, ..., 14 and 15."""


def least_distance(x: np.ndarray, rest: np.ndarray, thickness: float) -> float:
    """The smallest distance between two of ``x`` that were not rest neighbours (REST_EXCLUSION × ``thickness``
    apart or more at rest), as a fraction of ``thickness``; in float64."""
    x = x.astype(np.float64)
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    d[np.linalg.norm(rest[:, None] - rest[None], axis=2) < REST_EXCLUSION * thickness] = np.inf
    return float(d.min() / thickness)


def test_a_stride_collides_every_few_particles_at_their_spacing():
    """With self_collision_stride = 2 a quarter of the sheet collides, at a thickness of twice the spacing's default:
    dropped folded, those particles keep the thickness from each other at every substep (ε as above), and the
    particles between them, which only their sticks hold, stay at least 0.35 × the thickness apart (measured 0.42;
    the same drop without self-collision passes through itself, test_a_folded_cloth_keeps_its_layers_apart)."""
    sim = drop([sheet("sheet", HEIGHT, self_collision=True, self_collision_stride=STRIDE)])
    assert sim.scene.cloths[0].options["collision_thickness"] == pytest.approx(STRIDE_THICKNESS)
    data = sim.model.constraints["self contact"]
    np.testing.assert_array_equal(data.particle.numpy(), STRIDED)
    rest = sim.model.rest_positions.astype(np.float64)
    sim.state.set_positions(self_contact_bench.folded(rest, SPACING, STRIDE_THICKNESS))
    colliding, every = [], []
    for _ in range(16 * sim.settings.substeps):
        sim.step()
        x = sim.positions()
        colliding.append(least_distance(x[STRIDED], rest[STRIDED], STRIDE_THICKNESS))
        every.append(least_distance(x, rest, STRIDE_THICKNESS))
    assert colliding[0] > 1.4  # starts apart: the fold's gap is 1.5 thicknesses
    assert min(colliding) >= 1.0 - GAP_TOLERANCE
    assert colliding[-1] < 1.1, "the layers never met"
    assert min(every) >= 0.35
    assert sim.positions()[:, 1].min() >= 0.0 and sim.positions()[:, 1].max() < 3 * STRIDE_THICKNESS  # landed


def grid_candidates(points: np.ndarray, thickness: np.ndarray, dims, reach: float, device: str,
                    builds: int = 1, cell_factor: float = GRID_CELL) -> list[list[int]]:
    """Each point's candidate list as the binding finds it: the hash grid built (``builds`` times, the earlier
    builds from other points, so that nothing of them may survive) with cells ``cell_factor`` × the query
    radius, then ``contact_candidates``."""
    from warp_verlet.kernels.self_contact import contact_candidates

    n, cap = len(points), 64
    radius = reach * float(thickness.max())
    cell = cell_factor * radius
    with wp.ScopedDevice(device):
        x = wp.array(points, dtype=wp.vec3)
        h = wp.array(thickness, dtype=float)
        rest = wp.array(np.arange(n)[:, None] * np.array([[10.0, 0.0, 0.0]]), dtype=wp.vec3)  # no rest neighbours
        cloth = wp.zeros(n, dtype=int)
        candidate, count = wp.zeros(n * cap, dtype=int), wp.zeros(n, dtype=int)
        grid = wp.HashGrid(*dims)
        grid.reserve(n)
        rng = np.random.default_rng(3)
        for build in range(builds):
            x.assign(points if build == builds - 1 else rng.permutation(points) + rng.normal(0, 0.05, points.shape))
            grid.build(x, cell)
        wp.launch(contact_candidates, n, [wp.uint64(grid.id), x, h, rest, cloth, REST_EXCLUSION, reach, radius, cap, 0],
                  [candidate, count])
        found, counts = candidate.numpy().reshape(n, cap), count.numpy()
    return [list(found[i, :counts[i]]) for i in range(n)]


@pytest.mark.parametrize("cell_factor", [1.0, GRID_CELL])
@pytest.mark.parametrize("dims", [(8, 8, 8), (40, 9, 23)])
def test_the_hash_grid_search_finds_every_pair_within_reach_and_no_other(device, dims, cell_factor):
    # Points spread over more than the grid's cells (so far cells wrap onto near ones), some not colliding; the
    # grid is built three times, so anything stale of an earlier build would show as a missing or extra candidate.
    rng = np.random.default_rng(7)
    n, reach = 3000, 1.25
    points = rng.uniform(-0.3, 0.3, (n, 3)).astype(np.float32)
    thickness = np.where(rng.uniform(size=n) < 0.9, rng.uniform(0.02, 0.04, n), 0.0).astype(np.float32)
    got = grid_candidates(points, thickness, dims, reach, device, builds=3, cell_factor=cell_factor)
    pair = 0.5 * (thickness[:, None] + thickness[None])
    near = np.linalg.norm(points[:, None].astype(np.float64) - points[None], axis=2) < reach * pair
    near &= (thickness[:, None] > 0) & (thickness[None] > 0)
    np.fill_diagonal(near, False)
    assert near.sum() > n  # the test has pairs to find
    for i in range(n):
        assert sorted(got[i]) == list(np.flatnonzero(near[i])), i
    # A fixed order (the grid's), the same however the grid was reached.
    assert got == grid_candidates(points, thickness, dims, reach, device, builds=1, cell_factor=cell_factor)


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
def test_a_large_folded_cloth_holds_on_cuda_with_its_frames_captured_beside_another_hash_grid():
    # Warp's CUDA hash-grid build copies its descriptor from one static host variable, which a captured build reads
    # at replay: the measuring grid built between frames would stand in for the cloth's own, and the layers pass
    # through each other (256^2), unless the cloth's grid is built once before each replay. Captured frames are
    # then bit for bit the frames stepped launch by launch.
    sc = self_contact_bench
    n = 256
    thickness = sc.DEFAULT_FRACTION * sc.SIZE / (n - 1)

    def run(use_graph: bool):
        sim = Simulator(sc.folded_scene(n, True, 20, 32, 8), "cuda", use_graph=use_graph)
        assert sim.replays_frames == use_graph
        sim.state.set_positions(sc.folded(sim.model.rest_positions, sc.SIZE / (n - 1), thickness))
        meter = sc.GapMeter(sim, thickness)  # its own hash grid, built at every frame's end
        worst = 0.0
        for _ in range(20):
            sim.step_frame()
            worst = max(worst, meter.penetration())
        return sim.positions(), worst

    captured, worst = run(True)
    assert worst < 0.2  # without self-collision: 1.0 (two particles at one point)
    stepped, _ = run(False)
    np.testing.assert_array_equal(captured, stepped)
