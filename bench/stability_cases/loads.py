"""Extreme loads: gravity 1000 m/s^2, and a gale that tears every stick."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from warp_verlet.core.simulator import Simulator

from .base import Check, count_check, hanging, run_with_energy, scene, ulp


def heavy_gravity(device: str = "cpu", size: str = "test") -> list[Check]:
    """Gravity 1000 m/s^2 (g dt^2 = 1.7 cm per substep, half a particle spacing at 32^2), undamped, 1 s."""
    n = 16 if size == "test" else 64
    case = f"loads: gravity 1000 m/s^2 ({n}x{n})"
    sim = Simulator(hanging(n, {"iterations": 8, "gravity": [0.0, -1000.0, 0.0]}), device)
    log = run_with_energy(sim, 240)
    stretch = sim.stretch().max
    return [replace(c, note=f"{c.note}; stretch max {stretch:.3g}") if c.note else c for c in log.checks(case)]


def tearing_gale(device: str = "cpu", size: str = "test") -> list[Check]:
    """Every other particle pinned (a checkerboard), structural sticks only, so every stick joins a pin to a
    free particle; a wind of |w| = 2.2e4 m/s^2 moves a free particle w dt^2 = 0.39 m per substep, against a
    spacing of L = 0.1 m, and every stick must tear (threshold 1.5). The sticks are soft, compliance
    alpha = 4 dt^2 / m (m the particle's mass; alpha~ = 4 / m: one projection removes 1/5 of a stick's error),
    so that no intact equilibrium exists: a stick of stiffness 1 / alpha pushes or pulls with at most L / alpha
    until it tears (compressed to 0, or stretched by 0.5 L), so the at most 4 sticks of a particle hold at most
    4 L / alpha = m L / dt^2, less than the wind's m |w| since |w| dt^2 = 0.39 m > L; the spring the XPBD sweeps
    converge to cannot hold the particle, which accelerates until its sticks tear. Afterwards no stick acts, so
    each free particle is in free fall under gravity + wind: its second differences x[n+1] - 2 x[n] + x[n-1]
    equal (g + w) dt^2 to float32 rounding."""
    n = 8 if size == "test" else 64
    case = f"loads: gale tears every stick ({n}x{n})"
    pins = [[r, c] for r in range(n) for c in range(n) if (r + c) % 2 == 0]
    mass, dt = 1.0, 1.0 / 240.0
    alpha = 4.0 * dt * dt / (mass / (n * n))  # m/N
    sc = scene({"iterations": 8, "wind": [2.0e4, 0.0, 1.0e4]},
               {"name": "net", "resolution": [n, n], "size": [0.1 * (n - 1)] * 2, "pins": pins, "mass": mass,
                "sticks": ["structural"], "compliance": {"structural": alpha}, "tear_threshold": 1.5})
    assert sc.simulation.dt == dt
    sim = Simulator(sc, device)
    torn_at = None
    for step in range(1, 41):
        sim.step()
        if torn_at is None and sim.torn_count() == sim.model.stick_count:
            torn_at = step
    history = []
    for _ in range(12):
        sim.step()
        history.append(sim.positions().astype(np.float64))
    free = sim.model.inv_mass.numpy() > 0
    y = np.array(history)[:, free]
    second = y[2:] - 2 * y[1:-1] + y[:-2]
    dt = sim.settings.dt
    a = (np.asarray(sim.settings.gravity) + np.asarray(sim.settings.wind)) * dt * dt
    # Each of the three positions is rounded to half an ulp, and the increment too: 4 ulps of |x| in all.
    error = float(np.abs(second - a).max() / (4 * ulp(y)))
    return [
        Check(case, "sticks not torn after 40 substeps", float(sim.model.stick_count - sim.torn_count()), 0.0,
              "physics: |w| dt^2 > spacing, so 4 soft sticks cannot hold a particle (docstring)",
              f"all {sim.model.stick_count} torn at substep {torn_at}; alpha = {alpha:.3g} m/N"),
        count_check(case, "particles lost or added", abs(sim.positions().shape[0] - n * n)),
        Check(case, "free fall after tearing: max |second difference - a dt^2| / (4 ulp)", error, 1.0,
              "float32 rounding of three positions", f"a dt^2 = {np.linalg.norm(a):.3f} m"),
    ]
