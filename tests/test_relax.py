"""Distance-stick relaxation against analytic answers, and convergence with the iteration count."""

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.kernels.relax import relax_colour, relax_jacobi
from warp_verlet.core.simulator import Simulator


def relax_one_stick(xi, xj, wi, wj, rest, device, k=1.0):
    x = wp.array(np.array([xi, xj], np.float32), dtype=wp.vec3, device=device)
    inv_mass = wp.array(np.array([wi, wj], np.float32), dtype=float, device=device)
    ends = wp.array(np.array([[0, 1]], np.int32), dtype=wp.vec2i, device=device)
    rest_a = wp.array(np.array([rest], np.float32), dtype=float, device=device)
    k_a = wp.array(np.array([k], np.float32), dtype=float, device=device)
    wp.launch(relax_colour, 1, inputs=[x, inv_mass, ends, rest_a, k_a, 0, 1], device=device)
    return x.numpy()


def test_moves_split_by_inverse_mass(device):
    # Error D - L = 1 m along x; w = (1, 3): the ends move 1/4 and 3/4 of it towards each other.
    out = relax_one_stick([0, 0, 0], [2, 0, 0], 1.0, 3.0, 1.0, device)
    np.testing.assert_allclose(out, [[0.25, 0, 0], [1.25, 0, 0]], atol=1e-7)


def test_pinned_end_does_not_move(device):
    out = relax_one_stick([0, 0, 0], [0, 3, 4], 0.0, 2.0, 1.0, device)  # D = 5
    np.testing.assert_allclose(out[0], [0, 0, 0], atol=0)
    np.testing.assert_allclose(out[1], [0, 0.6, 0.8], atol=1e-6)


def test_compressed_stick_pushes_apart_with_partial_stiffness(device):
    out = relax_one_stick([0, 0, 0], [0.5, 0, 0], 1.0, 1.0, 1.0, device, k=0.5)  # half of the 0.5 m error
    np.testing.assert_allclose(out, [[-0.125, 0, 0], [0.625, 0, 0]], atol=1e-7)


@pytest.mark.parametrize("wi, wj", [(1.0, 1.0), (0.0, 0.0)])
def test_coincident_or_doubly_pinned_ends_stay_finite_and_still(device, wi, wj):
    out = relax_one_stick([1, 2, 3], [1, 2, 3], wi, wj, 0.5, device)  # D = 0: no direction to push along
    np.testing.assert_array_equal(out, [[1, 2, 3], [1, 2, 3]])


def test_jacobi_gather_matches_analytic_average(device):
    # Particle 1 sits between two pinned particles; sticks of rest 1 are both stretched by 0.5 m along x and
    # y. Each stick alone would move it fully; Jacobi averages the two corrections.
    x = wp.array(np.array([[0, 0, 0], [1.5, 0, 0], [1.5, 1.5, 0]], np.float32), dtype=wp.vec3, device=device)
    out = wp.empty_like(x)
    inv_mass = wp.array(np.array([0.0, 1.0, 0.0], np.float32), dtype=float, device=device)
    start = wp.array(np.array([0, 1, 3, 4], np.int32), dtype=int, device=device)
    nbr = wp.array(np.array([1, 0, 2, 1], np.int32), dtype=int, device=device)
    ones = wp.array(np.ones(4, np.float32), dtype=float, device=device)
    wp.launch(relax_jacobi, 3, inputs=[x, inv_mass, start, nbr, ones, ones, 0, 1], outputs=[out], device=device)
    # to particle 0: move (-0.5, 0); to particle 2: D = 1.5 along +y, move (0, +0.5); average (-0.25, 0.25).
    np.testing.assert_allclose(out.numpy()[1], [1.25, 0.25, 0.0], atol=1e-6)
    np.testing.assert_array_equal(out.numpy()[[0, 2]], x.numpy()[[0, 2]])


@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_stretch_falls_as_iterations_rise(device, solver):
    rms = []
    for iterations in (1, 4, 16, 64):
        scene = make_scene({"iterations": iterations, "relaxation": solver, "damping": 2.4}, resolution=[12, 12],
                           pins=["top-left", "top-right"], sticks=["structural", "shear"])
        sim = Simulator(scene, device)
        for _ in range(20):
            sim.step_frame()
        rms.append(sim.stretch().rms)
    assert all(b < a for a, b in zip(rms, rms[1:])), rms
    assert rms[-1] < 0.2 * rms[0], rms


def test_gauss_seidel_converges_faster_than_jacobi():
    # The point of colouring: for the same iteration count, Gauss-Seidel removes more error than Jacobi.
    rms = {}
    for solver in ("coloured", "jacobi"):
        scene = make_scene({"iterations": 8, "relaxation": solver}, resolution=[12, 12], pins=["top-edge"])
        sim = Simulator(scene, "cpu")
        for _ in range(20):
            sim.step_frame()
        rms[solver] = sim.stretch().rms
    assert rms["coloured"] < rms["jacobi"], rms
