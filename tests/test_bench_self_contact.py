"""bench/self_contact.py at a tiny size: a row with and without self-collision per size, the cost measured, and
the worst penetration it reports is the one the self-contact tests bound with contact and large without; --peer
without Newton skips Newton's rows with one line, and with it adds them."""

from __future__ import annotations

import csv
import math

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import self_contact


def test_both_runs_are_measured_and_only_the_contact_holds(tmp_path):
    assert self_contact.main(["--sizes", "12", "--frames", "20", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "self_contact.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(r["n"], r["self_collision"]) for r in rows] == [("12", "off"), ("12", "on")]
    for r in rows:
        assert math.isfinite(float(r["ms/frame"])) and float(r["ms/frame"]) > 0
    off, on = (float(r["worst penetration"]) for r in rows)
    # The folded cloth lands on itself within 20 frames: without contact its layers meet (more than half the
    # thickness), with it they stay within the tests' tolerance (tests/test_self_contact.py's GAP_TOLERANCE).
    assert off > 0.5 and 0.0 <= on <= 0.15
    assert float(rows[0]["x without"]) == 1.0
    assert "command: `" in (tmp_path / "self_contact.md").read_text()


def test_peer_without_newton_prints_the_skip_and_keeps_the_table(tmp_path, capsys, monkeypatch):
    import sys

    from bench import newton_self_contact

    monkeypatch.setitem(sys.modules, "newton", None)  # `import newton` raises ImportError, installed or not
    assert not newton_self_contact.available()
    assert self_contact.main(["--sizes", "6", "--frames", "2", "--peer", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count(newton_self_contact.SKIP_MESSAGE) == 1
    with open(tmp_path / "self_contact.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(r["n"], r["self_collision"]) for r in rows] == [("6", "off"), ("6", "on")]
    assert "simulator" not in rows[0]  # warp-verlet's table as without --peer
    reported = []
    assert newton_self_contact.peer_rows(6, 2, 8, 8, "cpu", report=reported.append) == []
    assert reported == [newton_self_contact.SKIP_MESSAGE]


def test_grid_order_maps_newtons_particles_to_warp_verlets_and_refuses_another_grid():
    import numpy as np
    import pytest

    from bench import newton_self_contact

    n, spacing, origin = 4, 1.0 / 3.0, (-0.5, 0.1, -0.5)
    r, c = np.divmod(np.arange(n * n), n)
    grid = np.stack([origin[0] + c * spacing, np.full(n * n, origin[1]), origin[2] + r * spacing], axis=1)
    shuffle = np.random.default_rng(3).permutation(n * n)
    assert (newton_self_contact.grid_order(grid[shuffle], n, origin, spacing) == shuffle).all()
    with pytest.raises(RuntimeError, match="not warp-verlet's 4 x 4 grid"):
        newton_self_contact.grid_order(grid * 1.01, n, origin, spacing)  # not on the grid's cells
    with pytest.raises(RuntimeError, match="not warp-verlet's 4 x 4 grid"):
        newton_self_contact.grid_order(grid[[0, *range(n * n - 1)]], n, origin, spacing)  # a cell twice


@pytest.mark.slow
def test_newton_rows_when_newton_is_installed():
    pytest.importorskip("newton")
    from bench import newton_self_contact

    rows = newton_self_contact.peer_rows(8, 20, 8, 8, "cpu")
    assert [(r["simulator"], r["self_collision"]) for r in rows] == [
        ("newton-vbd", "off"), ("newton-vbd", "on"), ("newton-style3d", "off"), ("newton-style3d", "on")]
    for r in rows:
        assert math.isfinite(r["ms/frame"]) and r["ms/frame"] > 0 and r["particles"] == 64
    # The layers meet without self-contact and stay apart with it (the measure warp-verlet's rows are held to).
    assert rows[0]["worst penetration"] > 0.5 and rows[1]["worst penetration"] <= 0.15
    assert rows[3]["worst penetration"] <= 0.15
