"""What a browser draws of one cloth: a subset of its vertices and the triangles over them, as float32 and
uint32 arrays ready to send as binary. numpy only: the live viewer and the cache player share it.

A grid larger than ``max_grid_quads`` a side is drawn as a coarser grid through every k-th row and column
(both edges always kept), so that what goes to the browser each frame stays small whatever the cloth's size:
a 1024 x 1024 cloth costs what a 256 x 256 one does. A coarse quad is hidden when any fine face it covers is
torn. Any other mesh is drawn whole, its faces fanned into triangles.
"""

from __future__ import annotations

import numpy as np

from .faces import Faces, as_faces

# 256 quads a side: 66049 vertices, 790 KB of float32 per frame, which a browser redraws at 60 frames/s.
MAX_GRID_QUADS = 256


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


class DisplayMesh:
    """The drawn part of one cloth of ``vertex_count`` vertices with ``faces``; ``grid`` (rows, cols) when the
    faces are the writer's grid (``faces.grid_faces``), which may then be drawn coarser."""

    def __init__(self, faces: Faces | np.ndarray, vertex_count: int, grid: tuple[int, int] | None = None,
                 max_grid_quads: int = MAX_GRID_QUADS):
        faces = as_faces(faces)
        self.vertex_count = vertex_count
        self.grid = grid
        self.rope = len(faces) == 0  # no faces: drawn as a polyline through every vertex
        self.note = ""  # what the screen says when the drawing is coarser than the cloth
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
            self._triangles, self._triangle_face = fan_triangles(faces)
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
        if self._rows is None:
            face_hidden = np.zeros(int(self._triangle_face.max(initial=-1)) + 1, bool)
            face_hidden[hidden_faces[(hidden_faces >= 0) & (hidden_faces < len(face_hidden))]] = True
        else:
            rows, cols = self.grid
            fine = np.zeros((rows - 1) * (cols - 1), bool)
            fine[hidden_faces[(hidden_faces >= 0) & (hidden_faces < len(fine))]] = True
            fine = fine.reshape(rows - 1, cols - 1)
            face_hidden = np.logical_or.reduceat(np.logical_or.reduceat(fine, self._rows[:-1], axis=0),
                                                 self._cols[:-1], axis=1).ravel()
        return self._all_triangles[~face_hidden[self._triangle_face]]


def rope_segments(points: np.ndarray) -> np.ndarray:
    """A polyline (N, 3) as (N - 1, 2, 3) float32 line segments."""
    points = np.asarray(points, dtype=np.float32)
    return np.ascontiguousarray(np.stack([points[:-1], points[1:]], axis=1))
