"""bench.rigid_patches at a tiny size: both methods and the patch-less cloth run on the same cloth, the all-pairs
sticks kind registered from the bench really runs (its colours are launched) and the registry is put back."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import rigid_patches
from warp_verlet import constraints
from warp_verlet.geometry.colouring import MAX_COLOURS

RIGID = 1.0e-6
"""m: shape matching leaves a patch of a 0.2 m cloth on its rest shape within float32 rounding."""


def read(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def registry() -> list:
    return [constraints.CONSTRAINT_KINDS, constraints.kinds()]


def test_both_methods_on_the_same_cloth(tmp_path):
    before = registry()
    assert rigid_patches.main(["--cloth", "10", "--patches", "2", "4", "--sweeps", "4", "--frames", "3",
                               "--out", str(tmp_path)]) == 0
    assert all(now is then for now, then in zip(registry(), before))  # put back
    rows = read(tmp_path / "rigid_patches.csv")
    assert [(r["patch"], r["method"]) for r in rows] == [(p, m) for p in ("2x2", "4x4") for m in rigid_patches.METHODS]
    for shape, pairs, free in zip(rows[0::3], rows[1::3], rows[2::3]):
        k = int(shape["patch"].split("x")[0])
        for r in (shape, pairs, free):
            assert math.isfinite(float(r["ms/frame"])) and float(r["ms/frame"]) > 0
        # One launch per sweep for all the patches; all-pairs sticks: a particle touches k^2 - 1 of its patch's
        # sticks, each in a colour of its own, and at most MAX_COLOURS colours (the last the overflow).
        assert int(shape["patch launches / sweep"]) == 1 and int(free["patch launches / sweep"]) == 0
        assert k * k - 1 <= int(pairs["patch launches / sweep"]) <= MAX_COLOURS
        for r in (shape, pairs):
            assert int(r["launches / sweep"]) == int(free["launches / sweep"]) + int(r["patch launches / sweep"])
        assert float(shape["worst pair error m"]) <= RIGID
        # The patch-less cloth bends the same particles: the measurement sees what the constraints prevent.
        assert float(free["worst pair error m"]) > 10 * max(float(shape["worst pair error m"]),
                                                            float(pairs["worst pair error m"]))
    assert "command: `" in (tmp_path / "rigid_patches.md").read_text()


def test_the_registry_is_put_back_when_a_run_fails():
    before = registry()
    with pytest.raises(RuntimeError, match="inside"):
        with rigid_patches.registered(rigid_patches.AllPairsSticks()):
            assert constraints.CONSTRAINT_KINDS[-1].name == "all-pairs sticks"
            assert all(kinds is constraints.CONSTRAINT_KINDS for kinds in registry())
            raise RuntimeError("inside")
    assert all(now is then for now, then in zip(registry(), before))
