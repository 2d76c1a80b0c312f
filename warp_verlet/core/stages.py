"""The one table of what a substep runs: its stages. Inside the relaxation run the constraint kinds
(warp_verlet/constraints/), inside the clamp the collider kinds (warp_verlet/colliders/), each declared in its
own module.

Every stage is declared once, here, as a class that says

- ``needed(req)``: whether a scene uses it, from its counts alone (before anything is built);
- ``device_bytes(req)``: the device arrays it allocates, in the Model, the State and the solver;
- ``bind(...)``: its launches, recorded against one State's arrays.

From that one declaration the rest is derived: the solver runs the bound stages (the launches), the memory
estimate sums ``device_bytes`` (warp_verlet/core/memory.py), the CPU thread team runs the constraint kinds'
phases, and ``Simulator.stages()`` names them. A new stage is one class in STAGES and one kernel file; a new
constraint or collider kind is one module of its package, one kernel file and one registry line.

This module does not import warp at the top, so that ``memory.estimate`` (and ``warp-verlet validate``)
stays light; the binding code imports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    from ..input.scene import Scene
    from .aerodynamics import AirCounts

from ..constraints import kinds as constraint_kinds
from ..constraints.tethers import Tethers
from ..launches import FLOAT, VEC2I, VEC3, VEC3D, BoundStage, noted_pushes, recorded, split_tasks


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
    collider_friction: bool  # whether any collider has friction (a stage noting contact normals sums the pushes)
    tethered: int = 0  # free particles of tethered cloths
    tether_rows: int = 0  # the tether table's rows: the particles of the tethered cloths' span
    tethers_per_particle: int = 0
    coarse_sticks: int = 0  # multilevel: coarse sticks over all levels
    coarse_children: int = 0  # multilevel: particles moved by interpolation, over all levels
    precision: str = "float32"  # the positions' float type, resolved ("auto" never appears here)
    grid_rows: int = 0  # implicit grid sticks: the cloth's rows and columns (0: the sticks are arrays)
    grid_cols: int = 0
    soft_sticks: int = 0  # implicit grid sticks of families with a compliance (each keeps an XPBD tension)
    grid_pins: int = 0  # implicit grid tethers: the cloth's pins (0: the tethers are arrays)
    grid_tiles: bool = False  # implicit grid sticks swept tile by tile in shared memory (kernels/grid_tiles.py)
    stick_clusters: bool = False  # stick arrays swept cluster by cluster in shared memory (kernels/stick_clusters.py)
    weight_pins: int = 0  # implicit grid sticks of a cloth whose free particles weigh alike: its pins
    elements: tuple[tuple[str, object], ...] = ()  # (kind name, its count(scene)) of the kinds a scene uses
    global_iterations: int = 0  # the global correction's conjugate-gradient iterations (0: no correction)
    global_levels: tuple[tuple[int, int, int], ...] = ()  # its multigrid's coarse levels: (nodes, sticks, children)
    tension_tears: bool = False  # a cloth tears by tension: the sticks keep their tension, the tear kernel reads it
    air: "AirCounts | None" = None  # [simulation.air]'s faces, keys, clock (core/aerodynamics.py); None: no air

    def count(self, kind: str):
        """Constraint kind ``kind``'s ``count(scene)`` (0 when the scene does not use it)."""
        return dict(self.elements).get(kind, 0)

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
        """The scene's need, with ``simulation.precision`` resolved (warp_verlet/core/precision.py) and the sticks'
        form chosen (``sticks``: "auto", "explicit" or "implicit"; see :func:`implicit_grid_obstacle`)."""
        from dataclasses import replace

        from ..constraints.multilevel import hierarchy_counts  # counts from the grid's size, without building anything
        from ..geometry.topology import stick_count
        from .precision import resolve

        from ..colliders import counts as collider_counts
        from ..colliders.kind import has_friction
        from .aerodynamics import air_counts

        free = any(c.pin_count < c.particle_count for c in scene.cloths)
        counts = [hierarchy_counts(*c.resolution) for c in scene.cloths] if scene.simulation.multilevel else []
        coarse = (sum(n for n, _ in counts), sum(n for _, n in counts))
        req = cls(
            particles=scene.particle_count, sticks=sum(stick_count(c) for c in scene.cloths),
            relaxation=scene.simulation.relaxation, iterations=scene.simulation.iterations, free_particles=free,
            compliant=scene.compliant, tears=scene.tears, colliders=collider_counts(scene.colliders),
            collider_friction=has_friction(scene.colliders),
            tethered=scene.tethered_particles, tether_rows=scene.tether_rows,
            tethers_per_particle=scene.tethers_per_particle,
            coarse_sticks=coarse[0], coarse_children=coarse[1], tension_tears=scene.tears_by_tension,
            elements=tuple((kind.name, n) for kind in constraint_kinds() if (n := kind.count(scene))),
            global_iterations=scene.simulation.global_iterations,
            global_levels=global_levels(scene),
            air=air_counts(scene),
        )
        req = replace(req, **grid_counts(scene, sticks))
        req = replace(req, precision=resolve(scene, relaxes=RELAX.needed(req)))
        if sticks == "auto" and req.implicit_grid and req.grid_rows * req.grid_cols >= MIN_TILED_PARTICLES:
            req = replace(req, grid_tiles=True)
        if (sticks == "auto" and not req.implicit_grid and req.particles >= MIN_CLUSTERED_PARTICLES
                and cluster_obstacle(scene, req) is None):
            req = replace(req, stick_clusters=True)
        if sticks == "clustered":
            from ..errors import StickFormRefused

            obstacle = cluster_obstacle(scene, req)
            if obstacle is not None:
                raise StickFormRefused(f"sticks = 'clustered' sweeps float32 stick arrays of the coloured solver "
                                       f"that cannot tear, but {obstacle}")
            req = replace(req, stick_clusters=True)
        return req


def global_levels(scene: "Scene") -> tuple[tuple[int, int, int], ...]:
    """The coarse levels the global correction's multigrid builds: none without the correction, with the Jacobi
    preconditioner, or with a mesh cloth."""
    from .global_solve import coarse_level_counts

    sim = scene.simulation
    if not sim.global_iterations or sim.global_preconditioner != "multigrid" or any(c.resolution is None
                                                                                     for c in scene.cloths):
        return ()
    return tuple(coarse_level_counts([tuple(c.resolution) for c in scene.cloths]))


STICK_FORMS = ("auto", "explicit", "implicit", "tiled", "clustered")
MIN_TILED_PARTICLES = 512 * 512
"""Where "auto" sweeps a grid's sticks, rigid or soft, tile by tile (kernels/grid_tiles.py) on a GPU: from this
many particles on. On an H100 the tiles reached the same RMS stretch as a launch per colour in less time at 512^2,
1024^2 and 2048^2, rigid or with soft bend sticks, and took longer at 256^2, where a launch of a quarter of the
tiles leaves most of the GPU idle (bench/results/grid_tiles); with float64 positions, 14% less time on the 1024^2
drape (bench/results/grid_tiles/float64)."""
MIN_CLUSTERED_PARTICLES = 512 * 512
"""Where "auto" sweeps float32 stick arrays (a mesh cloth's, or several cloths') cluster by cluster on a GPU
(constraints/stick_clusters.py): from this many particles on. On an H100 the clustered sweep took 28-60% less time
than a launch per colour at 512^2 and 1024^2, rigid or with soft bend sticks, for the same stretch; at 256^2 the
two were within 3% of each other either way, and below it the clustered sweep was slower (bench/results/mesh).
A layout the clustered sweep refuses (an overflow colour, a region too large for shared memory) keeps a launch
per colour (Model)."""
MAX_UNIFORM_MASS_PINS = 8
"""Implicit grid sticks find a particle's weight without reading it (0 for a pin, the free particles' for any
other) when the cloth sets no particle masses and has at most this many pins, which each projection checks."""
MAX_GRID_TETHER_PINS = 8
"""Implicit tethers find each particle's nearest pins in every sweep, among all the cloth's pins: above this
many pins the tether table (kernels/tether.py) serves instead."""


def implicit_grid_obstacle(scene: "Scene") -> str | None:
    """Why the scene's sticks cannot be implicit grid sticks, or None when they can: one grid cloth (whose
    particles lie on a uniform lattice), relaxed by the coloured solver, that cannot tear."""
    from ..geometry.topology import stick_count

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
    if scene.simulation.global_iterations and cloth.compliance:
        return "the global correction starts each soft stick's tension, which implicit grid sticks keep per family"
    return None


def cluster_obstacle(scene: "Scene", req: Requirements) -> str | None:
    """Why the scene's sticks cannot be swept cluster by cluster (constraints/stick_clusters.py), or None."""
    if scene.simulation.relaxation != "coloured":
        return "the Jacobi solver gathers each particle's sticks from a neighbour list"
    if req.sticks == 0:
        return "the scene has no sticks"
    if scene.tears:
        return "a cloth can tear (the sweep reads no stick's weight)"
    if scene.compliant and scene.simulation.global_iterations:
        return "the global correction starts each soft stick's tension in the stick arrays' order"
    if req.precision != "float32":
        return "the positions are float64 (simulation.precision)"
    return None


def grid_counts(scene: "Scene", sticks: str) -> dict:
    """Requirements's implicit-grid fields: all 0 when the sticks are arrays ("explicit", or "auto" where
    :func:`implicit_grid_obstacle` names one); "implicit" where one is named raises ArgumentError. "auto"
    computes the sticks and keeps the tether table; "implicit" computes the tethers too (of a cloth with at most
    MAX_GRID_TETHER_PINS pins), so that no per-stick or per-particle table is left on the device."""
    from ..errors import ArgumentError, StickFormRefused

    if sticks not in STICK_FORMS:
        raise ArgumentError(f"sticks must be one of {', '.join(STICK_FORMS)}, got {sticks!r}")
    obstacle = implicit_grid_obstacle(scene)
    if sticks in ("implicit", "tiled") and obstacle is not None:
        raise StickFormRefused(f"sticks = {sticks!r} needs one grid cloth that cannot tear and the coloured "
                               f"solver, but {obstacle}")
    if sticks in ("explicit", "clustered") or obstacle is not None:
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
    return {"grid_rows": r, "grid_cols": c, "soft_sticks": soft, "grid_pins": pins, "weight_pins": weight_pins,
            "grid_tiles": sticks == "tiled"}



class Aerodynamics:
    """Drag and lift on every face from the air (kernels/aerodynamics.py, warp_verlet/core/aerodynamics.py): each
    face's force, shared among its corners, which the Verlet step then gathers. Only with air that pushes."""

    name = "air"

    def needed(self, req: Requirements) -> bool:
        return req.air is not None and req.free_particles

    def device_bytes(self, req: Requirements) -> int:
        from .aerodynamics import device_bytes

        return device_bytes(req.air, req.particles, req.position_bytes, req.tears)

    def bind(self, model, state, solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.aerodynamics import face_forces
        from warp_verlet.kernels.collide_sphere import advance_clock
        from warp_verlet.kernels.positions import instance

        air, real = model.air, model.position_scalar
        kernel = instance(face_forces, model.position_dtype)
        share = solver.scratch("air_share", air.face_params.shape[0], model.position_dtype)
        clock = state.air_clock if air.clock else air.no_clock
        weight = state.stick_weight if model.tears else air.no_weight
        inputs = [state.particle_q, state.particle_q_inertial, state.particle_dq, air.face_start, air.face_corner,
                  air.face_params, air.side_entry, weight, clock, air.key_times, air.key_values, air.gust_direction,
                  air.gust_wave, air.gust_timing, air.density]
        faces = air.face_params.shape[0]

        def run(state, dt: float) -> None:
            # The force at the start of the step, from the velocity over the last one (the exact start set
            # dt_prev = dt before the first).
            wp.launch(kernel, faces, inputs=[*inputs, real(1.0 / state.dt_prev), real(dt), share])
            if air.clock:
                wp.launch(advance_clock, 1, inputs=[clock, wp.float64(dt)])

        return BoundStage(run)


class Integrate:
    """The Verlet step (kernels/integrate.py): gravity and wind in one acceleration, damping per second; with air,
    each particle's share of its faces' forces too (Aerodynamics)."""

    name = "integrate"

    def needed(self, req: Requirements) -> bool:
        return req.free_particles

    def device_bytes(self, req: Requirements) -> int:
        return 0  # it updates the State's positions, prediction and increment, which every scene has

    def bind(self, model, state, solver) -> BoundStage:
        if AERODYNAMICS.needed(solver.req):
            return self._bind_air(model, state, solver)
        import warp as wp

        from warp_verlet.kernels.integrate import verlet_step, verlet_step_tethered
        from warp_verlet.kernels.positions import instance

        settings, accel, real = solver.settings, solver.accel, model.position_scalar
        x, x_inertial, dq, inv_mass, n = (state.particle_q, state.particle_q_inertial, state.particle_dq,
                                          model.inv_mass, model.particle_count)
        # Launched every substep: the kernel is resolved once here.
        if tethers_in_integrate(solver):
            kernel = instance(verlet_step_tethered, model.position_dtype)
            length = state.tether_length if state.tether_length is not None else model.tether_length
            tethers = [model.tether_pin, length]
            weights = []  # a pin's row says it is one
        else:
            kernel, tethers, weights = instance(verlet_step, model.position_dtype), [], [inv_mass]

        def run(state, dt: float) -> None:
            ratio = min(dt / state.dt_prev, settings.max_dt_ratio)
            # In the positions' type (accel is one too): a float32 factor would cost float64 its precision.
            velocity_scale = real(math.exp(-settings.damping * dt) * ratio)
            accel_offset = accel * real(dt * (dt + state.dt_prev) * 0.5)
            wp.launch(kernel, n, inputs=[x, x_inertial, dq, *weights, velocity_scale, accel_offset, *tethers])

        return BoundStage(run)

    def _bind_air(self, model, state, solver) -> BoundStage:
        """The step with the air's per-particle acceleration, gathered from the Aerodynamics stage's shares."""
        import warp as wp

        from warp_verlet.kernels.integrate import verlet_step_air
        from warp_verlet.kernels.positions import instance

        settings, accel, real, air = solver.settings, solver.accel, model.position_scalar, model.air
        kernel = instance(verlet_step_air, model.position_dtype)
        share = solver.scratch("air_share", air.face_params.shape[0], model.position_dtype)
        arrays = [state.particle_q, state.particle_q_inertial, state.particle_dq, model.inv_mass]

        def run(state, dt: float) -> None:
            ratio = min(dt / state.dt_prev, settings.max_dt_ratio)
            velocity_scale = real(math.exp(-settings.damping * dt) * ratio)
            factor = real(dt * (dt + state.dt_prev) * 0.5)
            wp.launch(kernel, model.particle_count, inputs=[*arrays, velocity_scale, accel * factor, share,
                                                            air.particle_face_start, air.particle_face, factor])

        return BoundStage(run)


FOLD_TETHERS_INTO_INTEGRATE = {"cpu": False, "cuda": True}
"""Per kind of device, whether the Verlet step runs the first sweep's tether pass where it may
(tethers_in_integrate). On a GPU that saves a launch a substep and a trip of the positions through memory; on the
CPU the pass apart, which runs a thread's whole piece in one loop, measured faster
(bench/results/grid_tiles/barriers-and-fold.md). The two agree bit for bit, which the tests check on the CPU too."""


def tethers_in_integrate(solver) -> bool:
    """Whether the Verlet step also runs the first sweep's tether pass (kernels/integrate.verlet_step_tethered,
    launched over the tether table's rows): on a device kind where FOLD_TETHERS_INTO_INTEGRATE says so, where the
    tether table's kind runs and its rows hold every particle (row i is then particle i), and where nothing runs
    between the step and the first sweep's tethers that reads or moves the positions (the air's forces, the global
    correction, a constraint kind's per-substep set-up such as the multilevel pass or the self-contact search)."""
    req, model = solver.req, solver.model
    if not (FOLD_TETHERS_INTO_INTEGRATE["cuda" if model.device.is_cuda else "cpu"] and req.free_particles
            and RELAX.needed(req) and not AERODYNAMICS.needed(req) and not GLOBAL.needed(req)
            and any(isinstance(c, Tethers) and c.needed(req) for c in constraint_kinds())
            and not any(c.reads_positions_before_sweeps and c.needed(req) for c in constraint_kinds())):
        return False
    table = model.tether_table
    return table.first == 0 and table.count == model.particle_count


class GlobalSolve:
    """The global correction (warp_verlet/core/global_solve.py): Gauss-Newton steps on the sticks with contact
    inside, between the prediction and the sweeps, when ``simulation.global_iterations`` > 0."""

    name = "global"

    def needed(self, req: Requirements) -> bool:
        return req.global_iterations > 0 and req.sticks > 0 and req.free_particles

    def device_bytes(self, req: Requirements) -> int:
        from .global_solve import device_bytes

        weights = 0 if req.tears else req.sticks * FLOAT  # a scene that tears lends the State's live weights
        friction = req.particles * VEC3 if req.collider_friction else 0  # each particle's pushes summed
        return (device_bytes(req.particles, req.sticks, req.global_levels) - req.sticks * FLOAT + weights
                + req.particles * (req.position_bytes - 3 * 8) + friction)

    def bind(self, model, state, solver) -> BoundStage:
        from .global_solve import GlobalCorrection

        correction = solver.cached("global", lambda: GlobalCorrection(model, solver.settings))
        pushes = noted_pushes(model, solver, "global")
        launches = [kind.bind(model, state, pushes) for kind, _ in model.colliders.kinds]
        place = [p for bound in launches for p in bound.before] if collider_placement(solver) == self.name else []
        return correction.bind(model, state, place, [task for bound in launches for task in bound.clamps],
                               lambda m: solver.scratch("stick_tension", m.stick_count, float), pushes)


class Relax:
    """``iterations`` sweeps; a sweep runs every constraint kind (warp_verlet/constraints/) that the scene needs, in
    table order (Gauss-Seidel across sets, and across colours inside a set). Before the sweeps, each set's
    per-substep work runs, in table order (the multilevel pass, a soft stick's tension reset)."""

    name = "relax"

    def needed(self, req: Requirements) -> bool:
        return req.iterations > 0 and any(c.needed(req) for c in constraint_kinds())

    def device_bytes(self, req: Requirements) -> int:
        return sum(c.device_bytes(req) for c in constraint_kinds() if c.needed(req))

    def bind(self, model, state, solver) -> BoundStage:
        kinds = [c for c in constraint_kinds() if c.needed(solver.req)]
        sets = [c.bind(model, state, solver) for c in kinds]
        phases = [phase for bound in sets for phase in bound.phases]
        # The phases of the first sweep: the sets' once-a-substep phases, then the sweep's, without the tether
        # pass where the Verlet step has run it.
        folded = tethers_in_integrate(solver)
        first = [phase for bound in sets for phase in bound.substep_phases or ()]
        first += [phase for c, bound in zip(kinds, sets) if not (folded and isinstance(c, Tethers))
                  for phase in bound.phases]
        before = [bound.run for bound in sets if bound.run is not None]  # per-substep set-up (dt, zeroing)
        replay_hooks = [bound.before_replay for bound in sets if bound.before_replay is not None]
        collide_first = ()
        places, every_sweep = collider_placement(solver) == self.name, contact_every_sweep(solver)
        launches = [kind.bind(model, state) for kind, _ in model.colliders.kinds] if places or every_sweep else []
        if places:
            # A clamp ends every sweep, or a kind clamps before the sweeps: the colliders are placed for this
            # substep before either.
            collide_first = [place for bound in launches for place in bound.before]
        if every_sweep:
            # A clamp is one launch over every particle, so the CPU thread team's member 0 runs it and the other
            # threads wait at its barrier; a phase still needs an entry per thread.
            idle = [None] * (solver.threads - 1)
            clamps = [[task, *idle] for bound in launches for task in bound.clamps]
            phases, first = phases + clamps, first + clamps
        iterations = solver.settings.iterations
        team = solver.team(first + phases * (iterations - 1), repeats=1) if first != phases else solver.team(phases)
        sweep = [task.run for phase in phases for task in phase if task is not None]
        first_sweep = [task.run for phase in first for task in phase if task is not None]

        def run(state, dt: float) -> None:
            for place in collide_first:
                place(dt)
            for prepare in before:
                prepare(state, dt)
            if team is not None:
                team.run()
                return
            for task in first_sweep:
                task()
            for _ in range(iterations - 1):
                for task in sweep:
                    task()

        def before_replay() -> None:
            for hook in replay_hooks:
                hook()

        return BoundStage(run, phases, before_replay if replay_hooks else None)


def collider_placement(solver) -> str:
    """The name of the first stage of a substep that clamps, which places the moving colliders for it."""
    req = solver.req
    if GLOBAL.needed(req) and req.colliders:
        return GLOBAL.name
    clamps_before_sweeps = (bool(req.colliders) and RELAX.needed(req)
                            and any(c.clamps_before_sweeps and c.needed(req) for c in constraint_kinds()))
    return RELAX.name if contact_every_sweep(solver) or clamps_before_sweeps else Collide.name


def contact_every_sweep(solver) -> bool:
    """Whether the collider clamp also ends every sweep (``contact_projection = "every_sweep"``, with colliders and
    sweeps): the clamp after the sweeps then still runs, once more, as the substep's last word."""
    return (solver.settings.contact_projection == "every_sweep" and bool(solver.req.colliders)
            and RELAX.needed(solver.req))


class Collide:
    """Collider clamping after the sweeps: every collider kind of the registry (warp_verlet/colliders) the scene
    has, in registry order (spheres first, planes last, so that a sphere resting on the ground cannot push
    cloth through the ground). Each kind's ``before`` (a moving sphere placed on the device clock) runs before
    any clamp."""

    name = "collide"

    def needed(self, req: Requirements) -> bool:
        return bool(req.colliders)

    def device_bytes(self, req: Requirements) -> int:
        from ..colliders import device_bytes

        return device_bytes(req.colliders)

    def bind(self, model, state, solver) -> BoundStage:
        bound = [kind.bind(model, state) for kind, _ in model.colliders.kinds]
        # An earlier stage that clamps (the global correction, the sweeps) places the colliders for the substep.
        before = ([prepare for launches in bound for prepare in launches.before]
                  if collider_placement(solver) == self.name else [])
        clamps = [task for launches in bound for task in launches.clamps]
        # On CPU threads each thread clamps its own run of particles, kind after kind (a clamp reads and writes its
        # particle alone, so the positions are those of one thread bit for bit). A kind that makes no clamp pieces
        # has its whole clamps run by the team's first thread while the others wait.
        team = None
        if solver.threads > 1:
            idle = [None] * (solver.threads - 1)
            phases = []
            for launches in bound:
                if launches.clamp_pieces:
                    phases += [split_tasks(make, 0, model.particle_count, solver.threads)
                               for make in launches.clamp_pieces]
                else:
                    phases += [[task, *idle] for task in launches.clamps]
            team = solver.team(phases, repeats=1)

        def run(state, dt: float) -> None:
            for prepare in before:
                prepare(dt)
            if team is not None:
                team.run()
                return
            for task in clamps:
                task.run()

        return BoundStage(run)


TENSION_AVERAGE_TIME = 0.01
"""s: the time constant over which a stick's force is averaged before it is compared with its tear force. The
force of one substep is the impulse its projections gave over dt, so a contact's jolt (a cloth landing on the
ground) lasts one substep and grows as dt shrinks; averaged over a fixed time it is the same at any substep
count, and a steady load is unchanged (docs/method.md, tearing, measures the choice)."""


class Tear:
    """Tearing after the clamping (kernels/tear.py): zeroes the State's weight of an overlong stick, and, where a
    cloth tears by tension, of a stick whose force, averaged over TENSION_AVERAGE_TIME, passed its tear force."""

    name = "tear"

    def needed(self, req: Requirements) -> bool:
        return req.tears

    def device_bytes(self, req: Requirements) -> int:
        # Per entry a tear length (Model) and a live weight (State); Jacobi has two entries per stick and keeps
        # their ends. Tearing by tension (coloured only) adds a tear force (Model) and an average force (State) per
        # stick, and, where no stick is soft, the tension the sweeps accumulate (solver scratch; soft sticks count
        # theirs in Sticks).
        if req.relaxation != "coloured":
            return req.sticks * 2 * (2 * FLOAT + VEC2I)
        by_tension = (2 * FLOAT + (0 if req.compliant else FLOAT)) if req.tension_tears else 0
        return req.sticks * (2 * FLOAT + by_tension)

    def bind(self, model, state, solver) -> BoundStage:
        from warp_verlet.kernels.tear import tear_sticks, tear_sticks_by_tension

        if not model.tension_tears:
            task = recorded(tear_sticks, model.tear_ends.shape[0],
                            [state.particle_q, model.tear_ends, model.tear_length],
                            [state.stick_weight, state.torn_entries])
            return BoundStage(lambda state, dt: task.run())
        tension = solver.scratch("stick_tension", model.stick_count, float)  # the sticks' sweeps fill it
        if not RELAX.needed(solver.req):
            tension.zero_()  # no sweeps (iterations = 0): nothing pulls, and nothing else writes it
        task = recorded(tear_sticks_by_tension, model.tear_ends.shape[0],
                        [state.particle_q, model.tear_ends, model.tear_length, tension, model.tear_force, 0.0, 0.0],
                        [state.stick_force, state.stick_weight, state.torn_entries])

        def run(state, dt: float) -> None:
            task.launch.set_param_by_name("inv_dt2", 1.0 / (dt * dt))
            task.launch.set_param_by_name("blend", -math.expm1(-dt / TENSION_AVERAGE_TIME))  # 1 - exp(-dt / tau)
            task.run()

        return BoundStage(run)


RELAX = Relax()
GLOBAL = GlobalSolve()
AERODYNAMICS = Aerodynamics()
STAGES = (AERODYNAMICS, Integrate(), GLOBAL, RELAX, Collide(), Tear())
"""The stages of a substep, in order."""


def particle_bytes(req: Requirements) -> int:
    """Every scene's per-particle arrays: the State's positions, prediction and increment (12 bytes each in
    float32, 24 in float64), the Model's inverse mass (float32 either way)."""
    return 3 * req.position_bytes + FLOAT


def device_bytes(req: Requirements) -> int:
    """The device memory a scene's arrays take: the sum of what its stages declare."""
    return req.particles * particle_bytes(req) + sum(s.device_bytes(req) for s in STAGES if s.needed(req))
