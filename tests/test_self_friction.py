"""Coulomb friction in self contact (kernels/self_contact.py): a sheet slid over another sheet lying on the ground
stops after v0^2 / (2 mu_k g), whatever the substeps, and keeps sliding without friction; the result is
bit-identical with and without the frame's capture; bad keys are refused.

The two sheets are the same 6 x 6 grid, one particle above each particle of the other, a thickness (the rest
spacing, 0.2 m) apart, so that every contact pushes straight up while the top sheet is still. The lower sheet is
ten times heavier and lies on a ground with high friction, which holds it; damping is off.
"""

from __future__ import annotations

import numpy as np
import pytest

from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene

G = 9.81
N, SIZE = 6, 1.0
SPACING = SIZE / (N - 1)
MU = 0.5
STOP = 0.004  # m: the stopping distance v0^2 / (2 mu_k g) the top sheet is launched for
STOP_TOLERANCE = 0.10
"""Relative. The lower sheet is a lattice of spheres, not a plane: as the top sheet slides off their tops, the
contact normals tilt forward by up to STOP / thickness and push it on (about STOP / (2 thickness mu_k) = 2% of
the friction), and the contact's support takes a few substeps to settle (measured: 6% over at 8 substeps, 4% at
32)."""
GROUND = {"type": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0], "friction_coefficient": 1.0}


def stacked(mu: float | None, substeps: int, use_graph: bool = False) -> Simulator:
    """The two sheets at rest, the top one launched along +X at sqrt(2 mu g STOP) (MU's speed without
    friction)."""
    lower = {"name": "lower", "resolution": [N, N], "size": [SIZE, SIZE], "origin": [-SIZE / 2, 0.0, -SIZE / 2],
             "orientation": "horizontal", "sticks": ["structural", "shear"], "mass": 1.0, "self_collision": True,
             "collision_thickness": SPACING}
    if mu is not None:
        lower["self_friction_coefficient"] = mu
    upper = dict(lower, name="upper", origin=[-SIZE / 2, SPACING, -SIZE / 2], mass=0.1)
    scene = parse_scene({"simulation": {"fps": 60, "substeps": substeps, "iterations": 2, "damping": 0.0},
                         "cloth": [lower, upper], "collider": [GROUND]}, file="<test>")
    sim = Simulator(scene, "cpu", use_graph=use_graph)
    velocity = np.zeros((sim.model.particle_count, 3))
    velocity[sim.model.cloths[1].particles, 0] = np.sqrt(2 * MU * G * STOP)
    sim.state.set_velocity(velocity)
    return sim


def slide(sim: Simulator, frames: int = 12) -> tuple[float, float]:
    """(how far the top sheet moved along +X, its speed over the last frame) after ``frames`` frames."""
    top = sim.model.cloths[1].particles
    start = sim.positions()[top].astype(np.float64)
    for _ in range(frames):
        before = sim.positions()[top].astype(np.float64)
        sim.step_frame()
    end = sim.positions()[top].astype(np.float64)
    return float((end - start)[:, 0].mean()), float((end - before)[:, 0].mean() * sim.settings.fps)


@pytest.mark.parametrize("substeps", [8, 32])
def test_a_sheet_slid_over_another_stops_after_coulombs_distance(substeps):
    # v0 = 0.198 m/s stops in 0.04 s (v0 / (mu g)) after 4 mm; 12 frames are 0.2 s.
    sim = stacked(MU, substeps)
    moved, speed = slide(sim)
    assert moved == pytest.approx(STOP, rel=STOP_TOLERANCE)
    assert abs(speed) < 1e-3
    lower = sim.model.cloths[0].particles
    assert np.abs(sim.positions()[lower, 0] - sim.model.rest_positions[lower, 0]).max() < 1e-4  # held by the ground


def test_without_friction_it_keeps_sliding():
    v0 = np.sqrt(2 * MU * G * STOP)
    for mu in (None, 0.0):
        moved, speed = slide(stacked(mu, 8))
        # Nothing slows it: off the tops of the lower sheet's spheres the contact normals tilt forward, so it
        # gains speed (0.2 s at v0 alone would be 40 mm).
        assert speed >= v0
        assert moved > 8 * STOP


def test_friction_conserves_momentum_between_two_sheets_of_different_masses():
    # No ground: the light sheet, thrown down onto the heavy one and along +X, is slowed along X by friction and
    # the heavy one pulled along, each by its inverse-mass share, so the two sheets' X momentum stays 0.1 kg m/s.
    lower = {"name": "lower", "resolution": [N, N], "size": [SIZE, SIZE], "origin": [-SIZE / 2, 0.0, -SIZE / 2],
             "orientation": "horizontal", "sticks": ["structural", "shear"], "mass": 1.0, "self_collision": True,
             "self_friction_coefficient": MU}
    upper = dict(lower, name="upper", origin=[-SIZE / 2, 2 * SPACING, -SIZE / 2], mass=0.1)
    scene = parse_scene({"simulation": {"fps": 60, "substeps": 8, "iterations": 2, "damping": 0.0},
                         "cloth": [lower, upper]}, file="<test>")
    sim = Simulator(scene, "cpu", use_graph=False)
    top = sim.model.cloths[1].particles
    velocity = np.zeros((sim.model.particle_count, 3))
    velocity[top] = (1.0, -2.0, 0.0)
    sim.state.set_velocity(velocity)
    mass = 1.0 / sim.model.host_inv_mass.astype(np.float64)
    for _ in range(12):
        sim.step_frame()
    v = (sim.positions().astype(np.float64) - sim.state.previous_positions().astype(np.float64)) / sim.dt
    assert (mass * v[:, 0]).sum() == pytest.approx(0.1, rel=1e-3)
    assert v[top, 0].mean() < 0.5  # friction acted: the light sheet lost half its speed along X


def test_friction_is_bit_identical_with_and_without_the_capture():
    runs = []
    for use_graph in (True, False):
        sim = stacked(MU, 8, use_graph)
        slide(sim, 4)
        runs.append(sim.positions())
    assert np.array_equal(*runs)


@pytest.mark.parametrize("keys, problem", [
    ({"self_friction_coefficient": 0.3}, r"self_friction_coefficient.*needs self_collision = true"),
    ({"self_static_friction_coefficient": 0.3}, r"self_static_friction_coefficient.*needs self_collision = true"),
    ({"self_collision": True, "self_friction_coefficient": -0.1}, r"self_friction_coefficient.*expected a number"),
    ({"self_collision": True, "self_friction_coefficient": 0.5, "self_static_friction_coefficient": 0.4},
     r"self_static_friction_coefficient.*at least self_friction_coefficient \(0\.5\).*got 0\.4"),
])
def test_bad_friction_keys_are_refused(keys, problem):
    from conftest import make_scene

    with pytest.raises(SceneError, match=problem):
        make_scene(resolution=[4, 4], size=[1.0, 1.0], **keys)
