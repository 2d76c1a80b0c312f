"""bench/aerodynamics.py at a tiny size: a cost row per cloth size, timed with and without air, and the table
written where --out says."""

from __future__ import annotations

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import aerodynamics


def test_the_cost_table_times_each_size_with_and_without_air(tmp_path):
    assert aerodynamics.main(["--sizes", "6", "--threads", "1", "--frames", "2", "--repeats", "1",
                              "--out", str(tmp_path)]) == 0
    text = (tmp_path / "aerodynamics.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith("| cpu | 6 x 6 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    without, with_air = float(cells[4].split()[0]), float(cells[5].split()[0])
    assert without > 0.0 and with_air > 0.0 and cells[3] == "25"  # (6 - 1)^2 faces


@pytest.mark.slow
def test_the_flag_flutters_in_air_and_not_under_the_uniform_wind():
    air = aerodynamics.flutter({"air": {"velocity": [10.0, 0.0, 0.0]}}, 8)
    wind = aerodynamics.flutter({"wind": [0.8 * 9.81, 0.0, 0.0]}, 8)
    assert air["rms"] > 10 * wind["rms"] and air["f"] > 0.0
