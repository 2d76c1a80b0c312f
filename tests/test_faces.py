"""Faces of any size (warp_verlet.geometry.faces): the flat layout, the grid's quads, and which faces lie beside an edge,
checked against the grid-only topology code and against meshes worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from warp_verlet.geometry.faces import Faces, as_faces, edge_faces, grid_faces, next_corner
from warp_verlet.input.scene import ClothSpec
from warp_verlet.geometry.topology import STRUCT_H, STRUCT_V, build_cloth

from meshes import HOUSE, HOUSE_POINTS  # tests/meshes.py (pytest puts tests/ on sys.path)

# Every pair asked about, and the faces beside it, lower index first, worked out from the picture in
# meshes.py.
HOUSE_EDGES = {
    (1, 2): (0, 1),  # pentagon 1 -> 2, quad 2 -> 1 (the quad's wrap-around side)
    (6, 2): (1, 2),  # quad 6 -> 2, triangle 2 -> 6; asked the other way round
    (2, 3): (0, 2),  # pentagon 2 -> 3, triangle 3 -> 2 (the triangle's wrap-around side)
    (0, 4): (0, -1),  # the pentagon's wrap-around side, on the border
    (3, 4): (0, -1),
    (0, 1): (0, -1),
    (5, 6): (1, -1),
    (3, 6): (2, -1),
    (0, 2): (-1, -1),  # a diagonal of the pentagon: no side
    (1, 6): (-1, -1),  # a diagonal of the quad
    (4, 6): (-1, -1),  # two vertices that share no face
}

BIG = np.iinfo(np.int32).max


def faces_beside_sticks(rows: int, cols: int, grid_class: np.ndarray, anchor: np.ndarray) -> np.ndarray:
    """The grid's own answer, written from rows and columns (what the simulator used before faces): a horizontal
    stick (r, c)-(r, c+1) borders faces (r-1, c) and (r, c); a vertical stick (r, c)-(r+1, c) borders faces
    (r, c-1) and (r, c), face (r, c) having index r * (cols - 1) + c; -1 beyond the border."""
    out = np.full((len(grid_class), 2), -1, np.int32)
    if rows < 2 or cols < 2:
        return out
    r, c = anchor[:, 0].astype(np.int64), anchor[:, 1].astype(np.int64)
    per_row = cols - 1
    h, v = grid_class == STRUCT_H, grid_class == STRUCT_V
    out[:, 0] = np.where(h & (r > 0), (r - 1) * per_row + c, np.where(v & (c > 0), r * per_row + c - 1, -1))
    out[:, 1] = np.where(h & (r < rows - 1), r * per_row + c, np.where(v & (c < cols - 1), r * per_row + c, -1))
    return out


def by_face(pairs: np.ndarray) -> np.ndarray:
    """Each row's two faces in ascending order with -1 (none) last: edge_faces' order, for comparing with
    faces_beside_sticks, whose order is (above or left, below or right)."""
    rows = np.sort(np.where(pairs < 0, BIG, pairs), axis=1)
    return np.where(rows == BIG, -1, rows)


# ------------------------------------------------------------------------------------------- the layout


def test_uniform_offsets_and_equality():
    quads = np.array([[0, 1, 2, 3], [1, 4, 5, 2]], np.int64)
    faces = Faces.uniform(quads)
    assert len(faces) == 2 and faces.counts.dtype == np.int32 and faces.indices.dtype == np.int32
    np.testing.assert_array_equal(faces.counts, [4, 4])
    np.testing.assert_array_equal(faces.indices, quads.ravel())
    np.testing.assert_array_equal(faces.offsets, [0, 4, 8])
    np.testing.assert_array_equal(faces.as_uniform(), quads)
    assert faces == Faces([4, 4], quads.ravel()) and faces != Faces.uniform(quads[::-1])
    assert as_faces(quads) == faces and as_faces(faces) is faces
    np.testing.assert_array_equal(HOUSE.offsets, [0, 5, 9, 12])
    assert HOUSE.as_uniform() is None  # mixed sizes


def test_faces_are_frozen_copies():
    quads = np.array([[0, 1, 2, 3]], np.int32)
    faces = Faces.uniform(quads)
    quads[0, 0] = 9  # the caller's array is not shared
    assert faces.indices[0] == 0
    with pytest.raises(ValueError):
        faces.indices[0] = 5


def test_empty():
    for faces in (Faces.empty(), Faces.uniform(np.zeros((0, 4), np.int32)), grid_faces(1, 5), grid_faces(5, 1)):
        assert len(faces) == 0 and len(faces.indices) == 0
        np.testing.assert_array_equal(faces.offsets, [0])
        faces.validate(0, "rope")
    assert edge_faces(Faces.empty(), np.array([[0, 1]])).tolist() == [[-1, -1]]


def test_next_corner_wraps_each_face():
    np.testing.assert_array_equal(next_corner(np.array([3, 4])), [1, 2, 0, 4, 5, 6, 3])
    assert len(next_corner(np.zeros(0, np.int32))) == 0


@pytest.mark.parametrize("rows, cols", [(2, 2), (3, 5), (7, 4), (1, 6), (6, 1), (1, 1)])
def test_grid_faces_are_build_cloths_quads(rows, cols):
    topology = build_cloth(ClothSpec("cloth", (rows, cols), (1.0, 1.0)))
    faces = grid_faces(rows, cols)
    assert len(faces) == len(topology.faces) == max(rows - 1, 0) * max(cols - 1, 0)
    assert topology.faces == faces
    # The grid-only topology code's quads, (r,c) -> (r+1,c) -> (r+1,c+1) -> (r,c+1), as its oracle.
    if rows > 1 and cols > 1:
        r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
        a = (r * cols + c).ravel()
        quads = np.stack([a, a + cols, a + cols + 1, a + 1], axis=1).astype(np.int32)
    else:
        quads = np.zeros((0, 4), np.int32)
    assert faces == Faces.uniform(quads)


# ---------------------------------------------------------------------------------------- validation


@pytest.mark.parametrize("faces, points, words", [
    (Faces([3, 3], [0, 1, 2, 2, 1]), 3, "2 faces with 6 corners in all need 6 vertex indices, got 5"),
    (Faces([3, 2], [0, 1, 2, 2, 1]), 3, "at least 3 corners, but face 1 of 2 has 2"),
    (Faces([3, 4], [0, 1, 2, 2, 1, 7, 3]), 4, "face 1 of 2 uses vertex 7; vertex indices must be in [0, 4)"),
    (Faces([3], [0, -1, 2]), 4, "face 0 of 1 uses vertex -1"),
    (Faces([3], [0, -1, 2]), None, "must be not negative"),
])
def test_validate_names_the_mesh_and_the_problem(faces, points, words):
    with pytest.raises(ValueError) as err:
        faces.validate(points, "shape 'flag'")
    assert str(err.value).startswith("shape 'flag': ") and words in str(err.value)


def test_validate_accepts_every_size_from_three():
    HOUSE.validate(len(HOUSE_POINTS), "house")
    Faces([3, 4, 5, 8], np.arange(20) % 9).validate(9, "mixed")
    Faces.uniform(np.arange(12).reshape(2, 6)).validate(None, "hexagons")


@pytest.mark.parametrize("build, words", [
    (lambda: Faces.uniform(np.arange(4)), "expected an (F, k) array"),
    (lambda: Faces([[3]], [0, 1, 2]), "face corner counts must be a 1-D array"),
    (lambda: Faces([3], [0.0, 1.0, 2.0]), "face vertex indices must be integers"),
    (lambda: Faces([3], [0, 1, 2**31]), "must fit in int32"),
])
def test_bad_arrays_are_refused_at_construction(build, words):
    with pytest.raises(ValueError) as err:
        build()
    assert words in str(err.value)


# ------------------------------------------------------------------------------------ faces of an edge


@pytest.mark.parametrize("rows, cols", [(2, 2), (2, 6), (6, 2), (5, 7), (33, 17), (1, 5), (5, 1)])
def test_edge_faces_match_faces_beside_sticks_on_a_grid(rows, cols):
    topology = build_cloth(ClothSpec("cloth", (rows, cols), (1.0, 1.0)))  # structural sticks
    assert len(topology.sticks) > 0
    got = edge_faces(grid_faces(rows, cols), topology.sticks)
    assert got.shape == (len(topology.sticks), 2) and got.dtype == np.int32
    expected = faces_beside_sticks(rows, cols, topology.grid_class, topology.anchor)
    np.testing.assert_array_equal(got, by_face(expected))
    if rows > 2 and cols > 2:  # both kinds of row: an inner stick has two faces, a border stick one
        assert ((got >= 0).sum(axis=1) == 2).any() and ((got >= 0).sum(axis=1) == 1).any()


def grid_sticks(rows: int, cols: int, dr: int, dc: int) -> np.ndarray:
    """Every stick (r, c) -> (r + dr, c + dc) inside the grid."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    ok = (r + dr < rows) & (c + dc >= 0) & (c + dc < cols)
    return np.stack([r[ok] * cols + c[ok], (r[ok] + dr) * cols + c[ok] + dc], axis=1)


@pytest.mark.parametrize("dr, dc", [(1, 1), (1, -1), (0, 2), (2, 0)])
def test_shear_and_bend_sticks_have_no_faces(dr, dc):
    sticks = grid_sticks(6, 5, dr, dc)
    assert len(sticks) > 0
    assert (edge_faces(grid_faces(6, 5), sticks) == -1).all()


def test_edge_faces_of_a_mixed_mesh():
    edges = np.array(list(HOUSE_EDGES))
    expected = np.array(list(HOUSE_EDGES.values()))
    np.testing.assert_array_equal(edge_faces(HOUSE, edges), expected)
    np.testing.assert_array_equal(edge_faces(HOUSE, edges[:, ::-1]), expected)  # an edge has no direction


def test_edge_faces_of_a_triangle_fan():
    # Triangles around vertex 0: 0 1 2, 0 2 3, 0 3 4 (a fan, open between 4 and 1).
    fan = Faces.uniform(np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4]]))
    edges = np.array([[0, 2], [3, 0], [1, 2], [0, 1], [4, 0], [3, 4], [1, 3], [1, 4], [0, 9]])
    expected = [[0, 1], [1, 2], [0, -1], [0, -1], [2, -1], [2, -1], [-1, -1], [-1, -1], [-1, -1]]
    assert edge_faces(fan, edges).tolist() == expected


def test_non_manifold_edges_are_refused_by_name():
    fins = Faces.uniform(np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))  # three faces on edge 0-1
    with pytest.raises(ValueError) as err:
        edge_faces(fins, np.array([[1, 2], [1, 0]]))
    message = str(err.value)
    assert "edge 1 (1, 0)" in message and "3 faces [0, 1, 2]" in message and "at most 2" in message
    assert edge_faces(fins, np.array([[1, 2], [0, 4]])).tolist() == [[0, -1], [2, -1]]  # other edges are fine


@pytest.mark.parametrize("edges, words", [
    (np.array([0, 1]), "(M, 2) array"),
    (np.zeros((2, 3), np.int32), "(M, 2) array"),
    (np.array([[0.0, 1.0]]), "integer vertex indices"),
    (np.array([[0, 1], [2, -1]]), "edge 1 (2, -1) has a negative vertex index"),
])
def test_bad_edges_are_refused(edges, words):
    with pytest.raises(ValueError) as err:
        edge_faces(HOUSE, edges)
    assert words in str(err.value)


def test_bad_faces_are_refused_by_edge_faces():
    with pytest.raises(ValueError, match="at least 3 corners"):
        edge_faces(Faces([3, 2], [0, 1, 2, 2, 3]), np.array([[0, 1]]))


@pytest.mark.slow
def test_edge_faces_scale_to_a_million_face_grid():
    rows = cols = 1025  # 1024 x 1024 faces, 2.1 million structural sticks
    topology = build_cloth(ClothSpec("cloth", (rows, cols), (1.0, 1.0)))
    got = edge_faces(grid_faces(rows, cols), topology.sticks)
    np.testing.assert_array_equal(got, by_face(faces_beside_sticks(rows, cols, topology.grid_class,
                                                                   topology.anchor)))
