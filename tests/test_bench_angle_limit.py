"""bench/angle_limit.py at a tiny size: its table has a row per limit and sweep count, each with its worst
joint angle, and the limited rows stay within the overshoot the angle-limit tests state."""

from __future__ import annotations

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import angle_limit


def test_the_worst_angle_is_measured_and_held_near_the_limit():
    free, _ = angle_limit.worst_angle(None, 16, 20)
    limited, ms = angle_limit.worst_angle(5.0, 16, 20)
    assert free > 7.0  # the free rope bends further than the limit within 20 frames: the row means something
    assert limited <= 5.0 * 1.15 and ms > 0.0
