"""The multilevel pass: its hierarchy, what one pass does to a stretched and to a folded cloth, its place in
a substep, and the scene keys."""

import numpy as np
import pytest
import warp as wp

from warp_verlet.errors import SceneError
from warp_verlet.kernels.multilevel import limit_coarse_colour, prolongate
from warp_verlet.constraints.multilevel import grid_hierarchy, hierarchy_counts, level_axes
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator


def hanging(n: int, substeps: int = 4, iterations: int = 8, multilevel: bool = False, tethers: bool = False,
            **simulation) -> dict:
    return {"simulation": {"substeps": substeps, "iterations": iterations, "damping": 0.24,
                           "multilevel": multilevel, **simulation},
            "cloth": [{"name": "cloth", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 1.0, 0.0],
                       "mass": 0.2, "pins": ["top-left", "top-right"], "sticks": ["structural", "shear", "bend"],
                       "tethers": tethers}]}


@pytest.mark.parametrize("rows, cols", [(2, 2), (5, 9), (64, 64), (65, 65), (1, 17), (33, 2)])
def test_each_level_splits_the_finer_one_into_kept_particles_and_children(rows, cols):
    positions = np.zeros((rows * cols, 3), np.float32)
    positions[:, 0] = np.tile(np.arange(cols), rows) * 0.1
    positions[:, 1] = -np.repeat(np.arange(rows), cols) * 0.1
    levels = grid_hierarchy(rows, cols, positions)[::-1]  # finest first
    axes = level_axes(rows, cols)
    fine = set(range(rows * cols))
    for level, (r, c) in zip(levels, axes):
        coarse = {int(i) * cols + int(j) for i in r for j in c}
        assert {0, cols - 1, (rows - 1) * cols, rows * cols - 1} <= coarse  # the corners are on every level
        assert set(level.child.tolist()) == fine - coarse and len(level.child) == len(fine - coarse)
        assert set(level.parents.ravel().tolist()) <= coarse
        np.testing.assert_allclose(level.weights.sum(axis=1), 1.0, rtol=1e-6)
        # Interpolation reproduces a linear field exactly: each child sits at its parents' weighted position.
        np.testing.assert_allclose(np.einsum("ck,ckd->cd", level.weights, positions[level.parents]),
                                   positions[level.child], atol=1e-6)
        # A coarse stick's limit is the rest distance of its ends; a colour never touches a particle twice.
        np.testing.assert_allclose(level.limit, np.linalg.norm(positions[level.ends[:, 1]] - positions[level.ends[:, 0]],
                                                                axis=1), rtol=1e-6)
        for first, count in level.colour_ranges:
            ends = level.ends[first:first + count].ravel()
            assert len(set(ends.tolist())) == ends.size
        fine = coarse
    assert hierarchy_counts(rows, cols) == (sum(len(l.ends) for l in levels), sum(len(l.child) for l in levels))


def one_pass(sim: Simulator) -> None:
    """One multilevel pass from the current positions, as a substep runs it (x_inertial = x on entry)."""
    m, state = sim.model, sim.state
    # On the simulator's device: a launch left to the default device (CUDA on a GPU machine) would run on the CPU
    # arrays' addresses there, an illegal memory access that breaks every later CUDA test of the session.
    with wp.ScopedDevice(sim.device):
        wp.copy(state.particle_q_inertial, state.particle_q)
        for level in m.constraints["multilevel"].levels:
            for first, count in level.colour_ranges:
                wp.launch(limit_coarse_colour, count,
                          inputs=[state.particle_q, m.inv_mass, level.ends, level.limit, first])
            wp.launch(prolongate, level.child.shape[0], inputs=[state.particle_q, state.particle_q_inertial,
                                                                m.inv_mass, level.child, level.parents, level.weights])


@pytest.mark.parametrize("precision, fine_order", [("float32", None), ("float64", None),
                                                    ("float32", "bend, shear, structural")])
def test_one_pass_takes_out_a_uniform_stretch_of_any_size(precision, fine_order, monkeypatch):
    """A cloth pinned at its top corners and stretched 30% downwards: the error is one smooth mode, which
    the coarsest level removes and the interpolation carries to every particle, to the rounding of the
    float32 rest layout (6e-8 m on 1.5 cm sticks: 2e-5) in either precision, whatever order the fine sweep
    takes its families in (the coarse levels keep structural first)."""
    if fine_order is not None:
        from bench.colour_order import ORDERS
        from warp_verlet.geometry import topology

        monkeypatch.setattr(topology, "SWEEP_ORDER", ORDERS[fine_order])
    sim = Simulator(parse_scene(hanging(65, multilevel=True, precision=precision), file="<ml>"), "cpu",
                    use_graph=False)
    rest = sim.model.rest_positions
    stretched = rest.copy()
    stretched[:, 1] = 1.0 - (1.0 - rest[:, 1]) * 1.3
    sim.state.set_positions(stretched)
    assert sim.stretch().max == pytest.approx(0.3, rel=1e-4)
    one_pass(sim)
    after = sim.stretch(sim.state.particle_q.numpy().astype(np.float64))
    assert after.max < 2e-5
    assert np.array_equal(sim.positions()[sim.model.host_inv_mass == 0], rest[sim.model.host_inv_mass == 0])


def test_a_pass_leaves_a_cloth_that_is_nowhere_stretched_alone():
    """Coarse sticks are limits: a cloth compressed to 70% (as a fold or a drape brings points closer) is
    not touched, bit for bit."""
    sim = Simulator(parse_scene(hanging(33, multilevel=True), file="<ml>"), "cpu", use_graph=False)
    rest = sim.model.rest_positions
    folded = rest.copy()
    folded[:, 0] = rest[:, 0] * 0.95
    folded[:, 1] = 1.0 - (1.0 - rest[:, 1]) * 0.7
    folded[:, 2] = 0.002 * np.sin(40.0 * rest[:, 1])  # rippled out of plane by less than it was shortened
    sim.state.set_positions(folded)
    before = sim.positions().copy()
    one_pass(sim)
    assert np.array_equal(sim.positions(), before)


def test_multilevel_carries_the_pins_to_a_hanging_cloth_that_plain_sweeps_leave_stretched():
    """64^2 hanging cloth, 4 substeps x 8 sweeps, 1 s: plain sweeps leave it a rubber sheet (5% RMS, 120%
    max); the pass brings it under 0.2% RMS and 1% max (measured 0.11% / 0.47%)."""
    def run(multilevel):
        sim = Simulator(parse_scene(hanging(64, multilevel=multilevel), file="<ml>"), "cpu", threads=1)
        for _ in range(60):
            sim.step_frame()
        stretch = sim.stretch()
        sim.close()
        return stretch
    plain, multilevel = run(False), run(True)
    assert plain.rms > 0.02 and plain.max > 0.5
    assert multilevel.rms < 0.002 and multilevel.max < 0.01


def test_the_pass_runs_once_per_substep_before_the_sweeps(launches):
    sim = Simulator(parse_scene(hanging(17, substeps=1, iterations=2, multilevel=True, multilevel_sweeps=2),
                                file="<ml>"), "cpu", use_graph=False, threads=1)
    issued = launches.of(sim.step)
    levels = sim.model.constraints["multilevel"].levels
    per_level = [2 * len(level.colour_ranges) * ["limit_coarse_colour"] + ["prolongate"] for level in levels]
    expected = ["verlet_start", "verlet_step"] + [name for level in per_level for name in level]
    expected += 2 * ["relax_colour"] * len(sim.model.colour_ranges)
    assert issued == expected
    assert len(sim.model.constraints["multilevel"].levels) == 4  # 17 -> 9 -> 5 -> 3 -> 2 particles a side


def test_no_multilevel_no_levels_and_no_launches(launches):
    sim = Simulator(parse_scene(hanging(17, substeps=1), file="<ml>"), "cpu", use_graph=False, threads=1)
    assert "multilevel" not in sim.model.constraints
    assert not {"limit_coarse_colour", "prolongate"} & set(launches.of(sim.step))


@pytest.mark.parametrize("cloth, key, words", [
    ({"tear_threshold": 1.5}, "simulation.multilevel", "can tear"),
    ({"compliance": {"structural": 1e-4}}, "simulation.multilevel", "soft structural"),
])
def test_multilevel_refuses_what_its_limits_would_break(cloth, key, words):
    data = hanging(9, multilevel=True)
    data["cloth"][0].update(cloth)
    with pytest.raises(SceneError) as err:
        parse_scene(data, file="scene.toml")
    assert key in str(err.value) and words in str(err.value) and "scene.toml" in str(err.value)


def test_multilevel_and_the_global_correction_are_refused_together():
    """Each carries a correction across the whole grid, and together they fed each other until a free cloth at rest
    (no gravity, nothing to correct) moved and diverged within a frame at 32 substeps: one clear error instead."""
    with pytest.raises(SceneError) as err:
        parse_scene(hanging(9, multilevel=True, global_iterations=1), file="scene.toml")
    assert "simulation.multilevel" in str(err.value) and "global_iterations" in str(err.value)
    parse_scene(hanging(9, multilevel=True), file="scene.toml")  # each alone is taken
    parse_scene(hanging(9, global_iterations=1), file="scene.toml")


def test_multilevel_keys_are_checked():
    with pytest.raises(SceneError, match="multilevel_sweeps"):
        parse_scene(hanging(9, multilevel=True, multilevel_sweeps=0), file="s.toml")
    with pytest.raises(SceneError, match="multilevel"):
        parse_scene(hanging(9, multilevel="yes"), file="s.toml")
