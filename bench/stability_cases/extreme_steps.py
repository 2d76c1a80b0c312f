"""Extreme steps: fixed dt from 1e-5 to 0.1 s, variable dt, abrupt dt drops, frame-time spikes and stalls."""

from __future__ import annotations

import numpy as np

from warp_verlet.errors import WarpVerletError
from warp_verlet.core.simulator import Simulator

from .base import (G, Check, EnergyLog, count_check, free_cloth, free_fall_error, hanging, run_with_energy, ulp)


STEP_RANGE = (1e-5, 1e-4, 1e-3, 1e-2, 1e-1)


def fixed_steps(device: str = "cpu", size: str = "test", dts: tuple = STEP_RANGE) -> list[Check]:
    """sim.step(dt) with fixed dt from 1e-5 s to 0.1 s. (1) A free (unpinned) cloth: its centre of mass falls
    exactly a t^2 / 2 (internal corrections are equal and opposite, the update is exact for constant
    acceleration), checked at the end of the run, once it has fallen 8e3 ulps or more. (2) A hanging cloth,
    undamped: finite and no energy gain (normalised by M|a|H: at 1e-5 s it falls only ~1e-4 m)."""
    checks = []
    for dt in dts:
        case = f"steps: fixed dt = {dt:g} s"
        steps = 1000 if size == "test" else 3000
        sim = Simulator(free_cloth(), device)
        if dt < sim.min_dt:
            # |a| dt^2 is under 4 float32 spacings of the coordinates: with relaxation on, a cloth would not
            # fall (1e-5 s) or fall 1.8% short (1e-4 s). The simulator must refuse, naming the limit.
            checks.append(refused(case, f"dt below the float32 limit ({sim.min_dt:.2g} s here) is refused",
                                  lambda: sim.step(dt), "smallest dt resolved"))
            continue
        x0 = sim.positions().astype(np.float64)
        for _ in range(steps):
            sim.step(dt)
        t = steps * dt
        a = np.asarray(sim.settings.gravity, np.float64)
        fall = sim.positions().astype(np.float64).mean(axis=0) - x0.mean(axis=0)
        error = float(np.linalg.norm(fall - 0.5 * a * t * t) / (0.5 * np.linalg.norm(a) * t * t))
        checks.append(Check(case, "free cloth: |centre-of-mass fall - a t^2/2| / (|a| t^2/2)", error, 1e-3,
                            "analytic; 1e-3 for float32 rounding", f"{steps} steps; fell {-fall[1]:.3g} m of "
                            f"{0.5 * G * t * t:.3g} m"))
        log = run_with_energy(Simulator(hanging(12, {"iterations": 8}), device), 300 if size == "test" else 3000, dt=dt)
        checks += log.checks(case, tolerance=1e-3, fixed_scale=True,
                             basis="physics (damping 0); 1e-3 M|a|H for the O(dt) velocity estimate")[:2]
    return checks


def refused(case: str, criterion: str, attempt, expected_text: str) -> Check:
    """1 if ``attempt()`` raises WarpVerletError whose message contains ``expected_text``, else 0 (bound 1:
    measured is 1 - refused, so a refusal measures 0)."""
    try:
        attempt()
    except WarpVerletError as exc:
        ok = expected_text in str(exc)
        return Check(case, criterion + " (0 = refused with a clear error)", 0.0 if ok else 1.0, 0.0,
                     "the simulator must say so, not return a wrong answer", str(exc)[:90])
    return Check(case, criterion + " (0 = refused with a clear error)", 1.0, 0.0,
                 "the simulator must say so, not return a wrong answer", "not refused")


def step_walk(rng, count: int, smallest: float, largest: float = 0.1, r_max: float = 2.0,
              up: float = 1e3) -> list[float]:
    """Steps that jump up by up to ``up`` at once (the ratio clamp's job) but shrink by at most r_max per
    step (shrinking faster is refused), within [smallest, largest]."""
    dts, dt = [], 1e-3
    for _ in range(count):
        if rng.random() < 0.4:
            dt = min(dt * up ** rng.uniform(0.1, 1.0), largest)
        else:
            dt = max(dt / r_max, smallest)
        dts.append(float(dt))
    return dts


def clamp_invariant_violation(before: tuple, after_delta: np.ndarray, free: np.ndarray, dt: float, dt_prev: float,
                              a: np.ndarray, r_max: float, kept: float) -> float:
    """What clamping guarantees, for every free particle and step: the carried velocity term of the step,
    step - a h (h + h') / 2, is the previous move scaled by kept * min(h / h', r_max) (kept = exp(-damping h),
    the velocity damping keeps), so it is never more than kept * r_max x the previous move. Returns the largest
    excess over that (<= rounding when held)."""
    x, xi, d = before
    move = (d + (x - xi))[free]
    carried = after_delta[free] - a * (dt * (dt + dt_prev) * 0.5)
    limit = kept * r_max * np.linalg.norm(move, axis=1)
    rounding = 4 * (ulp(after_delta[free]) + ulp(move))
    return float(np.max(np.linalg.norm(carried, axis=1) - limit - rounding))


def variable_steps(device: str = "cpu", size: str = "test") -> list[Check]:
    """Variable dt across 1e-5 .. 0.1 s. (1) Ratios within max_dt_ratio = 2 (a ramp up by 2x and back down):
    the time-step-corrected update is exact for constant acceleration, so a cloth with no relaxation (its
    sticks are never projected) stays on the parabola to float32 rounding. With relaxation on, rounding-
    level projections at 1e-5 s are velocities of ulp / dt ~ 6e-3 m/s, which later, longer steps carry:
    that is float32, not the integrator, so (1) leaves relaxation out. (2) Jumps of up to 1e4 in dt, with
    relaxation: the clamp caps the carried velocity term at r_max x the last move (checked on every free
    particle at every step), and free fall is then never faster than exact (a clamped step carries less
    velocity than the exact one; it cannot add any)."""
    case = "steps: variable dt"
    checks = []
    ramp = list(1e-5 * 2.0 ** np.arange(14))  # 1e-5 .. 0.082 s by factors of 2
    ramp = (ramp + ramp[::-1]) * (1 if size == "test" else 4)
    sim = Simulator(free_cloth(max_dt_ratio=2.0, iterations=0), device)
    x0 = sim.positions().astype(np.float64)
    t, worst = 0.0, 0.0
    for n, dt in enumerate(ramp, 1):
        sim.step(dt)
        t += dt
        worst = max(worst, free_fall_error(sim, x0, t) / (n * ulp(sim.positions())))
    checks.append(Check(case, "ratios <= 2, no relaxation: max |x - x0 - a t^2/2| / (n ulp)", worst, 4.0,
                        "float32 rounding of an exact update; measured 0.21", f"{len(ramp)} steps, t = {t:.3f} s"))

    sim = Simulator(free_cloth(max_dt_ratio=2.0), device)
    jumps = step_walk(np.random.default_rng(7), 60 if size == "test" else 600, 1.5 * sim.min_dt)
    x0 = sim.positions().astype(np.float64)
    a = np.asarray(sim.settings.gravity, np.float64)
    free = sim.model.inv_mass.numpy() > 0
    t, faster, excess, dt_prev = 0.0, -np.inf, -np.inf, None  # faster: in ulps per step, like the ramp
    for n, dt in enumerate(jumps, 1):
        state = sim.state
        before = tuple(arr.numpy().astype(np.float64)
                       for arr in (state.particle_q, state.particle_q_inertial, state.particle_dq))
        sim.step(dt)
        t += dt
        if dt_prev is not None:
            after = state.particle_dq.numpy().astype(np.float64)
            excess = max(excess, clamp_invariant_violation(before, after, free, dt, dt_prev, a, 2.0, 1.0))
        dt_prev = dt
        fall = -(sim.positions().astype(np.float64) - x0)[:, 1]
        faster = max(faster, float(fall.max() - 0.5 * G * t * t) / (n * ulp(sim.positions())))
    return checks + [
        Check(case, "jumps up to x1e3: carried velocity term beyond r_max x last move (m)", excess, 0.0,
              "invariant of the clamp (after a 4-ulp rounding allowance)"),
        Check(case, "jumps up to x1e3: free fall beyond exact, max (fall - g t^2/2) / (n ulp)", faster, 16.0,
              "analytic: a clamped step carries less velocity; float32 rounding", f"t = {t:.2f} s"),
    ]


def dt_drop_energy(device: str = "cpu", size: str = "test") -> list[Check]:
    """A hanging cloth (undamped) whose step shrinks. The relaxation leaves a residual stretch after each step;
    a step much shorter than the last removes it within that step, and Verlet turns the move into velocity
    residual / dt (a drop from 1/240 s to 1e-5 s gave 10x the kinetic energy gravity had released), so the
    simulator refuses a step that shrinks by more than max_dt_ratio at once. (1) That drop is refused with a
    clear error. (2) Steps from a walk that jumps up by up to 1e3 and shrinks by at most 2 per step, down to
    the float32 limit: kinetic energy never above the potential energy released, total energy never above
    its start (physics, damping 0)."""
    sim = Simulator(hanging(12, {"iterations": 8}), device)
    run_with_energy(sim, 240)
    checks = [refused("steps: dt drop 1/240 s -> 5e-4 s", "a step shrinking 8x at once is refused",
                      lambda: sim.step(5e-4), "max_dt_ratio")]
    case = "steps: walk, growing and shrinking <= 2x per step"
    sim = Simulator(hanging(12, {"iterations": 8}), device)
    log = EnergyLog(sim)
    for dt in step_walk(np.random.default_rng(7), 120 if size == "test" else 1200, 1.5 * sim.min_dt, up=2.0):
        sim.step(dt)
        log.sample(dt)
    return checks + log.checks(case, tolerance=0.02, fixed_scale=True,
                               basis="physics (damping 0); 2e-2 M|a|H for the O(dt) velocity estimate at 0.1 s")


def _advance_run(frame_times: list[float], device: str, max_frame_time: float = 0.1):
    sc = hanging(8, {"iterations": 4, "max_frame_time": max_frame_time})
    sim = Simulator(sc, device)
    counts, alphas = [], []
    for ft in frame_times:
        before = sim.steps
        alphas.append(sim.advance(ft))
        counts.append(sim.steps - before)
    reference = Simulator(sc, device)
    for _ in range(sim.steps):
        reference.step()
    return sim, counts, alphas, reference


def _advance_checks(case: str, sim, counts, alphas, reference, frame_times, max_frame_time) -> list[Check]:
    dt = sim.settings.dt
    cap = int(max_frame_time / dt + 1e-9)
    banked = 0.0
    lost = 0.0
    for ft in frame_times:  # time is dropped only when the bank would exceed max_frame_time
        lost += max(banked + ft - max_frame_time, 0.0)
        banked = min(banked + ft, max_frame_time)
        banked -= int(banked / dt + 1e-9) * dt
    accounted = abs(sim.time + alphas[-1] * dt - (sum(frame_times) - lost))
    return [
        Check(case, "substeps run by one advance()", float(max(counts)), float(cap),
              f"accumulator clamp: at most max_frame_time / dt = {cap}"),
        count_check(case, "advance() calls whose alpha is outside [0, 1)", sum(not 0.0 <= a < 1.0 for a in alphas)),
        Check(case, "|simulated + banked - (requested - clamped excess)| (s)", accounted, 1e-9,
              "invariant: only the excess over max_frame_time is dropped"),
        # Every substep of advance() has the fixed dt: the spike changes how many steps run, never their
        # length, so the dt ratio stays 1 and the state is bit-identical to as many plain fixed steps.
        Check(case, "max |x - x(same number of fixed steps)| (m)",
              float(np.abs(sim.positions() - reference.positions()).max()), 0.0,
              "invariant: bit-identical (the dt-ratio clamp is never needed)"),
    ]


def frame_spike(device: str = "cpu", size: str = "test") -> list[Check]:
    """A frame 10x longer than the others through advance(): 1/60 s frames, one of 10/60 s, then 1/60 s again.
    With max_frame_time = 0.1 s the spike runs 24 substeps, not 40; the frame after it runs the usual 4."""
    case = "steps: 10x frame spike through advance()"
    frames = [1 / 60] * 10 + [10 / 60] + [1 / 60] * 10
    sim, counts, alphas, reference = _advance_run(frames, device)
    checks = _advance_checks(case, sim, counts, alphas, reference, frames, 0.1)
    return checks + [count_check(case, "frames of 1/60 s that did not run exactly 4 substeps",
                                 sum(c != 4 for c, ft in zip(counts, frames) if ft == 1 / 60),
                                 f"spike ran {counts[10]} substeps")]


def long_stall(device: str = "cpu", size: str = "test") -> list[Check]:
    """Three 5 s stalls in a row, then normal frames: each stall runs at most max_frame_time / dt substeps
    (no spiral of death) and leaves no debt: the next 1/60 s frame runs 4."""
    checks = []
    for mft in ((0.1,) if size == "test" else (0.1, 0.25)):
        case = f"steps: 5 s stalls, max_frame_time {mft} s"
        frames = [1 / 60] * 3 + [5.0] * 3 + [1 / 60] * 3
        sim, counts, alphas, reference = _advance_run(frames, device, mft)
        checks += _advance_checks(case, sim, counts, alphas, reference, frames, mft)
        checks.append(count_check(case, "frames of 1/60 s after a stall that did not run exactly 4 substeps",
                                  sum(c != 4 for c in counts[6:]), f"stalls ran {counts[3:6]} substeps"))
    return checks
