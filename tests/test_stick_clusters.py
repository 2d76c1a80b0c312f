"""Stick arrays swept cluster by cluster (kernels/stick_clusters.py, constraints/stick_clusters.py): the layout is
a race-free sweep of every stick once, a clustered sweep is exactly the sequential Gauss-Seidel sweep in the
clusters' order (bit for bit on the CPU), it conserves the centre of mass and converges as the colour-by-colour
sweep does, and the form is refused where it does not apply."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from mesh_files import grid_mesh, mesh_scene, triangulated, write_obj
from warp_verlet.constraints.stick_clusters import StickClusters, check_layout, cluster_layout, colour_clusters
from warp_verlet.constraints.sticks import Sticks
from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import ArgumentError
from warp_verlet.kernels.relax import relax_colour

ROWS, COLS = 37, 45


def triangle_scene(tmp_path, **cloth):
    points, quads = grid_mesh(ROWS, COLS)
    path = write_obj(tmp_path / "sheet.obj", points, triangulated(quads))
    return mesh_scene(tmp_path, {"mesh": path.name, "sticks": ["structural", "bend"], **cloth},
                      {"substeps": 2, "iterations": 4})


def grid_scene(**cloth):
    spec = {"resolution": [ROWS, COLS], "size": [1.0, 1.2], "pins": ["top-left", "top-right"], **cloth}
    return make_scene({"substeps": 2, "iterations": 4}, **spec)


def perturbed(sim: Simulator, scale: float = 0.01, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = sim.model.rest_positions + rng.normal(0.0, scale, sim.model.rest_positions.shape)
    return x.astype(np.float32)


def sweep(sim: Simulator, start: np.ndarray, times: int = 1) -> np.ndarray:
    """``times`` sweeps of the sticks' phases alone, from ``start``: one substep of 1/240 s (soft sticks: its
    1 / dt^2 given and the tensions zeroed first)."""
    sim.state.set_positions(start)
    kind = StickClusters() if sim.model.sticks_form == "clustered" else Sticks()
    with wp.ScopedDevice(sim.device):  # as the solver binds (Sticks' launches take the current device)
        bound = kind.bind(sim.model, sim.state, sim.solver)
        if bound.run is not None:
            bound.run(sim.state, 1.0 / 240.0)
    for _ in range(times):
        for phase in bound.phases:
            for task in phase:
                if task is not None:
                    task.run()
    return sim.state.positions()


def layout_of(sim: Simulator):
    m = sim.model
    colour = np.repeat(np.arange(len(m.colour_ranges)), [n for _, n in m.colour_ranges])
    return cluster_layout(m.host_sticks, m.host_rest, colour, len(m.colour_ranges), m.rest_positions,
                          cluster_particles=64)


@pytest.fixture(params=["grid", "grid with masses", "triangle mesh"])
def scene(request, tmp_path):
    if request.param == "grid":
        return grid_scene()
    if request.param == "grid with masses":
        return grid_scene(particle_masses=[[4, 6, 0.05], [20, 17, 0.001]], pins=["top-left", [30, 40]])
    return triangle_scene(tmp_path)


@pytest.mark.parametrize("chained", [True, False], ids=["chained", "a launch per cluster colour"])
def test_a_clustered_sweep_is_the_sequential_sweep_in_cluster_order_bit_for_bit(scene, monkeypatch, chained):
    from warp_verlet.constraints import stick_clusters

    monkeypatch.setattr(stick_clusters, "CLUSTER_PARTICLES", 64)  # many clusters and cluster colours
    monkeypatch.setattr(stick_clusters, "MIN_CHAINED_PARTICLES", 0 if chained else 10**12)
    clustered = Simulator(scene, "cpu", threads=1, sticks="clustered")
    assert "stick clusters" in clustered.constraint_sets and "sticks" not in clustered.constraint_sets
    data = clustered.model.constraints["stick clusters"]
    assert len(data.launches) >= 4
    start = perturbed(clustered)
    bound = StickClusters().bind(clustered.model, clustered.state, clustered.solver)
    assert len(bound.phases) == (1 if chained else len(data.launches))
    clustered.state.set_positions(start)
    for phase in bound.phases:
        for task in phase:
            task.run()

    m = clustered.model
    layout = layout_of(clustered)
    x = wp.array(start, dtype=wp.vec3, device="cpu")
    ends = m.host_sticks[layout.stick]
    wp.launch(relax_colour, len(ends), device="cpu",
              inputs=[x, m.inv_mass, wp.array(ends, dtype=wp.vec2i, device="cpu"),
                      wp.array(m.host_rest[layout.stick], dtype=float, device="cpu"),
                      wp.array(np.ones(len(ends), np.float32), dtype=float, device="cpu"), 0, 1])
    assert np.abs(x.numpy() - start).max() > 1e-4  # the sweep did something
    np.testing.assert_array_equal(clustered.state.positions(), x.numpy())


def test_a_chained_sweep_takes_its_clusters_in_order_and_counts_each_clusters_sweeps(tmp_path, monkeypatch):
    """On the CPU a launch's blocks run one after another, so every wait of a chained sweep must already be met:
    a cluster's neighbours before it in the order have finished this sweep, those after it (and itself) the one
    before. After each launch the chain's counts are reset for the next, and every cluster has done one more
    sweep."""
    from warp_verlet.constraints import stick_clusters

    monkeypatch.setattr(stick_clusters, "CLUSTER_PARTICLES", 64)
    monkeypatch.setattr(stick_clusters, "MIN_CHAINED_PARTICLES", 0)
    sim = Simulator(triangle_scene(tmp_path), "cpu", threads=1, sticks="clustered")
    clusters = sim.model.constraints["stick clusters"].clusters
    sweep(sim, perturbed(sim), 5)
    chain = sim.solver.cached("cluster_chain", lambda: None)
    assert chain.counts.numpy().tolist() == [0, 0, 5]
    np.testing.assert_array_equal(chain.done.numpy(), np.full(clusters, 5))
    assert chain.order_broken.numpy()[0] == 0


def test_a_cluster_with_more_neighbours_than_the_chain_allows_takes_a_launch_per_cluster_colour(tmp_path,
                                                                                            monkeypatch):
    from warp_verlet.constraints import stick_clusters

    monkeypatch.setattr(stick_clusters, "CLUSTER_PARTICLES", 64)
    monkeypatch.setattr(stick_clusters, "MIN_CHAINED_PARTICLES", 0)
    most = int(np.diff(layout_of(Simulator(triangle_scene(tmp_path), "cpu", sticks="explicit")).neighbour_start).max())
    for limit, launches in ((most, 1), (most - 1, None)):
        monkeypatch.setattr(stick_clusters, "MAX_CHAINED_NEIGHBOURS", limit)
        sim = Simulator(triangle_scene(tmp_path), "cpu", threads=1, sticks="clustered")
        data = sim.model.constraints["stick clusters"]
        bound = StickClusters().bind(sim.model, sim.state, sim.solver)
        assert len(bound.phases) == (launches or len(data.launches)) and (data.neighbour is None) == (not launches)


@pytest.mark.parametrize("staged", [True, False], ids=["staged", "in global memory"])
def test_a_soft_clustered_sweep_is_the_sequential_xpbd_sweep_in_cluster_order_bit_for_bit(tmp_path, monkeypatch,
                                                                                          staged):
    from warp_verlet.constraints import stick_clusters
    from warp_verlet.kernels.relax import relax_colour_compliant

    monkeypatch.setattr(stick_clusters, "CLUSTER_PARTICLES", 64)
    monkeypatch.setattr(stick_clusters, "stage_soft_sticks", lambda layout: staged)
    clustered = Simulator(triangle_scene(tmp_path, compliance={"bend": 0.02}), "cpu", threads=1, sticks="clustered")
    m, dt = clustered.model, 1.0 / 240.0  # sweep()'s substep
    assert m.compliant and m.constraints["stick clusters"].stage_soft == staged
    start = perturbed(clustered)
    on_clusters = sweep(clustered, start, 3)  # one substep of dt: the tension carries from sweep to sweep

    layout = layout_of(clustered)
    x = wp.array(start, dtype=wp.vec3, device="cpu")
    tension = wp.zeros(len(layout.stick), dtype=float, device="cpu")
    compliance = m.stick_compliance.numpy()[layout.stick]
    assert 0 < np.count_nonzero(compliance) < len(compliance)  # soft bend sticks among rigid ones
    inputs = [x, m.inv_mass, wp.array(m.host_sticks[layout.stick], dtype=wp.vec2i, device="cpu"),
              wp.array(m.host_rest[layout.stick], dtype=float, device="cpu"),
              wp.array(np.ones(len(layout.stick), np.float32), dtype=float, device="cpu"),
              wp.array(compliance, dtype=float, device="cpu"), 1.0 / (dt * dt), 0, 1]
    for _ in range(3):
        wp.launch(relax_colour_compliant, len(layout.stick), device="cpu", inputs=inputs, outputs=[tension])
    rigid = sweep(Simulator(triangle_scene(tmp_path), "cpu", threads=1, sticks="clustered"), start, 3)
    assert np.abs(x.numpy() - rigid).max() > 1e-6  # the compliance changed the moves
    np.testing.assert_array_equal(on_clusters, x.numpy())
    stored = clustered.solver.scratch("cluster_tension", len(layout.stick), float).numpy()
    np.testing.assert_array_equal(stored, tension.numpy())


def test_the_layout_holds_every_stick_once_and_no_cluster_colour_shares_a_particle(tmp_path):
    sim = Simulator(triangle_scene(tmp_path), "cpu", threads=1, sticks="explicit")
    layout = layout_of(sim)
    sticks = sim.model.host_sticks[layout.stick]
    check_layout(layout, sticks)  # passes as built
    assert layout.capacity >= np.diff(layout.region_start).max() and layout.capacity % 32 == 0
    assert np.all(layout.stick_local >= 0) and np.all(layout.stick_local < layout.capacity)
    per_cluster = np.diff(layout.stick_start[::layout.colours])
    assert layout.stick_capacity >= per_cluster.max() and layout.stick_capacity % 64 == 0
    packed = layout.packed_ends
    np.testing.assert_array_equal(np.stack([packed & 0xFFFF, packed >> 16], axis=1), layout.stick_local)

    # Each way of breaking it is caught.
    merged = dataclasses.replace(layout, launches=[(0, sum(n for _, n in layout.launches))])
    with pytest.raises(AssertionError, match="share a particle"):
        check_layout(merged, sticks)
    wrong_end = layout.stick_local.copy()
    wrong_end[5, 1] = (wrong_end[5, 1] + 1) % np.diff(layout.region_start)[0]
    with pytest.raises(AssertionError, match="local end"):
        check_layout(dataclasses.replace(layout, stick_local=wrong_end), sticks)
    twice = layout.stick.copy()
    twice[1] = twice[0]
    with pytest.raises(AssertionError, match="exactly once"):
        check_layout(dataclasses.replace(layout, stick=twice), sticks)
    # A chained sweep's waits: each cluster lists itself and every cluster whose region shares a particle with its.
    assert np.all(np.diff(layout.neighbour_start) >= 2)  # itself and at least one other
    for dropped in (layout.neighbour_start[3], layout.neighbour_start[3] + 1):  # another cluster, or itself
        short = np.delete(layout.neighbour, dropped)
        starts = layout.neighbour_start - (np.arange(len(layout.neighbour_start)) > 3)
        with pytest.raises(AssertionError, match="neighbours"):
            check_layout(dataclasses.replace(layout, neighbour=short, neighbour_start=starts), sticks)


def test_clusters_that_share_a_particle_get_different_colours():
    # regions: 0 {0, 1}, 1 {1, 2}, 2 {3}, 3 {2, 3}: 0-1 share 1, 1-3 share 2, 2-3 share 3
    regions = {0: [0, 1], 1: [1, 2], 2: [3], 3: [2, 3]}
    keys = np.array(sorted(c * 4 + p for c, ps in regions.items() for p in ps))
    colour = colour_clusters(keys, 4, 4)
    for a, b in [(0, 1), (1, 3), (2, 3)]:
        assert colour[a] != colour[b]
    assert colour.tolist() == [0, 1, 0, 2]  # greedy in cluster order, the lowest colour no neighbour holds


def test_clustered_sweeps_keep_the_centre_of_mass_and_converge_as_colour_launches_do(tmp_path):
    """A free cloth (no pins) with its particles scattered: the projections move each pair by equal and opposite
    mass-weighted amounts, so the centre of mass stays put; and many sweeps bring every stick to its length, as
    the launch per colour does."""
    scene = triangle_scene(tmp_path, pins=[])
    stretch = {}
    for form in ("explicit", "clustered"):
        sim = Simulator(scene, "cpu", threads=1, sticks=form)
        start = perturbed(sim, 0.003)
        x = sweep(sim, start, 300)
        # float32 rounding over 300 sweeps moves it by about 1e-5 m; a lost or doubled move, by millimetres
        assert np.abs(x.mean(axis=0) - start.mean(axis=0)).max() < 5e-5
        stretch[form] = sim.stretch(x)
        assert sim.stretch(start).rms > 0.05
    # From over 5% RMS to under 0.05%, where the launch per colour ends, to within a tenth of it: the same
    # projections in another order (the rest of the way is the slow, cloth-wide part that any sweep leaves).
    assert stretch["clustered"].rms < 5e-4
    assert abs(stretch["clustered"].rms - stretch["explicit"].rms) < 0.1 * stretch["explicit"].rms


@pytest.mark.parametrize("simulation, cloth, why", [
    ({"relaxation": "jacobi"}, {}, "Jacobi"),
    ({}, {"tear_threshold": 1.5}, "tear"),
    ({"global_iterations": 2}, {"sticks": ["structural", "bend"], "compliance": {"bend": 0.5}}, "global correction"),
    ({"precision": "float64"}, {}, "float64"),
])
def test_clustered_sticks_are_refused_where_they_do_not_apply(simulation, cloth, why):
    scene = make_scene({"substeps": 2, "iterations": 4, **simulation}, resolution=[8, 8], **cloth)
    with pytest.raises(ArgumentError, match=why):
        Simulator(scene, "cpu", sticks="clustered")


def test_soft_sticks_are_staged_wherever_they_fit_a_blocks_shared_memory():
    from types import SimpleNamespace

    from warp_verlet.constraints.stick_clusters import MAX_SHARED_BYTES, shared_bytes, stage_soft_sticks

    # A 1024^2 triangle mesh's layout: 30,260 bytes staged, more blocks a launch than an H100 holds at once. The
    # rule is the same on every device.
    layout = SimpleNamespace(capacity=352, stick_capacity=1536, colours=12, launches=[(0, 1024)])
    assert shared_bytes(352, 1536, 12, staged_soft=True) == 30260
    assert stage_soft_sticks(layout)
    big = SimpleNamespace(capacity=MAX_SHARED_BYTES // 16 - 64, stick_capacity=64, colours=12, launches=[(0, 1)])
    assert shared_bytes(big.capacity, 64, 12) <= MAX_SHARED_BYTES < shared_bytes(big.capacity, 64, 12, True)
    assert not stage_soft_sticks(big)  # staged, it would pass the block's limit: global memory


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
@pytest.mark.parametrize("cloth, staged", [({}, True), ({"compliance": {"bend": 0.02}}, True),
                                           ({"compliance": {"bend": 0.02}}, False)],
                         ids=["rigid", "soft bend", "soft bend in global memory"])
def test_a_clustered_sweep_on_cuda_is_repeatable_and_agrees_with_the_cpu(tmp_path, monkeypatch, cloth, staged):
    from warp_verlet.constraints import stick_clusters

    monkeypatch.setattr(stick_clusters, "stage_soft_sticks", lambda layout: staged)
    scene = triangle_scene(tmp_path, **cloth)
    cpu = Simulator(scene, "cpu", threads=1, sticks="clustered")
    start = perturbed(cpu)
    on_cpu = sweep(cpu, start, 3)
    gpu = Simulator(scene, "cuda", sticks="clustered")
    first = sweep(gpu, start, 3)
    again = sweep(gpu, start, 3)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_allclose(first, on_cpu, atol=1e-5)


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
@pytest.mark.parametrize("cloth, staged", [({}, True), ({"compliance": {"bend": 0.02}}, True),
                                           ({"compliance": {"bend": 0.02}}, False)],
                         ids=["rigid", "soft bend", "soft bend in global memory"])
@pytest.mark.parametrize("rows, cluster", [(ROWS, 64), (256, 16)], ids=["all clusters at once", "more than fit"])
def test_a_chained_sweep_on_cuda_is_a_launch_per_cluster_colour_bit_for_bit(tmp_path, monkeypatch, cloth, staged,
                                                                             rows, cluster):
    """On CUDA the chained sweep's blocks run at once, each waiting for its neighbours: it must give the launch
    per cluster colour's positions exactly, over sweeps, with every cluster's blocks in flight together (without
    the waits, a cluster would read its neighbours' particles before they moved) and with more clusters than the
    GPU holds at once (the blocks waited for are those that took earlier clusters)."""
    from warp_verlet.constraints import stick_clusters

    monkeypatch.setattr(stick_clusters, "CLUSTER_PARTICLES", cluster)
    monkeypatch.setattr(stick_clusters, "stage_soft_sticks", lambda layout: staged)
    points, quads = grid_mesh(rows, rows)
    path = write_obj(tmp_path / "sheet.obj", points, triangulated(quads))
    scene = mesh_scene(tmp_path, {"mesh": path.name, "sticks": ["structural", "bend"], **cloth},
                       {"substeps": 2, "iterations": 4})
    result = {}
    for chained in (False, True):
        monkeypatch.setattr(stick_clusters, "MIN_CHAINED_PARTICLES", 0 if chained else 10**12)
        sim = Simulator(scene, "cuda", sticks="clustered")
        start = perturbed(sim)
        result[chained] = [sweep(sim, start, 4), sweep(sim, start, 4)]
    clusters = sim.model.constraints["stick clusters"].clusters
    assert clusters == -(-rows * rows // cluster)
    assert np.abs(result[False][0] - start).max() > 1e-4
    np.testing.assert_array_equal(result[True][0], result[False][0])
    np.testing.assert_array_equal(result[True][1], result[False][0])


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=[
    pytest.mark.cuda, pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")])])
def test_frames_with_a_chained_sweep_are_frames_with_a_launch_per_cluster_colour_bit_for_bit(tmp_path, monkeypatch,
                                                                                             device):
    """The chained sweep inside the solver: frames stepped (captured in a graph on CUDA) with soft bend sticks, as a
    Simulator runs them, end where a launch per cluster colour ends, bit for bit."""
    from warp_verlet.constraints import stick_clusters

    monkeypatch.setattr(stick_clusters, "CLUSTER_PARTICLES", 64)
    scene = triangle_scene(tmp_path, compliance={"bend": 0.02})
    ends = {}
    for chained in (False, True):
        monkeypatch.setattr(stick_clusters, "MIN_CHAINED_PARTICLES", 0 if chained else 10**12)
        sim = Simulator(scene, device, sticks="clustered")
        assert (sim.model.constraints["stick clusters"].neighbour is not None) == chained
        start = sim.state.positions()
        for _ in range(6):
            sim.step_frame()
        ends[chained] = sim.state.positions()
        sim.close()
    assert np.abs(ends[True] - start).max() > 1e-3  # the cloth fell and swung
    np.testing.assert_array_equal(ends[True], ends[False])


def test_a_region_larger_than_packed_ends_can_name_is_refused_with_the_reason(tmp_path, monkeypatch):
    from warp_verlet.constraints import stick_clusters

    monkeypatch.setattr(stick_clusters, "MAX_REGION", 64)
    with pytest.raises(ArgumentError, match="packed ends"):
        Simulator(triangle_scene(tmp_path), "cpu", sticks="clustered")


def test_a_cluster_larger_than_shared_memory_is_refused_with_the_reason(tmp_path, monkeypatch):
    from warp_verlet.constraints import stick_clusters

    data = Simulator(triangle_scene(tmp_path), "cpu", sticks="clustered").model.constraints["stick clusters"]
    needed = stick_clusters.shared_bytes(data.capacity, data.stick_capacity, data.colours)
    monkeypatch.setattr(stick_clusters, "MAX_SHARED_BYTES", needed)
    Simulator(triangle_scene(tmp_path), "cpu", sticks="clustered")  # exactly at the limit: taken
    monkeypatch.setattr(stick_clusters, "MAX_SHARED_BYTES", needed - 1)
    with pytest.raises(ArgumentError, match="shared memory"):
        Simulator(triangle_scene(tmp_path), "cpu", sticks="clustered")


def test_auto_chooses_clustered_stick_arrays_from_a_size_on_and_only_where_they_apply(tmp_path):
    from warp_verlet.core import stages
    from warp_verlet.core.stages import Requirements

    mesh = triangle_scene(tmp_path)
    large = mesh.particle_count >= stages.MIN_CLUSTERED_PARTICLES
    assert not large  # the test meshes are below the size on which "auto" clusters
    assert not Requirements.of(mesh, "auto").stick_clusters
    threshold = mesh.particle_count
    original = stages.MIN_CLUSTERED_PARTICLES
    try:
        stages.MIN_CLUSTERED_PARTICLES = threshold
        assert Requirements.of(mesh, "auto").stick_clusters
        assert not Requirements.of(mesh, "explicit").stick_clusters  # asked for a launch per colour
        assert not Requirements.of(triangle_scene(tmp_path, tear_threshold=1.5), "auto").stick_clusters
        grid = make_scene({"substeps": 2, "iterations": 4}, resolution=[ROWS, COLS])
        assert not Requirements.of(grid, "auto").stick_clusters  # one grid cloth: implicit sticks or tiles
        stages.MIN_CLUSTERED_PARTICLES = threshold + 1
        assert not Requirements.of(mesh, "auto").stick_clusters
    finally:
        stages.MIN_CLUSTERED_PARTICLES = original


def test_auto_keeps_a_launch_per_colour_where_the_clustered_layout_is_refused(tmp_path, monkeypatch):
    from warp_verlet.constraints import stick_clusters
    from warp_verlet.core import model as model_module, stages

    scene = triangle_scene(tmp_path)
    # As on a GPU ("auto" reaches Requirements.of), with the scene above the size "auto" clusters from.
    monkeypatch.setattr(model_module, "stick_form", lambda sticks, colouring, device: sticks)
    monkeypatch.setattr(stages, "MIN_CLUSTERED_PARTICLES", 1)
    chosen = Simulator(scene, "cpu", threads=1)
    assert chosen.model.sticks_form == "clustered" and "stick clusters" in chosen.constraint_sets

    monkeypatch.setattr(stick_clusters, "MAX_SHARED_BYTES", 1024)
    kept = Simulator(scene, "cpu", threads=1)
    assert kept.model.sticks_form == "explicit" and kept.model.stick_request == "explicit"
    assert "sticks" in kept.constraint_sets and "stick clusters" not in kept.constraint_sets
    assert "shared memory" in kept.model.clusters_refused
    explicit = Simulator(scene, "cpu", threads=1, sticks="explicit")
    for _ in range(3):
        kept.step_frame()
        explicit.step_frame()
    np.testing.assert_array_equal(kept.state.positions(), explicit.state.positions())
    kept.retune(iterations=2)  # a later Requirements asks for the form the model kept
    kept.step_frame()
    with pytest.raises(ArgumentError, match="shared memory"):  # asked for by name, the refusal stands
        Simulator(scene, "cpu", threads=1, sticks="clustered")


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
def test_auto_sweeps_a_large_mesh_cluster_by_cluster_on_cuda(tmp_path, monkeypatch):
    from warp_verlet.core import stages

    monkeypatch.setattr(stages, "MIN_CLUSTERED_PARTICLES", ROWS * COLS)
    sim = Simulator(triangle_scene(tmp_path), "cuda")
    assert sim.model.sticks_form == "clustered" and sim.model.clusters_refused is None
    sim.step_frame()
    assert np.isfinite(sim.state.positions()).all()
    assert Simulator(triangle_scene(tmp_path), "cpu").model.sticks_form == "explicit"  # the CPU keeps arrays


@pytest.mark.slow
def test_every_shipped_scene_a_clustered_sweep_can_take_runs_with_it_as_stretched_as_with_a_launch_per_colour():
    """The clustered sweep composes with every stage the shipped scenes use (mesh colliders, self-collision, air,
    soft sticks, angle limits, tethers): 60 frames end finite, and over the last 40 of them the mean RMS and max
    stretch are within 1.5x a launch per colour's, the same projections in another order (a mean over many frames,
    because a flag fluttering in the air changes its longest stick's stretch 3x from frame to frame, in either
    order: over 10 frames the two orders' means of it differed 1.75x). The scenes of a million
    particles are left to the benchmarks."""
    from warp_verlet.core.stages import Requirements, cluster_obstacle
    from warp_verlet.input.scene import load_scene

    taken = 0
    for path in sorted((Path(__file__).resolve().parent.parent / "scenes").glob("*.toml")):
        scene = load_scene(path)
        if scene.particle_count > 10_000 or cluster_obstacle(scene, Requirements.of(scene, "explicit")):
            continue
        stretch = {}
        for form in ("explicit", "clustered"):
            sim = Simulator(scene, "cpu", sticks=form)
            late = []
            for frame in range(60):
                sim.step_frame()
                if frame >= 20:
                    late.append(sim.stretch())
            assert np.isfinite(sim.state.positions()).all(), (path.name, form)
            stretch[form] = {measure: float(np.mean([getattr(s, measure) for s in late])) for measure in ("rms", "max")}
        for measure in ("rms", "max"):
            ours, theirs = stretch["clustered"][measure], stretch["explicit"][measure]
            assert ours < 1.5 * theirs + 1e-4 and theirs < 1.5 * ours + 1e-4, (path.name, measure, ours, theirs)
        taken += 1
    assert taken >= 12  # the shipped scenes that cannot tear


def test_the_run_summary_says_how_the_sticks_were_swept_and_why_auto_did_not_cluster(tmp_path, monkeypatch):
    from warp_verlet.apps.runner import SWEEP_FORMS, run_scene, sweep_description
    from warp_verlet.constraints import stick_clusters
    from warp_verlet.core import model as model_module, stages

    grid = grid_scene()
    assert sweep_description(Simulator(grid, "cpu").model) == SWEEP_FORMS["explicit"]  # "auto" on the CPU
    for form in ("implicit", "tiled"):
        assert sweep_description(Simulator(grid, "cpu", sticks=form).model) == SWEEP_FORMS[form]
    jacobi = make_scene({"substeps": 2, "iterations": 4, "relaxation": "jacobi"}, resolution=[8, 8])
    assert "Jacobi" in sweep_description(Simulator(jacobi, "cpu").model)

    mesh = triangle_scene(tmp_path)
    summary = run_scene(mesh, tmp_path / "mesh.usdc", device="cpu", frames=2).format()
    assert f"sweep            {SWEEP_FORMS['explicit']}\n" in summary
    monkeypatch.setattr(model_module, "stick_form", lambda sticks, colouring, device: sticks)  # as on a GPU
    monkeypatch.setattr(stages, "MIN_CLUSTERED_PARTICLES", 1)
    assert sweep_description(Simulator(mesh, "cpu").model) == SWEEP_FORMS["clustered"]
    monkeypatch.setattr(stick_clusters, "MIN_CHAINED_PARTICLES", mesh.particle_count)
    chained = SWEEP_FORMS["clustered"] + ", chained (one launch a sweep)"
    assert sweep_description(Simulator(mesh, "cpu").model) == chained
    monkeypatch.setattr(stick_clusters, "MIN_CHAINED_PARTICLES", mesh.particle_count + 1)
    monkeypatch.setattr(stick_clusters, "MAX_SHARED_BYTES", 1024)
    kept = sweep_description(Simulator(mesh, "cpu").model)
    assert kept.startswith(SWEEP_FORMS["explicit"] + " (clustered refused: ") and "shared memory" in kept
