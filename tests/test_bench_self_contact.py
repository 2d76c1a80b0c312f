"""bench/self_contact.py at a tiny size: a row with and without self-collision per size, the cost measured, and
the worst penetration it reports is the one the self-contact tests bound with contact and large without."""

from __future__ import annotations

import csv
import math

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
