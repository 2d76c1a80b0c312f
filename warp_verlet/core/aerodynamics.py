"""Air: drag and lift on every face of the cloths (kernels/aerodynamics.py), from ``[simulation.air]``.

What a scene asks for is counted from the scene alone (:func:`air_counts`, for ``Requirements``), the device
data is built once from the Model's particles and faces (:class:`AirModel`), and the stage
(``core/stages.Aerodynamics``) launches the face kernel before the Verlet step, which gathers each particle's
share (``kernels/integrate.verlet_step_air``). A scene without air, or with a density of 0, or whose cloths
all have both coefficients 0, needs none of it: nothing is allocated and nothing launched.

Gusts are a sum of :data:`GUST_MODES` sinusoids in space and time, each with a random direction of its own
velocity, a random direction and length of its wave (wavelengths ``gust_length`` x U(0.5, 1.5)), a random
period (``gust_period`` x U(0.5, 1.5)) and a random phase, drawn on the host with numpy's PCG64 from
``gust_seed``: the same seed gives the same field on every device. Their amplitudes are scaled so that the
RMS speed of the gust, over space and time, is ``gust_speed``.

This module does not import warp at the top (``Requirements.of`` and the memory estimate stay light).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..launches import FLOAT, FLOAT64, INT, VEC3

if TYPE_CHECKING:  # pragma: no cover
    from ..input.scene import AirSettings, ClothSpec, Scene

GUST_MODES = 4


@dataclass(frozen=True)
class AirCounts:
    """What a scene's air needs, known before anything is built: the faces that feel it and their corners over
    all cloths, the velocity's keyframes kept on the device (1 when constant), whether the air changes with time
    (a device clock) and whether it has gusts."""

    faces: int
    corners: int
    keys: int
    clock: bool
    gusts: bool


def feels_air(cloth: "ClothSpec") -> bool:
    """Whether a cloth's faces are pushed by air at all (a coefficient above 0)."""
    return cloth.drag_coefficient > 0.0 or cloth.lift_coefficient > 0.0


def cloth_face_counts(cloth: "ClothSpec") -> tuple[int, int]:
    """(faces, corners) of one cloth, from its spec: a grid's quads, a mesh's faces; a rope has none."""
    if cloth.mesh is not None:
        faces = cloth.mesh.mesh.faces
        return len(faces), int(faces.counts.sum(dtype=np.int64))
    rows, cols = cloth.resolution
    quads = (rows - 1) * (cols - 1) if rows > 1 and cols > 1 else 0
    return quads, 4 * quads


def air_counts(scene: "Scene") -> AirCounts | None:
    """The scene's air, counted; None when there is no aerodynamic force (no air, a density of 0, or no face
    with a coefficient above 0)."""
    air = scene.simulation.air
    if air is None or not air.felt:
        return None
    counts = [cloth_face_counts(c) for c in scene.cloths if feels_air(c)]
    faces, corners = sum(f for f, _ in counts), sum(k for _, k in counts)
    if faces == 0:
        return None
    return AirCounts(faces, corners, len(air.velocity) if air.moving else 1, air.moving or air.gusts, air.gusts)


def device_bytes(counts: AirCounts, particles: int, position_bytes: int, tears: bool) -> int:
    """The arrays :class:`AirModel` builds, the State's clock and the solver's scratch of face shares."""
    total = (counts.faces + 1) * INT + counts.corners * INT  # each face's corners
    total += counts.faces * VEC3  # (C_d, C_l, lightest areal density x rest area) per face
    total += (particles + 1) * INT + counts.corners * INT  # each particle's faces
    total += counts.corners * INT if tears else 0  # each side's tear entry
    total += 2 * INT + counts.keys * (FLOAT + VEC3)  # the velocity's keyframes
    total += GUST_MODES * (2 * VEC3 + 2 * FLOAT) if counts.gusts else 0
    total += FLOAT64 if counts.clock else 0
    return total + counts.faces * position_bytes  # one share per face (solver scratch)


def gust_modes(air: "AirSettings") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gusts' sinusoids from the seed: (velocity directions x amplitude (M, 3) m/s, wave vectors (M, 3)
    rad/m, (angular rate rad/s, phase rad) (M, 2)), float32, for g(x, t) = sum_m d_m sin(K_m . x - w_m t + phi_m).
    Each sine's mean square is 1/2, so M unit directions scaled by gust_speed sqrt(2 / M) give an RMS speed of
    gust_speed."""
    rng = np.random.default_rng(air.gust_seed)
    direction = rng.normal(size=(GUST_MODES, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    wave = rng.normal(size=(GUST_MODES, 3))
    wave /= np.linalg.norm(wave, axis=1, keepdims=True)
    wave *= 2.0 * np.pi / (air.gust_length * rng.uniform(0.5, 1.5, size=(GUST_MODES, 1)))
    rate = 2.0 * np.pi / (air.gust_period * rng.uniform(0.5, 1.5, size=GUST_MODES))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=GUST_MODES)
    amplitude = air.gust_speed * np.sqrt(2.0 / GUST_MODES)
    return ((direction * amplitude).astype(np.float32), wave.astype(np.float32),
            np.stack([rate, phase], axis=1).astype(np.float32))


def polygon_areas(points: np.ndarray, counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """The area of each face (faces one after another, ``counts`` corners each), float64: half the length of
    sum_k p_k x p_k+1, the vector area of a closed polygon."""
    from ..geometry.faces import next_corner

    p = points.astype(np.float64)
    cross = np.cross(p[indices], p[indices[next_corner(counts)]])
    face = np.repeat(np.arange(len(counts)), counts)
    vector = np.zeros((len(counts), 3))
    np.add.at(vector, face, cross)
    return 0.5 * np.linalg.norm(vector, axis=1)


class AirModel:
    """The air's device data, built once from a Model (its particles, faces, masses and tear entries).

    ``face_start`` (F + 1,) and ``face_corner`` (C,) int: each face's corners (global particle indices), the faces
    of the cloths that feel air, cloth after cloth. ``face_params`` (F,) vec3: (C_d, C_l, the lightest areal
    density of its corners times its rest area, kg: a corner's mass over its share of its faces' rest areas, +inf
    for a face of pins).
    ``particle_face_start`` (N + 1,) and ``particle_face`` (C,) int: each particle's faces in increasing order,
    the gather's fixed order. ``side_entry`` (C,) int, only when a cloth can tear: per corner, the tear entry of
    the stick along the side to the next corner (-1 where that side is no stick). ``key_start``, ``key_times``,
    ``key_values``: the velocity's keyframes (colliders.kind.keyframe_arrays). ``gust_direction``, ``gust_wave``,
    ``gust_timing``: the gusts' sinusoids (:func:`gust_modes`), empty without gusts. ``density``: kg/m^3 (host).
    """

    def __init__(self, model, scene: "Scene", counts: AirCounts, device):
        import warp as wp

        from ..colliders.kind import keyframe_arrays

        air = scene.simulation.air
        self.density = float(air.density)
        self.clock = counts.clock
        face_counts, corners, params = [], [], []
        for slot, spec in zip(model.cloths, scene.cloths):
            faces = slot.device_topology.faces
            if not feels_air(spec) or len(faces) == 0:
                continue
            face_counts.append(faces.counts)
            corners.append(faces.indices.astype(np.int64) + slot.first)
            params.append(np.tile([spec.drag_coefficient, spec.lift_coefficient], (len(faces), 1)))
        counts_of_face = np.concatenate(face_counts).astype(np.int64)
        corner = np.concatenate(corners)
        face_start = np.r_[0, np.cumsum(counts_of_face)]
        n = model.particle_count
        # Areal density of each corner: its mass over its share (area / corners) of every face it belongs to.
        area = polygon_areas(model.rest_positions, counts_of_face, corner)
        share = np.zeros(n)
        np.add.at(share, corner, np.repeat(area / counts_of_face, counts_of_face))
        inv_mass = model.host_inv_mass.astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            sigma = np.where((inv_mass > 0) & (share > 0), 1.0 / (inv_mass * share), np.inf)
        lightest = np.minimum.reduceat(sigma[corner], face_start[:-1])
        with np.errstate(invalid="ignore"):  # a face of pins is never limited, whatever its area (inf x 0 is NaN)
            rest_mass = np.where(np.isinf(lightest), np.inf, lightest * area)
        face_params = np.concatenate([np.concatenate(params), rest_mass[:, None]], axis=1).astype(np.float32)
        face_of_corner = np.repeat(np.arange(len(counts_of_face)), counts_of_face)
        order = np.lexsort((face_of_corner, corner))  # by particle, then face: the gather's order
        particle_face_start = np.r_[0, np.cumsum(np.bincount(corner, minlength=n))]
        with wp.ScopedDevice(device):
            self.face_start = wp.array(face_start.astype(np.int32), dtype=int)
            self.face_corner = wp.array(corner.astype(np.int32), dtype=int)
            self.face_params = wp.array(face_params, dtype=wp.vec3)
            self.particle_face_start = wp.array(particle_face_start.astype(np.int32), dtype=int)
            self.particle_face = wp.array(face_of_corner[order].astype(np.int32), dtype=int)
            self.side_entry = wp.array(self._side_entries(model, counts_of_face, corner), dtype=int) \
                if model.tears else wp.empty(0, dtype=int)
            self.key_start, self.key_times, self.key_values = keyframe_arrays((air,))
            if counts.gusts:
                direction, wave, timing = gust_modes(air)
                self.gust_direction = wp.array(direction, dtype=wp.vec3)
                self.gust_wave = wp.array(wave, dtype=wp.vec3)
                self.gust_timing = wp.array(timing, dtype=wp.vec2)
            else:
                self.gust_direction = self.gust_wave = wp.empty(0, dtype=wp.vec3)
                self.gust_timing = wp.empty(0, dtype=wp.vec2)
            self.no_clock = wp.empty(0, dtype=wp.float64)
            self.no_weight = wp.empty(0, dtype=float)

    @staticmethod
    def _side_entries(model, counts_of_face: np.ndarray, corner: np.ndarray) -> np.ndarray:
        """Per corner, the tear entry of the stick from it to the next corner of its face, -1 where none."""
        from ..geometry.faces import next_corner

        n = model.particle_count
        sticks = model.host_sticks.astype(np.int64)
        keys = np.minimum(sticks[:, 0], sticks[:, 1]) * n + np.maximum(sticks[:, 0], sticks[:, 1])
        order = np.argsort(keys, kind="stable")
        a, b = corner, corner[next_corner(counts_of_face)]
        wanted = np.minimum(a, b) * n + np.maximum(a, b)
        at = np.minimum(np.searchsorted(keys[order], wanted), max(len(keys) - 1, 0))
        found = (keys[order][at] == wanted) if len(keys) else np.zeros(len(wanted), bool)
        stick = order[at]
        # The tear entries of each stick (one for the coloured solver, one per end for Jacobi): both tear
        # together, so the first serves.
        entry_stick = model._tear_entry_stick
        first_entry = np.full(len(keys), -1, np.int64)
        first_entry[entry_stick[::-1]] = np.arange(len(entry_stick))[::-1]
        return np.where(found, first_entry[stick], -1).astype(np.int32)
