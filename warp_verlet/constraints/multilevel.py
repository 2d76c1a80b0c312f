"""The grid hierarchy of the multilevel solve (hierarchical position-based dynamics, Mueller 2008).

Why: a Gauss-Seidel sweep carries a correction about one stick per colour pass, so a 1024^2 cloth needs
hundreds of sweeps before its hem feels its pins. On a coarse level of every second particle a sweep carries
it twice as far per pass, on the next level four times, and so on: one pass down the hierarchy spreads a
correction across the whole cloth.

Level 0 is the cloth. Level l keeps every second row and column of level l - 1, and always its first and
last, so that the border of the cloth is on every level. A level's particles are real particles of the cloth
(no copies): its *coarse sticks* join neighbouring level-l particles along rows, columns and both diagonals,
with the rest-pose distance as a **limit, not a length**: a coarse stick acts only when its two particles
are further apart than they are in the rest pose. A flat cloth cannot pull two of its points further apart
than that without stretching, but it may bring them closer by folding or draping. A bilateral coarse stick
would forbid the fold (a CPU prototype with bilateral coarse sticks pulled a sheet lying on the ground
together to 1% of its area); a unilateral one leaves folds, drapes and contact to the fine level.

After level l's sweeps, the particles of level l - 1 that level l does not hold (its *children*) move by
the bilinear interpolation of their parents' moves since the start of the pass (the parents are the level-l
particles around them, in index space). Pins have zero inverse mass, neither move nor are moved.
Everything here is host-side numpy, built once per model; kernels/multilevel.py does the work per substep.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .kind import ConstraintSet
from ..geometry.colouring import grid_colouring
from ..launches import FLOAT, INT, VEC2I, BoundStage, recorded
from ..geometry.topology import CLASS_ORDER, SHEAR_ANTI, SHEAR_DIAG, STRUCT_H, STRUCT_V


def coarser(index: np.ndarray) -> np.ndarray:
    """Every second entry of a level's row (or column) indices, and always the last one."""
    kept = index[::2]
    return kept if kept[-1] == index[-1] else np.r_[kept, index[-1]]


def level_axes(rows: int, cols: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (row indices, column indices) of levels 1, 2, ... down to the coarsest level that still has a
    coarse stick to project (at least two particles along a row or a column), for a rows x cols grid."""
    r, c = np.arange(rows), np.arange(cols)
    levels = []
    while len(r) > 2 or len(c) > 2:
        r, c = coarser(r), coarser(c)
        levels.append((r, c))
    return levels


def _coarse_sticks(r: np.ndarray, c: np.ndarray, cols: int):
    """Coarse sticks of one level, as local particle pairs, with the grid class and anchor (in the level's
    own index space) that the analytic grid colouring needs."""
    nr, nc = len(r), len(c)
    ends, classes, anchors = [], [], []
    for dr, dc, cls in ((0, 1, STRUCT_H), (1, 0, STRUCT_V), (1, 1, SHEAR_DIAG), (1, -1, SHEAR_ANTI)):
        ii = np.arange(nr - dr)
        jj = np.arange(max(0, -dc), nc - max(0, dc))
        if ii.size == 0 or jj.size == 0:
            continue
        ii, jj = np.meshgrid(ii, jj, indexing="ij")
        ii, jj = ii.ravel(), jj.ravel()
        a = r[ii] * cols + c[jj]
        b = r[ii + dr] * cols + c[jj + dc]
        ends.append(np.stack([a, b], axis=1))
        classes.append(np.full(len(a), cls, np.int8))
        anchors.append(np.stack([ii, jj], axis=1))
    return np.concatenate(ends), np.concatenate(classes), np.concatenate(anchors)


def _parents(fine: np.ndarray, coarse: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each fine index: the coarse indices on either side and the weight of the second (linear
    interpolation in index space; a fine index that is also coarse has itself twice, weight 0)."""
    right = np.searchsorted(coarse, fine, side="left")
    exact = coarse[np.minimum(right, len(coarse) - 1)] == fine
    hi = np.minimum(right, len(coarse) - 1)  # the first and last fine index are coarse: never past the end
    lo = np.where(exact, hi, hi - 1)
    a, b = coarse[lo], coarse[hi]
    t = np.where(b > a, (fine - a) / np.maximum(b - a, 1), 0.0)
    return a, b, t


def _children(fine: tuple[np.ndarray, np.ndarray], coarse: tuple[np.ndarray, np.ndarray], cols: int):
    """The particles of the finer level that the coarser one does not hold, each with four parents and
    bilinear weights (repeated parents carry the weight of the missing ones)."""
    (fr, fc), (cr, cc) = fine, coarse
    ra, rb, rt = _parents(fr, cr)
    ca, cb, ct = _parents(fc, cc)
    is_coarse = np.isin(fr, cr)[:, None] & np.isin(fc, cc)[None, :]
    ri, ci = np.nonzero(~is_coarse)
    child = fr[ri] * cols + fc[ci]
    parents = np.stack([ra[ri] * cols + ca[ci], ra[ri] * cols + cb[ci],
                        rb[ri] * cols + ca[ci], rb[ri] * cols + cb[ci]], axis=1)
    u, v = rt[ri], ct[ci]
    weights = np.stack([(1 - u) * (1 - v), (1 - u) * v, u * (1 - v), u * v], axis=1)
    return child, parents, weights


@dataclass(frozen=True)
class Level:
    """One level, particle indices global. ``ends``/``limit`` are its coarse sticks sorted by colour, with
    ``colour_ranges`` (first, count) into them; ``child``/``parents``/``weights`` the particles of the next
    finer level that this one moves by interpolation."""

    ends: np.ndarray  # (Mc, 2) int32
    limit: np.ndarray  # (Mc,) float32, m: the rest-pose distance, the most the two may be apart
    colour_ranges: tuple[tuple[int, int], ...]
    child: np.ndarray  # (C,) int32
    parents: np.ndarray  # (C, 4) int32
    weights: np.ndarray  # (C, 4) float32, summing to 1


def grid_hierarchy(rows: int, cols: int, positions: np.ndarray, first: int = 0) -> list[Level]:
    """Levels of one rows x cols grid whose particle 0 is global particle ``first``, coarsest first (the
    order a pass runs them). ``positions`` are the cloth's rest positions (N, 3)."""
    axes = level_axes(rows, cols)
    finer = [(np.arange(rows), np.arange(cols))] + axes[:-1]
    pos64 = positions.astype(np.float64)
    levels = []
    for fine, coarse in zip(finer, axes):
        ends, classes, anchors = _coarse_sticks(*coarse, cols)
        # Structural sticks first, whatever the fine sweep's order: a smooth stretch is then taken out exactly
        # (shear sticks projected first pull the particles sideways; tests/test_multilevel.py).
        colouring = grid_colouring(classes, anchors, order=CLASS_ORDER)
        order = np.argsort(colouring.colour, kind="stable")
        ends = ends[order]
        sizes = colouring.sizes
        starts = np.r_[0, np.cumsum(sizes)[:-1]]
        limit = np.linalg.norm(pos64[ends[:, 1]] - pos64[ends[:, 0]], axis=1).astype(np.float32)
        child, parents, weights = _children(fine, coarse, cols)
        levels.append(Level(
            ends=(ends + first).astype(np.int32), limit=limit,
            colour_ranges=tuple((int(a), int(n)) for a, n in zip(starts, sizes) if n > 0),
            child=(child + first).astype(np.int32), parents=(parents + first).astype(np.int32),
            weights=weights.astype(np.float32)))
    return levels[::-1]


def hierarchy_counts(rows: int, cols: int) -> tuple[int, int]:
    """(coarse sticks, children) over all levels of a rows x cols grid, without building it."""
    sticks = children = 0
    fine = (rows, cols)
    for r, c in level_axes(rows, cols):
        nr, nc = len(r), len(c)
        sticks += nr * (nc - 1) + (nr - 1) * nc + 2 * (nr - 1) * (nc - 1)
        children += fine[0] * fine[1] - nr * nc
        fine = (nr, nc)
    return sticks, children


def merge_levels(per_cloth: list[list[Level]]) -> list[Level]:
    """One level list for all cloths: level k of every cloth, joined (coarsest first, aligned at the finest
    level so that level k means the same stride everywhere). Cloths touch disjoint particles, so the union
    of colour c of each is still a colour."""
    depth = max((len(levels) for levels in per_cloth), default=0)
    merged = []
    for k in range(depth):
        parts = [levels[len(levels) - depth + k] for levels in per_cloth if len(levels) - depth + k >= 0]
        colours = max(len(p.colour_ranges) for p in parts)
        ends, limit, ranges, first = [], [], [], 0
        for colour in range(colours):
            count = 0
            for p in parts:
                if colour < len(p.colour_ranges):
                    a, n = p.colour_ranges[colour]
                    ends.append(p.ends[a:a + n])
                    limit.append(p.limit[a:a + n])
                    count += n
            ranges.append((first, count))
            first += count
        merged.append(Level(
            ends=np.concatenate(ends), limit=np.concatenate(limit), colour_ranges=tuple(ranges),
            child=np.concatenate([p.child for p in parts]), parents=np.concatenate([p.parents for p in parts]),
            weights=np.concatenate([p.weights for p in parts])))
    return merged


@dataclass(frozen=True)
class DeviceLevel:
    """One level of the multilevel hierarchy on the device (of a :class:`Level`)."""

    ends: Any  # (Mc,) vec2i wp.array
    limit: Any  # (Mc,) float32, m
    colour_ranges: tuple[tuple[int, int], ...]
    child: Any  # (C,) int32
    parents: Any  # (C,) vec4i
    weights: Any  # (C,) vec4 float32


class MultilevelData:
    """The hierarchy of every grid cloth on the device: ``levels``, one :class:`DeviceLevel` per level, coarsest
    first (each cloth's levels merged, so one launch per colour serves every cloth)."""

    def __init__(self, model, device):
        import warp as wp

        per_cloth = [grid_hierarchy(s.topology.rows, s.topology.cols, s.topology.positions, s.first)
                     for s in model.cloths]
        self.levels = [DeviceLevel(
            ends=wp.array(level.ends, dtype=wp.vec2i, device=device),
            limit=wp.array(level.limit, dtype=float, device=device), colour_ranges=level.colour_ranges,
            child=wp.array(level.child, dtype=int, device=device),
            parents=wp.array(level.parents, dtype=wp.vec4i, device=device),
            weights=wp.array(level.weights, dtype=wp.vec4, device=device)) for level in merge_levels(per_cloth)]


class Multilevel(ConstraintSet):
    """The multilevel pass (the hierarchy above, kernels/multilevel.py): once per substep, before the
    sweeps, coarsest level first: ``multilevel_sweeps`` sweeps of a level's unilateral coarse sticks, then its
    moves interpolated to the next finer level's other particles. It must run first in the relaxation: it
    measures each particle's move from the Verlet prediction."""

    name = "multilevel"
    reads_positions_before_sweeps = True

    def needed(self, req) -> bool:
        return req.coarse_sticks > 0

    def device_bytes(self, req) -> int:
        # ends and limit per coarse stick; child, four parents and four weights per child
        return req.coarse_sticks * (VEC2I + FLOAT) + req.coarse_children * (INT + 4 * INT + 4 * FLOAT)

    def build(self, model, scene, device):
        return MultilevelData(model, device)

    def bind(self, model, state, solver) -> BoundStage:
        from warp_verlet.kernels.multilevel import limit_coarse_colour, prolongate

        x, x_inertial, inv_mass = state.particle_q, state.particle_q_inertial, model.inv_mass
        sweeps = solver.settings.multilevel_sweeps
        tasks = []
        for level in model.constraints[self.name].levels:
            colours = [recorded(limit_coarse_colour, n, [x, inv_mass, level.ends, level.limit, f])
                       for f, n in level.colour_ranges]
            tasks += colours * sweeps
            tasks.append(recorded(prolongate, level.child.shape[0], [x, x_inertial, inv_mass, level.child,
                                                                     level.parents, level.weights]))
        runs = [task.run for task in tasks]

        def run(state, dt: float) -> None:
            for task in runs:
                task()

        return BoundStage(run, [])
