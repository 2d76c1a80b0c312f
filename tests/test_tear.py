"""Tearing: sticks stretched past threshold x rest length are removed, on the device, deterministically.

The physics checks are analytic: with relaxation off, a top-pinned cloth's first row falls freely, so the
stick to the pinned row tears at the first substep where g t^2 / 2 > (threshold - 1) L; once a stick has
torn, the particle it held follows free fall exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from conftest import make_scene
from warp_verlet.geometry.colouring import check_partition
from warp_verlet.geometry.faces import grid_faces
from warp_verlet.apps.runner import run_scene
from warp_verlet.output.usd_writer import validate_cache
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator

G = 9.81


def gale(**simulation):
    """A 16 x 24 flag on a pole in a 72 m/s^2 wind, with a 1.3 tear threshold: it tears within 40 frames."""
    settings = {"fps": 60, "substeps": 4, "iterations": 8, "wind": [60.0, 0.0, 40.0], **simulation}
    return make_scene(settings, resolution=[16, 24], size=[0.6, 0.9], pins=["left-edge"], mass=0.1,
                      sticks=["structural", "shear"], compliance={"shear": 0.03}, tear_threshold=1.3)


def all_stick_ratios(sim: Simulator) -> np.ndarray:
    """D / L of every stick, from a host copy of the positions."""
    p = sim.positions().astype(np.float64)
    s = sim.model.host_sticks
    return np.linalg.norm(p[s[:, 1]] - p[s[:, 0]], axis=1) / sim.model.host_rest


@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_free_falling_rows_tear_from_the_pins_at_the_analytic_time(device, solver):
    # 5 rows spaced L = 0.25 m, top row pinned, no relaxation (iterations = 0): rows 1.. fall freely, so only
    # the sticks that reach the pinned row stretch. The vertical ones reach 1.2 L when g t^2 / 2 = 0.2 L.
    rows, cols, height, threshold = 5, 4, 1.0, 1.2
    spacing = height / (rows - 1)
    fps, substeps = 60, 4
    dt = 1.0 / (fps * substeps)
    scene = make_scene({"fps": fps, "substeps": substeps, "iterations": 0, "relaxation": solver},
                       resolution=[rows, cols], size=[height, 1.0], pins=["top-edge"],
                       sticks=["structural"], tear_threshold=threshold)
    sim = Simulator(scene, device)
    expected_step = int(np.floor(np.sqrt(2 * (threshold - 1) * spacing / G) / dt)) + 1  # first t with drop > 0.2 L
    drop = lambda n: G * (n * dt) ** 2 / 2  # noqa: E731
    assert drop(expected_step - 1) < 0.99 * (threshold - 1) * spacing < drop(expected_step) / 1.01  # not borderline

    torn_at = None
    for n in range(1, expected_step + 5):
        sim.step()
        if sim.torn_count() and torn_at is None:
            torn_at = n
    assert torn_at == expected_step
    torn = sim.torn_sticks()
    s = sim.model.host_sticks
    reaches_pinned_row = (s < cols).sum(axis=1) == 1  # one end pinned, one free
    # Every stick from the pinned row tore (one vertical per column), and no other stick did.
    assert torn.sum() == cols == sim.torn_count()
    assert np.array_equal(torn, reaches_pinned_row)


def test_a_torn_stick_exerts_no_force(device):
    # A pinned particle holding a free one (0.5 kg) by a soft stick (compliance 1e-4 m/N: it would settle
    # 0.5 kg x 1000 m/s^2 x 1e-4 m/N = 5 cm long, past the 1 cm the threshold allows), under g = 1000 m/s^2: the
    # stick tears, and then the free particle follows free fall: second differences x[n+1] - 2 x[n] + x[n-1] =
    # g dt^2, to rounding.
    g = 1000.0
    scene = make_scene({"fps": 60, "substeps": 4, "iterations": 1, "gravity": [0.0, -g, 0.0]},
                       resolution=[2, 1], size=[0.1, 0.0], pins=["top-left"], sticks=["structural"],
                       compliance={"structural": 1e-4}, tear_threshold=1.1)
    sim = Simulator(scene, device)
    history, torn_at = [], None
    for n in range(40):
        sim.step()
        history.append(sim.positions()[:, 1].astype(np.float64))
        if torn_at is None and sim.torn_count() == 1:
            torn_at = n  # history[n] is the first state without the stick
    assert torn_at is not None and torn_at > 0, "the stick should hold for a step, then tear under 100 g"
    y = np.array(history[torn_at:])
    assert len(y) >= 10
    dt = sim.settings.dt
    second = y[2:, 1:] - 2 * y[1:-1, 1:] + y[:-2, 1:]  # the two free particles
    np.testing.assert_allclose(second, -g * dt * dt, rtol=2e-3)


def test_below_the_threshold_nothing_tears_and_nothing_changes(device):
    # Run once without tearing and record the largest D / L any stick reached after any substep; a threshold
    # 1 % above it must tear nothing and leave the motion bit-identical, one 1 % below it must tear.
    base = dict(resolution=[12, 12], pins=["top-left", "top-right"], sticks=["structural", "shear", "bend"],
                compliance={"bend": 1e-3}, tethers=False)
    settings = {"fps": 60, "substeps": 4, "iterations": 4}
    plain = Simulator(make_scene(settings, **base), device)
    peak, frames = 1.0, []
    for _ in range(30 * 4):
        plain.step()
        peak = max(peak, float(all_stick_ratios(plain).max()))
        frames.append(plain.positions())
    assert peak > 1.01  # the cloth is really loaded

    safe = Simulator(make_scene(settings, **base, tear_threshold=1 + 1.01 * (peak - 1)), device)
    for expected in frames:
        safe.step()
        assert np.array_equal(safe.positions(), expected)
    assert safe.torn_count() == 0

    tight = Simulator(make_scene(settings, **base, tear_threshold=1 + 0.99 * (peak - 1)), device)
    for _ in frames:
        tight.step()
    assert tight.torn_count() > 0


def test_tearing_keeps_particles_and_a_valid_colouring():
    sim = Simulator(gale(), "cpu")
    model = sim.model
    ends_before, weight_before = model.stick_ends.numpy().copy(), model.stick_weight.numpy().copy()
    assert (weight_before == 1).all() and np.array_equal(sim.state.stick_weight.numpy(), weight_before)
    for _ in range(40):
        sim.step_frame()
    torn = sim.torn_sticks()
    assert 0 < torn.sum() < model.stick_count
    points = sim.positions()
    assert points.shape == (16 * 24, 3) and np.isfinite(points).all()  # no particle lost or broken

    # Torn sticks stay in their colour slot (no compaction, no recolouring) with the State's weight 0; the rest
    # keep weight 1, the Model is untouched, and the sticks still alive are still a valid partition: no two
    # of one colour share a particle.
    assert np.array_equal(model.stick_ends.numpy(), ends_before)
    assert np.array_equal(model.stick_weight.numpy(), weight_before)
    weight = sim.state.stick_weight.numpy()
    assert (weight[torn] == 0).all() and (weight[~torn] == 1).all()
    assert sim.torn_count() == int(sim.state.torn_entries.numpy()[0]) == torn.sum()
    colour = np.concatenate([np.full(n, c) for c, (_, n) in enumerate(model.colour_ranges)])
    check_partition(model.host_sticks[~torn], colour[~torn])


def test_same_scene_same_device_tears_bit_identically(device):
    scene = gale()

    def run():
        sim = Simulator(scene, device)
        for _ in range(40):
            sim.step_frame()
        return sim.positions(), sim.torn_sticks()

    (p1, t1), (p2, t2) = run(), run()
    assert t1.any() and np.array_equal(t1, t2) and np.array_equal(p1, p2)


def test_only_tearing_scenes_launch_and_allocate_the_tear_kernel(launches):
    k = 3
    # An unpinned 8 x 8 grid of structural sticks (4 colours), so no tethers: the Verlet step and K sweeps.
    plain = Simulator(make_scene({"iterations": k}, resolution=[8, 8]), "cpu", use_graph=False)
    plain.step()
    assert launches.of(plain.step) == ["verlet_step"] + ["relax_colour"] * (4 * k)
    assert not hasattr(plain.model, "tear_length") and plain.state.stick_weight is None
    assert plain.state.torn_entries is None
    # The same cloth that can tear: one tear_sticks launch after the sweeps, nothing else added.
    tearing = Simulator(make_scene({"iterations": k}, resolution=[8, 8], tear_threshold=1.5), "cpu", use_graph=False)
    tearing.step()
    assert launches.of(tearing.step) == ["verlet_step"] + ["relax_colour"] * (4 * k) + ["tear_sticks"]
    # Jacobi tears per stick end: still one launch.
    jacobi = Simulator(make_scene({"iterations": k, "relaxation": "jacobi"}, resolution=[8, 8], tear_threshold=1.5),
                       "cpu", use_graph=False)
    jacobi.step()
    assert launches.of(jacobi.step) == ["verlet_step"] + ["relax_jacobi", "copy"] * k + ["tear_sticks"]
    # A pinned cloth that can tear gets no tethers unless asked; asked, they run first in every sweep.
    pinned = make_scene({"iterations": k}, resolution=[8, 8], pins=["top-edge"], tear_threshold=1.5)
    assert not pinned.cloths[0].uses_tethers
    tethered = Simulator(make_scene({"iterations": k}, resolution=[8, 8], pins=["top-edge"], tear_threshold=1.5,
                                    tethers=True, tether_scale=2.0), "cpu", use_graph=False)
    tethered.step()
    assert launches.of(tethered.step) == (["verlet_step"] + (["pull_tethers"] + ["relax_colour"] * 4) * k
                                          + ["tear_sticks"])
    assert [name for name, _ in plain.stages()] == ["integrate", "relax"]
    assert [name for name, _ in tearing.stages()] == ["integrate", "relax", "tear"]


def torn_edge_faces(rows: int, cols: int, sticks: np.ndarray, torn: np.ndarray) -> set[int]:
    """Brute force: the faces with at least one of their four edges among the torn sticks."""
    torn_pairs = {tuple(sorted(p)) for p in sticks[torn].tolist()}
    hidden = set()
    for r in range(rows - 1):
        for c in range(cols - 1):
            a, b, d, e = r * cols + c, r * cols + c + 1, (r + 1) * cols + c, (r + 1) * cols + c + 1
            if {(a, b), (d, e), (a, d), (b, e)} & torn_pairs:
                hidden.add(r * (cols - 1) + c)
    return hidden


@pytest.mark.parametrize("solver,torn_faces", [("coloured", "holes"), ("jacobi", "holes"), ("coloured", "remove"),
                                               ("jacobi", "remove")])
def test_cache_hides_exactly_the_faces_beside_torn_sticks(tmp_path, solver, torn_faces):
    rows, cols = 16, 24
    # Soft shear sticks (as in gale()) where the solver has them; Jacobi's rigid sticks tear all the same.
    soft = {"compliance": {"shear": 0.03}} if solver == "coloured" else {}
    data = {
        "simulation": {"fps": 60, "frames": 30, "substeps": 4, "iterations": 8, "wind": [60.0, 0.0, 40.0],
                       "relaxation": solver},
        "output": {"torn_faces": torn_faces},
        "cloth": [
            {"name": "flag", "resolution": [rows, cols], "size": [0.6, 0.9], "pins": ["left-edge"], "mass": 0.1,
             "sticks": ["structural", "shear"], "tear_threshold": 1.3, **soft},
            {"name": "calm", "resolution": [4, 4], "size": [0.3, 0.3], "origin": [3.0, 0.0, 0.0],
             "pins": ["top-edge"]},
        ],
    }
    scene = parse_scene(data, "<test>")
    out = tmp_path / "torn.usda"
    summary = run_scene(scene, out, device="cpu")
    assert summary.torn and "torn sticks" in summary.format()

    # The same run again, frame by frame, for the torn set at every frame (runs are deterministic).
    sim = Simulator(scene, "cpu")
    flag = sim.model.cloths[0]
    expected, changes, last = {}, [0], set()
    for frame in range(1, 31):
        sim.step_frame()
        mine = (sim.model.host_sticks >= flag.first).all(axis=1) & (sim.model.host_sticks < flag.first + flag.count).all(axis=1)
        hidden = torn_edge_faces(rows, cols, sim.model.host_sticks[mine] - flag.first, sim.torn_sticks()[mine])
        expected[frame] = hidden
        if hidden != last:
            changes.append(frame)
            last = hidden

    stage = Usd.Stage.Open(str(out))
    flag_mesh = UsdGeom.Mesh.Get(stage, "/World/flag")
    holes = flag_mesh.GetHoleIndicesAttr()
    counts, indices = flag_mesh.GetFaceVertexCountsAttr(), flag_mesh.GetFaceVertexIndicesAttr()
    assert 2 <= len(changes) < 31  # something tore, and some frames changed nothing (so had no sample)
    all_faces = grid_faces(rows, cols).as_uniform()
    if torn_faces == "holes":
        assert list(holes.GetTimeSamples()) == changes  # frame 0 (empty) and then only where the set changed
        assert not counts.GetTimeSamples() and not indices.GetTimeSamples()  # the topology never changes
        for frame in range(1, 31):
            assert set(np.asarray(holes.Get(frame)).tolist()) == expected[frame]
    else:  # the torn faces are left out of a time-sampled topology: exactly those, and only where it changed
        assert not holes.HasAuthoredValue()
        assert list(counts.GetTimeSamples()) == list(indices.GetTimeSamples()) == changes
        for frame in range(0, 31):
            kept = [f for f in range(len(all_faces)) if f not in expected.get(frame, set())]
            np.testing.assert_array_equal(np.asarray(counts.Get(frame)), np.full(len(kept), 4))
            np.testing.assert_array_equal(np.asarray(indices.Get(frame)), all_faces[kept].ravel())
        # The full grid stays the default value, for readers that ask for no time.
        np.testing.assert_array_equal(np.asarray(indices.Get()), all_faces.ravel())
    assert validate_cache(out) == []  # UsdValidation, and ValidateTopology at every topology sample
    # The cloth that cannot tear carries nothing about tearing, and its points count never changes.
    calm = UsdGeom.Mesh.Get(stage, "/World/calm")
    assert not calm.GetHoleIndicesAttr().HasAuthoredValue() and not calm.GetFaceVertexIndicesAttr().GetTimeSamples()
    flag_points = UsdGeom.Mesh.Get(stage, "/World/flag").GetPointsAttr()
    assert {len(flag_points.Get(t)) for t in flag_points.GetTimeSamples()} == {rows * cols}


def test_a_cloth_that_tears_by_tension_alone_writes_its_torn_faces(tmp_path):
    """tear_tension without tear_threshold: the run tears sticks, and the cache hides the faces beside them (the
    writer was once told such a cloth does not tear, and the run stopped before writing its cache)."""
    data = {"simulation": {"fps": 60, "frames": 30, "substeps": 8, "iterations": 4},
            "cloth": [{"name": "sheet", "resolution": [8, 8], "size": [1.0, 1.0], "orientation": "horizontal",
                       "origin": [-0.5, 1.0, -0.5], "mass": 5.0, "pins": ["left-edge", "right-edge"],
                       "sticks": ["structural", "shear"], "tear_tension": 2.0}]}
    out = tmp_path / "tension.usda"
    summary = run_scene(parse_scene(data, "<tension>"), out, device="cpu")
    assert summary.torn
    stage = Usd.Stage.Open(str(out))
    counts = UsdGeom.Mesh.Get(stage, "/World/sheet").GetFaceVertexCountsAttr()  # the default: torn faces removed
    last = counts.GetTimeSamples()[-1]
    assert len(counts.Get(0)) == 7 * 7 and len(counts.Get(last)) < 7 * 7
    assert validate_cache(out) == []


def test_stretch_statistics_leave_torn_sticks_out():
    scene = gale()
    sim = Simulator(scene, "cpu")
    for _ in range(40):
        sim.step_frame()
    torn = sim.torn_sticks()
    structural = sim.model.structural
    assert (torn & structural).any()
    ratios = all_stick_ratios(sim)
    assert ratios[torn].max() > 1.3  # torn ends drift apart: including them would blow up the figure
    alive = structural & ~torn
    assert sim.stretch().max == pytest.approx(float(np.abs(ratios[alive] - 1).max()), rel=1e-9)


@pytest.mark.parametrize("name, frames", [("flag_tear", 45), ("ball_through_net", 45)])
def test_shipped_tearing_scenes_tear(name, frames):
    from pathlib import Path

    from warp_verlet.input.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parent.parent / "scenes" / f"{name}.toml")
    sim = Simulator(scene, "cpu")
    for _ in range(frames):
        sim.step_frame()
    points = sim.positions()
    assert sim.torn_count() > 0 and points.shape[0] == scene.particle_count and np.isfinite(points).all()
    assert points[:, 1].min() >= -1e-5  # both scenes have ground at y = 0: nothing fell through it
