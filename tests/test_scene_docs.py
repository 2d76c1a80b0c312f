"""docs/scenes.md's key tables against the keys' declarations (warp_verlet.scene_keys.Key).

- the tables in docs/scenes.md are exactly what docs/make_scene_tables.py writes from the declarations;
- the generator rewrites only what lies between its markers, and refuses a marker it cannot fill;
- collider and constraint kinds' tables come from their registries, when those exist;
- each declaration's default is the settings dataclasses' default, and the range its ``allowed`` text states is
  the range its parser enforces, end by end.
"""

from __future__ import annotations

import importlib.util
import math
import sys
import types
from dataclasses import MISSING, fields, replace
from pathlib import Path

import pytest
from key_ranges import documented_range, is_scalar_number

from warp_verlet.errors import ArgumentError
from warp_verlet.input import mesh_scene

from warp_verlet.input import scene
from warp_verlet.input.scene import CLOTH_KEYS, GRID_KEYS, OUTPUT_KEYS, SIMULATION_KEYS, ClothSpec, OutputSettings
from warp_verlet.scene_keys import REQUIRED, Invalid, Key, real

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("make_scene_tables", REPO / "docs" / "make_scene_tables.py")
tables_tool = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(tables_tool)

SCENES_MD = REPO / "docs" / "scenes.md"
ALL_KEYS = SIMULATION_KEYS + OUTPUT_KEYS + CLOTH_KEYS + GRID_KEYS + mesh_scene.MESH_KEYS


def test_scenes_md_tables_are_the_declarations():
    text = SCENES_MD.read_text(encoding="utf-8")
    tables = tables_tool.key_tables()
    new, changed = tables_tool.rewrite(text, tables)
    assert not changed, (f"docs/scenes.md's tables {', '.join(changed)} are out of date with the key declarations: "
                         "run python docs/make_scene_tables.py")
    assert new == text
    for name in ("simulation", "output", "cloth", "grid", "mesh"):  # each of the scene's own tables is in the docs
        assert f"<!-- keys: {name} -->" in text


def test_the_check_fails_on_a_changed_declaration(tmp_path, monkeypatch, capsys):
    """What makes the test above fail: a declaration whose doc changed leaves its table out of date, and the
    script's --check says so (exit 1) and names the table; a plain run writes it, and --check passes again."""
    copy = tmp_path / "scenes.md"
    copy.write_text(SCENES_MD.read_text(encoding="utf-8"), encoding="utf-8")
    assert tables_tool.main(["--check", "--file", str(copy)]) == 0
    changed = tuple(replace(k, doc="Frames per second.") if k.name == "fps" else k for k in SIMULATION_KEYS)
    monkeypatch.setattr(scene, "SIMULATION_KEYS", changed)
    assert tables_tool.main(["--check", "--file", str(copy)]) == 1
    assert "simulation" in capsys.readouterr().err
    assert tables_tool.main(["--file", str(copy)]) == 0
    assert "| `fps` | number | Hz | `60.0` | > 0 | Frames per second. |" in copy.read_text(encoding="utf-8")
    assert tables_tool.main(["--check", "--file", str(copy)]) == 0


KEYS = (Key("speed", real(0.0), 1.5, "number", "m/s", allowed="≥ 0", doc="How fast."),
        Key("label", lambda v, k: v, REQUIRED, "string", doc="Its name."),
        Key("axis", lambda v, k: v, (0.0, 1.0, 0.0), "[x, y, z] numbers", allowed="finite", doc="Which way."),
        Key("on", lambda v, k: v, False, "boolean", doc="Whether."),
        Key("limit", lambda v, k: v, None, "number", default_text="absent: no limit", doc="At most."))
TABLE = """| key | type | unit | default | allowed | meaning |
|---|---|---|---|---|---|
| `speed` | number | m/s | `1.5` | ≥ 0 | How fast. |
| `label` | string | – | **required** |  | Its name. |
| `axis` | [x, y, z] numbers | – | `[0.0, 1.0, 0.0]` | finite | Which way. |
| `on` | boolean | – | `false` |  | Whether. |
| `limit` | number | – | absent: no limit |  | At most. |"""


def test_the_generator_writes_between_the_markers_and_nowhere_else():
    text = "# Title\n\nprose | with a bar\n<!-- keys: things -->\nstale\n| old |\n<!-- /keys -->\nafter\n"
    new, changed = tables_tool.rewrite(text, {"things": KEYS})
    assert changed == ["things"]
    assert new == ("# Title\n\nprose | with a bar\n<!-- keys: things -->\n\n" + TABLE + "\n\n<!-- /keys -->\nafter\n")
    assert tables_tool.rewrite(new, {"things": KEYS}) == (new, [])  # written once, it is up to date


@pytest.mark.parametrize("text, problem", [
    ("<!-- keys: nothing -->\n<!-- /keys -->\n", "no table of keys is named 'nothing'"),
    ("<!-- keys: things -->\n| a |\n", "has no <!-- /keys --> after it"),
    ("text\n<!-- /keys -->\n", "without a <!-- keys: NAME --> before it"),
    ("<!-- keys: things -->\n<!-- keys: things -->\n<!-- /keys -->\n", "a marker inside the table 'things'"),
    ("<!-- keys things -->\n", "expected a marker <!-- keys: NAME -->"),
    ("<!-- keys: empty -->\n<!-- /keys -->\n", "declares no keys"),
])
def test_a_marker_the_generator_cannot_fill_is_an_error(text, problem):
    with pytest.raises(tables_tool.TableError, match="scenes.md:[0-9]+: ") as info:
        tables_tool.rewrite(text, {"things": KEYS, "empty": ()}, "docs/scenes.md")
    assert problem in str(info.value)


def test_a_declaration_without_a_writable_default_or_with_a_bar_is_an_error():
    with pytest.raises(tables_tool.TableError, match="'limit'.*default_text"):
        tables_tool.render_table([replace(KEYS[4], default_text=None)])
    with pytest.raises(tables_tool.TableError, match="'speed'.*'\\|'"):
        tables_tool.render_table([replace(KEYS[0], doc="a | b")])
    assert "\\|x\\|" in tables_tool.render_table([replace(KEYS[0], doc="a \\|x\\| b")])  # escaped: a cell


def _fake_module(monkeypatch, name: str, **attributes) -> None:
    module = types.ModuleType(name)
    module.__dict__.update(attributes)
    monkeypatch.setitem(sys.modules, name, module)


def test_kind_registries_add_their_tables(monkeypatch):
    """A collider kind's table is collider.<its name or type>, with its keys; a constraint kind's is
    constraint.<name>, with its cloth_keys; the keys every collider shares are the table collider."""
    box = types.SimpleNamespace(type="box", keys=KEYS[:2])
    _fake_module(monkeypatch, "warp_verlet.colliders", COLLIDER_KINDS={"box": box}, SHARED_KEYS=KEYS[2:])
    angle = types.SimpleNamespace(name="angle_limit", cloth_keys=KEYS[4:])
    plain = types.SimpleNamespace(name="plain", cloth_keys=())
    _fake_module(monkeypatch, "warp_verlet.constraints", CONSTRAINT_KINDS=(angle, plain))
    tables = tables_tool.key_tables()
    assert tables["collider.box"] == KEYS[:2] and tables["collider"] == KEYS[2:]
    assert tables["constraint.angle_limit"] == KEYS[4:] and tables["constraint.plain"] == ()
    assert tables["simulation"] == SIMULATION_KEYS and tables["mesh"] == mesh_scene.MESH_KEYS
    text = "<!-- keys: collider.box -->\n<!-- /keys -->\n"
    assert tables_tool.rewrite(text, tables)[1] == ["collider.box"]


def test_without_the_registries_the_scene_tables_remain(monkeypatch):
    monkeypatch.setitem(sys.modules, "warp_verlet.colliders", None)  # as if the package were not there
    monkeypatch.setitem(sys.modules, "warp_verlet.constraints", None)
    assert set(tables_tool.key_tables()) == {"simulation", "simulation.air", "output", "cloth", "grid", "mesh"}


def test_a_kind_without_keys_or_a_name_is_an_error(monkeypatch):
    _fake_module(monkeypatch, "warp_verlet.colliders", COLLIDER_KINDS=(types.SimpleNamespace(type="box"),))
    with pytest.raises(tables_tool.TableError, match="kind 'box' has no keys tuple"):
        tables_tool.key_tables()
    _fake_module(monkeypatch, "warp_verlet.colliders", COLLIDER_KINDS=(types.SimpleNamespace(keys=KEYS),))
    with pytest.raises(tables_tool.TableError, match="has no name"):
        tables_tool.key_tables()


def test_every_declaration_is_documented():
    for key in ALL_KEYS:
        assert key.doc and key.type and key.unit, key
        assert key.doc.endswith((".", ")")), key.name  # a sentence


def test_the_settings_dataclasses_hold_the_declared_defaults():
    """Settings built in code (SimulationSettings(), ClothSpec(...)) get what a scene file that leaves the key
    out gets."""
    for cls, keys in ((scene.SimulationSettings, SIMULATION_KEYS), (OutputSettings, OUTPUT_KEYS),
                      (ClothSpec, CLOTH_KEYS + GRID_KEYS)):
        declared = {k.name: k.default for k in keys}
        for f in fields(cls):
            if f.name not in declared or declared[f.name] is REQUIRED:
                continue
            default = f.default_factory() if f.default_factory is not MISSING else f.default
            if declared[f.name] is None:
                continue  # decided by the loader from the rest of the scene (name, path, torn_faces, tethers)
            assert default == declared[f.name], (cls.__name__, f.name, default, declared[f.name])
    assert scene.parse_scene({"cloth": [{"resolution": [2, 2], "size": [1.0, 1.0]}]}).simulation == \
        scene.SimulationSettings()


SCALAR_NUMBERS = [k for k in ALL_KEYS if is_scalar_number(k)]


@pytest.mark.parametrize("key", SCALAR_NUMBERS, ids=[k.name for k in SCALAR_NUMBERS])
def test_the_documented_range_is_the_range_the_parser_enforces(key):
    """Each end of the range a key's docs state is probed: on it (accepted unless open), just past it (refused),
    just inside it (accepted); an unbounded end accepts a huge number."""
    lo, lo_open, hi, hi_open, integer = documented_range(key)

    def accepted(value) -> bool:
        try:
            key.parse(value, key.name)
        except Invalid:
            return False
        return True

    def step(x, direction):
        return x + direction if integer else math.nextafter(x, direction * math.inf)

    for end, is_open, outward in ((lo, lo_open, -1), (hi, hi_open, 1)):
        if end is None:
            assert accepted(outward * (10**12 if integer else 1e300)), key.name
            continue
        assert accepted(end) != is_open, (key.name, end)
        assert not accepted(step(end, outward)), (key.name, end)
        assert accepted(step(end, -outward)), (key.name, end)


# ---------------------------------------------------------------------------------------------- declarations


def test_a_key_that_needs_context_is_bound_first():
    """pins and particle_masses need the grid: their declaration makes the parser from (rows, cols)."""
    pins = scene._GRID["pins"]
    with pytest.raises(ArgumentError, match="needs its context"):
        pins.take(scene._Table("k.toml", "cloth[0]", {"pins": [0]}))
    table = scene._Table("k.toml", "cloth[0]", {"pins": ["bottom-right", 1]})
    assert pins.bound(3, 4).take(table) == ((0, 1), (2, 3))
    with pytest.raises(ArgumentError, match="takes no context"):
        SIMULATION_KEYS[0].bound(3, 4)
    with pytest.raises(ArgumentError, match="exactly one of parse and bind"):
        Key("both", real(), bind=lambda: real())
    with pytest.raises(ArgumentError, match="exactly one of parse and bind"):
        Key("neither")


EXTRA = Key("angle_limit", real(0.0, 180.0), None, "number", "degrees", default_text="absent: no limit",
            allowed="0 … 180", doc="The largest angle between neighbouring faces.")


@pytest.mark.parametrize("cloth", [{"resolution": [2, 3], "size": [1.0, 1.0]}, "mesh"], ids=["grid", "mesh"])
def test_the_keys_of_constraint_kinds_land_in_the_cloths_options(tmp_path, monkeypatch, cloth):
    """The seam for constraint kinds: a key cloth_keys_of_kinds() declares is taken from a grid and a mesh cloth
    alike into ClothSpec.options, left out it is its default, a bad value is refused naming it, and without the
    declaration it is an unknown key."""
    if cloth == "mesh":
        from mesh_files import grid_mesh, triangulated, write_obj

        points, faces = grid_mesh(2, 3)
        cloth = {"mesh": str(write_obj(tmp_path / "panel.obj", points, triangulated(faces)))}

    def load(**extra):
        return scene.parse_scene({"cloth": [{**cloth, **extra}]}, "k.toml", tmp_path / "k.toml").cloths[0]

    with pytest.raises(scene.SceneError, match="cloth\\[0\\].angle_limit: unknown key"):
        load(angle_limit=30.0)
    assert load().options == {"line_passes": 0, "max_bend_angle": None, "self_collision": False,
                              "collision_thickness": None,
                              "self_collision_stride": None, "self_friction_coefficient": None,
                              "self_static_friction_coefficient": None, "rigid_patches": ()}  # the kinds' defaults
    monkeypatch.setattr(scene, "cloth_keys_of_kinds", lambda: (EXTRA,))
    spec = load(angle_limit=30)
    assert spec.options == {"angle_limit": 30.0} and isinstance(spec.options["angle_limit"], float)
    with pytest.raises(TypeError):
        spec.options["angle_limit"] = 1.0  # read-only
    assert load().options == {"angle_limit": None}
    with pytest.raises(scene.SceneError, match="cloth\\[0\\].angle_limit: expected a number in \\[0.0, 180.0\\]"):
        load(angle_limit=181.0)


def test_cloth_options_are_read_only_and_survive_pickling():
    """A sweep's process pool pickles scenes: ClothSpec.options must pickle (a mappingproxy does not)."""
    import pickle

    from warp_verlet.scene_keys import FrozenMapping

    options = FrozenMapping({"angle_limit": 30.0})
    spec = ClothSpec("c", (2, 2), (1.0, 1.0), options=options)
    assert pickle.loads(pickle.dumps(spec)).options == {"angle_limit": 30.0}
    assert ClothSpec("c", (2, 2), (1.0, 1.0)).options == {"line_passes": 0, "max_bend_angle": None,
                                                          "self_collision": False,
                                                          "collision_thickness": None, "self_collision_stride": None,
                                                          "self_friction_coefficient": None,
                                                          "self_static_friction_coefficient": None,
                                                          "rigid_patches": ()}
    assert FrozenMapping() == {}
    with pytest.raises(TypeError):
        options["angle_limit"] = 1.0
    with pytest.raises(AttributeError):
        options._items = {}
    assert dict(options) == {"angle_limit": 30.0} and dict({**options, "x": 1}) == {"angle_limit": 30.0, "x": 1}
