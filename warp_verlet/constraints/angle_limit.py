"""The angle limit: ``max_bend_angle`` on a cloth bounds how far it bends, like the stop of an elbow or a knee.

On a grid, along each row and each column (and along a rope, a grid of one row), the angle between two
successive structural sticks, 0 when they are straight, never exceeds the limit: a *joint* of three particles.
On a mesh, the dihedral angle across each interior edge between its two faces, 0 when they are flat, never
exceeds it either way: a *hinge* of four particles. The limit is unilateral, so a cloth straighter than it is
untouched, and its corrections are weighted by inverse mass (a pin does not move). Joints and hinges are each
coloured by :func:`warp_verlet.geometry.colouring.colour`, projected after the sticks in every sweep
(kernels/angle_limit.py). A limit of 180 degrees builds nothing.

A torn stick would leave its joints holding the torn pieces at an angle, so a cloth that can tear
(``tear_threshold`` or ``tear_tension``) takes no ``max_bend_angle``.
"""

from __future__ import annotations

import math

import numpy as np

from .kind import ConstraintSet
from ..launches import FLOAT, BoundStage, recorded, split_tasks
from ..scene_keys import Key, real

MAX_BEND_ANGLE = Key(
    "max_bend_angle", real(0.0, 180.0, lo_open=True), None, type="number", unit="degrees",
    default_text="absent: no limit", allowed="0 < x ≤ 180",
    doc="The most a cloth may bend: on a grid or a rope, the angle between two successive structural sticks "
        "along a row or a column (0 when straight); on a mesh, the angle between the two faces across each "
        "interior edge (0 when flat). Unilateral (a straighter cloth is untouched) and weighted by inverse "
        "mass. 180 changes nothing. Not with `tear_threshold` or `tear_tension`.")


def limit_of(spec) -> float | None:
    """The cloth's limit in radians, or None where it has none (or 180 degrees, which limits nothing)."""
    degrees = spec.options.get(MAX_BEND_ANGLE.name)
    return None if degrees is None or degrees >= 180.0 else math.radians(degrees)


def grid_joints(rows: int, cols: int) -> np.ndarray:
    """(J, 3) int32 joints (a, b, c) of a rows x cols grid: along every row, then along every column."""
    index = np.arange(rows * cols, dtype=np.int32).reshape(rows, cols)
    along_rows = np.stack([index[:, :-2], index[:, 1:-1], index[:, 2:]], axis=-1).reshape(-1, 3)
    along_cols = np.stack([index[:-2, :], index[1:-1, :], index[2:, :]], axis=-1).reshape(-1, 3)
    return np.concatenate([along_rows, along_cols]).astype(np.int32)


def mesh_hinges(faces) -> np.ndarray:
    """(H, 4) int32 hinges (wing A, wing B, p, q) across every interior edge p-q (exactly two faces A and B) of
    ``faces`` (a faces.Faces): a wing is p's other neighbour in its face, a triangle's third corner."""
    from ..geometry.faces import edge_keys, next_corner

    if len(faces) == 0:
        return np.zeros((0, 4), np.int32)
    pairs, _ = faces.sides()
    after = next_corner(faces.counts)
    before = np.empty_like(after)
    before[after] = np.arange(len(after))
    keys = edge_keys(pairs, int(faces.indices.max()) + 1)
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    new = np.r_[True, keys[1:] != keys[:-1]]
    start = np.flatnonzero(new)
    two = start[np.diff(np.r_[start, len(keys)]) == 2]
    a, b = order[two], order[two + 1]
    p, q = pairs[a, 0], pairs[a, 1]
    wing_a = faces.indices[before[a]]
    same_way = pairs[b, 0] == p  # B runs p -> q too (its faces wind against A's): p's other neighbour precedes it
    wing_b = np.where(same_way, faces.indices[before[b]], faces.indices[after[after[b]]])
    hinges = np.stack([wing_a, wing_b, p, q], axis=1).astype(np.int32)
    return hinges[(wing_a != wing_b) & (wing_a != q) & (wing_b != q)]


def _grid_joint_count(spec) -> int:
    rows, cols = spec.resolution
    return rows * max(cols - 2, 0) + max(rows - 2, 0) * cols


def _coloured(elements: np.ndarray, limits: np.ndarray, vector, device):
    """Elements sorted by colour on ``device``: (elements, limits, [(first, per_thread, threads)] per colour;
    the overflow colour, if any, is one thread's work)."""
    import warp as wp

    from ..geometry.colouring import check_partition, colour, colour_ranges

    colouring = colour(elements)
    overflow = colouring.count - 1 if colouring.overflow else None
    check_partition(elements, colouring.colour, overflow)  # cheap, and a wrong colouring is a silent race
    order, ranges = colour_ranges(colouring)
    launches = []
    for first, count in ranges:
        if colouring.overflow and colouring.colour[order[first]] == colouring.count - 1:
            launches.append((first, count, 1))  # the overflow colour: one thread, its elements in order
        else:
            launches.append((first, 1, count))
    return (wp.array(elements[order], dtype=vector, device=device),
            wp.array(limits[order].astype(np.float32), dtype=float, device=device), launches)


class _AngleData:
    """One form's elements on the device, sorted by colour: ``ends`` (E,) vec3i or vec4i particle indices,
    ``limit`` (E,) float32 radians, and per colour (first, per_thread, threads)."""

    def __init__(self, elements, limits, vector, device):
        self.ends, self.limit, self.colours = _coloured(elements, limits, vector, device)


def _bind(kernel_name: str, data: _AngleData, model, state, solver) -> BoundStage:
    from warp_verlet.kernels import angle_limit

    kernel = getattr(angle_limit, kernel_name)
    x = state.particle_q
    phases = []
    for first, per_thread, threads in data.colours:
        if per_thread == 1:
            def make(f, n):
                return recorded(kernel, n, [x, model.inv_mass, data.ends, data.limit, f, 1])
            phases.append(split_tasks(make, first, threads, solver.threads))
        else:  # the overflow colour: one thread, its elements in order
            phases.append([recorded(kernel, 1, [x, model.inv_mass, data.ends, data.limit, first, per_thread])])
    return BoundStage(None, phases)


class AngleJoints(ConstraintSet):
    """The angle limit's joints, on grid cloths and ropes (three particles each)."""

    name = "angle joints"
    cloth_keys = (MAX_BEND_ANGLE,)

    def check_cloth(self, spec, table):
        if spec.options.get(MAX_BEND_ANGLE.name) is None:
            return None
        if spec.tears:
            raise table.error(MAX_BEND_ANGLE.name, "a cloth that can tear (tear_threshold or tear_tension) takes no "
                              "max_bend_angle (a torn stick would leave its joints holding the pieces at an angle); "
                              "remove one of the two")
        if spec.mesh is None and "structural" not in spec.sticks:
            raise table.error(MAX_BEND_ANGLE.name, "bounds the angle between structural sticks, and sticks = "
                              f"{list(spec.sticks)} builds none: add \"structural\"")
        return None

    def count(self, scene) -> int:
        return sum(_grid_joint_count(c) for c in scene.cloths if c.mesh is None and limit_of(c) is not None)

    def needed(self, req) -> bool:
        return req.count(self.name) > 0

    def device_bytes(self, req) -> int:
        return req.count(self.name) * (3 * 4 + FLOAT)  # three particle indices and a limit

    def build(self, model, scene, device):
        import warp as wp

        parts = [(grid_joints(*spec.resolution) + slot.first, limit_of(spec))
                 for slot, spec in zip(model.cloths, scene.cloths) if spec.mesh is None and limit_of(spec) is not None]
        elements = np.concatenate([e for e, _ in parts])
        limits = np.concatenate([np.full(len(e), lim) for e, lim in parts])
        return _AngleData(elements, limits, wp.vec3i, device)

    def bind(self, model, state, solver) -> BoundStage:
        return _bind("limit_joints", model.constraints[self.name], model, state, solver)


class AngleHinges(ConstraintSet):
    """The angle limit's hinges, across a mesh cloth's interior edges (four particles each). Its key is the
    joints' (one ``max_bend_angle`` per cloth)."""

    name = "angle hinges"

    def count(self, scene) -> int:
        return sum(len(mesh_hinges(c.mesh.mesh.faces)) for c in scene.cloths
                   if c.mesh is not None and limit_of(c) is not None)

    def needed(self, req) -> bool:
        return req.count(self.name) > 0

    def device_bytes(self, req) -> int:
        return req.count(self.name) * (4 * 4 + FLOAT)  # four particle indices and a limit

    def build(self, model, scene, device):
        import warp as wp

        parts = [(mesh_hinges(slot.device_topology.faces) + slot.first, limit_of(spec))
                 for slot, spec in zip(model.cloths, scene.cloths)
                 if spec.mesh is not None and limit_of(spec) is not None]
        elements = np.concatenate([e for e, _ in parts])
        limits = np.concatenate([np.full(len(e), lim) for e, lim in parts])
        return _AngleData(elements, limits, wp.vec4i, device)

    def bind(self, model, state, solver) -> BoundStage:
        return _bind("limit_hinges", model.constraints[self.name], model, state, solver)
