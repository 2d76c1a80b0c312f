"""Soft sticks are XPBD constraints (kernels/relax.py): a stick of compliance alpha (m/N) is a spring of
stiffness 1 / alpha, whatever the substeps and the iterations, and alpha = 0 is the rigid stick."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.kernels.relax import relax_colour, relax_colour_compliant
from warp_verlet.core.simulator import Simulator

G = 9.81


# ---------------------------------------------------------------------------------------------- one projection


def project(x, inv_mass, rest, compliance, inv_dt2, device, tension=None, weight=None):
    """One launch of relax_colour_compliant on the sticks (0, 1), (2, 3), ...: new positions and tensions."""
    n = len(rest)
    x = wp.array(np.asarray(x, np.float32), dtype=wp.vec3, device=device)
    args = [
        wp.array(np.asarray(inv_mass, np.float32), dtype=float, device=device),
        wp.array(np.arange(2 * n, dtype=np.int32).reshape(n, 2), dtype=wp.vec2i, device=device),
        wp.array(np.asarray(rest, np.float32), dtype=float, device=device),
        wp.array(np.ones(n, np.float32) if weight is None else np.asarray(weight, np.float32), dtype=float,
                 device=device),
        wp.array(np.asarray(compliance, np.float32), dtype=float, device=device),
    ]
    mu = wp.array(np.zeros(n, np.float32) if tension is None else np.asarray(tension, np.float32), dtype=float,
                  device=device)
    wp.launch(relax_colour_compliant, n, inputs=[x, *args, inv_dt2, 0, 1], outputs=[mu], device=device)
    return x.numpy(), mu.numpy()


def test_one_projection_moves_by_the_xpbd_step(device):
    # A stick of rest 1 m stretched to 2 m along x, w = (1, 3), alpha = 0.5 m/N at dt = 0.5 s: alpha~ = alpha /
    # dt^2 = 2, so the step is s = (D - L) / (w_i + w_j + alpha~) = 1 / 6, the ends move w s towards each other
    # and the tension becomes s.
    x, mu = project([[0, 0, 0], [2, 0, 0]], [1.0, 3.0], [1.0], [0.5], 1 / 0.25, device)
    np.testing.assert_allclose(x, [[1 / 6, 0, 0], [2 - 3 / 6, 0, 0]], atol=1e-6)
    np.testing.assert_allclose(mu, [1 / 6], rtol=1e-6)
    # A second sweep in the same substep, from there with that tension: C - alpha~ mu = (2 - 4/6 - 1) - 2/6 = 0,
    # so one stick alone is already solved and nothing moves (the XPBD iteration's fixed point).
    again, mu2 = project(x, [1.0, 3.0], [1.0], [0.5], 1 / 0.25, device, tension=mu)
    np.testing.assert_allclose(again, x, atol=1e-6)
    np.testing.assert_allclose(mu2, mu, atol=1e-6)


def test_a_torn_soft_stick_moves_nothing(device):
    x, mu = project([[0, 0, 0], [2, 0, 0]], [1.0, 1.0], [1.0], [0.5], 4.0, device, weight=[0.0])
    np.testing.assert_array_equal(x, [[0, 0, 0], [2, 0, 0]])
    np.testing.assert_array_equal(mu, [0.0])


def test_zero_compliance_is_the_rigid_projection_bit_for_bit():
    # Many independent sticks (one colour) in random poses, masses (pins among them), rest lengths and
    # weights (torn sticks among them), relaxed by both kernels, several sweeps: with alpha = 0 the XPBD
    # kernel must give the rigid kernel's positions bit for bit, so that making a family soft with compliance 0
    # changes nothing. (No coordinate is -0.0: the rigid kernel writes x + 0 * w for a skipped stick, which
    # turns -0.0 into +0.0, while the XPBD kernel leaves it as it is.)
    rng = np.random.default_rng(7)
    n = 5000
    x0 = rng.normal(size=(2 * n, 3)).astype(np.float32)
    inv_mass = rng.choice([0.0, 0.25, 1.0, 3.0, 40.0], size=2 * n).astype(np.float32)
    ends = np.arange(2 * n, dtype=np.int32).reshape(n, 2)
    length = np.linalg.norm(x0[ends[:, 1]] - x0[ends[:, 0]], axis=1)
    rest = (length * rng.uniform(0.5, 1.5, size=n)).astype(np.float32)
    weight = rng.choice([0.0, 1.0], size=n, p=[0.2, 0.8]).astype(np.float32)

    def arrays():
        return (wp.array(x0, dtype=wp.vec3, device="cpu"), wp.array(inv_mass, dtype=float, device="cpu"),
                wp.array(ends, dtype=wp.vec2i, device="cpu"), wp.array(rest, dtype=float, device="cpu"),
                wp.array(weight, dtype=float, device="cpu"))

    x, *sticks = rigid = arrays()
    for _ in range(3):
        wp.launch(relax_colour, n, inputs=[*rigid, 0, 1], device="cpu")
    xs, *soft_sticks = soft = arrays()
    zero = wp.zeros(n, dtype=float, device="cpu")
    tension = wp.zeros(n, dtype=float, device="cpu")
    for _ in range(3):
        wp.launch(relax_colour_compliant, n, inputs=[*soft, zero, 57600.0, 0, 1], outputs=[tension], device="cpu")
    a, b = x.numpy(), xs.numpy()
    differ = (a != b).any(axis=1)
    assert not differ.any(), (
        f"relax_colour_compliant with compliance 0 differs from relax_colour in {differ.sum()} of {2 * n} particles "
        f"(by up to {np.abs(a - b).max():.2e} m): it computes the move as d * ((C / w) / D) where the rigid kernel "
        "computes d * (C / (D * w)); the same value in exact arithmetic, a different float32 rounding. Computing "
        "d * (C' / (D * (w + alpha~))) in the XPBD kernel (C' = k (D - L - alpha~ mu)) makes alpha = 0 exact.")


def test_zero_compliance_agrees_with_the_rigid_projection_to_rounding():
    # The companion of the bit-for-bit test above: whatever the rounding, the two kernels agree to a few float32
    # ulps of the coordinates at alpha = 0.
    rng = np.random.default_rng(3)
    n = 2000
    x0 = rng.normal(size=(2 * n, 3)).astype(np.float32)
    inv_mass = rng.choice([0.0, 1.0, 3.0], size=2 * n).astype(np.float32)
    rest = (np.linalg.norm(x0[1::2] - x0[0::2], axis=1) * rng.uniform(0.5, 1.5, size=n)).astype(np.float32)
    soft, _ = project(x0, inv_mass, rest, np.zeros(n), 57600.0, "cpu")
    x = wp.array(x0, dtype=wp.vec3, device="cpu")
    wp.launch(relax_colour, n, device="cpu", inputs=[
        x, wp.array(inv_mass, dtype=float, device="cpu"),
        wp.array(np.arange(2 * n, dtype=np.int32).reshape(n, 2), dtype=wp.vec2i, device="cpu"),
        wp.array(rest, dtype=float, device="cpu"), wp.array(np.ones(n, np.float32), dtype=float, device="cpu"), 0, 1])
    np.testing.assert_allclose(soft, x.numpy(), rtol=0, atol=4 * np.spacing(np.float32(np.abs(x0).max() * 2)))


# ---------------------------------------------------------------------------------------------- the spring


def hanging_extension(substeps: int, iterations: int, alpha: float, mass: float, device: str = "cpu") -> float:
    """A particle of ``mass`` kg hanging 0.5 m below a pin by one stick of compliance ``alpha``, after 2.5 s
    with damping 15/s: its stretch beyond the rest length, m."""
    scene = make_scene({"fps": 60, "substeps": substeps, "iterations": iterations, "damping": 15.0, "frames": 150},
                       resolution=[2, 1], size=[0.5, 0.0], pins=["top-left"], sticks=["structural"],
                       compliance={"structural": alpha}, particle_masses=[[1, 0, mass]],
                       tethers=False)  # a tether would cap the particle at the rest length from its pin
    sim = Simulator(scene, device)
    pin = sim.positions()[0].copy()
    for _ in range(150):
        sim.step_frame()
    p = sim.positions()
    assert np.array_equal(p[0], pin)
    assert abs(p[1, 0]) < 1e-6 and abs(p[1, 2]) < 1e-6  # straight down
    return float(np.linalg.norm(p[1].astype(np.float64) - p[0]) - sim.model.host_rest[0])


@pytest.mark.parametrize("substeps", [2, 8])
@pytest.mark.parametrize("iterations", [1, 4, 16])
@pytest.mark.parametrize("alpha, mass", [(1e-3, 0.5), (2e-2, 0.2)])
def test_a_hanging_mass_stretches_its_stick_by_m_g_alpha(device, substeps, iterations, alpha, mass):
    # At rest the stick holds the weight m g, and a spring of stiffness 1 / alpha stretches m g alpha under it:
    # 4.9 mm and 39 mm here, at any substeps and iterations (per-sweep stiffness fractions did not).
    assert hanging_extension(substeps, iterations, alpha, mass, device) == pytest.approx(mass * G * alpha, rel=1e-3)


def test_a_rigid_stick_does_not_stretch():
    scene = make_scene({"fps": 60, "substeps": 2, "iterations": 1, "damping": 15.0}, resolution=[2, 1],
                       size=[0.5, 0.0], pins=["top-left"], tethers=False, particle_masses=[[1, 0, 0.5]])
    sim = Simulator(scene, "cpu")
    for _ in range(60):
        sim.step_frame()
    p = sim.positions().astype(np.float64)
    assert abs(np.linalg.norm(p[1] - p[0]) - sim.model.host_rest[0]) < 1e-6
