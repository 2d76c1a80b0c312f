"""bench.l2_profile, the frames bench/gpu_l2_profile.sh hands Nsight Compute: it builds the sheet with the sticks
asked for and steps it, on any device (smoke test on the CPU; the profile itself needs a GPU and ncu)."""

from __future__ import annotations

import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import l2_profile


@pytest.mark.parametrize("sticks, sets", [("explicit", "'sticks'"), ("implicit", "'grid sticks'"),
                                         ("tiled", "'grid tiles'")])
def test_it_steps_the_sheet_with_the_sticks_asked_for(sticks, sets, capsys):
    assert l2_profile.main(["--size", "8", "--budget", "1x1", "--frames", "1", "--device", "cpu",
                            "--sticks", sticks]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"8^2 1x1 {sticks}: constraint sets") and sets in out, out
