"""Whether self-collision could hold the run's layers apart: the run watches how fast its colliding particles move
relative to their neighbours in space, and says so where they outran the contact.

Self-contact (constraints/self_contact.py) finds its pairs once a substep and pushes apart those closer than the
collision thickness; a layer that approaches another by more than about half the thickness in one substep can be
past it before the pair is ever found closer than the thickness, and the layers then pass through each other
without a sign. The run cannot see each substep, but it holds every frame's positions for the cache anyway. Over a
frame of S substeps, the colliding particles that end the frame in one cell of ``NEAR_THICKNESSES`` x the
thickness are near enough to have met; the box their moves spread over, its diagonal divided by S, bounds how
fast any two of them approached each other in an average substep. Where that exceeds ``SAFE_FRACTION`` of the
thinnest colliding cloth's thickness, the summary warns, with the frame, the speed, the substeps that would keep
it under, and the stride or thickness of each cloth that would make the contact thick enough instead. A cloth that falls or swings as one piece spreads nothing in a cell, and neither do two far-apart parts
of a cloth that move differently.
"""

from __future__ import annotations

import math

import numpy as np

SAFE_FRACTION = 0.5
"""The relative move per substep, as a fraction of the collision thickness, up to which the contact holds (the
rule ``collision_thickness`` documents)."""
NEAR_THICKNESSES = 4.0
"""The cells' size, in collision thicknesses: particles that end a frame in one cell are at most 6.9 thicknesses
apart."""
SAMPLE_LIMIT = 16384
"""Colliding particles watched at most (a fixed random sample of them beyond this), so that the check costs the run a few
milliseconds a frame on the host at most, and only in frames whose moves spread past the limit at all."""


class ContactSpeedWatch:
    """Follows the colliding particles of the cloths with ``self_collision`` through the run's frames
    (``observe``) and keeps the fastest relative move per substep against the thinnest of their thicknesses."""

    def __init__(self, scene, model, gate: float = SAFE_FRACTION):
        """``gate``: the fraction of the thickness below which a frame's cells are not sorted out (the check
        needs only moves past the warning's limit; a measurement of the moves themselves passes 0)."""
        from ..constraints.self_contact import colliding_particles, thickness_of

        indices, self.specs = [], []  # per colliding cloth: (its spec, its thickness m)
        for slot, spec in zip(model.cloths, scene.cloths):
            h = thickness_of(spec)
            if h is None:
                continue
            indices.append(slot.first + colliding_particles(spec))
            self.specs.append((spec, h))
        self.active = bool(indices)
        if not self.active:
            return
        watched = np.concatenate(indices)
        if len(watched) > SAMPLE_LIMIT:
            # A fixed random sample, spread over the cloth as every k-th index is not (on a grid, every k-th of
            # them falls in a few columns, which another layer's sample may never share a cell with).
            watched = np.sort(np.random.default_rng(0).choice(watched, SAMPLE_LIMIT, replace=False))
        self.watched = watched
        thinnest, self.thickness = min(self.specs, key=lambda pair: pair[1])
        self.thinnest = thinnest.name
        self.gate = gate * self.thickness
        self.previous: np.ndarray | None = None
        self.worst = 0.0  # the fastest relative move per substep seen, m
        self.worst_frame = 0
        self.worst_substeps = 1

    def observe(self, frame: int, points: np.ndarray, substeps: int) -> None:
        """Frame ``frame``'s positions (scene order), stepped in ``substeps`` substeps since the last ones."""
        if not self.active:
            return
        now = points[self.watched]
        if self.previous is not None:
            moves = now - self.previous
            # The spread of all the moves bounds every cell's: cells are sorted out only where it could matter.
            limit = max(self.worst, self.gate) * substeps
            if np.linalg.norm(moves.max(axis=0) - moves.min(axis=0)) > limit:
                spread = local_spread(now, moves, NEAR_THICKNESSES * self.thickness) / substeps
                if spread > self.worst:
                    self.worst, self.worst_frame, self.worst_substeps = spread, frame, substeps
        self.previous = now  # points[watched] is a copy already

    def advice(self) -> str | None:
        """The warning where the colliding particles outran the contact, else None."""
        if not self.active or self.worst <= SAFE_FRACTION * self.thickness:
            return None
        needed = math.ceil(self.worst_substeps * self.worst / (SAFE_FRACTION * self.thickness))
        names = [spec.name for spec, _ in self.specs]
        which = (f"cloth '{names[0]}'" if len(names) == 1
                 else "the self-colliding cloths (" + ", ".join(f"'{n}'" for n in names) + ")")
        wanted = self.worst / SAFE_FRACTION
        thicker = [thicker_contact(spec, h, wanted) for spec, h in self.specs if h < wanted]
        thicker = " and ".join(thicker) if all(thicker) else None
        return (f"{which}: colliding particles moved up to {self.worst * 1e3:.3g} mm relative to each other in a "
                f"substep (frame {self.worst_frame}, {self.worst_substeps} substeps), over "
                f"{SAFE_FRACTION:g} x the collision_thickness ({self.thickness * 1e3:.3g} mm, cloth "
                f"'{self.thinnest}'): layers that fast can pass through each other between two substeps; give it "
                f"substeps = {needed} or more, or {thicker or 'a thicker contact (a larger self_collision_stride)'}")


def thicker_contact(spec, thickness: float, needed: float) -> str | None:
    """The keys that give cloth ``spec`` (now at collision ``thickness``, m) a contact of at least ``needed`` m,
    as the summary's advice, or None where no stride of it allows one: a larger ``self_collision_stride`` where
    the thickness is its default (which grows with the stride), else ``collision_thickness``, with a stride where
    the thickness would pass its collision spacing (the rest spacing times the stride)."""
    from ..constraints.self_contact import DEFAULT_FRACTION, rest_spacing, stride_of

    stride, spacing = stride_of(spec), rest_spacing(spec)
    if spacing is None:
        return None
    longest = None if spec.mesh is not None else min(spec.resolution) - 1  # a grid's largest stride
    where = f"on cloth '{spec.name}'"
    if math.isclose(thickness, DEFAULT_FRACTION * spacing * stride, rel_tol=1e-6):
        wider = math.ceil(stride * needed / thickness * (1 - 1e-9))
        if longest is not None and wider > longest:
            return None
        return (f"self_collision_stride = {wider} {where} (its default thickness then "
                f"{DEFAULT_FRACTION * spacing * wider * 1e3:.3g} mm)")
    if needed <= spacing * stride:
        return f"collision_thickness = {needed:.3g} {where} (m; at most {spacing * stride:.3g} at its stride)"
    wider = math.ceil(needed / spacing * (1 - 1e-9))
    if longest is not None and wider > longest:
        return None
    return f"self_collision_stride = {wider} and collision_thickness = {needed:.3g} {where} (m)"


def local_spread(points: np.ndarray, moves: np.ndarray, cell: float) -> float:
    """The largest diagonal of the box over which the ``moves`` of the ``points`` in one cubic cell of side
    ``cell`` spread (cells counted from the points' lowest corner; past 2^21 cells an axis, the farthest share
    the last)."""
    index = np.floor((points - points.min(axis=0)) / cell).astype(np.int64)
    np.clip(index, 0, (1 << 21) - 1, out=index)
    key = (index[:, 0] << 42) | (index[:, 1] << 21) | index[:, 2]
    order = np.argsort(key, kind="stable")
    key, moves = key[order], moves[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    highest = np.maximum.reduceat(moves, starts, axis=0)
    lowest = np.minimum.reduceat(moves, starts, axis=0)
    return float(np.sqrt(((highest - lowest) ** 2).sum(axis=1)).max())
