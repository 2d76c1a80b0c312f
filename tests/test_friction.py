"""Coulomb friction at the position level, against its closed forms, whatever the substeps.

A flat cloth lies on a collider's surface. Tilting gravity by theta off the surface's normal is the same
physics as tilting the surface under upright gravity, and keeps the cloth exactly in the surface, so its
sticks stay at rest length and only the contact acts on its motion: it must stay put while tan(theta) < mu_s,
and otherwise slide at g (sin(theta) - mu_k cos(theta)). On a level surface a cloth launched at v0 stops after
v0^2 / (2 mu_k g). Damping is off, so that friction alone takes the speed away.
"""

import math

import numpy as np
import pytest

from warp_verlet.colliders import coulomb
from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene

G = 9.81
FPS = 60
SHEET = {"name": "sheet", "resolution": [4, 4], "size": [0.3, 0.3], "origin": [-0.15, 0.0, -0.15],
         "orientation": "horizontal", "sticks": ["structural", "shear"]}


def lying_on(collider, surface_height, theta_degrees, substeps, velocity=None, precision="auto"):
    """A simulator of SHEET lying exactly on ``collider``'s upper surface (``surface_height`` up), gravity
    tilted by ``theta_degrees`` towards +X; with ``velocity`` (m/s, along +X) it starts sliding."""
    theta = math.radians(theta_degrees)
    gravity = [G * math.sin(theta), -G * math.cos(theta), 0.0]
    half = SHEET["size"][0] / 2
    cloth = dict(SHEET, origin=[-half, surface_height, -half])
    scene = parse_scene({"simulation": {"fps": FPS, "substeps": substeps, "iterations": 2, "damping": 0.0,
                                        "gravity": gravity, "precision": precision},
                         "cloth": [cloth], "collider": [collider]}, file="<test>")
    sim = Simulator(scene, "cpu", use_graph=False)
    if velocity is not None:
        sim.state.set_velocity([velocity, 0.0, 0.0])
    return sim


def travel(sim, seconds):
    """How far the cloth's centre moved along +X (downhill) in ``seconds``, and its largest height change."""
    start = sim.positions().astype(np.float64)
    for _ in range(round(seconds * FPS)):
        sim.step_frame()
    end = sim.positions().astype(np.float64)
    return (end[:, 0] - start[:, 0]).mean(), np.abs(end[:, 1] - start[:, 1]).max()


def ground(mu_k, mu_s=None):
    plane = {"type": "plane", "name": "ground", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0],
             "friction_coefficient": mu_k}
    if mu_s is not None:
        plane["static_friction_coefficient"] = mu_s
    return plane


SUBSTEPS = [4, 16, 64]


@pytest.mark.parametrize("substeps", SUBSTEPS)
def test_cloth_on_an_incline_flatter_than_static_friction_stays_put(substeps):
    # tan(20 deg) = 0.36 < mu_s = 0.5, though above mu_k = 0.2: only static friction holds it. Exactly: the
    # tangential step is removed each substep, so the cloth does not creep at all (a per-substep fraction of the
    # velocity, removed after the step, lets it creep g sin(theta) dt^2 per substep: 3 cm in a second at 4).
    sim = lying_on(ground(0.2, 0.5), 0.0, 20.0, substeps)
    moved, lifted = travel(sim, 1.0)
    assert abs(moved) < 1e-5, f"the cloth crept {moved:.2e} m down a slope it should rest on"
    assert lifted < 1e-5


@pytest.mark.parametrize("substeps", SUBSTEPS)
def test_cloth_on_an_incline_steeper_than_static_friction_slides_at_coulombs_acceleration(substeps):
    # tan(35 deg) = 0.70 > mu_s = 0.5: it slides at g (sin - mu_k cos) = 9.81 (0.574 - 0.3 x 0.819) = 3.22 m/s^2,
    # from rest: 0.5 a t^2 = 1.61 m in a second. Within 2% at every substep count.
    theta = math.radians(35.0)
    mu_k = 0.3
    sim = lying_on(ground(mu_k, 0.5), 0.0, 35.0, substeps)
    moved, lifted = travel(sim, 1.0)
    expected = 0.5 * G * (math.sin(theta) - mu_k * math.cos(theta)) * 1.0 ** 2
    assert moved == pytest.approx(expected, rel=0.02)
    assert lifted < 1e-5


def test_stopping_distance_on_level_ground_does_not_depend_on_the_substeps():
    # Launched at 2 m/s on level ground with mu_k = 0.3: it decelerates at mu_k g and stops after
    # v0^2 / (2 mu_k g) = 0.680 m (in 0.68 s), at each substep count within 2%, and they agree within 2%.
    # In float64: at 64 substeps the speed lost per substep, mu_k g dt^2 = 0.2 um, is 3 float32 spacings of the
    # cloth's coordinates, and the rounding of the moved positions biases the stop by a few percent.
    v0, mu_k = 2.0, 0.3
    expected = v0 ** 2 / (2.0 * mu_k * G)
    stops = []
    for substeps in SUBSTEPS:
        sim = lying_on(ground(mu_k), 0.0, 0.0, substeps, velocity=v0, precision="float64")
        moved, _ = travel(sim, 1.0)
        assert moved == pytest.approx(expected, rel=0.02), f"{substeps} substeps"
        more, _ = travel(sim, 0.25)
        assert abs(more) < 1e-6, f"{substeps} substeps: still moving after it should have stopped"
        stops.append(moved)
    assert max(stops) == pytest.approx(min(stops), rel=0.02)


def test_frictionless_contact_slides_as_in_free_fall_along_the_surface():
    # mu = 0: the clamp removes nothing tangential, so the slide is 0.5 g sin(theta) t^2 (Verlet is exact for a
    # constant acceleration).
    sim = lying_on(ground(0.0), 0.0, 30.0, 8)
    moved, _ = travel(sim, 0.5)
    assert moved == pytest.approx(0.5 * G * 0.5 * 0.5 ** 2, rel=1e-3)


@pytest.mark.parametrize("substeps", [4, 64])
def test_sphere_and_mesh_colliders_use_the_same_law(tmp_path, substeps):
    # The same on the crown of a large ball and on a box mesh whose top face is level at y = 0: held at 20
    # degrees with mu = 0.5, sliding at 3.22 m/s^2 at 35 degrees with mu_k = 0.3, mu_s = 0.5. The sheet lies
    # flat, so on the ball its rim starts up to 22 um above the surface and lands, pulling the middle a few um: on a
    # slope steeper than mu_k that slip would go on (as it should), hence mu_k = mu_s for the hold.
    # The ball's centre is 1 km away, where float32 spacings (61 um) exceed a substep's g dt^2: float64.
    trimesh = pytest.importorskip("trimesh")
    trimesh.creation.box(extents=[4.0, 1.0, 4.0]).apply_translation([0.0, -0.5, 0.0]).export(tmp_path / "box.obj")
    radius = 1000.0
    ball = {"type": "sphere", "name": "ball", "centre": [0.0, -radius, 0.0], "radius": radius}
    box = {"type": "mesh", "name": "box", "mesh": str(tmp_path / "box.obj")}
    slide = 0.5 * G * (math.sin(math.radians(35.0)) - 0.3 * math.cos(math.radians(35.0)))
    for collider, precision in ((ball, "float64"), (box, "auto")):
        held, _ = travel(lying_on(dict(collider, friction_coefficient=0.5), 0.0, 20.0, substeps,
                                  precision=precision), 0.5)
        assert abs(held) < 1e-5, f"{collider['type']}: crept {held:.2e} m"
        sliding = dict(collider, friction_coefficient=0.3, static_friction_coefficient=0.5)
        moved, _ = travel(lying_on(sliding, 0.0, 35.0, substeps, precision=precision), 0.5)
        assert moved == pytest.approx(slide * 0.5 ** 2, rel=0.02), collider["type"]


def test_static_below_kinetic_is_refused():
    with pytest.raises(SceneError, match=r"collider\[0\]\.static_friction_coefficient.*at least friction_coefficient"):
        parse_scene({"simulation": {}, "cloth": [SHEET], "collider": [ground(0.5, 0.3)]}, file="<test>")


def test_the_old_per_substep_friction_key_is_refused_with_what_to_write():
    plane = {"type": "plane", "point": [0.0, 0.0, 0.0], "friction": 0.4}
    with pytest.raises(SceneError, match=r"collider\[0\]\.friction.*per substep.*friction_coefficient"):
        parse_scene({"simulation": {}, "cloth": [SHEET], "collider": [plane]}, file="<test>")


def test_static_coefficient_defaults_to_the_kinetic_one():
    scene = parse_scene({"simulation": {}, "cloth": [SHEET], "collider": [ground(0.4), dict(ground(0.4, 0.6), name="rough")]},
                        file="<test>")
    assert [coulomb(c) for c in scene.colliders] == [(0.4, 0.4), (0.4, 0.6)]
