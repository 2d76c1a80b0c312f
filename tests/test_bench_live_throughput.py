"""bench.live_throughput at a tiny size: the table has its columns with finite numbers, every vertex of a small grid
is drawn and crosses the socket as float32 (message size at least the raw positions), the live app ran, and the
budget and tethers asked for are the ones measured (the stretch is the cloth's, not a default's)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from browser import free_port

pytest.importorskip("viser", reason="bench.live_throughput needs viser: pip install 'warp-verlet[live]'")


def rows_of(tmp_path, *extra: str) -> tuple[list[dict], Path]:
    from bench import live_throughput

    args = ["--device", "cpu", "--sizes", "8", "--seconds", "0.5", "--port", str(free_port()), "--out", str(tmp_path),
            *extra]
    assert live_throughput.main(args) == 0
    [path] = tmp_path.glob("live-cpu-*.csv")
    with open(path) as f:
        return list(csv.DictReader(f)), path


@pytest.mark.slow
def test_live_table_has_every_column_with_numbers(tmp_path):
    rows, path = rows_of(tmp_path)
    assert path.name == "live-cpu-4x8.csv"
    [row] = rows
    assert row["grid"] == "8^2" and row["budget"] == "4x8" and row["device"] == "cpu"
    for key in ("sim ms/frame", "copy ms", "readout ms", "reduce ms", "send ms", "arrives ms", "live frames/s",
                "draws/s"):
        assert math.isfinite(float(row[key])) and float(row[key]) >= 0, key
    assert int(row["drawn"]) == 64  # a small grid is drawn whole
    assert float(row["KB/draw"]) >= float(row["raw KB"]) > 0  # float32 positions, not fewer bytes
    assert float(row["live frames/s"]) > 0 and float(row["draws/s"]) > 0
    assert 0 < float(row["stretch RMS"].rstrip("%")) <= float(row["stretch max"].rstrip("%"))


@pytest.mark.slow
def test_budget_and_tethers_reach_the_scene(tmp_path):
    plain, _ = rows_of(tmp_path / "plain", "--substeps", "1", "--iterations", "1")
    tethered, path = rows_of(tmp_path / "tethered", "--substeps", "1", "--iterations", "1", "--tethers")
    assert path.name == "live-cpu-1x1-tethers.csv" and tethered[0]["budget"] == "1x1 tethers"
    # One sweep a substep leaves the plain 8 x 8 cloth stretched; tethers hold it nearer its length.
    assert float(tethered[0]["stretch max"].rstrip("%")) < float(plain[0]["stretch max"].rstrip("%"))
