"""bench.implicit_grid at a tiny size on the CPU: a row per form and budget with its time and stretch, the
computed sticks the same positions as the arrays, the tiled sweep its own order, and a bad tile refused."""

from __future__ import annotations

import csv

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import implicit_grid


def test_a_row_per_form_and_budget(tmp_path):
    # The tiled form first: its positions (another Gauss-Seidel order) are no reference for the others.
    assert implicit_grid.main(["--device", "cpu", "--sizes", "16", "--budgets", "2x2", "--repeats", "1",
                               "--target-size", "0", "--forms", "tiled", "explicit", "implicit",
                               "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "implicit-grid.csv")))
    assert [r["sticks"] for r in rows] == ["tiled", "explicit", "implicit"]
    same = {r["sticks"]: r["same positions"] for r in rows}
    assert same == {"tiled": "(tile order)", "explicit": "", "implicit": "yes"}
    assert "grid tiles" in rows[0]["constraint sets"]
    for row in rows:
        assert float(row["ms/frame"]) > 0 and row["stretch rms"].endswith("%")


def test_a_tile_that_is_not_a_multiple_of_four_is_refused(capsys):
    with pytest.raises(SystemExit):
        implicit_grid.main(["--device", "cpu", "--sizes", "16", "--tile", "6", "--target-size", "0"])
    assert "--tile must be a multiple of 4" in capsys.readouterr().err


def test_the_tether_pass_apart_gives_the_same_rows(tmp_path, monkeypatch):
    """--tethers-apart runs the first sweep's tether pass as its own launch: the same positions, so the same
    stretch to every printed digit."""
    from warp_verlet.core import stages

    monkeypatch.setattr(stages, "FOLD_TETHERS_INTO_INTEGRATE", {"cpu": True, "cuda": True})  # restored after
    rows = {}
    for name, extra in (("folded", []), ("apart", ["--tethers-apart"])):
        assert implicit_grid.main(["--device", "cpu", "--sizes", "16", "--budgets", "2x2", "--repeats", "1",
                                   "--target-size", "0", "--forms", "explicit", "--out", str(tmp_path / name),
                                   *extra]) == 0
        assert stages.FOLD_TETHERS_INTO_INTEGRATE["cpu"] == (name == "folded")
        rows[name] = list(csv.DictReader(open(tmp_path / name / "implicit-grid.csv")))[0]
    assert "tethers" in rows["apart"]["constraint sets"]
    for key in ("stretch rms", "stretch max"):
        assert rows["folded"][key] == rows["apart"][key]
