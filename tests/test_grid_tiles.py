"""Tiled sweeps over implicit grid sticks (kernels/grid_tiles.py, constraints.sticks.GridTiles): one tiled sweep
is exactly the sequential Gauss-Seidel sweep over the same sticks in the tiles' order (tile colour, tile, stick
colour, cell), bit for bit on the CPU; it converges as the colour-by-colour sweep does; and the form is refused
where it does not apply."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.constraints.sticks import GridTiles
from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import ArgumentError
from warp_verlet.constraints import sticks
from warp_verlet.core import stages
from warp_verlet.input.scene import parse_scene
from warp_verlet.kernels.grid_tiles import NO_STEP, STEP, STEP_TETHERED
from warp_verlet.kernels.relax import relax_colour

ROWS, COLS = 37, 45  # several tiles each way, neither a multiple of the tile


def sheet(**cloth):
    spec = {"resolution": [ROWS, COLS], "size": [1.0, 1.2], "pins": ["top-left", "top-right"], **cloth}
    return make_scene({"substeps": 2, "iterations": 4}, **spec)


def tile_order(ends: np.ndarray, colour_of: np.ndarray, cols: int, tile: int) -> np.ndarray:
    """The order in which the tiled sweep projects the sticks: by tile colour (tile row parity, then column
    parity), tile (row-major among that colour's tiles), stick colour, then cell (row-major in the tile)."""
    r, c = np.divmod(ends[:, 0], cols)  # a stick's first end is its anchor
    tr, tc = r // tile, c // tile
    cell = (r % tile) * tile + c % tile
    return np.lexsort((cell, colour_of, tc // 2, tr // 2, tc % 2, tr % 2))


def perturbed(sim: Simulator, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = sim.model.rest_positions + rng.normal(0.0, 0.01, sim.model.rest_positions.shape)
    return x.astype(np.float32)


def run_phases(bound) -> None:
    """One tiled sweep: every tile colour's launch, in order."""
    for phase in bound.phases:
        for task in phase:
            task.run()


def sequential_tile_order(explicit: Simulator, tile: int):
    """The stick-array model, its sticks' ends, and its sticks in the tiled sweep's order (``tile_order``)."""
    m = explicit.model
    ends = m.stick_ends.numpy()
    colour_of = np.repeat(np.arange(len(m.colour_ranges)), [n for _, n in m.colour_ranges])
    return m, ends, tile_order(ends, colour_of, COLS, tile)


@pytest.mark.parametrize("tile, cloth", [
    (4, {}),  # the smallest tile
    (16, {}),  # the default
    (16, {"particle_masses": [[4, 6, 0.05], [20, 17, 0.001]], "pins": ["top-left", [30, 40]]}),  # weights read
    (8, {"sticks": ["structural", "bend"], "pins": ["top-edge"]}),  # no shear; more pins than the kernel checks
])
def test_a_tiled_sweep_is_the_sequential_sweep_in_tile_order_bit_for_bit(tile, cloth, monkeypatch):
    monkeypatch.setattr(sticks, "GRID_TILE", tile)
    scene = sheet(**cloth)
    tiled = Simulator(scene, "cpu", threads=1, sticks="tiled")
    explicit = Simulator(scene, "cpu", threads=1, sticks="explicit")
    assert "grid tiles" in tiled.constraint_sets and "grid sticks" not in tiled.constraint_sets
    start = perturbed(tiled)

    tiled.state.set_positions(start)
    bound = GridTiles().bind(tiled.model, tiled.state, tiled.solver)
    assert len(bound.phases) == 4  # one launch per tile colour
    run_phases(bound)

    m, ends, order = sequential_tile_order(explicit, tile)
    x = wp.array(start, dtype=wp.vec3, device="cpu")
    wp.launch(relax_colour, len(order), device="cpu",
              inputs=[x, m.inv_mass, wp.array(ends[order], dtype=wp.vec2i, device="cpu"),
                      wp.array(m.stick_rest.numpy()[order], dtype=float, device="cpu"),
                      wp.array(m.stick_weight.numpy()[order], dtype=float, device="cpu"), 0, 1])
    moved = np.abs(x.numpy() - start).max()
    assert moved > 1e-4  # the sweep did something
    np.testing.assert_array_equal(tiled.state.positions(), x.numpy())


@pytest.mark.parametrize("tile", [8, 16])
def test_a_soft_tiled_sweep_is_the_sequential_xpbd_sweep_in_tile_order_bit_for_bit(tile, monkeypatch):
    """Soft families (XPBD): the tiled sweep projects each soft stick with its compliance and the tension it has
    gathered over the substep's sweeps, kept where the launch per colour keeps it: two sweeps of a substep are
    the sequential XPBD sweeps in tile order, positions and tensions bit for bit."""
    from warp_verlet.kernels.relax import relax_colour_compliant

    monkeypatch.setattr(sticks, "GRID_TILE", tile)
    families = ["structural", "shear", "bend"]
    scene = sheet(sticks=families, compliance={"shear": 0.01, "bend": 0.05})
    tiled = Simulator(scene, "cpu", threads=1, sticks="tiled")
    explicit = Simulator(scene, "cpu", threads=1, sticks="explicit")
    start = perturbed(tiled)
    dt = 1.0 / 240.0

    tiled.state.set_positions(start)
    bound = GridTiles().bind(tiled.model, tiled.state, tiled.solver)
    bound.run(tiled.state, dt)  # the substep's 1 / dt^2, the tensions zeroed
    for _ in range(2):
        run_phases(bound)

    m, ends, order = sequential_tile_order(explicit, tile)
    compliance = m.stick_compliance.numpy()[order]
    assert 0 < np.count_nonzero(compliance) < len(order)  # soft shear and bend sticks among rigid ones
    x = wp.array(start, dtype=wp.vec3, device="cpu")
    tension = wp.zeros(len(order), dtype=float, device="cpu")
    inputs = [x, m.inv_mass, wp.array(ends[order], dtype=wp.vec2i, device="cpu"),
              wp.array(m.stick_rest.numpy()[order], dtype=float, device="cpu"),
              wp.array(m.stick_weight.numpy()[order], dtype=float, device="cpu"),
              wp.array(compliance, dtype=float, device="cpu"), 1.0 / (dt * dt), 0, 1]
    for _ in range(2):
        wp.launch(relax_colour_compliant, len(order), device="cpu", inputs=inputs, outputs=[tension])
    rigid = Simulator(sheet(sticks=families), "cpu", threads=1, sticks="tiled")
    rigid.state.set_positions(start)
    for _ in range(2):
        for phase in GridTiles().bind(rigid.model, rigid.state, rigid.solver).phases:
            for task in phase:
                task.run()
    assert np.abs(rigid.state.positions() - x.numpy()).max() > 1e-6  # the compliance changed the moves
    np.testing.assert_array_equal(tiled.state.positions(), x.numpy())

    # Each soft stick's tension, where the launch per colour keeps it: its colour's first tension plus its
    # place in the colour (the explicit arrays hold a colour's sticks in the order of its anchors).
    grid = tiled.model.grid
    sequential = np.empty(len(order), np.float32)
    sequential[order] = tension.numpy()
    kept = tiled.solver.scratch("grid_tension", grid.soft_sticks, float).numpy()
    for colour, (first, count) in zip(grid.colours, m.colour_ranges):
        if colour.compliance > 0.0:
            np.testing.assert_array_equal(kept[colour.tension_first:colour.tension_first + count],
                                          sequential[first:first + count])


@pytest.mark.parametrize("threads", [2, 3])
def test_a_cpu_thread_team_runs_the_tiles_on_one_thread_and_changes_no_bit(threads):
    """With a CPU thread team (the tethers' pass split between the threads), one thread runs each tile colour, whose
    shared memory is one buffer for the process on the CPU: the positions are the one thread's, bit for bit."""
    scene = sheet(orientation="horizontal", pins=["top-left", "top-right"])
    runs = []
    for n in (1, threads):
        sim = Simulator(scene, "cpu", threads=n, sticks="tiled")
        for _ in range(5):
            sim.step_frame()
        runs.append(sim.positions())
    assert np.abs(runs[0] - sim.model.rest_positions).max() > 0.01  # it fell
    np.testing.assert_array_equal(runs[1], runs[0])


def one_tiled_substep(scene, device: str, start: np.ndarray) -> np.ndarray:
    """Positions after one frame of one substep of one sweep from ``start`` at rest: a Verlet step, then one
    tiled sweep, through the simulator as a run steps."""
    sim = Simulator(scene, device, threads=1 if device == "cpu" else None, sticks="tiled")
    sim.state.set_positions(start)
    sim.step_frame()
    return sim.positions()


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
@pytest.mark.parametrize("tile, cloth", [
    (8, {}), (16, {}), (16, {"sticks": ["structural", "shear", "bend"], "compliance": {"bend": 0.05}})],
                         ids=["8", "16", "16-soft-bend"])
def test_a_tiled_sweep_on_cuda_is_the_sequential_sweep(tile, cloth, monkeypatch):
    """A GPU block runs a colour's sticks at once and relies on one barrier after each colour (and after the
    staging) for the next colour to read them: a missing barrier reads positions a correction (about the 1 cm
    perturbation) old. The substep must equal the CPU's, which runs the sweep's projections one after another,
    to float32 rounding (1e-6 m, against sticks of about 3 cm), whatever the compiler contracts into fused
    multiply-adds."""
    monkeypatch.setattr(sticks, "GRID_TILE", tile)
    scene = make_scene({"substeps": 1, "iterations": 1}, resolution=[ROWS, COLS], size=[1.0, 1.2],
                       pins=["top-left", "top-right"], **cloth)
    start = perturbed(Simulator(scene, "cpu", threads=1, sticks="tiled"))
    sequential = one_tiled_substep(scene, "cpu", start)
    on_gpu = one_tiled_substep(scene, "cuda", start)
    assert np.abs(sequential - start).max() > 1e-3  # the sweep did something
    np.testing.assert_allclose(on_gpu, sequential, rtol=0, atol=1e-6)


def test_tiled_sweeps_converge_as_the_coloured_sweeps_do(device):
    """A sheet falling from two corners, after 20 frames: tiled and colour-by-colour sweeps are two orders of the
    same projections, so both leave it as stretched (RMS within 20% of each other) and in the same place (within
    1% of how far it fell)."""
    scene = sheet(orientation="horizontal")  # pinned at two corners, it falls and swings
    runs = {}
    for form in ("explicit", "tiled"):
        sim = Simulator(scene, device, sticks=form)
        for _ in range(20):
            sim.step_frame()
        runs[form] = (sim.positions(), sim.stretch())
    (x_e, s_e), (x_t, s_t) = runs["explicit"], runs["tiled"]
    moved = np.abs(x_e - sim.model.rest_positions).max()
    assert moved > 0.1  # it fell and swung
    assert abs(s_t.rms - s_e.rms) <= 0.2 * s_e.rms
    assert np.abs(x_t - x_e).max() < 0.01 * moved


@pytest.mark.parametrize("cloth, simulation, words", [
    ({}, {"precision": "float64"}, "float32"),
    ({"tear_threshold": 1.5}, {}, "can tear"),
])
def test_tiled_sweeps_refuse_what_they_do_not_cover(cloth, simulation, words):
    spec = {"resolution": [8, 8], "pins": ["top-left"], **cloth}
    scene = make_scene(simulation, **spec)
    with pytest.raises(ArgumentError, match=words):
        Simulator(scene, "cpu", sticks="tiled")


def frames_with_and_without_the_step_in_the_sweep(scene, device: str, frames: int = 3):
    """The positions after ``frames`` frames, the last sweep of each substep taking the next substep's Verlet step
    and with every step its own launch, the rest positions, and the way the step was taken (stages.step_in_tiles)."""
    out = []
    for step_in_sweep in (True, False):
        sim = Simulator(scene, device, threads=1, sticks="tiled")
        mode = stages.step_in_tiles(sim.solver)
        sim.solver.steps_in_sweep = step_in_sweep and sim.solver.steps_in_sweep
        for _ in range(frames):
            sim.step_frame()
        out.append(sim.positions())
        rest = sim.model.rest_positions
        sim.close()
    return out[0], out[1], rest, mode


@pytest.mark.parametrize("simulation, cloth, tethers_in_step, mode", [
    ({"substeps": 4, "iterations": 1}, {"tethers": True}, True, STEP_TETHERED),
    ({"substeps": 3, "iterations": 2}, {"tethers": True}, True, STEP_TETHERED),
    ({"substeps": 3, "iterations": 2}, {"tethers": True}, False, STEP),  # the tether pass a launch of its own
    ({"substeps": 4, "iterations": 1}, {"tethers": False}, True, STEP),
    ({"substeps": 2, "iterations": 3}, {"tethers": True, "compliance": {"bend": 0.5}}, True, STEP_TETHERED),
])
def test_the_step_taken_in_the_tiled_sweep_is_the_step_launched_bit_for_bit(device, simulation, cloth,
                                                                             tethers_in_step, mode, monkeypatch):
    """A hanging sheet, the step taken by each cell's last writer in a substep's last sweep: the same positions,
    bit for bit, as with the step a launch of its own, tethered or not, rigid or soft, one sweep or several."""
    monkeypatch.setitem(stages.FOLD_TETHERS_INTO_INTEGRATE, "cuda" if device == "cuda" else "cpu", tethers_in_step)
    scene = make_scene({**simulation, "fps": 30}, resolution=[ROWS, COLS], size=[1.0, 1.2],
                       pins=["top-left", "top-right"], orientation="horizontal",
                       sticks=["structural", "shear", "bend"], **cloth)
    stepped_in_sweep, stepped_apart, rest, taken = frames_with_and_without_the_step_in_the_sweep(scene, device)
    assert taken == mode
    assert np.abs(stepped_apart - rest).max() > 0.03  # it fell (0.049 m in 0.1 s)
    np.testing.assert_array_equal(stepped_in_sweep, stepped_apart)


@pytest.mark.parametrize("simulation, cloth", [
    ({}, {"tethers": True, "pins": ["top-left"]}),  # the reference: the step is taken in the sweep
    ({}, {"particle_masses": [[4, 6, 0.05]]}),  # tethered, but the sweep has no pin list to find a tether's row
    ({"air": {"velocity": [3.0, 0.0, 0.0]}}, {}),  # the air's forces enter the step
    ({"global_iterations": 2}, {}),  # the global correction runs between the step and the sweeps
])
def test_the_step_stays_a_launch_where_a_substep_holds_more(simulation, cloth, monkeypatch):
    """What may run between two substeps' sweeps keeps the step a launch of its own: a collider's clamp, the
    air, the global correction, a tethered cloth whose sweep has no pin list; and a CPU thread team."""
    monkeypatch.setitem(stages.FOLD_TETHERS_INTO_INTEGRATE, "cpu", True)  # tethered as on a GPU
    base = {"resolution": [ROWS, COLS], "pins": ["top-left", "top-right"], **cloth}
    scene = make_scene({"substeps": 2, **simulation}, **base)
    sim = Simulator(scene, "cpu", threads=1, sticks="tiled")
    expected = STEP_TETHERED if not simulation and "particle_masses" not in cloth else NO_STEP
    assert stages.step_in_tiles(sim.solver) == expected
    if expected != NO_STEP:
        assert stages.step_in_tiles(Simulator(scene, "cpu", threads=2, sticks="tiled").solver) == NO_STEP
    with_ground = parse_scene({"simulation": {"substeps": 2}, "cloth": [{**base, "size": [1.0, 1.0]}],
                               "collider": [{"type": "plane", "point": [0.0, -2.0, 0.0]}]}, file="<test>")
    assert stages.step_in_tiles(Simulator(with_ground, "cpu", threads=1, sticks="tiled").solver) == NO_STEP
