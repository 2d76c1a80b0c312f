"""The global correction: Gauss-Newton steps on the sticks, with contact inside the operator, between the Verlet
prediction and the sweeps.

Why: a Gauss-Seidel sweep carries a correction about one stick per colour pass, so where nothing but contact
holds the cloth up (a drape) its hanging parts stretch in proportion to the grid's size, and tethers cannot
help (they need pins). A global step moves every particle at once towards the stick lengths, so the sweeps that
follow start from a nearly unstretched cloth and only make the final, exact projection.

Each substep, when ``simulation.global_iterations`` > 0:

1. the colliders clamp the prediction once (a moving collider is placed for the substep first); each particle
   they moved is *in contact*, with the direction of that move as its normal;
2. ``global_newton`` Gauss-Newton steps: the sticks become springs of stiffness ``STIFFNESS`` x m / h^2 (rigid to
   the step's resolution, yet well conditioned enough for a short conjugate-gradient run), every contact a
   normal-only penalty of ``CONTACT_SCALE`` x its particle's diagonal, and ``global_iterations`` iterations of
   conjugate gradients preconditioned by the 3 x 3 diagonal blocks solve H dx = -grad E
   (kernels/global_solve.py). After each step the colliders clamp again, so no step leaves a particle inside;
3. the sweeps and the clamp then run as without it.

Everything is device work with fixed counts (no convergence test on the host), so a frame still replays from one
capture. The per-particle sums gather over a CSR table of incident sticks built here once, in a fixed order.
"""

from __future__ import annotations

import numpy as np

from ..launches import FLOAT, INT, VEC2I, VEC3, BoundStage, recorded

STIFFNESS = 1.0e3
"""k h^2 / m of the sticks' springs: a stick yields 1e-3 of what a particle's inertia resists over a step. Stiffer
springs need more conjugate-gradient iterations for the same step (bench/results/global_solve.md)."""
CONTACT_SCALE = 1.0
"""A contact's normal stiffness, as a multiple of its particle's diagonal (mass and sticks). Far stiffer contacts
make the truncated solve throw the cloth off the collider (bench/results/global_solve.md)."""
MAT33 = 36
REDUCTION_CHUNK = 256  # values one thread adds per level of a device sum


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


def device_bytes(particles: int, sticks: int) -> int:
    """The correction's arrays in float64 positions: per stick its ends, rest length, weight (a scene that tears
    uses the State's), direction and stretch, and two CSR entries; per particle a CSR offset, the clamp's
    snapshot (a position), contact normal and stiffness, right-hand side, inverse diagonal block, the five
    conjugate-gradient vectors and the levels of its sums; five scalars."""
    per_stick = VEC2I + 2 * FLOAT + VEC3 + FLOAT + 2 * INT
    per_particle = INT + 3 * 8 + 7 * VEC3 + MAT33 + FLOAT
    return sticks * per_stick + particles * per_particle + INT + 8 * sum(reduction_sizes(particles)) + 5 * 8


class GlobalCorrection:
    """The arrays and launches of the correction for one model (bound per State by :meth:`bind`)."""

    def __init__(self, model, settings):
        import warp as wp

        device = model.device
        self.model = model
        self.newton = settings.global_newton
        self.iterations = settings.global_iterations
        ends = np.asarray(model.host_sticks, np.int32)
        offsets, codes = incidence(ends, model.particle_count)
        self.stick_count = len(ends)
        self.ends = wp.array(ends, dtype=wp.vec2i, device=device)
        self.rest = wp.array(np.asarray(model.host_rest, np.float32), dtype=float, device=device)
        self.offsets = wp.array(offsets, dtype=int, device=device)
        self.incident = wp.array(codes, dtype=int, device=device)
        self.ones = wp.ones(len(ends), dtype=float, device=device) if not model.tears else None
        n, s = model.particle_count, len(ends)
        self.direction = wp.zeros(s, dtype=wp.vec3, device=device)
        self.residual = wp.zeros(s, dtype=float, device=device)
        vec = lambda: wp.zeros(n, dtype=wp.vec3, device=device)  # noqa: E731
        self.contact, self.rhs, self.r, self.z, self.p, self.q, self.dx = (vec() for _ in range(7))
        self.diagonal_inverse = wp.zeros(n, dtype=wp.mat33, device=device)
        self.contact_stiffness = wp.zeros(n, dtype=float, device=device)
        self.x_before = wp.zeros(n, dtype=model.position_dtype, device=device)
        sizes = reduction_sizes(n)
        self.sums = [wp.zeros(size, dtype=wp.float64, device=device) for size in sizes]
        self.scalars = wp.zeros(5, dtype=wp.float64, device=device)

    def bind(self, model, state, place: list, clamps: list) -> BoundStage:
        """The correction against ``state``: ``place`` are the colliders' placements for the substep (run first),
        ``clamps`` their clamp launches."""
        import warp as wp

        from warp_verlet.kernels import global_solve as k

        n, s = model.particle_count, self.stick_count
        x, x_inertial = state.particle_q, state.particle_q_inertial
        weight = state.stick_weight if model.tears else self.ones
        directions = recorded(k.stick_directions, s, [x, self.ends, self.rest, weight], [self.direction, self.residual])
        snapshot = recorded(k.contact_normals, n, [x, self.x_before], [self.contact])
        assemble = recorded(k.assemble, n, [x, x_inertial, model.inv_mass, 0.0, 0.0, CONTACT_SCALE, self.offsets,
                                            self.incident, self.rest, self.direction, self.residual, self.contact],
                            [self.rhs, self.diagonal_inverse, self.contact_stiffness])
        chunk, threads = 1, n  # one particle per thread; its share of a dot product is summed level by level
        cg = (self.offsets, self.incident, self.ends, self.rest, self.direction, self.residual, self.contact,
              self.contact_stiffness)
        start = recorded(k.cg_start, threads, [self.rhs, self.diagonal_inverse, n, chunk],
                         [self.r, self.z, self.p, self.dx, self.sums[0]])
        operator = recorded(k.cg_operator, threads, [self.p, model.inv_mass, 0.0, 0.0, *cg, n, chunk],
                            [self.q, self.sums[0]])
        advance = recorded(k.cg_advance, threads, [self.scalars, self.p, self.q, self.diagonal_inverse, n, chunk],
                           [self.dx, self.r, self.z, self.sums[0]])
        direction = recorded(k.cg_direction, n, [self.scalars, self.z], [self.p])

        def finish(stage: int) -> list:
            """The levels of the sum of sums[0], then the scalars it sets."""
            levels = [recorded(k.sum_chunks, self.sums[level + 1].shape[0],
                               [self.sums[level], self.sums[level].shape[0], REDUCTION_CHUNK], [self.sums[level + 1]])
                      for level in range(len(self.sums) - 1)]
            return levels + [recorded(k.cg_scalars, 1, [self.sums[-1], stage], [self.scalars])]

        correct = recorded(k.apply_correction, n, [x, self.dx])
        iteration = [operator, *finish(1), advance, *finish(2), direction]
        step = [directions, assemble, start, *finish(0), *(iteration * self.iterations), correct, *clamps]
        mean_mass = float(np.mean(1.0 / model.host_inv_mass[model.host_inv_mass > 0]))

        def run(state, dt: float) -> None:
            inv_h2 = 1.0 / (dt * dt)
            stiffness = STIFFNESS * mean_mass * inv_h2
            for launch in (assemble, operator):
                launch.launch.set_param_by_name("inv_h2", inv_h2)
                launch.launch.set_param_by_name("stiffness", stiffness)
            for prepare in place:
                prepare(dt)
            wp.copy(self.x_before, x)
            for clamp in clamps:
                clamp.run()
            snapshot.run()
            for _ in range(self.newton):
                for task in step:
                    task.run()

        return BoundStage(run)
