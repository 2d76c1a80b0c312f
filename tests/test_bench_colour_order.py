"""bench.colour_order: both orders on the same scene, the order put back after, a bad budget refused."""

from __future__ import annotations

import csv

import pytest

from bench import colour_order
from warp_verlet.geometry import topology


def test_both_orders_run_and_the_sweep_order_is_put_back(tmp_path):
    before = topology.SWEEP_ORDER
    assert colour_order.main(["--device", "cpu", "--scenes", "hanging", "--sizes", "12", "--budgets", "4x2",
                              "--repeats", "1", "--out", str(tmp_path)]) == 0
    assert topology.SWEEP_ORDER is before
    rows = list(csv.DictReader(open(tmp_path / "colour-order.csv")))
    assert [r["order"] for r in rows] == ["longest first", "classes' order"]
    rms = [float(r["structural rms"].rstrip("%")) for r in rows]
    assert rms[0] < rms[1]  # the same launches, less stretch
    assert "command: `python -m bench.colour_order" in (tmp_path / "colour-order.md").read_text()


def test_a_bad_budget_is_a_usage_error(capsys):
    with pytest.raises(SystemExit):
        colour_order.main(["--device", "cpu", "--sizes", "12", "--budgets", "4by2"])
    assert "--budgets takes SxK pairs" in capsys.readouterr().err
