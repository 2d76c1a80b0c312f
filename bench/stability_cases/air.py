"""Air ([simulation.air]): a flag in a gale (20 m/s) and in a hurricane (50 m/s), a light free sheet carried
by a hurricane, and air of density 0.

Energy here is not conserved: the air does work on the cloth. What stays bounded is checked instead: finite
positions; the kinetic energy, at most that of the whole free mass moving at the air's speed, 1/2 M U^2 (a
flag's free edge whips, but a pinned flag driven by the air stays far below it); the structural
stretch (rigid sticks, so it is the relaxation's residual under the load); for a free sheet driven by drag
alone, its mean velocity along the stream, which drag brings up to the air's speed U and not past it (the
overshoot limit of kernels/aerodynamics.py, without which a 0.05 kg/m^2 sheet at 50 m/s, 1/240 s steps,
diverges)."""

from __future__ import annotations

import numpy as np

from warp_verlet.core.simulator import Simulator

from .base import Check, count_check, implicit_velocity, nonfinite, particle_masses, scene

GALE, HURRICANE = 20.0, 50.0  # m/s
STRETCH_BOUND = 0.5  # a cloth, not a divergence: the measured maxima are in bench/results/stability


def flag_scene(n: int, speed: float, density: float = 1.2):
    """A 1 m, 0.2 kg flag of n x n particles nailed along its left edge, in a stream of ``speed`` along +X with
    gusts of a tenth of it (they break the symmetry of the flat flag at once)."""
    return scene({"iterations": 8, "air": {"velocity": [speed, 0.0, 0.0], "density": density,
                                           "gust_speed": 0.1 * speed, "gust_seed": 3}},
                 _flag_cloth(n))


def run_in_air(sc, device: str, frames: int, speed: float) -> tuple[Simulator, int, float, float, float]:
    """Run ``sc`` for ``frames`` frames in air of ``speed``: the simulator, the NaN/inf coordinates summed over the
    frames, the largest kinetic energy of the free particles over 1/2 M U^2, the fastest free particle over U and
    the largest structural stretch."""
    sim = Simulator(sc, device)
    m = particle_masses(sc)
    free = sim.model.inv_mass.numpy() > 0
    bad, kinetic, stretch, fastest = 0, 0.0, 0.0, 0.0
    for _ in range(frames):
        sim.step_frame()
        bad += nonfinite(sim.positions())
        v = implicit_velocity(sim, sim.settings.dt)[free]
        speed2 = np.sum(v * v, axis=1)
        kinetic = max(kinetic, float(0.5 * np.sum(m[free] * speed2)))
        fastest = max(fastest, float(np.sqrt(speed2.max())))
        stretch = max(stretch, sim.stretch().max)
    bound = 0.5 * float(m[free].sum()) * speed * speed
    return sim, bad, kinetic / bound, fastest / speed, stretch


def flag_in(speed: float, label: str, device: str, size: str) -> list[Check]:
    n = 16 if size == "test" else 64
    case = f"air: flag in a {label}, {speed:g} m/s ({n}x{n})"
    _, bad, kinetic, fastest, stretch = run_in_air(flag_scene(n, speed), device, 120, speed)  # 2 s
    return [
        count_check(case, "particles with a NaN/inf coordinate, summed over frames", bad),
        Check(case, "kinetic energy max KE / (1/2 M U^2)", kinetic, 1.0,
              "the whole free mass moving at the air's speed: a flag the air drives stays far below it",
              f"fastest particle {fastest:.2f} U"),
        Check(case, "structural stretch max over the run", stretch, STRETCH_BOUND,
              "bounded: a cloth, not a divergence (rigid sticks, 4 x 8)"),
    ]


def air_gale(device: str = "cpu", size: str = "test") -> list[Check]:
    """A flag in a 20 m/s gale for 2 s."""
    return flag_in(GALE, "gale", device, size)


def air_hurricane(device: str = "cpu", size: str = "test") -> list[Check]:
    """A flag in a 50 m/s hurricane for 2 s."""
    return flag_in(HURRICANE, "hurricane", device, size)


def air_carried_sheet(device: str = "cpu", size: str = "test") -> list[Check]:
    """A free 1 m, 0.05 kg/m^2 sheet, turned 60 degrees to a 50 m/s stream, for 2 s, by drag alone (no gravity,
    no lift: with them it could glide faster than the air, as a sail can): it is carried off, its mean velocity
    along the stream rising to U and not past it. Without the overshoot limit the same sheet diverges."""
    n = 16 if size == "test" else 64
    case = f"air: free sheet carried by {HURRICANE:g} m/s ({n}x{n})"
    sc = scene({"iterations": 8, "gravity": [0.0, 0.0, 0.0], "air": {"velocity": [HURRICANE, 0.0, 0.0]}},
               {"name": "free", "resolution": [n, n], "size": [1.0, 1.0], "origin": [0.0, 1.0, 0.0], "mass": 0.05,
                "sticks": ["structural", "shear"], "lift_coefficient": 0.0})
    sim = Simulator(sc, device)
    p = sim.positions().astype(np.float64)
    turn = np.radians(60.0)
    p[:, 2], p[:, 0] = p[:, 0] * np.sin(turn), p[:, 0] * np.cos(turn)
    sim.state.set_positions(p)
    m = particle_masses(sc)
    bad, mean_speeds = 0, []
    for _ in range(120):
        sim.step_frame()
        bad += nonfinite(sim.positions())
        v = implicit_velocity(sim, sim.settings.dt)
        mean_speeds.append(float(np.sum(m * v[:, 0]) / m.sum()))
    top, last = max(mean_speeds), mean_speeds[-1]
    return [
        count_check(case, "particles with a NaN/inf coordinate, summed over frames", bad),
        Check(case, "mean velocity along the stream, max / U", top / HURRICANE, 1.01,
              "physics: drag drives the sheet to the stream's velocity; 1 % as each face of a crumpling sheet is "
              "pushed by its own relative velocity, not the mean's", f"at the end {last / HURRICANE:.4f} U"),
        Check(case, "carried: 1 - (mean velocity at the end / U)", 1.0 - last / HURRICANE, 0.1,
              "physics: drag brings the sheet to the stream's speed (time constant under 0.1 s at 50 m/s)"),
    ]


def air_stretched_strip(device: str = "cpu", size: str = "test") -> list[Check]:
    """A light strip far from converged in a 17 m/s stream: 20 m long and 2 cm wide (11 x 9 particles, so its
    faces are 800 times longer than wide), 10 g, nailed along its short left edge and at one more particle, one
    sweep a substep (8 x 1), for 1 s. The sweep cannot hold its 2.5 mm sticks against the air, so its faces stretch
    many times their width and present that much more area to the flow while their corners keep their mass. The
    overshoot limit must count the area the face has now, not its rest area: with the rest area the strip took
    more force every step and went to NaN in its second frame (found by `python -m bench.fuzz`). Not a size
    case: the test and bench runs are the same."""
    case = "air: a light strip stretched by a 17 m/s stream, 8 x 1"
    speed = 17.0
    sc = scene({"substeps": 8, "iterations": 1, "air": {"velocity": [speed, 0.0, 0.0]}},
               {"name": "strip", "resolution": [11, 9], "size": [20.0, 0.02], "orientation": "horizontal",
                "origin": [0.0, 1.0, 0.0], "mass": 0.01, "sticks": ["structural", "shear", "bend"],
                "compliance": {"shear": 0.01, "bend": 1.0}, "pins": ["left-edge", [8, 1]]})
    sim, bad, kinetic, _, _ = run_in_air(sc, device, 60, speed)
    return [
        count_check(case, "particles with a NaN/inf coordinate, summed over frames", bad),
        Check(case, "kinetic energy max KE / (1/2 M U^2)", kinetic, 1.0,
              "the whole free mass moving at the air's speed: the air cannot drive the strip faster",
              f"stretch at the end {sim.stretch().max:.3g} (not a criterion: one sweep a substep)"),
    ]


def air_zero_density(device: str = "cpu", size: str = "test") -> list[Check]:
    """Air of density 0 at 50 m/s is no air: positions bit-identical to the same flag without [simulation.air]."""
    n = 16 if size == "test" else 64
    case = f"air: density 0 ({n}x{n})"
    still = flag_scene(n, HURRICANE, density=0.0)
    plain = scene({"iterations": 8}, _flag_cloth(n))
    with_air, without = Simulator(still, device), Simulator(plain, device)
    for _ in range(60):
        with_air.step_frame()
        without.step_frame()
    differ = int(np.count_nonzero(with_air.positions() != without.positions()))
    return [count_check(case, "coordinates that differ from the scene without air after 1 s", differ),
            count_check(case, "air arrays built", int(with_air.model.air is not None))]


def _flag_cloth(n: int) -> dict:
    return {"name": "flag", "resolution": [n, n], "size": [1.0, 1.0], "origin": [0.0, 1.0, 0.0], "mass": 0.2,
            "pins": ["left-edge"], "sticks": ["structural", "shear", "bend"]}
