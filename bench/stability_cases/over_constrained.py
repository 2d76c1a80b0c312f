"""Over-constrained cloths: pins moved beyond reach, one particle pinned two ways."""

from __future__ import annotations

import numpy as np

from warp_verlet.core.simulator import Simulator

from ..common import HANGING_FAMILIES
from .base import Check, count_check, nonfinite, scene


def pins_apart(device: str = "cpu", size: str = "test") -> list[Check]:
    """The top-right pin moved 2 m further right after construction (pins 3 m apart; the top edge is 1 m
    long): nothing can satisfy the sticks. Undamped for 2 s, the cloth stays finite and every particle stays
    inside the pins' bounding box grown by twice the cloth size (1 m). Once is not enough for rigid sticks
    relaxed by 8 sweeps, which stretch: the same cloth with its pins in place already swings 1.003 m (16^2) to
    1.089 m (64^2) below them; over-constrained it reaches 0.74 m and 1.003 m."""
    n = 16 if size == "test" else 64
    case = f"over-constrained: pins 3 m apart ({n}x{n}, 1 m cloth)"
    reach = {}
    for shift in (0.0, 2.0):
        sc = scene({"iterations": 8}, {"name": "curtain", "resolution": [n, n], "size": [1.0, 1.0],
                                       "pins": ["top-left", "top-right"], "sticks": HANGING_FAMILIES})
        sim = Simulator(sc, device)
        x = sim.positions()
        x[n - 1] += np.float32([shift, 0.0, 0.0])
        sim.state.set_positions(x)
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


def xpbd_sweeps(u: float, L: float, d: float, w: float, alpha_tilde: float, sweeps: int, a_first: bool) -> float:
    """The middle particle's position after ``sweeps`` coloured XPBD sweeps from ``u`` (kernels/relax.py, in
    float64 along the line): stick A ties it to the pin at 0, stick B to the pin at d, both of rest length L;
    each projection moves it by w e / (w + alpha~) with e = C - alpha~ mu, and the tensions mu start at 0 in
    every substep. alpha~ = 0 is the rigid projection."""
    mu = [0.0, 0.0]
    for _ in range(sweeps):
        for stick in ((0, 1) if a_first else (1, 0)):
            if stick == 0:
                e = (u - L) - alpha_tilde * mu[0]
                mu[0] += e / (w + alpha_tilde)
                u -= w * e / (w + alpha_tilde)
            else:
                e = (d - u - L) - alpha_tilde * mu[1]
                mu[1] += e / (w + alpha_tilde)
                u += w * e / (w + alpha_tilde)
    return u


def two_places(device: str = "cpu", size: str = "test") -> list[Check]:
    """A particle between two pinned neighbours whose pins are moved apart, d = 3 L, no gravity: both sticks
    cannot hold. The K sweeps of one substep map the particle's predicted position u affinely, u -> a u + b, and
    a particle at rest must sit at the fixed point u* = b / (1 - a). Rigid sticks, coloured Gauss-Seidel: the
    stick projected last is exact and the other takes all of the error (u* = d - L when stick A, from the pin at
    0, comes first; a = 0). Jacobi averages the two corrections and splits it evenly (u* = d / 2). Soft sticks
    (XPBD compliance alpha, alpha~ = alpha / dt^2, the tensions reset each substep): a and b follow exactly from
    the kernel's update (:func:`xpbd_sweeps`, float64), and u* lies between the rigid d - L and the balance of
    two equal springs, d / 2, which the sweeps converge to (measured: alpha~ = w / 5 gives 0.765 m, alpha~ = w
    0.750006 m). The run must reach that fixed point, never leave [L, d - L], and sim.stretch() must report the
    unsatisfied error. Compliances are given as alpha~ / w, w the particle's inverse mass: alpha~ = w is the
    compliance at which one projection removes half of a stick's error."""
    checks = []
    L, d = 0.5, 1.5
    runs = [("coloured", 0.0), ("coloured", 0.2), ("coloured", 1.0), ("jacobi", 0.0)]
    if size == "bench":
        runs += [("coloured", 10.0)]
    for solver, ratio in runs:
        iterations = 8
        cloth = {"name": "rope", "resolution": [1, 3], "size": [0.0, 2 * L], "pins": [0, 2], "sticks": ["structural"]}
        probe = Simulator(scene({"iterations": iterations, "gravity": [0.0, 0.0, 0.0]}, cloth), "cpu")
        w, dt = float(probe.model.host_inv_mass[1]), probe.settings.dt
        alpha = ratio * w * dt * dt  # m/N
        if alpha:
            cloth["compliance"] = {"structural": alpha}
        label = f"alpha = {alpha:.3g} m/N (alpha~ = {ratio:g} w)" if alpha else "rigid"
        case = f"over-constrained: one particle pinned two ways ({solver}, {label})"
        sim = Simulator(scene({"iterations": iterations, "gravity": [0.0, 0.0, 0.0], "relaxation": solver}, cloth),
                        device)
        x = sim.positions()
        x[2, 0] = d
        sim.state.set_positions(x)
        if solver == "coloured":
            a_first = tuple(sim.model.host_sticks[0]) == (0, 1)  # sticks are stored in launch (colour) order
            b = xpbd_sweeps(0.0, L, d, w, alpha / (dt * dt), iterations, a_first)
            a = xpbd_sweeps(1.0, L, d, w, alpha / (dt * dt), iterations, a_first) - b
            u_star = b / (1.0 - a)
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
