"""Stick colourings: the partition property (no two sticks of one colour share a particle)."""

import numpy as np
import pytest
import trimesh

from conftest import make_scene
from warp_verlet.geometry.colouring import check_partition, graph_colouring, grid_colouring, stick_conflict_edges
from warp_verlet.geometry.topology import build_cloth

ALL = ["structural", "shear", "bend"]


def cloth(rows, cols, sticks):
    return build_cloth(make_scene(resolution=[rows, cols], sticks=sticks).cloths[0])


@pytest.mark.parametrize("rows, cols", [(2, 2), (3, 7), (16, 16), (1, 9), (9, 1), (33, 20)])
@pytest.mark.parametrize("families, colours", [
    (["structural"], 4), (["structural", "shear"], 8), (ALL, 12), (["bend"], 4),
])
def test_grid_colouring_is_a_partition_with_the_minimum_colours(rows, cols, families, colours):
    topo = cloth(rows, cols, families)
    result = grid_colouring(topo.grid_class, topo.anchor)
    check_partition(topo.sticks, result.colour)
    degree = np.bincount(topo.sticks.ravel(), minlength=rows * cols).max()
    assert result.count >= degree  # no edge colouring can use fewer colours than the largest degree
    if min(rows, cols) >= 5:  # large enough for every direction to appear with both parities
        assert result.count == colours == degree


def test_check_partition_rejects_a_bad_colouring():
    topo = cloth(4, 4, ["structural"])
    with pytest.raises(AssertionError, match="sharing particle"):
        check_partition(topo.sticks, np.zeros(len(topo.sticks), np.int32))


def test_conflict_edges_join_exactly_the_sticks_sharing_a_particle():
    sticks = np.array([[0, 1], [1, 2], [2, 3], [4, 5], [1, 4]], np.int32)
    edges = {tuple(e) for e in stick_conflict_edges(sticks)}
    assert edges == {(0, 1), (0, 4), (1, 2), (1, 4), (3, 4)}


@pytest.mark.parametrize("mesh", [
    trimesh.creation.icosphere(subdivisions=3),
    trimesh.creation.annulus(r_min=0.3, r_max=1.0, height=0.2, sections=17),
    trimesh.creation.cylinder(radius=0.5, height=1.0, sections=13),
], ids=["icosphere", "annulus", "cylinder"])
def test_graph_colouring_of_irregular_meshes(mesh):
    sticks = np.asarray(mesh.edges_unique, np.int32)
    result = graph_colouring(sticks)
    check_partition(sticks, result.colour)
    degree = np.bincount(sticks.ravel()).max()
    assert degree <= result.count <= 2 * degree - 1  # Vizing/greedy: a greedy line-graph colouring needs < 2 deg
    assert result.sizes.sum() == len(sticks)


def test_graph_colouring_of_a_grid_is_valid_and_near_minimal():
    topo = cloth(24, 24, ALL)
    result = graph_colouring(topo.sticks)
    check_partition(topo.sticks, result.colour)
    assert 12 <= result.count <= 16
