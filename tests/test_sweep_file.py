"""The sweep file loader: every mistake is one SceneError naming the sweep file, the key (or the axis) and what was
expected, as for scene files; ranges, random draws, names and hashes; and fuzzing like tests/test_scene_fuzz.py
(only SceneError ever escapes, numeric axis values are accepted exactly when the scene accepts them)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sweep_helpers import BASE_SCENE
from test_scene_fuzz import RANGES, assert_number_loaded, extreme_numbers, full_scene, loaded_value, same
from toml_text import dump
from warp_verlet.errors import SceneError
from warp_verlet.apps.sweep import Sweep, load_sweep, parameter_hash

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def write(tmp_path: Path, text: str | bytes, base: str = BASE_SCENE) -> Path:
    (tmp_path / "base.toml").write_text(base)
    path = tmp_path / "sweep.toml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def error(tmp_path: Path, text: str | bytes, base: str = BASE_SCENE) -> SceneError:
    path = write(tmp_path, text, base)
    with pytest.raises(SceneError) as info:
        load_sweep(path)
    assert info.value.file == str(path)
    return info.value


HEAD = '[sweep]\nscene = "base.toml"\n'

CASES = [
    # (sweep text after nothing / HEAD, key, a fragment of the problem)
    ("", "sweep", "is required but missing"),
    ("[sweep]\n[axes]\nx = [1]\n", "sweep.scene", "is required but missing"),
    ('[sweep]\nscene = "base.toml"\nspeed = 1\n[axes]\n"simulation.fps" = [30]\n', "sweep.speed", "unknown key"),
    ('[sweep]\nscene = "missing.toml"\n[axes]\n"simulation.fps" = [30]\n', "sweep.scene", "cannot read the file"),
    ('[sweep]\nscene = 3\n', "sweep.scene", "expected a non-empty string, got int 3"),
    (HEAD + 'frames = 0\n[axes]\n"simulation.fps" = [30]\n', "sweep.frames", "expected an integer >= 1"),
    (HEAD + 'format = "abc"\n[axes]\n"simulation.fps" = [30]\n', "sweep.format", "expected one of 'usdc'"),
    (HEAD, None, "expected [axes] (a grid of values) or [random]"),
    (HEAD + "[axes]\n", "axes", "expected at least one axis"),
    ("axes = 3\n" + HEAD, "axes", "expected a table of axes"),
    (HEAD + '[axes]\n"simulation.fps" = 30\n', "axes.simulation.fps", "expected an array of values or a range"),
    (HEAD + '[axes]\n"simulation.fps" = []\n', "axes.simulation.fps", "expected at least one value"),
    (HEAD + '[axes]\n"simulation..fps" = [1]\n', "axes.simulation..fps", "without empty parts"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 1, stop = 2 }\n', "axes.simulation.fps", "exactly one of step"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 1, stop = 2, step = -1 }\n', "axes.simulation.fps.step",
     "never goes from start 1 to stop 2"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 1, stop = 2, num = 0 }\n', "axes.simulation.fps.num",
     "expected an integer in [1, 100000]"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 1, stop = "2", num = 2 }\n', "axes.simulation.fps.stop",
     "expected a number, got str '2'"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 0, stop = 2, num = 3, spacing = "log" }\n', "axes.simulation.fps",
     "log spacing needs start and stop > 0"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 1, stop = 2, step = 1, spacing = "log" }\n',
     "axes.simulation.fps.spacing", "log spacing takes num"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 1, stop = 1e9, step = 1 }\n', "axes.simulation.fps",
     "expected at most 100000 values"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 1, stop = 3, num = 2, end = 1 }\n', "axes.simulation.fps.end",
     "unknown key in a range"),
    (HEAD + '[axes]\n"simulation.fps" = [30, 0]\n', "axes.simulation.fps",
     "the value 0 gives an invalid scene (variant 1: simulation.fps = 0): simulation.fps: expected a number in (0.0"),
    (HEAD + '[axes]\n"cloth.0.tear_threshold" = [1.5, 0.5]\n', "axes.cloth.0.tear_threshold",
     "cloth[0].tear_threshold: expected a number in (1.0, inf), got 0.5"),
    (HEAD + '[axes]\n"cloth.0.size.1" = [1.0, "a"]\n', "axes.cloth.0.size.1", "cloth[0].size[1]: expected a number"),
    (HEAD + '[axes]\n"cloth.0.sticks" = [["structural"], ["sheer"]]\n', "axes.cloth.0.sticks",
     "unknown stick family 'sheer'"),
    (HEAD + '[axes]\n"simulation.substepz" = [1]\n', "axes.simulation.substepz", "unknown key"),
    (HEAD + '[axes]\n"cloth.3.mass" = [1.0]\n', "axes.cloth.3.mass", "cloth is an array of 1 in the base scene"),
    (HEAD + '[axes]\n"cloth.first.mass" = [1.0]\n', "axes.cloth.first.mass", "expected an index 0 .. 0"),
    (HEAD + '[axes]\n"simulation.frames.x" = [1.0]\n', "axes.simulation.frames.x",
     "simulation.frames is int 3 in the base scene, not a table or an array"),
    (HEAD + '[axes]\n"simulation.wind.2" = [1.0]\n', "axes.simulation.wind.2", "simulation.wind is not in the base scene"),
    (HEAD + '[axes]\n"output.path" = ["a.usdc"]\n', "axes.output.path", "output.path is set by the sweep"),
    (HEAD + 'frames = 3\n[axes]\n"simulation.frames" = [1, 2]\n', "axes.simulation.frames", "already set"),
    (HEAD + '[axes]\n"simulation.fps" = [30]\nsimulation.fps = [40]\n', "axes.simulation.fps",
     "varies the same scene key as axes.simulation.fps"),
    (HEAD + '[axes]\n"simulation.target_stretch" = [0.01]\n', "axes.simulation.target_stretch",
     "substeps chosen by the scene"),
    (HEAD + '[axes]\n"simulation.fps" = { start = 1, stop = 400, step = 1 }\n"cloth.0.mass" = '
     '{ start = 1, stop = 400, step = 1 }\n', None, "the sweep has 160000 variants, more than 100000"),
    (HEAD + "[random]\nsamples = 2\n[random.axes]\n\"simulation.fps\" = { uniform = [1, 2] }\n", "random.seed",
     "is required but missing"),
    (HEAD + "[random]\nseed = 1\nsamples = 0\n[random.axes]\n\"simulation.fps\" = { uniform = [1, 2] }\n",
     "random.samples", "expected an integer in [1, 100000]"),
    (HEAD + "[random]\nseed = 1\nsamples = 2\n", "random.axes", "is required but missing"),
    (HEAD + "[random]\nseed = 1\nsamples = 2\n[random.axes]\n\"simulation.fps\" = [1, 2]\n", "random.axes.simulation.fps",
     "expected a distribution"),
    (HEAD + "[random]\nseed = 1\nsamples = 2\n[random.axes]\n\"simulation.fps\" = { uniform = [2, 1] }\n",
     "random.axes.simulation.fps.uniform", "expected lo <= hi"),
    (HEAD + "[random]\nseed = 1\nsamples = 2\n[random.axes]\n\"simulation.fps\" = { loguniform = [0, 1] }\n",
     "random.axes.simulation.fps.loguniform", "expected 0 < lo <= hi"),
    (HEAD + "[random]\nseed = 1\nsamples = 2\n[random.axes]\n\"simulation.fps\" = { integers = [1.5, 3] }\n",
     "random.axes.simulation.fps.integers", "expected an integer"),
    (HEAD + "[random]\nseed = 1\nsamples = 2\n[random.axes]\n\"simulation.fps\" = { choice = [] }\n",
     "random.axes.simulation.fps.choice", "expected a non-empty array"),
    (HEAD + "[random]\nseed = 1\nsamples = 2\n[random.axes]\n\"simulation.wind\" = { uniform = [[0, 0], [1, 1, 1]] }\n",
     "random.axes.simulation.wind.uniform", "vectors of one length"),
    (HEAD + "[random]\nseed = 1\nsamples = 2\nextra = 1\n[random.axes]\n\"simulation.fps\" = { uniform = [1, 2] }\n",
     "random.extra", "unknown key"),
    (HEAD + "[random]\nseed = 1\nsamples = 5\n[random.axes]\n\"cloth.0.mass\" = { uniform = [-1.0, 1.0] }\n",
     "random.axes.cloth.0.mass", "gives an invalid scene"),
    (HEAD + "[axes]\n\"simulation.fps\" = [60]\nunknown = 1\n", "axes.unknown", "expected an array of values"),
    ('[sweep]\nscene = "base.toml"\n[axes]\n"simulation.fps" = [60]\n[extra]\n', "extra", "unknown key"),
    ("x = ", None, "not valid TOML"),
    (b"\xff\xfe", None, "expected UTF-8 text"),
]


@pytest.mark.parametrize("text, key, problem", CASES, ids=[f"{i}" for i in range(len(CASES))])
def test_clean_errors(tmp_path, text, key, problem):
    err = error(tmp_path, text)
    assert err.key == key, str(err)
    assert problem in err.problem, str(err)
    assert "Traceback" not in str(err)


def test_an_invalid_base_scene_is_named(tmp_path):
    err = error(tmp_path, HEAD + '[axes]\n"simulation.fps" = [30]\n', base=BASE_SCENE.replace("frames = 3", "frames = 0"))
    assert err.key == "sweep.scene" and f"the base scene {tmp_path / 'base.toml'} is invalid" in err.problem
    assert "simulation.frames: expected an integer >= 1, got 0" in err.problem


def test_a_combination_the_scene_refuses_names_the_variant(tmp_path):
    # Each value alone is fine; together, the jacobi solver refuses soft sticks.
    text = HEAD + '[axes]\n"simulation.relaxation" = ["coloured", "jacobi"]\n"cloth.0.compliance" = [{}, { structural = 0.001 }]\n'
    err = error(tmp_path, text)
    assert err.key == "axes.cloth.0.compliance"
    assert ('the value { structural = 0.001 } gives an invalid scene (variant 3: simulation.relaxation = "jacobi", '
            "cloth.0.compliance = { structural = 0.001 }): cloth[0].compliance: soft sticks") in err.problem
    assert "soft sticks need the coloured solver" in err.problem


@pytest.mark.slow
def test_ranges_grids_names_and_hashes(tmp_path):
    text = HEAD + ("frames = 5\n[axes]\n"
                   'simulation.substeps = { start = 8, stop = 32, step = 8 }\n'
                   '"cloth.0.mass" = { start = 0.1, stop = 0.3, step = 0.1 }\n'
                   '"simulation.damping" = { start = 0.01, stop = 1, num = 3, spacing = "log" }\n'
                   '"simulation.iterations" = { start = 1, stop = 64, num = 7, spacing = "log" }\n'
                   '"simulation.fps" = { start = 30, stop = 60, num = 3 }\n')
    sweep = load_sweep(write(tmp_path, text))
    values = {a.name: a.values for a in sweep.axes}
    assert values["simulation.substeps"] == (8, 16, 24, 32)
    assert values["cloth.0.mass"] == (0.1, 0.2, 0.3)  # not 0.30000000000000004
    assert values["simulation.damping"] == (0.01, 0.1, 1.0)
    assert values["simulation.iterations"] == (1, 2, 4, 8, 16, 32, 64)  # integers, as the key needs
    assert values["simulation.fps"] == (30.0, 45.0, 60.0)
    assert len(sweep.variants) == 4 * 3 * 3 * 7 * 3
    v = sweep.variants[-1]
    assert v.params == {"simulation.substeps": 32, "cloth.0.mass": 0.3, "simulation.damping": 1.0,
                        "simulation.iterations": 64, "simulation.fps": 60.0}
    sim = v.scene.simulation
    assert (sim.substeps, sim.damping, sim.iterations, sim.fps, sim.frames) == (32, 1.0, 64, 60.0, 5)
    assert v.scene.cloths[0].mass == 0.3
    assert v.name == "755_substeps=32_mass=0.3_damping=1_iterations=64_fps=60"
    assert sweep.variants[0].name.startswith("000_") and len({x.name for x in sweep.variants}) == 756
    assert len({x.hash for x in sweep.variants}) == 756
    # The hash is the variant's scene: loading again gives the same; the output directory does not enter it.
    again = load_sweep(tmp_path / "sweep.toml", output=tmp_path / "elsewhere")
    assert [x.hash for x in again.variants] == [x.hash for x in sweep.variants]
    assert again.output == tmp_path / "elsewhere" and sweep.output == Path("sweep")
    assert parameter_hash({"a": 1, "output": {"path": "x.usdc"}}, "usdc") == parameter_hash({"a": 1, "output": {}}, "usdc")
    assert parameter_hash({"a": 1}, "usdc") != parameter_hash({"a": 1}, "usda")


def test_bare_and_quoted_dotted_keys_are_the_same_axis(tmp_path):
    a = load_sweep(write(tmp_path, HEAD + '[axes]\ncloth.0.mass = [0.1, 0.2]\n'))
    b = load_sweep(write(tmp_path, HEAD + '[axes]\n"cloth.0.mass" = [0.1, 0.2]\n'))
    c = load_sweep(write(tmp_path, HEAD + '[axes.cloth.0]\nmass = [0.1, 0.2]\n'))
    assert [v.hash for v in a.variants] == [v.hash for v in b.variants] == [v.hash for v in c.variants]
    assert [v.scene.cloths[0].mass for v in a.variants] == [0.1, 0.2]


def test_random_draws_are_seeded_and_grow_with_samples(tmp_path):
    def sampled(seed, samples, grid=""):
        return load_sweep(write(tmp_path, HEAD + grid + f"[random]\nseed = {seed}\nsamples = {samples}\n[random.axes]\n"
                                '"simulation.wind" = { uniform = [[-3.0, 0.0, 0.0], [3.0, 0.0, 6.0]] }\n'
                                '"cloth.0.tear_threshold" = { loguniform = [1.05, 2.0] }\n'
                                '"simulation.substeps" = { integers = [1, 4] }\n'
                                '"cloth.0.sticks" = { choice = [["structural"], ["structural", "shear"]] }\n'))

    small, big, other = sampled(7, 20), sampled(7, 40), sampled(8, 20)
    assert [v.params for v in big.variants[:20]] == [v.params for v in small.variants]  # more samples extend
    assert [v.hash for v in big.variants[:20]] == [v.hash for v in small.variants]
    assert [v.params for v in other.variants] != [v.params for v in small.variants]
    for v in big.variants:
        wind, tear = v.params["simulation.wind"], v.params["cloth.0.tear_threshold"]
        assert -3 <= wind[0] <= 3 and wind[1] == 0.0 and 0 <= wind[2] <= 6 and 1.05 <= tear <= 2.0
        assert v.scene.simulation.wind == tuple(wind) and v.scene.cloths[0].tear_threshold == tear
        assert v.params["simulation.substeps"] in (1, 2, 3, 4)
        assert v.scene.cloths[0].sticks == tuple(v.params["cloth.0.sticks"])
    assert {v.params["simulation.substeps"] for v in big.variants} == {1, 2, 3, 4}
    # With a grid too, every grid point takes each draw: the draws do not depend on the grid.
    mixed = sampled(7, 20, '[axes]\n"simulation.iterations" = [1, 2]\n')
    assert len(mixed.variants) == 40 and [v.sample for v in mixed.variants[:3]] == [0, 1, 2]
    assert [v.params["simulation.wind"] for v in mixed.variants[20:]] == [v.params["simulation.wind"] for v in small.variants]


def test_shipped_sweeps_load():
    for path in sorted((ROOT / "scenes" / "sweeps").glob("*.toml")):
        sweep = load_sweep(path)
        assert isinstance(sweep, Sweep) and sweep.variants and sweep.base.is_file(), path


# ---------------------------------------------------------------------------------------------- fuzzing

keys = st.text(st.characters(codec="utf-8"), max_size=12)
scalars = st.one_of(st.booleans(), st.integers(min_value=-(2**63), max_value=2**63 - 1), st.floats(), keys)
values = st.recursive(scalars, lambda c: st.lists(c, max_size=3) | st.dictionaries(keys, c, max_size=3), max_leaves=8)
SCENE_PATHS = ["simulation.fps", "simulation.substeps", "cloth.0.mass", "cloth.0.size.1", "cloth.0.pins",
               "cloth.0.compliance.bend", "collider.0.radius", "output.up_axis", "simulation.wind.2"]
axis_names = st.one_of(st.sampled_from(SCENE_PATHS), keys)
specs = st.one_of(
    st.lists(values, max_size=3),
    st.dictionaries(st.sampled_from(["start", "stop", "step", "num", "spacing", "x"]), scalars, max_size=4),
    st.dictionaries(st.sampled_from(["uniform", "loguniform", "integers", "choice"]), values, min_size=1, max_size=1),
    values,
)
sweep_docs = st.fixed_dictionaries(
    {},
    optional={
        "sweep": st.one_of(st.fixed_dictionaries({"scene": st.just("base.toml")},
                                                 optional={"frames": scalars, "format": scalars, "output": scalars}),
                           values),
        "axes": st.one_of(st.dictionaries(axis_names, specs, max_size=3), values),
        "random": st.one_of(st.fixed_dictionaries({}, optional={"seed": scalars, "samples": st.integers(-2, 5),
                                                                "axes": st.dictionaries(axis_names, specs, max_size=3)}),
                            values),
        "other": values,
    },
)


@pytest.mark.slow
@FUZZ
@given(doc=sweep_docs)
def test_random_sweep_documents_raise_only_scene_errors(tmp_path, doc):
    text = dump(doc)
    assert same(tomllib.loads(text), doc)
    try:
        sweep = load_sweep(write(tmp_path, text))
    except SceneError as err:
        assert err.file == str(tmp_path / "sweep.toml") and err.problem
    else:
        assert sweep.variants and all(v.scene.cloths for v in sweep.variants)


FULL = dump(full_scene())
NUMERIC = [(path, spec) for path, spec in RANGES.items() if path[0] in ("simulation", "cloth", "collider")]


def _dotted(path: tuple) -> str:
    return ".".join(str(p) for p in path)


@pytest.mark.slow
@pytest.mark.parametrize("path, spec", NUMERIC, ids=[_dotted(p) for p, _ in NUMERIC])
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(number=extreme_numbers)
def test_numeric_axis_values_load_in_range_or_name_the_axis(tmp_path, path, spec, number):
    """As tests/test_scene_fuzz.py's extreme numbers, through a sweep axis over the full scene: a value either
    reaches the variant's scene exactly, inside the documented range, or is refused naming the axis."""
    lo, lo_open, hi, hi_open, integer = spec
    axis = _dotted(path)
    sweep_path = write(tmp_path, dump({"sweep": {"scene": "base.toml"}, "axes": {axis: [number]}}), base=FULL)
    try:
        sweep = load_sweep(sweep_path)
    except SceneError as err:
        assert err.key == f"axes.{axis}", f"{axis} = {number!r}: {err}"
        return
    (variant,) = sweep.variants
    assert_number_loaded(loaded_value(variant.scene, path), number, integer, lo, hi, lo_open, hi_open)


@pytest.mark.slow
def test_every_byte_prefix_of_the_shipped_sweeps_is_an_error_or_a_sweep(tmp_path):
    for path in sorted((ROOT / "scenes" / "sweeps").glob("*.toml")):
        raw = path.read_bytes().replace(b'"../', b'"' + str(ROOT / "scenes").encode() + b"/")
        for cut in range(0, len(raw), 7):
            target = tmp_path / "cut.toml"
            target.write_bytes(raw[:cut])
            try:
                load_sweep(target)
            except SceneError as err:
                assert err.file == str(target)
