"""Loader fuzzing beyond tests/test_scene_validation.py.

That file fuzzes one-line-per-key documents (every table inline), nearly valid scenes with random values
written over them, and random or spliced bytes of one shipped scene; it checks only that nothing but
SceneError escapes. Here, with hypothesis and a small TOML serialiser that writes real ``[table]`` and
``[[array]]`` headers (checked to round-trip through tomllib first):

- random structured documents, weighted to the real section and key names, raise only SceneError;
- every key the loader takes, given a value of a wrong type, raises SceneError naming the file and that key (or an
  element of it). The keys and the kinds each accepts are not listed here: they are recorded from the loader itself
  (warp_verlet/scene_keys.recorded_keys) as it loads a scene with every section (a grid cloth, a mesh cloth, a
  plane, a still and a moving sphere), so a key added to the loader is fuzzed without anyone adding it here;
- every numeric key, given huge, tiny, negative or zero numbers, either loads with exactly that value inside
  its documented range or raises SceneError naming the key: the loader never accepts an out-of-range value;
- unknown unicode keys are reported as unknown under their own dotted path; unicode names, choices and pin
  names are refused unless valid, and a unicode output path loads unchanged;
- any subset of sections and keys left out: loads with the documented defaults, or, when a required key is
  missing, raises SceneError saying so for one of the missing required keys;
- every shipped scene truncated at every byte offset: SceneError or a valid Scene, never anything else;
- random valid scenes (every key, drawn inside its documented range) load and read back what was written.
"""

from __future__ import annotations

import math
import re
import sys
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from warp_verlet.errors import SceneError
from warp_verlet.colliders.plane import PlaneCollider
from warp_verlet.colliders.sphere import SphereCollider
from warp_verlet.input.mesh_scene import MESH_KEYS
from warp_verlet.input.scene import NAMED_PINS, ClothSpec, OutputSettings, Scene, SimulationSettings, load_scene, parse_scene
from warp_verlet.scene_keys import Table, real, recorded_keys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCENES = Path(__file__).resolve().parent.parent / "scenes"
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

from key_ranges import Range, documented_range, is_scalar_number  # noqa: E402
from mesh_files import grid_mesh, triangulated, write_obj  # noqa: E402
from toml_text import dump  # noqa: E402


def same(a, b) -> bool:
    """Equality that treats NaN as equal to NaN and keeps int and float apart."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


def load_text(tmp_path: Path, text: str | bytes, name: str = "fuzz.toml") -> Scene:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8"))
    return load_scene(path)


def load_doc(tmp_path: Path, doc: dict) -> Scene:
    return load_text(tmp_path, dump(doc))


def scene_error(tmp_path: Path, doc: dict) -> SceneError:
    with pytest.raises(SceneError) as info:
        load_doc(tmp_path, doc)
    return info.value


# ---------------------------------------------------------------------------------------------- strategies

text = st.text(st.characters(codec="utf-8"), max_size=12)
keys = text
finite = st.floats(allow_nan=False, allow_infinity=False)
scalars = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(),
    text,
)
values = st.recursive(scalars, lambda c: st.lists(c, max_size=3) | st.dictionaries(keys, c, max_size=3), max_leaves=8)

# Wrong-type value pools, one per kind of TOML value (the kinds of warp_verlet/scene_keys.py: each parser declares
# the kinds it accepts; the others are wrong for it).
KINDS = {
    "bool": st.booleans(),
    "int": st.integers(min_value=-(2**70), max_value=2**70),
    "float": st.floats().filter(lambda x: not x.is_integer() if math.isfinite(x) else True),
    "string": text,
    "array": st.lists(scalars, max_size=3),
    "table": st.dictionaries(keys, scalars, max_size=3),
}


def kind_of(value) -> str:
    return {bool: "bool", int: "int", float: "float", str: "string", list: "array", dict: "table"}[type(value)]


def full_scene() -> dict:
    """A valid scene that gives every key (a moving sphere is a separate case: ``path`` excludes ``centre``).
    Its pins and particle masses stay on row 0, so that any row count keeps them valid."""
    return {
        "simulation": {"fps": 60.0, "frames": 10, "substeps": 2, "iterations": 4, "gravity": [0.0, -9.81, 0.0],
                       "wind": [1.0, 0.0, 0.5], "damping": 0.5, "relaxation": "coloured", "max_dt_ratio": 2.0,
                       "max_frame_time": 0.1, "position_bound": 100.0, "precision": "float64"},
        "output": {"path": "fuzz.usdc", "save_every": 5, "up_axis": "Y", "meters_per_unit": 1.0, "kind": "cache",
                   "torn_faces": "holes"},
        "cloth": [{"name": "sheet", "resolution": [3, 4], "size": [0.5, 0.6], "origin": [0.0, 1.0, 0.0],
                   "orientation": "vertical", "mass": 0.2, "sticks": ["structural", "shear", "bend"],
                   "compliance": {"structural": 1e-4, "shear": 1e-3, "bend": 1e-2},
                   "pins": ["top-left", 3, [0, 2]], "tear_threshold": 1.5, "particle_masses": [[0, 1, 0.05]],
                   "tethers": True, "tether_scale": 2.0}],
        "collider": [{"type": "plane", "name": "ground", "thickness": 0.01, "friction_coefficient": 0.2, "normal": [0.0, 1.0, 0.0],
                      "point": [0.0, -1.0, 0.0], "display_size": 4.0, "purpose": "default"},
                     {"type": "sphere", "name": "ball", "thickness": 0.0, "friction_coefficient": 0.0, "radius": 0.2,
                      "centre": [0.0, 0.5, 0.3], "purpose": "guide"}],
    }


# The mesh of the every-key scene's mesh cloth: 2 x 3 vertices, triangles (as trimesh gives them), written once.
_MESH_DIR = tempfile.TemporaryDirectory(prefix="scene_fuzz_")
MESH = write_obj(Path(_MESH_DIR.name) / "panel.obj", *(lambda p, f: (p, triangulated(f)))(*grid_mesh(2, 3)))


def every_key_scene() -> dict:
    """full_scene() and the sections it lacks: a mesh cloth with every mesh key (a USD prim aside: an OBJ refuses
    one), and a moving sphere (``path`` instead of ``centre``)."""
    doc = full_scene()
    doc["cloth"].append({"name": "panel", "mesh": str(MESH), "translate": [0.0, 2.0, 0.0], "rotate": [0.0, 90.0, 0.0],
                         "scale": 0.5, "weld_distance": 1e-6, "pins": [0, {"min": [-9.0, -9.0, -9.0],
                                                                        "max": [9.0, 2.0, 9.0]}],
                         "particle_masses": [[5, 0.01]], "mass_distribution": "even", "mass": 0.1,
                         "sticks": ["structural", "bend"], "compliance": {"bend": 0.5}, "tear_threshold": 3.0,
                         "tethers": False, "tether_scale": 4.0})
    doc["collider"].append({"type": "sphere", "name": "swing", "thickness": 0.01, "friction_coefficient": 0.1, "radius": 0.1,
                            "path": [[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 1.0, 0.0]], "purpose": "guide"})
    return doc


def recorded(doc: dict) -> dict[str, frozenset]:
    """Every key the loader takes from ``doc`` (present or left to its default), with the kinds it accepts."""
    with recorded_keys() as taken:
        parse_scene(doc, "every_key.toml", Path(_MESH_DIR.name) / "every_key.toml")
    return taken


EVERY_KEY = recorded(every_key_scene())


def path_of(key: str) -> tuple:
    """The path into a document of a key as the loader names it: "cloth[1].compliance.bend" ->
    ("cloth", 1, "compliance", "bend")."""
    return tuple(int(index) if index else name for name, index in re.findall(r"([^.\[\]]+)|\[(\d+)\]", key))


def doc_keys(doc: dict, prefix: str = "") -> list[str]:
    """Every key a document gives, as the loader names it: tables and arrays of tables are walked into."""
    out = []
    for name, value in doc.items():
        key = f"{prefix}.{name}" if prefix else name
        out.append(key)
        if isinstance(value, dict):
            out += doc_keys(value, key)
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value) and name in (
                "cloth", "collider"):
            for i, item in enumerate(value):
                out += doc_keys(item, f"{key}[{i}]")
    return out


def known_key_paths() -> list[tuple[str, tuple, frozenset]]:
    """(dotted key as the loader names it, path into full_scene(), kinds accepted) for every key the loader takes
    from full_scene(), recorded from the loader."""
    return [(key, path_of(key), kinds) for key, kinds in sorted(recorded(full_scene()).items())]


def put(doc, path: tuple, value) -> None:
    for p in path[:-1]:
        doc = doc[p]
    doc[path[-1]] = value


def names_key(err: SceneError, key: str) -> bool:
    return err.key is not None and (err.key == key or err.key.startswith((key + "[", key + ".")))


# ---------------------------------------------------------------------------------------------- the serialiser


@pytest.mark.slow
@settings(max_examples=150, deadline=None)
@given(doc=st.dictionaries(keys, values, max_size=5))
def test_serialiser_round_trips_through_tomllib(doc):
    assert same(tomllib.loads(dump(doc)), doc)


def test_serialiser_writes_headers_and_full_scene_loads(tmp_path):
    text = dump(full_scene())
    assert "[simulation]" in text and "[[cloth]]" in text and "[cloth.compliance]" in text and "[[collider]]" in text
    scene = load_text(tmp_path, text)
    assert scene.cloths[0].tear_threshold == 1.5 and len(scene.colliders) == 2
    assert scene.cloths[0].sticks == ("structural", "shear", "bend") and scene.cloths[0].compliance["bend"] == 1e-2


# ---------------------------------------------------------------------------------------------- random structure

SECTION = st.sampled_from(["simulation", "output", "cloth", "collider"])
# The loader's keys, and the old ones it refuses with a message of their own.
KNOWN = sorted({path_of(key)[-1] for key in EVERY_KEY if isinstance(path_of(key)[-1], str)} | {"drag", "solver"})
near_keys = st.one_of(st.sampled_from(KNOWN), keys)
near_tables = st.dictionaries(near_keys, values, max_size=8)
documents = st.dictionaries(
    st.one_of(SECTION, keys),
    st.one_of(near_tables, st.lists(near_tables, min_size=1, max_size=3), values),
    max_size=5,
)


@pytest.mark.slow
@FUZZ
@given(doc=documents)
def test_random_structured_documents_raise_only_scene_errors(tmp_path, doc):
    try:
        scene = load_doc(tmp_path, doc)
    except SceneError as err:
        assert err.problem and str(err).startswith(str(tmp_path / "fuzz.toml"))
    else:
        assert isinstance(scene, Scene) and scene.cloths


# ---------------------------------------------------------------------------------------------- wrong types


def test_every_key_a_full_scene_loads_is_recorded_with_the_kinds_it_accepts():
    """The fuzzed keys are the loader's: the keys a hand-kept table once missed are among them, every key the
    every-key scene gives was taken by the loader, each declares what it accepts, and the value given is of
    such a kind."""
    mesh_keys = tuple(key.name for key in MESH_KEYS)
    assert {"simulation.multilevel", "simulation.multilevel_sweeps", "simulation.target_stretch",
            "simulation.max_substeps", "collider[2].path", *(f"cloth[1].{k}" for k in mesh_keys)} <= set(EVERY_KEY)
    doc = every_key_scene()
    assert set(doc_keys(doc)) <= set(EVERY_KEY), set(doc_keys(doc)) - set(EVERY_KEY)
    assert all(EVERY_KEY.values()), [key for key, kinds in EVERY_KEY.items() if not kinds]
    for key in doc_keys(doc):
        value = doc
        for p in path_of(key):
            value = value[p]
        assert kind_of(value) in EVERY_KEY[key], (key, value, EVERY_KEY[key])


def _collider_kinds_declared() -> bool:
    """Whether the collider kinds declare their keys (a registry, warp_verlet.colliders.COLLIDER_KINDS)."""
    import importlib

    try:
        return hasattr(importlib.import_module("warp_verlet.colliders"), "COLLIDER_KINDS")
    except ModuleNotFoundError:
        return False


def test_every_key_the_loader_takes_is_declared_and_documented():
    """Every key the every-key scene's load takes was taken through a declaration (scene_keys.Key) with a doc, a
    type and a unit, which docs/scenes.md's tables are written from. Not declared on their own, and why:
    - the sections (simulation, output, cloth, collider): tables of keys, each key of which is declared;
    - a declared key's own sub-keys (compliance.structural, .shear, .bend): the key is one table whose entries
      are the stick families, documented in its row ("table of family = number");
    - a collider's keys, until the collider kinds declare theirs (warp_verlet.colliders.COLLIDER_KINDS): from
      then on they are held to the same rule."""
    declared = EVERY_KEY.declared
    undeclared = []
    for key in EVERY_KEY:
        if key in declared:
            decl = declared[key]
            assert decl.doc and decl.type and decl.unit, (key, decl)
            assert decl.name == path_of(key)[-1], (key, decl.name)
            continue
        parent = key.rsplit(".", 1)[0]
        if len(path_of(key)) == 1 or (parent != key and parent in declared):
            continue
        if key.startswith("collider[") and not _collider_kinds_declared():
            continue
        undeclared.append(key)
    assert not undeclared, f"keys taken without a declaration: {undeclared}"
    assert {"simulation.fps", "output.torn_faces", "cloth[0].pins", "cloth[1].mesh", "cloth[1].tethers"} <= set(
        declared)


def test_a_key_taken_without_its_declaration_is_caught():
    """What the test above guards against: a key taken as t.take(name, parse) is recorded with no declaration,
    one taken as key.take(t) with its own."""
    from warp_verlet.scene_keys import Key

    declared = Key("brand_new", real(0.0), 1.0, "number", "m", doc="New.")
    with recorded_keys() as taken:
        table = Table("new.toml", "simulation", {})
        table.take("raw", real(0.0), 1.0)
        declared.take(table)
    assert set(taken) == {"simulation.raw", "simulation.brand_new"}
    assert taken.declared == {"simulation.brand_new": declared}


def test_a_key_taken_by_any_table_is_recorded():
    """What makes a new key fuzzed: a take() inside recorded_keys() records it with its parser's kinds (and nothing
    is recorded outside one)."""
    Table("new.toml", "simulation", {}).take("brand_new", real(0.0), 1.0)
    with recorded_keys() as taken:
        Table("new.toml", "simulation", {"brand_new": 2.0}).take("brand_new", real(0.0), 1.0)
    assert taken == {"simulation.brand_new": frozenset({"int", "float"})}


@pytest.mark.slow
@pytest.mark.parametrize("key", sorted(EVERY_KEY))
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_wrong_type_for_every_key_names_the_file_and_the_key(tmp_path, key, data):
    wrong = [kind for kind in KINDS if kind not in EVERY_KEY[key]]
    value = data.draw(st.sampled_from(wrong).flatmap(lambda kind: KINDS[kind]), label="value")
    doc = every_key_scene()
    put(doc, path_of(key), value)
    err = scene_error(tmp_path, doc)
    assert err.file == str(tmp_path / "fuzz.toml") and str(err).startswith(f"{err.file}: {err.key}: "), str(err)
    assert names_key(err, key), f"{key}: {err}"


# ---------------------------------------------------------------------------------------------- extreme numbers

# Documented ranges (docs/scenes.md): (low, low_open, high, high_open, integer). None: unbounded. Each key that is one
# number has its declaration's (its allowed text, read by tests/key_ranges.py), so a new one is fuzzed here
# without being listed; elements of vectors and tables, and colliders' keys, are listed here.
SCALAR_RANGES = {path_of(key): documented_range(decl) for key, decl in recorded(full_scene()).declared.items()
                 if is_scalar_number(decl)}
RANGES = {
    **SCALAR_RANGES,
    ("simulation", "gravity", 1): (None, False, None, False, False),
    ("simulation", "wind", 0): (None, False, None, False, False),
    ("cloth", 0, "size", 1): (0.0, True, None, False, False),  # 4 columns: > 0
    ("cloth", 0, "origin", 2): (None, False, None, False, False),
    ("cloth", 0, "resolution", 0): (1, False, 32_768, False, True),
    ("cloth", 0, "compliance", "shear"): (0.0, False, None, False, False),
    ("cloth", 0, "particle_masses", 0, 2): (0.0, True, None, False, False),
    ("collider", 0, "thickness"): (0.0, False, None, False, False),
    ("collider", 0, "friction_coefficient"): (0.0, False, None, False, False),
    ("collider", 0, "display_size"): (0.0, True, None, False, False),
    ("collider", 0, "point", 1): (None, False, None, False, False),
    ("collider", 1, "radius"): (0.0, True, None, False, False),
    ("collider", 1, "centre", 0): (None, False, None, False, False),
}

extreme_numbers = st.one_of(
    st.sampled_from([0, -0.0, 0.0, 1, -1, 1e-320, -1e-320, 5e-324, 1e308, -1e308, 1.7976931348623157e308,
                     2**31, 2**63, -(2**63), 2**64, 10**309, -(10**309), 32_768, 32_769, 10_000, 10_001,
                     100_000, 100_001, 1.0000000000000002, 0.9999999999999999]),
    st.integers(min_value=-(2**1100), max_value=2**1100),
    st.integers(min_value=0, max_value=3000).map(lambda b: 2**b),  # up to 900 digits
    st.floats(allow_nan=False),
)


def dotted(path: tuple) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def loaded_value(scene: Scene, path: tuple):
    section = path[0]
    if section == "simulation":
        v = getattr(scene.simulation, path[1])
        return v[path[2]] if len(path) > 2 else v
    if section == "output":
        return getattr(scene.output, path[1])
    if section == "cloth":
        spec = scene.cloths[path[1]]
        name = path[2]
        v = getattr(spec, name) if hasattr(spec, name) else spec.options[name]  # else a constraint kind's key
        if name == "compliance":
            return v.get(path[3], 0.0)  # 0 (rigid) is dropped on loading
        if name == "particle_masses":
            return v[path[3]][path[4]]
        return v[path[3]] if len(path) > 3 else v
    collider = scene.colliders[path[1]]
    if path[2] == "centre":
        return collider.keyframes[0][1][path[3]]
    v = getattr(collider, path[2])
    return v[path[3]] if len(path) > 3 else v


@pytest.mark.slow
@pytest.mark.parametrize("path", list(RANGES), ids=[dotted(p) for p in RANGES])
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(number=extreme_numbers)
def test_extreme_numbers_load_in_range_or_are_refused(tmp_path, path, number):
    lo, lo_open, hi, hi_open, integer = RANGES[path]
    doc = full_scene()
    put(doc, path, number)
    key = dotted(path)
    try:
        scene = load_doc(tmp_path, doc)
    except SceneError as err:
        assert names_key(err, key), f"{key} = {number!r}: {err}"
        return
    # It loaded: the value is the one written (as a float where a number is expected), of the right type,
    # finite, and inside the documented range.
    assert_number_loaded(loaded_value(scene, path), number, integer, lo, hi, lo_open, hi_open)


def assert_number_loaded(value, number, integer: bool, lo, hi, lo_open: bool, hi_open: bool) -> None:
    """``value`` is ``number`` as written (a float where a number is expected), finite, within [lo, hi]."""
    if integer:
        assert isinstance(value, int) and value == number
    else:
        assert isinstance(value, float) and value == float(number) and math.isfinite(value)
    if lo is not None:
        assert value > lo if lo_open else value >= lo
    if hi is not None:
        assert value < hi if hi_open else value <= hi


@pytest.mark.parametrize("path", list(RANGES), ids=[dotted(p) for p in RANGES])
def test_out_of_range_edges_are_refused(tmp_path, path):
    """Deterministic companions of the property above: just past each documented end is refused."""
    lo, lo_open, hi, hi_open, integer = RANGES[path]

    def past(end, is_open, direction):
        if end is None:
            return None
        if is_open:
            return end
        return end + direction if integer else math.nextafter(end, direction * math.inf)

    below, above = past(lo, lo_open, -1), past(hi, hi_open, 1)
    for bad in [v for v in (below, above, math.nan, math.inf, -math.inf) if v is not None]:
        doc = full_scene()
        put(doc, path, bad)
        assert names_key(scene_error(tmp_path, doc), dotted(path)), (path, bad)


# ---------------------------------------------------------------------------------------------- unicode

TABLE_PATHS = [((), ""), (("simulation",), "simulation"), (("output",), "output"), (("cloth", 0), "cloth[0]"),
               (("collider", 0), "collider[0]"), (("collider", 1), "collider[1]")]


@FUZZ
@given(where=st.sampled_from(TABLE_PATHS), key=st.text(st.characters(codec="utf-8"), min_size=1, max_size=10),
       value=values)
def test_unknown_unicode_keys_are_named(tmp_path, where, key, value):
    path, dotted_table = where
    doc = full_scene()
    table = doc
    for p in path:
        table = table[p]
    # "mesh" turns a grid cloth into a mesh cloth (tests/test_mesh_cloth.py checks its keys)
    if key in table or key in {"path", "collider", "cloth", "simulation", "output", "mesh"} or (
            path == ("collider", 1) and key == "path"):
        return  # a known key: other tests' business
    table[key] = value
    err = scene_error(tmp_path, doc)
    expected = f"{dotted_table}.{key}" if dotted_table else key
    assert err.key == expected and "unknown key" in err.problem, str(err)


name_like = st.one_of(st.text(st.characters(codec="utf-8"), max_size=10),
                      st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True))


@FUZZ
@given(name=name_like, which=st.sampled_from([("cloth", 0, "name"), ("collider", 0, "name")]))
def test_unicode_names(tmp_path, name, which):
    if name == "ball":
        return  # the sphere's name: a duplicate, tested in test_scene_validation
    doc = full_scene()
    put(doc, which, name)
    valid = re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) is not None
    if valid:
        scene = load_doc(tmp_path, doc)
        assert (scene.cloths[0].name if which[0] == "cloth" else scene.colliders[0].name) == name
    else:
        assert names_key(scene_error(tmp_path, doc), dotted(which))


@FUZZ
@given(value=st.text(st.characters(codec="utf-8"), max_size=12),
       which=st.sampled_from([("simulation", "relaxation"), ("output", "up_axis"), ("cloth", 0, "orientation"),
                              ("collider", 0, "type"), ("cloth", 0, "pins", 0)]))
def test_unicode_choices_are_exact(tmp_path, value, which):
    options = {"relaxation": {"coloured", "jacobi"}, "up_axis": {"Y", "Z"}, "orientation": {"vertical", "horizontal"},
               "type": {"plane", "sphere"}, 0: set(NAMED_PINS)}[which[-1]]
    doc = full_scene()
    put(doc, which, value)
    if value in options and which[-1] != "type":  # a plane turned sphere would lack a radius
        load_doc(tmp_path, doc)
    elif value not in options:
        assert names_key(scene_error(tmp_path, doc), dotted(which))


@FUZZ
# No "/" in the stem: "a/.usdc" names a dot-file with no suffix, refused (rightly) as not ending in .usdc.
@given(stem=st.text(st.characters(codec="utf-8", exclude_characters="\0/"), min_size=1, max_size=12),
       suffix=st.sampled_from([".usd", ".usdc", ".usda"]))
def test_unicode_output_paths_load_unchanged(tmp_path, stem, suffix):
    doc = full_scene()
    doc["output"]["path"] = stem + suffix
    assert load_doc(tmp_path, doc).output.path == Path(stem + suffix)
    doc["output"]["path"] = stem + "\0" + suffix
    assert scene_error(tmp_path, doc).key == "output.path"


# ---------------------------------------------------------------------------------------------- missing keys

REQUIRED = {("cloth",), ("cloth", 0, "resolution"), ("cloth", 0, "size"), ("collider", 0, "type"),
            ("collider", 1, "type"), ("collider", 1, "radius")}
OPTIONAL = [("simulation",), ("output",), ("collider",)] + [
    p for _, p, _ in known_key_paths() if p not in REQUIRED and len(p) > 1 and p[-1] != "type"]


def default_of(scene: Scene, path: tuple):
    """(loaded value, documented default) for an optional key that was left out."""
    if path == ("simulation",):
        return scene.simulation, SimulationSettings()
    if path == ("output",):
        return scene.output, OutputSettings(path=Path("fuzz.usdc"))
    if path == ("collider",):
        return scene.colliders, ()
    if path[0] == "simulation":
        return getattr(scene.simulation, path[1]), getattr(SimulationSettings(), path[1])
    if path[0] == "output":
        return getattr(scene.output, path[1]), {"path": Path("fuzz.usdc"), "save_every": 10, "up_axis": "Y",
                                                 "meters_per_unit": 1.0, "kind": "cache",
                                                 "torn_faces": "remove"}[path[1]]
    if path[0] == "cloth":
        spec = scene.cloths[0]
        if len(path) == 4:  # one family left out of the compliance table: that family is rigid
            return spec.compliance.get(path[3]), None
        attribute = path[2]
        defaults = {"name": "cloth0", "origin": (0.0, 0.0, 0.0), "orientation": "vertical", "mass": 1.0,
                    "pins": (), "tear_threshold": None, "particle_masses": (), "sticks": ("structural",),
                    "compliance": {}, "tethers": None, "tether_scale": 1.0}
        return getattr(spec, attribute), defaults[attribute]
    collider = scene.colliders[path[1]]
    if path[2] == "centre":
        return collider.keyframes, ((0.0, (0.0, 0.0, 0.0)),)
    defaults = {"name": f"{'plane' if path[1] == 0 else 'sphere'}{path[1]}", "thickness": 0.0, "friction_coefficient": 0.0,
                "normal": (0.0, 1.0, 0.0), "point": (0.0, 0.0, 0.0), "display_size": 10.0, "purpose": "guide"}
    return getattr(collider, path[2]), defaults[path[2]]


def drop(doc, path: tuple) -> bool:
    table = doc
    for p in path[:-1]:
        if isinstance(table, dict) and p not in table or isinstance(table, list) and p >= len(table):
            return False
        table = table[p]
    if path[-1] in table:
        del table[path[-1]]
        return True
    return False


@FUZZ
@given(dropped=st.lists(st.sampled_from(OPTIONAL + sorted(REQUIRED)), max_size=6, unique=True))
def test_missing_sections_and_keys(tmp_path, dropped):
    doc = full_scene()
    gone = [p for p in dropped if drop(doc, p)]  # keys inside a dropped section are gone with it
    # What the loader must report first, in its reading order: the cloth array, then a cloth's required
    # keys, then a cloth's keys that no longer agree (tethers without pins; a compliance for a family that the
    # default sticks, structural only, do not build), then a collider's required keys.
    cloth_required = [p for p in gone if p in REQUIRED and p[0] == "cloth"]
    cloth = ("cloth",) not in gone and not cloth_required
    tethers_without_pins = cloth and ("cloth", 0, "pins") in gone and ("cloth", 0, "tethers") not in gone
    rigid_again = {p[3] for p in gone if len(p) == 4 and p[:3] == ("cloth", 0, "compliance")}
    soft_left = {"structural", "shear", "bend"} - rigid_again
    unbuilt = sorted(soft_left - {"structural"}) if (
        cloth and ("cloth", 0, "sticks") in gone and ("cloth", 0, "compliance") not in gone) else []
    collider_required = [p for p in gone if p in REQUIRED and p[0] == "collider" and ("collider",) not in gone]
    if not cloth:
        err = scene_error(tmp_path, doc)
        assert "is required but missing" in err.problem, str(err)
        expected = [("cloth",)] if ("cloth",) in gone else cloth_required
        assert err.key in {dotted(p) for p in expected}, str(err)
        return
    if tethers_without_pins:
        err = scene_error(tmp_path, doc)
        assert err.key == "cloth[0].tethers" and "expected pins" in err.problem, str(err)
        return
    if unbuilt:
        err = scene_error(tmp_path, doc)
        assert err.key == f"cloth[0].compliance.{unbuilt[0]}" and "does not build" in err.problem, str(err)
        return
    if collider_required:
        err = scene_error(tmp_path, doc)
        assert "is required but missing" in err.problem, str(err)
        assert err.key in {dotted(p) for p in collider_required}, str(err)
        return
    scene = load_doc(tmp_path, doc)
    for p in gone:
        if p[0] == "collider" and ("collider",) in gone and p != ("collider",):
            continue
        if p[:3] == ("cloth", 0, "compliance") and len(p) == 4 and ("cloth", 0, "compliance") in gone:
            continue
        loaded, default = default_of(scene, p)
        assert loaded == default, (p, loaded, default)


# ---------------------------------------------------------------------------------------------- truncation


@pytest.mark.slow
@pytest.mark.parametrize("scene_file", sorted(SCENES.glob("*.toml")), ids=lambda p: p.name)
def test_shipped_scene_truncated_at_every_byte(tmp_path, scene_file):
    (tmp_path / "assets").symlink_to(SCENES / "assets")  # the mesh scenes' files, where their paths lead
    data = scene_file.read_bytes()
    errors = loaded = 0
    for cut in range(len(data) + 1):
        try:
            scene = load_text(tmp_path, data[:cut])
        except SceneError as err:
            assert err.problem and err.file == str(tmp_path / "fuzz.toml")
            errors += 1
        else:
            assert isinstance(scene, Scene) and scene.cloths
            loaded += 1
    assert loaded >= 1 and errors >= 1  # the whole file loads; the empty file does not


# ---------------------------------------------------------------------------------------------- valid scenes load

unit = st.floats(min_value=0.0, max_value=1.0)
positive = st.floats(min_value=1e-6, max_value=1e6)
coordinate = st.floats(min_value=-1e6, max_value=1e6)
vec3 = st.lists(coordinate, min_size=3, max_size=3)
name = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,10}", fullmatch=True)


@st.composite
def valid_scenes(draw) -> dict:
    rows = draw(st.integers(1, 40))
    cols = draw(st.integers(2 if rows == 1 else 1, 40))
    solver = draw(st.sampled_from(["coloured", "jacobi"]))
    sticks = draw(st.lists(st.sampled_from(["structural", "shear", "bend"]), min_size=1, unique=True))
    # Soft sticks need the coloured solver; compliance 0 (rigid) is accepted with either.
    alpha = st.one_of(st.just(0.0), positive) if solver == "coloured" else st.just(0.0)
    compliance = draw(st.dictionaries(st.sampled_from(sticks), alpha))
    cell = st.tuples(st.integers(0, rows - 1), st.integers(0, cols - 1))
    pins = draw(st.lists(st.one_of(st.sampled_from(sorted(NAMED_PINS)), st.integers(0, rows * cols - 1),
                                   cell.map(list)), max_size=4))
    masses = draw(st.dictionaries(cell, positive, max_size=4))
    cloth = {"name": draw(name), "resolution": [rows, cols],
             "size": [draw(positive) if rows > 1 else draw(st.sampled_from([0.0, 1.0])), draw(positive)],
             "origin": draw(vec3), "orientation": draw(st.sampled_from(["vertical", "horizontal"])),
             "mass": draw(positive),
             "sticks": sticks, "compliance": compliance, "pins": pins,
             "particle_masses": [[r, c, kg] for (r, c), kg in masses.items()]}
    if draw(st.booleans()):
        cloth["tear_threshold"] = draw(st.floats(min_value=1.001, max_value=100.0))
    if draw(st.booleans()):
        cloth["tethers"] = draw(st.booleans()) if pins else False  # tethers need pins
        cloth["tether_scale"] = draw(st.floats(1.0, 100.0))
    collider = draw(st.one_of(
        st.fixed_dictionaries({"type": st.just("plane"), "point": vec3, "thickness": st.floats(0.0, 1.0),
                               "friction_coefficient": unit, "display_size": positive,
                               "normal": vec3.filter(lambda v: math.sqrt(sum(x * x for x in v)) > 1e-3)}),
        st.fixed_dictionaries({"type": st.just("sphere"), "radius": positive, "centre": vec3, "friction_coefficient": unit}),
    ))
    return {
        "simulation": {"fps": draw(positive), "frames": draw(st.integers(1, 10**6)),
                       "substeps": draw(st.integers(1, 10_000)),
                       "iterations": draw(st.integers(0, 100_000)), "gravity": draw(vec3), "wind": draw(vec3),
                       "damping": draw(st.floats(0.0, 1e6)), "relaxation": solver,
                       "max_dt_ratio": draw(st.floats(1.0, 1e6)), "max_frame_time": draw(positive),
                       "position_bound": draw(positive),
                       "precision": draw(st.sampled_from(["auto", "float32", "float64"]))},
        "output": {"path": draw(st.text(st.characters(codec="utf-8", exclude_characters="\0/"), min_size=1, max_size=8))
                   + draw(st.sampled_from([".usd", ".usdc", ".usda"])), "save_every": draw(st.integers(1, 1000)),
                   "up_axis": draw(st.sampled_from(["Y", "Z"])), "meters_per_unit": draw(positive)},
        "cloth": [cloth],
        "collider": [collider],
    }


@pytest.mark.slow
@FUZZ
@given(doc=valid_scenes())
def test_valid_scenes_load_and_read_back(tmp_path, doc):
    scene = load_doc(tmp_path, doc)
    sim, out, cloth = doc["simulation"], doc["output"], doc["cloth"][0]
    assert scene.simulation == SimulationSettings(**{k: tuple(v) if isinstance(v, list) else float(v) if k in (
        "fps", "damping", "max_dt_ratio", "max_frame_time", "position_bound") else v for k, v in sim.items()})
    assert scene.output == OutputSettings(path=Path(out["path"]), save_every=out["save_every"], up_axis=out["up_axis"],
                                          meters_per_unit=out["meters_per_unit"])
    spec = scene.cloths[0]
    assert isinstance(spec, ClothSpec) and spec.name == cloth["name"]
    assert spec.resolution == tuple(cloth["resolution"]) and spec.size == tuple(cloth["size"])
    assert spec.origin == tuple(cloth["origin"]) and spec.mass == cloth["mass"]
    assert spec.sticks == tuple(f for f in ("structural", "shear", "bend") if f in cloth["sticks"])
    assert spec.compliance == {k: v for k, v in cloth["compliance"].items() if v > 0}
    assert spec.tethers == cloth.get("tethers") and spec.tether_scale == cloth.get("tether_scale", 1.0)
    assert spec.tear_threshold == cloth.get("tear_threshold")
    assert sorted(spec.particle_masses) == sorted(tuple(m) for m in cloth["particle_masses"])
    rows, cols = cloth["resolution"]
    expected_pins = set()
    for pin in cloth["pins"]:
        if isinstance(pin, str):
            expected_pins.update(NAMED_PINS[pin](rows, cols))
        elif isinstance(pin, int):
            expected_pins.add(divmod(pin, cols))
        else:
            expected_pins.add(tuple(pin))
    assert spec.pins == tuple(sorted(expected_pins))
    (collider,) = scene.colliders
    given_collider = doc["collider"][0]
    if given_collider["type"] == "plane":
        assert isinstance(collider, PlaneCollider) and collider.point == tuple(given_collider["point"])
        assert math.isclose(sum(v * v for v in collider.normal), 1.0, rel_tol=1e-9)
    else:
        assert isinstance(collider, SphereCollider) and collider.radius == given_collider["radius"]
        assert collider.keyframes == ((0.0, tuple(given_collider["centre"])),)


# ---------------------------------------------------------------------------------------------- float32 and names

FLOAT32_MAX = 3.4028234663852886e38
beyond_float32 = st.floats(min_value=3.5e38, max_value=1.7e308) | st.floats(min_value=-1.7e308, max_value=-3.5e38)
# Keys whose value goes to the device as float32: a finite float64 beyond float32 must be refused, naming the key.
# (A cloth's total mass does not: only each particle's inverse mass does, tested in test_stability.py.)
FLOAT32_PATHS = [("simulation", "gravity", 1), ("simulation", "wind", 0), ("cloth", 0, "origin", 2),
                 ("cloth", 0, "size", 1), ("cloth", 0, "compliance", "bend"), ("collider", 0, "point", 1),
                 ("collider", 0, "display_size"), ("collider", 0, "thickness"), ("collider", 1, "radius"),
                 ("collider", 1, "centre", 0), ("cloth", 0, "particle_masses", 0, 2)]
POSITIVE = {"cloth[0].size[1]", "cloth[0].compliance.bend", "collider[0].display_size", "collider[0].thickness",
            "collider[1].radius", "cloth[0].particle_masses[0][2]"}


@pytest.mark.parametrize("path", FLOAT32_PATHS, ids=[dotted(p) for p in FLOAT32_PATHS])
@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(number=beyond_float32)
def test_numbers_beyond_float32_are_refused_naming_the_key(tmp_path, path, number):
    doc = full_scene()
    put(doc, path, abs(number) if dotted(path) in POSITIVE else number)  # a negative one is refused anyway
    err = scene_error(tmp_path, doc)
    assert names_key(err, dotted(path)), err
    assert "float32" in err.problem


@pytest.mark.slow
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(normal=st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=3, max_size=3))
@example(normal=[1e300, 1e300, 0.0])
@example(normal=[1.7e308, -1.7e308, 1.7e308])
@example(normal=[5e-324, 0.0, 0.0])
def test_any_finite_plane_normal_is_refused_as_zero_or_kept_as_its_direction(tmp_path, normal):
    doc = full_scene()
    put(doc, ("collider", 0, "normal"), normal)
    if not any(normal):
        assert names_key(scene_error(tmp_path, doc), "collider[0].normal")
        return
    unit = load_doc(tmp_path, doc).colliders[0].normal
    assert math.isclose(math.hypot(*unit), 1.0, rel_tol=1e-12)
    big = max(range(3), key=lambda k: abs(normal[k]))  # the largest component keeps its sign and its share
    assert unit[big] * normal[big] > 0 and abs(unit[big]) >= 1 / math.sqrt(3) - 1e-12
    for k in range(3):
        assert (unit[k] == 0.0) == (normal[k] == 0.0) or abs(normal[k] / normal[big]) < 1e-300


@FUZZ
@given(name=name, clash=st.sampled_from(["Colliders", "collider"]), colliders=st.booleans())
def test_a_cloth_may_not_take_a_reserved_or_a_collider_prim_name(tmp_path, name, clash, colliders):
    doc = full_scene()
    if not colliders:
        del doc["collider"]
    taken = "Colliders" if clash == "Colliders" or not colliders else doc["collider"][1]["name"]
    doc["cloth"].append(dict(doc["cloth"][0], name=taken))
    err = scene_error(tmp_path, doc)
    assert err.key == "cloth[1].name" and repr(taken) in err.problem
    doc["cloth"][1]["name"] = name if name not in ("Colliders", "sheet", "ground", "ball") else "other"
    assert len(load_doc(tmp_path, doc).cloths) == 2
