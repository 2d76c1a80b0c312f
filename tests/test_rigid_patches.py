"""Rigid patches (warp_verlet/constraints/rigid_patches.py, kernels/rigid_patches.py): every pairwise distance
inside a patch stays at its rest value while the cloth moves, a patch's centre of mass follows free fall, the
projection keeps momentum, patches compose with pins, and bad patches are refused."""

from __future__ import annotations

import numpy as np
import pytest

from warp_verlet.errors import SceneError
from warp_verlet.scene import parse_scene
from warp_verlet.simulator import Simulator

RIGID_TOLERANCE = 1.0e-6
"""Metres a pairwise distance inside a 0.2 m patch may be off its rest value at a frame: the patch's last
projection puts it on its rest shape exactly, up to float32 rounding of positions near 2 m (about 2.4e-7)."""

LABEL = {"min": [0.3, -1.0, 0.2], "max": [0.5, 3.0, 0.4]}  # a 5 x 5 square of the flag below


def flag(simulation: dict | None = None, **cloth) -> dict:
    spec = {"name": "flag", "resolution": [16, 24], "size": [0.6, 0.9], "origin": [0.0, 2.0, 0.0],
            "orientation": "horizontal", "pins": ["top-left", "top-right"], "sticks": ["structural", "shear"]}
    spec.update(cloth)
    return {"simulation": {"fps": 60, "substeps": 8, "iterations": 16, "damping": 0.5, **(simulation or {})},
            "cloth": [spec]}


def distances(points: np.ndarray) -> np.ndarray:
    p = points.astype(np.float64)
    return np.linalg.norm(p[:, None] - p[None], axis=2)


def worst_pair_error(sim: Simulator, members: np.ndarray, frames: int) -> tuple[float, float]:
    """(worst |distance - rest distance| inside the patch over the frames, how far the patch moved)."""
    start = sim.positions()[members]
    rest = distances(start)
    worst = 0.0
    for _ in range(frames):
        sim.step_frame()
        worst = max(worst, float(np.abs(distances(sim.positions()[members]) - rest).max()))
    return worst, float(np.abs(sim.positions()[members] - start).max())


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_a_patch_keeps_its_shape_while_the_cloth_falls_and_folds(precision):
    sim = Simulator(parse_scene(flag({"precision": precision}, rigid_patches=[[LABEL]])), "cpu")
    (patch,) = sim.scene.cloths[0].options["rigid_patches"]
    assert len(patch) == 25
    members = np.array(patch)
    worst, moved = worst_pair_error(sim, members, 90)
    assert moved > 0.2, "the patch hardly moved: the test would pass without the constraint"
    assert worst <= RIGID_TOLERANCE
    plain = Simulator(parse_scene(flag({"precision": precision})), "cpu")
    assert worst_pair_error(plain, members, 90)[0] > 100 * RIGID_TOLERANCE  # the same square without it bends


def test_the_patch_runs_last_in_a_sweep(launches):
    sim = Simulator(parse_scene(flag(rigid_patches=[[LABEL]])), "cpu", use_graph=False)
    assert sim.constraint_sets[-1] == "rigid patches"
    names = launches.of(sim.step)
    assert names.count("match_patches") == sim.settings.iterations
    assert names.index("match_patches") > names.index("relax_colour")


def test_a_free_falling_patch_follows_free_fall():
    # No pins: the whole cloth and its two patches fall freely from rest; each patch's centre of mass drops
    # g t^2 / 2, as every particle does (constant-acceleration Verlet is exact for it).
    data = flag({"frames": 30, "damping": 0.0}, pins=[], rigid_patches=[[LABEL], [[0, 0], [0, 1], [1, 0], [1, 1]]])
    sim = Simulator(parse_scene(data), "cpu")
    patches = [np.array(p) for p in sim.scene.cloths[0].options["rigid_patches"]]
    start = [sim.positions()[p].astype(np.float64).mean(0) for p in patches]
    for _ in range(30):
        sim.step_frame()
    t = 30 / 60
    for p, c0 in zip(patches, start):
        expected = c0 + np.array([0.0, -0.5 * 9.81 * t * t, 0.0])
        assert np.abs(sim.positions()[p].astype(np.float64).mean(0) - expected).max() < 1e-5


def test_the_projection_keeps_the_cloths_momentum():
    # A cloth thrown tumbling (each particle its own velocity) with a patch: the projections move particles but
    # not the mass-weighted centroid, so the cloth's centre of mass follows x0 + v0 t + g t^2 / 2 exactly.
    data = flag({"frames": 30, "damping": 0.0}, pins=[], rigid_patches=[[LABEL]])
    sim = Simulator(parse_scene(data), "cpu")
    rng = np.random.default_rng(3)
    velocity = rng.normal(0.0, 1.0, (sim.model.particle_count, 3))
    sim.state.set_velocity(velocity)
    x0 = sim.positions().astype(np.float64).mean(0)
    v0 = velocity.mean(0)  # equal masses
    for _ in range(30):
        sim.step_frame()
    t = 30 / 60
    expected = x0 + v0 * t + np.array([0.0, -0.5 * 9.81 * t * t, 0.0])
    assert np.abs(sim.positions().astype(np.float64).mean(0) - expected).max() < 1e-4


def test_a_patch_holding_a_pin_turns_about_it():
    # The patch's corner is the cloth's only pin: the patch swings about it, rigid, the pin where it was.
    data = flag(pins=["top-left"], rigid_patches=[[[r, c] for r in range(4) for c in range(4)]])
    sim = Simulator(parse_scene(data), "cpu")
    members = np.array(sim.scene.cloths[0].options["rigid_patches"][0])
    pin = sim.positions()[0].copy()
    worst, moved = worst_pair_error(sim, members, 60)
    assert moved > 0.05 and worst <= RIGID_TOLERANCE
    assert np.array_equal(sim.positions()[0], pin)


def test_patches_on_a_mesh_cloth(tmp_path):
    from test_angle_limit import strip_obj

    strip_obj(tmp_path / "strip.obj")  # 4 x 20 vertices, 0.05 m apart, in the y = 1 plane
    data = {"simulation": {"fps": 60, "substeps": 8, "iterations": 16},
            "cloth": [{"mesh": "strip.obj", "pins": [0, 20, 40, 60], "sticks": ["structural", "shear"],
                       "rigid_patches": [[{"min": [0.6, 0.0, -1.0], "max": [0.8, 2.0, 1.0]}], [10, 11, 30, 31]]}]}
    sim = Simulator(parse_scene(data, str(tmp_path / "s.toml"), tmp_path / "s.toml"), "cpu")
    first, second = (np.array(p) for p in sim.scene.cloths[0].options["rigid_patches"])
    assert len(first) == 4 * 5 and list(second) == [10, 11, 30, 31]
    for members in (first, second):
        sim2 = Simulator(parse_scene(data, str(tmp_path / "s.toml"), tmp_path / "s.toml"), "cpu")
        worst, moved = worst_pair_error(sim2, members, 45)
        assert moved > 0.05 and worst <= RIGID_TOLERANCE


@pytest.mark.parametrize("patches, key, problem", [
    ([[0]], "rigid_patches[0]", "two particles or more"),
    ([[0, 1], [1, 2]], "rigid_patches[1]", "shares particle 1 with rigid_patches[0]"),
    ([[0, 10_000]], "rigid_patches[0][1]", "outside the grid"),
    ([[[0, 0], [99, 0]]], "rigid_patches[0][1]", "outside the 16 x 24 grid"),
    ([[{"min": [5, 5, 5], "max": [6, 6, 6]}]], "rigid_patches[0][0]", "holds no particle"),
    ([["top-middle"]], "rigid_patches[0][0]", "unknown pin name"),
    ([[0, 1.5]], "rigid_patches[0][1]", "expected a particle index"),
    ([], "rigid_patches", "expected an array of patches"),
    ([[]], "rigid_patches[0]", "non-empty array"),
    ([[{"min": [1, 0, 0], "max": [0, 1, 1]}]], "rigid_patches[0][0]", "min <= max"),
])
def test_bad_patches_are_refused_naming_the_key(patches, key, problem):
    with pytest.raises(SceneError) as err:
        parse_scene(flag(rigid_patches=patches), "flag.toml")
    assert f"cloth[0].{key}" in str(err.value) and problem in str(err.value), str(err.value)
