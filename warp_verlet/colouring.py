"""Stick colouring: partition the sticks so that no two sticks of one colour share a particle.

Kept apart from the solver, as Box2D v3 keeps its constraint graph apart from its solver: the solver only
sees "sticks sorted by colour, with offsets". Two colourings are offered:

- :func:`grid_colouring`, the analytic fast path for regular grids: each of the six stick directions gets
  two colours by the parity of its anchor row or column, so structural + shear + bend needs 12 colours,
  the minimum (a grid particle touches 12 sticks).
- :func:`graph_colouring`, for any topology: Warp's ``wp.utils.graph_coloring_assign`` on the
  stick-conflict graph (nodes are sticks, edges join sticks that share a particle), then
  ``graph_coloring_balance`` to even out colour sizes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .topology import BEND_H, BEND_V, SHEAR_ANTI, SHEAR_DIAG, STRUCT_H, STRUCT_V


@dataclass(frozen=True)
class Colouring:
    colour: np.ndarray  # (M,) int32, colour of each stick
    count: int
    method: str

    @property
    def sizes(self) -> np.ndarray:
        return np.bincount(self.colour, minlength=self.count)

    @property
    def balance(self) -> float:
        """Largest colour over smallest non-empty colour (1 = perfectly balanced)."""
        sizes = self.sizes[self.sizes > 0]
        return float(sizes.max() / sizes.min()) if sizes.size else 1.0


def grid_colouring(grid_class: np.ndarray, anchor: np.ndarray) -> Colouring:
    """Analytic colouring of grid sticks. A stick's colour is 2 * class + parity, where parity is that of
    the coordinate along which neighbouring sticks of the same direction would share a particle."""
    row, col = anchor[:, 0], anchor[:, 1]
    parity = np.select(
        [grid_class == STRUCT_H, grid_class == STRUCT_V, np.isin(grid_class, (SHEAR_DIAG, SHEAR_ANTI)),
         grid_class == BEND_H, grid_class == BEND_V],
        # A bend stick spans two cells, so sticks 2 apart share a particle: colour by pairs of columns/rows.
        [col % 2, row % 2, row % 2, (col // 2) % 2, (row // 2) % 2],
    )
    raw = 2 * grid_class.astype(np.int32) + parity.astype(np.int32)
    return _compact(raw, "grid analytic")


def stick_conflict_edges(sticks: np.ndarray) -> np.ndarray:
    """Edges of the graph whose nodes are sticks, joining every pair of sticks that share a particle."""
    m = len(sticks)
    stick_of_end = np.repeat(np.arange(m, dtype=np.int64), 2)
    particle = sticks.reshape(-1).astype(np.int64)
    order = np.argsort(particle, kind="stable")
    particle, stick_of_end = particle[order], stick_of_end[order]
    starts = np.flatnonzero(np.r_[True, particle[1:] != particle[:-1]])
    counts = np.diff(np.r_[starts, particle.size])
    pairs = []
    # Group particles by degree so that each group is one vectorised upper-triangle expansion.
    for degree in np.unique(counts):
        if degree < 2:
            continue
        group = starts[counts == degree][:, None] + np.arange(degree)[None, :]
        members = stick_of_end[group]  # (particles, degree)
        a, b = np.triu_indices(degree, k=1)
        pairs.append(np.stack([members[:, a].ravel(), members[:, b].ravel()], axis=1))
    if not pairs:
        return np.zeros((0, 2), np.int32)
    # Two distinct sticks share at most one particle, so no pair comes out twice: a lexicographic sort gives
    # what np.unique(axis=0) gave (it took 16 s at 512^2, the sort under one).
    edges = np.sort(np.concatenate(pairs), axis=1)
    return edges[np.lexsort((edges[:, 1], edges[:, 0]))].astype(np.int32)


def graph_colouring(sticks: np.ndarray, balance: bool = True) -> Colouring:
    """Colour any stick topology with Warp's graph colouring of the stick-conflict graph."""
    import warp as wp

    m = len(sticks)
    if m == 0:
        return Colouring(np.zeros(0, np.int32), 0, "graph (empty)")
    edges = stick_conflict_edges(sticks)
    colours = wp.zeros(m, dtype=wp.int32, device="cpu")
    edges_wp = wp.array(edges.reshape(-1, 2), dtype=wp.int32, device="cpu")
    count = wp.utils.graph_coloring_assign(edges_wp, colours, wp.utils.GraphColoringAlgorithm.MCS)
    if balance and count > 1:
        wp.utils.graph_coloring_balance(edges_wp, colours, count, 1.1)
    return _compact(colours.numpy().astype(np.int32), "graph MCS" + (", balanced" if balance else ""))


def check_partition(sticks: np.ndarray, colour: np.ndarray) -> None:
    """Raise AssertionError unless every colour's sticks touch pairwise-distinct particles."""
    for c in np.unique(colour):
        ends = sticks[colour == c].reshape(-1)
        if np.unique(ends).size != ends.size:
            values, counts = np.unique(ends, return_counts=True)
            raise AssertionError(f"colour {c} holds two sticks sharing particle {values[counts > 1][0]}")


def _compact(raw: np.ndarray, method: str) -> Colouring:
    """Renumber colours 0..count-1 in order of first use (absent stick families leave gaps)."""
    used, colour = np.unique(raw, return_inverse=True)
    return Colouring(colour.astype(np.int32), int(used.size), method)
