"""Stick colouring: partition the sticks so that no two sticks of one colour share a particle.

Kept apart from the solver, as Box2D v3 keeps its constraint graph apart from its solver: the solver only
sees "sticks sorted by colour, with offsets". Two colourings are offered:

- :func:`grid_colouring`, the analytic fast path for regular grids: each of the six stick directions gets
  two colours by the parity of its anchor row or column, so structural + shear + bend needs 12 colours,
  the minimum (a grid particle touches 12 sticks); the directions come in the order a sweep projects them
  (topology.SWEEP_ORDER).
- :func:`graph_colouring`, for any topology: Warp's ``wp.utils.graph_coloring_assign`` on the
  stick-conflict graph (nodes are sticks, edges join sticks that share a particle), then
  ``graph_coloring_balance`` to even out colour sizes.
- :func:`colour`, the same for elements on any number of particles (an angle limit on three, a dihedral on
  four), with an *overflow colour*: past ``max_colours`` the remaining elements go into one last colour whose
  elements may share particles, which one thread projects one after another (as Box2D v3's constraint graph
  keeps an overflow set for the constraints its colours cannot take).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError

from . import topology
from .topology import BEND_H, BEND_V, SHEAR_ANTI, SHEAR_DIAG, STRUCT_H, STRUCT_V


@dataclass(frozen=True)
class Colouring:
    colour: np.ndarray  # (M,) int32, colour of each stick (or element)
    count: int
    method: str
    overflow: bool = False  # the last colour is the overflow colour: its elements may share particles

    @property
    def sizes(self) -> np.ndarray:
        return np.bincount(self.colour, minlength=self.count)

    @property
    def balance(self) -> float:
        """Largest colour over smallest non-empty colour (1 = perfectly balanced)."""
        sizes = self.sizes[self.sizes > 0]
        return float(sizes.max() / sizes.min()) if sizes.size else 1.0


def grid_colouring(grid_class: np.ndarray, anchor: np.ndarray, order: tuple[int, ...] | None = None) -> Colouring:
    """Analytic colouring of grid sticks. A stick's colour is 2 * (its class's place in ``order``) + parity, where
    parity is that of the coordinate along which neighbouring sticks of the same direction would share a
    particle: the colours come in the order a sweep projects them. ``order``: the six grid classes, by default
    topology.SWEEP_ORDER (read at the call)."""
    rank = np.empty(6, np.int32)
    rank[list(topology.SWEEP_ORDER if order is None else order)] = np.arange(6)
    row, col = anchor[:, 0], anchor[:, 1]
    parity = np.select(
        [grid_class == STRUCT_H, grid_class == STRUCT_V, np.isin(grid_class, (SHEAR_DIAG, SHEAR_ANTI)),
         grid_class == BEND_H, grid_class == BEND_V],
        # A bend stick spans two cells, so sticks 2 apart share a particle: colour by pairs of columns/rows.
        [col % 2, row % 2, row % 2, (col // 2) % 2, (row // 2) % 2],
    )
    raw = 2 * rank[grid_class] + parity.astype(np.int32)
    return _compact(raw, "grid analytic")


def stick_conflict_edges(sticks: np.ndarray) -> np.ndarray:
    """Edges of the graph whose nodes are sticks (or elements of k particles, (M, k)), joining every pair that
    shares a particle."""
    m, k = sticks.shape if sticks.ndim == 2 else (len(sticks), 2)
    edges = shared_particle_pairs(np.repeat(np.arange(m, dtype=np.int64), k), sticks.reshape(-1))
    # Two distinct sticks share at most one particle, so no pair comes out twice: a lexicographic sort gives
    # what np.unique(axis=0) gave, many times faster on large grids (bench/results/code_choices.md). Elements
    # of more particles may share several, so their pairs are made unique.
    if k > 2:
        return np.unique(edges, axis=0).astype(np.int32)
    return edges[np.lexsort((edges[:, 1], edges[:, 0]))].astype(np.int32)


def shared_particle_pairs(element: np.ndarray, particle: np.ndarray) -> np.ndarray:
    """(a, b), a < b, for every two entries (element[e], particle[e]) of distinct entries with the same particle:
    the pairs of elements that share it, once per particle they share (unsorted), as int64."""
    particle = np.asarray(particle, np.int64)
    order = np.argsort(particle, kind="stable")
    particle, element = particle[order], np.asarray(element, np.int64)[order]
    starts = np.flatnonzero(np.r_[True, particle[1:] != particle[:-1]])
    counts = np.diff(np.r_[starts, particle.size])
    pairs = []
    # Group particles by degree so that each group is one vectorised upper-triangle expansion.
    for degree in np.unique(counts):
        if degree < 2:
            continue
        group = starts[counts == degree][:, None] + np.arange(degree)[None, :]
        members = element[group]  # (particles, degree)
        a, b = np.triu_indices(degree, k=1)
        pairs.append(np.stack([members[:, a].ravel(), members[:, b].ravel()], axis=1))
    if not pairs:
        return np.zeros((0, 2), np.int64)
    return np.sort(np.concatenate(pairs), axis=1)


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


MAX_COLOURS = 64
"""The most colours :func:`colour` makes, the overflow colour included: a colour is one launch per sweep, and
past a few dozen the launches cost more than projecting the few remaining elements on one thread."""


def colour(elements: np.ndarray, max_colours: int = MAX_COLOURS) -> Colouring:
    """Colour elements of k particles each ((M, k) int array) so that no two elements of a colour share a
    particle, with Warp's graph colouring of their conflict graph; elements past colour ``max_colours - 1`` go
    into one overflow colour (the last), whose elements may share particles and are projected in order by one
    thread (``Colouring.overflow``)."""
    elements = np.asarray(elements)
    if elements.ndim != 2 or elements.shape[1] < 1:
        raise ArgumentError(f"expected an (M, k) array of particle indices, got shape {elements.shape}")
    if max_colours < 2:
        raise ArgumentError(f"max_colours must be at least 2 (one colour and the overflow), got {max_colours}")
    coloured = graph_colouring(elements)
    if coloured.count <= max_colours:
        return coloured
    capped = np.minimum(coloured.colour, max_colours - 1).astype(np.int32)
    return Colouring(capped, max_colours, coloured.method + f", overflow past {max_colours - 1}", overflow=True)


def stick_order(colour: np.ndarray, sticks: np.ndarray) -> np.ndarray:
    """The order that sorts sticks by colour and, inside a colour, by first particle, then second. A colour is
    one launch with one thread per stick, so a launch then reads memory forward (its sticks share no particle,
    so their order inside a colour changes no result). A grid's sticks are in this order already (each colour
    is one direction, its sticks in row-major order of their first particle)."""
    return np.lexsort((sticks[:, 1], sticks[:, 0], colour))


def colour_ranges(colouring: Colouring) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """The order that sorts elements by colour (stable), and each non-empty colour's (first, count) in it."""
    order = np.argsort(colouring.colour, kind="stable")
    sizes = colouring.sizes
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    return order, [(int(a), int(n)) for a, n in zip(starts, sizes) if n > 0]


def check_partition(sticks: np.ndarray, colour: np.ndarray, overflow: int | None = None) -> None:
    """Raise AssertionError unless every colour's sticks (or elements, (M, k)) touch pairwise-distinct
    particles; the ``overflow`` colour, projected by one thread, may share them."""
    for c in np.unique(colour):
        if c == overflow:
            continue
        ends = sticks[colour == c].reshape(-1)
        if np.unique(ends).size != ends.size:
            values, counts = np.unique(ends, return_counts=True)
            raise AssertionError(f"colour {c} holds two sticks sharing particle {values[counts > 1][0]}")


def _compact(raw: np.ndarray, method: str) -> Colouring:
    """Renumber colours 0..count-1 in order of first use (absent stick families leave gaps)."""
    used, colour = np.unique(raw, return_inverse=True)
    return Colouring(colour.astype(np.int32), int(used.size), method)
