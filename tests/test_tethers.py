"""Tethers (long-range attachments, kernels/tether.py): a tethered particle stays within its tether length
of its pins, a tear that cuts a piece off its pins drops those tethers so the piece falls freely, and a
cloth without pins gets none."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.kernels.tether import into_two_balls

G = 9.81


def hanging(tethers: bool, n: int = 16):
    return make_scene({"substeps": 4, "iterations": 8, "damping": 0.24}, resolution=[n, n], size=[1.0, 1.0],
                      mass=0.2, pins=["top-left", "top-right"], sticks=["structural", "shear", "bend"],
                      tethers=tethers)


def excess_over_tether(sim: Simulator, table) -> np.ndarray:
    """(distance to pin - tether length) / tether length, per tether (the table's slots that hold one)."""
    p = sim.positions().astype(np.float64)
    rows, slots = np.nonzero(table.tethered)
    pins = table.pin[rows, slots]
    distance = np.linalg.norm(p[table.particle[rows]] - p[pins], axis=1)
    return (distance - table.length[rows, slots]) / table.length[rows, slots]


def test_a_tethered_cloth_stays_within_its_tether_lengths(device):
    sim = Simulator(hanging(True), device)
    table = sim.model.tether_table
    assert table.first == 0 and table.pin.shape == (16 * 16, 2)  # a row per particle
    assert table.tethered.sum() == 2 * (16 * 16 - 2)  # every free particle, tied to both pins
    assert (table.pin[:, 0] == -2).sum() == 2  # the pins' rows say so
    for _ in range(60):
        sim.step_frame()
    # The tether pass runs before the sticks in each sweep, so the last sweep's stick corrections (the residual
    # stretch, about 1e-5 here) may carry a particle that far past its tether: 1e-4 relative bounds it.
    assert excess_over_tether(sim, table).max() < 1e-4
    # The same cloth without tethers ends far beyond those lengths: the bound above is not vacuous.
    plain = Simulator(hanging(False), device)
    for _ in range(60):
        plain.step_frame()
    assert excess_over_tether(plain, table).max() > 1e-2


def test_tethers_cut_the_stretch_of_a_big_hanging_cloth():
    with_tethers, without = Simulator(hanging(True, 64), "cpu"), Simulator(hanging(False, 64), "cpu")
    for _ in range(60):
        with_tethers.step_frame()
        without.step_frame()
    # Measured (bench/convergence.py, CPU): 0.027% RMS / 0.18% max with tethers, 3.6% / 90% without.
    assert with_tethers.stretch().rms < 1e-3 and with_tethers.stretch().max < 5e-3
    assert without.stretch().rms > 1e-2


def test_a_piece_torn_off_its_pins_drops_its_tethers_and_falls_freely(device):
    # 4 rows hanging from a pinned top row; tethers with slack 2 (so they cannot stop the 1.2 tear); g = 100
    # m/s^2 stretches the top sticks past 1.2 L and tears them. The rest of the cloth is then cut off from
    # every pin: sync_tears drops its tethers and its centre of mass follows free fall, x[n+1] - 2 x[n] + x[n-1]
    # = g dt^2 (its sticks still ring, but their corrections are equal and opposite between equal masses).
    g = 100.0
    scene = make_scene({"fps": 60, "substeps": 4, "iterations": 2, "gravity": [0.0, -g, 0.0]},
                       resolution=[4, 3], size=[0.3, 0.2], pins=["top-edge"], sticks=["structural"],
                       compliance={"structural": 1e-2}, tear_threshold=1.2, tethers=True, tether_scale=2.0)
    sim = Simulator(scene, device)
    assert sim.model.tether_table is not None
    for _ in range(200):
        sim.step()
        if sim.torn_count() == 3:
            break
    assert sim.torn_count() == 3, "the three sticks to the pinned row should tear"
    sim.sync_tears()
    assert np.isinf(sim.state.tether_length.numpy()).all()  # every free particle was cut off
    history = []
    for _ in range(12):
        sim.step()
        history.append(sim.positions()[3:, 1].astype(np.float64).mean())
    y = np.array(history)
    second = y[2:] - 2 * y[1:-1] + y[:-2]
    dt = sim.settings.dt
    np.testing.assert_allclose(second, -g * dt * dt, rtol=2e-3)


def test_a_stale_tether_would_hold_the_torn_piece():
    # The same tear without sync_tears: the tethers (2 x the rest distance) catch the piece, so the free-fall
    # check above can fail.
    g = 100.0
    scene = make_scene({"fps": 60, "substeps": 4, "iterations": 2, "gravity": [0.0, -g, 0.0]},
                       resolution=[4, 3], size=[0.3, 0.2], pins=["top-edge"], sticks=["structural"],
                       compliance={"structural": 1e-2}, tear_threshold=1.2, tethers=True, tether_scale=2.0)
    sim = Simulator(scene, "cpu")
    for _ in range(400):
        sim.step()
    assert sim.torn_count() >= 3
    # 400 steps of free fall would take it 100 * (400 / 240)^2 / 2 = 139 m down; the stale tethers hold every
    # particle within 2 x its rest distance (at most 0.3 m) of a pin.
    assert sim.positions()[3:, 1].min() > -0.3 * 2.0 - 1e-3


def test_a_cloth_without_pins_or_with_tethers_off_gets_none():
    assert Simulator(make_scene(resolution=[8, 8]), "cpu").model.tether_table is None
    assert Simulator(hanging(False), "cpu").model.tether_table is None
    assert Simulator(hanging(True), "cpu").solver.req.tethered == 16 * 16 - 2


WINDY = {"substeps": 2, "iterations": 3, "wind": [0.5, 0.0, 4.0]}
EVERYWHERE = {"cpu": True, "cuda": True}
NOWHERE = {"cpu": False, "cuda": False}


@pytest.mark.parametrize("cloth, simulation, threads", [
    ({"pins": ["top-left", "top-right"]}, {}, 1),  # two pins: every particle tied to both
    ({"pins": ["top-left", "top-right"]}, {}, 2),  # the CPU thread team runs the first sweep without the pass
    ({"pins": ["top-edge"], "tear_threshold": 1.05, "tethers": True, "tether_scale": 1.05},
     {"wind": [0.5, 0.0, 20.0]}, 1),  # a gale tears it, and the tears cut tethers
    ({"pins": ["top-left", [0, 5]], "tether_scale": 1.2}, {"precision": "float64"}, 1),
    ({"pins": ["top-left", "top-right"]}, {"relaxation": "jacobi"}, 1),
])
def test_the_first_tether_pass_inside_the_verlet_step_changes_no_bit(cloth, simulation, threads, device, monkeypatch):
    """The Verlet step that also runs the first sweep's tether pass (kernels/integrate.verlet_step_tethered) leaves
    every position as the two launches one after the other do, bit for bit, on every device (the CPU runs them
    apart by default, so the test switches it on there)."""
    from warp_verlet.core import stages

    if device != "cpu":
        threads = None
    scene = make_scene({**WINDY, **simulation}, resolution=[12, 10], size=[1.0, 0.8], **cloth)
    runs = []
    for fold in (EVERYWHERE, NOWHERE):
        monkeypatch.setattr(stages, "FOLD_TETHERS_INTO_INTEGRATE", fold)
        sim = Simulator(scene, device, threads=threads)
        assert stages.tethers_in_integrate(sim.solver) == fold["cpu"]
        for _ in range(12):
            sim.step_frame()
        runs.append(sim.positions())
    if "tear_threshold" in cloth:
        assert sim.torn_count() > 0  # the tears cut tethers during the run
    assert np.abs(runs[0] - sim.model.rest_positions).max() > 0.05  # it moved
    np.testing.assert_array_equal(runs[0], runs[1])


def test_with_the_pass_inside_a_substep_launches_one_tether_pass_fewer(launches, monkeypatch):
    from warp_verlet.core import stages

    monkeypatch.setattr(stages, "FOLD_TETHERS_INTO_INTEGRATE", EVERYWHERE)
    k = 4
    sim = Simulator(make_scene({"iterations": k}, resolution=[8, 8], pins=["top-left", "top-right"]), "cpu",
                    use_graph=False)
    sim.step()  # the first step also runs verlet_start
    assert launches.of(sim.step) == (["verlet_step_tethered"] + ["relax_colour"] * 4
                                     + (["pull_tethers"] + ["relax_colour"] * 4) * (k - 1))


@pytest.mark.parametrize("simulation, cloth", [
    ({"multilevel": True}, {}),  # its pass measures moves from the Verlet prediction, before the first sweep
    ({"global_iterations": 3}, {}),  # the global correction runs between the step and the sweeps
    ({"air": {"velocity": [0.0, 0.0, 5.0]}}, {}),  # the air's step gathers each particle's force
    ({}, {"self_collision": True}),  # the self-contact search reads the positions before the first sweep
])
def test_the_tether_pass_stays_out_of_the_verlet_step_where_something_runs_between(simulation, cloth, monkeypatch):
    from warp_verlet.core import stages

    monkeypatch.setattr(stages, "FOLD_TETHERS_INTO_INTEGRATE", EVERYWHERE)
    scene = make_scene(simulation, resolution=[12, 10], pins=["top-left", "top-right"], **cloth)
    sim = Simulator(scene, "cpu")
    assert "tethers" in sim.constraint_sets
    assert not stages.tethers_in_integrate(sim.solver)


def test_the_tether_pass_stays_out_of_the_verlet_step_unless_the_table_holds_every_particle(monkeypatch):
    from warp_verlet.core import stages

    monkeypatch.setattr(stages, "FOLD_TETHERS_INTO_INTEGRATE", EVERYWHERE)
    grid = make_scene({}, resolution=[12, 10], pins=["top-left", "top-right"])
    assert stages.tethers_in_integrate(Simulator(grid, "cpu").solver)
    assert not stages.tethers_in_integrate(Simulator(grid, "cpu", sticks="implicit").solver)  # computed tethers
    untethered = make_scene({}, resolution=[12, 10], pins=["top-left"], tethers=False)
    assert not stages.tethers_in_integrate(Simulator(untethered, "cpu").solver)
    assert not stages.tethers_in_integrate(Simulator(three_cloths("ab"), "cpu").solver)  # b's particles have no row
    assert stages.tethers_in_integrate(Simulator(three_cloths("abc"), "cpu").solver)  # b lies inside the span
    monkeypatch.setattr(stages, "FOLD_TETHERS_INTO_INTEGRATE", {"cpu": False, "cuda": True})
    assert not stages.tethers_in_integrate(Simulator(grid, "cpu").solver)  # the CPU runs the pass apart


def three_cloths(names: str):
    """Cloths a and c hang tethered from their top corners; b, pinned at one corner, has no tethers."""
    from warp_verlet.input.scene import parse_scene

    cloths = {
        "a": {"name": "a", "resolution": [6, 5], "size": [1.0, 1.0], "pins": ["top-left", "top-right"]},
        "b": {"name": "b", "resolution": [4, 4], "size": [1.0, 1.0], "origin": [2.0, 0.0, 0.0], "pins": ["top-left"],
              "tethers": False},
        "c": {"name": "c", "resolution": [5, 6], "size": [1.0, 1.0], "origin": [4.0, 0.0, 0.0],
              "pins": ["top-left", "top-right"]},
    }
    return parse_scene({"simulation": {"substeps": 4, "iterations": 4}, "cloth": [cloths[n] for n in names]},
                       file="<test>")


@pytest.mark.parametrize("names", ["abc", "ba"])
def test_a_table_spanning_an_untethered_cloth_holds_its_pin_and_moves_its_free_particles(names, device, monkeypatch):
    """The tether table has a row per particle of the tethered cloths' span: an untethered cloth inside it (abc)
    keeps its pin's row marked pinned and its free particles' rows empty, and one before it (ba) starts the
    table further on. Its pin stays put and its free particles swing down, with the tether pass inside the Verlet
    step or apart, bit for bit the same, and the tethered cloths stay within their tethers."""
    from warp_verlet.core import stages

    scene = three_cloths(names)
    runs = []
    for fold in (EVERYWHERE, NOWHERE):
        monkeypatch.setattr(stages, "FOLD_TETHERS_INTO_INTEGRATE", fold)
        sim = Simulator(scene, device)
        assert stages.tethers_in_integrate(sim.solver) == (fold["cpu"] and names == "abc")
        for _ in range(20):
            sim.step_frame()
        runs.append(sim.positions())
    np.testing.assert_array_equal(runs[0], runs[1])
    table, first = sim.model.tether_table, names.index("b") * (6 * 5 if names == "abc" else 0)
    b = slice(first, first + 16)
    assert table.first == (16 if names == "ba" else 0) and table.count == sim.model.particle_count - table.first
    if names == "abc":
        rows = table.pin[b]
        assert (rows[0] == [-2, -1]).all() and (rows[1:] == -1).all()  # b's pin, then its untethered particles
    rest, end = sim.model.rest_positions[b], runs[0][b]
    np.testing.assert_array_equal(end[0], rest[0])  # b's pin
    assert np.linalg.norm(end[1:] - rest[1:], axis=1).min() > 0.05  # b's free particles swung down
    assert excess_over_tether(sim, table).max() < 1e-4
    from test_memory import simulator_bytes
    from warp_verlet.core.memory import estimate

    assert simulator_bytes(sim) == estimate(scene, sim.model.sticks_form).device_bytes  # the table's rows counted


@wp.kernel
def nearest_in_lens(p: wp.array(dtype=Any), a: wp.array(dtype=Any), la: wp.array(dtype=Any), b: wp.array(dtype=Any),
                    lb: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    i = wp.tid()
    out[i] = into_two_balls(p[i], a[i], la[i], b[i], lb[i])


def into_lens(p, a, la, b, lb, vector=wp.vec3d, scalar=wp.float64) -> np.ndarray:
    """kernels/tether.into_two_balls on the CPU for each row of p, a, la, b, lb, in the precision of ``vector`` and
    ``scalar`` (the inputs rounded to it), as float64."""
    dtype = np.float32 if scalar == wp.float32 else np.float64
    cases = [wp.array(np.asarray(v, dtype=dtype), dtype=vector if np.ndim(v) == 2 else scalar, device="cpu")
             for v in (p, a, la, b, lb)]
    out = wp.zeros(len(cases[0]), dtype=vector, device="cpu")
    wp.launch(nearest_in_lens, len(out), inputs=cases, outputs=[out], device="cpu")
    return out.numpy().astype(np.float64)


def nearest_in_two_balls(p, a, la, b, lb, turns: int = 3000):
    """The nearest point to p of the intersection of two balls by Dykstra's alternating projections (float64), an
    independent route to what kernels/tether.into_two_balls computes in closed form."""
    def into(q, c, r):
        d = q - c
        n = np.linalg.norm(d)
        return q if n <= r else c + d * (r / n)
    x, pa, pb = p.copy(), np.zeros(3), np.zeros(3)
    for _ in range(turns):
        y = into(x + pa, a, la)
        pa = x + pa - y
        x = into(y + pb, b, lb)
        pb = y + pb - x
    return x


def test_two_tethers_move_a_particle_to_the_nearest_point_inside_both():
    rng = np.random.default_rng(4)
    n = 150
    a = rng.normal(0, 1, (n, 3))
    b = a + rng.normal(0, 1, (n, 3))
    gap = np.linalg.norm(b - a, axis=1)
    la = gap * rng.uniform(0.3, 1.2, n)
    lb = np.maximum(gap - la, 0) + gap * rng.uniform(0.05, 1.0, n)  # the balls overlap
    p = a + rng.normal(0, 1.5, (n, 3))  # inside both, one, or neither
    got = into_lens(p, a, la, b, lb)
    kinds = set()
    for i in range(n):
        expected = nearest_in_two_balls(p[i], a[i], la[i], b[i], lb[i])
        np.testing.assert_allclose(got[i], expected, atol=1e-7 * (1 + gap[i]), err_msg=str(i))
        inside = (np.linalg.norm(p[i] - a[i]) <= la[i], np.linalg.norm(p[i] - b[i]) <= lb[i])
        on_circle = (abs(np.linalg.norm(got[i] - a[i]) - la[i]) < 1e-9
                     and abs(np.linalg.norm(got[i] - b[i]) - lb[i]) < 1e-9)
        kinds.add("inside" if all(inside) else "circle" if on_circle else "one ball")
    assert kinds == {"inside", "circle", "one ball"}  # every branch was taken


def test_two_tethers_in_float32_keep_their_digits_near_the_line_between_the_pins():
    # The top rows of a 1 m cloth at 1024² hung by its two top corners: the two spheres cross at a shallow angle, the
    # lens between them is thin, and la + lb - gap is a small difference of large lengths. In float32 the projection
    # stays within 1.5e-7 m (about one float32 spacing at 1 m) of the float64 one from the same inputs. Computed as
    # la + lb - gap in float32 it misses by 1.2e-4 m; with the cone tests by the distance to the other pin, 1.7e-6 m.
    rng = np.random.default_rng(1)
    n, h = 5000, 1.0 / 1023
    rest = np.stack([-0.5 + rng.integers(0, 1024, n) * h, 1 - rng.integers(0, 12, n) * h, np.zeros(n)], 1)
    a, b = np.tile([-0.5, 1.0, 0.0], (n, 1)), np.tile([0.5, 1.0, 0.0], (n, 1))
    la = np.linalg.norm(rest - a, axis=1).astype(np.float32)
    lb = np.linalg.norm(rest - b, axis=1).astype(np.float32)
    p = (rest + rng.normal(0, 3 * h, (n, 3)) + [0, -2 * h, 0]).astype(np.float32)  # moved by gravity and the sticks
    exact = into_lens(p, a, la, b, lb)
    assert (np.linalg.norm(exact - p, axis=1) > 0).mean() > 0.9  # nearly all were moved: the tethers hold them
    assert np.linalg.norm(into_lens(p, a, la, b, lb, wp.vec3, wp.float32) - exact, axis=1).max() < 1.5e-7


@pytest.mark.parametrize("vector,scalar", [(wp.vec3, wp.float32), (wp.vec3d, wp.float64)])
def test_two_tethers_in_extreme_cases_give_a_finite_nearest_point(vector, scalar):
    # Pins dragged apart past both lengths (no lens: the point where the spheres' radical plane, which holds their
    # circle while they meet, crosses the axis, as it holds the touching point), pins at one place (the smaller
    # ball), one ball inside the other (that ball), a cut tether (length +inf: the other ball alone), and p on the
    # axis (no direction off it): each answer finite and where it should be.
    inf = np.inf
    cases = [  # p, a, la, b, lb, expected
        ((0.0, -1.0, 0.0), (0, 0, 0), 1.0, (4, 0, 0), 2.0, (1.625, 0.0, 0.0)),   # apart: (16 + 1 - 4) / 8 along
        ((4.0, 3.0, 0.0), (0, 0, 0), 1.0, (0, 0, 0), 0.5, (0.4, 0.3, 0.0)),      # one place: the smaller ball
        ((3.5, 4.0, 0.0), (0, 0, 0), 2.0, (0.5, 0, 0), 0.5, (0.8, 0.4, 0.0)),    # b inside a: b's ball
        ((0.0, 3.0, 0.0), (0, 0, 0), inf, (0, 1, 0), 1.0, (0.0, 2.0, 0.0)),      # a cut: b's ball alone
        ((0.0, 3.0, 0.0), (0, 0, 0), 1.0, (0, 1, 0), inf, (0.0, 1.0, 0.0)),      # b cut: a's ball alone
        ((-2.0, 0.0, 0.0), (0, 0, 0), 1.0, (1, 0, 0), 1.0, (0.0, 0.0, 0.0)),     # on the axis, behind a: the lens's tip
    ]
    columns = list(zip(*cases))
    got = into_lens(*columns[:5], vector, scalar)
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, np.array(columns[5]), atol=1e-6)


def test_a_cloth_hung_in_its_rest_pose_by_two_corners_stays_still():
    # Vertical, flat and pinned at its two top corners, the rigid cloth is at rest where it starts: every free
    # particle hangs at the lowest point within its two tethers (the circle about the line between the pins that
    # passes through its rest position), and the sticks are at their lengths. It moves 6e-8 m (one float32 spacing);
    # projected onto one tether and then the other, the particles were pushed sideways and it moved 2.0e-5 m.
    sim = Simulator(hanging(True, 24), "cpu")
    x0 = sim.positions().astype(np.float64)
    for _ in range(30):
        sim.step_frame()
    assert np.abs(sim.positions() - x0).max() < 2e-6
