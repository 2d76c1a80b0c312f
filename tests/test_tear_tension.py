"""Tearing by tension (``tear_tension``, N/m): a stick tears when the force it transmits, averaged over
TENSION_AVERAGE_TIME, passes tear_tension x its rest length.

The checks are analytic. In a chain hanging from a pin, the stick at height h carries the weight below it, at
any number of sweeps once the chain is still (each substep's corrections then undo exactly the fall that
gravity gave). Loaded at t = 0, the average F(t) = W (1 - exp(-t / tau)) crosses a limit F* below the load W at
t* = -tau ln(1 - F* / W).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import make_scene
from test_memory import mesh_native_bytes, simulator_bytes
from warp_verlet.core.memory import estimate
from warp_verlet.core.simulator import Simulator
from warp_verlet.core.stages import TENSION_AVERAGE_TIME
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene

G = 9.81
LINKS, PARTICLE_MASS, LINK = 8, 0.1, 0.1  # a chain of 8 sticks 10 cm long, 100 g a particle, pinned at the top
SUBSTEPS = 32
DT = 1.0 / (60 * SUBSTEPS)


def chain(limit: float | None = None, precision: str = "float64", iterations: int = 64, device: str = "cpu",
          **cloth) -> Simulator:
    """The hanging chain; ``limit`` is the tear force in N (tear_tension = limit / L), None: very strong."""
    tension = 1e9 if limit is None else limit / LINK
    scene = make_scene({"fps": 60, "substeps": SUBSTEPS, "iterations": iterations, "precision": precision},
                       resolution=[LINKS + 1, 1], size=[LINK * LINKS, 0.0], pins=["top-left"],
                       mass=PARTICLE_MASS * (LINKS + 1), sticks=["structural"], tear_tension=tension, **cloth)
    return Simulator(scene, device)


def top_down(sim: Simulator) -> np.ndarray:
    """The chain's sticks from the pin down (the order of their upper particle)."""
    return np.argsort(sim.model.host_sticks.min(axis=1))


def weight_below(k: int) -> float:
    """The weight (N) that the k-th stick from the top carries: the particles below it."""
    return (LINKS - k) * PARTICLE_MASS * G


# float32: a substep's fall g dt^2 = 2.7e-6 m is 45 float32 spacings of a coordinate near 0.5 m, so each
# correction is rounded by about 2%.
@pytest.mark.parametrize("precision, tolerance", [("float64", 1e-6), ("float32", 5e-2)])
def test_a_still_chain_carries_the_weight_below_each_stick(device, precision, tolerance):
    # 2 sweeps a substep leave the chain 0.1% stretched, but once it is still the force is exact: what the
    # substep's corrections add up to is what holds the particles up against gravity.
    sim = chain(precision=precision, iterations=2, device=device)
    for _ in range(60):
        sim.step_frame()
    force = sim.state.stick_force.numpy()[top_down(sim)]
    expected = np.array([weight_below(k) for k in range(LINKS)])
    np.testing.assert_allclose(force, expected, rtol=tolerance)
    assert sim.torn_count() == 0


@pytest.mark.parametrize("between", [0, 2])
def test_a_chain_tears_at_its_top_when_the_limit_is_below_the_weight_there(device, between):
    # A limit between the weights below sticks `between` and `between + 1`: every stick above it carries more
    # than the limit, but the top one carries the most, so its average crosses first, at t*, and the chain
    # below falls freely, unloaded: no other stick tears.
    limit = 0.5 * (weight_below(between) + weight_below(between + 1))
    sim = chain(limit, device=device)
    order = top_down(sim)
    expected = -TENSION_AVERAGE_TIME * math.log(1.0 - limit / weight_below(0))
    torn_at = None
    for n in range(1, 2 * SUBSTEPS * 60 // 10):  # 0.2 s
        sim.step()
        if torn_at is None and sim.torn_count():
            torn_at = n
    assert torn_at is not None and abs(torn_at * DT - expected) <= 2 * DT, (torn_at * DT, expected)
    assert list(sim.torn_sticks()[order]) == [True] + [False] * (LINKS - 1)


def test_a_chain_does_not_tear_under_a_limit_just_above_its_load(device):
    sim = chain(1.02 * weight_below(0), device=device)
    for _ in range(30):
        sim.step_frame()
    assert sim.torn_count() == 0
    assert sim.state.stick_force.numpy()[top_down(sim)][0] == pytest.approx(weight_below(0), rel=1e-6)


def test_a_stick_that_never_reaches_its_tear_force_leaves_the_motion_bit_identical(device):
    # The relaxation that keeps the tension moves the particles exactly as the plain one: a chain that swings
    # (started sideways) with a tear force it never reaches matches the same chain that cannot tear, bit for bit.
    def swing(**tearing):
        scene = make_scene({"fps": 60, "substeps": 8, "iterations": 4}, resolution=[LINKS + 1, 1],
                           size=[LINK * LINKS, 0.0], pins=["top-left"], orientation="horizontal",
                           mass=PARTICLE_MASS * (LINKS + 1), sticks=["structural", "bend"], tethers=False,
                           compliance={"bend": 1e-3} if tearing.pop("soft", False) else {}, **tearing)
        sim = Simulator(scene, device)
        for _ in range(20):
            sim.step_frame()
        return sim.positions()

    for soft in (False, True):
        np.testing.assert_array_equal(swing(soft=soft, tear_tension=1e6), swing(soft=soft))


def hanging_sheet(device: str = "cpu", **tearing) -> Simulator:
    """A 16 x 16 sheet, 0.6 m, 0.5 kg, pinned along its top edge, rigid structural sticks and soft shear and bend,
    at the 32 x 2 budget that leaves it under 0.1% stretch. Each column hangs from its top structural stick,
    which carries the 15 particles below it: F = 15 m g (the soft sticks carry under 1% of it)."""
    scene = make_scene({"fps": 60, "substeps": 32, "iterations": 2}, resolution=[16, 16], size=[0.6, 0.6],
                       pins=["top-edge"], mass=0.5, sticks=["structural", "shear", "bend"],
                       compliance={"shear": 1e-2, "bend": 1e-1}, tethers=False, **tearing)
    return Simulator(scene, device)


SHEET_TOP_FORCE = 15 * 0.5 / 256 * G  # N
SHEET_SPACING = 0.6 / 15  # m


def settled_sheet(device: str, **tearing) -> Simulator:
    """The sheet after 1 s without tearing (released from rest it rings for about half a second, its soft sticks
    springing), continued with ``tearing``."""
    still = hanging_sheet(device)
    for _ in range(60):
        still.step_frame()
    sim = hanging_sheet(device, **tearing)
    sim.take_state(still)
    return sim


@pytest.mark.parametrize("ratio, tears", [(0.95, True), (1.02, False)])
def test_a_converged_sheet_tears_along_its_pinned_edge_by_tension(device, ratio, tears):
    sim = settled_sheet(device, tear_tension=ratio * SHEET_TOP_FORCE / SHEET_SPACING)
    assert sim.stretch().max < 0.01  # converged
    for _ in range(6):  # 0.1 s, ten averaging times; the first tears are the ones checked (the sheet then hangs
        sim.step_frame()  # by its soft sticks, springing, and tears further)
        if sim.torn_count():
            break
    torn = sim.torn_sticks()
    if not tears:
        assert not torn.any()
        return
    sticks, inv_mass = sim.model.host_sticks, sim.model.host_inv_mass
    pinned_end = (inv_mass[sticks] == 0).sum(axis=1) == 1
    top_structural = sim.model.structural & pinned_end  # the 16 sticks from the pins down
    assert top_structural.sum() == 16
    assert np.array_equal(torn, top_structural)


@pytest.mark.parametrize("threshold", [1.01, 1.1])
def test_the_stretch_threshold_does_not_tear_the_same_converged_sheet(device, threshold):
    sim = hanging_sheet(device, tear_threshold=threshold)  # from its release: the stretch peaks while it rings
    for _ in range(66):
        sim.step_frame()
    assert sim.torn_count() == 0
    assert sim.stretch().max < 0.01


def test_with_both_criteria_either_tears(device):
    # The stretch threshold still tears what the tension does not reach: a chain with a tear force far above
    # its load but a threshold its first substeps pass (no sweeps: it falls freely from the pin).
    scene = make_scene({"fps": 60, "substeps": 4, "iterations": 0}, resolution=[LINKS + 1, 1],
                       size=[LINK * LINKS, 0.0], pins=["top-left"], sticks=["structural"], tear_tension=1e6,
                       tear_threshold=1.01)
    sim = Simulator(scene, device)
    for _ in range(10):
        sim.step()
    assert sim.torn_count() == 1


# ------------------------------------------------------------------------------------------------- tethers
# The rule: a tether's pull is not counted in any stick's tension. A tether holds only beyond tether_scale x
# its rest distance, so above the converged cloth's stretch it never pulls and the sticks carry, and tear by,
# the whole load; at scale 1 it holds a straight hanging particle itself and the sticks between it and its pin
# carry nothing. Once a stick tears, every tether whose particle is cut off from its pin is dropped.

def test_slack_tethers_leave_the_tension_and_the_tear_unchanged(device):
    limit = 0.7 * weight_below(0)
    runs = []
    for tethers in ({}, {"tethers": True, "tether_scale": 1.05}):
        sim = chain(limit, device=device, **tethers)
        forces, torn_at = [], None
        for n in range(1, 200):
            sim.step()
            forces.append(sim.state.stick_force.numpy()[top_down(sim)][0])
            if torn_at is None and sim.torn_count():
                torn_at = n
        runs.append((torn_at, np.array(forces), sim.positions()))
    (torn_plain, force_plain, x_plain), (torn_tethered, force_tethered, x_tethered) = runs
    assert torn_plain is not None and torn_tethered == torn_plain
    np.testing.assert_array_equal(force_tethered, force_plain)


def test_taut_tethers_carry_the_load_themselves_and_nothing_tears(device):
    sim = chain(0.1 * weight_below(0), device=device, tethers=True, tether_scale=1.0)
    for _ in range(30):
        sim.step_frame()
    assert sim.torn_count() == 0
    assert np.abs(sim.state.stick_force.numpy()).max() < 1e-3 * weight_below(0)


def test_a_torn_off_chain_loses_its_tethers_and_falls_freely(device):
    # Tethers at 1.05: the top stick tears at t*; once the tear is synced the chain below is cut off from the pin
    # and its tethers are dropped, so its bottom falls g t^2 / 2 from where it was (it was still at the tear:
    # the chain hung at rest). Kept, the tethers would catch it within 5% of its rest distance.
    sim = chain(0.7 * weight_below(0), device=device, tethers=True, tether_scale=1.05)
    for _ in range(SUBSTEPS * 6):  # 0.1 s: it tears at 12 ms
        sim.step()
        if sim.torn_count():
            break
    assert sim.torn_count() == 1
    sim.sync_tears()
    assert np.isinf(sim.state.tether_length.numpy()).all()
    bottom = int(np.argmin(sim.model.rest_positions[:, 1]))
    y0 = sim.positions()[bottom, 1]
    steps = 96  # 0.05 s
    for _ in range(steps):
        sim.step()
    t = steps * DT
    fall = y0 - sim.positions()[bottom, 1]
    assert fall == pytest.approx(0.5 * G * t * t, rel=0.02)


# ------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("value", [-1.0, 0.0, math.inf, math.nan])
def test_a_bad_tear_tension_is_one_scene_error_naming_the_file_and_key(value):
    with pytest.raises(SceneError) as info:
        parse_scene({"cloth": [{"resolution": [4, 4], "size": [1.0, 1.0], "tear_tension": value}]}, file="flag.toml")
    assert info.value.file == "flag.toml" and info.value.key == "cloth[0].tear_tension"
    assert "flag.toml: cloth[0].tear_tension" in str(info.value)


def test_tearing_by_tension_needs_the_coloured_solver():
    with pytest.raises(SceneError) as info:
        make_scene({"relaxation": "jacobi"}, tear_tension=10.0)
    assert info.value.key == "cloth[0].tear_tension" and "coloured" in str(info.value)


# ------------------------------------------------------------------------------ launches and memory
@pytest.mark.parametrize("compliance, relax", [({}, "relax_colour_tension"),
                                               ({"bend": 1e-3}, "relax_colour_compliant")])
def test_a_tension_scene_launches_the_tension_kernels(launches, compliance, relax):
    scene = make_scene({"iterations": 2}, resolution=[4, 5], pins=["top-edge"], sticks=["structural", "bend"],
                       compliance=compliance, tear_tension=10.0)
    sim = Simulator(scene, "cpu", use_graph=False)
    names = launches.of(sim.step)
    colours = len(sim.model.colour_ranges)
    assert names.count("zero") == 1  # the tension restarts every substep
    assert [n for n in names if n.startswith("relax_")] == [relax] * (2 * colours)
    assert names[-1] == "tear_sticks_by_tension" and "tear_sticks" not in names


@pytest.mark.parametrize("cloth", [
    {"tear_tension": 10.0},
    {"tear_tension": 10.0, "compliance": {"shear": 1e-4, "bend": 1e-3}},
    {"tear_tension": 10.0, "tear_threshold": 1.5, "pins": ["top-edge"], "tethers": True, "tether_scale": 1.2},
    {"tear_tension": 10.0, "precision_float64": True},
])
def test_the_memory_estimate_counts_the_tension_arrays(cloth):
    cloth = dict(cloth)
    simulation = {"precision": "float64"} if cloth.pop("precision_float64", False) else {}
    spec = {"resolution": [24, 31], "size": [1.0, 1.0], "sticks": ["structural", "shear", "bend"], **cloth}
    scene = parse_scene({"simulation": simulation, "cloth": [spec]}, file="<test>")
    sim = Simulator(scene, "cpu", use_graph=False)
    sim.step()
    counters = 4  # the tear counter
    allocated = simulator_bytes(sim) + mesh_native_bytes(sim)
    assert allocated - estimate(scene, sim.model.sticks_form).device_bytes == counters


@pytest.mark.slow
def test_the_shipped_flag_tears_off_its_pole_while_converged():
    # The converged budget (32 x 2) keeps the cloth under 1% RMS stretch in every frame, tearing or not; by the end
    # no free particle is joined to a pin through intact sticks.
    from pathlib import Path

    from warp_verlet.geometry.mesh_cloth import connected_labels
    from warp_verlet.input.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parent.parent / "scenes" / "flag_tear.toml")
    sim = Simulator(scene, "cpu")
    torn, worst = 0, 0.0
    for _ in range(scene.simulation.frames):
        sim.step_frame()
        if sim.torn_count() != torn:
            torn = sim.torn_count()
            sim.sync_tears()
        worst = max(worst, sim.stretch().rms)
    assert worst < 0.01
    model = sim.model
    labels = connected_labels(model.particle_count, model.host_sticks[~sim.torn_sticks()])
    pinned = model.host_inv_mass == 0
    assert not np.isin(labels[~pinned], labels[pinned]).any()


def gale(**simulation):
    """A 16 x 24 flag on a pole in a 72 m/s^2 wind, rigid structural and soft shear sticks, that tears by
    tension within 30 frames."""
    settings = {"fps": 60, "substeps": 8, "iterations": 4, "wind": [60.0, 0.0, 40.0], **simulation}
    return make_scene(settings, resolution=[16, 24], size=[0.6, 0.9], pins=["left-edge"], mass=0.1,
                      sticks=["structural", "shear"], compliance={"shear": 0.03}, tear_tension=12.0,
                      tear_threshold=2.0)


def test_tearing_by_tension_is_bit_identical_on_any_thread_count_and_captured_or_not():
    # Each stick's tension is written only by the thread that projects it, and the tear kernel reads it once
    # the sweeps are done: the torn set, the averaged forces and the positions do not depend on the threads.
    def run(**options):
        sim = Simulator(gale(), "cpu", **options)
        for _ in range(30):
            sim.step_frame()
        return sim.positions(), sim.torn_sticks(), sim.state.stick_force.numpy()

    one = run(threads=1)
    assert one[1].any()
    for other in (run(threads=3), run(threads=1, use_graph=False)):
        for a, b in zip(one, other):
            np.testing.assert_array_equal(a, b)
