"""The global correction: Gauss-Newton steps on the sticks, with contact inside the operator, between the Verlet
prediction and the sweeps.

Why: a Gauss-Seidel sweep carries a correction about one stick per colour pass, so where nothing but contact
holds the cloth up (a drape) its hanging parts stretch in proportion to the grid's size, and tethers cannot
help (they need pins). A global step moves every particle at once towards the stick lengths, so the sweeps that
follow start from a nearly unstretched cloth and only make the final, exact projection.

Each substep, when ``simulation.global_iterations`` > 0:

1. the colliders clamp the prediction once (a moving collider is placed for the substep first); each particle
   they moved is *in contact*, with the direction of that move as its normal;
2. ``global_newton`` Gauss-Newton steps: the rigid sticks become springs of stiffness ``STIFFNESS`` x m / h^2
   (rigid to the step's resolution, yet well conditioned enough for a short conjugate-gradient run), a soft
   stick one of 1 / compliance, every contact a normal-only stiffness of ``CONTACT_SCALE`` x its particle's
   diagonal. ``global_iterations`` conjugate-gradient iterations, preconditioned by a multigrid V-cycle over the
   grid's levels (:func:`hierarchy`) or by the 3 x 3 diagonal blocks, solve H dx = -grad E
   (kernels/global_solve.py); a line search over ``LINE_SEARCH`` step lengths keeps the one of lowest energy,
   and the colliders clamp again, so no step leaves a particle inside;
3. each stick's tension is handed to the sweeps (``hand_over_tension``), which then run, with the clamp, as
   without the correction.

Everything is device work with fixed counts (no convergence test on the host), so a frame still replays from one
capture. The per-particle sums gather over a CSR table of incident sticks built here once, in a fixed order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..launches import FLOAT, INT, VEC2I, VEC3, BoundStage, clamp_noting_normals, recorded

STIFFNESS = 1.0e3
"""k h^2 / m of the sticks' springs: a stick yields 1e-3 of what a particle's inertia resists over a step. Stiffer
springs made the frictionless drape slide off its ball in every run (bench/results/global_solve.md)."""
CONTACT_SCALE = 1.0e2
"""A contact's normal stiffness, as a multiple of its particle's diagonal (mass and sticks): the step all but
cannot move a particle in contact along its normal (bench/results/global_solve.md compares 1, 10 and 100)."""
MAT33 = 36
REDUCTION_CHUNK = 256  # values one thread adds per level of a device sum
SMOOTHING_WEIGHT = 0.6  # damped Jacobi's weight in the multigrid cycle (2/3 is the classic choice for a Laplacian)
SMOOTHING_SWEEPS = 1  # Jacobi sweeps before and after the coarse correction, per level
LINE_SEARCH = 4  # step lengths tried after each Gauss-Newton solve (kernels/global_solve.py)
COARSEST_SWEEPS = 8  # Jacobi sweeps on the coarsest level (a few nodes: an approximate solve)


def incidence(ends: np.ndarray, particles: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR of each particle's sticks: (offsets[particles + 1], codes), code = 2 s + end (end 0: the particle is the
    stick's first end), sorted by particle then stick, so that every gather runs in one fixed order."""
    owner = ends.reshape(-1).astype(np.int64)  # entry 2 s + end belongs to particle ends[s, end]
    order = np.argsort(owner, kind="stable")
    counts = np.bincount(owner, minlength=particles)
    offsets = np.zeros(particles + 1, np.int32)
    np.cumsum(counts, out=offsets[1:])
    return offsets, order.astype(np.int32)


def reduction_sizes(particles: int) -> list[int]:
    """The lengths of a dot product's levels: one value per particle, then one per REDUCTION_CHUNK of the level
    before, down to one."""
    sizes = [particles]
    while sizes[-1] > 1:
        sizes.append(-(-sizes[-1] // REDUCTION_CHUNK))
    return sizes


def coarse_level_counts(grids: list[tuple[int, int]]) -> list[tuple[int, int, int]]:
    """(nodes, sticks, children) of each coarse level, finest first, for the grids (rows, cols) of a scene whose
    cloths are all grids, without building anything (the counts ``hierarchy`` builds)."""
    from ..constraints.multilevel import level_axes

    per_grid = []
    for rows, cols in grids:
        fine, counts = rows * cols, []
        for r, c in level_axes(rows, cols):
            nr, nc = len(r), len(c)
            counts.append((nr * nc, nr * (nc - 1) + (nr - 1) * nc + 2 * (nr - 1) * (nc - 1), fine - nr * nc))
            fine = nr * nc
        per_grid.append(counts)
    depth = max((len(c) for c in per_grid), default=0)
    return [tuple(sum(c[k][i] for c in per_grid if k < len(c)) for i in range(3)) for k in range(depth)]


def level_bytes(nodes: int, sticks: int, finer_nodes: int, children: int) -> int:
    """A coarse level's arrays: its sticks (global and local ends, rest, compliance, weight, direction, stretch,
    stiffness, two CSR entries), per node a CSR offset, pin flag, mass, contact block, inverse diagonal, three
    vectors and its family (itself and its children's four parents' shares), and the prolongation to the finer
    level (four parents and weights per finer node)."""
    per_stick = 2 * VEC2I + 5 * FLOAT + VEC3 + 2 * INT
    per_node = 2 * INT + INT + FLOAT + 2 * MAT33 + 3 * VEC3 + (INT + FLOAT)
    return (sticks * per_stick + nodes * per_node + 2 * INT + 4 * children * (INT + FLOAT)
            + finer_nodes * 4 * (INT + FLOAT))


def device_bytes(particles: int, sticks: int, levels: tuple[tuple[int, int, int], ...] = ()) -> int:
    """The correction's arrays in float64 positions: per stick its ends, rest length, compliance, weight (a scene that tears
    uses the State's), direction and stretch, and two CSR entries; per particle a CSR offset, the clamp's
    snapshot (a position), contact normal and stiffness, right-hand side, inverse diagonal block, the five
    conjugate-gradient vectors and the levels of its sums; five scalars."""
    per_stick = VEC2I + 3 * FLOAT + VEC3 + 2 * FLOAT + 2 * INT
    per_particle = INT + 3 * 8 + 5 * VEC3 + (FLOAT + 2 * MAT33 + 3 * VEC3)
    finer = [particles] + [nodes for nodes, _, _ in levels]
    return (sticks * per_stick + particles * per_particle + INT + 8 * sum(reduction_sizes(particles))
            + (6 + LINE_SEARCH) * 8
            + sum(level_bytes(nodes, count, above, children)
                  for (nodes, count, children), above in zip(levels, finer)))


@dataclass
class Level:
    """One level of the operator's hierarchy, on the host. Level 0 is the cloth (every particle, every stick);
    level l > 0 keeps every second row and column of level l - 1 (constraints/multilevel.py) with its coarse
    sticks. ``family`` (CSR by coarse node: fine index, weight) restricts from level l - 1; ``parents`` and
    ``weights`` (per node of level l - 1: four nodes of level l) prolong to it."""

    nodes: np.ndarray  # (n,) global particle of each node
    ends: np.ndarray  # (s, 2) the sticks' ends, global (for their directions)
    local_ends: np.ndarray  # (s, 2) the same, as nodes of this level
    rest: np.ndarray  # (s,) float32, m
    fixed: np.ndarray  # (n,) int32: 1 for a pin
    compliance: np.ndarray  # (s,) float32, m/N (0: rigid; coarse sticks are rigid)
    family_offsets: np.ndarray | None = None
    family: np.ndarray | None = None
    family_weight: np.ndarray | None = None
    finer_parents: np.ndarray | None = None  # (n of level l - 1, 4) int32
    finer_weights: np.ndarray | None = None  # (n of level l - 1, 4) float32


def hierarchy(model) -> list[Level]:
    """The levels for a scene whose cloths are all grids: level 0, then the coarse levels of the multilevel
    hierarchy, finest first. A scene with a mesh cloth gets level 0 alone (the Jacobi preconditioner)."""
    ends = np.asarray(model.host_sticks, np.int32)
    fixed = (model.host_inv_mass == 0).astype(np.int32)
    top = Level(np.arange(model.particle_count), ends, ends, np.asarray(model.host_rest, np.float32), fixed,
                np.asarray(model.host_compliance, np.float32))
    if not all(c.topology.is_grid for c in model.cloths):
        return [top]
    from ..constraints.multilevel import grid_hierarchy, merge_levels

    per_cloth = [grid_hierarchy(c.topology.rows, c.topology.cols, c.topology.positions, c.first) for c in model.cloths]
    levels = [top]
    for coarse in merge_levels(per_cloth)[::-1]:  # finest coarse level first
        finer = levels[-1]
        local = np.full(model.particle_count, -1, np.int64)
        keep = np.ones(model.particle_count, bool)
        keep[coarse.child] = False
        nodes = finer.nodes[keep[finer.nodes]]
        local[nodes] = np.arange(len(nodes))
        finer_local = np.full(model.particle_count, -1, np.int64)
        finer_local[finer.nodes] = np.arange(len(finer.nodes))
        # restriction: each coarse node gathers itself (weight 1) and every child it is a parent of
        rows = np.concatenate([local[nodes], local[coarse.parents.reshape(-1)]])
        cols = np.concatenate([finer_local[nodes], np.repeat(finer_local[coarse.child], 4)])
        vals = np.concatenate([np.ones(len(nodes), np.float32), coarse.weights.reshape(-1)])
        order = np.lexsort((cols, rows))
        offsets = np.zeros(len(nodes) + 1, np.int32)
        np.cumsum(np.bincount(rows, minlength=len(nodes)), out=offsets[1:])
        # prolongation: a kept node is its own parent; a child has its four
        parents = np.repeat(local[finer.nodes][:, None], 4, axis=1)
        weights = np.zeros((len(finer.nodes), 4), np.float32)
        weights[:, 0] = 1.0
        children = finer_local[coarse.child]
        parents[children] = local[coarse.parents]
        weights[children] = coarse.weights
        levels.append(Level(nodes, coarse.ends, local[coarse.ends].astype(np.int32), coarse.limit,
                            fixed[nodes], np.zeros(len(coarse.ends), np.float32), offsets, cols[order].astype(np.int32), vals[order].astype(np.float32),
                            parents.astype(np.int32), weights))
    return levels


class DeviceLevel:
    """A level's arrays on the device: its sticks and their incidence, and the per-node working set."""

    def __init__(self, level: Level, device):
        import warp as wp

        n, s = len(level.nodes), len(level.ends)
        self.count, self.stick_count = n, s
        offsets, codes = incidence(level.local_ends, n)
        self.ends = wp.array(level.ends, dtype=wp.vec2i, device=device)
        self.local_ends = self.ends if level.local_ends is level.ends else wp.array(level.local_ends, dtype=wp.vec2i,
                                                                                     device=device)
        self.rest = wp.array(level.rest, dtype=float, device=device)
        self.offsets = wp.array(offsets, dtype=int, device=device)
        self.incident = wp.array(codes, dtype=int, device=device)
        self.direction = wp.zeros(s, dtype=wp.vec3, device=device)
        self.residual = wp.zeros(s, dtype=float, device=device)
        self.stiffness = wp.zeros(s, dtype=float, device=device)
        self.compliance = wp.array(level.compliance, dtype=float, device=device)
        self.mass_h2 = wp.zeros(n, dtype=float, device=device)
        self.extra = wp.zeros(n, dtype=wp.mat33, device=device)
        self.diagonal_inverse = wp.zeros(n, dtype=wp.mat33, device=device)
        self.b, self.e, self.q = (wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(3))
        if level.family is not None:
            self.fixed = wp.array(level.fixed, dtype=int, device=device)
            self.family_offsets = wp.array(level.family_offsets, dtype=int, device=device)
            self.family = wp.array(level.family, dtype=int, device=device)
            self.family_weight = wp.array(level.family_weight, dtype=float, device=device)
            self.finer_parents = wp.array(level.finer_parents, dtype=wp.vec4i, device=device)
            self.finer_weights = wp.array(level.finer_weights, dtype=wp.vec4, device=device)
            self.ones = wp.ones(s, dtype=float, device=device)


class GlobalCorrection:
    """The arrays and launches of the correction for one model (bound per State by :meth:`bind`)."""

    def __init__(self, model, settings):
        import warp as wp

        device = model.device
        self.newton = settings.global_newton
        self.iterations = settings.global_iterations
        levels = hierarchy(model)
        if settings.global_preconditioner == "jacobi":
            levels = levels[:1]
        self.levels = [DeviceLevel(level, device) for level in levels]
        n = model.particle_count
        self.ones = wp.ones(len(levels[0].ends), dtype=float, device=device) if not model.tears else None
        self.contact, self.rhs, self.r, self.p, self.dx = (wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(5))
        self.x_before = wp.zeros(n, dtype=model.position_dtype, device=device)
        self.sums = [wp.zeros(size, dtype=wp.float64, device=device) for size in reduction_sizes(n)]
        self.scalars = wp.zeros(6 + LINE_SEARCH, dtype=wp.float64, device=device)

    def bind(self, model, state, place: list, clamps: list, tension_scratch, pushes) -> BoundStage:
        """The correction against ``state``: ``place`` are the colliders' placements for the substep (run first),
        ``clamps`` their clamp launches (bound with ``pushes``: launches.clamp_noting_normals),
        ``tension_scratch(model)`` the soft sticks' XPBD tension it starts."""
        from warp_verlet.kernels import global_solve as k

        n = model.particle_count
        top = self.levels[0]
        x, x_inertial = state.particle_q, state.particle_q_inertial
        weight = state.stick_weight if model.tears else self.ones
        rigid = []  # the launches that set each stick's stiffness, from the rigid one that follows dt
        with_inv_h2 = []  # the launches that read 1 / dt^2

        def sticks(level, stick_weight):
            task = recorded(k.stick_directions, level.stick_count, [x, level.ends, level.rest, stick_weight,
                                                                    level.compliance, 0.0],
                            [level.direction, level.residual, level.stiffness])
            rigid.append(task)
            return task

        def operator(level, p, q):
            return recorded(k.level_operator, level.count, [p, level.mass_h2, level.extra, level.stiffness,
                                                            level.offsets, level.incident, level.local_ends,
                                                            level.rest, level.direction, level.residual], [q])

        set_up = [sticks(top, weight)]
        assemble = recorded(k.assemble, n, [x, x_inertial, model.inv_mass, 0.0, top.stiffness, CONTACT_SCALE,
                                            top.offsets,
                                            top.incident, top.rest, top.direction, top.residual, self.contact],
                            [self.rhs, top.mass_h2, top.extra])
        set_up.append(assemble)
        for finer, level in zip(self.levels, self.levels[1:]):
            set_up += [sticks(level, level.ones),
                       recorded(k.restrict_level, level.count, [finer.mass_h2, finer.extra, level.family_offsets,
                                                                level.family, level.family_weight, level.fixed],
                                [level.mass_h2, level.extra])]
        for level in self.levels:
            set_up.append(recorded(k.level_diagonal, level.count,
                                   [level.mass_h2, level.extra, level.stiffness, level.offsets, level.incident,
                                    level.rest, level.direction, level.residual], [level.diagonal_inverse]))

        def v_cycle(depth: int, b, e) -> list:
            """e = V(b) from level ``depth`` down: damped Jacobi before and after, the coarse level between."""
            level = self.levels[depth]
            last = depth == len(self.levels) - 1
            omega = 1.0 if len(self.levels) == 1 else SMOOTHING_WEIGHT
            work = [recorded(k.smooth_start, level.count, [b, level.diagonal_inverse, omega], [e])]
            sweeps = (COARSEST_SWEEPS if len(self.levels) > 1 else 1) if last else SMOOTHING_SWEEPS
            for _ in range(sweeps - 1):
                work += [operator(level, e, level.q),
                         recorded(k.smooth, level.count, [b, level.q, level.diagonal_inverse, omega], [e])]
            if last:
                return work
            coarse = self.levels[depth + 1]
            work += [operator(level, e, level.q),
                     recorded(k.restrict_residual, coarse.count, [b, level.q, coarse.family_offsets, coarse.family,
                                                                 coarse.family_weight, coarse.mass_h2], [coarse.b]),
                     *v_cycle(depth + 1, coarse.b, coarse.e),
                     recorded(k.prolong_add, level.count, [coarse.e, coarse.finer_parents, coarse.finer_weights,
                                                           level.mass_h2], [e])]
            for _ in range(SMOOTHING_SWEEPS):
                work += [operator(level, e, level.q),
                         recorded(k.smooth, level.count, [b, level.q, level.diagonal_inverse, omega], [e])]
            return work

        def finish_sum() -> list:
            """The levels of the sum of sums[0], into sums[-1][0]."""
            return [recorded(k.sum_chunks, self.sums[i + 1].shape[0],
                             [self.sums[i], self.sums[i].shape[0], REDUCTION_CHUNK], [self.sums[i + 1]])
                    for i in range(len(self.sums) - 1)]

        def finish(stage: int) -> list:
            """The sum of sums[0], then the scalars it sets."""
            return finish_sum() + [recorded(k.cg_scalars, 1, [self.sums[-1], stage], [self.scalars])]

        z = top.e  # the preconditioned residual: level 0's V-cycle output
        precondition = v_cycle(0, self.r, z)
        r_dot_z = [recorded(k.dot_values, n, [self.r, z], [self.sums[0]])]
        cg_operator = [operator(top, self.p, top.q), recorded(k.dot_values, n, [self.p, top.q], [self.sums[0]])]
        start = [recorded(k.cg_start, n, [self.rhs], [self.r, self.dx]), *precondition, *r_dot_z, *finish(0),
                 recorded(k.cg_direction, n, [self.scalars, z], [self.p])]
        iteration = [*cg_operator, *finish(1), recorded(k.cg_advance, n, [self.scalars, self.p, top.q],
                                                         [self.dx, self.r]),
                     *precondition, *r_dot_z, *finish(2), recorded(k.cg_direction, n, [self.scalars, z], [self.p])]
        # A line search over LINE_SEARCH step lengths: the step is Newton's on a model of E, and where the cloth is
        # crumpled (slack sticks, whose true stiffness across is negative) the full step can overshoot.
        search = []
        for candidate in range(k.LINE_SEARCH):
            step_length = 0.0 if candidate == k.LINE_SEARCH - 1 else 1.0 / (1 << candidate)
            energy = recorded(k.candidate_energy, n, [x, x_inertial, self.dx, step_length, model.inv_mass, 0.0,
                                                      self.contact, top.offsets, top.incident, top.local_ends,
                                                      top.rest, top.stiffness], [self.sums[0]])
            with_inv_h2.append(energy)
            search += [energy, *finish_sum(), recorded(k.keep_energy, 1, [self.sums[-1], candidate], [self.scalars])]
        search.append(recorded(k.choose_step, 1, [], [self.scalars]))
        correct = recorded(k.apply_correction, n, [x, self.dx, self.scalars])
        step = [*set_up, *start, *(iteration * self.iterations), *search, correct, *clamps]
        hand_over = None
        if model.compliant or model.tension_tears:  # explicit sticks, each with its tension in the sweeps
            tension = tension_scratch(model)
            hand_over = recorded(k.hand_over_tension, top.stick_count, [x, top.ends, top.rest, top.stiffness, 0.0],
                                 [tension])
        clamp_prediction = clamp_noting_normals(x, clamps, self.x_before, self.contact, pushes)
        mean_mass = float(np.mean(1.0 / model.host_inv_mass[model.host_inv_mass > 0]))

        def run(state, dt: float) -> None:
            inv_h2 = 1.0 / (dt * dt)
            for task in [assemble, *with_inv_h2]:
                task.launch.set_param_by_name("inv_h2", inv_h2)
            for task in rigid:
                task.launch.set_param_by_name("rigid", STIFFNESS * mean_mass * inv_h2)
            for prepare in place:
                prepare(dt)
            for task in clamp_prediction:
                task.run()
            for _ in range(self.newton):
                for task in step:
                    task.run()
            if hand_over is not None:
                hand_over.launch.set_param_by_name("h2", dt * dt)
                hand_over.run()

        return BoundStage(run)
