"""Over-constrained cloths: pins moved beyond reach, one particle pinned two ways."""

from __future__ import annotations

import numpy as np

from warp_verlet.simulator import Simulator

from ..common import HANGING_STICKS, set_positions
from .base import Check, count_check, nonfinite, scene


def pins_apart(device: str = "cpu", size: str = "test") -> list[Check]:
    """The top-right pin moved 2 m further right after construction (pins 3 m apart; the top edge is 1 m
    long): nothing can satisfy the sticks. Undamped for 2 s, the cloth stays finite and every particle stays
    inside the pins' bounding box grown by twice the cloth size (1 m). Once is not enough for a cloth of
    finite stiffness: the same cloth with its pins in place already swings 1.007 m (16^2) to 1.157 m (64^2)
    below them (8 sweeps); over-constrained it reaches 0.88 m and 1.006 m."""
    n = 16 if size == "test" else 64
    case = f"over-constrained: pins 3 m apart ({n}x{n}, 1 m cloth)"
    reach = {}
    for shift in (0.0, 2.0):
        sc = scene({"iterations": 8}, {"name": "curtain", "resolution": [n, n], "size": [1.0, 1.0],
                                       "pins": ["top-left", "top-right"], "sticks": HANGING_STICKS})
        sim = Simulator(sc, device)
        x = sim.positions()
        x[n - 1] += np.float32([shift, 0.0, 0.0])
        set_positions(sim, x)
        pins = x[[0, n - 1]].astype(np.float64)
        lo, hi = pins.min(axis=0), pins.max(axis=0)
        outside, bad = -np.inf, 0
        for _ in range(120):
            sim.step_frame()
            p = sim.positions().astype(np.float64)
            bad += nonfinite(p)
            outside = max(outside, float(np.max(np.maximum(lo - p, p - hi))))
        reach[shift] = outside
    return [count_check(case, "particles with a NaN/inf coordinate", bad),
            Check(case, "furthest a particle got outside the pins' box (m)", reach[2.0], 2.0,
                  "stated: the box grown by 2 x the cloth size",
                  f"pins in place: {reach[0.0]:.3f} m; stretch max {sim.stretch().max:.3g} (never converges; "
                  "the simulator does not say so)")]


def two_places(device: str = "cpu", size: str = "test") -> list[Check]:
    """A particle between two pinned neighbours whose pins are moved apart, d = 3 L, no gravity: both sticks
    cannot hold. Coloured Gauss-Seidel projects stick A (colour first) then stick B by k' each, so along the
    line the middle particle at u (from A) maps to u1 = u - k'(u - L), then u2 = u1 + k'(d - u1 - L). The
    fixed point is u* = ((1 - k') L + d - L) / (2 - k'): stick A keeps error (d - 2L) / (2 - k'), stick B
    (1 - k') (d - 2L) / (2 - k'). At k' = 1 the stick projected last is exact and the other takes all of
    it; Jacobi averages the two corrections and splits it evenly (u* = d / 2). The run must reach that fixed
    point, never leave [L, d - L], and sim.stretch() must report the unsatisfied error."""
    checks = []
    L, d = 0.5, 1.5
    runs = [("coloured", 1.0), ("coloured", 0.5), ("jacobi", 1.0)]
    if size == "bench":
        runs += [("coloured", 0.1), ("jacobi", 0.5)]
    for solver, k in runs:
        case = f"over-constrained: one particle pinned two ways ({solver}, k = {k})"
        iterations = 8
        sim = Simulator(scene({"iterations": iterations, "gravity": [0.0, 0.0, 0.0], "solver": solver},
                              {"name": "rope", "resolution": [1, 3], "size": [0.0, 2 * L], "pins": [0, 2],
                               "sticks": {"structural": k}}), device)
        x = sim.positions()
        x[2, 0] = d
        set_positions(sim, x)
        kp = 1.0 - (1.0 - k) ** (1.0 / iterations)
        if solver == "coloured":
            first = tuple(sim.model.host_sticks[0])  # sticks are stored in launch (colour) order
            u_star = ((1 - kp) * L + d - L) / (2 - kp)
            if first == (1, 2):  # stick B first: mirror
                u_star = d - u_star
        else:
            u_star = d / 2
        excursion = -np.inf
        for _ in range(400):
            sim.step()
            u = float(sim.positions()[1, 0])
            excursion = max(excursion, L - u, u - (d - L))
        p = sim.positions().astype(np.float64)
        errors = np.abs(np.linalg.norm(np.diff(p, axis=0), axis=1) - L) / L
        checks += [
            Check(case, "|u - u*| / d after 400 substeps", abs(p[1, 0] - u_star) / d, 1e-5,
                  "analytic fixed point; float32", f"u* = {u_star:.6f} m, measured {p[1, 0]:.6f} m"),
            Check(case, "furthest outside [L, d - L] (m)", excursion, 1e-6, "analytic: between both sticks' answers"),
            Check(case, "|sim.stretch().max - predicted max stick error / L|",
                  abs(sim.stretch().max - max(abs(u_star - L), abs(d - u_star - L)) / L), 1e-5,
                  "analytic; the residual is visible", f"stick errors / L: {errors[0]:.4f}, {errors[1]:.4f}"),
        ]
    return checks
