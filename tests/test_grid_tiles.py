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
from warp_verlet.kernels.relax import relax_colour

ROWS, COLS = 37, 45  # several tiles each way, neither a multiple of the tile


def sheet(simulation: dict | None = None, **cloth):
    spec = {"resolution": [ROWS, COLS], "size": [1.0, 1.2], "pins": ["top-left", "top-right"], **cloth}
    return make_scene({"substeps": 2, "iterations": 4, **(simulation or {})}, **spec)


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


@pytest.mark.parametrize("tile, cloth, precision", [
    (4, {}, "float32"),  # the smallest tile
    (16, {}, "float32"),  # the default
    (16, {}, "float64"),  # float64 positions, held as float64 in the shared region
    (16, {"particle_masses": [[4, 6, 0.05], [20, 17, 0.001]], "pins": ["top-left", [30, 40]]},
     "float32"),  # weights read
    (8, {"sticks": ["structural", "bend"], "pins": ["top-edge"]},
     "float32"),  # no shear; more pins than the kernel checks
])
def test_a_tiled_sweep_is_the_sequential_sweep_in_tile_order_bit_for_bit(tile, cloth, precision, monkeypatch):
    monkeypatch.setattr(sticks, "GRID_TILE", tile)
    scene = sheet({"precision": precision}, **cloth)
    tiled = Simulator(scene, "cpu", threads=1, sticks="tiled")
    explicit = Simulator(scene, "cpu", threads=1, sticks="explicit")
    assert "grid tiles" in tiled.constraint_sets and "grid sticks" not in tiled.constraint_sets
    vector = wp.vec3d if precision == "float64" else wp.vec3
    start = perturbed(tiled).astype(tiled.model.host_position_dtype)

    tiled.state.set_positions(start)
    bound = GridTiles().bind(tiled.model, tiled.state, tiled.solver)
    assert len(bound.phases) == 4  # one launch per tile colour
    run_phases(bound)

    m, ends, order = sequential_tile_order(explicit, tile)
    x = wp.array(start, dtype=vector, device="cpu")
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
@pytest.mark.parametrize("tile, cloth, precision", [
    (8, {}, "float32"), (16, {}, "float32"),
    (16, {"sticks": ["structural", "shear", "bend"], "compliance": {"bend": 0.05}}, "float32"), (16, {}, "float64")],
                         ids=["8", "16", "16-soft-bend", "16-float64"])
def test_a_tiled_sweep_on_cuda_is_the_sequential_sweep(tile, cloth, precision, monkeypatch):
    """A GPU block runs a colour's sticks at once and relies on one barrier after each colour (and after the
    staging) for the next colour to read them: a missing barrier reads positions a correction (about the 1 cm
    perturbation) old. The substep must equal the CPU's, which runs the sweep's projections one after another,
    to float32 rounding (1e-6 m, against sticks of about 3 cm), whatever the compiler contracts into fused
    multiply-adds."""
    monkeypatch.setattr(sticks, "GRID_TILE", tile)
    scene = make_scene({"substeps": 1, "iterations": 1, "precision": precision}, resolution=[ROWS, COLS],
                       size=[1.0, 1.2], pins=["top-left", "top-right"], **cloth)
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
    ({"tear_threshold": 1.5}, {}, "can tear"),
])
def test_tiled_sweeps_refuse_what_they_do_not_cover(cloth, simulation, words):
    spec = {"resolution": [8, 8], "pins": ["top-left"], **cloth}
    scene = make_scene(simulation, **spec)
    with pytest.raises(ArgumentError, match=words):
        Simulator(scene, "cpu", sticks="tiled")
