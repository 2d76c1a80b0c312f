"""Step orchestration: the accumulator, determinism, CPU/CUDA parity, and leaving out what a scene does not use."""

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.core.simulator import Simulator

HANGING = dict(resolution=[10, 12], pins=["top-left", "top-right"], sticks=["structural", "shear", "bend"])


def test_advance_runs_whole_substeps_and_returns_alpha():
    sim = Simulator(make_scene({"fps": 60, "substeps": 4}, **HANGING), "cpu")  # dt = 1/240 s
    alpha = sim.advance(1 / 60)
    assert sim.steps == 4 and alpha == pytest.approx(0.0, abs=1e-6)
    alpha = sim.advance(1.5 / 240)
    assert sim.steps == 5 and alpha == pytest.approx(0.5, abs=1e-6)
    alpha = sim.advance(0.75 / 240)  # the banked half step plus 0.75 pays for one more, 0.25 left
    assert sim.steps == 6 and alpha == pytest.approx(0.25, abs=1e-6)


def test_advance_clamps_a_stall_so_it_cannot_spiral():
    # A 5 s stall with max_frame_time = 0.1 s runs at most 0.1 s of substeps (24 of 1/240 s), not 1200.
    sim = Simulator(make_scene({"fps": 60, "substeps": 4, "max_frame_time": 0.1}, **HANGING), "cpu")
    alpha = sim.advance(5.0)
    assert sim.steps == 24 and 0.0 <= alpha < 1.0
    sim.advance(1 / 60)
    assert sim.steps == 28  # the stall left no debt behind


def test_render_positions_interpolate_between_the_last_two_substeps():
    sim = Simulator(make_scene({"fps": 60, "substeps": 4}, **HANGING), "cpu")
    sim.advance(1 / 60)
    previous, current = sim.previous_positions(), sim.positions()
    np.testing.assert_allclose(sim.render_positions(0.0), previous, atol=1e-6)
    np.testing.assert_allclose(sim.render_positions(1.0), current, atol=1e-6)
    np.testing.assert_allclose(sim.render_positions(0.5), 0.5 * (previous + current), atol=1e-6)


@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_same_scene_same_device_is_bit_identical(device, solver):
    def run():
        sim = Simulator(make_scene({"relaxation": solver, "wind": [2.0, 0.0, 1.0], "damping": 2.4}, **HANGING), device)
        for _ in range(15):
            sim.step_frame()
        return sim.positions()

    assert np.array_equal(run(), run())


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_cpu_and_cuda_agree(solver):
    # Same kernels, same launch order; only the compilers' floating-point contraction differs. Tolerance:
    # 1e-5 of the cloth size after 30 frames of a hanging cloth.
    def run(device):
        sim = Simulator(make_scene({"relaxation": solver}, **HANGING), device)
        for _ in range(30):
            sim.step_frame()
        return sim.positions()

    assert np.abs(run("cpu") - run("cuda")).max() < 1e-5


def one_step(sim, launches) -> list[str]:
    """What one substep of ``sim`` (after the exact start) actually issued."""
    sim.step()  # the first step also runs verlet_start, which sets x_prev
    return launches.of(sim.step)


def test_a_step_launches_only_what_the_scene_uses(launches):
    k = 5
    # Structural + shear sticks of an 8 x 8 grid: 4 directions x 2 parities = 8 colours (no bend family: no
    # bend colours). No pins (so no tethers), no soft sticks, no colliders, no tearing: a substep is the
    # Verlet step and K sweeps of one launch per colour, and nothing else.
    structural_shear = Simulator(make_scene({"iterations": k}, resolution=[8, 8], sticks=["structural", "shear"]),
                                 "cpu", use_graph=False)
    assert structural_shear.model.colour_count == 8
    assert launches.of(structural_shear.step) == ["verlet_start", "verlet_step"] + ["relax_colour"] * (8 * k)
    assert launches.of(structural_shear.step) == ["verlet_step"] + ["relax_colour"] * (8 * k)

    # All three families: 12 colours.
    everything = Simulator(make_scene({"iterations": k}, resolution=[8, 8], sticks=["structural", "shear", "bend"]),
                           "cpu", use_graph=False)
    assert everything.model.colour_count == 12
    assert one_step(everything, launches) == ["verlet_step"] + ["relax_colour"] * (12 * k)

    # Soft bend sticks: the XPBD kernel for every colour (one stick set, one kernel), after zeroing the tensions.
    soft = Simulator(make_scene({"iterations": k}, resolution=[8, 8], sticks=["structural", "shear", "bend"],
                                compliance={"bend": 1e-3}), "cpu", use_graph=False)
    assert one_step(soft, launches) == ["verlet_step", "zero"] + ["relax_colour_compliant"] * (12 * k)

    # Jacobi: a gather into the scratch buffer and a copy back per sweep.
    jacobi = Simulator(make_scene({"iterations": k, "relaxation": "jacobi"}, resolution=[8, 8]), "cpu", use_graph=False)
    assert one_step(jacobi, launches) == ["verlet_step"] + ["relax_jacobi", "copy"] * k

    # A pinned cloth that cannot tear gets tethers: one launch per sweep, before the sticks' 4 colours.
    pinned = make_scene({"iterations": k}, resolution=[8, 8], pins=["top-left", "top-right"])
    assert pinned.cloths[0].uses_tethers
    tethered = Simulator(pinned, "cpu", use_graph=False)
    assert tethered.model.colour_count == 4
    assert one_step(tethered, launches) == ["verlet_step"] + (["pull_tethers"] + ["relax_colour"] * 4) * k
    untethered = Simulator(make_scene({"iterations": k}, resolution=[8, 8], pins=["top-left", "top-right"],
                                      tethers=False), "cpu", use_graph=False)
    assert one_step(untethered, launches) == ["verlet_step"] + ["relax_colour"] * (4 * k)

    # The stages a substep runs (and the throughput benchmark times): no collide or tear stage here.
    assert [name for name, _ in jacobi.stages()] == ["integrate", "relax"]
    unsolved = Simulator(make_scene({"iterations": 0}, resolution=[8, 8]), "cpu", use_graph=False)
    assert [name for name, _ in unsolved.stages()] == ["integrate"]
    assert one_step(unsolved, launches) == ["verlet_step"]
    # Every particle pinned: nothing to integrate, only the sticks' sweeps (which move nothing).
    frozen = Simulator(make_scene({"iterations": 2}, resolution=[1, 3], size=[0.0, 1.0], pins=[0, 1, 2]),
                       "cpu", use_graph=False)
    assert [name for name, _ in frozen.stages()] == ["relax"]
    assert one_step(frozen, launches) == ["relax_colour"] * (frozen.model.colour_count * 2)


def test_arrays_are_allocated_only_for_the_solver_in_use():
    coloured = Simulator(make_scene(resolution=[8, 8]), "cpu")
    coloured.step()
    assert coloured.solver._scratch == {} and not hasattr(coloured.model, "neighbour")
    jacobi = Simulator(make_scene({"relaxation": "jacobi"}, resolution=[8, 8]), "cpu")
    jacobi.step()
    assert set(jacobi.solver._scratch) == {"jacobi_positions"} and not hasattr(jacobi.model, "stick_ends")
    soft = Simulator(make_scene(resolution=[8, 8], compliance={"structural": 1e-4}), "cpu")
    soft.step()
    assert set(soft.solver._scratch) == {"stick_tension"} and soft.model.stick_compliance is not None
    assert coloured.model.stick_compliance is None  # rigid sticks carry no compliance
    # A structural-only cloth carries only structural sticks: 2 * 8 * 7 of them.
    assert coloured.model.stick_count == 2 * 8 * 7


def test_multiple_cloths_share_launches_and_stay_independent():
    from warp_verlet.input.scene import parse_scene

    cloth = {"resolution": [6, 6], "size": [1.0, 1.0], "pins": ["top-edge"], "sticks": ["structural", "shear", "bend"]}
    two = parse_scene({"cloth": [dict(cloth, name="a"), dict(cloth, name="b", origin=[3.0, 0.0, 0.0])]})
    one = parse_scene({"cloth": [dict(cloth, name="a")]})
    sim2, sim1 = Simulator(two, "cpu"), Simulator(one, "cpu")
    assert sim2.model.colour_count == sim1.model.colour_count == 12  # colours merge across cloths
    for _ in range(10):
        sim2.step_frame()
        sim1.step_frame()
    a, b = sim2.model.split(sim2.positions())
    np.testing.assert_array_equal(a, sim1.positions())  # cloth a does not feel cloth b
    np.testing.assert_allclose(b - [3.0, 0.0, 0.0], a, atol=1e-5)  # same cloth, shifted


def test_graph_colouring_gives_the_same_physics_as_the_grid_fast_path():
    # Different colour orders give different Gauss-Seidel sweeps, but both must converge to the same
    # hanging shape: after 2 s the two cloths agree to 1% of their size.
    scene = make_scene({"iterations": 16, "damping": 4.85}, **HANGING)  # the old drag 0.98 at 240 substeps/s
    grid, graph = Simulator(scene, "cpu", colouring="grid"), Simulator(scene, "cpu", colouring="graph")
    for _ in range(120):
        grid.step_frame()
        graph.step_frame()
    assert np.abs(grid.positions() - graph.positions()).max() < 0.01


def test_bad_device_is_one_clear_error():
    from warp_verlet.errors import WarpVerletError

    with pytest.raises(WarpVerletError, match="device must be"):
        Simulator(make_scene(), "tpu")
    if not wp.is_cuda_available():
        with pytest.raises(WarpVerletError, match="no CUDA device"):
            Simulator(make_scene(), "cuda:0")


def test_divergence_check_finds_the_lowest_bad_particle(device):
    sim = Simulator(make_scene({"position_bound": 10.0}, resolution=[4, 4]), device)
    assert sim.diverged_particle() is None
    x = sim.positions()
    x[12] = (np.inf, 0.0, 0.0)
    x[9] = (0.0, np.nan, 0.0)
    x[5] = (0.0, 0.0, -10.5)
    sim.state.set_positions(x)
    assert sim.diverged_particle() == 5  # beyond the bound
    x[5] = (0.0, 0.0, -10.0)  # on the bound is still fine
    sim.state.set_positions(x)
    assert sim.diverged_particle() == 9  # NaN
    x[9] = 0.0
    sim.state.set_positions(x)
    assert sim.diverged_particle() == 12  # inf


@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_device_readbacks_match_the_host(device, solver):
    """render_points and device_stretch (a viewer's readbacks) give what the host computes from every position:
    the same interpolated points, and the same stretch over the untorn structural sticks."""
    scene = make_scene({"relaxation": solver, "iterations": 2}, resolution=[20, 20], pins=["top-left", "top-right"],
                       tear_threshold=1.05)
    sim = Simulator(scene, device)
    for _ in range(40):
        sim.step_frame()
    assert sim.torn_count() > 0  # so that skipping torn sticks is tested
    host, reduced = sim.stretch(), sim.device_stretch()
    assert reduced.max == pytest.approx(host.max, rel=1e-6)  # the max comes back as float32
    assert reduced.rms == pytest.approx(host.rms, rel=1e-12)  # float64 sums in another order
    chosen = np.arange(0, 400, 7)
    np.testing.assert_allclose(sim.render_points(chosen, 0.3), sim.render_positions(0.3)[chosen], atol=1e-6)
    untorn = Simulator(make_scene(resolution=[6, 6]), device)
    untorn.step_frame()
    assert untorn.device_stretch().rms == pytest.approx(untorn.stretch().rms, rel=1e-12)


def test_a_device_that_is_not_a_string_is_an_argument_error():
    from warp_verlet.errors import ArgumentError

    with pytest.raises(ArgumentError, match="device must be None or a string.*got 3"):
        Simulator(make_scene(), 3)


def test_a_dt_too_large_for_the_position_bound_is_refused_before_it_moves_anything():
    from warp_verlet.errors import ArgumentError

    # Gravity only (9.81 m/s^2) and position_bound = 1e4 m: |a| dt^2 <= 1e4 m allows dt up to sqrt(1e4 / 9.81) s.
    sim = Simulator(make_scene({"position_bound": 1.0e4}, **HANGING), "cpu")
    largest = np.sqrt(1.0e4 / 9.81)
    start = sim.positions()
    for dt in (1e300, 1e20, 1.01 * largest):
        with pytest.raises(ArgumentError, match="dt = .* is too large"):
            sim.step(dt)
        assert np.array_equal(sim.positions(), start) and sim.steps == 0
    for dt in ("fast", [1e-3], float("nan"), -1e-3, 0.0):  # no number, or no positive finite one
        with pytest.raises(ArgumentError, match="dt must be a"):
            sim.step(dt)
    sim.step(0.5 * largest)  # within the bound: taken, and every position stays finite and inside it
    assert sim.steps == 1 and np.isfinite(sim.positions()).all() and np.abs(sim.positions()).max() <= 1.0e4
