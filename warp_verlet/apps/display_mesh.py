"""What a browser draws of one cloth: a subset of its vertices and the triangles over them, as float32 and
uint32 arrays ready to send as binary. numpy only: the live viewer and the cache player share it.

A grid larger than ``max_grid_quads`` a side is drawn as a coarser grid through every k-th row and column
(both edges always kept), so that what goes to the browser each frame stays small whatever the cloth's size:
a 1024 x 1024 cloth costs what a 256 x 256 one does. A coarse quad is hidden when any fine face it covers is
torn.

Any other mesh has its faces fanned into triangles. One with more vertices than such a coarse grid, (max_grid_quads
+ 1)^2, is decimated once, on its rest pose, by quadric edge collapses (fast-simplification, a maintained C++
implementation of Garland and Heckbert's method, in the ``live`` extra), keeping its open border (a hem, a torn
edge to be). Each coarse vertex is drawn at one of the cloth's own vertices from those that collapsed into it, so
a live session gathers just those on the device, and the drawing passes exactly through them. A coarse triangle is
hidden when any vertex that collapsed into one of its corners lies on a torn face. A few coarse triangles may
fold over a neighbour (under 1% on a folded sheet, measured in the tests): slivers in the drawing only.
"""

from __future__ import annotations

import numpy as np

from ..geometry.faces import Faces, as_faces

# 256 quads a side: 66049 vertices, 790 KB of float32 per frame, which a browser redraws at 60 frames/s.
MAX_GRID_QUADS = 256
TRIANGLES_PER_VERTEX = 2  # a surface mesh has about two triangles per vertex (Euler: V - E + F ~ 0)


def grid_lines(quads: int, limit: int) -> np.ndarray:
    """Indices of the fine grid lines kept by a coarse grid of at most ``limit`` quads: both ends always."""
    return np.round(np.linspace(0, quads, min(quads, limit) + 1)).astype(np.int64)


def fan_triangles(faces: Faces) -> tuple[np.ndarray, np.ndarray]:
    """Each face (k corners) as k - 2 triangles fanned from its first corner: (T, 3) corner indices, and the
    face each triangle came from (T,)."""
    counts = faces.counts.astype(np.int64)
    tris_per_face = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), tris_per_face)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])[face]
    # The j-th triangle of a face: corners 0, j + 1, j + 2.
    j = np.arange(len(face)) - np.repeat(np.cumsum(tris_per_face) - tris_per_face, tris_per_face)
    idx = faces.indices.astype(np.int64)
    triangles = np.stack([idx[start], idx[start + j + 1], idx[start + j + 2]], axis=1)
    return triangles, face


def decimate(triangles: np.ndarray, rest_points: np.ndarray, vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decimate the triangle mesh to about ``vertices`` vertices (quadric edge collapses on ``rest_points``, the
    open border kept). Returns, per coarse vertex, the original vertex drawn for it; the coarse triangles (indices
    into the coarse vertices); and, for every original vertex, the coarse vertex it collapsed into."""
    import fast_simplification

    used = np.unique(triangles)
    if len(used) < len(rest_points):  # the library drops vertices no triangle uses, renumbering the rest
        local = np.full(len(rest_points), -1, np.int64)
        local[used] = np.arange(len(used))
        drawn, coarse, collapsed_into = decimate(local[triangles], np.asarray(rest_points)[used], vertices)
        everywhere = np.full(len(rest_points), -1, np.int64)  # a loose vertex is in no face: never looked up
        everywhere[used] = collapsed_into
        return used[drawn], coarse, everywhere
    points = np.ascontiguousarray(rest_points, dtype=np.float64)
    coarse_points, coarse, collapses = fast_simplification.simplify(
        points, np.ascontiguousarray(triangles, dtype=np.int32), target_count=TRIANGLES_PER_VERTEX * vertices,
        return_collapses=True, preserve_border=True)
    # collapses[i] = (a, b): b merged into a, which may merge on later. Follow each vertex to the one left standing
    # (pointer jumping: a few passes over the array, whatever the chains' length).
    root = np.arange(len(points))
    root[collapses[:, 1]] = collapses[:, 0]
    while True:
        jumped = root[root]
        if np.array_equal(jumped, root):
            break
        root = jumped
    standing = np.flatnonzero(root == np.arange(len(points)))
    number = np.empty(len(points), np.int64)
    number[standing] = np.arange(len(standing))  # the library numbers the coarse mesh's vertices in this order
    collapsed_into = number[root]
    # Each coarse vertex is drawn at the original vertex of its cluster nearest the library's own (optimal) point
    # for it, not at the one left standing: on a folded sheet that one folded 3% of the coarse triangles over
    # their neighbours, the nearest one under 1%.
    distance = np.linalg.norm(points - coarse_points[collapsed_into], axis=1)
    order = np.lexsort((distance, collapsed_into))
    first = np.r_[True, collapsed_into[order][1:] != collapsed_into[order][:-1]]
    return order[first], np.asarray(coarse, np.int64), collapsed_into


class DisplayMesh:
    """The drawn part of one cloth of ``vertex_count`` vertices with ``faces``; ``grid`` (rows, cols) when the
    faces are the writer's grid (``faces.grid_faces``), which may then be drawn coarser. Any other mesh over
    (max_grid_quads + 1)^2 vertices is decimated when its ``rest_points`` are given."""

    def __init__(self, faces: Faces | np.ndarray, vertex_count: int, grid: tuple[int, int] | None = None,
                 max_grid_quads: int = MAX_GRID_QUADS, rest_points: np.ndarray | None = None):
        faces = as_faces(faces)
        self.vertex_count = vertex_count
        self.grid = grid
        self.rope = len(faces) == 0  # no faces: drawn as a polyline through every vertex
        self.note = ""  # what the screen says when the drawing is coarser than the cloth
        self._collapsed_into = None  # a decimated mesh: each vertex's drawn vertex
        if grid is not None and max(grid) - 1 > max_grid_quads:
            rows, cols = grid
            self._rows, self._cols = grid_lines(rows - 1, max_grid_quads), grid_lines(cols - 1, max_grid_quads)
            nr, nc = len(self._rows), len(self._cols)
            self.vertex_index = (self._rows[:, None] * cols + self._cols[None, :]).ravel()
            v = np.arange(nr * nc).reshape(nr, nc)
            quads = np.stack([v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]], axis=2).reshape(-1, 4)  # grid winding
            self._triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
            self._triangle_face = np.tile(np.arange(len(quads)), 2)
            self.note = f"{rows} x {cols} vertices drawn as {nr} x {nc}"
        else:
            self._rows = self._cols = None
            self.vertex_index = None  # every vertex
            self._fan = self._triangles, self._triangle_face = fan_triangles(faces)
            budget = (max_grid_quads + 1) ** 2
            if not self.rope and vertex_count > budget and rest_points is not None:
                self.vertex_index, self._triangles, self._collapsed_into = decimate(self._triangles, rest_points,
                                                                                    budget)
                self.note = f"{vertex_count:,} mesh vertices drawn as {len(self.vertex_index):,} (decimated)"
        self._all_triangles = self._triangles.astype(np.uint32)

    @property
    def drawn_vertex_count(self) -> int:
        return self.vertex_count if self.vertex_index is None else len(self.vertex_index)

    @property
    def reduced(self) -> bool:
        return self.vertex_index is not None

    def vertices(self, points: np.ndarray) -> np.ndarray:
        """The drawn vertices as contiguous float32 (V, 3), from all the cloth's ``points`` (vertex_count, 3) or
        from the drawn ones already (drawn_vertex_count, 3: what a live session gathers on the device)."""
        if self.vertex_index is not None and len(points) == self.vertex_count:
            points = points[self.vertex_index]
        return np.ascontiguousarray(points, dtype=np.float32)

    def triangles(self, hidden_faces=()) -> np.ndarray:
        """(T, 3) uint32 triangles over the drawn vertices, without those of the faces in ``hidden_faces``."""
        hidden_faces = np.asarray(hidden_faces, dtype=np.int64)
        if hidden_faces.size == 0:
            return self._all_triangles
        if self._rows is not None:
            rows, cols = self.grid
            fine = np.zeros((rows - 1) * (cols - 1), bool)
            fine[hidden_faces[(hidden_faces >= 0) & (hidden_faces < len(fine))]] = True
            fine = fine.reshape(rows - 1, cols - 1)
            face_hidden = np.logical_or.reduceat(np.logical_or.reduceat(fine, self._rows[:-1], axis=0),
                                                 self._cols[:-1], axis=1).ravel()
            return self._all_triangles[~face_hidden[self._triangle_face]]
        fan, fan_face = self._fan
        face_hidden = np.zeros(int(fan_face.max(initial=-1)) + 1, bool)
        face_hidden[hidden_faces[(hidden_faces >= 0) & (hidden_faces < len(face_hidden))]] = True
        if self._collapsed_into is None:
            return self._all_triangles[~face_hidden[fan_face]]
        touched = np.zeros(len(self.vertex_index), bool)
        touched[self._collapsed_into[fan[face_hidden[fan_face]]]] = True
        return self._all_triangles[~touched[self._triangles].any(axis=1)]


def rope_segments(points: np.ndarray) -> np.ndarray:
    """A polyline (N, 3) as (N - 1, 2, 3) float32 line segments."""
    points = np.asarray(points, dtype=np.float32)
    return np.ascontiguousarray(np.stack([points[:-1], points[1:]], axis=1))
