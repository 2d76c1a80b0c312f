"""Verlet integration against closed-form motion."""

import numpy as np
import pytest

from conftest import make_scene
from warp_verlet.core.simulator import Simulator

EPS32 = float(np.finfo(np.float32).eps)
G = np.array([0.0, -9.81, 0.0])


def free_fall_bound(steps: int, displacement: float, coordinate: float) -> float:
    """Float32 error budget that grows linearly with the step count: each step may cost one rounding of the
    increment and one of the coordinate (the bound of recursive summation). The textbook x_prev form breaks
    it, because there each rounding of x becomes a velocity error and the error grows with steps^2
    (measured: 2300 ulps after 240 steps, against under 170 in summed form)."""
    return steps * EPS32 * (displacement + coordinate)


def test_free_fall_exact_at_every_frame(device):
    # The integrator alone (no relaxation sweeps): every particle follows x0 + g t^2 / 2.
    scene = make_scene({"fps": 60, "substeps": 4, "iterations": 0}, resolution=[6, 5], origin=[0.3, 2.0, -0.1])
    sim = Simulator(scene, device)
    x0 = sim.positions().astype(np.float64)
    for frame in range(1, 121):
        sim.step_frame()
        t = frame / 60.0
        exact = x0 + 0.5 * G * t * t
        error = np.abs(sim.positions() - exact).max()
        bound = free_fall_bound(frame * 4, 0.5 * 9.81 * t * t, np.abs(exact).max())
        assert error <= bound, f"frame {frame}: error {error:.3e} m > bound {bound:.3e} m"


def test_free_falling_cloth_keeps_its_shape(device):
    # With every stick family relaxed each substep, the cloth falls rigidly. Float32 rounding of the falling
    # coordinates (in steps of an ulp that doubles at every power of two the cloth crosses) looks like strain
    # to the relaxation, and corrections rounded at different magnitudes do not cancel exactly, so the cloth
    # drifts from the closed form by a few 1e-5 of the fall (measured: at most 4.5e-5). Bounds: every particle
    # within 1e-4 of the fall distance, and relative stretch below 1e-5.
    scene = make_scene({"fps": 60, "substeps": 4, "iterations": 4}, resolution=[6, 5], origin=[0.3, 2.0, -0.1],
                       sticks=["structural", "shear", "bend"])
    sim = Simulator(scene, device)
    x0 = sim.positions().astype(np.float64)
    for frame in range(1, 121):
        sim.step_frame()
        t = frame / 60.0
        fall = 0.5 * 9.81 * t * t
        error = np.abs(sim.positions() - (x0 + 0.5 * G * t * t)).max()
        assert error <= 1e-4 * fall, f"frame {frame}: off by {error:.3e} m after a fall of {fall:.3f} m"
        assert sim.stretch().max < 1e-5


def test_free_fall_with_initial_time_matches_closed_form_after_one_step():
    # The very first step must already be exact: x1 = x0 + a dt^2 / 2, not x0 + a dt^2 (the naive x_prev = x0).
    scene = make_scene({"fps": 10, "substeps": 1, "iterations": 0})
    sim = Simulator(scene, "cpu")
    x0 = sim.positions().astype(np.float64)
    sim.step()
    dt = 0.1
    np.testing.assert_allclose(sim.positions(), x0 + 0.5 * G * dt * dt, rtol=0, atol=4 * np.spacing(np.float32(3.0)))


@pytest.mark.parametrize("schedule", [[0.01, 0.02, 0.005, 0.009, 0.013, 0.001, 0.002], [1e-3] * 5 + [1.8e-3] * 5])
def test_variable_dt_exact_under_constant_acceleration(device, schedule):
    # Time-step-corrected Verlet: x + (x - x_prev) dt/dt_prev + a dt (dt + dt_prev) / 2 is exact for constant
    # acceleration, whatever the sequence of steps (ratios here stay below max_dt_ratio = 2).
    scene = make_scene({"iterations": 0, "gravity": [1.5, -9.81, 2.0], "max_dt_ratio": 2.0})
    sim = Simulator(scene, device)
    x0 = sim.positions().astype(np.float64)
    a = np.array([1.5, -9.81, 2.0])
    t = 0.0
    for dt in schedule:
        sim.step(dt)
        t += dt
        exact = x0 + 0.5 * a * t * t
        error = np.abs(sim.positions() - exact).max()
        assert error <= free_fall_bound(len(schedule), 0.5 * 9.81 * t * t, np.abs(exact).max()), (t, error)


def test_seed_variable_dt_form_is_not_exact_but_ours_is():
    """The seed's x + (x - x_prev) dt/dt_prev + a dt^2 misses the closed form after a dt change; ours does not.
    Evaluated in float64 on the host, so the difference is the formula, not rounding."""
    a, steps = -9.81, [0.01, 0.01, 0.03, 0.03]

    def run(accel_term):
        x_prev, x, dt_prev = 0.5 * a * 0.01**2, 0.0, 0.01  # exact start, x(t) = a t^2 / 2
        for dt in steps:
            x, x_prev, dt_prev = x + (x - x_prev) * dt / dt_prev + accel_term(dt, dt_prev), x, dt
        return x

    exact = 0.5 * a * sum(steps) ** 2
    ours = run(lambda dt, dtp: a * dt * (dt + dtp) / 2)
    seed = run(lambda dt, dtp: a * dt * dt)
    assert abs(ours - exact) < 1e-12
    assert abs(seed - exact) > 1e-4


def test_ratio_clamp_limits_a_spike(device):
    # A step 10x longer than the previous one: the implicit velocity is scaled by at most max_dt_ratio.
    scene = make_scene({"iterations": 0, "gravity": [0.0, 0.0, 0.0], "max_dt_ratio": 2.0})
    sim = Simulator(scene, device)
    # Give the cloth a known velocity of 1 m/s along x: the first step (the exact start) moves it 0.01 m.
    sim.state.set_velocity([1.0, 0.0, 0.0])
    x0 = sim.positions()
    sim.step(0.01)
    np.testing.assert_allclose(sim.positions()[:, 0] - x0[:, 0], 0.01, rtol=1e-5)
    before = sim.positions()
    sim.step(0.1)  # ratio 10, clamped to 2
    moved = sim.positions()[:, 0] - before[:, 0]
    np.testing.assert_allclose(moved, 0.02, rtol=1e-5)


def test_pins_never_move(device):
    scene = make_scene({"gravity": [0.0, -50.0, 3.0], "wind": [5.0, 0.0, 0.0]}, resolution=[8, 8],
                       pins=["top-left", "top-right", [4, 4]], sticks=["structural", "shear"],
                       compliance={"shear": 1e-3})
    sim = Simulator(scene, device)
    pinned = [0, 7, 4 * 8 + 4]
    x0 = sim.positions()[pinned].copy()
    for _ in range(30):
        sim.step_frame()
    assert np.array_equal(sim.positions()[pinned], x0)  # bit-exact: pins are never written


def test_damping_decays_implicit_velocity_geometrically(device):
    # With no forces and no constraints, each step scales x - x_prev by exp(-damping dt): a particle launched at
    # v moves v dt e, v dt e^2, ... (e = exp(-damping dt), the first step included), so after n steps it has
    # moved v dt (e + e^2 + ... + e^n). (tests/test_damping.py: the same decay per second at any substeps.)
    damping, n, v = 25.0, 12, 2.4
    scene = make_scene({"iterations": 0, "gravity": [0.0, 0.0, 0.0], "damping": damping})
    sim = Simulator(scene, device)
    dt = sim.settings.dt
    e = np.exp(-damping * dt)
    start = sim.positions()[:, 0]
    sim.state.set_velocity([v, 0.0, 0.0])
    for _ in range(n):
        sim.step()
    expected = v * dt * sum(e**k for k in range(1, n + 1))
    np.testing.assert_allclose(sim.positions()[:, 0] - start, expected, rtol=1e-5)
    # The last increment is v dt e^n: the implicit velocity has decayed to v exp(-damping t).
    np.testing.assert_allclose(sim.state.particle_dq.numpy()[:, 0] / dt, v * np.exp(-damping * n * dt), rtol=1e-5)
