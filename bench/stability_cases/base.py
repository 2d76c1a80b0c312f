"""What every stability case uses: the :class:`Check` row, the scenes, reading the simulator's state, energy.

Energy, wherever it is used: kinetic from the implicit velocity v = (x - x_prev) / dt of the last step with
per-particle masses (``mass / particles``, then ``particle_masses`` overrides; pins are fixed and carry
none), read from the summed-form State as x - x_prev = particle_dq + (particle_q - particle_q_inertial) in
float64; potential -sum m a.x with a = gravity + wind (both are uniform accelerations). E0 is the initial pose
at rest. Relaxation is a projection and removes energy (README: "projection damping"), so undamped (damping 0)
energy may fall but must not rise; elastic energy of stretched sticks is not counted (rigid sticks have none).

Scenes: every stick is rigid unless a case is about softness (then it says what compliance it uses and why),
and every cloth has tethers off (``tethers = false``) unless the case is about them, so that the cases measure
what they measured before tethers existed. A case's old per-substep ``drag`` d is the damping -ln(d) / dt at
that case's own dt (:func:`damping`): the same velocity kept per substep, to float64 rounding.

Float32 rounding: an ulp is ``np.spacing(float32(|x|))`` of the largest coordinate involved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from warp_verlet.input.scene import Scene
from warp_verlet.core.simulator import Simulator

from ..common import HANGING_FAMILIES, cloth_size, damping_for_drag, hanging_sheet
from ..common import scene as bench_scene

G = 9.81
SIZES = ("test", "bench")
SCENE_NAME = "<stability>"  # stands for the file in scene error messages (zero_area checks one word for word)
DT = 1.0 / 240.0  # s: the scenes' fixed step (60 fps x 4 substeps) unless a case says otherwise


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


def damping(drag: float, dt: float = DT) -> float:
    """The damping rate (1/s) of an old per-substep ``drag`` at the step ``dt``: exp(-damping dt) = drag."""
    return damping_for_drag(drag, dt)


def scene(simulation: dict, cloths: dict | list, colliders: list | None = None) -> Scene:
    """bench.common.scene under the stability suite's name; a cloth that does not say otherwise gets
    ``tethers = false``."""
    cloths = [{"tethers": False, **c} for c in (cloths if isinstance(cloths, list) else [cloths])]
    return bench_scene(simulation, cloths, colliders, name=SCENE_NAME)


def hanging(n: int, simulation: dict, sticks: list | None = None, **cloth) -> Scene:
    """The benchmark's n x n, 1 m sheet, horizontal (it swings down through 0.5 m), pinned at its two top corners,
    rigid sticks (all three families unless ``sticks`` lists others), no tethers unless ``cloth`` asks."""
    return scene(simulation, hanging_sheet(n, orientation="horizontal", sticks=list(sticks or HANGING_FAMILIES),
                                           **cloth))


def free_fall_error(sim: Simulator, x0: np.ndarray, t: float) -> float:
    """max over particles of |x - (x0 + a t^2 / 2)|, float64."""
    a = np.asarray(sim.settings.gravity, np.float64) + np.asarray(sim.settings.wind, np.float64)
    return float(np.abs(sim.positions().astype(np.float64) - (x0 + 0.5 * a * t * t)).max())


def free_cloth(n: int = 6, **simulation) -> Scene:
    """An unpinned n x n, 0.5 m cloth at the origin: in free fall its sticks stay at rest length, so every
    particle follows x0 + a t^2 / 2 (the integrator is exact for constant acceleration, for any dt)."""
    return scene({"iterations": 8, **simulation},
                 {"name": "free", "resolution": [n, n], "size": [0.5, 0.5], "sticks": ["structural", "shear"]})


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
    """(x - x_prev) / dt in float64, from the summed-form State: x - x_prev = particle_dq + (particle_q -
    particle_q_inertial). Before the first step, the velocity set_velocity gave (State.start_velocity)."""
    state = sim.state
    if state.dt_prev is None:
        if state.start_velocity is None:
            return np.zeros((sim.model.particle_count, 3))
        return state.start_velocity.astype(np.float64)
    x, xi, d = (a.numpy().astype(np.float64) for a in (state.particle_q, state.particle_q_inertial,
                                                       state.particle_dq))
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
        x = self.sim.state.particle_q.numpy().astype(np.float64)
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
        return float(self.m[self.free].sum() * np.linalg.norm(self.a) * cloth_size(self.sim.scene))

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
        basis = basis or (f"physics: damping 0 and a dissipative projection; {tolerance:g} for the O(dt) bias of "
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
