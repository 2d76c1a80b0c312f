"""A mesh cloth's particles renumbered for locality: the order the Model holds them in on the device.

A relaxation sweep is one launch per colour, one thread per stick, and each stick reads its two particles. A
grid's particles are in row-major order, so the sticks of a colour, taken in order, read memory forward. A mesh's
particles come in whatever order its file lists its vertices, which need not place neighbours near each other.
The Model can therefore hold a mesh cloth's particles in Morton order (Z order) of their rest positions: particles
close in space are close in memory, and with each colour's sticks sorted by their first particle
(warp_verlet/geometry/colouring.stick_order) a launch walks memory forward as it does on a grid. It does so
("auto") where that brings the sticks' ends much closer in memory than the file's order (LOCALITY_GAIN), and
always with ``particle_order = "morton"``: a file that already lists its vertices row by row measured faster
as it is on an H100.

Morton order needs only the rest positions (no graph, no new dependency: a few lines of numpy, a fraction of a
second at a million particles) and does not depend on the order the file lists the vertices in, except between
particles that share one of the 2^21 cells per axis. Reverse Cuthill-McKee of the stick graph (scipy's) was
measured beside it (bench/particle_orders.py, bench/results/mesh): both beat a shuffled vertex list by the same
margin, within about 10% of each other, so the order that needs no new dependency was taken.

The user never sees this order: the Model keeps the permutation (``Model.scene_particle``) and the State's host
readbacks return the particles in the scene's order. Grid cloths are never renumbered: their analytic colouring
and implicit sticks rely on row-major order.

This module uses numpy only.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import ArgumentError
from .faces import Faces

MORTON_BITS = 21  # per axis: three axes interleaved fill 63 bits of one uint64 code


def _spread_bits(values: np.ndarray) -> np.ndarray:
    """Each value's low 21 bits moved to every third bit (bit i to bit 3i), as uint64."""
    x = values.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


def morton_codes(points: np.ndarray) -> np.ndarray:
    """(n,) uint64 Morton codes of ``points`` (n, 3): each point's cell in a grid of 2^21 cubes per axis over
    their bounding box (one cube size on every axis, so that a flat or long cloth keeps square cells), the
    cell's three coordinates' bits interleaved."""
    p = np.asarray(points, np.float64)
    if len(p) == 0:
        return np.zeros(0, np.uint64)
    lo = p.min(axis=0)
    span = float((p.max(axis=0) - lo).max())
    scale = (2 ** MORTON_BITS - 1) / span if span > 0 else 0.0
    cell = np.floor((p - lo) * scale).astype(np.int64)
    return _spread_bits(cell[:, 0]) | (_spread_bits(cell[:, 1]) << np.uint64(1)) | (_spread_bits(cell[:, 2]) << np.uint64(2))


def locality_order(points: np.ndarray) -> np.ndarray:
    """(n,) int32: the particles in Morton order of ``points`` (their rest positions); ties (one cell) keep
    their given order. ``order[k]`` is the particle that goes to place k."""
    return np.argsort(morton_codes(points), kind="stable").astype(np.int32)


LOCALITY_GAIN = 4.0
"""``particle_order = "auto"`` renumbers a mesh cloth only where Morton order brings its sticks' ends this many
times closer in memory on average: on an H100 at 1024^2, renumbering a mesh whose file already lists its vertices
row by row made a sweep slower (bench/results/mesh/h100-orders.md), while a shuffled vertex list gains from it."""


def mean_stick_span(sticks: np.ndarray, place: np.ndarray | None = None) -> float:
    """The mean |i - j| over ``sticks`` (M, 2), with particle p held at ``place[p]`` (its own index if None)."""
    if len(sticks) == 0:
        return 0.0
    ends = sticks if place is None else place[sticks]
    return float(np.abs(ends[:, 0].astype(np.int64) - ends[:, 1]).mean())


def wants_locality_order(topology, order: np.ndarray) -> bool:
    """Whether holding ``topology``'s particles in ``order`` brings its sticks' ends LOCALITY_GAIN times closer
    in memory than the file's order does."""
    return mean_stick_span(topology.sticks) > LOCALITY_GAIN * mean_stick_span(topology.sticks, inverse_order(order))


def inverse_order(order: np.ndarray) -> np.ndarray:
    """(n,) int32: the place each particle goes to under ``order`` (``inverse[order[k]] == k``)."""
    inverse = np.empty(len(order), np.int32)
    inverse[order] = np.arange(len(order), dtype=np.int32)
    return inverse


def reorder_topology(topology, order: np.ndarray):
    """``topology`` (a mesh cloth's ClothTopology) with its particles renumbered: new particle k is old particle
    ``order[k]``. Everything indexed by particle follows (positions, masses, sticks, faces, pins), each stick
    is stored (low, high) and the sticks are sorted within each family, as a mesh given in this order would
    have them; the vertices stay the source's, each following its particle (``vertex_particle``), so the cache
    it writes is the same."""
    if topology.is_grid:
        raise ArgumentError(f"cloth {topology.name!r} is a grid: its analytic colouring and implicit sticks rely on "
                         "its row-major order, so it is never renumbered")
    n = topology.particle_count
    order = np.asarray(order, np.int32)
    if order.shape != (n,) or not np.array_equal(np.sort(order), np.arange(n)):
        raise ArgumentError(f"cloth {topology.name!r}: expected a permutation of its {n} particles")
    new = inverse_order(order)
    sticks = np.sort(new[topology.sticks], axis=1).astype(np.int32)
    by_family = np.lexsort((sticks[:, 1], sticks[:, 0], topology.family))
    faces = Faces(topology.faces.counts, new[topology.faces.indices])
    of_vertex = new if topology.vertex_particle is None else new[topology.vertex_particle]
    return replace(topology, positions=topology.positions[order], inv_mass=topology.inv_mass[order],
                   sticks=sticks[by_family], rest_length=topology.rest_length[by_family],
                   compliance=topology.compliance[by_family], family=topology.family[by_family], faces=faces,
                   pinned=np.sort(new[topology.pinned]).astype(np.int32), vertex_particle=of_vertex.astype(np.int32),
                   vertex_faces=topology.cache_faces)
