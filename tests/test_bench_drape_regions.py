"""bench.drape_regions: the structural stretch of a grid, signed, against a hand-made stretch; the regions; and a
tiny run on the CPU with a row per run, a bad budget refused."""

from __future__ import annotations

import csv

import numpy as np
import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import drape_regions


def test_the_stretch_of_a_grid_pulled_along_its_rows_is_signed_and_per_stick():
    # A flat 5 x 5 grid of the drape's spacing, stretched 2% along x and squeezed 1% along z: the row sticks read
    # +2%, the column sticks -1%, and the row at the top shows the first row's values.
    n = 5
    h = 1.0 / (n - 1)
    col, row = np.meshgrid(np.arange(n), np.arange(n))
    x = np.stack([1.02 * h * col, np.zeros_like(col, float), 0.99 * h * row], axis=-1).reshape(-1, 3)
    stretch, middle = drape_regions.structural_stretch(x, n)
    assert stretch.shape == (2 * n * (n - 1),) and middle.shape == (2 * n * (n - 1), 3)
    np.testing.assert_allclose(stretch[: n * (n - 1)], 0.02, atol=1e-12)
    np.testing.assert_allclose(stretch[n * (n - 1):], -0.01, atol=1e-12)
    np.testing.assert_allclose(middle[0], [0.51 * h, 0.0, 0.0])
    assert drape_regions.row_at_top(stretch, n, count=2) == pytest.approx([0.02, 0.02])


def test_regions_split_sticks_by_the_surface_they_lie_on():
    on_ball = [0.0, drape_regions.BALL_RADIUS + 0.01, 0.0]
    on_ground = [0.6, drape_regions.GROUND + 0.01, 0.0]
    free = [0.6, 0.0, 0.0]
    masks = drape_regions.regions(np.array([on_ball, on_ground, free]))
    assert {k: v.tolist() for k, v in masks.items()} == {"ball": [True, False, False], "ground": [False, True, False],
                                                         "free": [False, False, True]}


def test_a_row_per_run(tmp_path):
    assert drape_regions.main(["--device", "cpu", "--sizes", "8", "--budgets", "2x1", "--families",
                               "structural,shear,bend", "structural", "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "drape-regions.csv")))
    assert [r["families"] for r in rows] == ["structural, shear, bend", "structural"]
    for r in rows:
        shares = [float(r[f"{k}: share"].rstrip("%")) for k in ("ball", "ground", "free")]
        assert sum(shares) == pytest.approx(100, abs=1.5) and float(r["ms/frame"]) > 0
        assert len(r["row at the top"].split()) == 7  # a row of 8 particles: all its 7 sticks


def test_a_bad_budget_is_refused(capsys):
    with pytest.raises(SystemExit):
        drape_regions.main(["--sizes", "8", "--budgets", "2by1"])
    assert "a budget is substeps x sweeps" in capsys.readouterr().err
