"""Rigid patches: ``rigid_patches`` on a cloth lists groups of particles that keep their rest shape relative to
each other while the patch moves and turns with the cloth (a stiff label sewn on a flag, a batten in a
curtain's hem, a square of four particles).

Each patch is projected by shape matching (kernels/rigid_patches.py) at the end of every sweep, after the
sticks and the angle limits, so that a sweep ends with every patch exactly rigid; one thread per patch. All-pairs
sticks were the alternative: they need n - 1 colours for a patch of n particles and converge by Gauss-Seidel,
so a patch stays rigid only as far as the sweeps converge (bench/results/rigid_patches.md measures both).

A patch is written as ``pins`` are: on a grid, particle indices, ``[row, col]`` pairs, pin names
(``"top-edge"``, …) and boxes ``{ min = [x, y, z], max = [x, y, z] }`` in metres; on a mesh, vertex indices and
boxes, and on a mesh read from USD the vertices a primvar marks (``{ primvar = "name" }``, non-zero values) or a
GeomSubset holds (``{ subset = "name" }``), which the mesh reader looks up with the pins'
(:meth:`RigidPatches.named_vertex_sets`). Patches may not share particles (one rigid body would be two), and a
patch needs two particles or more. Pins inside a patch compose: the patch turns about them.
"""

from __future__ import annotations

import numpy as np

from .kind import ConstraintSet
from ..launches import FLOAT, INT, VEC3, BoundStage, recorded, split_tasks
from ..errors import SceneError
from ..scene_keys import Invalid, Key, accepts, ARRAY, describe, int_text, per_element, text

PIN_WEIGHT = 1.0e4
"""A pin's weight in a patch's fit, as a multiple of the patch's free mass: enough that the fitted rotation
turns about the pins, little enough that float32 keeps the free members' part of the sums."""


NAMED_SETS = ("primvar", "subset")
"""The items that select a USD mesh's vertices by name, as ``pins`` does."""
_name = per_element(text)  # an error names the item's own key


def _selection(value, key: str) -> tuple[tuple, ...]:
    """One patch as written: ("index", i), ("cell", row, col), ("name", pin name), ("box", lo, hi) or
    ("primvar" or "subset", name), each with its own key for errors."""
    if not isinstance(value, list) or not value:
        raise Invalid(f"expected a non-empty array of particle indices, [row, col] pairs, pin names, boxes "
                      f"{{ min = [x, y, z], max = [x, y, z] }}, {{ primvar = \"name\" }} or {{ subset = \"name\" }}, "
                      f"got {describe(value)}", key)
    items = []
    for i, item in enumerate(value):
        item_key = f"{key}[{i}]"
        if isinstance(item, bool):
            raise Invalid(f"expected a particle index, a [row, col] pair, a pin name or a box, got {describe(item)}",
                          item_key)
        if isinstance(item, int):
            if item < 0:
                raise Invalid(f"expected an index >= 0, got {int_text(item)}", item_key)
            items.append(("index", item, item_key))
        elif isinstance(item, str):
            items.append(("name", item, item_key))
        elif isinstance(item, list) and len(item) == 2 and all(isinstance(v, int) and not isinstance(v, bool)
                                                              for v in item):
            items.append(("cell", item[0], item[1], item_key))
        elif isinstance(item, dict) and set(item) == {"min", "max"}:
            corners = []
            for end in ("min", "max"):
                point = item[end]
                if not (isinstance(point, list) and len(point) == 3 and all(
                        isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in point)):
                    raise Invalid(f"expected an array of 3 finite numbers, got {describe(point)}", f"{item_key}.{end}")
                corners.append(tuple(float(v) for v in point))
            if any(a > b for a, b in zip(*corners)):
                raise Invalid(f"expected min <= max on every axis, got min = {list(corners[0])}, "
                              f"max = {list(corners[1])}", item_key)
            items.append(("box", corners[0], corners[1], item_key))
        elif isinstance(item, dict) and len(item) == 1 and next(iter(item)) in NAMED_SETS:
            kind = next(iter(item))
            items.append((kind, _name(item[kind], f"{item_key}.{kind}"), item_key))
        else:
            raise Invalid(f"expected a particle index, a [row, col] pair, a pin name, a box "
                          f"{{ min = [x, y, z], max = [x, y, z] }}, {{ primvar = \"name\" }} or "
                          f"{{ subset = \"name\" }}, got {describe(item)}", item_key)
    return tuple(items)


@accepts(ARRAY)
def _patches(value, key: str) -> tuple[tuple[tuple, ...], ...]:
    if not isinstance(value, list) or not value or not all(isinstance(p, list) for p in value):
        raise Invalid(f"expected an array of patches, each an array of particles (e.g. [[0, 1, 40, 41]]), "
                      f"got {describe(value)}")
    return tuple(_selection(patch, f"{key}[{k}]") for k, patch in enumerate(value))


RIGID_PATCHES = Key(
    "rigid_patches", _patches, (), type="array of arrays", unit="–", default_text="`[]`",
    allowed="each patch 2 or more particles, patches disjoint; items as for `pins`, and boxes",
    doc="Groups of particles that keep their rest shape relative to each other while the patch moves and turns "
        "with the cloth (a stiff label, a batten): on a grid, particle indices, `[row, col]` pairs, pin names and "
        "boxes `{ min = [x, y, z], max = [x, y, z] }` (m); on a mesh, vertex indices and boxes, and on a mesh "
        "read from USD `{ primvar = \"name\" }` (the vertices it marks non-zero) and `{ subset = \"name\" }` "
        "(a GeomSubset's points, or its faces' corners). A pin inside a patch holds it, and the patch turns "
        "about it.")


def _resolve(spec, table, written) -> tuple[tuple[int, ...], ...]:
    """Each patch as sorted particle indices of the cloth, checked."""
    from ..scene_keys import NAMED_PINS
    from ..geometry.topology import grid_positions

    mesh = spec.mesh.mesh if spec.mesh is not None else None
    if mesh is None:
        rows, cols = spec.resolution
        positions = grid_positions(spec)
    patches, owner = [], {}
    for k, items in enumerate(written):
        found: set[int] = set()
        for item in items:
            kind, key = item[0], item[-1]
            if kind == "box":
                lo, hi = np.array(item[1]), np.array(item[2])
                if mesh is not None:
                    hits = mesh.particles_in_box(item[1], item[2])
                else:
                    hits = np.flatnonzero(((positions >= lo) & (positions <= hi)).all(axis=1))
                if not len(hits):
                    raise SceneError(table.file, key, f"the box min = {list(item[1])}, max = {list(item[2])} holds "
                                     "no particle of the cloth")
                found.update(int(p) for p in hits)
            elif kind in NAMED_SETS:
                if mesh is None:
                    raise SceneError(table.file, key, f"a {kind} selects vertices of a mesh read from USD; a grid "
                                     "cloth's patch lists particle indices, [row, col] pairs, pin names and boxes")
                hits = mesh.particles_of(mesh.source.named_vertices[(kind, item[1])])
                if not len(hits):
                    raise SceneError(table.file, key, f"{kind} {item[1]!r} marks no vertex of the mesh")
                found.update(int(p) for p in hits)
            elif mesh is not None:
                if kind != "index":
                    raise SceneError(table.file, key, "a mesh cloth's patch lists vertex indices, boxes, primvars "
                                     f"and subsets, not {'[row, col] pairs' if kind == 'cell' else 'pin names'}")
                if item[1] >= mesh.vertex_count:
                    raise SceneError(table.file, key, f"vertex {int_text(item[1])} is outside the mesh "
                                     f"(0 .. {mesh.vertex_count - 1})")
                found.update(int(p) for p in mesh.particles_of([item[1]]))
            elif kind == "index":
                if item[1] >= rows * cols:
                    raise SceneError(table.file, key, f"particle index {int_text(item[1])} is outside the grid "
                                     f"(0 .. {rows * cols - 1})")
                found.add(item[1])
            elif kind == "cell":
                r, c = item[1], item[2]
                if not (0 <= r < rows and 0 <= c < cols):
                    raise SceneError(table.file, key, f"[row, col] = [{int_text(r)}, {int_text(c)}] is outside the "
                                     f"{rows} x {cols} grid")
                found.add(r * cols + c)
            else:
                if item[1] not in NAMED_PINS:
                    raise SceneError(table.file, key, f"unknown pin name {item[1]!r} (expected one of "
                                     f"{', '.join(NAMED_PINS)})")
                found.update(r * cols + c for r, c in NAMED_PINS[item[1]](rows, cols))
        key = f"{RIGID_PATCHES.name}[{k}]"
        if len(found) < 2:
            raise table.error(key, f"a patch needs two particles or more, and this one selects {len(found)}")
        shared = sorted(p for p in found if p in owner)
        if shared:
            raise table.error(key, f"shares particle {shared[0]} with rigid_patches[{owner[shared[0]]}]: patches "
                              "that share particles are one rigid body, so list them as one patch")
        owner.update((p, k) for p in found)
        patches.append(tuple(sorted(found)))
    return tuple(patches)


class PatchData:
    """The patches on the device: ``patch_start`` (P + 1,) int32 offsets into the per-member arrays ``member``
    (M,) int32 particle, ``rest_offset`` (M,) vec3 float32 m (rest position less the rest centroid) and
    ``weight`` (M,) float32 kg (a pin's outweighs the rest, PIN_WEIGHT)."""

    def __init__(self, model, scene, device):
        import warp as wp

        members, offsets, weights, starts = [], [], [], [0]
        inv_mass = model.host_inv_mass
        for slot, spec in zip(model.cloths, scene.cloths):
            for patch in spec.options[RIGID_PATCHES.name]:
                index = model.device_particles(np.asarray(patch, np.int64) + slot.first)  # scene -> device
                w = inv_mass[index].astype(np.float64)
                free = w > 0
                mass = np.where(free, 1.0 / np.where(free, w, 1.0), 0.0)
                weight = np.where(free, mass, PIN_WEIGHT * max(mass.sum(), 1.0))
                rest = model.rest_positions[index].astype(np.float64)
                centre = (weight[:, None] * rest).sum(0) / weight.sum()
                members.append(index)
                offsets.append(rest - centre)
                weights.append(weight)
                starts.append(starts[-1] + len(index))
        self.count = len(starts) - 1
        self.patch_start = wp.array(np.asarray(starts, np.int32), dtype=int, device=device)
        self.member = wp.array(np.concatenate(members).astype(np.int32), dtype=int, device=device)
        self.rest_offset = wp.array(np.concatenate(offsets).astype(np.float32), dtype=wp.vec3, device=device)
        self.weight = wp.array(np.concatenate(weights).astype(np.float32), dtype=float, device=device)


class RigidPatches(ConstraintSet):
    """Shape matching of each cloth's ``rigid_patches``, last in every sweep."""

    name = "rigid patches"
    cloth_keys = (RIGID_PATCHES,)

    def named_vertex_sets(self, options):
        return tuple((item[0], item[1], item[-1]) for patch in options.get(RIGID_PATCHES.name) or ()
                     for item in patch if isinstance(item, tuple) and item[0] in NAMED_SETS)

    def check_cloth(self, spec, table):
        written = spec.options.get(RIGID_PATCHES.name) or ()
        return {RIGID_PATCHES.name: _resolve(spec, table, written)} if written else None

    def count(self, scene):
        patches = [p for c in scene.cloths for p in c.options.get(RIGID_PATCHES.name, ())]
        return (sum(len(p) for p in patches), len(patches)) if patches else 0

    def needed(self, req) -> bool:
        return bool(req.count(self.name))

    def device_bytes(self, req) -> int:
        members, patches = req.count(self.name)
        return members * (INT + VEC3 + FLOAT) + (patches + 1) * INT

    def build(self, model, scene, device):
        return PatchData(model, scene, device)

    def bind(self, model, state, solver) -> BoundStage:
        from warp_verlet.kernels.rigid_patches import match_patches

        data, x = model.constraints[self.name], state.particle_q

        def make(first, count):
            return recorded(match_patches, count, [x, model.inv_mass, data.patch_start, data.member,
                                                   data.rest_offset, data.weight, first])
        return BoundStage(None, [split_tasks(make, 0, data.count, solver.threads)])
