"""Damping is a rate per second: the implicit velocity decays as exp(-damping t), whatever the substeps (the
old per-substep drag made a cloth with more substeps lose velocity faster)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import make_scene
from warp_verlet.core.simulator import Simulator

EPS32 = float(np.finfo(np.float32).eps)


def launched(substeps: int, damping: float, v0, fps: float = 10.0, device: str = "cpu") -> Simulator:
    """A free cloth with no forces and no sticks solved (iterations = 0), launched at ``v0`` m/s."""
    scene = make_scene({"fps": fps, "substeps": substeps, "iterations": 0, "gravity": [0.0, 0.0, 0.0],
                        "damping": damping}, resolution=[3, 4], origin=[0.2, 0.7, -0.4])
    sim = Simulator(scene, device)
    sim.state.set_velocity(v0)
    return sim


def implicit_velocity(sim: Simulator) -> np.ndarray:
    """(x - x_prev) / dt of the last step, from the summed form: the increment plus what moved x since."""
    state = sim.state
    move = state.particle_dq.numpy().astype(np.float64)
    move += state.particle_q.numpy().astype(np.float64) - state.particle_q_inertial.numpy()
    return move / sim.settings.dt


@pytest.mark.parametrize("substeps", [1, 4, 16])
def test_velocity_decays_as_exp_of_minus_damping_t_at_any_substeps(device, substeps):
    # 0.5 s at 10 fps with damping 2/s: the velocity is v0 e^-1 after 5, 20 or 80 substeps. Float32 error: each
    # step multiplies the increment by exp(-damping dt) rounded to float32 and rounds the product, at most
    # 2^-24 relative each, so after n <= 80 steps at most 80 x 2^-23 = 9.5e-6 < 1e-5.
    damping, v0 = 2.0, np.array([1.5, -0.5, 0.25])
    sim = launched(substeps, damping, v0, device=device)
    for _ in range(5):
        sim.step_frame()
    assert sim.time == pytest.approx(0.5, rel=1e-12) and sim.steps == 5 * substeps
    expected = v0 * math.exp(-damping * sim.time)
    np.testing.assert_allclose(implicit_velocity(sim), np.tile(expected, (12, 1)), rtol=1e-5)


@pytest.mark.parametrize("substeps", [1, 4, 16])
def test_distance_travelled_is_the_integral_of_the_decaying_velocity(substeps):
    # Each step of dt moves v0 dt e^k, k = 1 .. n (e = exp(-damping dt): the first step is damped too), so after
    # n steps x - x0 = v0 dt e (1 - e^n) / (1 - e): a right Riemann sum of v0 exp(-damping s) over [0, t], so
    # short of the integral v0 (1 - exp(-damping t)) / damping by at most v0 dt (1 - exp(-damping t)).
    damping, v0, fps = 2.0, np.array([0.0, 0.0, 3.0]), 10.0
    sim = launched(substeps, damping, v0, fps)
    x0 = sim.positions().astype(np.float64)
    for _ in range(5):
        sim.step_frame()
    dt, n = sim.settings.dt, 5 * substeps
    e = math.exp(-damping * dt)
    travelled = v0 * dt * e * (1 - e**n) / (1 - e)
    error = np.abs(sim.positions() - (x0 + travelled)).max()
    assert error <= n * EPS32 * (np.abs(travelled).max() + np.abs(x0).max()), error
    continuous = v0 * (1 - math.exp(-damping * sim.time)) / damping
    assert 0 <= (continuous - travelled)[2] <= v0[2] * dt * (1 - math.exp(-damping * sim.time))


def test_no_damping_keeps_the_velocity():
    sim = launched(4, 0.0, [0.3, 0.0, -0.2])
    for _ in range(5):
        sim.step_frame()
    np.testing.assert_allclose(implicit_velocity(sim), np.tile([0.3, 0.0, -0.2], (12, 1)), rtol=1e-6, atol=1e-9)


def test_pinned_particles_stay_when_the_cloth_is_launched():
    scene = make_scene({"fps": 10, "substeps": 4, "iterations": 0, "gravity": [0.0, 0.0, 0.0], "damping": 1.0},
                       resolution=[3, 4], pins=["top-edge"])
    sim = Simulator(scene, "cpu")
    x0 = sim.positions()
    sim.state.set_velocity([1.0, 2.0, 3.0])
    for _ in range(5):
        sim.step_frame()
    np.testing.assert_array_equal(sim.positions()[:4], x0[:4])
    np.testing.assert_allclose(implicit_velocity(sim)[4:], np.tile([1.0, 2.0, 3.0], (8, 1)) * math.exp(-0.5),
                               rtol=1e-5)
