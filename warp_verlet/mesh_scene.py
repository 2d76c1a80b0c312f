"""The scene keys of a mesh cloth (``[[cloth]]`` with ``mesh = "path"``), read and checked when the scene loads.

The mesh file is read here, welded and checked (warp_verlet/mesh_io.py, mesh_cloth.py), so that a bad mesh
is one SceneError naming the scene file, the key and the mesh's problem, from ``warp-verlet validate`` as
from ``run``. Pins and particle masses are resolved to particle indices here too: nothing downstream sees
vertex indices, boxes or primvar names. docs/scenes.md documents every key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .errors import SceneError
from .mesh_cloth import MASS_DISTRIBUTIONS, MeshError, prepare
from .mesh_io import read_mesh, transform_matrix
from .scene import (
    ClothSpec, MeshSpec, _any_real, _boolean, _describe, _int_text, _Invalid, _per_element, _prim_name,
    _read_compliance, _read_sticks, _Table, check_cloth, choice, real, text, vector,
)

GRID_KEYS = ("resolution", "size", "origin", "orientation")
_positive = _per_element(real(0.0, lo_open=True))
_point = _per_element(vector(3, _any_real))  # an error names the element's own key


def _scale(value: Any, key: str) -> tuple[float, float, float]:
    if isinstance(value, list):
        return vector(3, _positive)(value, key)
    s = _positive(value, key)
    return (s, s, s)


def _pin_items(value: Any, key: str) -> tuple[tuple, ...]:
    """Pins as written: ("vertex", i, key), ("box", lo, hi, key), ("primvar" or "subset", name, key)."""
    if not isinstance(value, list):
        raise _Invalid(f"expected an array of vertex indices and tables {{ min = [x, y, z], max = [x, y, z] }}, "
                       f"{{ primvar = \"name\" }} or {{ subset = \"name\" }}, got {_describe(value)}")
    items = []
    for i, item in enumerate(value):
        item_key = f"{key}[{i}]"
        if isinstance(item, int) and not isinstance(item, bool):
            if item < 0:
                raise _Invalid(f"expected a vertex index >= 0, got {_int_text(item)}", item_key)
            items.append(("vertex", item, item_key))
        elif isinstance(item, dict) and set(item) == {"min", "max"}:
            lo = _point(item["min"], f"{item_key}.min")
            hi = _point(item["max"], f"{item_key}.max")
            if any(a > b for a, b in zip(lo, hi)):
                raise _Invalid(f"expected min <= max on every axis, got min = {list(lo)}, max = {list(hi)}", item_key)
            items.append(("box", lo, hi, item_key))
        elif isinstance(item, dict) and len(item) == 1 and next(iter(item)) in ("primvar", "subset"):
            kind = next(iter(item))
            items.append((kind, text(item[kind], f"{item_key}.{kind}"), item_key))
        else:
            raise _Invalid("expected a vertex index or a table { min = [..], max = [..] }, { primvar = \"name\" } "
                           f"or {{ subset = \"name\" }}, got {_describe(item)}", item_key)
    return tuple(items)


def _mass_items(value: Any, key: str) -> tuple[tuple[int, float, str], ...]:
    if not isinstance(value, list):
        raise _Invalid(f"expected an array of [vertex, kg] pairs, got {_describe(value)}")
    out = []
    for i, item in enumerate(value):
        item_key = f"{key}[{i}]"
        if not (isinstance(item, list) and len(item) == 2):
            raise _Invalid(f"expected a [vertex, kg] pair, got {_describe(item)}", item_key)
        vertex, kg = item
        if not isinstance(vertex, int) or isinstance(vertex, bool) or vertex < 0:
            raise _Invalid(f"expected a vertex index >= 0, got {_describe(vertex)}", f"{item_key}[0]")
        out.append((vertex, _positive(kg, f"{item_key}[1]"), item_key))
    return tuple(out)


def read_mesh_cloth(t: _Table, index: int, scene_dir: Path) -> ClothSpec:
    for key in GRID_KEYS:
        if key in t.data:
            raise t.error(key, f"a mesh cloth takes its particles from the mesh: remove {key} (or mesh, for a grid)")
    name = t.take("name", _prim_name, f"cloth{index}")
    relative = t.take("mesh", text)
    path = Path(relative) if Path(relative).is_absolute() else scene_dir / relative
    prim = t.take("prim", text, None)
    transform = transform_matrix(t.take("translate", vector(3, _any_real), (0.0, 0.0, 0.0)),
                                 t.take("rotate", vector(3, _any_real), (0.0, 0.0, 0.0)),
                                 t.take("scale", _scale, (1.0, 1.0, 1.0)))
    weld_distance = t.take("weld_distance", real(0.0), None)
    pins = t.take("pins", _pin_items, ())
    masses = t.take("particle_masses", _mass_items, ())
    spec = ClothSpec(
        name=name, resolution=None, size=None,
        mass=t.take("mass", real(0.0, lo_open=True), 1.0),
        sticks=t.take("sticks", _read_sticks, ("structural",)),
        compliance=t.take("compliance", _read_compliance, {}),
        tear_threshold=t.take("tear_threshold", real(1.0, lo_open=True), None),
        tethers=t.take("tethers", _boolean, None),
        tether_scale=t.take("tether_scale", real(1.0), 1.0),
    )
    distribution = t.take("mass_distribution", choice(MASS_DISTRIBUTIONS), "area")
    t.finish()

    named = tuple(dict.fromkeys((item[0], item[1]) for item in pins if item[0] in ("primvar", "subset")))
    try:
        mesh = prepare(read_mesh(path, prim, transform, named), weld_distance)
    except MeshError as exc:
        raise t.error("mesh", str(exc)) from None
    vertices = mesh.vertex_count
    pinned: set[int] = set()
    for item in pins:
        kind, key = item[0], item[-1]
        if kind == "vertex":
            if item[1] >= vertices:
                raise SceneError(t.file, key, f"vertex {_int_text(item[1])} is outside the mesh (0 .. {vertices - 1})")
            found = mesh.particles_of([item[1]])
        elif kind == "box":
            found = mesh.particles_in_box(item[1], item[2])
            if not len(found):
                raise SceneError(t.file, key, f"the box min = {list(item[1])}, max = {list(item[2])} holds no "
                                 "vertex of the mesh (after translate, rotate and scale)")
        else:
            found = mesh.particles_of(mesh.source.named_vertices[(kind, item[1])])
            if not len(found):
                raise SceneError(t.file, key, f"{kind} {item[1]!r} marks no vertex of the mesh")
        pinned.update(int(p) for p in found)
    overrides: dict[int, float] = {}
    for vertex, kg, key in masses:
        if vertex >= vertices:
            raise SceneError(t.file, key, f"vertex {_int_text(vertex)} is outside the mesh (0 .. {vertices - 1})")
        particle = int(mesh.particle_of_vertex[vertex])
        if particle in overrides:
            raise SceneError(t.file, key, f"vertex {vertex} (particle {particle}) is given a mass twice")
        overrides[particle] = kg
    if spec.tear_threshold is not None and mesh.non_manifold_edges:
        raise t.error("tear_threshold", f"tearing needs a manifold mesh (each edge beside at most two faces, to "
                      f"know which faces a torn edge opens), and {mesh.non_manifold_edges} edges have more")
    from dataclasses import replace

    spec = replace(spec, mesh=MeshSpec(mesh, tuple(sorted(pinned)), tuple(sorted(overrides.items())), distribution))
    check_cloth(t, spec)
    return spec


def check_override(file: str, cloths: tuple[ClothSpec, ...]) -> None:
    """An override layer overrides USD prims: every cloth must come from a prim, all of one USD file."""
    assets = set()
    for i, spec in enumerate(cloths):
        source = spec.mesh.mesh.source if spec.mesh is not None else None
        if source is None or source.prim_path is None:
            raise SceneError(file, "output.kind", f"an override layer overrides the USD prims the cloths came from, "
                             f"and cloth[{i}] ({spec.name!r}) is not from a USD prim: write kind = \"cache\"")
        assets.add(source.file.resolve())
    if len(assets) > 1:
        raise SceneError(file, "output.kind", f"an override layer goes over one asset, and the cloths come from "
                         f"{len(assets)} files ({', '.join(sorted(map(str, assets)))}): write kind = \"cache\"")
