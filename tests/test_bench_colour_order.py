"""bench.colour_order: every order on the same scene, the sweep order put back after, bad arguments refused."""

from __future__ import annotations

import csv

import pytest

from bench import colour_order
from warp_verlet.geometry import topology


def test_the_orders_run_on_a_bench_scene_and_a_shipped_one_and_the_sweep_order_is_put_back(tmp_path):
    before = topology.SWEEP_ORDER
    # The drape, not the hanging sheet: hung by two corners where it would hang, the sheet stays still under its
    # tethers at this size, and every order leaves it unstretched.
    assert colour_order.main(["--device", "cpu", "--scenes", "drape", "--sizes", "12", "--budgets", "4x2",
                              "--shipped", "rope", "--orders", "all", "--repeats", "1", "--out", str(tmp_path)]) == 0
    assert topology.SWEEP_ORDER is before
    rows = list(csv.DictReader(open(tmp_path / "colour-order.csv")))
    assert [r["order"] for r in rows] == list(colour_order.ORDERS) * 2
    assert [r["scene"] for r in rows] == ["drape"] * 6 + ["rope"] * 6
    drape = {r["order"]: float(r["structural rms"].rstrip("%")) for r in rows[:6]}
    assert len(set(drape.values())) > 1  # the order changes the result
    assert "command: `python -m bench.colour_order" in (tmp_path / "colour-order.md").read_text()


@pytest.mark.parametrize("args, words", [
    (["--budgets", "4by2"], "--budgets takes SxK pairs"),
    (["--orders", "shear first"], "--orders: unknown"),
    (["--shipped", "no_such_scene"], "no scenes/no_such_scene.toml"),
])
def test_bad_arguments_are_usage_errors(args, words, capsys):
    with pytest.raises(SystemExit):
        colour_order.main(["--device", "cpu", "--sizes", "12", *args])
    assert words in capsys.readouterr().err
