"""bench.mesh_throughput at a tiny size: its table has the three variants per size with finite numbers, the quad mesh
has the grid's particles and sticks (its exact quads) and at least the grid's 12 colours, and the mesh pins are
the grid's."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import mesh_throughput


def read(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def test_three_variants_and_the_quad_mesh_is_the_grid(tmp_path):
    args = ["--device", "cpu", "--sizes", "6", "--frames", "3", "--repeats", "1", "--threads", "1",
            "--out", str(tmp_path)]
    assert mesh_throughput.main(args) == 0  # 2 warm-up frames, 1 timed
    rows = read(tmp_path / "mesh_throughput.csv")
    assert [(r["size"], r["variant"]) for r in rows] == [("6x6", v) for v in ("grid", "quad mesh", "triangle mesh")]
    for r in rows:
        for key in ("ms/frame", "Mproj/s", "stretch rms", "stretch max", "balance", "load s", "build s"):
            assert math.isfinite(float(r[key])) and float(r[key]) >= 0, key
        assert int(r["particles"]) == 36 and r["frames timed"] == "1"
    grid, quads, triangles = rows
    assert (quads["particles"], quads["sticks"]) == (grid["particles"], grid["sticks"])
    assert int(quads["colours"]) >= int(grid["colours"]) == 12
    assert int(triangles["sticks"]) != int(grid["sticks"])  # diagonals structural, no shear: other sticks
    text = (tmp_path / "mesh_throughput.md").read_text()
    assert "command: `" in text and "not the same measure" in text


def test_mesh_pins_are_the_grids(tmp_path):
    for pins, count in (("corners", 2), ("top-edge", 5)):
        scenes = mesh_throughput.grid_and_meshes(5, 4, 8, pins, "ply", tmp_path)
        grid = scenes["grid"][0].cloths[0]
        expected = sorted(r * 5 + c for r, c in grid.pins)
        assert len(expected) == count
        for variant in ("quad mesh", "triangle mesh"):
            assert list(scenes[variant][0].cloths[0].mesh.pins) == expected, (pins, variant)


def test_orders_give_a_row_each_and_setup_only_times_the_reordering(tmp_path):
    args = ["--device", "cpu", "--sizes", "6", "--frames", "3", "--repeats", "1", "--threads", "1", "--shuffle",
            "--orders", "input", "reordered", "--out", str(tmp_path)]
    assert mesh_throughput.main(args) == 0
    rows = read(tmp_path / "mesh_throughput.csv")
    assert [(r["variant"], r["particle order"]) for r in rows] == [
        ("grid", "row-major"), ("quad mesh", "input"), ("quad mesh", "Morton"), ("triangle mesh", "input"),
        ("triangle mesh", "Morton")]
    assert [r["reorder s"] == "" for r in rows] == [True, True, False, True, False]
    assert all(float(r["reorder s"]) >= 0 for r in rows if r["reorder s"])
    assert rows[1]["sticks"] == rows[2]["sticks"] == rows[0]["sticks"]  # the same cloth in either order
    assert "(Morton order)" in (tmp_path / "mesh_throughput.md").read_text()
    assert mesh_throughput.main(["--device", "cpu", "--sizes", "6", "--setup-only", "--no-colouring",
                                 "--out", str(tmp_path), "--stem", "setup"]) == 0
    (row,) = read(tmp_path / "setup.csv")
    assert int(row["particles"]) == 36 and float(row["reorder s"]) >= 0 and row["graph colouring s"] == ""
