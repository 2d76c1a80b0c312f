"""Line solves (``line_passes``): what one pass does to a stretched grid, what it keeps (momentum, pins, contact),
its place in a substep, the drape it holds to length, and the scene key's checks."""

from pathlib import Path

import numpy as np
import pytest
import warp as wp

from warp_verlet.constraints.line_solve import LineSolves, capacity_of
from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene

SOFT = {"shear": 1.0, "bend": 1.0}  # m/N: a cloth that can drape without stretching


def sheet(rows: int, cols: int, line_passes: int = 1, colliders=(), **cloth) -> dict:
    spec = {"name": "sheet", "resolution": [rows, cols], "size": [1.0, 0.8], "origin": [-0.5, 0.0, -0.4],
            "orientation": "horizontal", "mass": 0.2, "sticks": ["structural", "shear", "bend"], "compliance": SOFT,
            "line_passes": line_passes, **cloth}
    return {"simulation": {"substeps": 4, "iterations": 1}, "cloth": [spec], "collider": list(colliders)}


def one_pass(sim: Simulator) -> None:
    """The stage's per-substep run, alone: the clamp of the colliders, then the line passes."""
    with wp.ScopedDevice(sim.device):
        LineSolves().bind(sim.model, sim.state, sim.solver).run(sim.state, sim.scene.simulation.dt)


def structural_strain(sim: Simulator, x: np.ndarray) -> np.ndarray:
    """(D - L) / L of the structural sticks (the first family of a grid's sticks)."""
    top = sim.model.cloths[0].topology
    rest = sim.model.rest_positions.reshape(top.rows, top.cols, 3).astype(np.float64)
    x = x.reshape(top.rows, top.cols, 3).astype(np.float64)
    strains = []
    for a, b in ((np.s_[:, 1:], np.s_[:, :-1]), (np.s_[1:, :], np.s_[:-1, :])):
        length = np.linalg.norm(x[a] - x[b], axis=-1)
        strains.append((length / np.linalg.norm(rest[a] - rest[b], axis=-1) - 1.0).ravel())
    return np.concatenate(strains)


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("rows, cols", [(12, 9), (1, 40), (33, 2)])
def test_one_pass_takes_out_a_uniform_stretch(rows, cols, precision):
    """A flat grid stretched 10% along its rows and 20% along its columns: each row and column is a straight
    chain, so one Newton step on it is exact, and rows and columns meet at right angles, so the column solve
    leaves the rows' lengths alone. One pass leaves every structural stick at its length, to float32 rounding
    (measured 2e-7)."""
    data = sheet(rows, cols)
    data["simulation"]["precision"] = precision
    sim = Simulator(parse_scene(data, file="<lines>"), "cpu", use_graph=False)
    rest = sim.model.rest_positions.astype(np.float64)
    stretched = rest.copy()
    stretched[:, 0] *= 1.1
    stretched[:, 2] *= 1.2
    sim.state.set_positions(stretched)
    assert np.abs(structural_strain(sim, sim.positions())).max() > 0.09
    one_pass(sim)
    assert np.abs(structural_strain(sim, sim.positions())).max() < 2e-6


def crumpled_pass(**cloth) -> tuple[Simulator, np.ndarray, np.ndarray]:
    """A 17 x 13 sheet with uneven masses, crumpled by 1 cm noise, before and after one pass."""
    data = sheet(17, 13, particle_masses=[[3, 4, 0.05], [10, 2, 0.01]], **cloth)
    sim = Simulator(parse_scene(data, file="<lines>"), "cpu", use_graph=False)
    rng = np.random.default_rng(7)
    sim.state.set_positions(sim.model.rest_positions + rng.normal(0.0, 0.01, (sim.model.particle_count, 3)))
    before = sim.positions().astype(np.float64)
    one_pass(sim)
    return sim, before, sim.positions().astype(np.float64)


def test_a_pass_keeps_momentum():
    """The moves are W J^T lambda, so m dx summed over the cloth is the sum of J^T lambda: every stick pushes its
    two ends by opposite amounts, and the cloth's momentum does not change (to float32 rounding of the moves)."""
    sim, before, after = crumpled_pass()
    mass = 1.0 / sim.model.host_inv_mass
    moved = np.abs(after - before).max()
    assert moved > 1e-3  # it did something
    momentum = (mass[:, None] * (after - before)).sum(axis=0)
    assert np.abs(momentum).max() < 1e-5 * mass.max() * moved


def newton_step_on_lines(x: np.ndarray, w: np.ndarray, rest: np.ndarray, lines: list[np.ndarray]) -> np.ndarray:
    """One Newton step on each line's stick lengths, one line after another, solved densely in numpy (no
    contact): J W J^T lambda = -C, x += W J^T lambda."""
    x = x.copy()
    for line in lines:
        e = x[line[1:]] - x[line[:-1]]
        length = np.linalg.norm(e, axis=1)
        n = e / length[:, None]
        m = len(line) - 1
        jacobian = np.zeros((m, 3 * (m + 1)))
        for k in range(m):
            jacobian[k, 3 * k:3 * k + 3] = -n[k]
            jacobian[k, 3 * k + 3:3 * k + 6] = n[k]
        weights = np.repeat(w[line], 3)
        multipliers = np.linalg.solve((jacobian * weights) @ jacobian.T, rest[:m] - length)
        x[line] += (weights * (jacobian.T @ multipliers)).reshape(-1, 3)
    return x


def test_a_pass_is_a_newton_step_on_each_line():
    """On a crumpled 17 x 13 sheet with uneven masses and pins, one pass moves every particle as a dense solve of
    each row's and then each column's Newton step does (lines of 12 and 16 sticks, padded to 16 equations; row 8
    has two pins). The kernel rounds the sticks' directions to float32 for the couplings and moves (a relative 6e-8
    of moves of up to 5 cm): measured 1.2e-8 m apart."""
    data = sheet(17, 13, pins=[[8, 6], [8, 1]], particle_masses=[[3, 4, 0.05], [10, 2, 0.01]])
    data["simulation"]["precision"] = "float64"
    sim = Simulator(parse_scene(data, file="<lines>"), "cpu", use_graph=False)
    rng = np.random.default_rng(7)
    crumpled = sim.model.rest_positions + rng.normal(0.0, 0.01, (sim.model.particle_count, 3))
    sim.state.set_positions(crumpled)
    one_pass(sim)
    index = np.arange(17 * 13).reshape(17, 13)
    spacing = np.linalg.norm(np.diff(sim.model.rest_positions.reshape(17, 13, 3), axis=1), axis=-1)[0]
    across = np.linalg.norm(np.diff(sim.model.rest_positions.reshape(17, 13, 3), axis=0), axis=-1)[:, 0]
    rows = newton_step_on_lines(crumpled, sim.model.host_inv_mass, spacing, list(index))
    expected = newton_step_on_lines(rows, sim.model.host_inv_mass, across, list(index.T))
    assert np.abs(expected - crumpled).max() > 5e-3  # the step moves the sheet
    assert np.abs(sim.positions() - expected).max() < 1e-7


def test_a_line_held_along_itself_at_both_ends_stays_finite():
    """A 3-particle rope hanging from a pin, its bottom particle starting 5 cm under the ground: the clamp holds the
    bottom along the rope, so the middle particle sits between two ends that cannot move along the line, and the
    line's system is singular (equal multipliers on both sticks move nothing). The pass must leave every particle
    finite (an exact zero pivot made NaN: kernels/line_solve.py), the bottom on the ground and the middle between
    its neighbours."""
    ground = -0.15
    data = {"simulation": {"fps": 60, "frames": 1, "substeps": 1, "iterations": 1},
            "cloth": [{"name": "rope", "resolution": [3, 1], "size": [0.2, 0.0], "orientation": "vertical",
                       "origin": [0.0, 0.0, 0.0], "mass": 0.03, "sticks": ["structural"], "line_passes": 1,
                       "pins": ["top-left"]}],
            "collider": [{"type": "plane", "name": "ground", "point": [0.0, ground, 0.0]}]}
    sim = Simulator(parse_scene(data, file="<rope>"), "cpu", use_graph=False)
    assert sim.positions()[2, 1] < ground - 0.04  # it starts under the ground
    sim.step_frame()
    y = sim.positions()[:, 1].astype(np.float64)
    assert np.isfinite(sim.positions()).all()
    assert y[0] == 0.0 and abs(y[2] - ground) < 1e-6
    assert ground < y[1] < 0.0


def test_a_pass_never_moves_a_pin():
    sim, before, after = crumpled_pass(pins=["top-left", "top-right", [8, 6]])
    pinned = sim.model.host_inv_mass == 0
    assert pinned.sum() == 3 and np.array_equal(after[pinned], before[pinned])
    assert np.abs(after - before).max() > 1e-3


def test_each_cloth_gets_its_own_passes():
    """Two crumpled cloths in one scene, one asking one pass and one two (and a third asking none): each ends as it
    would alone, bit for bit, and the second pass takes the second cloth closer to its lengths."""
    rng = np.random.default_rng(3)

    def crumpled(spec_passes: list[int]) -> tuple[Simulator, list[np.ndarray]]:
        cloths = []
        for k, n in enumerate(spec_passes):
            cloth = sheet(9, 13, line_passes=n)["cloth"][0]
            cloth.update(name=f"c{k}", origin=[-0.5, float(k), -0.4])
            cloths.append(cloth)
        sim = Simulator(parse_scene({"simulation": {}, "cloth": cloths}, file="<lines>"), "cpu", use_graph=False)
        sim.state.set_positions(sim.model.rest_positions + noise[:sim.model.particle_count])
        one_pass(sim)
        x = sim.positions()
        return sim, [x[slot.first:slot.first + slot.count] for slot in sim.model.cloths]

    noise = rng.normal(0.0, 0.01, (3 * 9 * 13, 3))
    _, (once, twice, untouched) = crumpled([1, 2, 0])
    alone_sim, (alone,) = crumpled([1])
    assert np.array_equal(once, alone)
    second = Simulator(parse_scene(sheet(9, 13, line_passes=2), file="<lines>"), "cpu", use_graph=False)
    rest = second.model.rest_positions.astype(np.float64)
    assert np.array_equal(untouched, (rest + np.array([0.0, 2.0, 0.0]) + noise[2 * 117:3 * 117]).astype(np.float32))

    def worst(x):
        return np.abs(structural_strain(alone_sim, x)).max()

    assert worst(twice) < 0.5 * worst(once)


def test_a_particle_on_a_collider_slides_along_it():
    """A sheet predicted 1 mm into the ground and stretched 10% along it: the clamp lifts every particle onto
    the ground, and the solve then moves them only along it, shortening the rows and columns to their lengths
    without pushing any particle through the ground or off it."""
    ground = {"type": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]}
    sim = Simulator(parse_scene(sheet(9, 11, colliders=[ground]), file="<lines>"), "cpu", use_graph=False)
    stretched = sim.model.rest_positions.astype(np.float64)
    stretched[:, 0] *= 1.1
    stretched[:, 2] *= 1.1
    stretched[:, 1] = -0.001
    sim.state.set_positions(stretched)
    one_pass(sim)
    x = sim.positions()
    assert np.abs(x[:, 1]).max() < 1e-7
    assert np.abs(structural_strain(sim, x)).max() < 2e-6


def test_a_particle_on_a_ball_slides_over_it_and_not_into_it():
    """A sheet stretched and wrapped 1 mm inside a 0.25 m ball (structural strain up to 27%, 13% RMS): the clamp
    puts every particle on the ball, and one pass shortens the rows and columns (chords of the ball) by moving
    each particle along the ball's surface only (a curved line's Newton step is not exact: measured 8.2% max,
    2.1% RMS after it), so that none ends inside it; without the contact, the shortened chords would pull the
    particles in. (A particle counts as in contact when the clamp moved it: a second pass, with nothing to
    clamp, would not hold it.)"""
    ball = {"type": "sphere", "radius": 0.25, "centre": [0.0, 0.0, 0.0]}
    sim = Simulator(parse_scene(sheet(9, 11, size=[0.3, 0.3], origin=[-0.15, 0.0, -0.15], colliders=[ball]),
                                file="<lines>"), "cpu", use_graph=False)
    rest = sim.model.rest_positions.astype(np.float64)
    wrapped = np.stack([1.1 * rest[:, 0], np.full(len(rest), 0.25), 1.1 * rest[:, 2]], axis=1)
    wrapped *= 0.249 / np.linalg.norm(wrapped, axis=1, keepdims=True)
    sim.state.set_positions(wrapped)
    assert np.abs(structural_strain(sim, sim.positions())).max() > 0.25
    one_pass(sim)
    strain = structural_strain(sim, sim.positions())
    assert np.abs(strain).max() < 0.1 and np.sqrt(np.mean(strain ** 2)) < 0.03
    assert np.linalg.norm(sim.positions().astype(np.float64), axis=1).min() > 0.25 - 1e-6


def test_the_passes_run_once_per_substep_after_the_clamp_and_before_the_sweeps(launches):
    ground = {"type": "plane", "point": [0.0, -1.0, 0.0]}
    data = sheet(8, 8, line_passes=2, colliders=[ground])
    data["simulation"].update(substeps=1, iterations=1)
    sim = Simulator(parse_scene(data, file="<lines>"), "cpu", use_graph=False, threads=1)
    issued = [name.rsplit("__", 1)[-1] for name in launches.of(sim.step)]  # a generated kernel's local name
    start = issued.index("copy_positions")
    assert issued[start:start + 3] == ["copy_positions", "collide_planes", "contact_normals"]
    assert issued[start + 3:start + 7] == 4 * ["solve_lines"]  # two passes of rows, then columns
    after = issued[start + 7:]
    assert issued.index("verlet_step") < start
    assert any(name.startswith("relax_colour") for name in after) and after[-1] == "collide_planes"  # then the clamp
    without = Simulator(parse_scene(sheet(8, 8, line_passes=0), file="<lines>"), "cpu", use_graph=False)
    assert "line solves" not in without.model.constraints
    assert not {"solve_lines", "contact_normals"} & set(launches.of(without.step))


def drape(n: int, line_passes: int, frames: int = 60, substeps: int = 16) -> Simulator:
    """bench.convergence's drape (1 m, 0.2 kg, dropped from 0.5 m onto a 0.25 m ball), its shear and bend sticks
    soft, run ``frames`` frames on one CPU thread."""
    from bench import convergence

    tables = convergence.merge(convergence.drape(n, substeps, 1, frames),
                               {"cloth": {"compliance": SOFT, "line_passes": line_passes}})
    scene = parse_scene(tables, file="<drape>")
    sim = Simulator(scene, "cpu", threads=1)
    for _ in range(frames):
        sim.step_frame()
    return sim


def test_line_passes_hold_a_drape_to_its_length_where_sweeps_do_not():
    """The 48^2 drape at 16 x 1, 1 s: plain sweeps leave it stretched (measured 1.3% RMS, 7.3% max); one line
    pass a substep holds it under 0.3% RMS and 3% max (measured 0.13% / 1.2%), and no particle ends inside the
    ball."""
    plain, lines = drape(48, 0), drape(48, 1)
    assert plain.stretch().rms > 0.006 and plain.stretch().max > 0.04
    assert lines.stretch().rms < 0.003 and lines.stretch().max < 0.03
    x = lines.positions().astype(np.float64)
    assert np.linalg.norm(x, axis=1).min() > 0.25 - 1e-5
    assert x[:, 1].min() < 0.0  # it hangs over the ball, not on it as a plate


def test_a_drape_with_line_passes_repeats_bit_for_bit():
    a, b = drape(24, 1, frames=20), drape(24, 1, frames=20)
    assert np.array_equal(a.positions(), b.positions())


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
def test_cpu_and_cuda_agree_and_cuda_repeats():
    """A sheet falling 5 cm onto a ball, 10 frames at 16 x 1 (it lands after 6): CUDA repeats itself bit for bit,
    and agrees with the CPU within 1e-4 m (the same equations in the same order, rounded differently; later the
    folds on a symmetric ball make any difference grow)."""
    device = "cuda"
    tables = sheet(40, 40, colliders=[{"type": "sphere", "radius": 0.25, "centre": [0.0, -0.3, 0.0]}])
    tables["simulation"].update(substeps=16, frames=10)
    scene = parse_scene(tables, file="<lines>")

    def run(on):
        sim = Simulator(scene, on)
        for _ in range(10):
            sim.step_frame()
        return sim.positions().astype(np.float64)

    cpu, gpu, again = run("cpu"), run(device), run(device)
    assert np.array_equal(gpu, again)
    assert np.abs(cpu - gpu).max() < 1e-4


@pytest.mark.parametrize("cloth, words", [
    ({"compliance": {"structural": 1e-4}}, "structural sticks are soft"),
    ({"tear_threshold": 1.5}, "can tear"),
    ({"sticks": ["shear", "bend"]}, "no structural sticks"),
    ({"line_passes": -1}, "line_passes"),
    ({"line_passes": 1.5}, "line_passes"),
    ({"resolution": [2, 2050]}, "longer than 2048 sticks"),
])
def test_line_passes_refuse_what_they_cannot_solve(cloth, words):
    data = sheet(9, 9)
    data["cloth"][0].update(cloth)
    with pytest.raises(SceneError) as err:
        parse_scene(data, file="scene.toml")
    assert "line_passes" in str(err.value) and words in str(err.value) and "scene.toml" in str(err.value)


def test_line_passes_refuse_a_mesh_cloth():
    table = Path(__file__).resolve().parent.parent / "scenes" / "assets" / "tablecloth.obj"
    data = {"simulation": {}, "cloth": [{"name": "cloth", "mesh": str(table), "line_passes": 1}]}
    with pytest.raises(SceneError, match="line_passes.*mesh cloth has no rows"):
        parse_scene(data, file="scene.toml")


@pytest.mark.parametrize("sticks, capacity", [(1, 2), (2, 2), (3, 4), (63, 64), (64, 64), (65, 128)])
def test_the_kernel_holds_the_longest_line(sticks, capacity):
    assert capacity_of(sticks) == capacity


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=[
    pytest.mark.cuda, pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")])])
def test_a_line_sliding_on_ground_with_friction_stays_bounded(device):
    """A strip pinned at its bottom corners 0.27 m under a ground with friction, with two line passes and no
    tethers (the features fuzz found six such scenes). Friction shortens a sliding particle's move along the
    ground, so its whole move leans up to atan(0.6) = 31 degrees off the ground's normal; taken as the contact
    normal, it let the line solve slide particles into the ground, the singular, pinned-through row's system
    multiplied that, and the strip was thrown to 1e10 m (NaN in float32). The clamps now give the line solve their
    pushes themselves, and the strip stays within its own size."""
    data = {"simulation": {"fps": 60, "frames": 20, "substeps": 32, "iterations": 4},
            "cloth": [{"name": "strip", "resolution": [2, 10], "size": [0.74, 0.49], "origin": [0.0, 0.46, 0.0],
                       "sticks": ["structural"], "line_passes": 2, "tethers": False,
                       "pins": ["bottom-left", "bottom-right"]}],
            "collider": [{"type": "plane", "point": [0.0, -0.005, 0.0], "friction_coefficient": 0.6}]}
    sim = Simulator(parse_scene(data, file="<friction>"), device)
    largest = 0.0
    for _ in range(20):
        sim.step_frame()
        points = sim.positions()
        assert np.isfinite(points).all()
        largest = max(largest, float(np.abs(points).max()))
    assert largest < 1.0, largest
