"""Self-collision and cloth–cloth contact: ``self_collision = true`` on a cloth gives each of its particles a
``collision_thickness``, and no two such particles (of the same cloth or of any two cloths that both ask for it)
come closer than the thickness, unless they were that close in the rest pose.

Particles are spheres of diameter ``collision_thickness`` (Macklin, Müller, Chentanez and Kim 2014, "Unified
Particle Physics for Real-Time Applications"; Müller's self-collision demo): a pair closer than its thickness
(the mean of its two particles') is pushed apart along its separation, each particle by its share of the
inverse mass. Pairs of one cloth whose REST distance is under ``REST_EXCLUSION`` × the thickness never collide:
that excludes the topological neighbours (structural sticks at one spacing apart, and diagonals where the
thickness reaches them) without a table, so that a cloth at rest is not in contact with itself.

The colliding particles are every particle of the cloths that ask for it, or with ``self_collision_stride`` k a
grid's every k-th row and column (and its last) or a mesh's spread subset (``spread_subset``): they stand for the
cloth between them, so the thickness may reach k spacings, and everything below runs over them alone.

Each substep (``run``) rebuilds a ``wp.HashGrid`` of the colliding particles with cells of ``GRID_CELL`` × the query
radius (``QUERY_REACH`` × the largest thickness); then (``substep_phases``, divided over the CPU's relaxation
threads) each particle lists its candidate pairs, those within ``QUERY_REACH`` × their thickness (at most
``MAX_CANDIDATES``). Both are redone every substep because at the shipped speeds a particle moves up to about a
thickness per substep, so a list kept for longer would miss new pairs (a list kept while the cloth moves less
than a skin was measured slower on a GPU: bench/results/self_contact.md).
Each sweep then (``phases``) gathers, per particle, the pushes of its candidates closer than the thickness, from
the same old positions, into a scratch buffer (their average: Jacobi, as the Jacobi sticks do in
kernels/relax.py) and copies the buffer back in a second launch: no atomics on positions, so the result is
bit-for-bit repeatable on every device.

Friction (``self_friction_coefficient`` μ_k, ``self_static_friction_coefficient`` μ_s) is the colliders' Coulomb law
at the position level, on the pair's relative motion over the substep: a pair pushed apart by d_n whose relative
tangential move is under μ_s d_n sticks (the move is removed), otherwise the move is shortened by μ_k d_n; each
particle takes its inverse-mass share, as of the push. A pair uses the mean of its two particles' coefficients.

A thickness is at most the cloth's rest spacing (a grid's ``size / (n - 1)``, the smaller of its two axes; a
mesh's median edge): above it, the rest neighbours that never collide (within ``REST_EXCLUSION`` × the
thickness) reach past the nearest ring of particles, so a tight fold could pass through itself there. The
default, ``DEFAULT_FRACTION`` × the spacing, stays above half a grid square's diagonal (0.71 × the spacing), so
that a particle cannot slip between the four particles of a square of another layer.
"""

from __future__ import annotations

import math

import numpy as np

from .kind import ConstraintSet
from ..launches import FLOAT, INT, VEC3, BoundStage, copy_back_phase, recorded, split_tasks
from ..scene_keys import Key, boolean, integer, real

DEFAULT_FRACTION = 0.8
"""The default thickness as a fraction of the cloth's rest spacing."""
REST_EXCLUSION = 1.5
"""Pairs of one cloth closer than this × their thickness in the rest pose never collide."""
QUERY_REACH = 1.25
"""Candidates are the pairs within this × their thickness at the start of a substep (and the hash grid's query
radius this × the largest thickness): they are found once per substep and checked in each of its sweeps,
so the margin covers what the sweeps move a pair together after the search."""
MAX_CANDIDATES = 12
"""Candidate pairs kept per particle and substep, the first found in the grid's order (a fixed order, so which
ones is repeatable). Particles at least a thickness apart fit about 12 around one within 1.25 × the thickness
(a dense packing); a particle between two layers of a fold has 2 to 8."""
MESH_SUBSET_RADIUS = 0.7
"""On a mesh with ``self_collision_stride`` k, the colliding particles are at least this × k median edges apart and
every particle lies within that of one (``spread_subset``): under the default thickness, 0.8 k edges, so a
particle of another layer cannot pass between them, as on a grid, whose stride leaves holes of half a square's
diagonal, 0.71 k spacings."""
GRID_CELL = 2.0
"""The hash grid's cell, as a multiple of the query radius: a query then visits 2 × 2 × 2 cells instead of the
3 × 3 × 3 of a cell the radius's size. Fewer, fuller cells take fewer turns of the query's loop, whose
instructions and divergence are what the search spends its time on (bench/results/self_contact.md)."""
THIN_AXIS_CELLS = 8
"""Cells along an axis where the cloths are flat at rest: room for the layers of a fold or a pile."""
CELLS_PER_PARTICLE = 8
"""The hash grid's cells at most, per particle (above 4096 cells): its cell table costs 8 bytes a cell."""

SELF_COLLISION = Key(
    "self_collision", boolean, False, type="boolean", default_text="`false`",
    doc="Particle contact: no two particles of the cloth come closer than `collision_thickness`, unless they were "
        "that close at rest (within 1.5 × the thickness: the nearest neighbours). Cloths that all ask for it also "
        "collide with each other. Costs a hash grid rebuilt every substep and a pass per sweep.")
COLLISION_THICKNESS = Key(
    "collision_thickness", real(0.0, None, lo_open=True), None, type="number", unit="m",
    default_text="absent: 0.8 × the collision spacing", allowed="> 0, at most the collision spacing",
    doc="The contact distance of `self_collision` (each colliding particle a sphere of this diameter; a pair of two "
        "cloths uses the mean of theirs). The collision spacing is the rest spacing (a grid's `size / (n - 1)`, the "
        "smaller of its two axes, or a mesh's median edge) times `self_collision_stride`. Keep a particle's move "
        "per substep under half of it, or a fast layer can pass through another between two substeps (the run "
        "summary warns where colliding particles approached each other faster). Only with `self_collision = true`.")
SELF_COLLISION_STRIDE = Key(
    "self_collision_stride", integer(1), None, type="integer", unit="particles", default_text="`1`",
    allowed="≥ 1; on a grid, less than its rows and columns",
    doc="Every how many particles along a grid's rows and columns one takes part in `self_collision` (and its last "
        "row and column): 2 collides a quarter of them, 3 a ninth; on a mesh, particles about 0.7 × this many "
        "median edges apart. The colliding particles stand for the cloth between them, so the thickness may reach "
        "`self_collision_stride` times the rest spacing: a fine cloth can then collide with a thickness of a few of "
        "its spacings, at a fraction of the search's cost. Only with `self_collision = true`.")

SELF_FRICTION_COEFFICIENT = Key(
    "self_friction_coefficient", real(0.0), None, type="number", default_text="`0`", allowed="≥ 0",
    doc="Coulomb's kinetic friction coefficient μ_k of `self_collision`, on the relative motion of two particles in "
        "contact: a sliding pair's relative move along the contact in a substep is shortened by μ_k times the "
        "distance the contact pushed them apart, so a cloth sliding on another that lies on the ground stops from "
        "v after v² / (2 μ_k g), whatever the substeps. A pair of two cloths uses the mean of theirs. "
        "Only with `self_collision = true`.")
SELF_STATIC_FRICTION_COEFFICIENT = Key(
    "self_static_friction_coefficient", real(0.0), None, type="number",
    default_text="`self_friction_coefficient`", allowed="≥ 0; at least `self_friction_coefficient`",
    doc="Coulomb's static friction coefficient μ_s of `self_collision`: a pair whose relative move along the "
        "contact in a substep is under μ_s times the distance the contact pushed them apart stops moving relative "
        "to each other. Only with `self_collision = true`.")


def friction_of(spec) -> tuple[float, float]:
    """The cloth's self-contact Coulomb coefficients (μ_k, μ_s), as the gather takes them; (0, 0) without."""
    kinetic = spec.options.get(SELF_FRICTION_COEFFICIENT.name) or 0.0
    static = spec.options.get(SELF_STATIC_FRICTION_COEFFICIENT.name)
    return kinetic, kinetic if static is None else static


def rest_spacing(spec) -> float | None:
    """The cloth's rest spacing in metres: a grid's ``size / (n - 1)`` over the axes with two particles or more
    (the smaller), a mesh's median edge; None for a single particle."""
    if spec.mesh is not None:
        mesh = spec.mesh.mesh
        if len(mesh.faces) == 0:
            return None
        pairs, _ = mesh.faces.sides()
        edges = np.unique(np.sort(pairs, axis=1), axis=0)
        edges = edges[edges[:, 0] != edges[:, 1]]
        if not len(edges):
            return None
        points = mesh.particle_points
        return float(np.median(np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)))
    steps = [size / (n - 1) for n, size in zip(spec.resolution, spec.size) if n > 1]
    return min(steps) if steps else None


def thickness_of(spec) -> float | None:
    """The cloth's resolved collision thickness (m), or None where it does not collide."""
    return spec.options.get(COLLISION_THICKNESS.name) if spec.options.get(SELF_COLLISION.name) else None


def stride_of(spec) -> int:
    """Every how many particles along a grid's rows and columns one collides (1: all of them)."""
    return spec.options.get(SELF_COLLISION_STRIDE.name) or 1


def strided(n: int, stride: int) -> np.ndarray:
    """Every ``stride``-th of ``n`` indices, and always the last, so that the cloth's edge collides."""
    kept = np.arange(0, n, stride)
    return kept if kept[-1] == n - 1 else np.r_[kept, n - 1]


def colliding_particles(spec) -> np.ndarray:
    """The cloth's colliding particles, as its own (scene-order) indices, ascending: all of them; with a stride k
    on a grid, the particles of every k-th row and column (and the last); on a mesh, a subset about
    MESH_SUBSET_RADIUS × k median edges apart (``spread_subset``)."""
    stride = stride_of(spec)
    if stride == 1:
        return np.arange(spec.particle_count)
    if spec.mesh is not None:
        return _mesh_subset(spec.mesh.mesh.particle_points, MESH_SUBSET_RADIUS * stride * rest_spacing(spec))
    rows, cols = spec.resolution
    return (strided(rows, stride)[:, None] * cols + strided(cols, stride)[None, :]).ravel()


_MESH_SUBSETS: list[tuple[np.ndarray, float, np.ndarray]] = []
"""The last few mesh subsets (points, radius, subset): the memory estimate and the Model ask for the same one, and a
large mesh's takes seconds."""


def _mesh_subset(points: np.ndarray, radius: float) -> np.ndarray:
    for held, r, subset in _MESH_SUBSETS:
        if held is points and r == radius:
            return subset
    subset = spread_subset(points, radius)
    subset.flags.writeable = False  # shared by every caller
    _MESH_SUBSETS[:] = [(points, radius, subset), *_MESH_SUBSETS[:3]]
    return subset


def colliding_count(spec) -> int:
    """How many of the cloth's particles collide (0 without self_collision), before the Model is built."""
    if not spec.options.get(SELF_COLLISION.name):
        return 0
    return spec.particle_count if stride_of(spec) == 1 else len(colliding_particles(spec))


def spread_subset(points: np.ndarray, radius: float) -> np.ndarray:
    """Indices of ``points`` no two of which are closer than ``radius``, such that every point lies within
    ``radius`` of one of them (a Poisson-disk subset, greedy, offered in Morton order of the points: a fixed
    order, so the subset is repeatable). Ascending."""
    from ..geometry.particle_order import morton_codes

    cell_of = [tuple(c) for c in np.floor(points / radius).astype(np.int64).tolist()]
    xyz = points.tolist()
    taken: dict[tuple[int, int, int], list[int]] = {}
    for i in np.argsort(morton_codes(points), kind="stable").tolist():
        if not _within(xyz, i, taken, cell_of[i], radius * radius):
            taken.setdefault(cell_of[i], []).append(i)
    return np.sort(np.fromiter((i for kept in taken.values() for i in kept), np.int64))


def _within(xyz: list, i: int, taken: dict, cell: tuple[int, int, int], r2: float) -> bool:
    """Whether point i is closer than sqrt(r2) to a point already taken, in its cell or the 26 around it."""
    x, y, z = xyz[i]
    cx, cy, cz = cell
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                for j in taken.get((cx + dx, cy + dy, cz + dz), ()):
                    px, py, pz = xyz[j]
                    if (x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2 < r2:
                        return True
    return False


def hash_grid_dims(lo: np.ndarray, hi: np.ndarray, cell: float, particles: int) -> tuple[int, int, int]:
    """Cells per axis of the hash grid over the colliding cloths' rest box [lo, hi]: the box in cells (a cell
    per point of a sheet, so that a flat cloth's cells do not wrap onto each other), THIN_AXIS_CELLS on an axis
    the cloths are flat along, halved on the largest axis while above CELLS_PER_PARTICLE per particle. Only the
    speed depends on it: a position outside the box wraps onto a cell inside, and the query checks distances."""
    dims = [max(1, math.ceil(float(e) / cell)) for e in np.asarray(hi) - np.asarray(lo)]
    dims = [max(d, THIN_AXIS_CELLS) for d in dims]
    budget = max(CELLS_PER_PARTICLE * particles, 4096)
    while math.prod(dims) > budget:
        largest = int(np.argmax(dims))
        dims[largest] = math.ceil(dims[largest] / 2)
    return tuple(dims)


def hash_grid_bytes(particles: int, cells: int) -> int:
    """Bytes Warp's hash grid allocates natively (outside any wp.array; warp/native/hashgrid.cpp and .cu, Warp
    1.19): a cell and a point index per point, each for 1.5 × the points (its reserve's slack) and doubled for
    its radix sort's second buffer, and a start and an end per cell. A CUDA sort's temporary space is not in it."""
    return particles * 6 * INT + cells * 2 * INT


def _colliding(scene) -> list:
    return [c for c in scene.cloths if c.options.get(SELF_COLLISION.name)]


def _rest_box(spec) -> tuple[np.ndarray, np.ndarray]:
    """A cloth's rest bounding box, from its grid's size or its mesh's points (without building it)."""
    from ..geometry.topology import grid_positions

    points = spec.mesh.mesh.particle_points if spec.mesh is not None else grid_positions(spec)
    return points.min(axis=0), points.max(axis=0)


class ContactData:
    """The contact's device data, per colliding particle (M of them, in the Model's particle order): ``particle``
    (M,) int32 (its index in the Model), ``thickness`` (M,) float32 m, ``rest`` (M,) vec3 float32 m (rest
    position), ``cloth`` (M,) int32 (its cloth's index) and ``friction`` (M,) vec2 float32 (its cloth's
    self-contact (μ_k, μ_s)); ``every_particle`` where the M are all the Model's particles (then the search reads
    the positions themselves, not a gathered copy); and for the hash grid, ``radius`` (m, the query radius),
    ``cell`` (m, its cell) and ``dims``. The candidates, rewritten each substep, are the solver's scratch."""

    def __init__(self, model, scene, device):
        import warp as wp

        particle, thickness, cloth, friction = [], [], [], []
        for k, (slot, spec) in enumerate(zip(model.cloths, scene.cloths)):
            h = thickness_of(spec)
            if h is None:
                continue
            # In the device's order (a mesh's particles may be renumbered there), ascending.
            mine = np.sort(model.device_particles(slot.first + colliding_particles(spec)))
            particle.append(mine)
            thickness.append(np.full(len(mine), h, np.float32))
            cloth.append(np.full(len(mine), k, np.int32))
            friction.append(np.tile(np.asarray(friction_of(spec), np.float32), (len(mine), 1)))
        particle = np.concatenate(particle)  # ascending: the cloths' slots follow each other
        self.count = len(particle)
        self.every_particle = self.count == model.particle_count
        self.radius = QUERY_REACH * float(max(t.max() for t in thickness))
        self.cell = GRID_CELL * self.radius
        self.dims = scene_grid_dims(scene)
        self.particle = wp.array(particle.astype(np.int32), dtype=int, device=device)
        self.thickness = wp.array(np.concatenate(thickness), dtype=float, device=device)
        self.rest = wp.array(model.rest_positions[particle].astype(np.float32), dtype=wp.vec3, device=device)
        self.cloth = wp.array(np.concatenate(cloth), dtype=int, device=device)
        self.friction = wp.array(np.concatenate(friction), dtype=wp.vec2, device=device)


def scene_grid_dims(scene) -> tuple[int, int, int]:
    """The hash grid's cells per axis for ``scene`` (from its counts and rest boxes, before anything is built)."""
    cloths = _colliding(scene)
    boxes = [_rest_box(c) for c in cloths]
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    cell = GRID_CELL * QUERY_REACH * max(thickness_of(c) for c in cloths)
    return hash_grid_dims(lo, hi, cell, sum(colliding_count(c) for c in cloths))


class SelfContact(ConstraintSet):
    """Particle–particle contact of the cloths with ``self_collision`` (kernels/self_contact.py): a hash grid
    rebuilt each substep, then in each sweep a Jacobi gather of the pushes and a copy back."""

    name = "self contact"
    reads_positions_before_sweeps = True
    cloth_keys = (SELF_COLLISION, COLLISION_THICKNESS, SELF_COLLISION_STRIDE, SELF_FRICTION_COEFFICIENT,
                  SELF_STATIC_FRICTION_COEFFICIENT)

    def capturable(self, device) -> bool:
        return True  # on CUDA with ``bind``'s before_replay

    def check_cloth(self, spec, table):
        given = spec.options.get(COLLISION_THICKNESS.name)
        if not spec.options.get(SELF_COLLISION.name):
            for key, what in ((COLLISION_THICKNESS, "a collision thickness"),
                              (SELF_COLLISION_STRIDE, "a self-collision stride"),
                              (SELF_FRICTION_COEFFICIENT, "a self-contact friction coefficient"),
                              (SELF_STATIC_FRICTION_COEFFICIENT, "a self-contact friction coefficient")):
                if spec.options.get(key.name) is not None:
                    raise table.error(key.name, f"{what} needs self_collision = true on the same cloth")
            return None
        kinetic = spec.options.get(SELF_FRICTION_COEFFICIENT.name) or 0.0
        static = spec.options.get(SELF_STATIC_FRICTION_COEFFICIENT.name)
        if static is not None and static < kinetic:
            raise table.error(SELF_STATIC_FRICTION_COEFFICIENT.name,
                              f"must be at least self_friction_coefficient ({kinetic:g}): a pair that slides is held "
                              f"at most as hard as one at rest; got {static:g}")
        spacing = rest_spacing(spec)
        if spacing is None:
            raise table.error(SELF_COLLISION.name, "self-collision needs a cloth of two particles or more")
        stride = stride_of(spec)
        if stride > 1 and spec.mesh is None and stride >= min(spec.resolution):
            raise table.error(SELF_COLLISION_STRIDE.name,
                              f"expected less than the cloth's {min(spec.resolution)} particles along its shorter "
                              f"side, got {stride}")
        spacing *= stride
        what = "the cloth's rest spacing" if stride == 1 else f"{stride} × the cloth's rest spacing"
        if given is None:
            return {COLLISION_THICKNESS.name: DEFAULT_FRACTION * spacing}
        if given > spacing:
            raise table.error(COLLISION_THICKNESS.name,
                              f"expected at most {what}, {spacing:.6g} m, got {given:g} m: a thicker cloth's "
                              f"colliding neighbours that never collide (within {REST_EXCLUSION} × the thickness at "
                              "rest) reach past the nearest ones, so a tight fold could pass through itself")
        return None

    def count(self, scene):
        """(the particles that collide, the hash grid's cells, whether every particle of the scene collides),
        or 0."""
        colliding = sum(colliding_count(c) for c in _colliding(scene))
        if not colliding:
            return 0
        return colliding, math.prod(scene_grid_dims(scene)), int(colliding == scene.particle_count)

    def needed(self, req) -> bool:
        return bool(req.count(self.name))

    def device_bytes(self, req) -> int:
        # per colliding particle: its index, thickness, rest position, cloth, friction (μ_k, μ_s) (Model); a
        # scratch position, the candidates and their count, and unless every particle collides the positions the
        # search reads (solver); the hash grid
        colliding, cells, every_particle = req.count(self.name)
        search_positions = 0 if every_particle else req.position_bytes
        per_particle = (INT + FLOAT + VEC3 + INT + 2 * FLOAT + req.position_bytes + (MAX_CANDIDATES + 1) * INT
                        + search_positions)
        return colliding * per_particle + hash_grid_bytes(colliding, cells)

    def build(self, model, scene, device):
        return ContactData(model, scene, device)

    def bind(self, model, state, solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.self_contact import (contact_candidates, contact_gather, gather_positions,
                                                      scatter_positions)

        data, x = model.constraints[self.name], state.particle_q
        n = data.count
        real = model.position_scalar
        scratch = solver.scratch("contact_positions", n, model.position_dtype)
        candidate = solver.scratch("contact_candidates", n * MAX_CANDIDATES, int)
        candidate_count = solver.scratch("contact_candidate_count", n, int)
        # The positions the grid holds and the search reads: the particles' own where every one collides, else
        # the colliding ones' gathered each substep.
        searched = x if data.every_particle else solver.scratch("contact_search_positions", n, model.position_dtype)
        collect = None if data.every_particle else recorded(gather_positions, n, [x, data.particle], [searched])
        grid = wp.HashGrid(*data.dims, device=model.device, dtype=real)
        grid.reserve(n)
        cell = data.cell

        def find(f, count):
            return recorded(contact_candidates, count, [wp.uint64(grid.id), searched, data.thickness, data.rest,
                                                        data.cloth, REST_EXCLUSION, QUERY_REACH, real(data.radius),
                                                        MAX_CANDIDATES, f], [candidate, candidate_count])

        def build_grid(state, dt: float) -> None:
            if collect is not None:
                collect.run()
            grid.build(searched, cell)

        def gather(f, count):
            return recorded(contact_gather, count, [x, model.inv_mass, data.particle, data.thickness, candidate,
                                                    candidate_count, MAX_CANDIDATES, state.particle_q_inertial,
                                                    state.particle_dq, data.friction, f, scratch])

        def scatter(f, count):
            return recorded(scatter_positions, count, [scratch, data.particle, f], [x])

        def point_descriptor_at_this_grid() -> None:
            # Warp's CUDA HashGrid.build ends by copying the grid's descriptor to the device from one static host
            # variable per dtype, which a captured build records by address; at replay the copy reads whatever grid
            # was built last in the process (a second simulator's, a measuring grid's), and the search would walk
            # that grid. A build of this one, just before each replay, leaves its own descriptor there.
            grid.build(searched, cell)

        write_back = (copy_back_phase(x, scratch, n, solver.threads) if data.every_particle
                      else split_tasks(scatter, 0, n, solver.threads))
        # ``build_grid`` holds the grid, which the recorded launches read by its id only. The search, a query per
        # particle, divides over the CPU's relaxation threads as the gather does.
        return BoundStage(build_grid, [split_tasks(gather, 0, n, solver.threads), write_back],
                          point_descriptor_at_this_grid if model.device.is_cuda else None,
                          substep_phases=[split_tasks(find, 0, n, solver.threads)])
