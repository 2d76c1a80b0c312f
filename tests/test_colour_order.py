"""The order in which a sweep projects a grid's stick classes (topology.SWEEP_ORDER): the longest sticks first, so
that the structural sticks have the last word. Every grid form (stick arrays, implicit sticks, tiles) follows it,
and it leaves a hanging cloth less stretched than the classes' own order at the same budget."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import make_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.geometry import topology

def hanging(n: int, substeps: int, iterations: int):
    return make_scene({"substeps": substeps, "iterations": iterations, "damping": 0.24}, resolution=[n, n],
                      size=[1.0, 1.0], mass=0.2, pins=["top-left", "top-right"], sticks=["structural", "shear", "bend"])


def test_the_colours_come_longest_sticks_first_in_every_grid_form():
    scene = hanging(9, 2, 2)
    explicit = Simulator(scene, "cpu", sticks="explicit").model
    cols = 9
    classes = []
    for first, count in explicit.colour_ranges:
        steps = np.unique(np.diff(explicit.host_sticks[first:first + count], axis=1))
        assert len(steps) == 1  # one direction per colour
        dr = (int(steps[0]) + 1) // cols  # a stick's step is dr * cols + dc, dc in -1..2
        classes.append((dr, int(steps[0]) - dr * cols))
    assert classes == [(0, 2), (0, 2), (2, 0), (2, 0), (1, 1), (1, 1), (1, -1), (1, -1),
                       (0, 1), (0, 1), (1, 0), (1, 0)]  # bend, shear, structural; each direction's two parities
    implicit = Simulator(scene, "cpu", sticks="implicit").model
    assert [(c.layout.dr, c.layout.dc) for c in implicit.grid.colours] == classes


@pytest.mark.parametrize("substeps, iterations", [(16, 1), (4, 4)])
def test_longest_first_leaves_a_hanging_cloth_less_stretched_than_the_classes_order(substeps, iterations,
                                                                                  monkeypatch):
    """The same launches in two orders: longest first leaves the structural stretch at least 15% lower (about 30%
    measured on 64² to 1024² grids, bench/results/colour_order.md), at every budget tried."""
    runs = {}
    for name, order in (("longest first", topology.SWEEP_ORDER), ("classes", topology.CLASS_ORDER)):
        monkeypatch.setattr(topology, "SWEEP_ORDER", order)
        sim = Simulator(hanging(24, substeps, iterations), "cpu")
        for _ in range(30):
            sim.step_frame()
        runs[name] = sim.stretch()
    assert runs["longest first"].rms < 0.85 * runs["classes"].rms
    assert runs["longest first"].max < runs["classes"].max
