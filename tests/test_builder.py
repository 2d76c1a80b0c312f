"""SceneBuilder: a scene built in Python equals the same scene loaded from a file (dataclass equality, and the same
positions bit for bit after a few frames), a bad value is the file's error naming the call, finalize() is the
Simulator's Model, and docs/api.md's example runs."""

from __future__ import annotations

import dataclasses
import functools
import re
from pathlib import Path

import numpy as np
import pytest
import warp as wp

from warp_verlet import SceneBuilder, SceneError, Simulator, load_scene
from warp_verlet.builder import toml_value
from warp_verlet.input.scene import Scene
from warp_verlet.scene_keys import Key, real

from toml_text import dump

REPO = Path(__file__).resolve().parent.parent
FRAMES = 4

# One scene of every kind of table: a grid with pins, tethers, soft families and particle masses, a rope with
# an angle limit, a grid with rigid patches, a still sphere, a moving sphere and a plane; each table as TOML
# would hold it, and the builder gets the same keys (as Python values: tuples where TOML has arrays).
SIMULATION = {"fps": 50.0, "frames": FRAMES, "substeps": 3, "iterations": 6, "gravity": [0.0, -9.81, 0.5],
              "damping": 0.2}
OUTPUT = {"save_every": 2, "up_axis": "Z"}
GRID = {"name": "sheet", "resolution": [6, 5], "size": [1.0, 0.8], "origin": [-0.4, 1.5, 0.0], "mass": 0.7,
        "sticks": ["structural", "shear", "bend"], "compliance": {"shear": 1e-4, "bend": 2e-3},
        "pins": ["top-left", [0, 4], 2], "tethers": True, "tether_scale": 1.05,
        "particle_masses": [[5, 4, 0.05]]}
ROPE = {"name": "rope", "resolution": [1, 12], "size": [0.0, 1.1], "origin": [1.0, 1.5, 0.0],
        "orientation": "horizontal", "pins": [0], "max_bend_angle": 10.0}
PATCHED = {"name": "banner", "resolution": [5, 5], "size": [0.6, 0.6], "origin": [2.0, 1.5, 0.0],
           "sticks": ["structural", "shear"], "pins": ["top-edge"],
           "rigid_patches": [[[4, 0], [4, 1], [4, 2], [4, 3], [4, 4]],
                             [{"min": [2.1, 1.1, -0.1], "max": [2.4, 1.4, 0.1]}]]}
SPHERE = {"type": "sphere", "name": "ball", "radius": 0.2, "centre": [0.0, 0.9, 0.1], "thickness": 0.01,
          "friction_coefficient": 0.3}
MOVING = {"type": "sphere", "radius": 0.1, "path": [[0.0, 1.0, 0.5, 0.4], [0.1, 1.0, 0.5, -0.4]], "purpose": "default"}
PLANE = {"type": "plane", "point": [0.0, 0.2, 0.0], "normal": [0.0, 1.0, 0.0], "thickness": 0.005}


def as_python(value):
    """A TOML value as a Python user would more likely write it: arrays as tuples."""
    if isinstance(value, list):
        return tuple(as_python(v) for v in value)
    if isinstance(value, dict):
        return {k: as_python(v) for k, v in value.items()}
    return value


def load(tmp_path: Path, doc: dict, name: str = "scene") -> Scene:
    path = tmp_path / f"{name}.toml"
    path.write_text(dump(doc), encoding="utf-8")
    return load_scene(path)


def build(doc: dict, name: str = "scene") -> SceneBuilder:
    """The builder calls for a document of the shape above."""
    builder = SceneBuilder(name)
    if "simulation" in doc:
        builder.set_simulation(**as_python(doc["simulation"]))
    if "output" in doc:
        builder.set_output(**as_python(doc["output"]))
    for cloth in doc["cloth"]:
        keys = as_python(cloth)
        if "mesh" in keys:
            builder.add_mesh(keys.pop("mesh"), **keys)
        else:
            builder.add_grid(**keys)
    for collider in doc.get("collider", []):
        keys = as_python(collider)
        kind = keys.pop("type")
        {"sphere": builder.add_sphere, "plane": builder.add_plane}[kind](**keys)
    return builder


def frames_of(scene: Scene, frames: int = FRAMES) -> np.ndarray:
    sim = Simulator(scene, "cpu", threads=1)
    for _ in range(frames):
        sim.step_frame()
    return sim.positions()


def test_a_built_scene_equals_the_file_and_runs_the_same(tmp_path):
    doc = {"simulation": SIMULATION, "output": OUTPUT, "cloth": [GRID, ROPE, PATCHED],
           "collider": [SPHERE, MOVING, PLANE]}
    from_file = load(tmp_path, doc)
    built = build(doc).scene()
    assert built.source == "scene" and from_file.source == str(tmp_path / "scene.toml")
    assert dataclasses.replace(built, source=from_file.source) == from_file
    # What the comparison above covers, so that it cannot pass on defaults alone.
    sheet, rope, banner = built.cloths
    assert sheet.compliance == {"shear": 1e-4, "bend": 2e-3} and sheet.uses_tethers
    assert rope.options["max_bend_angle"] == 10.0 and len(banner.options["rigid_patches"]) == 2
    assert [c.name for c in built.colliders] == ["ball", "sphere1", "plane2"]
    assert built.output.path == Path("scene.usdc") and built.simulation.fps == 50.0
    positions = frames_of(built)
    assert np.array_equal(positions, frames_of(from_file))
    assert not np.array_equal(positions, Simulator(built, "cpu").positions())  # it moved


def test_defaults_come_from_the_declarations(tmp_path):
    """A builder given only the required keys is the file given only those: every default is the declaration's."""
    doc = {"cloth": [{"resolution": [3, 4], "size": [1.0, 1.0]}], "collider": [{"type": "sphere", "radius": 0.5}]}
    built = build(doc).scene()
    assert dataclasses.replace(built, source="x") == dataclasses.replace(load(tmp_path, doc), source="x")
    assert built.cloths[0].name == "cloth0" and built.colliders[0].name == "sphere0"


def test_python_values_stand_for_their_toml_values(tmp_path):
    """numpy arrays and scalars, tuples and paths are written as the TOML values they stand for, and None leaves
    out a key that is absent by default; a None for any other key is refused as the file's wrong type is."""
    doc = {"output": {"path": "out.usda"}, "cloth": [{"resolution": [4, 3], "size": [0.5, 0.25], "mass": 2.0,
                                                      "origin": [0.0, 1.0, 0.0], "pins": [[0, 1]]}]}
    builder = SceneBuilder("scene")
    builder.set_output(path=Path("out.usda"))
    builder.add_grid(resolution=np.array([4, 3]), size=np.array([0.5, 0.25], np.float32), mass=np.float32(2.0),
                     origin=(np.int64(0), 1, 0.0), pins=np.array([[0, 1]]), tear_threshold=None, tethers=None)
    assert dataclasses.replace(builder.scene(), source="x") == dataclasses.replace(load(tmp_path, doc), source="x")
    assert toml_value({"a": (1, np.float64(2.5)), "b": Path("p")}) == {"a": [1, 2.5], "b": "p"}
    with pytest.raises(SceneError) as caught:
        builder.add_grid(resolution=(2, 2), size=(1.0, 1.0), mass=None)
    assert (caught.value.key, caught.value.problem) == ("mass", "expected a number, got NoneType None")


# ------------------------------------------------------------------------------------------------------------
# A bad value: the file's error, naming the builder call where the file's names the file and the table.

GOOD_GRID = {"resolution": [4, 4], "size": [1.0, 1.0]}
BAD_VALUES = [  # (section of the file, its table, the key the file's error names below the table)
    ("cloth", {**GOOD_GRID, "mass": 0.0}, "mass"),
    ("cloth", {**GOOD_GRID, "size": [1.0, -1.0]}, "size[1]"),
    ("cloth", {**GOOD_GRID, "pins": ["top-left", [4, 0]]}, "pins[1]"),
    ("cloth", {**GOOD_GRID, "sticks": ["bend", "twist"]}, "sticks[1]"),
    ("cloth", {**GOOD_GRID, "compliance": {"bend": 1e-3}}, "compliance.bend"),
    ("cloth", {**GOOD_GRID, "colour": "red"}, "colour"),
    ("cloth", {**GOOD_GRID, "max_bend_angle": 200.0}, "max_bend_angle"),
    ("cloth", {**GOOD_GRID, "rigid_patches": [[0]]}, "rigid_patches[0]"),
    ("cloth", {"size": [1.0, 1.0]}, "resolution"),
    ("simulation", {"fps": 0.0}, "fps"),
    ("simulation", {"substeps": 2, "target_stretch": 0.01}, "target_stretch"),
    ("output", {"path": "out.txt"}, "path"),
    ("output", {"kind": "override", "up_axis": "Z"}, "up_axis"),
    ("collider", {"type": "sphere", "radius": -1.0}, "radius"),
    ("collider", {"type": "sphere", "radius": 1.0, "centre": [0, 0, 0], "path": [[0, 0, 0, 0]]}, "path"),
    ("collider", {"type": "plane", "normal": [0.0, 0.0, 0.0]}, "normal"),
    ("collider", {"type": "cube"}, "type"),
]
CALL = {"simulation": "set_simulation()", "output": "set_output()", "cloth": "add_grid(cloth 0)",
        "collider": "add_collider(collider 0)"}
FILE_KEY = {"simulation": "simulation", "output": "output", "cloth": "cloth[0]", "collider": "collider[0]"}


@pytest.mark.parametrize("section,table,key", BAD_VALUES, ids=lambda v: v if isinstance(v, str) else None)
def test_a_bad_value_is_the_files_error_naming_the_call(tmp_path, section, table, key):
    doc = {"cloth": [GOOD_GRID]}
    doc[section] = [table] if section in ("cloth", "collider") else table
    with pytest.raises(SceneError) as from_file:
        load(tmp_path, doc)
    builder = SceneBuilder()
    keys = as_python(table)
    with pytest.raises(SceneError) as built:
        if section == "simulation":
            builder.set_simulation(**keys)
        elif section == "output":
            builder.set_output(**keys)
        elif section == "cloth":
            builder.add_grid(**keys)
        else:
            builder.add_collider(keys.pop("type"), **keys)
    assert from_file.value.key == f"{FILE_KEY[section]}.{key}"
    assert (built.value.file, built.value.key) == (CALL[section], key)
    assert built.value.problem == from_file.value.problem
    assert str(built.value) == f"{CALL[section]}: {key}: {from_file.value.problem}"


def test_the_checks_across_tables_name_the_builder(tmp_path):
    doc = {"simulation": {"relaxation": "jacobi"}, "cloth": [{**GOOD_GRID, "name": "a"}, {**GOOD_GRID, "name": "a"}]}
    with pytest.raises(SceneError) as from_file:
        load(tmp_path, doc)
    builder = build(doc, name="twins")
    with pytest.raises(SceneError) as built:
        builder.scene()
    assert (built.value.file, built.value.key) == ("twins", "cloth[1].name") == ("twins", from_file.value.key)
    assert built.value.problem == from_file.value.problem
    with pytest.raises(SceneError, match="expected one or more cloths"):
        SceneBuilder("empty").scene()


def test_the_collider_shorthands_are_add_collider(tmp_path):
    builder = SceneBuilder()
    builder.add_grid(**GOOD_GRID)
    sphere, same = builder.add_sphere(radius=0.5), builder.add_collider("sphere", radius=0.5)
    plane, same_plane = builder.add_plane(normal=(0, 0, 1)), builder.add_collider("plane", normal=[0, 0, 1])
    assert [c.name for c in builder.colliders] == ["sphere0", "sphere1", "plane2", "plane3"]
    assert dataclasses.replace(same, name="sphere0") == sphere
    assert dataclasses.replace(same_plane, name="plane2") == plane
    with pytest.raises(SceneError) as caught:
        builder.add_sphere(radius=0.5, type="plane")
    assert (caught.value.file, caught.value.key) == ("add_sphere(collider 4)", "type")
    with pytest.raises(SceneError) as caught:
        builder.add_grid(mesh="cloth.obj")
    assert caught.value.key == "mesh" and "add_mesh" in caught.value.problem


@dataclasses.dataclass(frozen=True)
class RingCollider:
    name: str
    inner: float
    thickness: float = 0.0
    friction_coefficient: float = 0.0
    static_friction_coefficient: float | None = None
    purpose: str = "guide"


class RingKind:
    """A collider kind's scene input alone (what loading a scene asks of it), registered for one test."""

    type = "ring"
    spec = RingCollider
    keys = (Key("inner", real(0.0, lo_open=True), 0.5, type="number", unit="m", allowed="> 0", doc="Inner radius."),)

    def read(self, table, shared):
        return RingCollider(inner=self.keys[0].take(table), **shared)

    def check_numbers(self, spec, file, key):
        return None


class TwistKind:
    """A constraint kind's scene input alone: one cloth key, resolved by check_cloth."""

    name = "twist"
    cloth_keys = (Key("max_twist", real(0.0, 90.0), None, type="number", unit="degrees", default_text="absent",
                      allowed="0 … 90", doc="The most a cloth may twist."),)

    def check_cloth(self, spec, table):
        twist = spec.options.get("max_twist")
        return None if twist is None else {"max_twist": round(twist, 1)}


def test_kinds_registered_later_work_through_the_builder(tmp_path, monkeypatch):
    """A collider kind and a constraint kind that the builder has never heard of: their keys are taken from their
    declarations, checked by their parsers, and the scene equals the file's."""
    from warp_verlet import colliders, constraints

    monkeypatch.setattr(colliders, "COLLIDER_KINDS", (*colliders.COLLIDER_KINDS, RingKind()))
    monkeypatch.setattr(constraints, "CONSTRAINT_KINDS", (*constraints.CONSTRAINT_KINDS, TwistKind()))
    doc = {"cloth": [{**GOOD_GRID, "max_twist": 12.34}], "collider": [{"type": "ring", "inner": 0.25}]}
    built = build_with_any_collider(doc).scene()
    assert built.cloths[0].options["max_twist"] == 12.3 and built.colliders == (RingCollider("ring0", 0.25),)
    assert dataclasses.replace(built, source="x") == dataclasses.replace(load(tmp_path, doc), source="x")
    for call, keys, key in ((SceneBuilder().add_grid, {**GOOD_GRID, "max_twist": 91.0}, "max_twist"),
                            (functools.partial(SceneBuilder().add_collider, "ring"), {"inner": 0.0}, "inner")):
        with pytest.raises(SceneError) as caught:
            call(**keys)
        assert caught.value.key == key and caught.value.problem.startswith("expected a number in")


def build_with_any_collider(doc: dict) -> SceneBuilder:
    builder = build({**doc, "collider": []})
    for collider in doc.get("collider", []):
        keys = as_python(collider)
        builder.add_collider(keys.pop("type"), **keys)
    return builder


# ------------------------------------------------------------------------------------------------------------
# Mesh cloths: from a file, and from points and faces given directly.

def mesh_arrays(rows: int = 4, cols: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A flat sheet of triangles in the XZ plane, its points exact in float64 text."""
    x, z = np.meshgrid(np.arange(cols) * 0.25, np.arange(rows) * 0.25)
    points = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    quads = [(r * cols + c, (r + 1) * cols + c, (r + 1) * cols + c + 1, r * cols + c + 1)
             for r in range(rows - 1) for c in range(cols - 1)]
    triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return points, triangles


def write_obj(path: Path, points: np.ndarray, faces: np.ndarray) -> Path:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in points.tolist()]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in faces.tolist()]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def same_mesh_cloth(a, b) -> bool:
    """Two mesh cloths hold the same cloth: every ClothSpec field equal, and the meshes' arrays equal (a MeshSpec
    compares by identity)."""
    ma, mb = a.mesh, b.mesh
    return (dataclasses.replace(a, mesh=None) == dataclasses.replace(b, mesh=None)
            and ma.pins == mb.pins and ma.particle_masses == mb.particle_masses
            and ma.mass_distribution == mb.mass_distribution
            and np.array_equal(ma.mesh.source.points, mb.mesh.source.points)
            and ma.mesh.source.faces == mb.mesh.source.faces
            and np.array_equal(ma.mesh.particle_of_vertex, mb.mesh.particle_of_vertex)
            and np.array_equal(ma.mesh.particle_points, mb.mesh.particle_points)
            and ma.mesh.faces == mb.mesh.faces and ma.mesh.weld_distance == mb.mesh.weld_distance)


MESH_KEYS = {"translate": [0.0, 1.0, 0.0], "rotate": [0.0, 0.0, 10.0], "scale": 1.5, "mass": 0.4,
             "pins": [0, {"min": [-1.0, 0.0, 0.7], "max": [2.0, 2.0, 1.0]}], "particle_masses": [[19, 0.02]],
             "mass_distribution": "even", "sticks": ["structural", "bend"], "compliance": {"bend": 1e-3},
             "max_bend_angle": 30.0}


def test_a_built_mesh_cloth_equals_the_file(tmp_path):
    points, triangles = mesh_arrays()
    obj = write_obj(tmp_path / "sheet.obj", points, triangles)
    doc = {"cloth": [{"name": "sheet", "mesh": str(obj), **MESH_KEYS}], "collider": [PLANE]}
    from_file = load(tmp_path, doc)
    from_file_built = build(doc).scene()
    in_memory = SceneBuilder("scene")
    in_memory.add_mesh(points=points, faces=triangles, name="sheet", **as_python(MESH_KEYS))
    in_memory.add_plane(**{k: v for k, v in PLANE.items() if k != "type"})
    in_memory = in_memory.scene()
    for built in (from_file_built, in_memory):
        assert same_mesh_cloth(built.cloths[0], from_file.cloths[0])
        assert (built.simulation, built.output, built.colliders) == \
            (from_file.simulation, from_file.output, from_file.colliders)
    assert in_memory.cloths[0].mesh.mesh.source.file is None  # no file to refuse as an output or to override
    assert len(in_memory.cloths[0].mesh.pins) == 1 + 5  # vertex 0 and the far row, from the box
    positions = frames_of(from_file)
    assert np.array_equal(frames_of(in_memory), positions)
    assert np.array_equal(frames_of(from_file_built), positions)


def test_a_mesh_of_polygons_of_any_size(tmp_path):
    """faces as a list of faces of different sizes (a quad and a triangle), as Faces would hold them."""
    from warp_verlet.geometry.faces import Faces

    points = [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1), (2, 0, 0)]
    builder = SceneBuilder()
    spec = builder.add_mesh(points=points, faces=[[0, 3, 2, 1], [1, 2, 4]], pins=[0])
    assert spec.mesh.mesh.faces == Faces([4, 3], [0, 3, 2, 1, 1, 2, 4]) and spec.particle_count == 5
    again = builder.add_mesh(points=np.array(points, np.float32), faces=Faces([4, 3], [0, 3, 2, 1, 1, 2, 4]),
                             name="again", pins=[0])
    assert same_mesh_cloth(dataclasses.replace(again, name=spec.name), spec)


@pytest.mark.parametrize("call,key,problem", [
    (dict(points=[(0, 0, 0), (1, 0, 0)]), "faces", "is required with points"),
    (dict(mesh="a.obj", points=[(0, 0, 0)], faces=[(0, 0, 0)]), "mesh", "not both"),
    (dict(), "mesh", "expected a mesh file"),
    (dict(points=[(0, 0), (1, 0), (0, 1)], faces=[(0, 1, 2)]), "points", "got shape (3, 2)"),
    (dict(points=[(0, 0, 0), (1, 0, np.nan), (0, 1, 0)], faces=[(0, 1, 2)]), "points[1]", "finite point"),
    (dict(points=[(0, 0, 0), (1, 0, 0), (0, 1, 0)], faces=[(0, 1, 2.5)]), "faces", "must be integers"),
    (dict(points=[(0, 0, 0), (1, 0, 0), (0, 1, 0)], faces=[(0, 1, 3)]), None, "uses vertex 3"),
    (dict(points=[(0, 0, 0), (1, 0, 0), (0, 1, 0), (5, 5, 5)], faces=[(0, 1, 2)]), None, "vertex 3 is used by no face"),
    (dict(points=[(0, 0, 0), (1, 0, 0), (0, 1, 0)], faces=[(0, 1, 2)], prim="/Cloth"), "prim", "unknown key"),
    (dict(points=[(0, 0, 0), (1, 0, 0), (0, 1, 0)], faces=[(0, 1, 2)], pins=[{"primvar": "pinned"}]), "pins[0]",
     "need a USD file"),
    (dict(points=[(0, 0, 0), (1, 0, 0), (0, 1, 0)], faces=[(0, 1, 2)], pins=[3]), "pins[0]", "outside the mesh"),
])
def test_a_bad_mesh_in_memory_names_the_call_and_the_argument(call, key, problem):
    builder = SceneBuilder()
    builder.add_grid(**GOOD_GRID)
    with pytest.raises(SceneError) as caught:
        builder.add_mesh(**call)
    assert (caught.value.file, caught.value.key) == ("add_mesh(cloth 1)", key)
    assert problem in caught.value.problem
    assert len(builder.cloths) == 1  # nothing was added


# ------------------------------------------------------------------------------------------------------------
# finalize(): the Model the Simulator builds.

def _arrays_equal(a, b, where: str) -> list[str]:
    """Where the Models' contents differ: device arrays by value, nested containers and objects by their parts."""
    if isinstance(a, wp.array):
        same = (isinstance(b, wp.array) and a.dtype == b.dtype and a.shape == b.shape
                and np.array_equal(a.numpy(), b.numpy()))
        return [] if same else [where]
    if isinstance(a, np.ndarray):
        return [] if isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b) else [where]
    if isinstance(a, dict):
        if not isinstance(b, dict) or a.keys() != b.keys():
            return [where]
        return [d for k in a for d in _arrays_equal(a[k], b[k], f"{where}[{k!r}]")]
    if isinstance(a, (list, tuple)):
        if type(a) is not type(b) or len(a) != len(b):
            return [where]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _arrays_equal(x, y, f"{where}[{i}]")]
    if isinstance(a, (Scene, wp.Device)) or a is None or isinstance(a, (bool, int, float, str, type)):
        return [] if a == b or a is b else [where]
    if hasattr(a, "__dict__"):
        if type(a) is not type(b):
            return [where]
        return _arrays_equal(vars(a), vars(b), where)
    return [] if a == b else [where]


@pytest.mark.parametrize("cloths", ["one grid", "grids", "grids and a mesh"])
def test_finalize_is_the_simulators_model(device, cloths):
    """One grid cloth gets implicit sticks on a GPU, several grids the analytic colouring, a mesh Warp's graph
    colouring: in each case finalize() builds the Model the Simulator builds."""
    grids = [GRID] if cloths == "one grid" else [GRID, ROPE, PATCHED]
    builder = build({"simulation": SIMULATION, "cloth": grids, "collider": [SPHERE, MOVING, PLANE]})
    if cloths == "grids and a mesh":
        points, triangles = mesh_arrays()
        builder.add_mesh(points=points, faces=triangles, name="sheet2", pins=[0], translate=(3.0, 1.0, 0.0))
    model = builder.finalize(device)
    reference = Simulator(builder.scene(), device).model
    assert str(model.device) == str(reference.device) and model.device.is_cpu == (device == "cpu")
    assert model.sticks_form == reference.sticks_form
    assert sorted(vars(model)) == sorted(vars(reference))
    assert _arrays_equal(model, reference, "model") == []
    assert model.particle_count == {"one grid": 30, "grids": 67, "grids and a mesh": 87}[cloths]
    # The comparison sees a changed array.
    changed = builder.finalize(device)
    vars(changed)["host_inv_mass"] = changed.host_inv_mass + np.eye(1, changed.particle_count, 3, np.float32)[0]
    assert _arrays_equal(changed, reference, "model") == ["model['host_inv_mass']"]


# ------------------------------------------------------------------------------------------------------------
# docs/api.md's example.

def api_example() -> str:
    text = (REPO / "docs" / "api.md").read_text(encoding="utf-8")
    found = re.search(r"^## Build a scene in Python\n.*?```python\n(.*?)```", text, re.S | re.M)
    assert found, "docs/api.md has no Python example under 'Build a scene in Python'"
    return found[1]


def test_the_api_docs_example_builds_and_runs_a_scene(tmp_path, monkeypatch, capsys):
    from warp_verlet.output.cache_reader import open_cache
    from warp_verlet.output.usd_writer import validate_cache

    code = api_example()
    assert "toml" not in code.lower() and "SceneBuilder" in code
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "docs/api.md", "exec"), {"__name__": "__main__"})
    out = capsys.readouterr().out
    cache = tmp_path / "drape.usda"
    assert validate_cache(cache) == []
    written = open_cache(cache)
    assert (len(written.frames), len(written.cloths), len(written.colliders)) == (31, 1, 2)  # frame 0 and 30 more
    assert re.search(r"^frames\s+30$", out, re.M) and "(256, 3)" in out
