"""Long runs: an undamped cloth over 10 000 substeps."""

from __future__ import annotations

from warp_verlet.core.simulator import Simulator

from .base import Check, hanging, run_with_energy


def long_run(device: str = "cpu", size: str = "test") -> list[Check]:
    """10 000 substeps (bench; 2 000 in the test) of an undamped (damping 0) cloth pinned at two corners,
    swinging down from horizontal: finite, energy never above its start by more than 1% of the potential
    energy released. The drift at the end is reported (negative: projection dissipates)."""
    n, steps = (16, 2000) if size == "test" else (32, 10000)
    case = f"long run: {steps} substeps, damping 0 ({n}x{n})"
    log = run_with_energy(Simulator(hanging(n, {"iterations": 8}), device), steps)
    return log.checks(case, tolerance=0.01)
