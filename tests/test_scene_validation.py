"""Scene validation: every class of bad input gives one SceneError naming the file, the dotted key and
what was expected; good input (the shipped scenes, defaults) loads; and no input of any kind makes
``load_scene`` raise anything but SceneError (a hypothesis fuzz test)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warp_verlet.errors import SceneError
from warp_verlet.input.scene import (CLOTH_KEYS, GRID_KEYS, NAMED_PINS, OUTPUT_KEYS, SIMULATION_KEYS, STICK_FAMILIES,
                                     ClothSpec, OutputSettings, Scene, SimulationSettings, load_scene)
from warp_verlet.geometry.topology import build_cloth

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCENES = Path(__file__).resolve().parent.parent / "scenes"

# The smallest valid scene: a 4 x 5 grid (20 particles, flat indices 0 .. 19).
CLOTH = """
[[cloth]]
resolution = [4, 5]
size = [0.3, 0.4]
"""


def write(tmp_path: Path, text: str | bytes, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


def scene_error(path: Path) -> SceneError:
    with pytest.raises(SceneError) as info:
        load_scene(path)
    return info.value


def assert_names(err: SceneError, path: Path, key: str | None, *expected: str) -> None:
    """The message names the file, then the exact dotted key, then contains every ``expected`` fragment."""
    message = str(err)
    assert err.file == str(path)
    assert err.key == key, message
    prefix = f"{path}: {key}: " if key else f"{path}: "
    assert message.startswith(prefix), message
    for fragment in expected:
        assert fragment in err.problem, message


def check(tmp_path: Path, text: str, key: str | None, *expected: str) -> SceneError:
    path = write(tmp_path, text)
    err = scene_error(path)
    assert_names(err, path, key, *expected)
    return err


# ---------------------------------------------------------------------------------------------- unknown keys


@pytest.mark.parametrize(
    "text, key",
    [
        ("colour = 1\n" + CLOTH, "colour"),
        ("[simulation]\nfsp = 60\n" + CLOTH, "simulation.fsp"),
        ("[output]\npth = 'a.usdc'\n" + CLOTH, "output.pth"),
        (CLOTH + "mas = 1.0\n", "cloth[0].mas"),
        (CLOTH + "[[cloth]]\nname = 'b'\nresolution = [2, 2]\nsize = [1, 1]\npinz = [0]\n", "cloth[1].pinz"),
        ("\"ключ\" = 1\n" + CLOTH, "ключ"),
    ],
    ids=["top-level", "simulation", "output", "cloth", "second-cloth", "unicode"],
)
def test_unknown_key(tmp_path, text, key):
    err = check(tmp_path, text, key, "unknown key", "known keys here:")
    if key.startswith("simulation"):
        assert "fps" in err.problem  # lists what would have been accepted
    if key.startswith("cloth"):
        assert "resolution" in err.problem


def test_unknown_stick_family(tmp_path):
    check(tmp_path, CLOTH + "sticks = ['structural', 'sheer']\n", "cloth[0].sticks[1]",
          "unknown stick family 'sheer'", "structural, shear, bend")
    check(tmp_path, CLOTH + "compliance = { sheer = 0.5 }\n", "cloth[0].compliance.sheer",
          "unknown stick family", "structural, shear, bend")


# ---------------------------------------------------------------------------------------------- keys that moved


def test_drag_is_refused_with_the_equivalent_damping(tmp_path):
    # drag d kept d of the velocity per substep; damping c keeps exp(-c dt) per substep of dt = 1 / (fps substeps):
    # c = -ln(d) fps substeps = -ln(0.995) x 60 x 8 = 2.406 per second.
    err = check(tmp_path, "[simulation]\nfps = 60\nsubsteps = 8\ndrag = 0.995\n" + CLOTH, "simulation.drag",
                "replaced by damping", "damping = 2.406", "0.995", "60 fps", "8 substeps")
    assert f"{-math.log(0.995) * 60 * 8:.4g}" == "2.406"
    assert str(err).count("simulation.drag") == 1  # one error, naming the key once
    # With the defaults (60 fps, 4 substeps), and for a value with no equivalent, the formula instead.
    check(tmp_path, "[simulation]\ndrag = 0.999\n" + CLOTH, "simulation.drag",
          f"damping = {-math.log(0.999) * 240:.4g}")
    check(tmp_path, "[simulation]\ndrag = false\n" + CLOTH, "simulation.drag", "damping = -ln(drag) x fps x substeps")
    check(tmp_path, "[simulation]\ndrag = 1.5\n" + CLOTH, "simulation.drag", "damping = -ln(drag) x fps x substeps")


def test_the_old_solver_key_names_relaxation(tmp_path):
    # "solver" named both the scheme and the stepping object; the scheme's key is relaxation now.
    err = check(tmp_path, "[simulation]\nsolver = 'jacobi'\n" + CLOTH, "simulation.solver", "renamed relaxation",
                'relaxation = "coloured"', '"jacobi"')
    assert str(err).count("simulation.solver") == 1


def test_drag_of_one_suggests_no_damping(tmp_path):
    # drag = 1 kept all the velocity: the equivalent is damping = 0, written as a user would write it (not "-0",
    # the sign of -ln(1.0) x fps x substeps = -0.0).
    err = check(tmp_path, "[simulation]\ndrag = 1.0\n" + CLOTH, "simulation.drag", "replaced by damping")
    assert "damping = 0 " in err.problem and "damping = -0" not in err.problem, (
        f"the suggestion for drag = 1 should read damping = 0: {err.problem}")


def test_the_stiffness_table_is_refused_saying_what_to_write(tmp_path):
    err = check(tmp_path, CLOTH + "sticks = { structural = 1.0, shear = 1.0, bend = 0.3 }\n", "cloth[0].sticks",
                "the table form { family = stiffness } is gone", 'sticks = ["structural", "shear", "bend"]',
                "compliance", "bend = ")
    assert "structural = 1e-3" not in err.problem and "shear = 1e-3" not in err.problem  # only soft families
    # All rigid: no compliance to suggest.
    err = check(tmp_path, CLOTH + "sticks = { structural = 1.0 }\n", "cloth[0].sticks", 'sticks = ["structural"]')
    assert "compliance" not in err.problem


def test_compliance_needs_its_family_built(tmp_path):
    check(tmp_path, CLOTH + "sticks = ['structural', 'shear']\ncompliance = { bend = 0.5 }\n",
          "cloth[0].compliance.bend", "bend family", 'sticks = ["structural", "shear"]', "does not build")
    # The default sticks are structural only.
    check(tmp_path, CLOTH + "compliance = { shear = 0.5 }\n", "cloth[0].compliance.shear", "does not build")


def test_compliance_needs_the_coloured_solver(tmp_path):
    check(tmp_path, "[simulation]\nrelaxation = 'jacobi'\n" + CLOTH + "compliance = { structural = 1e-3 }\n",
          "cloth[0].compliance", "coloured solver")
    # Rigid (compliance 0) is fine with Jacobi: it is the default.
    scene = load_scene(write(tmp_path, "[simulation]\nrelaxation = 'jacobi'\n" + CLOTH
                             + "compliance = { structural = 0 }\n"))
    assert scene.cloths[0].compliance == {} and not scene.compliant


# ---------------------------------------------------------------------------------------------- wrong types


@pytest.mark.parametrize(
    "text, key, expected",
    [
        # a string where a number is expected
        ("[simulation]\nfps = '60'\n" + CLOTH, "simulation.fps", ["expected a number", "str '60'"]),
        (CLOTH + "mass = 'heavy'\n", "cloth[0].mass", ["expected a number", "str 'heavy'"]),
        # a boolean where an integer (or a number) is expected
        ("[simulation]\nframes = true\n" + CLOTH, "simulation.frames", ["expected an integer", "boolean true"]),
        ("[simulation]\ndamping = false\n" + CLOTH, "simulation.damping", ["expected a number", "boolean false"]),
        ("[[cloth]]\nresolution = [true, 5]\nsize = [1, 1]\n", "cloth[0].resolution[0]",
         ["expected an integer", "boolean true"]),
        # a float where an integer is expected, even a whole one
        ("[simulation]\nsubsteps = 4.0\n" + CLOTH, "simulation.substeps", ["expected an integer", "float 4.0"]),
        ("[[cloth]]\nresolution = [4, 5.5]\nsize = [1, 1]\n", "cloth[0].resolution[1]",
         ["expected an integer", "float 5.5"]),
        ("[output]\nsave_every = 2.5\n" + CLOTH, "output.save_every", ["expected an integer", "float 2.5"]),
        # vectors: wrong element, wrong length, not an array
        ("[simulation]\ngravity = [0, 'down', 0]\n" + CLOTH, "simulation.gravity[1]", ["expected a number"]),
        ("[simulation]\nwind = [1.0, 2.0]\n" + CLOTH, "simulation.wind", ["expected an array of 3 numbers",
                                                                           "an array of 2"]),
        (CLOTH + "origin = 1.0\n", "cloth[0].origin", ["expected an array of 3 numbers", "float 1.0"]),
        # strings and choices
        ("[simulation]\nrelaxation = 'gauss'\n" + CLOTH, "simulation.relaxation", ["'coloured', 'jacobi'", "'gauss'"]),
        ("[output]\nup_axis = 'X'\n" + CLOTH, "output.up_axis", ["'Y', 'Z'"]),
        (CLOTH + "orientation = 'diagonal'\n", "cloth[0].orientation", ["'vertical', 'horizontal'"]),
        (CLOTH + "name = 5\n", "cloth[0].name", ["expected a non-empty string", "int 5"]),
        (CLOTH + "name = '1st'\n", "cloth[0].name", ["letters, digits and '_'"]),
        (CLOTH + "name = \"sheet\\n\"\n", "cloth[0].name", ["letters, digits and '_'"]),
        (CLOTH + "name = 'my cloth'\n", "cloth[0].name", ["letters, digits and '_'"]),
        # tables where tables belong
        ("simulation = 5\n" + CLOTH, "simulation", ["expected a table", "int 5"]),
        ("output = 'out.usdc'\n" + CLOTH, "output", ["expected a table"]),
        (CLOTH + "sticks = 1.0\n", "cloth[0].sticks", ["expected a non-empty array of stick families", "float 1.0"]),
        (CLOTH + "sticks = 'structural'\n", "cloth[0].sticks", ["expected a non-empty array", "str 'structural'"]),
        (CLOTH + "sticks = ['structural', 1]\n", "cloth[0].sticks[1]", ["unknown stick family 1"]),
        (CLOTH + "compliance = 0.5\n", "cloth[0].compliance", ["expected a table", "float 0.5"]),
        (CLOTH + "compliance = ['structural']\n", "cloth[0].compliance", ["expected a table", "an array of 1"]),
        ("cloth = [1]\n", "cloth[0]", ["expected a table", "int 1"]),
        ("[cloth]\nresolution = [2, 2]\nsize = [1, 1]\n", "cloth", ["one or more [[cloth]] tables"]),
        # pins of the wrong kind
        (CLOTH + "pins = 'top-left'\n", "cloth[0].pins", ["expected an array"]),
        (CLOTH + "pins = [1.0]\n", "cloth[0].pins[0]", ["a pin name, a particle index or a [row, col] pair",
                                                        "float 1.0"]),
        (CLOTH + "pins = [0, true]\n", "cloth[0].pins[1]", ["boolean true"]),
        (CLOTH + "pins = [[1, 2, 3]]\n", "cloth[0].pins[0]", ["[row, col] pair", "an array of 3"]),
        (CLOTH + "pins = [[1, 2.0]]\n", "cloth[0].pins[0]", ["[row, col] pair"]),
        (CLOTH + "sticks = ['shear']\ncompliance = { shear = '0.5' }\n", "cloth[0].compliance.shear",
         ["expected a number", "str '0.5'"]),
        (CLOTH + "compliance = { structural = true }\n", "cloth[0].compliance.structural", ["boolean true"]),
        (CLOTH + "tear_threshold = true\n", "cloth[0].tear_threshold", ["expected a number"]),
        (CLOTH + "particle_masses = [0, 0, 1.0]\n", "cloth[0].particle_masses[0]", ["[row, col, kg]"]),
        (CLOTH + "particle_masses = [[0, 0]]\n", "cloth[0].particle_masses[0]", ["[row, col, kg]"]),
        (CLOTH + "particle_masses = [[0.0, 0, 1.0]]\n", "cloth[0].particle_masses[0][0]", ["integer"]),
        (CLOTH + "particle_masses = 5\n", "cloth[0].particle_masses", ["array"]),
    ],
)
def test_wrong_type(tmp_path, text, key, expected):
    check(tmp_path, text, key, *expected)


# ---------------------------------------------------------------------------------------------- out of range


@pytest.mark.parametrize(
    "text, key, expected",
    [
        (CLOTH + "mass = 0.0\n", "cloth[0].mass", ["(0.0, inf)", "got 0.0"]),
        (CLOTH + "mass = -1\n", "cloth[0].mass", ["(0.0, inf)", "got -1"]),
        ("[[cloth]]\nresolution = [0, 5]\nsize = [1, 1]\n", "cloth[0].resolution[0]", ["[1, 32768]", "got 0"]),
        ("[[cloth]]\nresolution = [4, -3]\nsize = [1, 1]\n", "cloth[0].resolution[1]", ["[1, 32768]", "got -3"]),
        ("[[cloth]]\nresolution = [4, 40000]\nsize = [1, 1]\n", "cloth[0].resolution[1]", ["[1, 32768]"]),
        ("[[cloth]]\nresolution = [1, 1]\nsize = [0, 0]\n", "cloth[0].resolution", ["at least 2 particles"]),
        (CLOTH + "sticks = ['shear']\ncompliance = { shear = -0.1 }\n", "cloth[0].compliance.shear",
         ["[0.0, inf)", "got -0.1"]),
        (CLOTH + "sticks = ['structural', 'bend']\ncompliance = { bend = -1e-9 }\n", "cloth[0].compliance.bend",
         ["[0.0, inf)", "got -1e-09"]),
        (CLOTH + "compliance = { structural = nan }\n", "cloth[0].compliance.structural", ["finite"]),
        (CLOTH + "compliance = { structural = inf }\n", "cloth[0].compliance.structural", ["finite"]),
        (CLOTH + "sticks = []\n", "cloth[0].sticks", ["expected a non-empty array", "an array of 0"]),
        (CLOTH + "sticks = ['shear', 'bend', 'shear']\n", "cloth[0].sticks", ["listed twice"]),
        (CLOTH + "tear_threshold = 1.0\n", "cloth[0].tear_threshold", ["(1.0, inf)", "got 1.0"]),
        (CLOTH + "tear_threshold = 0.5\n", "cloth[0].tear_threshold", ["(1.0, inf)", "got 0.5"]),
        (CLOTH + "tear_threshold = inf\n", "cloth[0].tear_threshold", ["finite"]),
        (CLOTH + "particle_masses = [[0, 0, 0.0]]\n", "cloth[0].particle_masses[0][2]", ["(0.0, inf)", "got 0.0"]),
        (CLOTH + "particle_masses = [[0, 9, 1.0]]\n", "cloth[0].particle_masses[0][1]", ["[0, 4]", "got 9"]),
        (CLOTH + "particle_masses = [[-1, 0, 1.0]]\n", "cloth[0].particle_masses[0][0]", ["got -1"]),
        (CLOTH + "particle_masses = [[1, 1, 2.0], [1, 1, 3.0]]\n", "cloth[0].particle_masses[1]", ["twice"]),
        ("[simulation]\nfps = 0\n" + CLOTH, "simulation.fps", ["(0.0, inf)", "got 0.0"]),
        ("[simulation]\nfps = -60.0\n" + CLOTH, "simulation.fps", ["(0.0, inf)", "got -60.0"]),
        ("[simulation]\nfps = nan\n" + CLOTH, "simulation.fps", ["expected a finite number", "nan"]),
        ("[simulation]\nfps = inf\n" + CLOTH, "simulation.fps", ["expected a finite number", "inf"]),
        ("[simulation]\nfps = -inf\n" + CLOTH, "simulation.fps", ["expected a finite number", "-inf"]),
        ("[simulation]\ngravity = [0.0, -inf, 0.0]\n" + CLOTH, "simulation.gravity[1]", ["finite"]),
        (CLOTH + "origin = [nan, 0, 0]\n", "cloth[0].origin[0]", ["finite"]),
        ("[simulation]\nframes = nan\n" + CLOTH, "simulation.frames", ["expected an integer", "float nan"]),
        ("[simulation]\nframes = 0\n" + CLOTH, "simulation.frames", [">= 1", "got 0"]),
        ("[simulation]\nsubsteps = 10001\n" + CLOTH, "simulation.substeps", ["[1, 10000]"]),
        ("[simulation]\niterations = -1\n" + CLOTH, "simulation.iterations", ["[0, 100000]"]),
        ("[simulation]\ndamping = -0.01\n" + CLOTH, "simulation.damping", ["[0.0, inf)", "got -0.01"]),
        ("[simulation]\ndamping = inf\n" + CLOTH, "simulation.damping", ["finite"]),
        ("[simulation]\nmax_dt_ratio = 0.5\n" + CLOTH, "simulation.max_dt_ratio", ["[1.0, inf)"]),
        ("[simulation]\nmax_frame_time = 0\n" + CLOTH, "simulation.max_frame_time", ["(0.0, inf)"]),
        ("[simulation]\nposition_bound = -1\n" + CLOTH, "simulation.position_bound", ["(0.0, inf)"]),
        ("[output]\nsave_every = 0\n" + CLOTH, "output.save_every", [">= 1"]),
        ("[output]\nmeters_per_unit = 0\n" + CLOTH, "output.meters_per_unit", ["(0.0, inf)"]),
        ("[[cloth]]\nresolution = [4, 5]\nsize = [-0.3, 0.4]\n", "cloth[0].size[0]", ["[0.0, inf)", "got -0.3"]),
    ],
)
def test_out_of_range(tmp_path, text, key, expected):
    check(tmp_path, text, key, *expected)


@pytest.mark.parametrize(
    "resolution, size, key",
    [("[4, 5]", "[0.3, 0.0]", "cloth[0].size[1]"), ("[4, 5]", "[0, 0.4]", "cloth[0].size[0]"),
     ("[2, 1]", "[0.0, 0.0]", "cloth[0].size[0]")],
)
def test_zero_size_on_an_axis_with_more_than_one_particle(tmp_path, resolution, size, key):
    check(tmp_path, f"[[cloth]]\nresolution = {resolution}\nsize = {size}\n", key, "expected a length > 0 m")


def test_zero_size_on_an_axis_with_one_particle_is_fine(tmp_path):
    scene = load_scene(write(tmp_path, "[[cloth]]\nresolution = [1, 10]\nsize = [0.0, 1.0]\n"))
    assert scene.cloths[0].size == (0.0, 1.0)


def test_huge_integers_are_reported_not_crashed_on(tmp_path):
    # TOML hex literals have no length limit; the message summarises instead of printing 2400 digits.
    huge = "0x" + "f" * 2000
    check(tmp_path, f"[simulation]\nsubsteps = {huge}\n" + CLOTH, "simulation.substeps",
          "[1, 10000]", "an integer of 8000 bits")
    check(tmp_path, f"[simulation]\nfps = {huge}\n" + CLOTH, "simulation.fps", "expected a finite number")
    check(tmp_path, f"[simulation]\ngravity = [0, {'9' * 400}, 0]\n" + CLOTH, "simulation.gravity[1]",
          "expected a finite number")
    check(tmp_path, CLOTH + f"pins = [{huge}]\n", "cloth[0].pins[0]", "outside the grid")
    check(tmp_path, CLOTH + f"pins = [[0, -{'9' * 1000}]]\n", "cloth[0].pins[0]", "outside the 4 x 5 grid")


# ---------------------------------------------------------------------------------------------- pins


@pytest.mark.parametrize(
    "pins, key, expected",
    [
        ("[20]", "cloth[0].pins[0]", ["particle index 20", "outside the grid (0 .. 19)"]),
        ("[-1]", "cloth[0].pins[0]", ["particle index -1", "outside the grid"]),
        ("['top-left', 99]", "cloth[0].pins[1]", ["particle index 99"]),
        ("[[4, 0]]", "cloth[0].pins[0]", ["[row, col] = [4, 0]", "outside the 4 x 5 grid"]),
        ("[[0, 5]]", "cloth[0].pins[0]", ["[row, col] = [0, 5]"]),
        ("[[0, 0], [-1, 2]]", "cloth[0].pins[1]", ["[row, col] = [-1, 2]"]),
        ("['top-left', 'top-middle']", "cloth[0].pins[1]", ["unknown pin name 'top-middle'", "top-right"]),
    ],
)
def test_pin_outside_the_grid(tmp_path, pins, key, expected):
    check(tmp_path, CLOTH + f"pins = {pins}\n", key, *expected)


def test_pin_forms_agree(tmp_path):
    scene = load_scene(write(tmp_path, CLOTH + "pins = ['top-right', 4, [0, 4], 'bottom-edge', [3, 0]]\n"))
    # (0, 4) three times over, merged; the bottom row; sorted
    assert scene.cloths[0].pins == ((0, 4), (3, 0), (3, 1), (3, 2), (3, 3), (3, 4))


# ---------------------------------------------------------------------------------------------- whole-file problems


def test_missing_cloth(tmp_path):
    check(tmp_path, "[simulation]\nfps = 60\n", "cloth", "required but missing")


def test_empty_cloth_array(tmp_path):
    check(tmp_path, "cloth = []\n", "cloth", "one or more [[cloth]] tables")


def test_missing_required_cloth_key(tmp_path):
    check(tmp_path, "[[cloth]]\nsize = [1, 1]\n", "cloth[0].resolution", "required but missing")
    check(tmp_path, "[[cloth]]\nresolution = [2, 2]\n", "cloth[0].size", "required but missing")


def test_malformed_toml(tmp_path):
    check(tmp_path, "[simulation\nfps = 60\n", None, "not valid TOML")
    check(tmp_path, CLOTH + "mass = \n", None, "not valid TOML")
    check(tmp_path, "[simulation]\nfps = 60\nfps = 30\n" + CLOTH, None, "not valid TOML")  # duplicate key


def test_toml_that_tomllib_itself_chokes_on(tmp_path):
    # int() refuses > 4300 decimal digits with a bare ValueError; deep nesting overflows the recursion
    check(tmp_path, "[simulation]\nframes = " + "9" * 5000 + "\n" + CLOTH, None, "not valid TOML")
    check(tmp_path, "x = " + "[" * 5000 + "]" * 5000 + "\n" + CLOTH, None, "not valid TOML", "nested too deeply")


def test_non_utf8_bytes(tmp_path):
    path = write(tmp_path, b"[[cloth]]\nname = \"caf\xe9\"\nresolution = [2, 2]\nsize = [1, 1]\n")
    assert_names(scene_error(path), path, None, "expected UTF-8 text", "at byte 21")


def test_missing_file(tmp_path):
    path = tmp_path / "no_such_scene.toml"
    assert_names(scene_error(path), path, None, "cannot read the file")


def test_unreadable_file(tmp_path):
    # A directory cannot be read as a file on every platform, root or not (unlike chmod 000).
    path = tmp_path / "a_directory.toml"
    path.mkdir()
    assert_names(scene_error(path), path, None, "cannot read the file")


def test_path_with_nul_character(tmp_path):
    path = tmp_path / "bad\0name.toml"
    assert_names(scene_error(path), path, None, "cannot read the file")


def test_duplicate_cloth_names(tmp_path):
    two = "[[cloth]]\nname = 'sheet'\nresolution = [2, 2]\nsize = [1, 1]\n"
    check(tmp_path, two + two, "cloth[1].name", "expected a unique name", "'sheet' is used twice")


def test_duplicate_default_cloth_name(tmp_path):
    # The default name of cloth[1] is "cloth1": taking it explicitly for cloth[0] is a clash too.
    text = "[[cloth]]\nname = 'cloth1'\nresolution = [2, 2]\nsize = [1, 1]\n" + CLOTH
    check(tmp_path, text, "cloth[1].name", "'cloth1' is used twice")


@pytest.mark.parametrize("bad", ["out.abc", "out", "out.USDC", "out.usdz", ".usdc", "dir.usdc/out"])
def test_bad_output_extension(tmp_path, bad):
    check(tmp_path, f"[output]\npath = '{bad}'\n" + CLOTH, "output.path", ".usd, .usda, .usdc", repr(bad))


def test_bad_output_path(tmp_path):
    check(tmp_path, "[output]\npath = ''\n" + CLOTH, "output.path", "expected a non-empty string")
    check(tmp_path, "[output]\npath = 3\n" + CLOTH, "output.path", "expected a non-empty string")
    check(tmp_path, "[output]\npath = \"a\\u0000.usdc\"\n" + CLOTH, "output.path", "without NUL characters")


# ---------------------------------------------------------------------------------------------- good input


def test_every_shipped_scene_loads():
    files = sorted(SCENES.glob("*.toml"))
    names = {f.name for f in files}
    assert {"hanging_cloth.toml", "wind_sheet.toml", "rope.toml", "big_grid_1024.toml"} <= names
    for f in files:
        text = f.read_text(encoding="utf-8")
        assert text.startswith("#"), f"{f.name} should open with a comment saying what it shows"
        scene = load_scene(f)
        assert isinstance(scene, Scene) and scene.cloths
        assert scene.output.path == Path(f.stem + (".usda" if scene.output.kind == "override" else ".usdc"))


def test_shipped_scenes_say_what_the_brief_says():
    hanging = load_scene(SCENES / "hanging_cloth.toml")
    sim, cloth = hanging.simulation, hanging.cloths[0]
    assert (sim.fps, sim.frames, sim.substeps, sim.iterations, sim.damping) == (60.0, 120, 4, 8, 0.24)
    assert cloth.resolution == (64, 64) and cloth.size == (1.0, 1.0) and cloth.orientation == "vertical"
    assert cloth.pins == ((0, 0), (0, 63))
    assert cloth.sticks == ("structural", "shear", "bend") and cloth.compliance == {"bend": 0.7}

    wind = load_scene(SCENES / "wind_sheet.toml")
    assert wind.simulation.wind == (4.0, 0.0, 3.0)
    assert wind.cloths[0].resolution == (48, 64)
    assert wind.cloths[0].pins == tuple((r, 0) for r in range(48))

    rope = load_scene(SCENES / "rope.toml")
    spec = rope.cloths[0]
    assert spec.resolution == (1, 40) and spec.size == (0.0, 2.0) and spec.orientation == "horizontal"
    assert spec.pins == ((0, 0),) and spec.sticks == ("structural",) and spec.compliance == {}
    topo = build_cloth(spec)
    assert len(topo.sticks) == 39 and len(topo.faces) == 0

    big = load_scene(SCENES / "big_grid_1024.toml")
    assert big.cloths[0].resolution == (1024, 1024) and big.particle_count == 1 << 20
    assert big.cloths[0].sticks == ("structural", "shear", "bend")
    assert (big.simulation.frames, big.simulation.substeps, big.simulation.iterations) == (60, 32, 1)


def test_defaults_apply_when_sections_are_missing(tmp_path):
    scene = load_scene(write(tmp_path, CLOTH, name="minimal.toml"))
    assert scene.source == str(tmp_path / "minimal.toml")
    assert scene.simulation == SimulationSettings()
    assert scene.output == OutputSettings(path=Path("minimal.usdc"))  # relative: resolved against the cwd
    assert scene.cloths == (ClothSpec(name="cloth0", resolution=(4, 5), size=(0.3, 0.4)),)
    c = scene.cloths[0]
    assert (c.origin, c.orientation, c.mass, c.sticks, c.compliance, c.pins) == (
        (0.0, 0.0, 0.0), "vertical", 1.0, ("structural",), {}, ())
    assert scene.simulation.damping == 0.0 and not scene.compliant
    assert math.isclose(scene.simulation.dt, 1.0 / 240.0)


def test_defaults_apply_to_empty_sections(tmp_path):
    scene = load_scene(write(tmp_path, "[simulation]\n[output]\n" + CLOTH, name="empty.toml"))
    assert scene.simulation == SimulationSettings()
    assert scene.output == OutputSettings(path=Path("empty.usdc"))


def test_integers_are_accepted_for_numbers(tmp_path):
    scene = load_scene(write(tmp_path, "[simulation]\nfps = 30\ndamping = 1\n" + CLOTH
                             + "compliance = { structural = 2 }\n"))
    assert scene.simulation.fps == 30.0 and isinstance(scene.simulation.fps, float)
    assert scene.simulation.damping == 1.0 and isinstance(scene.simulation.damping, float)
    compliance = scene.cloths[0].compliance
    assert compliance == {"structural": 2.0} and isinstance(compliance["structural"], float)


def test_only_the_listed_families_are_built(tmp_path):
    scene = load_scene(write(tmp_path, CLOTH + "sticks = ['structural']\n"))
    spec = scene.cloths[0]
    assert spec.sticks == ("structural",)
    topo = build_cloth(spec)
    assert topo.families == ("structural",)
    assert len(topo.sticks) == 4 * 4 + 3 * 5  # horizontal + vertical structural sticks of a 4 x 5 grid


def test_compliance_zero_means_rigid(tmp_path):
    # Compliance 0 is the rigid default: dropped on loading, so the scene has no soft stick at all.
    spec = load_scene(write(tmp_path, CLOTH + "sticks = ['structural', 'shear']\n"
                                               "compliance = { structural = 0.0, shear = 0 }\n")).cloths[0]
    assert spec.sticks == ("structural", "shear") and spec.compliance == {}
    assert not build_cloth(spec).compliance.any()
    # A soft family gets its compliance on each of its sticks; the rest stay rigid.
    spec = load_scene(write(tmp_path, CLOTH + "sticks = ['structural', 'shear']\n"
                                               "compliance = { shear = 2.5e-3, structural = 0 }\n")).cloths[0]
    assert spec.compliance == {"shear": 2.5e-3}
    topo = build_cloth(spec)
    shear = topo.compliance > 0
    assert shear.sum() == 2 * 3 * 4 and (topo.compliance[shear] == np.float32(2.5e-3)).all()


def test_named_sticks_replace_the_default(tmp_path):
    spec = load_scene(write(tmp_path, CLOTH + "sticks = ['shear']\n")).cloths[0]
    assert spec.sticks == ("shear",)
    # Listed in any order, built in the fixed family order.
    spec = load_scene(write(tmp_path, CLOTH + "sticks = ['bend', 'structural']\n")).cloths[0]
    assert spec.sticks == ("structural", "bend")


def test_documented_example_loads(tmp_path):
    doc = (Path(__file__).resolve().parent.parent / "docs" / "scenes.md").read_text(encoding="utf-8")
    start = doc.index("```toml", doc.index("## A complete example")) + len("```toml")
    example = doc[start:doc.index("```", start)]
    scene = load_scene(write(tmp_path, example, name="two_cloths.toml"))
    assert [c.name for c in scene.cloths] == ["curtain", "tablecloth"]
    assert scene.cloths[1].pins == ((0, 0), (0, 39), (39, 0), (39, 39))


# ---------------------------------------------------------------------------------------------- fuzz


from toml_text import Raw, toml_document  # noqa: E402


def has_raw(v) -> bool:
    if isinstance(v, Raw):
        return True
    if isinstance(v, list):
        return any(has_raw(x) for x in v)
    if isinstance(v, dict):
        return any(has_raw(x) for x in v.values())
    return False


# Key names and strings the fuzz is weighted to: every declared key (and each stick family, compliance's keys),
# the old keys the loader refuses with a message of their own, and every declared choice with a few near misses.
# (A mesh cloth's keys are fuzzed in tests/test_scene_fuzz.py, with a mesh file to read.)
DECLARED_KEYS = SIMULATION_KEYS + OUTPUT_KEYS + CLOTH_KEYS + GRID_KEYS
KNOWN_KEYS = sorted({"simulation", "output", "cloth", "drag", "solver", *STICK_FAMILIES}
                    | {key.name for key in DECLARED_KEYS})
KNOWN_STRINGS = sorted({"out.usdc", "out.usda", "x.usd", ".usdc", "cloth0", "sheet", "", "\0", "1abc", "a\n",
                        *NAMED_PINS, *STICK_FAMILIES}
                       | {option for key in DECLARED_KEYS for option in getattr(key.parse, "options", ())})
RAW_LITERALS = [
    "1979-05-27", "07:32:00", "1979-05-27T07:32:00Z", "1979-05-27T00:32:00.999999-07:00",
    "0o777", "0b1011", "1_000", "9" * 5000, "0x" + "f" * 3000, "[" * 3000 + "]" * 3000, "'''multi\nline'''",
]

keys = st.one_of(st.sampled_from(KNOWN_KEYS), st.text(max_size=12))  # unicode, empty, dots, quotes...
scalars = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.integers(min_value=-3, max_value=40),
    st.integers(min_value=0, max_value=12_000).map(lambda b: 2**b - 1),  # huge
    st.integers(min_value=0, max_value=1100).map(lambda b: -(10**b)),  # huge negative
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 0.5, 1.0, 1.5, -0.1, 1e308, -1e308, 5e-324, 1e-300]),
    st.text(max_size=16),
    st.sampled_from(KNOWN_STRINGS),
    st.sampled_from(RAW_LITERALS).map(Raw),
)
values = st.recursive(
    scalars,
    lambda children: st.lists(children, max_size=4) | st.dictionaries(keys, children, max_size=4),
    max_leaves=12,
)


def valid_scene() -> dict:
    return {
        "simulation": {"fps": 60.0, "frames": 10, "substeps": 2, "iterations": 4},
        "output": {"path": "fuzz.usdc", "save_every": 5},
        "cloth": [{"name": "a", "resolution": [3, 4], "size": [1.0, 1.0], "pins": ["top-left"],
                   "sticks": ["structural", "shear"], "compliance": {"shear": 1e-3}}],
    }


@st.composite
def mutated_scenes(draw) -> dict:
    """A valid scene with random values written over (or added to) its tables."""
    doc = valid_scene()
    tables = [doc, doc["simulation"], doc["output"], doc["cloth"][0], doc["cloth"][0]["compliance"]]
    for _ in range(draw(st.integers(1, 4))):
        table = draw(st.sampled_from(tables))
        key = draw(keys)
        if key in table and draw(st.booleans()):
            del table[key]
        else:
            table[key] = draw(values)
    if isinstance(doc.get("cloth"), list) and draw(st.booleans()):  # "cloth" itself may have been replaced
        doc["cloth"].append(draw(st.dictionaries(keys, values, max_size=6)))
    return doc


VALID_TEXT = (SCENES / "hanging_cloth.toml").read_bytes() if (SCENES / "hanging_cloth.toml").exists() else b""


@st.composite
def broken_bytes(draw) -> bytes:
    """Random bytes, or a valid file truncated and/or with bytes spliced in."""
    if draw(st.booleans()):
        return draw(st.binary(max_size=200))
    data = VALID_TEXT or toml_document(valid_scene()).encode()
    cut = draw(st.integers(0, len(data)))
    insert = draw(st.binary(max_size=8))
    return data[:cut] + insert + data[cut + draw(st.integers(0, 8)):]


fuzz_inputs = st.one_of(
    st.dictionaries(keys, values, max_size=6),  # random documents
    mutated_scenes(),  # nearly valid scenes
    broken_bytes(),  # not TOML at all, or not UTF-8
)


@pytest.mark.slow
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=fuzz_inputs)
def test_fuzz_only_scene_errors(tmp_path, doc):
    if isinstance(doc, bytes):
        data = doc
    else:
        text = toml_document(doc)
        if not has_raw(doc):  # the emitter itself must write valid TOML that reads back the same
            assert toml_document(tomllib.loads(text)) == text
        data = text.encode("utf-8")
    path = tmp_path / "fuzz.toml"
    path.write_bytes(data)
    try:
        scene = load_scene(path)
    except SceneError as err:
        assert str(err).startswith(f"{path}: ")
        assert err.problem
    else:
        assert isinstance(scene, Scene)


# ---------------------------------------------------------------------------------------------- colliders
@pytest.mark.parametrize("collider, key, expected", [
    ('type = "cube"', "collider[0].type", "expected one of 'mesh', 'plane', 'sphere'"),
    ('type = "sphere"\ncentre = [0.0, 0.0, 0.0]', "collider[0].radius", "required"),
    ('type = "sphere"\nradius = 0.0', "collider[0].radius", "(0.0, inf)"),
    ('type = "sphere"\nradius = 1.0\ncentre = [0.0, 0.0, 0.0]\npath = [[0.0, 0.0, 0.0, 0.0]]', "collider[0].path", "not both"),
    ('type = "sphere"\nradius = 1.0\npath = [[0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]]', "collider[0].path[1][0]", "must increase"),
    ('type = "sphere"\nradius = 1.0\npath = [[0.0, 0.0, 0.0]]', "collider[0].path[0]", "array of 4"),
    ('type = "plane"\nnormal = [0.0, 0.0, 0.0]', "collider[0].normal", "non-zero"),
    ('type = "plane"\nfriction = 0.5', "collider[0].friction", "write friction_coefficient"),
    ('type = "plane"\nfriction_coefficient = -0.1', "collider[0].friction_coefficient", "[0.0, inf)"),
    ('type = "plane"\nfriction_coefficient = 0.5\nstatic_friction_coefficient = 0.4',
     "collider[0].static_friction_coefficient", "at least friction_coefficient"),
    ('type = "plane"\nthickness = -0.1', "collider[0].thickness", "[0.0, inf)"),
    ('type = "plane"\nbounce = 0.5', "collider[0].bounce", "unknown key"),
])
def test_bad_collider(tmp_path, collider, key, expected):
    check(tmp_path, CLOTH + "\n[[collider]]\n" + collider + "\n", key, expected)


def test_collider_defaults_and_normalised_normal(tmp_path):
    scene = load_scene(write(tmp_path, CLOTH + '\n[[collider]]\ntype = "plane"\nnormal = [0.0, 2.0, 0.0]\n'
                                        '\n[[collider]]\ntype = "sphere"\nradius = 0.5\n'))
    plane, sphere = scene.colliders
    assert plane.normal == (0.0, 1.0, 0.0) and plane.point == (0.0, 0.0, 0.0) and plane.thickness == 0.0
    assert plane.name == "plane0" and sphere.name == "sphere1"
    assert sphere.keyframes == ((0.0, (0.0, 0.0, 0.0)),) and not sphere.moving
