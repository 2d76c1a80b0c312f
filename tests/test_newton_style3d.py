"""bench.newton_style3d: the hanging cloth through Newton's Style3D (and VBD) cloth solvers.

Newton is optional (not installed in CI): the module imports without it, and the physics tests skip.
"""

from __future__ import annotations

import numpy as np
import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import newton_style3d


def test_structural_stretch_of_the_rest_grid_and_a_stretched_one():
    n = 5
    c, r = np.meshgrid(np.linspace(-0.5, 0.5, n), np.linspace(1.0, 0.0, n))
    rest = np.stack([c, r, np.zeros_like(c)], axis=-1).reshape(-1, 3)
    assert newton_style3d.structural_stretch(rest, n) == pytest.approx((0.0, 0.0), abs=1e-12)
    stretched = rest * np.array([1.1, 1.0, 1.0])  # horizontal pairs 10 % long, vertical ones at rest
    rms, worst = newton_style3d.structural_stretch(stretched, n)
    assert worst == pytest.approx(0.1)
    assert rms == pytest.approx(0.1 / np.sqrt(2.0))


def test_newton_to_grid_order_puts_newtons_top_row_first():
    order = newton_style3d.newton_to_grid_order(3)
    assert sorted(order) == list(range(9))
    assert list(order[6:]) == [0, 1, 2]  # Newton's last row (highest y) is warp_verlet's row 0


@pytest.mark.parametrize("solver", ["style3d", "vbd"])
def test_cloth_hangs_from_fixed_pins(solver):
    pytest.importorskip("newton")
    n = 8
    r = newton_style3d.run_peer(solver, n, frames=3, device="cpu")
    p = r["positions"]
    assert p.shape == (n * n, 3) and p.dtype == np.float32 and np.isfinite(p).all()
    # Particles 0 and n - 1 are the pinned top corners, where warp_verlet puts them.
    np.testing.assert_allclose(p[0], [-0.5, 1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(p[n - 1], [0.5, 1.0, 0.0], atol=1e-6)
    # Every other particle is below the pins, and gravity has pulled the free ones down.
    free = np.setdiff1d(np.arange(n * n), [0, n - 1])
    assert (p[free, 1] < 1.0).all()
    assert p[(n - 1) * n:, 1].max() < 0.0  # the bottom edge started at y = 0
    assert r["solver"] == solver and r["n"] == n
    assert (r["substeps"], r["iterations"]) == {"style3d": (2, 10), "vbd": (4, 8)}[solver]
    assert r["setup_s"] > 0 and r["first_frame_s"] > 0 and r["ms_per_frame"] > 0
    if solver == "style3d":
        assert newton_style3d.structural_stretch(p, n)[0] < 1e-2


def test_main_prints_or_skips(capsys):
    assert newton_style3d.main(["--n", "4", "--frames", "2", "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    if newton_style3d.available():
        assert "per frame" in out and "stretch" in out
    else:
        assert newton_style3d.SKIP_MESSAGE in out


def test_level_start_lays_the_cloth_as_the_swinging_scene_and_it_swings_down():
    # bench.convergence's swinging scene in Newton: level at y = 1 m, row r of warp_verlet's order at z = r / (n - 1)
    # (checked after one frame, when it has fallen under a millimetre), pinned at row 0's corners. After half a
    # second VBD's far edge has swung far below the pins (measured y = -0.005 m at 8²). Style3D's, with its
    # example's 2 x 10, has fallen only 0.1 m at 8² to 32² (its PCG carries the whole cloth's fall slowly).
    pytest.importorskip("newton")
    n = 8
    first = newton_style3d.run_peer("style3d", n, frames=1, device="cpu", level=True)["positions"].reshape(n, n, 3)
    np.testing.assert_allclose(first[:, 0, 2], np.arange(n) / (n - 1), atol=1e-4)
    np.testing.assert_allclose(first[..., 1], 1.0, atol=5e-3)
    later = newton_style3d.run_peer("vbd", n, frames=30, device="cpu", level=True)["positions"].reshape(n, n, 3)
    np.testing.assert_allclose(later[0, [0, -1]], [[-0.5, 1.0, 0.0], [0.5, 1.0, 0.0]], atol=1e-6)
    assert later[-1, :, 1].max() < 0.5
