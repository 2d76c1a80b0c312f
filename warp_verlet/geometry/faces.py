"""Faces of any size (triangles, quads, n-gons) as flat numpy arrays, and which faces lie beside an edge.

A mesh's faces are stored the way USD stores them (``faceVertexCounts`` and ``faceVertexIndices``): one
corner count per face and every face's vertex indices one after another. That holds a grid's quads, a
triangulated mesh and a mix of both alike, so the writer, the preview and tearing need no per-shape cases.
A face's corners run counter-clockwise seen from its front, and its sides are consecutive corners, the
last corner joined back to the first.

This module uses numpy only (no warp, no pxr), so that every layer can use it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import ArgumentError

_INT32 = np.iinfo(np.int32)


def _int32_vector(values: np.ndarray, what: str) -> np.ndarray:
    """A read-only int32 copy of a 1-D integer array; refuses what a cast to int32 would silently change
    (fractions, values out of range). An empty array of any dtype is fine: it changes nothing."""
    a = np.asarray(values)
    if a.ndim != 1:
        raise ArgumentError(f"{what} must be a 1-D array, got shape {a.shape}")
    if a.size and a.dtype.kind not in "iu":
        raise ArgumentError(f"{what} must be integers, got dtype {a.dtype}")
    if a.size and (a.min() < _INT32.min or a.max() > _INT32.max):
        raise ArgumentError(f"{what} must fit in int32, got values in [{a.min()}, {a.max()}]")
    out = a.astype(np.int32, copy=True)
    out.flags.writeable = False  # a frozen Faces must not change under the arrays built from it
    return out


def next_corner(counts: np.ndarray) -> np.ndarray:
    """For each corner of faces laid out one after another with ``counts`` corners each, the position of
    the corner that follows it along its face: the next one, or the face's first for its last corner."""
    counts = np.asarray(counts, dtype=np.int64)
    ends = np.cumsum(counts)
    out = np.arange(1, int(ends[-1]) + 1 if len(ends) else 1, dtype=np.int64)
    if len(counts):
        out[ends - 1] = ends - counts  # the wrap-around side, last corner -> first
    return out


@dataclass(frozen=True)
class Faces:
    """The faces of one mesh: ``counts[f]`` corners for face f, its vertex indices at
    ``indices[offsets[f]:offsets[f + 1]]``, counter-clockwise seen from the front.

    Both arrays are stored as read-only int32 copies. Construction checks only that they are 1-D
    integers; ``validate`` checks that they describe faces of a mesh with a given number of points.
    """

    counts: np.ndarray  # (F,) int32, corners per face, each >= 3
    indices: np.ndarray  # (sum(counts),) int32 vertex indices, faces one after another

    def __post_init__(self) -> None:
        object.__setattr__(self, "counts", _int32_vector(self.counts, "face corner counts"))
        object.__setattr__(self, "indices", _int32_vector(self.indices, "face vertex indices"))

    @classmethod
    def uniform(cls, array2d: np.ndarray) -> Faces:
        """Faces from an (F, k) array of vertex indices, every face with k corners (a grid's quads)."""
        a = np.asarray(array2d)
        if a.ndim != 2:
            raise ArgumentError(f"expected an (F, k) array of vertex indices, k corners per face, got shape {a.shape}")
        return cls(np.full(len(a), a.shape[1], np.int32), a.reshape(-1))

    @classmethod
    def empty(cls) -> Faces:
        """No faces: what a rope has."""
        return cls(np.zeros(0, np.int32), np.zeros(0, np.int32))

    def __len__(self) -> int:
        return len(self.counts)

    def __eq__(self, other: object) -> bool:
        # The generated __eq__ would compare arrays with ==, which is ambiguous for more than one face.
        if not isinstance(other, Faces):
            return NotImplemented
        return np.array_equal(self.counts, other.counts) and np.array_equal(self.indices, other.indices)

    @cached_property
    def offsets(self) -> np.ndarray:
        """(F + 1,) int64: face f's vertex indices are ``indices[offsets[f]:offsets[f + 1]]``."""
        out = np.zeros(len(self.counts) + 1, np.int64)
        np.cumsum(self.counts, out=out[1:])
        return out

    def as_uniform(self) -> np.ndarray | None:
        """The faces as an (F, k) array when every face has the same k corners, else None: the fast path
        for gathering corner positions with one fancy index."""
        if len(self.counts) == 0 or (self.counts != self.counts[0]).any():
            return None
        return self.indices.reshape(len(self.counts), int(self.counts[0]))

    def validate(self, point_count: int | None, name: str = "faces") -> None:
        """Raise ValueError, naming ``name``, unless these are faces of a mesh of ``point_count`` points:
        as many vertex indices as the corner counts add up to, at least 3 corners per face, and every index
        in [0, point_count). ``point_count=None`` checks only that the indices are not negative (for a
        reader that learns the point count later)."""
        f = len(self.counts)
        total = int(self.counts.sum(dtype=np.int64))
        if total != len(self.indices):
            raise ArgumentError(f"{name}: {f} faces with {total} corners in all need {total} vertex indices, "
                             f"got {len(self.indices)}")
        small = np.flatnonzero(self.counts < 3)
        if len(small):
            i = int(small[0])
            raise ArgumentError(f"{name}: every face needs at least 3 corners, but face {i} of {f} has "
                             f"{self.counts[i]} ({len(small)} such faces)")
        upper = _INT32.max if point_count is None else point_count
        bad = np.flatnonzero((self.indices < 0) | (self.indices >= upper))
        if len(bad):
            face = int(np.searchsorted(self.offsets, bad[0], side="right")) - 1
            expected = "not negative" if point_count is None else f"in [0, {point_count})"
            raise ArgumentError(f"{name}: face {face} of {f} uses vertex {self.indices[bad[0]]}; vertex indices "
                             f"must be {expected} ({len(bad)} bad indices)")

    def sides(self) -> tuple[np.ndarray, np.ndarray]:
        """Every side of every face: ((S, 2) vertex pairs (corner, next corner), (S,) the face of each)."""
        pairs = np.stack([self.indices, self.indices[next_corner(self.counts)]], axis=1)
        return pairs, np.repeat(np.arange(len(self.counts), dtype=np.int32), self.counts)


def as_faces(faces: Faces | np.ndarray) -> Faces:
    """``faces`` itself, or an (F, k) array converted by ``Faces.uniform``: for callers that still pass
    a grid's (F, 4) quad array."""
    return faces if isinstance(faces, Faces) else Faces.uniform(faces)


def grid_faces(rows: int, cols: int) -> Faces:
    """The quads of a ``rows x cols`` grid of points (vertex ``r * cols + c``): face (r, c) is
    (r,c), (r+1,c), (r+1,c+1), (r,c+1), at index ``r * (cols - 1) + c``, in row-major order. With rows
    running down -Y and columns along +X, that is counter-clockwise seen from +Z. No faces when
    ``rows < 2`` or ``cols < 2`` (a rope)."""
    if rows < 2 or cols < 2:
        return Faces.empty()
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (r * cols + c).ravel()
    return Faces.uniform(np.stack([a, a + cols, a + cols + 1, a + 1], axis=1))


def edge_keys(pairs: np.ndarray, base: int) -> np.ndarray:
    """One int64 key per undirected vertex pair, the same for (a, b) and (b, a)."""
    lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    return lo.astype(np.int64) * base + hi


def side_table(faces: Faces, base: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every distinct side as a key (see ``edge_keys``), sorted: (keys (K,), where each key's faces start
    in the last array (K,), how many faces (K,), the faces of all sides grouped by key, in index order)."""
    pairs, face_of_side = faces.sides()
    keys = edge_keys(pairs, base)
    order = np.argsort(keys, kind="stable")  # stable: faces stay in index order within a key
    keys, face_of_side = keys[order], face_of_side[order]
    # A degenerate face that lists the same side twice is still one face beside it.
    first = np.ones(len(keys), bool)
    first[1:] = (keys[1:] != keys[:-1]) | (face_of_side[1:] != face_of_side[:-1])
    keys, face_of_side = keys[first], face_of_side[first]
    new_key = np.ones(len(keys), bool)
    new_key[1:] = keys[1:] != keys[:-1]
    start = np.flatnonzero(new_key)
    count = np.diff(np.append(start, len(keys)))
    return keys[start], start, count, face_of_side


def edge_faces(faces: Faces, edges: np.ndarray) -> np.ndarray:
    """For each undirected edge (row of ``edges``, (M, 2) vertex indices), the indices of the faces that
    have it as a side, lower face index first, -1 where there is none: (M, 2) int32.

    A border edge has one face, (f, -1); a pair that is no face's side (a shear diagonal, a bend stick, a
    rope's stick) has none. Tearing uses this to hide the faces beside a torn stick. An edge that 3 or more
    faces share (a non-manifold mesh) has no answer in two columns, so it raises ValueError naming the edge.

    Vectorised, for million-face grids: every face side becomes an undirected-pair key, the keys are sorted
    once, and the edges are looked up by binary search.
    """
    edges = np.asarray(edges)
    if edges.ndim != 2 or edges.shape[1] != 2:
        raise ArgumentError(f"edges must be an (M, 2) array of vertex index pairs, got shape {edges.shape}")
    if edges.size and edges.dtype.kind not in "iu":
        raise ArgumentError(f"edges must be integer vertex indices, got dtype {edges.dtype}")
    if edges.size and edges.min() < 0:
        row = int(np.flatnonzero((edges < 0).any(axis=1))[0])
        raise ArgumentError(f"edge {row} {tuple(edges[row].tolist())} has a negative vertex index")
    faces.validate(None, "edge_faces: faces")
    out = np.full((len(edges), 2), -1, np.int32)
    if len(edges) == 0 or len(faces) == 0:
        return out

    base = int(faces.indices.max()) + 1
    unique, start, count, face_of_side = side_table(faces, base)
    inside = (edges < base).all(axis=1)  # an edge to a vertex no face uses is no side (and would not fit a key)
    wanted = edge_keys(np.where(inside[:, None], edges, 0), base)
    at = np.minimum(np.searchsorted(unique, wanted), len(unique) - 1)
    found = inside & (unique[at] == wanted)
    crowded = np.flatnonzero(found & (count[at] > 2))
    if len(crowded):
        row = int(crowded[0])
        s, n = start[at[row]], count[at[row]]
        raise ArgumentError(f"edge {row} {tuple(edges[row].tolist())} is a side of {n} faces "
                         f"{face_of_side[s:s + n].tolist()}; expected at most 2 (a non-manifold mesh)")
    s = start[at]
    out[:, 0] = np.where(found, face_of_side[s], -1)
    second = found & (count[at] == 2)
    out[:, 1] = np.where(second, face_of_side[np.minimum(s + 1, len(face_of_side) - 1)], -1)
    return out
