"""The one table of what a substep runs: its stages, and inside the relaxation its constraint sets.

Every stage and constraint set is declared once, here, as a class that says

- ``needed(req)``: whether a scene uses it, from its counts alone (before anything is built);
- ``device_bytes(req)``: the device arrays it allocates, in the Model, the State and the solver;
- ``bind(...)``: its launches, recorded against one State's arrays.

From that one declaration the rest is derived: the solver runs the bound stages (the launches), the memory
estimate sums ``device_bytes`` (warp_verlet/memory.py), the CPU thread team runs the constraint sets'
phases, and ``Simulator.stages()`` names them. A new constraint kind is one kernel file, one class here
(appended to CONSTRAINT_SETS) and its scene keys.

This module does not import warp at the top, so that ``memory.estimate`` (and ``warp-verlet validate``)
stays light; the binding code imports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from .model import Model
    from .scene import Scene
    from .state import State

VEC3, FLOAT, INT, VEC2I, FLOAT64 = 12, 4, 4, 8, 8
VEC3D = 24  # a float64 position


@dataclass(frozen=True)
class Requirements:
    """What a scene asks of the step, known from its counts before anything is built."""

    particles: int
    sticks: int
    relaxation: str
    iterations: int
    free_particles: bool
    compliant: bool
    tears: bool
    colliders: tuple[tuple[str, tuple[int, ...]], ...]  # (kind's type, its counts) per kind present, clamp order
    tethered: int = 0  # free particles of tethered cloths
    tethers_per_particle: int = 0
    coarse_sticks: int = 0  # multilevel: coarse sticks over all levels
    coarse_children: int = 0  # multilevel: particles moved by interpolation, over all levels
    precision: str = "float32"  # the positions' float type, resolved ("auto" never appears here)
    grid_rows: int = 0  # implicit grid sticks: the cloth's rows and columns (0: the sticks are arrays)
    grid_cols: int = 0
    soft_sticks: int = 0  # implicit grid sticks of families with a compliance (each keeps an XPBD tension)
    grid_pins: int = 0  # implicit grid tethers: the cloth's pins (0: the tethers are arrays)
    weight_pins: int = 0  # implicit grid sticks of a cloth whose free particles weigh alike: its pins

    @property
    def position_bytes(self) -> int:
        """Bytes of one position (a vec3 of the precision's float)."""
        return VEC3D if self.precision == "float64" else VEC3

    @property
    def implicit_grid(self) -> bool:
        """Whether the sticks are implicit grid sticks (computed from the grid, no stick arrays)."""
        return self.grid_rows > 0

    @classmethod
    def of(cls, scene: "Scene", sticks: str = "auto") -> "Requirements":
        """The scene's need, with ``simulation.precision`` resolved (warp_verlet/precision.py) and the sticks'
        form chosen (``sticks``: "auto", "explicit" or "implicit"; see :func:`implicit_grid_obstacle`)."""
        from dataclasses import replace

        from .multilevel import hierarchy_counts  # counts from the grid's size, without building anything
        from .topology import stick_count
        from .precision import resolve

        from .colliders import counts as collider_counts

        free = any(c.pin_count < c.particle_count for c in scene.cloths)
        counts = [hierarchy_counts(*c.resolution) for c in scene.cloths] if scene.simulation.multilevel else []
        coarse = (sum(n for n, _ in counts), sum(n for _, n in counts))
        req = cls(
            particles=scene.particle_count, sticks=sum(stick_count(c) for c in scene.cloths),
            relaxation=scene.simulation.relaxation, iterations=scene.simulation.iterations, free_particles=free,
            compliant=scene.compliant, tears=scene.tears, colliders=collider_counts(scene.colliders),
            tethered=scene.tethered_particles, tethers_per_particle=scene.tethers_per_particle,
            coarse_sticks=coarse[0], coarse_children=coarse[1],
        )
        req = replace(req, **grid_counts(scene, sticks))
        return replace(req, precision=resolve(scene, relaxes=RELAX.needed(req)))


STICK_FORMS = ("auto", "explicit", "implicit")
MAX_UNIFORM_MASS_PINS = 8
"""Implicit grid sticks find a particle's weight without reading it (0 for a pin, the free particles' for any
other) when the cloth sets no particle masses and has at most this many pins, which each projection checks."""
MAX_GRID_TETHER_PINS = 8
"""Implicit tethers find each particle's nearest pins in every sweep, among all the cloth's pins: above this
many pins the tether table (kernels/tether.py) serves instead."""


def implicit_grid_obstacle(scene: "Scene") -> str | None:
    """Why the scene's sticks cannot be implicit grid sticks, or None when they can: one grid cloth (whose
    particles lie on a uniform lattice), relaxed by the coloured solver, that cannot tear."""
    from .topology import stick_count

    if scene.simulation.relaxation != "coloured":
        return "the Jacobi solver gathers each particle's sticks from a neighbour list"
    if len(scene.cloths) != 1:
        return "the scene has several cloths"
    cloth = scene.cloths[0]
    if cloth.mesh is not None:
        return "the cloth is a mesh"
    if scene.tears:
        return "the cloth can tear (the tear kernel reads each stick's ends and weight)"
    if stick_count(cloth) == 0:
        return "the cloth has no sticks"
    return None


def grid_counts(scene: "Scene", sticks: str) -> dict:
    """Requirements's implicit-grid fields: all 0 when the sticks are arrays ("explicit", or "auto" where
    :func:`implicit_grid_obstacle` names one); "implicit" where one is named raises ArgumentError. "auto"
    computes the sticks and keeps the tether table; "implicit" computes the tethers too (of a cloth with at most
    MAX_GRID_TETHER_PINS pins), so that no per-stick or per-particle table is left on the device."""
    from .errors import ArgumentError

    if sticks not in STICK_FORMS:
        raise ArgumentError(f"sticks must be one of {', '.join(STICK_FORMS)}, got {sticks!r}")
    obstacle = implicit_grid_obstacle(scene)
    if sticks == "implicit" and obstacle is not None:
        raise ArgumentError(f"sticks = 'implicit' needs one grid cloth that cannot tear and the coloured solver, "
                            f"but {obstacle}")
    if sticks == "explicit" or obstacle is not None:
        return {}
    cloth = scene.cloths[0]
    r, c = cloth.resolution
    per_family = {"structural": r * (c - 1) + (r - 1) * c, "shear": 2 * (r - 1) * (c - 1),
                  "bend": r * max(c - 2, 0) + max(r - 2, 0) * c}
    soft = sum(per_family[f] for f in cloth.sticks if cloth.compliance.get(f, 0.0) > 0.0)
    # Implicit tethers only when asked for: on an H100 the tether table's pass measured faster than computing
    # each particle's nearest pins and their float64 distances in every sweep (bench/results/implicit_grid).
    pins = cloth.pin_count if (sticks == "implicit" and cloth.uses_tethers
                               and 0 < cloth.pin_count <= MAX_GRID_TETHER_PINS) else 0
    weight_pins = cloth.pin_count if not cloth.particle_masses and 0 < cloth.pin_count <= MAX_UNIFORM_MASS_PINS else 0
    return {"grid_rows": r, "grid_cols": c, "soft_sticks": soft, "grid_pins": pins, "weight_pins": weight_pins}


@dataclass(frozen=True)
class PhaseTask:
    """One launch of a phase, named by its kernel (or "copy" / "zero" for a memory operation)."""

    kernel: str
    run: Callable[[], None]
    launch: object = None  # the recorded wp.Launch, whose parameters (dt) can be updated in place


@dataclass
class BoundStage:
    """A stage's work against one State: ``run(state, dt)`` does it (the closures hold that state's arrays,
    never the State itself, so a solver's cache does not keep a dropped state alive); ``phases`` (constraint
    sets only) are the per-thread tasks of one sweep, phase after phase, which the CPU thread team may run
    instead."""

    run: Callable[["State", float], None] | None
    phases: list[list[PhaseTask | None]] | None = None


def recorded(kernel, dim: int, inputs: list, outputs: list | None = None, block_dim: int = 256) -> PhaseTask:
    """A launch recorded once (replaying it skips ``wp.launch``'s argument packing, which dominates small
    grids on the CPU: measured at 64^2, 2.5 -> 1.4 ms per 8 sweeps), as a PhaseTask."""
    import warp as wp

    launch = wp.launch(kernel, dim, inputs=inputs, outputs=outputs or [], record_cmd=True, block_dim=block_dim)
    return PhaseTask(kernel.key, launch.launch, launch)


def split_tasks(make: Callable[[int, int], PhaseTask], first: int, count: int, threads: int) -> list[PhaseTask | None]:
    """``count`` items from ``first`` cut into one piece per thread (None for an empty piece)."""
    from .cpu_team import split

    return [make(f, n) if n else None for f, n in split(first, count, threads)]


# ---------------------------------------------------------------------------------------------- stages
def start_compliant_substep(launches: list, tension) -> Callable[["State", float], None]:
    """A BoundStage's prepare for soft (XPBD) sticks: each substep gives ``launches`` its 1 / dt^2 and restarts the
    tension from zero."""
    def prepare(state: "State", dt: float) -> None:
        inv_dt2 = 1.0 / (dt * dt)
        for launch in launches:
            launch.set_param_by_name("inv_dt2", inv_dt2)
        tension.zero_()

    return prepare


class Integrate:
    """The Verlet step (kernels/integrate.py): gravity and wind in one acceleration, damping per second."""

    name = "integrate"

    def needed(self, req: Requirements) -> bool:
        return req.free_particles

    def device_bytes(self, req: Requirements) -> int:
        return 0  # it updates the State's positions, prediction and increment, which every scene has

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.integrate import verlet_step
        from warp_verlet.kernels.positions import instance

        settings, accel, real = solver.settings, solver.accel, model.position_scalar
        kernel = instance(verlet_step, model.position_dtype)  # launched every substep: resolved once here
        x, x_inertial, dq, inv_mass, n = (state.particle_q, state.particle_q_inertial, state.particle_dq,
                                          model.inv_mass, model.particle_count)

        def run(state: "State", dt: float) -> None:
            ratio = min(dt / state.dt_prev, settings.max_dt_ratio)
            # In the positions' type (accel is one too): a float32 factor would cost float64 its precision.
            velocity_scale = real(math.exp(-settings.damping * dt) * ratio)
            accel_offset = accel * real(dt * (dt + state.dt_prev) * 0.5)
            wp.launch(kernel, n, inputs=[x, x_inertial, dq, inv_mass, velocity_scale, accel_offset])

        return BoundStage(run)


class Relax:
    """``iterations`` sweeps; a sweep runs every constraint set of CONSTRAINT_SETS that the scene needs, in
    table order (Gauss-Seidel across sets, and across colours inside a set). Before the sweeps, each set's
    per-substep work runs, in table order (the multilevel pass, a soft stick's tension reset)."""

    name = "relax"

    def needed(self, req: Requirements) -> bool:
        return req.iterations > 0 and any(c.needed(req) for c in CONSTRAINT_SETS)

    def device_bytes(self, req: Requirements) -> int:
        return sum(c.device_bytes(req) for c in CONSTRAINT_SETS if c.needed(req))

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        sets = [c.bind(model, state, solver) for c in CONSTRAINT_SETS if c.needed(solver.req)]
        phases = [phase for bound in sets for phase in bound.phases]
        before = [bound.run for bound in sets if bound.run is not None]  # per-substep set-up (dt, zeroing)
        team = solver.team(phases)
        sweep = [task.run for phase in phases for task in phase if task is not None]
        iterations = solver.settings.iterations

        def run(state: "State", dt: float) -> None:
            for prepare in before:
                prepare(state, dt)
            if team is not None:
                team.run()
                return
            for _ in range(iterations):
                for task in sweep:
                    task()

        return BoundStage(run, phases)


class Collide:
    """Collider clamping after the sweeps: every collider kind of the registry (warp_verlet/colliders) the scene
    has, in registry order (spheres first, planes last, so that a sphere resting on the ground cannot push
    cloth through the ground). Each kind's ``before`` (a moving sphere placed on the device clock) runs before
    any clamp."""

    name = "collide"

    def needed(self, req: Requirements) -> bool:
        return bool(req.colliders)

    def device_bytes(self, req: Requirements) -> int:
        from .colliders import device_bytes

        return device_bytes(req.colliders)

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        bound = [kind.bind(model, state) for kind, _ in model.colliders.kinds]
        before = [prepare for launches in bound for prepare in launches.before]
        clamps = [task for launches in bound for task in launches.clamps]

        def run(state: "State", dt: float) -> None:
            for prepare in before:
                prepare(dt)
            for task in clamps:
                task.run()

        return BoundStage(run)


class Tear:
    """Threshold tearing after the clamping (kernels/tear.py): zeroes the State's weight of an overlong
    stick."""

    name = "tear"

    def needed(self, req: Requirements) -> bool:
        return req.tears

    def device_bytes(self, req: Requirements) -> int:
        # Per entry a tear length (Model) and a live weight (State); Jacobi has two entries per stick and keeps
        # their ends.
        return req.sticks * (2 * FLOAT if req.relaxation == "coloured" else 2 * (2 * FLOAT + VEC2I))

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        from warp_verlet.kernels.tear import tear_sticks

        task = recorded(tear_sticks, model.tear_ends.shape[0], [state.particle_q, model.tear_ends, model.tear_length],
                        [state.stick_weight, state.torn_entries])
        return BoundStage(lambda state, dt: task.run())


# ------------------------------------------------------------------------------------- constraint sets
class Sticks:
    """Distance sticks (kernels/relax.py). Coloured: one launch per colour, XPBD where a stick is soft.
    Jacobi: a gather into a scratch buffer and a copy back, cut by particle."""

    name = "sticks"

    def needed(self, req: Requirements) -> bool:
        return req.sticks > 0 and not req.implicit_grid

    def device_bytes(self, req: Requirements) -> int:
        if req.relaxation == "coloured":
            # ends, rest, weight; soft sticks add a compliance (Model) and a tension (solver scratch)
            return req.sticks * (VEC2I + 2 * FLOAT + (2 * FLOAT if req.compliant else 0))
        # neighbour, rest and weight for both ends; a scratch position and a row start per particle
        return req.sticks * 2 * (INT + 2 * FLOAT) + req.particles * (req.position_bytes + INT)

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.relax import relax_colour, relax_colour_compliant, relax_jacobi

        m, x, threads = model, state.particle_q, solver.threads
        if m.relaxation == "coloured":
            weight = state.stick_weight if m.tears else m.stick_weight
            if not m.compliant:
                def make(f, n):
                    return recorded(relax_colour, n, [x, m.inv_mass, m.stick_ends, m.stick_rest, weight, f])
                return BoundStage(None, [split_tasks(make, first, count, threads) for first, count in m.colour_ranges])
            tension = solver.scratch("stick_tension", m.stick_count, float)

            def make_soft(f, n):
                return recorded(relax_colour_compliant, n, [x, m.inv_mass, m.stick_ends, m.stick_rest, weight,
                                                            m.stick_compliance, 0.0, f], [tension])
            phases = [split_tasks(make_soft, first, count, threads) for first, count in m.colour_ranges]
            launches = [task.launch for phase in phases for task in phase if task is not None]

            return BoundStage(start_compliant_substep(launches, tension), phases)

        weight = state.stick_weight if m.tears else m.neighbour_weight
        scratch = solver.scratch("jacobi_positions", m.particle_count, m.position_dtype)

        def gather(f, n):
            return recorded(relax_jacobi, n, [x, m.inv_mass, m.neighbour_start, m.neighbour, m.neighbour_rest,
                                              weight, f, scratch])

        def copy_back(f, n):
            # The task holds the arrays, not the solver: worker threads keep their tasks alive, and must not
            # keep a solver alive.
            return PhaseTask("copy", lambda: wp.copy(x, scratch, dest_offset=f, src_offset=f, count=n))

        return BoundStage(None, [split_tasks(gather, 0, m.particle_count, threads),
                            split_tasks(copy_back, 0, m.particle_count, threads)])


class Multilevel:
    """The multilevel pass (warp_verlet/multilevel.py, kernels/multilevel.py): once per substep, before the
    sweeps, coarsest level first: ``multilevel_sweeps`` sweeps of a level's unilateral coarse sticks, then its
    moves interpolated to the next finer level's other particles. It must run first in the relaxation: it
    measures each particle's move from the Verlet prediction."""

    name = "multilevel"

    def needed(self, req: Requirements) -> bool:
        return req.coarse_sticks > 0

    def device_bytes(self, req: Requirements) -> int:
        # ends and limit per coarse stick; child, four parents and four weights per child
        return req.coarse_sticks * (VEC2I + FLOAT) + req.coarse_children * (INT + 4 * INT + 4 * FLOAT)

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        from warp_verlet.kernels.multilevel import limit_coarse_colour, prolongate

        x, x_inertial, inv_mass = state.particle_q, state.particle_q_inertial, model.inv_mass
        sweeps = solver.settings.multilevel_sweeps
        tasks = []
        for level in model.levels:
            colours = [recorded(limit_coarse_colour, n, [x, inv_mass, level.ends, level.limit, f])
                       for f, n in level.colour_ranges]
            tasks += colours * sweeps
            tasks.append(recorded(prolongate, level.child.shape[0], [x, x_inertial, inv_mass, level.child,
                                                                     level.parents, level.weights]))
        runs = [task.run for task in tasks]

        def run(state: "State", dt: float) -> None:
            for task in runs:
                task()

        return BoundStage(run, [])


class Tethers:
    """Long-range attachments (kernels/tether.py): one launch per sweep, before the sticks, so that every sweep
    starts from particles within reach of their pins. When the torn set changes, tethers cut off from their
    pin are dropped (warp_verlet/tethers.py)."""

    name = "tethers"

    def needed(self, req: Requirements) -> bool:
        return req.tethered > 0 and req.grid_pins == 0

    def device_bytes(self, req: Requirements) -> int:
        per_particle = INT + req.tethers_per_particle * (INT + FLOAT)  # particle; pin and length per tether
        live = req.tethers_per_particle * FLOAT if req.tears else 0  # the State's lengths, cut by tears
        return req.tethered * (per_particle + live)

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        from warp_verlet.kernels.tether import pull_tethers

        length = state.tether_length if state.tether_length is not None else model.tether_length
        x, n = state.particle_q, model.tether_particle.shape[0]

        def make(f, count):
            return recorded(pull_tethers, count, [x, model.tether_particle[f:f + count], model.tether_pin[f:f + count],
                                                  length[f:f + count]])
        return BoundStage(None, [split_tasks(make, 0, n, solver.threads)])

    @staticmethod
    def on_tear(model: "Model", state: "State", torn: "np.ndarray") -> None:
        """Drop the tethers whose particle a tear has cut off from its pin."""
        if state.tether_length is None:
            return
        from .tethers import cut_tethers

        state.tether_length.assign(cut_tethers(model.tether_table, model.particle_count, model.host_sticks[~torn]))


class GridTethers:
    """Tethers of a grid cloth with few pins, computed (kernels/grid_relax.py): each free particle finds its
    nearest pins and their rest-pose distances from its grid coordinates, so a sweep reads no tether table.
    One launch per sweep over the cloth's particles (pins skip), before the sticks, as Tethers."""

    name = "grid tethers"

    def needed(self, req: Requirements) -> bool:
        return req.tethered > 0 and req.grid_pins > 0

    def device_bytes(self, req: Requirements) -> int:
        # the pins, and per pin the squared column and row differences to it (float64)
        return req.grid_pins * (INT + (req.grid_cols + req.grid_rows) * FLOAT64)

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.grid_relax import pull_grid_tethers

        t, x = model.grid_tethers, state.particle_q

        def make(f, rows):
            return recorded(pull_grid_tethers, rows << t.col_bits,
                            [x, model.inv_mass, t.first_particle, t.cols, t.pins, t.pin_col_sq, t.pin_row_sq, t.tethers,
                             wp.float64(t.scale), t.col_bits, f])
        return BoundStage(None, [split_tasks(make, 0, t.rows, solver.threads)])


GRID_BLOCK_DIM = 128
"""Threads per block of the implicit grid sticks' launches: 128 ran 2% faster per frame than Warp's default 256
on an H100 at 1024^2, 512 7% slower (bench/results/implicit_grid/README.md)."""


class GridSticks:
    """Implicit grid sticks (kernels/grid_relax.py): one launch per colour of the analytic grid colouring, in
    its order, each stick's ends and rest length computed from the thread index and the grid; the same
    positions as Sticks bit for bit. XPBD for the colours of a soft family."""

    name = "grid sticks"

    def needed(self, req: Requirements) -> bool:
        return req.sticks > 0 and req.implicit_grid

    def device_bytes(self, req: Requirements) -> int:
        r, c = req.grid_rows, req.grid_cols
        steps = max(c - 1, 0) + max(c - 2, 0) + max(r - 1, 0) + max(r - 2, 0)  # 1 and 2 columns, 1 and 2 rows apart
        tables = steps * FLOAT + (max(c - 1, 0) + max(r - 1, 0)) * FLOAT64  # rest lengths; squared steps (shear)
        # a tension per soft stick (solver scratch); the pins where the free particles weigh alike
        return tables + req.soft_sticks * FLOAT + req.weight_pins * INT

    def bind(self, model: "Model", state: "State", solver) -> BoundStage:
        from warp_verlet.kernels.grid_relax import relax_grid_colour, relax_grid_colour_compliant

        g, x, threads = model.grid, state.particle_q, solver.threads
        tension = solver.scratch("grid_tension", g.soft_sticks, float) if g.soft_sticks else None
        phases, soft_launches = [], []
        for colour in g.colours:
            tables = [colour.pins, colour.col_rest, colour.row_rest, colour.col_sq, colour.row_sq]
            if colour.compliance > 0.0:
                def make(f, rows, colour=colour, tables=tables):
                    return recorded(relax_grid_colour_compliant, rows << colour.layout.col_bits,
                                    [x, model.inv_mass, colour.layout, *tables, colour.compliance, 0.0, f,
                                     colour.tension_first], [tension], block_dim=GRID_BLOCK_DIM)
            else:
                def make(f, rows, colour=colour, tables=tables):
                    return recorded(relax_grid_colour, rows << colour.layout.col_bits,
                                    [x, model.inv_mass, colour.layout, *tables, f], block_dim=GRID_BLOCK_DIM)
            phase = split_tasks(make, 0, colour.rows, threads)  # the CPU thread team cuts a colour by rows
            if colour.compliance > 0.0:
                soft_launches += [task.launch for task in phase if task is not None]
            phases.append(phase)
        if tension is None:
            return BoundStage(None, phases)

        return BoundStage(start_compliant_substep(soft_launches, tension), phases)


CONSTRAINT_SETS = (Multilevel(), Tethers(), GridTethers(), Sticks(), GridSticks())
"""Constraint sets in the order a sweep projects them."""

RELAX = Relax()
STAGES = (Integrate(), RELAX, Collide(), Tear())
"""The stages of a substep, in order."""


def particle_bytes(req: Requirements) -> int:
    """Every scene's per-particle arrays: the State's positions, prediction and increment (12 bytes each in
    float32, 24 in float64), the Model's inverse mass (float32 either way)."""
    return 3 * req.position_bytes + FLOAT


def device_bytes(req: Requirements) -> int:
    """The device memory a scene's arrays take: the sum of what its stages declare."""
    return req.particles * particle_bytes(req) + sum(s.device_bytes(req) for s in STAGES if s.needed(req))
