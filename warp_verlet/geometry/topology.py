"""Cloths as flat numpy arrays: particles, sticks, faces, UVs and inverse masses, from a grid or a mesh.

A mesh cloth's sticks come from its faces (warp_verlet/geometry/mesh_cloth.py); the rest of this docstring is about grids.

A grid is ``rows x cols`` particles in row-major order (particle ``r * cols + c``). Row 0 lies at the
``origin``; columns run along +X and rows run along -Y (``vertical``) or +Z (``horizontal``).

Stick families, each built only when the cloth lists it in ``sticks``:

- structural: (r, c)-(r, c+1) and (r, c)-(r+1, c)
- shear:      (r, c)-(r+1, c+1) and (r, c+1)-(r+1, c)
- bend:       (r, c)-(r, c+2) and (r, c)-(r+2, c)

Each stick also records its *grid class* (which of the six directions above it is) and its anchor
(r, c). :mod:`warp_verlet.geometry.colouring` uses those for the analytic 12-colour grid colouring.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .faces import Faces, grid_faces
from .mesh_cloth import BEND, SHEAR, STRUCTURAL, particle_masses, stick_families

# Grid classes (stick directions).
STRUCT_H, STRUCT_V, SHEAR_DIAG, SHEAR_ANTI, BEND_H, BEND_V = range(6)
CLASS_ORDER = (STRUCT_H, STRUCT_V, SHEAR_DIAG, SHEAR_ANTI, BEND_H, BEND_V)
SWEEP_ORDER = CLASS_ORDER
"""The order in which a sweep projects a grid's stick classes (geometry/colouring.grid_colouring numbers the colours
so, and the implicit grid sticks follow it): structural, shear, bend. The longest sticks first (bend, shear,
structural) was measured too: it left the benchmark's hanging sheet, whose bend sticks are rigid, about 30% less
stretched at the same cost, but on the shipped scenes it won on some and lost on others (2.6 times the stretch
where a ball tears through a net), and no other order of the three families won everywhere
(bench/results/colour_order.md; bench.colour_order runs the comparison)."""
FAMILY_OF_CLASS = ("structural", "structural", "shear", "shear", "bend", "bend")
FAMILY_CODE_OF_CLASS = np.array([STRUCTURAL, STRUCTURAL, SHEAR, SHEAR, BEND, BEND], np.int8)
FAMILY_NAMES = ("structural", "shear", "bend")  # by family code


@dataclass
class ClothTopology:
    """One cloth's static data on the host. Index arrays are local to this cloth.

    The simulation works on particles; the cache is written per *vertex*: a grid's vertices are its
    particles, a mesh's are the source mesh's own (``vertex_particle`` maps them, None when they are the
    particles), with the faces and UVs as the source has them."""

    name: str
    positions: np.ndarray  # (N, 3) float32, metres
    inv_mass: np.ndarray  # (N,) float32, 1/kg; 0 for pinned particles
    sticks: np.ndarray  # (M, 2) int32 particle indices
    rest_length: np.ndarray  # (M,) float32, metres
    compliance: np.ndarray  # (M,) float32, m/N (XPBD): 0 for a rigid stick
    family: np.ndarray  # (M,) int8: STRUCTURAL, SHEAR or BEND
    faces: Faces  # in particle indices, counter-clockwise seen from the front (+Z for vertical); none for a rope
    uvs: np.ndarray | None  # per vertex (V, 2) or per face corner; float32; None: no UVs
    pinned: np.ndarray  # (P,) int32 indices of pinned particles
    rows: int | None = None  # a grid's shape; None for a mesh
    cols: int | None = None
    grid_class: np.ndarray | None = None  # (M,) int8, one of the six classes above; None for a mesh
    anchor: np.ndarray | None = None  # (M, 2) int32 (row, col) of the stick's first particle; None for a mesh
    vertex_particle: np.ndarray | None = None  # (V,) int32: the particle each cache vertex shows; None: identity
    vertex_faces: Faces | None = None  # the faces in vertex indices when they differ from ``faces``
    uv_interpolation: str = "vertex"  # "vertex" or "faceVarying"
    left_handed: bool = False  # the source's faces wind clockwise seen from the front

    @property
    def particle_count(self) -> int:
        return len(self.positions)

    @property
    def is_grid(self) -> bool:
        return self.grid_class is not None

    @property
    def vertex_count(self) -> int:
        return self.particle_count if self.vertex_particle is None else len(self.vertex_particle)

    @property
    def cache_faces(self) -> Faces:
        """The faces as the cache writes them, in vertex indices."""
        return self.faces if self.vertex_faces is None else self.vertex_faces

    def cache_points(self, particles: np.ndarray) -> np.ndarray:
        """This cloth's vertices from its particles' positions: the particles themselves, or a gather."""
        return particles if self.vertex_particle is None else particles[self.vertex_particle]

    @property
    def families(self) -> tuple[str, ...]:
        return tuple(FAMILY_NAMES[c] for c in np.unique(self.family))


def grid_positions(spec) -> np.ndarray:
    rows, cols = spec.resolution
    height, width = spec.size
    # A 1-particle axis has no spacing; linspace(0, s, 1) gives [0] as wanted.
    down = np.linspace(0.0, height, rows) if rows > 1 else np.zeros(1)
    across = np.linspace(0.0, width, cols) if cols > 1 else np.zeros(1)
    r, c = np.meshgrid(down, across, indexing="ij")
    pos = np.zeros((rows, cols, 3), dtype=np.float64)
    pos[..., 0] = c
    if spec.orientation == "vertical":
        pos[..., 1] = -r
    else:
        pos[..., 2] = r
    pos += np.asarray(spec.origin, dtype=np.float64)
    return pos.reshape(-1, 3).astype(np.float32)


def _stick_block(rows: int, cols: int, dr: int, dc: int, grid_class: int):
    """All sticks (r, c) -> (r + dr, c + dc) that fit inside the grid, or None if none fit."""
    r_range = np.arange(rows - dr)
    c_range = np.arange(max(0, -dc), cols - max(0, dc))
    if r_range.size == 0 or c_range.size == 0:
        return None
    r, c = (g.ravel() for g in np.meshgrid(r_range, c_range, indexing="ij"))
    ends = np.stack([r * cols + c, (r + dr) * cols + (c + dc)], axis=1)
    return ends, np.full(r.shape, grid_class, np.int8), np.stack([r, c], axis=1)


def stick_count(spec) -> int:
    """The number of sticks :func:`build_cloth` makes for a cloth, without building it (a mesh's are
    counted from its faces)."""
    if spec.mesh is not None:
        return len(stick_families(spec.mesh.mesh, spec.sticks)[0])
    r, c = spec.resolution
    per_family = {
        "structural": r * (c - 1) + (r - 1) * c,
        "shear": 2 * (r - 1) * (c - 1),
        "bend": r * max(c - 2, 0) + max(r - 2, 0) * c,
    }
    return sum(per_family[family] for family in spec.sticks)


def build_cloth(spec) -> ClothTopology:
    if spec.mesh is not None:
        return build_mesh_cloth(spec)
    rows, cols = spec.resolution
    positions = grid_positions(spec)
    n = rows * cols

    # (dr, dc, class) per stick direction, grouped by family.
    directions = {
        "structural": [(0, 1, STRUCT_H), (1, 0, STRUCT_V)],
        "shear": [(1, 1, SHEAR_DIAG), (1, -1, SHEAR_ANTI)],
        "bend": [(0, 2, BEND_H), (2, 0, BEND_V)],
    }
    blocks, compliance = [], []
    for family in spec.sticks:
        for dr, dc, cls in directions[family]:
            block = _stick_block(rows, cols, dr, dc, cls)
            if block is not None:
                blocks.append(block)
                compliance.append(np.full(len(block[0]), spec.compliance.get(family, 0.0), np.float32))
    if blocks:
        sticks = np.concatenate([b[0] for b in blocks]).astype(np.int32)
        grid_class = np.concatenate([b[1] for b in blocks])
        anchor = np.concatenate([b[2] for b in blocks]).astype(np.int32)
        compliance_arr = np.concatenate(compliance)
    else:
        sticks = np.zeros((0, 2), np.int32)
        grid_class = np.zeros(0, np.int8)
        anchor = np.zeros((0, 2), np.int32)
        compliance_arr = np.zeros(0, np.float32)
    # Rest lengths from the float64 layout, so that every stick of one direction has the same length.
    pos64 = positions.astype(np.float64)
    rest = np.linalg.norm(pos64[sticks[:, 1]] - pos64[sticks[:, 0]], axis=1).astype(np.float32)

    inv_mass = np.full(n, n / spec.mass, dtype=np.float32)  # uniform: each particle carries mass/n
    for r, c, kg in spec.particle_masses:  # then the scene's per-particle overrides
        inv_mass[r * cols + c] = 1.0 / kg
    pinned = np.array([r * cols + c for r, c in spec.pins], dtype=np.int32)
    inv_mass[pinned] = 0.0

    # (r,c) -> (r+1,c) -> (r+1,c+1) -> (r,c+1): counter-clockwise seen from +Z for a vertical cloth (rows run
    # down -Y, columns along +X), so the front face looks at +Z. A rope has no surface: no faces.
    faces = grid_faces(rows, cols)
    u = np.arange(cols) / max(cols - 1, 1)
    v = 1.0 - np.arange(rows) / max(rows - 1, 1)
    uu, vv = np.meshgrid(u, v, indexing="xy")
    uvs = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float32)

    return ClothTopology(
        name=spec.name, rows=rows, cols=cols, positions=positions, inv_mass=inv_mass, sticks=sticks,
        rest_length=rest, compliance=compliance_arr, family=FAMILY_CODE_OF_CLASS[grid_class], grid_class=grid_class,
        anchor=anchor, faces=faces, uvs=uvs, pinned=pinned,
    )


def build_mesh_cloth(spec) -> ClothTopology:
    """A mesh cloth's topology: particles from the welded vertices, sticks from the faces."""
    mesh_spec = spec.mesh
    mesh, source = mesh_spec.mesh, mesh_spec.mesh.source
    positions = mesh.particle_points.astype(np.float32)
    sticks, family = stick_families(mesh, spec.sticks)
    compliance = np.array([spec.compliance.get(f, 0.0) for f in FAMILY_NAMES], np.float32)[family]
    # Rest lengths from the float32 positions in float64, as for a grid: the same points give the same lengths.
    pos64 = positions.astype(np.float64)
    rest = np.linalg.norm(pos64[sticks[:, 1]] - pos64[sticks[:, 0]], axis=1).astype(np.float32)
    mass = particle_masses(mesh, spec.mass, mesh_spec.mass_distribution)
    for particle, kg in mesh_spec.particle_masses:
        mass[particle] = kg
    inv_mass = (1.0 / mass).astype(np.float32)
    pinned = np.asarray(mesh_spec.pins, np.int32)
    inv_mass[pinned] = 0.0
    return ClothTopology(
        name=spec.name, positions=positions, inv_mass=inv_mass, sticks=sticks, rest_length=rest,
        compliance=compliance, family=family, faces=mesh.faces, uvs=source.uvs, pinned=pinned,
        vertex_particle=mesh.particle_of_vertex if mesh.welded else None,
        vertex_faces=source.faces if mesh.welded else None,
        uv_interpolation=source.uv_interpolation or "vertex", left_handed=source.left_handed,
    )
