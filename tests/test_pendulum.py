"""A pinned two-particle rope is a simple pendulum: its small-angle period is 2 pi sqrt(L / g)."""

import numpy as np

from conftest import make_scene
from warp_verlet.core.simulator import Simulator


LENGTH, G, THETA0 = 1.0, 9.81, 0.05


def swing(device, substeps):
    """Angle from equilibrium at every frame for 8 s (about 4 periods), and the frame times."""
    # The rope hangs straight down (-Y); tilting gravity by THETA0 starts it THETA0 from equilibrium.
    gravity = [G * np.sin(THETA0), -G * np.cos(THETA0), 0.0]
    scene = make_scene({"fps": 60, "substeps": substeps, "iterations": 1, "gravity": gravity},
                       resolution=[2, 1], size=[LENGTH, 0.0], pins=["top-left"])
    sim = Simulator(scene, device)
    angles, times = [], []
    for _ in range(60 * 8):  # 8 s, about 4 periods
        sim.step_frame()
        bob = sim.positions()[1] - sim.positions()[0]
        # angle from the equilibrium direction (along gravity)
        angles.append(np.arctan2(bob[0], -bob[1]) - THETA0)
        times.append(sim.time)
        assert abs(np.linalg.norm(bob) - LENGTH) < 1e-5  # the stick holds its length exactly (one projection)
    return np.array(angles), np.array(times)


def test_small_angle_period_within_one_percent(device):
    angles, times = swing(device, substeps=8)
    # Downward zero crossings, refined by linear interpolation between frames.
    i = np.flatnonzero((angles[:-1] > 0) & (angles[1:] <= 0))
    crossings = times[i] + angles[i] / (angles[i] - angles[i + 1]) * (times[i + 1] - times[i])
    period = np.mean(np.diff(crossings))
    expected = 2 * np.pi * np.sqrt(LENGTH / G) * (1 + THETA0**2 / 16)  # first finite-amplitude correction
    assert len(crossings) >= 3
    assert abs(period - expected) / expected < 0.01, (period, expected)


def test_projection_damping_is_first_order_in_dt():
    # Projecting onto the stick after an unconstrained Verlet step removes a little energy every step (the
    # amplitude never grows with d = 1). The loss is first order in dt: halving dt halves it. Measured over
    # 8 s: 12%, 6%, 3%, 1.3% at 4, 8, 16, 32 substeps of a 60 fps frame.
    loss = {}
    for substeps in (8, 16):
        angles, _ = swing("cpu", substeps)
        final = abs(angles[-120:]).max()
        assert final < THETA0
        loss[substeps] = 1 - final / THETA0
    assert 1.6 < loss[8] / loss[16] < 2.4, loss
