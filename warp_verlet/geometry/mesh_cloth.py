"""Cloth from any polygon mesh: welding, the checks a simulation needs, and the stick families from the faces.

A mesh as read (``mesh_io.SourceMesh``) keeps its own vertices, faces and UVs: the cache is written with them,
point for point, so it lines up with the source. The simulation runs on *particles*: vertices closer than
the weld distance (UV seams, split normals and duplicated borders put several vertices at one place) become
one particle, and every vertex follows its particle. Without duplicates, particle i is vertex i.

Stick families, built from the faces in particle indices (each only when the cloth lists it in ``sticks``):

- structural: every face side (an edge of the mesh), once;
- bend: across each interior edge (p, q) with exactly two faces A and B, one stick per end: p's other
  neighbour in A to p's other neighbour in B, and the same for q. On two triangles both ends name the two
  vertices opposite the edge, so that is one stick; on two quads it is the pair of skip-one sticks through
  p and through q, the grid's bend sticks;
- shear: the two diagonals of each quad face (a triangle has none).

A pair already joined by an earlier family is not joined again. Sticks are stored (low, high) and sorted, so
that the set does not depend on the face order.

This module uses numpy only (no warp, no pxr, no trimesh).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import WarpVerletError
from .faces import Faces, edge_keys, next_corner, side_table

# The default weld distance, as a fraction of the mesh's bounding-box diagonal: far below any edge a cloth
# simulation can use, far above float32 rounding of coordinates written by a DCC.
WELD_FRACTION = 1e-6
# A face whose area is below this fraction of its longest side squared is degenerate (collinear corners).
DEGENERATE_AREA_FRACTION = 1e-7
MASS_DISTRIBUTIONS = ("area", "even")

STRUCTURAL, SHEAR, BEND = 0, 1, 2  # family codes, in STICK_FAMILIES order
FAMILY_CODE = {"structural": STRUCTURAL, "shear": SHEAR, "bend": BEND}


class MeshError(WarpVerletError, ValueError):
    """A mesh cannot be used as cloth; the message says which face, edge or vertex and why."""


class NonManifoldWarning(UserWarning):
    """A mesh has edges shared by more than two faces: it is simulated, but no bend stick crosses them."""


@dataclass(frozen=True)
class SourceMesh:
    """A mesh as read from its file, in the scene's frame (metres, the scene's axes), before welding."""

    description: str  # the file, and the prim for USD, for messages
    file: Path  # the file it was read from
    points: np.ndarray  # (V, 3) float64, m
    faces: Faces  # as read: triangles, quads, n-gons, in source vertex indices
    uvs: np.ndarray | None = None  # (V, 2) for "vertex", (sum(counts), 2) for "faceVarying"; None: no UVs
    uv_interpolation: str | None = None  # "vertex" or "faceVarying"
    left_handed: bool = False  # USD orientation "leftHanded": faces wind clockwise seen from the front
    prim_path: str | None = None  # the USD prim the mesh came from (None for other formats)
    to_local: np.ndarray | None = None  # (4, 4) float64: scene-frame points back to the prim's own space
    named_vertices: dict | None = None  # (kind, name) -> vertex indices, for pins by primvar or subset
    # Every other file the source composes (a USD file's sublayers, references and payloads, recursively): a run's
    # output may not be one of them (output_file.input_files finds them here).
    dependencies: tuple[Path, ...] = ()


@dataclass(frozen=True, eq=False)
class ClothMesh:
    """A source mesh welded and checked, ready for the topology: host arrays, never changed."""

    source: SourceMesh
    particle_of_vertex: np.ndarray  # (V,) int32: the particle each source vertex follows
    particle_points: np.ndarray  # (P,) x 3 float64, m: each particle at its first vertex's position
    faces: Faces  # the source faces in particle indices (same face order)
    weld_distance: float  # m
    non_manifold_edges: int  # edges with more than two faces (no bend stick crosses them)
    # stick_families' answers by family tuple: the scene's counts (stages.Requirements) and the topology ask for the
    # same sticks, seconds of work at 1024^2, so they are built once per mesh.
    _sticks: dict = field(default_factory=dict, repr=False)

    @property
    def particle_count(self) -> int:
        return len(self.particle_points)

    @property
    def vertex_count(self) -> int:
        return len(self.source.points)

    @property
    def welded(self) -> bool:
        """Did welding merge any vertices? (If not, particle i is vertex i and the cache needs no gather.)"""
        return self.particle_count != self.vertex_count

    def particles_of(self, vertices: np.ndarray) -> np.ndarray:
        """The sorted distinct particles of some source vertices."""
        return np.unique(self.particle_of_vertex[np.asarray(vertices, np.int64)]).astype(np.int32)

    def particles_in_box(self, lo, hi) -> np.ndarray:
        """The particles whose rest position lies in the axis-aligned box [lo, hi] (bounds included)."""
        p = self.particle_points
        inside = ((p >= np.asarray(lo)) & (p <= np.asarray(hi))).all(axis=1)
        return np.flatnonzero(inside).astype(np.int32)


def connected_labels(particle_count: int, sticks: np.ndarray) -> np.ndarray:
    """Label of each particle's connected component through ``sticks`` (the lowest particle index in it):
    label propagation with pointer jumping, vectorised."""
    labels = np.arange(particle_count, dtype=np.int64)
    if len(sticks) == 0:
        return labels
    a, b = sticks[:, 0].astype(np.int64), sticks[:, 1].astype(np.int64)
    while True:
        low = np.minimum(labels[a], labels[b])
        before = labels.copy()
        np.minimum.at(labels, a, low)
        np.minimum.at(labels, b, low)
        labels = labels[labels]  # jump to the label's own label: halves the remaining path each round
        if np.array_equal(labels, before):
            return labels


def default_weld_distance(points: np.ndarray) -> float:
    if len(points) == 0:
        return 0.0
    return WELD_FRACTION * float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


# Bytes one candidate pair of the close-pair search takes at its peak: two int64 indices, the two points
# gathered (float64 x 3 each), their difference and its norm, with numpy's temporaries.
WELD_PAIR_BYTES = 128


def weld(points: np.ndarray, distance: float, what: str = "the mesh") -> np.ndarray:
    """The particle of each point: points within ``distance`` of each other (directly or through a chain of
    such points) share one. Particles are numbered in order of their first point, so with no duplicates
    particle i is point i.

    Coincident points are one particle whatever the distance, so they are collapsed first: a pile of k copies
    (stacked triangles, duplicated borders) costs one point instead of k (k - 1) / 2 comparisons. The rest go
    through :func:`_close_pairs`, which refuses (MeshError, naming ``what``) a search that cannot fit in memory."""
    points = np.asarray(points, np.float64)
    n = len(points)
    if n < 2:
        return np.zeros(n, np.int32)
    distinct, inverse = np.unique(points, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    component = connected_labels(len(distinct), _close_pairs(distinct, distance, what))[inverse]
    # Number the particles in order of their lowest point index, as if no point had been collapsed.
    lowest = np.full(len(distinct), n, np.int64)
    np.minimum.at(lowest, component, np.arange(n))
    _, particle = np.unique(lowest[component], return_inverse=True)
    return particle.reshape(-1).astype(np.int32)


def _close_pairs(points: np.ndarray, distance: float, what: str) -> np.ndarray:
    """(P, 2) pairs of points within ``distance`` of each other, enough to connect every such chain.

    Points within ``distance`` lie in one cell of side 2 x distance in at least one of the 8 grids shifted
    by 0 or half a cell along each axis (on each axis the two grids' cell borders alternate half a cell
    apart, so a gap shorter than half a cell crosses at most one of them). Each grid's cells are grouped by
    sorting, and only points sharing a cell are compared: k points in one cell make k (k - 1) / 2 candidate
    pairs, counted before any is made, so a dense cluster is refused before it exhausts the memory."""
    n = len(points)
    if distance <= 0.0:
        shifts = [np.zeros(3)]
        cells_of = lambda shift: points  # noqa: E731 - exact duplicates only: group equal coordinates
    else:
        cell = 2.0 * distance
        origin = points.min(axis=0)
        shifts = [np.array([(k >> a) & 1 for a in range(3)], np.float64) * 0.5 for k in range(8)]
        cells_of = lambda shift: np.floor((points - origin) / cell + shift)  # noqa: E731
    groups = []
    for shift in shifts:
        cells = cells_of(shift)
        order = np.lexsort(cells.T[::-1])
        sorted_cells = cells[order]
        new = np.ones(n, bool)
        new[1:] = (sorted_cells[1:] != sorted_cells[:-1]).any(axis=1)
        start = np.flatnonzero(new)
        size = np.diff(np.append(start, n))
        groups.append((order, start, size))
    candidates = sum(int((size * (size - 1) // 2).sum()) for _, _, size in groups)
    _check_weld_fits(candidates, max(int(size.max()) for _, _, size in groups), distance, what)
    pairs = []
    for order, start, size in groups:
        for k in np.unique(size[size > 1]):  # groups of k points: all k (k - 1) / 2 pairs at once
            members = order[start[size == k][:, None] + np.arange(k)]
            a, b = np.triu_indices(k, 1)
            pairs.append(np.stack([members[:, a].ravel(), members[:, b].ravel()], axis=1))
    if not pairs:
        return np.zeros((0, 2), np.int64)
    pairs = np.concatenate(pairs)
    close = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1) <= distance
    return pairs[close]


def _check_weld_fits(candidates: int, largest_group: int, distance: float, what: str) -> None:
    """Refuse a close-pair search whose candidate pairs would take more than half the available host memory
    (as memory.check_fits does for a run's arrays), or 8 GiB where that is unknown."""
    from ..machine import available_host_bytes, gib

    available = available_host_bytes()
    budget = available // 2 if available is not None else 8 * 2**30
    need = candidates * WELD_PAIR_BYTES
    if need > budget:
        raise MeshError(f"{what}: {largest_group} distinct vertices lie in one cell of {2 * distance:.3g} m (twice "
                        f"the weld distance): welding would compare {candidates} pairs of vertices, about "
                        f"{gib(need)}, more than the {gib(budget)} it may take here; lower weld_distance "
                        "or remove the crowded vertices")


def _vector_areas(points: np.ndarray, faces: Faces) -> np.ndarray:
    """(F, 3) Newell vector area of each face (half the sum of corner cross products): its length is the
    area of a planar polygon and its direction the face normal."""
    corner = points[faces.indices]
    following = points[faces.indices[next_corner(faces.counts)]]
    cross = np.cross(corner, following)
    face = np.repeat(np.arange(len(faces)), faces.counts)
    out = np.zeros((len(faces), 3))
    np.add.at(out, face, cross)
    return 0.5 * out


def prepare(source: SourceMesh, weld_distance: float | None = None) -> ClothMesh:
    """Weld ``source`` and check that it can be simulated as cloth; raises MeshError naming the problem and
    warns (NonManifoldWarning) about edges shared by more than two faces."""
    what = source.description
    points, faces = source.points, source.faces
    if len(points) == 0 or len(faces) == 0:
        raise MeshError(f"{what}: the mesh is empty ({len(points)} vertices, {len(faces)} faces); a cloth needs "
                        "faces (for a rope, use a grid with one row)")
    try:
        faces.validate(len(points), what)
    except ValueError as exc:
        raise MeshError(str(exc)) from None
    if not np.isfinite(points).all():
        bad = int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])
        shown = ", ".join(f"{float(v):g}" for v in points[bad])  # plain numbers, not numpy reprs
        raise MeshError(f"{what}: vertex {bad} is not a finite point: ({shown})")
    unused = np.setdiff1d(np.arange(len(points)), faces.indices)
    if len(unused):
        raise MeshError(f"{what}: vertex {int(unused[0])} is used by no face ({len(unused)} such vertices); a "
                        "loose vertex would fall on its own: remove it from the mesh")

    distance = default_weld_distance(points) if weld_distance is None else float(weld_distance)
    particle_of_vertex = weld(points, distance, what)
    _, first_vertex = np.unique(particle_of_vertex, return_index=True)  # each particle's lowest vertex
    particle_points = points[first_vertex]
    welded_faces = Faces(faces.counts, particle_of_vertex[faces.indices])

    # A side whose two corners are one particle has zero length: listed twice, or welded together.
    pairs, face_of_side = welded_faces.sides()
    short = np.flatnonzero(pairs[:, 0] == pairs[:, 1])
    if len(short):
        s = int(short[0])
        f = int(face_of_side[s])
        corners = faces.indices[faces.offsets[f]:faces.offsets[f + 1]]
        raise MeshError(f"{what}: face {f} (vertices {corners.tolist()}) has a zero-length edge: two of its "
                        f"corners are closer than the weld distance {distance:.3g} m ({len(short)} such edges); "
                        "remove the degenerate faces or lower weld_distance")
    area = np.linalg.norm(_vector_areas(particle_points, welded_faces), axis=1)
    side = np.linalg.norm(particle_points[pairs[:, 1]] - particle_points[pairs[:, 0]], axis=1)
    longest = np.zeros(len(faces))
    np.maximum.at(longest, face_of_side, side)
    flat = np.flatnonzero(area <= DEGENERATE_AREA_FRACTION * longest ** 2)
    if len(flat):
        f = int(flat[0])
        corners = faces.indices[faces.offsets[f]:faces.offsets[f + 1]]
        raise MeshError(f"{what}: face {f} (vertices {corners.tolist()}) is degenerate: its area "
                        f"{area[f]:.3g} m^2 is nothing beside its longest side {longest[f]:.3g} m (collinear "
                        f"corners; {len(flat)} such faces)")

    counts = side_table(welded_faces, particle_points.shape[0])[2]  # faces beside each distinct edge
    crowded = int((counts > 2).sum())
    if crowded:
        edges = "1 edge is" if crowded == 1 else f"{crowded} edges are"
        warnings.warn(f"{what}: {edges} shared by more than two faces (a non-manifold mesh); it is simulated, but "
                      "no bend stick crosses those edges", NonManifoldWarning, stacklevel=2)
    return ClothMesh(source=source, particle_of_vertex=particle_of_vertex, particle_points=particle_points,
                     faces=welded_faces, weld_distance=distance, non_manifold_edges=crowded)


def _unique_pairs(pairs: np.ndarray, base: int, exclude: np.ndarray | None = None) -> np.ndarray:
    """Distinct undirected pairs as sorted (low, high) rows, in key order, without self-pairs and without the
    keys in ``exclude``."""
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    keys = np.unique(edge_keys(pairs, base))
    if exclude is not None and len(exclude):
        keys = keys[~np.isin(keys, exclude)]
    return np.stack([keys // base, keys % base], axis=1).astype(np.int32)


def stick_families(mesh: ClothMesh, families: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The sticks of the listed families, in particle indices: ((M, 2) int32 (low, high), (M,) int8 family
    code), family after family in STICK_FAMILIES order. Built once per mesh and families; read-only."""
    if families not in mesh._sticks:
        sticks, family = _build_stick_families(mesh, families)
        sticks.flags.writeable = family.flags.writeable = False
        mesh._sticks[families] = (sticks, family)
    return mesh._sticks[families]


def _build_stick_families(mesh: ClothMesh, families: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    faces = mesh.faces
    base = mesh.particle_count
    pairs, face_of_side = faces.sides()
    structural = _unique_pairs(pairs, base)
    blocks = {"structural": structural}
    taken = edge_keys(structural, base)
    if "shear" in families:
        quads = np.flatnonzero(faces.counts == 4)
        corners = faces.indices[faces.offsets[quads][:, None] + np.arange(4)]
        diagonals = np.concatenate([corners[:, [0, 2]], corners[:, [1, 3]]]) if len(quads) else np.zeros((0, 2), np.int32)
        blocks["shear"] = _unique_pairs(diagonals, base, taken)
        taken = np.concatenate([taken, edge_keys(blocks["shear"], base)])
    if "bend" in families:
        blocks["bend"] = _unique_pairs(_bend_pairs(faces, pairs, face_of_side, base), base, taken)
    chosen = [f for f in ("structural", "shear", "bend") if f in families]
    sticks = np.concatenate([blocks[f] for f in chosen]).astype(np.int32)
    family = np.concatenate([np.full(len(blocks[f]), FAMILY_CODE[f], np.int8) for f in chosen])
    return sticks, family


def _bend_pairs(faces: Faces, pairs: np.ndarray, face_of_side: np.ndarray, base: int) -> np.ndarray:
    """For every interior edge (exactly two faces), the pairs (p's other neighbour in A, in B) and the same
    for q, as described in the module docstring."""
    n_corners = len(faces.indices)
    after = next_corner(faces.counts)
    before = np.empty(n_corners, np.int64)
    before[after] = np.arange(n_corners)
    # Side s runs from corner s to corner after[s]: its first end's other neighbour is the corner before s,
    # its second end's is the corner after after[s].
    first_other = faces.indices[before]
    second_other = faces.indices[after[after]]
    lo_first = pairs[:, 0] < pairs[:, 1]
    other_of_lo = np.where(lo_first, first_other, second_other)
    other_of_hi = np.where(lo_first, second_other, first_other)
    keys = edge_keys(pairs, base)
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    new = np.ones(len(keys), bool)
    new[1:] = keys[1:] != keys[:-1]
    start = np.flatnonzero(new)
    count = np.diff(np.append(start, len(keys)))
    two = start[count == 2]
    a, b = order[two], order[two + 1]
    return np.concatenate([np.stack([other_of_lo[a], other_of_lo[b]], axis=1),
                           np.stack([other_of_hi[a], other_of_hi[b]], axis=1)])


def particle_masses(mesh: ClothMesh, total: float, distribution: str) -> np.ndarray:
    """(P,) kg: ``total`` shared by area (each face's area split evenly among its corners: a particle carries
    the cloth around it) or evenly (every particle the same, as on a grid)."""
    if distribution == "even":
        return np.full(mesh.particle_count, total / mesh.particle_count)
    area = np.linalg.norm(_vector_areas(mesh.particle_points, mesh.faces), axis=1)
    per_corner = np.repeat(area / mesh.faces.counts, mesh.faces.counts)
    share = np.zeros(mesh.particle_count)
    np.add.at(share, mesh.faces.indices, per_corner)  # a welded face corner counts once per corner
    return total * share / share.sum()
