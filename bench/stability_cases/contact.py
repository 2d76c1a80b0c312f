"""Contact: a drape held up by a ball (with and without the global correction), a sheet that crumples onto
itself on the ground, and a sheet thrown at 30 m/s onto a ball and the ground.

Each case reads every substep: no coordinate may become NaN, no particle may end a substep inside a collider by
more than PENETRATION (the clamps run last in a substep and put a particle on the offset surface exactly, to
float32 rounding), and the energy may not rise (the clamps and the projections only remove energy). The
drape's end stretch is bounded by its measured value with a margin: it is what the stated budget buys, and a
regression that leaves the cloth rubbery fails it.
"""

from __future__ import annotations

import numpy as np

from warp_verlet.colliders.sphere import SphereCollider
from warp_verlet.core.simulator import Simulator

from .base import G, Check, count_check, implicit_velocity, nonfinite, particle_masses, scene

PENETRATION = 1e-5
"""m: the deepest a particle may end a substep inside a collider's offset surface."""

RADIUS, GROUND = 0.25, -0.5  # m: the ball (centred at the origin) and the ground's height
BALL = {"type": "sphere", "name": "ball", "radius": RADIUS, "centre": [0.0, 0.0, 0.0], "thickness": 0.005}
FLOOR = {"type": "plane", "name": "ground", "point": [0.0, GROUND, 0.0], "thickness": 0.005}


def penetration(sim: Simulator, x: np.ndarray) -> dict[str, float]:
    """The deepest any particle lies inside each collider's offset surface (m; 0 when none does), float64; the
    spheres stand still and the planes are infinite."""
    x = x.astype(np.float64)
    out = {}
    for c in sim.scene.colliders:
        if isinstance(c, SphereCollider):
            assert not c.moving, "penetration() reads a sphere's first keyframe"
            depth = c.radius + c.thickness - np.linalg.norm(x - np.asarray(c.keyframes[0][1], np.float64), axis=1)
        else:
            normal = np.asarray(c.normal, np.float64) / np.linalg.norm(c.normal)
            depth = c.thickness - (x - np.asarray(c.point, np.float64)) @ normal
        out[c.name] = max(0.0, float(depth.max()))
    return out


class ContactLog:
    """Per substep: non-finite coordinates, the deepest penetration of each collider, and the total energy
    (kinetic from (x - x_prev) / dt, potential m g y) against the start's, per particle mass."""

    def __init__(self, sim: Simulator):
        self.sim = sim
        self.m = particle_masses(sim.scene)
        self.nonfinite = 0
        self.deepest = {c.name: 0.0 for c in sim.scene.colliders}
        # Before the first step, implicit_velocity is the velocity set_velocity gave (zero without one).
        self.energy = [self.total(sim.positions(), implicit_velocity(sim, sim.dt))]

    def total(self, x: np.ndarray, v: np.ndarray) -> float:
        kinetic = 0.5 * np.sum(self.m * np.sum(v * v, axis=1))
        return float(kinetic + G * np.sum(self.m * x[:, 1].astype(np.float64)))

    def step(self) -> np.ndarray:
        """One substep, logged; the positions it ended with (float32, the scene's order)."""
        sim = self.sim
        sim.step()
        x = sim.positions()
        self.nonfinite += nonfinite(x)
        for name, depth in penetration(sim, x).items():
            self.deepest[name] = max(self.deepest[name], depth)
        v = (x.astype(np.float64) - sim.state.previous_positions().astype(np.float64)) / sim.dt
        self.energy.append(self.total(x, v))
        return x

    def checks(self, case: str, tolerance: float = 0.02) -> list[Check]:
        """No NaN; each collider's deepest penetration within PENETRATION; the total energy never above the
        start's by more than ``tolerance`` of M g H (H the cloth's size, 1 m here): the O(dt) bias of the
        Verlet velocity estimate."""
        scale = float(self.m.sum() * G * 1.0)
        rise = (max(self.energy[1:]) - self.energy[0]) / scale
        return [
            count_check(case, "particles with a NaN/inf coordinate, summed over substeps", self.nonfinite),
            *[Check(case, f"deepest penetration of '{name}' at the end of any substep (m)", depth, PENETRATION,
                    "the clamps run last and are exact to float32 rounding; 1e-5 m allowed")
              for name, depth in self.deepest.items()],
            Check(case, "energy rise max(E - E0) / (M g 1 m)", rise, tolerance,
                  "physics: contact, damping and projection only remove energy; 0.02 for the Verlet velocity's "
                  "O(dt) bias"),
        ]


LINE_PASS = {"compliance": {"shear": 1.0, "bend": 1.0}, "line_passes": 1}
"""A cloth with a line pass a substep, its shear and bend soft (m/N), as scenes/drape.toml has it."""


def drape_scene(n: int, substeps: int, iterations: int, cloth: dict | None = None, **simulation):
    """The drape of bench.convergence: 1 m, 0.2 kg, no pins, dropped flat from 0.5 m onto the ball; ``cloth``
    adds keys to the cloth."""
    return scene({"substeps": substeps, "iterations": iterations, "damping": 0.24, **simulation},
                 {"name": "sheet", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 0.5, -0.5],
                  "orientation": "horizontal", "mass": 0.2, "sticks": ["structural", "shear", "bend"],
                  **(cloth or {})},
                 [BALL, FLOOR])


def drape(device: str = "cpu", size: str = "test") -> list[Check]:
    """The drape for 1.5 s, with the sweeps alone, with the global correction (3 conjugate-gradient iterations a
    substep) and with a line pass a substep (soft shear and bend): it lands, wraps the ball and hangs from it,
    every particle held up by contact alone. The stretch bound is the sweeps' measured end stretch with a margin;
    the line pass has its own, tighter one."""
    n, substeps = (24, 8) if size == "test" else (64, 16)
    # One bound for the sweeps and the correction, about twice the sweeps' measured end stretch
    # (bench/results/stability). The frictionless drape is chaotic: the correction's drape slides on the ball
    # differently with each device's rounding, and its stretch with it, so this is a stability bound; the
    # correction's accuracy is tested in tests/test_global_solve.py.
    bound_rms, bound_max = (0.025, 0.15) if size == "test" else (0.025, 0.18)
    # The line pass: measured 0.06% / 0.24% (24^2) and 0.10% / 0.62% (64^2) on the CPU, about 5x allowed.
    lines_rms, lines_max = (0.003, 0.015) if size == "test" else (0.005, 0.03)
    out = []
    for method, keys, cloth, (most_rms, most_max) in (
            ("sweeps", {}, None, (bound_rms, bound_max)),
            ("global correction", {"global_iterations": 3}, None, (bound_rms, bound_max)),
            ("a line pass", {}, LINE_PASS, (lines_rms, lines_max))):
        case = f"contact: drape on a ball, {method} ({n}x{n}, {substeps} x 2)"
        sim = Simulator(drape_scene(n, substeps, 2, cloth, **keys), device, threads=1)
        log = ContactLog(sim)
        for _ in range(90 * substeps):
            log.step()
        stretch = sim.stretch()
        out += [*log.checks(case),
                Check(case, "RMS stretch at 1.5 s", stretch.rms, most_rms, "measured, with a margin"),
                Check(case, "max stretch at 1.5 s", stretch.max, most_max, "measured, with a margin")]
        sim.close()
    return out


def crumple(device: str = "cpu", size: str = "test", self_collision: bool = True) -> list[Check]:
    """A vertical sheet with self-collision, no pins, thrown down at 4 m/s onto the ground on its lower edge from
    0.2 m, tilted 3 degrees about that edge: its lower edge stops and the rest keeps coming, so it buckles and
    folds onto itself in a heap. Besides the shared checks, its layers stay apart: the closest two particles
    that were not rest neighbours overlap by less than half the collision thickness at the end of every
    substep (a contact pushes a pair apart within the substep, but the ground's clamp after it can put a
    particle back up into a landing layer, and a fold's tip moves faster than the landing), and after 2 s it
    lies in a heap. ``self_collision = False`` runs the same throw without it (the tests check that its layers
    then pass through each other), measured against the thickness self-collision would have used."""
    from warp_verlet.constraints.self_contact import DEFAULT_FRACTION, REST_EXCLUSION

    n = 16 if size == "test" else 32
    case = f"contact: a sheet crumpling onto itself on the ground ({n}x{n}, self-collision {'on' if self_collision else 'off'})"
    # The substeps keep a particle's move per substep at the landing speed under half the collision thickness, as
    # docs/scenes.md asks of self-collision.
    side, top, speed, substeps = 0.5, 0.7, 4.0, (8 if size == "test" else 16)
    ground = {"type": "plane", "name": "ground", "point": [0.0, 0.0, 0.0], "friction_coefficient": 0.5}
    sim = Simulator(scene({"substeps": substeps, "iterations": 8, "damping": 0.5},
                          {"name": "sheet", "resolution": [n, n], "size": [side, side], "origin": [-0.25, top, 0.0],
                           "mass": 0.2, "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 1.0},
                           "self_collision": self_collision}, [ground]), device, threads=1)
    thickness = DEFAULT_FRACTION * side / (n - 1)
    assert not self_collision or sim.scene.cloths[0].options["collision_thickness"] == thickness
    rest = sim.model.rest_positions.astype(np.float64)
    tilt = np.radians(3.0)  # a rigid turn about the lower edge: every stick stays at its rest length
    bottom = top - side
    tilted = rest.copy()
    tilted[:, 1] = bottom + (rest[:, 1] - bottom) * np.cos(tilt)
    tilted[:, 2] = (rest[:, 1] - bottom) * np.sin(tilt)
    sim.state.set_positions(tilted)
    velocity = np.zeros_like(rest)
    velocity[:, 1] = -speed
    sim.state.set_velocity(velocity)
    neighbours = np.linalg.norm(rest[:, None] - rest[None], axis=2) < REST_EXCLUSION * thickness
    log = ContactLog(sim)
    closest = np.inf
    for _ in range(120 * substeps):
        x = log.step().astype(np.float64)
        d = np.linalg.norm(x[:, None] - x[None], axis=2)
        d[neighbours] = np.inf
        closest = min(closest, float(d.min() / thickness))
    height = float(sim.positions()[:, 1].max())
    return [*log.checks(case),
            Check(case, "overlap of the closest non-neighbour pair, any substep, over the thickness", 1.0 - closest,
                  0.5, "no layer comes within half a thickness of passing through another; measured, with a margin",
                  note=f"thickness {thickness:.4f} m"),
            Check(case, "highest particle after 2 s, over the sheet's size", height / side, 0.5,
                  "it has buckled and lies folded, lower than half its size")]


def fast_impact(device: str = "cpu", size: str = "test", line_pass: bool = False) -> list[Check]:
    """A horizontal 1 m sheet thrown down at 30 m/s from just above the ball, at 16 substeps a frame: each
    particle moves 3 cm a substep, more than a 64^2 sheet's spacing. Its middle stops on the ball while the rest
    whips round it. The shared checks (no NaN, no penetration at the end of any substep, no energy gained) and
    no particle goes through the ball. At 4 or 8 substeps a frame a 64^2 sheet is dragged through the ball by
    its own sticks (docs/not_built.md), so the case runs at 16. ``line_pass`` gives the sheet a line pass a
    substep and soft shear and bend (LINE_PASS): the line solve then moves particles the clamp put on the ball
    along it, at these speeds."""
    n = 16 if size == "test" else 64
    substeps = 16
    case = (f"contact: a sheet thrown at 30 m/s onto a ball and the ground ({n}x{n}, {substeps} x 4"
            f"{', a line pass' if line_pass else ''})")
    sim = Simulator(scene({"substeps": substeps, "iterations": 4, "damping": 0.5},
                          {"name": "sheet", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 0.3, -0.5],
                           "orientation": "horizontal", "mass": 0.2, "sticks": ["structural", "shear", "bend"],
                           **(LINE_PASS if line_pass else {})},
                          [BALL, FLOOR]), device, threads=1)
    velocity = np.zeros((sim.model.particle_count, 3))
    velocity[:, 1] = -30.0
    sim.state.set_velocity(velocity)
    log = ContactLog(sim)
    through = 0
    before = sim.positions().astype(np.float64)
    inside = 0.5 * RADIUS  # a column half the ball's radius wide: from its sides a particle may slide round
    for _ in range(60 * substeps):
        after = log.step().astype(np.float64)
        # Within the ball's column, a particle above the centre at one substep and below it at the next went
        # through the ball: round it is more than half its circumference, 0.8 m, in one substep.
        column = (np.hypot(before[:, 0], before[:, 2]) < inside) & (np.hypot(after[:, 0], after[:, 2]) < inside)
        through += int((column & (before[:, 1] > 0.0) & (after[:, 1] < 0.0)).sum())
        before = after
    return [*log.checks(case),
            count_check(case, "particles that went through the ball (above its centre, then below, in its column)",
                        through)]


def fast_impact_line_pass(device: str = "cpu", size: str = "test") -> list[Check]:
    """``fast_impact`` with a line pass a substep (and soft shear and bend)."""
    return fast_impact(device, size, line_pass=True)
