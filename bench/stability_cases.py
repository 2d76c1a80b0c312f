"""The stability cases, shared by ``tests/test_stability.py`` (small sizes) and ``bench/stability.py`` (large).

Each case builds its scene, runs it and returns :class:`Check` rows: a stated pass criterion, the measured
value, the bound and where the bound comes from. A check passes when ``measured <= bound`` (a NaN never
passes). Sizes differ between ``size="test"`` and ``size="bench"``; the criteria and bounds do not, unless
a case says so.

Energy, wherever it is used: kinetic from the implicit velocity v = (x - x_prev) / dt of the last step with
per-particle masses (``mass / particles``, then ``particle_masses`` overrides; pins are fixed and carry
none), read from the summed-form state as x - x_prev = delta + (x - x_inertial) in float64; potential
-sum m a.x with a = gravity + wind (both are uniform accelerations). E0 is the initial pose at rest.
Relaxation is a projection and removes energy (README: "projection damping"), so with drag = 1 energy
may fall but must not rise; elastic energy of stretched sticks is not counted (PBD has none).

Float32 rounding: an ulp is ``np.spacing(float32(|x|))`` of the largest coordinate involved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.errors import DivergenceError, SceneError
from warp_verlet.scene import Scene, parse_scene
from warp_verlet.simulator import Simulator

G = 9.81
SIZES = ("test", "bench")


# ---------------------------------------------------------------------------------------------- reporting


@dataclass(frozen=True)
class Check:
    case: str
    criterion: str
    measured: float
    bound: float
    basis: str  # where the bound comes from: physics, float32 rounding, or a measured value with a margin
    note: str = ""

    @property
    def passed(self) -> bool:
        return bool(math.isfinite(self.measured) and self.measured <= self.bound)

    @property
    def margin(self) -> float:
        """bound / measured; infinite where the measured value is 0 or below (e.g. energy that only fell)."""
        return self.bound / self.measured if self.measured > 0 else math.inf

    def __str__(self) -> str:
        verdict = "pass" if self.passed else "FAIL"
        return (f"[{verdict}] {self.case}: {self.criterion}: measured {self.measured:.4g}, bound {self.bound:.4g} "
                f"({self.basis}){'; ' + self.note if self.note else ''}")


def count_check(case: str, criterion: str, violations: int, note: str = "") -> Check:
    """A check that something never happens: the measured value is the number of times it did."""
    return Check(case, criterion, float(violations), 0.0, "invariant: must never happen", note)


# ---------------------------------------------------------------------------------------------- scenes and state


HANGING_STICKS = {"structural": 1.0, "shear": 1.0, "bend": 0.5}


def scene(simulation: dict, cloths: dict | list, colliders: list | None = None, name: str = "<stability>") -> Scene:
    return parse_scene({"simulation": {"fps": 60, "substeps": 4, **simulation},
                        "cloth": cloths if isinstance(cloths, list) else [cloths],
                        "collider": colliders or []}, file=name)


def hanging(n: int, simulation: dict, sticks: dict | None = None, **cloth) -> Scene:
    """An n x n, 1 m cloth, horizontal (it swings down through 0.5 m), pinned at its two top corners."""
    spec = {"name": "sheet", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 1.0, 0.0],
            "orientation": "horizontal", "mass": 0.2, "pins": ["top-left", "top-right"],
            "sticks": sticks or HANGING_STICKS}
    spec.update(cloth)
    return scene(simulation, spec)


def particle_masses(sc: Scene) -> np.ndarray:
    out = []
    for spec in sc.cloths:
        rows, cols = spec.resolution
        m = np.full(rows * cols, spec.mass / (rows * cols))
        for r, c, kg in spec.particle_masses:
            m[r * cols + c] = kg
        out.append(m)
    return np.concatenate(out)


def implicit_velocity(sim: Simulator, dt: float) -> np.ndarray:
    """(x - x_prev) / dt in float64, from the summed-form state: x - x_prev = delta + (x - x_inertial)."""
    x, xi, d = (a.numpy().astype(np.float64) for a in (sim.x, sim.x_inertial, sim.delta))
    return (d + (x - xi)) / dt


def nonfinite(points: np.ndarray) -> int:
    return int((~np.isfinite(points)).any(axis=-1).sum())


def ulp(x) -> float:
    return float(np.spacing(np.float32(np.max(np.abs(x)))))


class EnergyLog:
    """Kinetic, potential and total energy after each sampled step (see the module docstring)."""

    def __init__(self, sim: Simulator):
        self.sim = sim
        self.m = particle_masses(sim.scene)
        self.free = sim.model.inv_mass.numpy() > 0
        self.a = np.asarray(sim.settings.gravity, np.float64) + np.asarray(sim.settings.wind, np.float64)
        x0 = sim.model.rest_positions.astype(np.float64)
        self.e0 = self.potential(x0)
        self.pe, self.ke = [self.e0], [0.0]
        self.nonfinite = 0

    def potential(self, x: np.ndarray) -> float:
        return float(-np.sum(self.m * (x @ self.a)))

    def sample(self, dt: float) -> None:
        x = self.sim.x.numpy().astype(np.float64)
        self.nonfinite += nonfinite(x)
        v = implicit_velocity(self.sim, dt)[self.free]
        self.ke.append(float(0.5 * np.sum(self.m[self.free] * np.sum(v * v, axis=1))))
        self.pe.append(self.potential(x))

    @property
    def total(self) -> np.ndarray:
        return np.add(self.ke, self.pe)

    @property
    def released(self) -> float:
        """Potential energy the run released at most: E0 - min PE."""
        return self.e0 - float(np.min(self.pe))

    def scale(self) -> float:
        """M |a| H: the potential energy of the free mass falling the cloth's largest size (the normaliser
        used where a run releases too little energy to normalise by, e.g. 400 steps of 1e-5 s)."""
        size = max(max(c.size) for c in self.sim.scene.cloths)
        return float(self.m[self.free].sum() * np.linalg.norm(self.a) * size)

    def rise(self, scale: float) -> float:
        """max over steps >= 1 of (E - E0) / scale; <= 0 when energy never rose above its start."""
        return float((self.total[1:].max() - self.e0) / scale)

    def drift(self, scale: float) -> float:
        return float((self.total[-1] - self.e0) / scale)

    def checks(self, case: str, tolerance: float = 0.02, fixed_scale: bool = False, basis: str = "") -> list[Check]:
        """Finite positions, total energy rising at most ``tolerance`` of the scale above E0, and kinetic
        energy at most (1 + tolerance) x the potential energy released."""
        scale = self.scale() if fixed_scale else self.released
        name = "M|a|H" if fixed_scale else "released PE (E0 - min PE)"
        basis = basis or (f"physics: drag 1 and a dissipative projection; {tolerance:g} for the O(dt) bias of "
                          "(x - x_prev)/dt")
        note = (f"drift at end {self.drift(scale):+.3e} of {name}; "
                f"released PE = {self.released / self.scale():.3f} M|a|H")
        return [
            count_check(case, "particles with a NaN/inf coordinate, summed over samples", self.nonfinite),
            Check(case, f"energy rise max(E - E0) / {name}", self.rise(scale), tolerance, basis, note),
            Check(case, "kinetic energy max KE / released PE", float(np.max(self.ke) / max(self.released, 1e-300)),
                  1.0 + tolerance, "physics: KE cannot exceed the potential energy released"),
        ]


def run_with_energy(sim: Simulator, steps: int, dt: float | None = None, every: int = 1) -> EnergyLog:
    log = EnergyLog(sim)
    dt = sim.settings.dt if dt is None else dt
    for n in range(1, steps + 1):
        sim.step(dt)
        if n % every == 0 or n == steps:
            log.sample(dt)
    return log


# ---------------------------------------------------------------------------------------------- stiff


def stiff_iterations(device: str = "cpu", size: str = "test") -> list[Check]:
    """Stiffness 1 and 200 sweeps: a hanging cloth settled (drag 0.95 per substep) must be nearly
    inextensible (the exact answer has stretch 0), and far less stretched than with 8 sweeps."""
    case = "stiff: k = 1, 200 iterations"
    n, frames = (16, 30) if size == "test" else (48, 60)
    sticks = {"structural": 1.0, "shear": 1.0}
    stretch, bad = {}, 0
    for iterations in (8, 200):
        sim = Simulator(hanging(n, {"iterations": iterations, "drag": 0.95}, sticks), device)
        for _ in range(frames):
            sim.step_frame()
        points = sim.positions()
        stretch[iterations] = sim.stretch(points).max
        bad += nonfinite(points)
    return [
        count_check(case, "particles with a NaN/inf coordinate at the end", bad),
        # Gauss-Seidel carries a correction about one particle per sweep, so the residual of a fixed sweep
        # count grows with the square of the grid: bound 2e-5 N^2, from measured 1.8e-3 at 16^2 (0.5 s) and
        # 2.2e-2 at 48^2 (1 s), a margin of 2.8 and 2.1.
        Check(case, f"max structural stretch |D - L| / L after settling ({n}x{n})", stretch[200], 2e-5 * n * n,
              "measured (1.8e-3 at 16^2, 2.2e-2 at 48^2) x2, scaled with N^2", f"{frames} frames"),
        # 25x the sweeps must cut the residual at least 5x (measured 12x at 16^2, 19x at 48^2).
        Check(case, "stretch(200 sweeps) / stretch(8 sweeps)", stretch[200] / stretch[8], 0.2,
              "convergence; measured 0.085 (16^2), 0.054 (48^2)", f"8 sweeps: {stretch[8]:.3g}"),
    ]


def bend_grid(device: str = "cpu", size: str = "test") -> list[Check]:
    """Structural, shear and bend sticks all at stiffness 1 on a large grid (256^2 in the bench, 48^2 in the
    test), undamped for 1 s: finite, and energy never grows (the 256^2 cloth is badly stretched at 8
    sweeps, README, but stretch is not this case's criterion)."""
    n = 48 if size == "test" else 256
    case = f"stiff: bend sticks on {n}x{n}"
    sim = Simulator(hanging(n, {"iterations": 8, "drag": 1.0}, {"structural": 1.0, "shear": 1.0, "bend": 1.0}), device)
    log = run_with_energy(sim, 240, every=1 if size == "test" else 4)
    checks = log.checks(case)
    return [replace(c, note=f"{c.note}; stretch max {sim.stretch().max:.3g}") if c.note else c for c in checks]


def checkerboard_masses(n: int, heavy: float, light: float) -> list[list]:
    return [[r, c, heavy if (r + c) % 2 == 0 else light] for r in range(n) for c in range(n)]


def mass_ratio(device: str = "cpu", size: str = "test") -> list[Check]:
    """Neighbouring particles 1e4 apart in mass (checkerboard particle_masses), structural + shear only (so
    every stick joins a heavy and a light particle, or two of a kind along a diagonal). Undamped: finite and
    energy bounded. Damped and settled: the stretch stays below a bound."""
    case = "stiff: mass ratio 1e4 (checkerboard)"
    n = 16 if size == "test" else 64
    masses = checkerboard_masses(n, 1e-2, 1e-6)
    sticks = {"structural": 1.0, "shear": 1.0}
    sim = Simulator(hanging(n, {"iterations": 8, "drag": 1.0}, sticks, particle_masses=masses), device)
    checks = run_with_energy(sim, 480).checks(case)
    settled = Simulator(hanging(n, {"iterations": 8, "drag": 0.95}, sticks, particle_masses=masses), device)
    for _ in range(60):
        settled.step_frame()
    stretch = settled.stretch().max
    uniform = Simulator(hanging(n, {"iterations": 8, "drag": 0.95}, sticks), device)
    for _ in range(60):
        uniform.step_frame()
    return checks + [
        # A light particle between two heavy ones is moved by nearly the whole correction of both sticks,
        # so the heavy lattice is held by corrections 1e-4 as large: it hangs very stretched. The bound
        # is from measurement, to catch it getting worse (measured 1.7 at 16^2, 2.7 at 64^2).
        Check(case, "max structural stretch after settling (1 s, drag 0.95)", stretch, 5.0,
              "measured 1.7 (16^2), 2.7 (64^2), x1.9", f"uniform mass: {uniform.stretch().max:.3g}"),
    ]


def heavy_chain(device: str = "cpu", size: str = "test") -> list[Check]:
    """A 20-particle, 1 m rope pinned at one end, its last particle 1e4 x heavier than the others, released
    horizontal and settled (drag 0.99). The analytic hanging length is L = 1 m (inextensible). Position-based
    relaxation stretches it: each sweep moves the heavy end by m_l / (m_h + m_l) of the last stick's error,
    so holding it against the g dt^2 it gains per substep takes an error e = g dt^2 (1 + m_h / m_l) / K per
    stick, about (N - 1) e over the chain: the PBD hanging length is L + (N - 1) e, -> L as K grows."""
    runs = [(1e4, 50)] if size == "test" else [(1e3, 8), (1e4, 50), (1e4, 200)]
    checks = []
    n, length, light = 20, 1.0, 1e-3
    for ratio, iterations in runs:
        case = f"stiff: heavy end ({ratio:.0e} x) on a light chain, {iterations} iterations"
        sc = scene({"iterations": iterations, "drag": 0.98},
                   {"name": "chain", "resolution": [1, n], "size": [0.0, length], "mass": light * n,
                    "pins": ["top-left"], "particle_masses": [[0, n - 1, light * ratio]]})
        sim = Simulator(sc, device)
        for _ in range(480):  # 8 s: the swing (period ~2.5 s) decays e-fold in ~50 substeps of drag
            sim.step_frame()
        p = sim.positions().astype(np.float64)
        dt = sim.settings.dt
        estimate = (n - 1) * G * dt * dt * (1.0 + ratio) / iterations
        extension = -p[-1, 1] - length
        chain = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
        checks += [
            count_check(case, "particles with a NaN/inf coordinate", nonfinite(p)),
            # Measured 0.946 - 0.995 of the estimate (it ignores the light particles' own weight and the
            # alternation between colours); 25% allowed.
            Check(case, "|heavy end depth - L| / PBD estimate, minus 1 (abs)", abs(extension / estimate - 1.0), 0.25,
                  "analytic estimate (docstring); measured within 6%",
                  f"end at y = {p[-1, 1]:.4f} m; L = {length} m, estimate L + {estimate:.4f} m"),
            Check(case, "chain length / (L + 2 x estimate)", chain / (length + 2 * estimate), 1.0,
                  "analytic estimate, x2", f"chain {chain:.4f} m"),
            # 8 s of drag 0.98 per substep leave e^-40 of the swing; measured 1e-8 - 3e-8.
            Check(case, "heavy end horizontal offset / L (settled straight down)", abs(p[-1, 0] - p[0, 0]) / length,
                  1e-5, "physics: a settled hanging chain is vertical; 1e-5 for float32"),
        ]
    return checks


# ---------------------------------------------------------------------------------------------- extreme steps


STEP_RANGE = (1e-5, 1e-4, 1e-3, 1e-2, 1e-1)


def free_fall_error(sim: Simulator, x0: np.ndarray, t: float) -> float:
    """max over particles of |x - (x0 + a t^2 / 2)|, float64."""
    a = np.asarray(sim.settings.gravity, np.float64) + np.asarray(sim.settings.wind, np.float64)
    return float(np.abs(sim.positions().astype(np.float64) - (x0 + 0.5 * a * t * t)).max())


def free_cloth(n: int = 6, **simulation) -> Scene:
    """An unpinned n x n, 0.5 m cloth at the origin: in free fall its sticks stay at rest length, so every
    particle follows x0 + a t^2 / 2 (the integrator is exact for constant acceleration, for any dt)."""
    return scene({"iterations": 8, **simulation},
                 {"name": "free", "resolution": [n, n], "size": [0.5, 0.5],
                  "sticks": {"structural": 1.0, "shear": 1.0}})


def fixed_steps(device: str = "cpu", size: str = "test", dts: tuple = STEP_RANGE) -> list[Check]:
    """sim.step(dt) with fixed dt from 1e-5 s to 0.1 s. (1) A free (unpinned) cloth: its centre of mass falls
    exactly a t^2 / 2 (internal corrections are equal and opposite, the update is exact for constant
    acceleration), checked at the end of the run, once it has fallen 8e3 ulps or more. (2) A hanging cloth,
    drag 1: finite and no energy gain (normalised by M|a|H: at 1e-5 s it falls only ~1e-4 m)."""
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
                             basis="physics (drag 1); 1e-3 M|a|H for the O(dt) velocity estimate")[:2]
    return checks


def refused(case: str, criterion: str, attempt, expected_text: str) -> Check:
    """1 if ``attempt()`` raises WarpVerletError whose message contains ``expected_text``, else 0 (bound 1:
    measured is 1 - refused, so a refusal measures 0)."""
    from warp_verlet.errors import WarpVerletError

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
                              a: np.ndarray, r_max: float, drag: float) -> float:
    """What clamping guarantees, for every free particle and step: the carried velocity term of the step,
    step - a h (h + h') / 2, is the previous move scaled by drag * min(h / h', r_max), so it is never more
    than drag * r_max x the previous move. Returns the largest excess over that (<= rounding when held)."""
    x, xi, d = before
    move = (d + (x - xi))[free]
    carried = after_delta[free] - a * (dt * (dt + dt_prev) * 0.5)
    limit = drag * r_max * np.linalg.norm(move, axis=1)
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
        before = tuple(arr.numpy().astype(np.float64) for arr in (sim.x, sim.x_inertial, sim.delta))
        sim.step(dt)
        t += dt
        if dt_prev is not None:
            excess = max(excess, clamp_invariant_violation(before, sim.delta.numpy().astype(np.float64), free,
                                                           dt, dt_prev, a, 2.0, 1.0))
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
    """A hanging cloth (drag 1) whose step shrinks. The relaxation leaves a residual stretch after each step;
    a step much shorter than the last removes it within that step, and Verlet turns the move into velocity
    residual / dt (a drop from 1/240 s to 1e-5 s gave 10x the kinetic energy gravity had released), so the
    simulator refuses a step that shrinks by more than max_dt_ratio at once. (1) That drop is refused with a
    clear error. (2) Steps from a walk that jumps up by up to 1e3 and shrinks by at most 2 per step, down to
    the float32 limit: kinetic energy never above the potential energy released, total energy never above
    its start (physics, drag 1)."""
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
                               basis="physics (drag 1); 2e-2 M|a|H for the O(dt) velocity estimate at 0.1 s")


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


# ---------------------------------------------------------------------------------------------- extreme loads


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
    spacing of 0.1 m, and stiffness 0.5 leaves half a stick's error after the sweeps: every stick must tear
    (threshold 1.5). Afterwards no stick acts, so each free particle is in free fall under gravity + wind:
    its second differences x[n+1] - 2 x[n] + x[n-1] equal (g + w) dt^2 to float32 rounding."""
    n = 8 if size == "test" else 64
    case = f"loads: gale tears every stick ({n}x{n})"
    pins = [[r, c] for r in range(n) for c in range(n) if (r + c) % 2 == 0]
    sc = scene({"iterations": 8, "wind": [2.0e4, 0.0, 1.0e4]},
               {"name": "net", "resolution": [n, n], "size": [0.1 * (n - 1)] * 2, "pins": pins,
                "sticks": {"structural": 0.5}, "tear_threshold": 1.5})
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
              "physics: w dt^2 > 2 x 0.5 x spacing", f"all {sim.model.stick_count} torn at substep {torn_at}"),
        count_check(case, "particles lost or added", abs(sim.positions().shape[0] - n * n)),
        Check(case, "free fall after tearing: max |second difference - a dt^2| / (4 ulp)", error, 1.0,
              "float32 rounding of three positions", f"a dt^2 = {np.linalg.norm(a):.3f} m"),
    ]


# ---------------------------------------------------------------------------------------------- degenerate geometry


def coincident(device: str = "cpu", size: str = "test") -> list[Check]:
    """D = 0. (1) In a hanging cloth, one particle put exactly on its neighbour and another exactly on the
    pinned corner (sim.x.assign before the first step): nothing becomes NaN, and the cloth recovers the
    shape of an undisturbed run. (2) A free cloth collapsed into one point: every stick has D = 0 and is
    skipped, so the point falls exactly as a single particle and never splits (no direction to push along)."""
    case = "degenerate: coincident particles"
    n = 12 if size == "test" else 32
    sc = scene({"iterations": 8, "drag": 0.97},
               {"name": "curtain", "resolution": [n, n], "size": [1.0, 1.0], "pins": ["top-left", "top-right"],
                "sticks": HANGING_STICKS})
    plain, moved = Simulator(sc, device), Simulator(sc, device)
    x = moved.positions()
    mid = (n // 2) * n + n // 2
    x[mid] = x[mid + 1]
    x[1] = x[0]  # onto the pinned corner
    moved.x.assign(x)
    bad = 0
    for _ in range(120):
        plain.step_frame()
        moved.step_frame()
        bad += nonfinite(moved.positions())
    difference = float(np.abs(moved.positions() - plain.positions()).max())

    point = Simulator(free_cloth(), device)
    p0 = np.zeros_like(point.positions()) + np.float32([0.25, -0.25, 0.0])
    point.x.assign(p0)
    spread, fall = 0.0, 0.0
    for step in range(1, 241):
        point.step()
        p = point.positions()
        bad += nonfinite(p)
        spread = max(spread, float(np.abs(p - p[0]).max()))
        fall = max(fall, free_fall_error(point, p0.astype(np.float64), step * point.settings.dt) / (step * ulp(p)))
    return [
        count_check(case, "particles with a NaN/inf coordinate, all substeps", bad),
        # The damped runs converge to the same drape: measured 2.4e-7 m (12^2) and 3.0e-7 m (32^2) after
        # 2 s; 1e-4 m (a thousandth of the cloth) allowed.
        Check(case, "max |x - x(undisturbed run)| after 2 s (m)", difference, 1e-4,
              "the disturbance is forgotten; measured 3e-7 m, x300"),
        Check(case, "collapsed cloth: max distance between its particles (m)", spread, 0.0,
              "invariant: sticks with D = 0 are skipped"),
        Check(case, "collapsed cloth: free fall max |x - x0 - a t^2/2| / (n ulp)", fall, 16.0, "float32 rounding"),
    ]


def zero_area(device: str = "cpu", size: str = "test") -> list[Check]:
    """A grid with zero size on an axis of several particles is refused with one SceneError naming the key;
    the legitimate zero-area cloth, a 1 x N rope, runs: undamped, it swings with no NaN, bounded stretch and
    no energy gain."""
    case = "degenerate: zero-area grid / 1 x N rope"
    expected = "<stability>: cloth[0].size[0]: expected a length > 0 m along an axis with 4 particles, got 0.0"
    try:
        scene({}, {"resolution": [4, 5], "size": [0.0, 1.0]})
        message = "no error"
    except SceneError as err:
        message = str(err)
    n = 20 if size == "test" else 40
    sim = Simulator(scene({"iterations": 8}, {"name": "rope", "resolution": [1, n], "size": [0.0, 1.0],
                                              "pins": ["top-left"]}), device)
    log = EnergyLog(sim)
    stretch = 0.0
    for _ in range(480):
        sim.step()
        log.sample(sim.settings.dt)
        stretch = max(stretch, sim.stretch().max)
    return [count_check(case, "size = [0, 1] on 4 rows: the message is the documented one", int(message != expected),
                        message)] + log.checks(case) + [
        # A 1 m rope swinging from horizontal at 8 sweeps: measured 0.053 (N = 20) and 0.21 (N = 40, the
        # shipped rope's count). It grows with N^2 at a fixed sweep count (4.3 at N = 200): not a bound for that.
        Check(case, f"rope ({n} particles): max structural stretch over 2 s", stretch, 0.5,
              "measured 0.053 (N=20), 0.21 (N=40), x2.4"),
    ]


def penetration(sim: Simulator, points: np.ndarray, free: np.ndarray) -> float:
    """How deep the deepest free particle is inside any collider (m); <= 0 when none is."""
    p = points[free].astype(np.float64)
    depth = -np.inf
    for plane in sim.scene.planes:
        depth = max(depth, float(np.max(plane.thickness - (p - plane.point) @ np.asarray(plane.normal))))
    for sphere, centre in zip(sim.scene.spheres, sim.colliders.centres()):
        depth = max(depth, float(np.max(sphere.radius + sphere.thickness - np.linalg.norm(p - centre, axis=1))))
    return depth


TOL = 1e-5  # clamping is exact up to float32 rounding of the projected position (tests/test_collide.py)


def small_sphere(device: str = "cpu", size: str = "test") -> list[Check]:
    """Spheres of radius 3 cm against a cloth of 10 cm spacing, pinned at its four corners so that it sags
    onto them (it sags about 6 cm) and stays in contact: one under a particle, one under the middle of a
    cell (it can poke through the cell), and one centred exactly on a particle (distance 0: pushed +Y). After every
    substep no free particle is inside any of them."""
    case = "degenerate: sphere smaller than a stick"
    n = 11 if size == "test" else 41
    spacing = 0.1
    cloth = {"name": "sheet", "resolution": [n, n], "size": [spacing * (n - 1)] * 2, "orientation": "horizontal",
             "origin": [0.0, 0.0, 0.0], "sticks": {"structural": 1.0, "shear": 1.0},
             "pins": ["top-left", "top-right", "bottom-left", "bottom-right"]}
    k = n // 2
    spheres = [{"type": "sphere", "name": "under_particle", "radius": 0.03,
                "centre": [k * spacing, -0.06, k * spacing]},
               {"type": "sphere", "name": "under_cell", "radius": 0.03,
                "centre": [(k - 1.5) * spacing, -0.05, (k - 1.5) * spacing]},
               {"type": "sphere", "name": "at_particle", "radius": 0.03,
                "centre": [(k + 2) * spacing, 0.0, (k + 2) * spacing]}]
    sim = Simulator(scene({"iterations": 8, "drag": 0.99}, cloth, spheres), device)
    free = sim.model.inv_mass.numpy() > 0
    deepest, bad, contact = -np.inf, 0, 0
    for _ in range(240):
        sim.step()
        p = sim.positions()
        bad += nonfinite(p)
        depth = penetration(sim, p, free)
        deepest = max(deepest, depth)
        contact += depth > -1e-4  # a particle within 0.1 mm of a surface: touching
    return [count_check(case, "particles with a NaN/inf coordinate", bad),
            Check(case, "deepest free particle inside a sphere, any substep (m)", deepest, TOL,
                  "float32 rounding of the projection", f"in contact on {contact} of 240 substeps")]


def start_inside(device: str = "cpu", size: str = "test") -> list[Check]:
    """A cloth entirely inside a 1 m sphere (one particle exactly at its centre) and one entirely 1 m below a
    plane: all free particles are out after the first substep, and stay out. The projection becomes velocity
    (Verlet), so the cloth leaves at depth / dt: reported, not bounded."""
    n = 9 if size == "test" else 33
    checks = []
    for label, cloth_origin, collider in (
            ("inside a sphere", [-0.5, 0.0, -0.5],
             {"type": "sphere", "name": "ball", "radius": 1.0, "centre": [0.0, 0.0, 0.0]}),
            ("1 m below a plane", [-0.5, -1.0, -0.5], {"type": "plane", "name": "ground", "point": [0.0, 0.0, 0.0]})):
        case = f"degenerate: cloth starting {label}"
        sim = Simulator(scene({"iterations": 8}, {"name": "sheet", "resolution": [n, n], "size": [1.0, 1.0],
                                                  "orientation": "horizontal", "origin": cloth_origin},
                              [collider]), device)
        free = sim.model.inv_mass.numpy() > 0
        sim.step()
        first = penetration(sim, sim.positions(), free)
        speed = float(np.linalg.norm(implicit_velocity(sim, sim.settings.dt), axis=1).max())
        later = -np.inf
        for _ in range(59):
            sim.step()
            later = max(later, penetration(sim, sim.positions(), free))
        checks += [Check(case, "deepest free particle inside after the first substep (m)", first, TOL,
                         "float32 rounding of the projection", f"ejection speed {speed:.0f} m/s"),
                   Check(case, "deepest free particle inside, substeps 2-60 (m)", later, TOL,
                         "float32 rounding of the projection")]
    return checks


# ---------------------------------------------------------------------------------------------- over-constrained


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
        sim.x.assign(x)
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
        sim.x.assign(x)
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


# ---------------------------------------------------------------------------------------------- long run


def long_run(device: str = "cpu", size: str = "test") -> list[Check]:
    """10 000 substeps (bench; 2 000 in the test) of an undamped (drag 1) cloth pinned at two corners,
    swinging down from horizontal: finite, energy never above its start by more than 1% of the potential
    energy released. The drift at the end is reported (negative: projection dissipates)."""
    n, steps = (16, 2000) if size == "test" else (32, 10000)
    case = f"long run: {steps} substeps, drag 1 ({n}x{n})"
    log = run_with_energy(Simulator(hanging(n, {"iterations": 8}), device), steps)
    return log.checks(case, tolerance=0.01)


# ---------------------------------------------------------------------------------------------- divergence


def divergence(device: str = "cpu", size: str = "test", out_dir: Path | None = None) -> list[Check]:
    """A cloth with no relaxation (iterations = 0) under 1000 m/s^2 with position_bound = 20 m: its free
    particles fall exactly (x0 + a t^2 / 2), so the frame where one first passes 20 m and the lowest such
    particle index are known in advance. run_scene must stop there with DivergenceError naming the frame,
    the cloth and the particle, and leave a valid cache holding frames 0 .. frame - 1."""
    import tempfile

    from pxr import Usd, UsdGeom

    from warp_verlet.runner import run_scene
    from warp_verlet.usd_writer import validate_cache

    case = "divergence: run_scene end to end"
    bound, g, fps = 20.0, 1000.0, 60
    sc = scene({"fps": fps, "frames": 60, "iterations": 0, "gravity": [0.0, -g, 0.0], "position_bound": bound},
               [{"name": "calm", "resolution": [2, 2], "size": [0.1, 0.1], "origin": [5.0, 0.0, 0.0],
                 "pins": ["top-edge", "bottom-edge"]},
                {"name": "net", "resolution": [4, 4], "size": [1.0, 1.0], "pins": ["top-edge"]}])
    y0 = np.concatenate([np.zeros(4), -np.repeat(np.arange(4) / 3.0, 4)])  # calm first, then net rows
    free = np.r_[np.zeros(4, bool), np.arange(16) >= 4]
    frame = next(f for f in range(1, 61) if np.any(free & (np.abs(y0 - 0.5 * g * (f / fps) ** 2) > bound)))
    y = y0 - 0.5 * g * (frame / fps) ** 2
    beyond = free & (np.abs(y) > bound)
    particle = int(np.flatnonzero(beyond)[0]) - 4
    assert np.min(np.abs(np.abs(y[free]) - bound)) > 0.1, "the prediction must not be borderline"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(out_dir or tmp) / "diverges.usdc"
        try:
            run_scene(sc, output=out, device=device)
            err = None
        except DivergenceError as exc:
            err = exc
        samples, problems = [], ["no cache"]
        if out.exists():
            stage = Usd.Stage.Open(str(out))
            samples = list(UsdGeom.Mesh.Get(stage, "/World/net").GetPointsAttr().GetTimeSamples())
            problems = validate_cache(out)
            del stage
    message = str(err) if err else "no DivergenceError"
    named = (err is not None and err.frame == frame and err.cloth == "net" and err.particle == particle
             and f"frame {frame}: cloth 'net' particle {particle}" in message and "beyond position_bound" in message)
    return [
        count_check(case, "DivergenceError names the predicted frame, cloth and particle", int(not named),
                    f"predicted frame {frame}, particle {particle}; got: {message}"),
        count_check(case, "cache time samples other than frames 0 .. frame - 1",
                    len(set(samples) ^ set(range(frame))), f"{len(samples)} samples"),
        count_check(case, "validate_cache problems", len(problems), "; ".join(problems)[:200]),
    ]


# ---------------------------------------------------------------------------------------------- registry


CASES = {
    "stiff_iterations": stiff_iterations,
    "bend_grid": bend_grid,
    "mass_ratio": mass_ratio,
    "heavy_chain": heavy_chain,
    "fixed_steps": fixed_steps,
    "variable_steps": variable_steps,
    "dt_drop_energy": dt_drop_energy,
    "frame_spike": frame_spike,
    "long_stall": long_stall,
    "heavy_gravity": heavy_gravity,
    "tearing_gale": tearing_gale,
    "coincident": coincident,
    "zero_area": zero_area,
    "small_sphere": small_sphere,
    "start_inside": start_inside,
    "pins_apart": pins_apart,
    "two_places": two_places,
    "long_run": long_run,
    "divergence": divergence,
}


def quiet() -> None:
    wp.config.quiet = True
