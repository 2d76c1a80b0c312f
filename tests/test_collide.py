"""Collider clamping: invariants after every substep, friction against a closed form, and leaving out
what a scene does not use."""

import numpy as np
import pytest

from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator

# Clamping is exact up to float32 rounding of the projected position, so after every substep no free
# particle may be inside a collider by more than TOL.
TOL = 1e-5
DROP = {"name": "sheet", "resolution": [16, 16], "size": [1.2, 1.2], "origin": [-0.6, 0.6, -0.6],
        "orientation": "horizontal", "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 0.02}}
GROUND = {"type": "plane", "name": "ground", "point": [0.0, -0.4, 0.0], "normal": [0.0, 1.0, 0.0], "thickness": 0.01}
BALL = {"type": "sphere", "name": "ball", "centre": [0.0, 0.0, 0.0], "radius": 0.3, "thickness": 0.02}


def scene(cloth, colliders, **simulation):
    return parse_scene({"simulation": {"fps": 60, "substeps": 4, "iterations": 8, **simulation},
                        "cloth": [cloth], "collider": colliders}, file="<test>")


def assert_outside(sim, positions, free):
    p = positions[free].astype(np.float64)
    for plane in sim.scene.planes:
        height = (p - plane.point) @ np.asarray(plane.normal)
        assert height.min() >= plane.thickness - TOL, f"{plane.name}: a particle is {plane.thickness - height.min():.2e} m inside"
    centres = sim.state.sphere_centres.numpy() if sim.scene.spheres else []
    for sphere, centre in zip(sim.scene.spheres, centres):
        distance = np.linalg.norm(p - centre, axis=1)
        reach = sphere.radius + sphere.thickness
        assert distance.min() >= reach - TOL, f"{sphere.name}: a particle is {reach - distance.min():.2e} m inside"


def run_checking(sim, substeps):
    free = sim.model.inv_mass.numpy() > 0
    for _ in range(substeps):
        sim.step()
        positions = sim.positions()
        assert np.isfinite(positions).all()
        assert_outside(sim, positions, free)
    return sim.positions()


def test_cloth_dropped_on_a_sphere_on_the_ground(device):
    sim = Simulator(scene(DROP, [BALL, GROUND]), device)
    final = run_checking(sim, 4 * 90)  # 1.5 s
    # It drapes: the middle rests on top of the ball, the corners hang lower than the top of the ball.
    middle = final[8 * 16 + 8]
    assert abs(middle[1] - 0.32) < 0.03
    assert final[0, 1] < 0.2


@pytest.mark.parametrize("start_y, colliders", [(-0.5, [GROUND]), (0.0, [BALL])], ids=["below-ground", "through-ball"])
def test_cloth_starting_inside_a_collider_is_pushed_out(device, start_y, colliders):
    # 10 cm under the ground, or cutting through the middle of the ball: one substep clears it, and it
    # stays clear.
    sim = Simulator(scene(dict(DROP, origin=[-0.6, start_y, -0.6]), colliders), device)
    run_checking(sim, 4 * 30)


def test_fast_sphere_sweeping_through_a_hanging_cloth(device):
    hanging = {"name": "curtain", "resolution": [20, 20], "size": [1.0, 1.0], "origin": [-0.5, 1.0, 0.0],
               "pins": ["top-edge"], "sticks": ["structural", "shear"]}
    # 10 m/s through the curtain's lower half, i.e. 4 cm per substep against 5 cm between particles.
    sweep = {"type": "sphere", "name": "ball", "radius": 0.2,
             "path": [[0.0, 0.0, 0.4, -1.0], [0.2, 0.0, 0.4, 1.0]]}
    sim = Simulator(scene(hanging, [sweep]), device)
    mid_sweep = run_checking(sim, 40)  # the ball is at z = 0.7 after 40 substeps
    assert mid_sweep[:, 2].max() > 0.5  # and has carried the curtain along with it
    run_checking(sim, 80)  # the curtain swings back; the invariant keeps holding


def test_moving_sphere_follows_its_keyframes(device):
    path = [[0.0, 0.0, 0.0, 0.0], [0.5, 1.0, 0.0, 0.0], [1.0, 1.0, 2.0, 0.0]]
    sim = Simulator(scene(DROP, [{"type": "sphere", "radius": 0.1, "path": path}], gravity=[0.0, 0.0, 0.0]), device)
    sphere = sim.scene.spheres[0]
    for frame in range(1, 80):
        sim.step_frame()
        expected = sphere.centre_at(frame / 60.0)
        np.testing.assert_allclose(sim.state.sphere_centres.numpy()[0], expected, atol=1e-5)
        np.testing.assert_array_equal(sim.model.colliders.moving_centres(sim.state), sim.state.sphere_centres.numpy())
    # held after the last key
    np.testing.assert_allclose(sim.state.sphere_centres.numpy()[0], [1.0, 2.0, 0.0], atol=1e-6)


@pytest.mark.parametrize("mu", [0.0, 0.5, 1.0])
def test_coulomb_friction_decelerates_a_sliding_cloth_at_mu_g(device, mu):
    # A flat cloth resting on the ground, launched at 2 m/s along x. Gravity presses it into the plane every
    # substep, pushed out by g dt^2 (half that on the first, as Verlet starts exactly), so sliding takes mu g dt^2
    # off its step each substep: after n substeps it has moved v t - mu g t^2 / 2, t = n dt, exactly (it stops only
    # at t = v / (mu g) = 0.2 s, past these 40 substeps). tests/test_friction.py checks the law on inclines.
    cloth = dict(DROP, origin=[0.0, 0.0, 0.0])
    ground = {"type": "plane", "point": [0.0, 0.0, 0.0], "friction_coefficient": mu}
    sim = Simulator(scene(cloth, [ground], iterations=2), device)
    dt, v, n = sim.settings.dt, 2.0, 40
    sim.state.set_velocity([v, 0.0, 0.0])
    start = sim.positions()[:, 0]
    for _ in range(n):
        sim.step()
    t = n * dt
    expected = v * t - mu * 9.81 * t ** 2 / 2
    np.testing.assert_allclose(sim.positions()[:, 0] - start, expected, atol=2e-5)
    assert np.abs(sim.positions()[:, 1]).max() < TOL  # and it stays on the plane


def test_only_the_collider_kinds_present_are_launched_and_allocated(launches):
    # DROP: all three stick families (12 colours), soft bend sticks (the XPBD kernel, after zeroing its
    # tensions), no pins (no tethers), no tearing; 8 sweeps. Colliders add their clamping after the sweeps.
    k = 8
    substep = ["verlet_step", "zero"] + ["relax_colour_compliant"] * (12 * k)

    def step_launches(colliders):
        sim = Simulator(scene(DROP, colliders), "cpu", use_graph=False)
        assert sim.model.colour_count == 12
        sim.step()
        return sim, launches.of(sim.step)

    plane_only, issued = step_launches([GROUND])
    assert issued == substep + ["collide_planes"]
    assert plane_only.state.sphere_centres is None and not hasattr(plane_only.colliders, "sphere_reach")
    still_ball, issued = step_launches([BALL])
    assert issued == substep + ["collide_spheres"]
    assert still_ball.state.collider_clock is None  # no moving sphere: no clock, no placing kernel
    assert not hasattr(still_ball.colliders, "key_times") and not hasattr(still_ball.colliders, "plane_points")
    # Spheres before planes; a moving sphere first advances the device clock and places the spheres on it.
    sweep = {"type": "sphere", "radius": 0.1, "path": [[0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0]]}
    everything, issued = step_launches([GROUND, sweep, BALL])
    assert issued == substep + ["advance_clock", "place_spheres", "collide_spheres", "collide_planes"]
    assert everything.state.collider_clock is not None and everything.state.sphere_centres.shape == (2,)
    nothing, issued = step_launches([])
    assert issued == substep
    assert [name for name, _ in nothing.stages()] == ["integrate", "relax"]
    assert [name for name, _ in everything.stages()] == ["integrate", "relax", "collide"]


def test_colliders_are_written_into_the_cache(tmp_path):
    from pxr import Usd, UsdGeom

    from warp_verlet.apps.runner import run_scene
    from warp_verlet.output.usd_writer import validate_cache

    sweep = {"type": "sphere", "name": "ball", "radius": 0.2, "thickness": 0.05,
             "path": [[0.0, 0.0, 0.4, -1.0], [0.1, 0.0, 0.4, 1.0]]}
    still = dict(BALL, name="still", centre=[2.0, 0.0, 0.0])
    out = tmp_path / "colliders.usda"
    run_scene(scene(DROP, [sweep, still, GROUND], frames=8), output=out, device="cpu")
    assert validate_cache(out) == []
    stage = Usd.Stage.Open(str(out))
    ball = UsdGeom.Sphere(stage.GetPrimAtPath("/World/Colliders/ball"))
    assert ball.GetRadiusAttr().Get() == pytest.approx(0.2)  # the visible radius: thickness is not drawn
    translate = ball.GetPrim().GetAttribute("xformOp:translate")
    assert translate.GetTimeSamples() == list(range(9))
    np.testing.assert_allclose(translate.Get(3), [0.0, 0.4, -1.0 + 2.0 * (3 / 60) / 0.1], atol=1e-5)
    still_translate = stage.GetPrimAtPath("/World/Colliders/still").GetAttribute("xformOp:translate")
    assert still_translate.GetTimeSamples() == [] and tuple(still_translate.Get()) == (2.0, 0.0, 0.0)
    ground = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Colliders/ground"))
    corners = np.array(ground.GetPointsAttr().Get())
    assert np.allclose(corners[:, 1], -0.4) and np.ptp(corners[:, 0]) == pytest.approx(10.0)


def test_a_scene_without_colliders_writes_none(tmp_path):
    from pxr import Usd

    from warp_verlet.apps.runner import run_scene

    out = tmp_path / "plain.usda"
    run_scene(scene(DROP, [], frames=2), output=out, device="cpu")
    assert not Usd.Stage.Open(str(out)).GetPrimAtPath("/World/Colliders")
