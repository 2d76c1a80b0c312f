"""The keys only a mesh cloth has (``[[cloth]]`` with ``mesh = "path"``), read and checked when the scene loads.

scene.py reads the keys every cloth has and calls :func:`read_mesh_keys`, then, once no key is unknown,
:func:`load_mesh`. The mesh file is read there, welded and checked (warp_verlet/geometry/mesh_io.py, mesh_cloth.py),
so that a bad mesh is one SceneError naming the scene file, the key and the mesh's problem, from
``warp-verlet validate`` as from ``run``. Pins and particle masses are resolved to particle indices here
too: nothing downstream sees vertex indices, boxes or primvar names. A constraint kind's options may select
vertices by primvar or GeomSubset as well (``ConstraintKind.named_vertex_sets``): they are read here, with the
pins', and the kind resolves them in its ``check_cloth``. Each key is declared once in
:data:`MESH_KEYS` (scene_keys.Key): docs/scenes.md's mesh table is written from it (docs/make_scene_tables.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from ..errors import SceneError
from ..geometry.mesh_cloth import MASS_DISTRIBUTIONS, ClothMesh, MeshError, SourceMesh, prepare
from ..geometry.mesh_io import USD_SUFFIXES, read_mesh, to_scene, transform_matrix
from ..scene_keys import (ARRAY, Invalid, Key, Table, accepts, any_real, choice, describe, int_text,
                          per_element, real, scale_factors, text, vector)

_positive = per_element(real(0.0, lo_open=True))
_point = per_element(vector(3, any_real))  # an error names the element's own key


@accepts(ARRAY)
def _pin_items(value: Any, key: str) -> tuple[tuple, ...]:
    """Pins as written: ("vertex", i, key), ("box", lo, hi, key), ("primvar" or "subset", name, key)."""
    if not isinstance(value, list):
        raise Invalid(f"expected an array of vertex indices and tables {{ min = [x, y, z], max = [x, y, z] }}, "
                       f"{{ primvar = \"name\" }} or {{ subset = \"name\" }}, got {describe(value)}")
    items = []
    for i, item in enumerate(value):
        item_key = f"{key}[{i}]"
        if isinstance(item, int) and not isinstance(item, bool):
            if item < 0:
                raise Invalid(f"expected a vertex index >= 0, got {int_text(item)}", item_key)
            items.append(("vertex", item, item_key))
        elif isinstance(item, dict) and set(item) == {"min", "max"}:
            lo = _point(item["min"], f"{item_key}.min")
            hi = _point(item["max"], f"{item_key}.max")
            if any(a > b for a, b in zip(lo, hi)):
                raise Invalid(f"expected min <= max on every axis, got min = {list(lo)}, max = {list(hi)}", item_key)
            items.append(("box", lo, hi, item_key))
        elif isinstance(item, dict) and len(item) == 1 and next(iter(item)) in ("primvar", "subset"):
            kind = next(iter(item))
            items.append((kind, text(item[kind], f"{item_key}.{kind}"), item_key))
        else:
            raise Invalid("expected a vertex index or a table { min = [..], max = [..] }, { primvar = \"name\" } "
                           f"or {{ subset = \"name\" }}, got {describe(item)}", item_key)
    return tuple(items)


@accepts(ARRAY)
def _mass_items(value: Any, key: str) -> tuple[tuple[int, float, str], ...]:
    if not isinstance(value, list):
        raise Invalid(f"expected an array of [vertex, kg] pairs, got {describe(value)}")
    out = []
    for i, item in enumerate(value):
        item_key = f"{key}[{i}]"
        if not (isinstance(item, list) and len(item) == 2):
            raise Invalid(f"expected a [vertex, kg] pair, got {describe(item)}", item_key)
        vertex, kg = item
        if not isinstance(vertex, int) or isinstance(vertex, bool) or vertex < 0:
            raise Invalid(f"expected a vertex index >= 0, got {describe(vertex)}", f"{item_key}[0]")
        out.append((vertex, _positive(kg, f"{item_key}[1]"), item_key))
    return tuple(out)


MESH_KEYS: tuple[Key, ...] = (  # in the order they are read, and of their table in docs/scenes.md
    Key("mesh", text, type="string",
        allowed="a file trimesh reads (`.obj`, `.ply`, `.stl`, `.off`, `.glb`, `.gltf`, …) or a USD file (`.usd`, "
                "`.usda`, `.usdc`, `.usdz`)",
        doc="The mesh, relative to the scene file's directory."),
    Key("prim", text, None, "string", default_text="required for USD, refused otherwise",
        allowed='an absolute prim path, e.g. `"/Set/Cloth"`', doc="The Mesh prim to read."),
    Key("translate", vector(3, any_real), (0.0, 0.0, 0.0), "[x, y, z] numbers", "m", allowed="finite",
        doc="Moves the mesh, after `rotate`."),
    Key("rotate", vector(3, any_real), (0.0, 0.0, 0.0), "[x, y, z] numbers", "degrees", allowed="finite",
        doc="Rotations about the fixed X, then Y, then Z axes, after `scale`."),
    Key("scale", scale_factors, (1.0, 1.0, 1.0), "number or [x, y, z]", default_text="`1.0`", allowed="> 0",
        doc="Scales the mesh first."),
    Key("weld_distance", real(0.0), None, "number", "m", default_text="10⁻⁶ × the mesh's bounding-box diagonal",
        allowed="≥ 0 (0: exact duplicates only)",
        doc="Vertices at most this far apart (after the transform) become one particle."),
    Key("pins", _pin_items, (), "array", allowed="see below", doc="Particles held fixed."),
    Key("particle_masses", _mass_items, (), "array of [vertex, kg]", "–, kg",
        allowed="vertex in the mesh, each particle once", doc="Overrides of single particles' mass."),
    Key("mass_distribution", choice(MASS_DISTRIBUTIONS), "area", "string", allowed='`"area"`, `"even"`',
        doc='`"area"`: each face\'s area is split evenly among its corners, so a particle carries the cloth around '
            'it. `"even"`: every particle the same, as on a grid.'),
)


FILE_KEYS = ("mesh", "prim")  # the keys that name the file: a mesh given in memory (points, faces) has neither
IN_MEMORY = "the given points and faces"  # such a mesh, in its messages


@dataclass(frozen=True, eq=False)
class MeshSpec:
    """A cloth's mesh, read, welded and checked, and what the scene says about its particles, resolved to
    particle indices."""

    mesh: ClothMesh
    pins: tuple[int, ...] = ()  # particle indices, sorted
    particle_masses: tuple[tuple[int, float], ...] = ()  # (particle, kg): overrides of the distributed mass
    mass_distribution: str = "area"


@dataclass(frozen=True)
class MeshKeys:
    """The mesh keys as written, checked, before the file is read."""

    path: Path | None  # None: the mesh is given in memory
    prim: str | None
    transform: Any  # (4, 4) numpy array
    weld_distance: float | None
    pins: tuple[tuple, ...]
    particle_masses: tuple[tuple[int, float, str], ...]
    mass_distribution: str


def read_mesh_keys(t: Table, scene_dir: Path, in_memory: bool = False) -> MeshKeys:
    """Take the mesh keys from a cloth's table, leaving the keys every cloth has (scene.py refuses a grid's).
    ``in_memory``: the mesh is given as points and faces (SceneBuilder.add_mesh), so :data:`FILE_KEYS` are not
    taken (a table that has them is refused as having unknown keys)."""
    values = {key.name: key.take(t) for key in MESH_KEYS if not (in_memory and key.name in FILE_KEYS)}
    relative = values.get("mesh")
    return MeshKeys(
        path=None if in_memory else Path(relative) if Path(relative).is_absolute() else scene_dir / relative,
        prim=values.get("prim"),
        transform=transform_matrix(values["translate"], values["rotate"], values["scale"]),
        weld_distance=values["weld_distance"],
        pins=values["pins"],
        particle_masses=values["particle_masses"],
        mass_distribution=values["mass_distribution"],
    )


def kinds_vertex_sets(options: Mapping[str, Any]) -> tuple[tuple[str, str, str], ...]:
    """The vertex sets the constraint kinds' ``options`` of a cloth select by name (each kind's
    ``named_vertex_sets``): ("primvar" or "subset", name, key), in registry order."""
    from ..constraints import kinds

    return tuple(found for kind in kinds() for found in kind.named_vertex_sets(options))


def load_mesh(t: Table, keys: MeshKeys, options: Mapping[str, Any], arrays: tuple | None = None) -> MeshSpec:
    """Read, weld and check the mesh, and resolve its pins and particle masses to particles. The vertex sets
    that the pins and the constraint kinds' ``options`` (the cloth's, as read) select by primvar or GeomSubset
    are looked up in the same read; the kinds resolve theirs in their ``check_cloth``. ``arrays``: the mesh in
    memory instead of a file, (points (V, 3) float64, Faces), moved by the transform keys as a file's is."""
    for_kinds = kinds_vertex_sets(options)
    is_usd = arrays is None and keys.path.suffix.lower() in USD_SUFFIXES
    if for_kinds and not is_usd:
        kind, name, key = for_kinds[0]
        where = ("this mesh is given as points and faces" if arrays is not None
                 else f"the mesh is a {keys.path.suffix or 'suffix-less'} file")
        raise SceneError(t.file, key, f"selecting vertices by {kind} ({name!r}) needs a USD file; {where}")
    wanted = [(item[0], item[1]) for item in keys.pins if item[0] in ("primvar", "subset")]
    wanted += [(kind, name) for kind, name, _ in for_kinds]
    try:
        if arrays is None:
            source = read_mesh(keys.path, keys.prim, keys.transform, tuple(dict.fromkeys(wanted)))
        else:
            for item in keys.pins:
                if item[0] in ("primvar", "subset"):
                    raise SceneError(t.file, item[-1], f"pins by {item[0]} ({item[1]!r}) need a USD file; this "
                                     "mesh is given as points and faces")
            points, faces = arrays
            source = SourceMesh(IN_MEMORY, None, to_scene(IN_MEMORY, keys.transform, points), faces)
        mesh = prepare(source, keys.weld_distance)
    except MeshError as exc:
        raise t.error("mesh" if arrays is None else None, str(exc)) from None
    vertices = mesh.vertex_count
    pinned: set[int] = set()
    for item in keys.pins:
        kind, key = item[0], item[-1]
        if kind == "vertex":
            if item[1] >= vertices:
                raise SceneError(t.file, key, f"vertex {int_text(item[1])} is outside the mesh (0 .. {vertices - 1})")
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
    for vertex, kg, key in keys.particle_masses:
        if vertex >= vertices:
            raise SceneError(t.file, key, f"vertex {int_text(vertex)} is outside the mesh (0 .. {vertices - 1})")
        particle = int(mesh.particle_of_vertex[vertex])
        if particle in overrides:
            raise SceneError(t.file, key, f"vertex {vertex} (particle {particle}) is given a mass twice")
        overrides[particle] = kg
    return MeshSpec(mesh, tuple(sorted(pinned)), tuple(sorted(overrides.items())), keys.mass_distribution)
