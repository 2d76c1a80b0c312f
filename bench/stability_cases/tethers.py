"""Convergence aids: tethers (long-range attachments to the pins) and small steps (many substeps, few sweeps).

Tethers are the one constraint here that is on by default (a pinned cloth that cannot tear gets them); every
other category turns them off. These cases turn them on and check that they do what they are for without
costing stability: they hold every particle within reach of its pins, they pull a hanging cloth taut at the
default budget, and they add no energy. Small steps are the other aid: they must stay exact where the physics
is exact (free fall) and accurate where it is known (a pendulum's period).
"""

from __future__ import annotations

import math

import numpy as np

from warp_verlet.core.simulator import Simulator

from ..common import HANGING_DAMPING, hanging_sheet
from .base import G, Check, count_check, free_cloth, free_fall_error, hanging, nonfinite, run_with_energy, scene, ulp


def tether_excess(sim: Simulator) -> np.ndarray:
    """Per tether (particle, pin), distance to the pin minus the tether length (m), float64; -inf where a
    particle has fewer tethers than the table's width."""
    table = sim.model.tether_table
    p = sim.positions().astype(np.float64)
    has = table.tethered
    distance = np.linalg.norm(p[table.particle][:, None, :] - p[np.where(has, table.pin, 0)], axis=2)
    return np.where(has, distance - table.length.astype(np.float64), -np.inf)


def tether_reach(device: str = "cpu", size: str = "test") -> list[Check]:
    """The benchmark's 64 x 64, 1 m hanging cloth (vertical, pinned at its two top corners, rigid sticks, damping
    0.24 /s) with tethers. (1) At a stiff budget (4 substeps x 100 sweeps) no particle ends any substep farther
    from a pin than its tether length, to 1e-6 m (8 float32 spacings of the 1 m cloth's coordinates): a tether
    pass leaves a particle on or inside its sphere up to rounding, and the sticks projected after it in the
    same sweep are converged enough to move it less than that. (At 4 x 8 the last sweep's stick corrections
    carry particles up to 3.4e-5 m past their tethers, the residual stretch: tests/test_tethers.py bounds that
    case.) (2) At the default budget, 4 x 8, the cloth ends under 0.1% RMS structural stretch: the tethers give
    every particle its pin's answer at once, where Gauss-Seidel alone carries a correction about one stick per
    colour pass (the same cloth without tethers is reported beside it)."""
    n = 64
    stiff_steps, frames = (120, 60) if size == "test" else (240, 120)
    case = f"tethers: {n}x{n} hanging cloth within reach of its pins"

    def cloth(tethers: bool, iterations: int) -> Simulator:
        return Simulator(scene({"iterations": iterations, "damping": HANGING_DAMPING},
                               hanging_sheet(n, tethers=tethers)), device)

    stiff = cloth(True, 100)
    table = stiff.model.tether_table
    worst, worst_relative, bad = -np.inf, -np.inf, 0
    for _ in range(stiff_steps):
        stiff.step()
        bad += nonfinite(stiff.positions())
        excess = tether_excess(stiff)
        worst = max(worst, float(excess.max()))
        worst_relative = max(worst_relative, float((excess[table.tethered] / table.length[table.tethered]).max()))
    taut = float(np.mean((tether_excess(stiff) > -1e-6).any(axis=1)[table.tethered.any(axis=1)]))

    tethered, plain = cloth(True, 8), cloth(False, 8)
    for _ in range(frames):
        tethered.step_frame()
        plain.step_frame()
    stretch, without = tethered.stretch(), plain.stretch()
    bad += nonfinite(tethered.positions())
    return [
        count_check(case, "particles with a NaN/inf coordinate (every substep at 4 x 100, the end at 4 x 8)", bad),
        Check(case, "4 x 100 sweeps: max over substeps and tethers of (distance to pin - tether length) (m)", worst,
              1e-6, "float32: 8 spacings of the 1 m cloth; the tether pass is exact",
              f"{stiff_steps} substeps; relative to the tether length at most {worst_relative:.2g}; "
              f"{taut:.0%} of the particles end on a tether"),
        Check(case, f"4 x 8 sweeps: RMS structural stretch after {frames / 60:g} s", stretch.rms, 1e-3,
              "stated: 0.1% (tethers carry the pins' answer to every particle)",
              f"max {stretch.max:.3g}; without tethers RMS {without.rms:.3g}, max {without.max:.3g}"),
    ]


def tether_energy(device: str = "cpu", size: str = "test") -> list[Check]:
    """An undamped (damping 0) cloth pinned at two corners, with tethers, released from rest horizontal (it swings
    down through 0.5 m), 2 s at 4 x 8: total energy (kinetic from the implicit velocity, plus potential) never
    exceeds its start by more than 1% of the potential energy released, as for the plain cloth (long_run). A
    tether is a projection that only ever moves a particle back towards its pin, onto the sphere it must stay
    in: like a stick's it can remove energy, never add it; 1% is the O(dt) bias of (x - x_prev) / dt."""
    n = 16 if size == "test" else 32
    case = f"tethers: no energy gain, damping 0 ({n}x{n})"
    sim = Simulator(hanging(n, {"iterations": 8}, tethers=True), device)
    log = run_with_energy(sim, 480)
    taut = float(np.mean((tether_excess(sim) > -1e-6).any(axis=1)))
    plain = run_with_energy(Simulator(hanging(n, {"iterations": 8}), device), 480)
    checks = log.checks(case, tolerance=0.01)
    return [c if not c.note else Check(c.case, c.criterion, c.measured, c.bound, c.basis,
                                       f"{c.note}; {taut:.0%} of the particles end on a tether; without tethers "
                                       f"drift {plain.drift(plain.released):+.3e}")
            for c in checks]


def small_steps(device: str = "cpu", size: str = "test") -> list[Check]:
    """Small steps: many substeps, few sweeps. (1) Free fall at 512 substeps per frame (dt = 3.3e-5 s, below the
    float32 limit of a relaxed cloth, so without relaxation: iterations 0): the summed-form update is exact for
    constant acceleration, so every particle stays on x0 + a t^2 / 2 up to float32 rounding, at most about one
    spacing of its coordinates per step (checked at the end of every frame). (2) A pendulum: a rope of 2
    particles, 1 m, one pinned, released from rest 0.05 rad from the vertical, at 64 substeps per frame with 1
    sweep (the small-steps recipe) and with 8: its period, from the zero crossings of the bob's horizontal
    offset, within 1% of the analytic 2 pi sqrt(L / g) (1 + theta0^2 / 16 + 11 theta0^4 / 3072) (that series is
    the exact period to 1e-8 here). dt = 2.6e-4 s is just above this pendulum's float32 limit (2.2e-4 s):
    g dt^2 is 6 float32 spacings of its coordinates, and rounding, not the integrator, sets the error
    (measured 0.005% at 1 sweep, 0.3% at 8)."""
    checks = []
    case = "small steps: free fall at 512 substeps per frame"
    frames = 30 if size == "test" else 120
    sim = Simulator(free_cloth(substeps=512, iterations=0), device)
    x0 = sim.positions().astype(np.float64)
    worst, bad = 0.0, 0
    for frame in range(1, frames + 1):
        sim.step_frame()
        points = sim.positions()
        bad += nonfinite(points)
        worst = max(worst, free_fall_error(sim, x0, sim.time) / (frame * 512 * ulp(points)))
    checks += [count_check(case, "particles with a NaN/inf coordinate", bad),
               Check(case, "max |x - x0 - a t^2/2| / (n ulp), n substeps so far", worst, 1.0,
                     "float32 rounding of an exact update: one spacing per step",
                     f"{frames * 512} substeps of {sim.settings.dt:.3g} s, t = {sim.time:.3g} s")]

    length, theta0 = 1.0, 0.05
    exact = 2 * math.pi * math.sqrt(length / G) * (1 + theta0 ** 2 / 16 + 11 * theta0 ** 4 / 3072)
    for iterations in (1, 8):
        case = f"small steps: pendulum period at 64 substeps x {iterations} sweep{'s' if iterations > 1 else ''}"
        sim = Simulator(scene({"substeps": 64, "iterations": iterations},
                              {"name": "pendulum", "resolution": [1, 2], "size": [0.0, length],
                               "pins": ["top-left"]}), device)
        x = sim.positions()
        x[1] = x[0] + np.float32([length * math.sin(theta0), -length * math.cos(theta0), 0.0])
        sim.state.set_positions(x)
        times, offsets = [0.0], [float(x[1, 0] - x[0, 0])]
        for _ in range(round(3.3 * exact * 60)):  # a little over three periods
            sim.step_frame()
            p = sim.positions()
            times.append(sim.time)
            offsets.append(float(p[1, 0] - p[0, 0]))
        t, u = np.array(times), np.array(offsets)
        i = np.flatnonzero(np.sign(u[:-1]) * np.sign(u[1:]) < 0)
        crossings = t[i] - u[i] * (t[i + 1] - t[i]) / (u[i + 1] - u[i])  # linear between frames
        period = 2 * (crossings[-1] - crossings[0]) / (len(crossings) - 1) if len(crossings) > 1 else math.nan
        checks += [Check(case, "|period / analytic period - 1|", abs(period / exact - 1), 0.01,
                         "stated: 1%; analytic small-angle period (docstring)",
                         f"period {period:.5f} s, analytic {exact:.5f} s, {len(crossings)} zero crossings; dt = "
                         f"{sim.settings.dt:.3g} s, smallest resolved {sim.min_dt:.2g} s; amplitude at the end "
                         f"{np.abs(u[-60:]).max() / (length * math.sin(theta0)):.3f} of the start")]
    return checks
