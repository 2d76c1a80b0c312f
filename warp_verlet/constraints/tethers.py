"""Tether construction on the host: which pins each free particle is tied to, and how far it may go.

For a flat grid the straight rest-pose distance to a pin is the geodesic along the cloth (the sheet is flat
and convex), so that is the tether length. Tearing changes the geodesics: a piece torn off must not hang on a
stale tether, so when the torn set changes, tethers whose particle is no longer connected to its pin through
intact sticks are dropped (:func:`cut_tethers`). A tether whose shortest path merely detours around a tear
keeps its straight length: it may then hold that particle tighter than the torn cloth would.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kind import ConstraintSet
from ..geometry.mesh_cloth import connected_labels
from ..launches import FLOAT, FLOAT64, INT, BoundStage, elements_per_thread, recorded, split_tasks

# Distances are computed for this many (particle, pin) pairs at a time, to bound the temporary memory.
PAIRS_PER_CHUNK = 1 << 22


NO_TETHER = -1
"""A pin slot that holds no tether (kernels/tether.tethered skips any negative slot)."""
PINNED_ROW = -2
"""The first pin slot of a pinned particle's row (kernels/tether.PINNED_ROW)."""


@dataclass(frozen=True)
class TetherTable:
    """A row per particle of the span first .. first + T - 1 (from the first tethered cloth's first particle to
    the last one's last), each tied to K pins (global particle indices): NO_TETHER where a particle has fewer
    (every slot of an untethered cloth's particle), PINNED_ROW in the first slot of a pinned particle's row. Row
    r's particle is first + r, so a kernel reads no particle index; a pinned row lets the Verlet step that runs
    the tether pass (kernels/integrate.verlet_step_tethered) skip pins without reading their weights."""

    first: int
    pin: np.ndarray  # (T, K) int32
    length: np.ndarray  # (T, K) float32, m (+inf where a slot holds no tether)

    @property
    def count(self) -> int:
        return len(self.pin)

    @property
    def particle(self) -> np.ndarray:
        """(T,) int64: each row's particle."""
        return np.arange(self.first, self.first + self.count)

    @property
    def tethered(self) -> np.ndarray:
        """(T, K) bool: the slots that hold a tether."""
        return self.pin >= 0


def nearest_pins(points: np.ndarray, pins: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """For each point, the indices (into ``pins``) of its k nearest pins and their distances, nearest first;
    ties go to the lower pin index, so the choice is deterministic."""
    pins64 = pins.astype(np.float64)
    index = np.empty((len(points), k), np.int64)
    distance = np.empty((len(points), k), np.float64)
    step = max(1, PAIRS_PER_CHUNK // max(len(pins), 1))
    for start in range(0, len(points), step):
        p = points[start:start + step].astype(np.float64)
        d = np.linalg.norm(p[:, None, :] - pins64[None, :, :], axis=2)
        order = np.argsort(d, axis=1, kind="stable")[:, :k]
        index[start:start + step] = order
        distance[start:start + step] = np.take_along_axis(d, order, axis=1)
    return index, distance


def build_tethers(cloths, specs, k: int) -> TetherTable | None:
    """Tethers of every cloth that uses them (``cloths``: the model's ClothSlots, ``specs`` their ClothSpecs),
    ``k`` per particle (the model-wide count; a cloth with one pin leaves its second slot empty), in a row per
    particle of their span (TetherTable)."""
    tethered = [i for i, spec in enumerate(specs) if spec.uses_tethers]
    if not any((cloths[i].device_topology.inv_mass > 0).any() for i in tethered):
        return None  # no cloth that uses tethers has a free particle
    span = cloths[tethered[0]:tethered[-1] + 1]
    first = span[0].first
    rows = sum(slot.device_topology.particle_count for slot in span)
    pin = np.full((rows, k), NO_TETHER, np.int64)
    length = np.full((rows, k), np.inf, np.float64)
    for slot, spec in zip(span, specs[tethered[0]:tethered[-1] + 1]):
        top = slot.device_topology  # device indices, as the Model holds the particles
        row = slot.first - first
        pin[row + np.flatnonzero(top.inv_mass == 0), 0] = PINNED_ROW
        if not spec.uses_tethers:
            continue
        pinned = np.asarray(top.pinned, np.int64)
        free = np.flatnonzero(top.inv_mass > 0)
        mine = min(k, len(pinned))
        index, distance = nearest_pins(top.positions[free], top.positions[pinned], mine)
        pin[row + free, :mine] = pinned[index] + slot.first
        length[row + free, :mine] = distance * spec.tether_scale
    return TetherTable(first, pin.astype(np.int32), length.astype(np.float32))


def cut_tethers(table: TetherTable, particle_count: int, intact_sticks: np.ndarray) -> np.ndarray:
    """The tether lengths with every tether whose particle is cut off from its pin set to +inf (off)."""
    labels = connected_labels(particle_count, intact_sticks)
    length = table.length.copy()
    has_pin = table.tethered
    same = np.zeros_like(has_pin)
    same[has_pin] = labels[table.particle[:, None].repeat(table.pin.shape[1], 1)[has_pin]] == labels[table.pin[has_pin]]
    length[~same] = np.inf
    return length


class Tethers(ConstraintSet):
    """Long-range attachments (kernels/tether.py): one launch per sweep, before the sticks, so that every sweep
    starts from particles within reach of their pins. When the torn set changes, tethers cut off from their
    pin are dropped (cut_tethers above)."""

    name = "tethers"

    def needed(self, req) -> bool:
        return req.tethered > 0 and req.grid_pins == 0

    def device_bytes(self, req) -> int:
        per_row = req.tethers_per_particle * (INT + FLOAT)  # a pin and a length per tether
        live = req.tethers_per_particle * FLOAT if req.tears else 0  # the State's lengths, cut by tears
        return req.tether_rows * (per_row + live)

    def bind(self, model, state, solver) -> BoundStage:
        from warp_verlet.kernels.tether import pull_tethers

        length = state.tether_length if state.tether_length is not None else model.tether_length
        x, first, n = state.particle_q, model.tether_table.first, model.tether_table.count

        def make(f, count):
            k = elements_per_thread(count, model.device)
            return recorded(pull_tethers, count // k, [x, first + f, model.tether_pin[f:f + count],
                                                       length[f:f + count], k])
        return BoundStage(None, [split_tasks(make, 0, n, solver.threads)])

    def on_tear(self, model, state, torn: np.ndarray) -> None:
        """Drop the tethers whose particle a tear has cut off from its pin."""
        if state.tether_length is None:
            return
        state.tether_length.assign(cut_tethers(model.tether_table, model.particle_count, model.host_sticks[~torn]))


class GridTethers(ConstraintSet):
    """Tethers of a grid cloth with few pins, computed (kernels/grid_relax.py): each free particle finds its
    nearest pins and their rest-pose distances from its grid coordinates, so a sweep reads no tether table.
    One launch per sweep over the cloth's particles (pins skip), before the sticks, as Tethers."""

    name = "grid tethers"

    def needed(self, req) -> bool:
        return req.tethered > 0 and req.grid_pins > 0

    def device_bytes(self, req) -> int:
        # the pins, and per pin the squared column and row differences to it (float64)
        return req.grid_pins * (INT + (req.grid_cols + req.grid_rows) * FLOAT64)

    def bind(self, model, state, solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.grid_relax import pull_grid_tethers

        t, x = model.grid_tethers, state.particle_q

        def make(f, rows):
            return recorded(pull_grid_tethers, rows << t.col_bits,
                            [x, model.inv_mass, t.first_particle, t.cols, t.pins, t.pin_col_sq, t.pin_row_sq, t.tethers,
                             wp.float64(t.scale), t.col_bits, f])
        return BoundStage(None, [split_tasks(make, 0, t.rows, solver.threads)])
